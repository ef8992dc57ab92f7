"""The whole job on the bundled default profile, without a window: ``make demo``.

Design -> fly -> identify, as far as the pipeline exists. Each stage writes into one output folder
and ``report.md`` links what it wrote.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from identify import LinearModel, format_modes, load_profile, residualize, simulate_run
from signaldesign import Signal, save_signals

DEFAULT_PROFILE = "s61_hover_8state"


def run_demo(out: str | Path, profile: str = DEFAULT_PROFILE, seed: int = 1) -> Path:
    """Run the pipeline into ``out``; return the path of its report."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    truth = LinearModel(load_profile(profile))
    reduced = residualize(truth, ["theta_R", "phi_R"]) if "theta_R" in truth.profile.states else None
    report = [f"# pseudostep demo: {truth.profile.name}", "", "## A priori model", "", "```",
              format_modes(truth.modes()), "```"]
    if reduced is not None:
        report += ["", "4-DOF reduction (rotor tilt instantaneous):", "", "```",
                   format_modes(LinearModel(reduced).modes()), "```"]

    signal = Signal(kind="doublet", input=truth.profile.input_names[0], dt=2.0, levels=[1, -1],
                    amplitude=0.02, delay=1.0, params={"width": 2.0})
    save_signals(signal, out / "signal.json")
    dt, t_end = 0.01, 20.0
    time = np.arange(int(round(t_end / dt)) + 1) * dt
    u = np.zeros((time.size, truth.n_inputs))
    u[:, 0] = signal(time)
    run = simulate_run(truth, time, u, noise_fraction=0.02, seed=seed,
                       meta={"signal": "doublet 2 s", "pilot": "exact"})
    run.to_csv(out / "run_simulated.csv")

    fig, axes = plt.subplots(len(truth.profile.outputs) + 1, 1, sharex=True, figsize=(8, 12))
    axes[0].step(time, u[:, 0], where="post")
    axes[0].set_ylabel(truth.profile.input_names[0])
    for ax, y in zip(axes[1:], truth.profile.outputs):
        ax.plot(time, run[y], lw=0.8)
        ax.set_ylabel(y)
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(out / "time_history.png", dpi=80)
    plt.close(fig)
    report += ["", "## Simulated test point", "",
               f"Doublet on `{signal.input}` (2 s, amplitude {signal.amplitude} rad), 20 s at 100 Hz, "
               "2 % measurement noise: [`run_simulated.csv`](run_simulated.csv).", "",
               "![time history](time_history.png)"]
    path = out / "report.md"
    path.write_text("\n".join(report) + "\n")
    return path

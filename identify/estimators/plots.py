"""Result plots to PNG: measured vs identified time histories (the paper's Figs 12-14), residuals.

Figures are drawn on matplotlib's Agg canvas directly (no pyplot, no display, no global state),
so plotting works headless and in parallel tests.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..errors import EstimationError
from ..model.profile import output_units
from .result import IdentificationResult

_PANEL_HEIGHT_IN = 1.3


def _check(result: IdentificationResult) -> None:
    if not result.time or len(result.measured) != len(result.time) or len(result.modelled) != len(result.time):
        raise EstimationError(f"{result.method.upper()} result holds no time histories to plot")


def _figure(n_panels: int, title: str) -> tuple[Figure, list]:
    fig = Figure(figsize=(8.0, 1.0 + _PANEL_HEIGHT_IN * n_panels), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_panels, 1, sharex=True, squeeze=False)[:, 0]
    fig.suptitle(title, fontsize=10)
    return fig, list(axes)


def _units(result: IdentificationResult) -> list[str]:
    units = output_units(result.profile)
    return [units[y] for y in result.profile.outputs]


def plot_time_histories(result: IdentificationResult, path: str | Path, run: int = 0, inputs=None) -> Path:
    """Measured (markers) and identified-model (line) outputs of run ``run`` (0-based), one panel
    per output; where the modelled outputs are one-step predictions (filter error), the
    identified model's open-loop simulation too, each labelled as what it is; below them the
    input(s) that drove the run: ``inputs`` the run itself (a :class:`~identify.data.runs.Run`
    holding the profile's inputs; None: outputs only, as a result read back from result.json holds
    no inputs). Written as PNG to ``path``."""
    _check(result)
    if not 0 <= run < len(result.time):
        raise EstimationError(f"no run {run + 1}: the result holds {len(result.time)} run(s)")
    t, z, y = result.time[run], result.measured[run], result.modelled[run]
    outputs = list(result.profile.outputs)
    drive = [u for u in result.profile.input_names if inputs is not None and u in inputs.channels]
    source = result.runs[run] if run < len(result.runs) else f"run {run + 1}"
    # the filter-error method's modelled outputs are one-step predictions (the measurements fed
    # back every sample: they flatter any model); its open-loop simulation is drawn beside them
    sim = result.simulated[run] if run < len(result.simulated) else None
    what = "one-step prediction (--), open-loop simulation (-)" if sim is not None else "identified model (-)"
    fig, axes = _figure(len(outputs) + bool(drive), f"{result.method.upper()}: measured (+), {what}, {source}")
    every = max(1, len(t) // 150)  # markers thin enough to see the line through them
    for j, (ax, name, unit) in enumerate(zip(axes, outputs, _units(result))):
        ax.plot(t[::every], z[::every, j], "+", color="0.35", markersize=4, label="measured")
        if sim is not None:
            ax.plot(t, y[:, j], "--", color="C1", linewidth=1.0, label="one-step prediction (filter)")
            ax.plot(t, sim[:, j], "-", color="C0", linewidth=1.2, label="open-loop simulation")
        else:
            ax.plot(t, y[:, j], "-", color="C0", linewidth=1.2, label="identified")
        ax.set_ylabel(f"{name}\n[{unit}]" if unit else name, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    if drive:  # what the pilot (or the designed signal) did: the cause of everything above
        ax, units = axes[-1], result.profile.inputs
        for k, u in enumerate(drive):
            ax.step(inputs.time, inputs[u], where="post", color=f"C{k + 2}", linewidth=1.0,
                    label=f"{u} [{units.get(u, '')}]".replace(" []", ""))
        ax.set_ylabel("input(s)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time [s]")
    return _save(fig, path)


def plot_residuals(result: IdentificationResult, path: str | Path) -> Path:
    """Residuals (measured - modelled) of every output over all runs, runs one after another."""
    _check(result)
    outputs = list(result.profile.outputs)
    fig, axes = _figure(len(outputs), f"{result.method.upper()}: output residuals, {len(result.time)} run(s)")
    for r, (t, e) in enumerate(zip(result.time, result.residuals())):
        for j, ax in enumerate(axes):
            ax.plot(t, e[:, j], linewidth=0.8, color=f"C{r % 10}", label=f"run {r + 1}")
    for j, (ax, name, unit) in enumerate(zip(axes, outputs, _units(result))):
        ax.axhline(0.0, color="0.5", linewidth=0.6)
        rms = result.fit.get(name, {}).get("rms")
        label = f"{name}\n[{unit}]" if unit else name
        ax.set_ylabel(label, fontsize=8)
        if rms is not None and np.isfinite(rms):
            ax.text(0.99, 0.9, f"RMS {rms:.3g}", transform=ax.transAxes, ha="right", va="top", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    if len(result.time) > 1:
        axes[0].legend(fontsize=7, loc="upper left")
    axes[-1].set_xlabel("time [s]")
    return _save(fig, path)


def save_plots(result: IdentificationResult, outdir: str | Path, runs=None) -> list[Path]:
    """``time_history_run<k>.png`` per run (with its inputs drawn, given the fitted ``runs``) and
    ``residuals.png`` in ``outdir``; returns the paths."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    runs = list(runs) if runs is not None and len(runs) == len(result.time) else [None] * len(result.time)
    paths = [plot_time_histories(result, outdir / f"time_history_run{r + 1}.png", r, runs[r])
             for r in range(len(result.time))]
    paths.append(plot_residuals(result, outdir / "residuals.png"))
    return paths


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path

"""The frequency-domain walk-through of docs/frequency.md, end to end on simulated S 61 flights.

A "real" S 61 (the 8-state hover model with a 0.08 s control delay on both cyclics) flies two
logarithmic sweeps per cyclic (40 s, 0.2 deg, 2 s of trim either side) and one held-out run of
3211s on both cyclics; instrument-grade noise. Then, as a user would:

    identify freq     sweeps -> Bode grids with the a priori, ML- and FR-identified 4-DOF models, J
    identify estimate --method fr --prune --fr-delays theta_s,theta_c --verify held-out run
    identify hq       sweeps --with-model -> ADS-33 charts, short-period LOES
    identify loes     p/theta_c: first order + delay

    python benchmarks/frequency_example.py     # -> benchmarks/output/frequency_example/ (no options)
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import subprocess  # noqa: E402
import sys  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.signal import chirp  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from identify import LinearModel, load_profile, simulate_run  # noqa: E402
from signaldesign.baselines import m3211  # noqa: E402
from _cli import parser as cli_parser  # noqa: E402

OUT = ROOT / "benchmarks" / "output" / "frequency_example"
DT, DELAY = 0.02, 0.08
DEG = np.pi / 180
NOISE = {"u": 0.05, "v": 0.05, "p": 0.05 * DEG, "q": 0.05 * DEG, "theta": 0.05 * DEG, "phi": 0.05 * DEG,
         "theta_R": 0.05 * DEG, "phi_R": 0.05 * DEG}


def simulate(out: Path) -> tuple[list[Path], Path, Path]:
    p = load_profile("s61_hover_8state")
    real = replace(p, meta={**p.meta, "delays": {"theta_s": DELAY, "theta_c": DELAY}},
                   name="S 61 hover, 8 states, 0.08 s control delay")
    aircraft = out / "s61_8state_delay.toml"
    real.save(aircraft)
    model = LinearModel(real)
    t = np.arange(0, 40, DT)
    on = (t >= 2) & (t < 38)
    sweeps = []
    for j, axis in enumerate(p.input_names):
        for k, (f0, f1) in enumerate([(0.1, 3.0), (0.15, 4.0)]):
            U = np.zeros((len(t), 2))
            U[:, j] = np.where(on, np.deg2rad(0.2) * chirp(t - 2, f0, 36, f1, method="logarithmic", phi=-90), 0)
            run = simulate_run(model, t, U, noise=NOISE, seed=10 * j + k, input_delay=DELAY)
            sweeps.append(run.to_csv(out / f"sweep_{axis}_{k + 1}.csv"))
    t = np.arange(0, 20, DT)
    U = np.column_stack([m3211(1.0, np.deg2rad(0.2), "theta_s", delay=1.0)(t),
                         m3211(0.7, np.deg2rad(0.2), "theta_c", delay=9.0)(t)])
    held = simulate_run(model, t, U, noise=NOISE, seed=99, input_delay=DELAY).to_csv(out / "held_out_3211s.csv")
    return sweeps, held, aircraft


def identify(*args) -> None:
    print("$ identify " + " ".join(str(a) for a in args), flush=True)
    subprocess.run([sys.executable, "-m", "identify", *map(str, args)], check=True, cwd=ROOT)


def parser():
    return cli_parser(__doc__)  # no options: --help only


def main(argv=None) -> int:
    parser().parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    sweeps, held, aircraft = simulate(OUT)
    identify("estimate", *sweeps, "--profile", "s61_hover_4dof", "--method", "ml", "--out", OUT / "ml")
    identify("estimate", *sweeps, "--profile", "s61_hover_4dof", "--method", "fr", "--prune",
             "--fr-delays", "theta_s,theta_c", "--verify", held, "--out", OUT / "fr")
    identify("freq", *sweeps, "--profile", "s61_hover_4dof", "--identified", OUT / "ml" / "identified_profile.toml",
             "--identified", OUT / "fr" / "identified_profile.toml", "--out", OUT / "freq")
    identify("hq", *sweeps, "--profile", aircraft, "--with-model", "--out", OUT / "hq")
    identify("loes", *sweeps, "--profile", "s61_hover_4dof", "--pair", "p/theta_c", "--num", "0", "--den", "1",
             "--tau-max", "0.3", "--out", OUT / "loes")
    return 0


if __name__ == "__main__":
    sys.exit(main())

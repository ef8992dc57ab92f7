"""The paper's S 61 case through `identify refine`: data from the 8-state model (rotor tip-path
plane), declared model the 4-DOF rigid body. Prints each step with its evidence and the error
before and after on the fit and validation runs, and the wall time.

    .venv/bin/python benchmarks/refine_s61.py [run length s] [max steps]   # --help: options
"""
import os
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from identify import LinearModel, load_profile, simulate_run  # noqa: E402
from identify.refine import Refine  # noqa: E402
from _cli import count, parser as cli_parser, positive  # noqa: E402

DT = 0.05


def cyclics(seed: int, n: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    k = int(0.5 / DT)
    u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=(n // k + 1, 2)), k, axis=0)[:n] * 0.01
    u[:k] = 0.0
    return u


def main(length: float = 15.0, max_steps: int = 4) -> None:
    truth = LinearModel(load_profile("s61_hover_8state"))
    t = np.arange(int(length / DT) + 1) * DT
    runs = [simulate_run(truth, t, cyclics(s, len(t)), noise_fraction=0.02, seed=s) for s in (1, 2, 3)]
    started = time.perf_counter()
    r = Refine(load_profile("s61_hover_4dof"), kinds=("derivative", "delay", "lag"),
               max_steps=max_steps).fit(runs[:2], validate=runs[2:])
    wall = time.perf_counter() - started
    print(f"S 61: truth 8-state, declared 4-DOF; 2 fit runs + 1 validation run of {length:g} s at "
          f"{1 / DT:g} Hz, both cyclics excited, 2 % noise; segment {r.segment_:.2f} s")
    for i, s in enumerate(r.steps_, start=1):
        params = ", ".join(f"{k} = {v['value']:.4g} ± {v['std']:.2g}" for k, v in s.parameters.items())
        print(f"step {i}: {s.effect} on {s.target}: {params}; score {s.statistic:.1f} > {s.threshold:.1f}; "
              f"validation {s.error_before['validation']['overall']:.4f} -> {s.error_after['validation']['overall']:.4f}")
    for s in r.rejected_:
        print(f"rejected: {s.effect} on {s.target}: {s.reason}")
    for where in ("fit", "validation"):
        print(f"{where} error (overall): {r.error_before_[where]['overall']:.4f} -> {r.error_after_[where]['overall']:.4f}")
    print(f"truth rotor flapping time constant 0.1 s (k = 10 1/s); wall time {wall:.1f} s")


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("length", nargs="?", type=positive, default=15.0, help="length of each run, s")
    ap.add_argument("max_steps", nargs="?", type=count, default=4, help="refine's largest number of steps")
    return ap


if __name__ == "__main__":
    args = parser().parse_args()
    main(args.length, args.max_steps)

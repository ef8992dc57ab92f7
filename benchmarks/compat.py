"""Flight-path reconstruction (identify compat) on synthetic flights with known sensor errors.

Each realisation: a 30 s flight (identify.compat.synthetic.flight: elevator 3211, aileron and
rudder doublets, turbulence, sensor noise) with an alpha vane of scale 1.05, bias 1 deg and a
60 ms skew and a q gyro biased by 0.2 deg/s, seeds 0..SEEDS-1 (default 25) at each of two
turbulence levels (50 realisations), and in the strong turbulence once more with the inertial
sensors' noise given (as from a data sheet) instead of estimated from the data.

Printed per sensor error: how often it was selected, the mean error over the Monte Carlo std
(bias/std), the Monte Carlo std of the estimates over the mean reported standard error (1 for
honest bounds, > 1 optimistic), the same over the bounds' parts (white: Cramér-Rao; coloured: the
engine's Morelli & Klein correction alone; white + the integrated input noise), how often the
truth lies within 2 reported standard errors (about 95 % for honest bounds); then the false
alarms (errors selected that are not there), the fits not converged and the wall time per fit.
Written also to benchmarks/output/compat.json. Usage: python benchmarks/compat.py [SEEDS] (--help: options)
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from _cli import counted  # noqa: E402
from identify.compat import Compat  # noqa: E402
from identify.compat.kinematics import INPUTS  # noqa: E402
from identify.compat.synthetic import ERRORS, NOISE, flight  # noqa: E402

# (deg RMS gust angle, the inertial sensors' noise given as a data sheet would, or None: estimated)
CASES = ((0.1, None), (0.5, None), (0.5, {c: NOISE[c] for c in INPUTS}))
OUT = Path(__file__).resolve().parent / "output"


def realisations(gust: float, input_noise, seeds: int) -> list[dict]:
    rows = []
    for seed in range(seeds):
        measured, _ = flight(seed=seed, gust_deg=gust)
        t0 = time.perf_counter()
        r = Compat(input_noise=input_noise).fit(measured).result_
        rows.append({"seed": seed, "wall": time.perf_counter() - t0, "converged": r.converged, "stop": r.stop,
                     "value": {e.name: float(v) for e, v in zip(r.errors, r.value)},
                     "std": {e.name: float(s) for e, s in zip(r.errors, r.std)},
                     **{k: r.info[k] for k in ("std_white", "std_coloured", "std_input_noise")}})
    return rows


def table(rows: list[dict]) -> list[str]:
    """Per sensor error: selected, bias/std, MC std over the mean bound (as reported: coloured
    output noise and integrated input noise; then the parts: white, coloured alone, white +
    input noise), within 2 reported standard errors."""
    lines = [f"    {'error':<10}{'selected':>9}{'bias/std':>10}{'MC std/bound':>14}  (white  coloured  white+inputs)"
             f"{'within 2 sd':>14}"]
    for name, truth in ERRORS.items():
        got = [r for r in rows if name in r["value"]]
        if len(got) < 2:
            lines.append(f"    {name:<10}{len(got):>6}/{len(rows):<2} (too few to judge)")
            continue
        err = np.array([r["value"][name] - truth for r in got])
        std = np.array([r["std"][name] for r in got])
        part = {k: np.array([r[k][name] for r in got]) for k in ("std_white", "std_coloured", "std_input_noise")}
        white_inputs = np.sqrt(part["std_white"] ** 2 + part["std_input_noise"] ** 2)
        mc = err.std(ddof=1)
        inside = int(np.sum(np.abs(err) < 2 * std))
        lines.append(f"    {name:<10}{len(got):>6}/{len(rows):<2}{err.mean() / mc:10.2f}{mc / std.mean():14.2f}"
                     f"  ({mc / part['std_white'].mean():5.2f}  {mc / part['std_coloured'].mean():8.2f}"
                     f"  {mc / white_inputs.mean():12.2f})"
                     f"{inside:>7}/{len(got)} ({100 * inside / len(got):.0f} %)")
    false = [n for r in rows for n in r["value"] if n not in ERRORS]
    lines.append(f"    false alarms: {len(false)} in {len(rows)} flights ({', '.join(sorted(set(false))) or 'none'}; "
                 f"family-wise level 0.01 per flight); not converged: {sum(not r['converged'] for r in rows)}")
    return lines


def parser():
    return counted(__doc__, "seeds", 25, "realisations per case (seeds 0..SEEDS-1; 3 cases)")


def main(argv=None):
    seeds = parser().parse_args(argv).seeds
    print(f"identify compat: {seeds} seeds per turbulence level, truth {ERRORS}", flush=True)
    saved = {}
    for gust, noise in CASES:
        rows = realisations(gust, noise, seeds)
        key = f"{gust}" + (" inertial noise given" if noise else "")
        saved[key] = rows
        print(f"  gust angle {gust} deg RMS, inertial sensors' noise {'given' if noise else 'estimated'}: "
              f"fit {np.median([r['wall'] for r in rows]):.1f} s (median)")
        print("\n".join(table(rows)), flush=True)
    print("  both turbulence levels, noise estimated (50 realisations by default):")
    print("\n".join(table([r for k, rows in saved.items() if "given" not in k for r in rows])))
    OUT.mkdir(exist_ok=True)
    (OUT / "compat.json").write_text(json.dumps({"truth": ERRORS, "seeds": seeds, "runs": saved}, indent=1))


if __name__ == "__main__":
    main()

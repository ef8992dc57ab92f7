"""Flight-path reconstruction (identify compat) on synthetic flights with known sensor errors.

Each realisation: a 30 s flight (identify.compat.synthetic.flight: elevator 3211, aileron and
rudder doublets, turbulence, sensor noise) with an alpha vane of scale 1.05, bias 1 deg and a
60 ms skew and a q gyro biased by 0.2 deg/s, seeds 0..SEEDS-1, at two turbulence levels. Printed:
per sensor error the share of realisations where it was selected and recovered within 2 of its
standard errors, the RMS of (estimate - truth) / std (1 for honest bounds), the false alarms
(errors selected that are not there) and the wall time per fit.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from identify.compat import Compat  # noqa: E402
from identify.compat.synthetic import ERRORS, flight  # noqa: E402

SEEDS = int(sys.argv[1]) if len(sys.argv) > 1 else 10


def main():
    print(f"identify compat: {SEEDS} seeds per turbulence level, truth {ERRORS}")
    for gust in (0.1, 0.5):
        z, hits, false, times = {k: [] for k in ERRORS}, {k: 0 for k in ERRORS}, [], []
        for seed in range(SEEDS):
            measured, _ = flight(seed=seed, gust_deg=gust)
            t0 = time.perf_counter()
            r = Compat().fit(measured).result_
            times.append(time.perf_counter() - t0)
            got = {e.name: (v, s) for e, v, s in zip(r.errors, r.value, r.std)}
            for name, truth in ERRORS.items():
                if name in got:
                    zz = (got[name][0] - truth) / got[name][1]
                    z[name].append(zz)
                    hits[name] += abs(zz) < 2
            false += [n for n in got if n not in ERRORS]
        print(f"  gust angle {gust} deg RMS: fit {np.median(times):.1f} s (median)")
        for name in ERRORS:
            rms = np.sqrt(np.mean(np.square(z[name]))) if z[name] else float("nan")
            print(f"    {name:<10} selected {len(z[name])}/{SEEDS}, within 2 std errors {hits[name]}/{SEEDS}, "
                  f"RMS z {rms:.2f}")
        print(f"    false alarms: {len(false)} in {SEEDS} flights ({', '.join(false) or 'none'}; "
              f"family-wise level 0.01 per flight)")


if __name__ == "__main__":
    main()

"""ML on a long record: peak memory and result.json size for one hour at 100 Hz.

Problem: the Navion longitudinal model (stable, so plain output error: one segment per run), one
run of ``HOURS`` hours at 100 Hz (360 000 samples for 1 h), a 3211 on the elevator every 20 s,
process noise (turbulence) and 5 % measurement noise; a priori values 20 % off. ML with the
coloured-residual bounds (the default), then ``result.save``. Printed: wall time, peak resident
memory of this process (``resource.getrusage``, so it includes numpy's imports, ~60 MB) and the
size of ``result.json``; the limits of issue 11 are 1 GB and 1 MB.

``python benchmarks/ml_long_record.py [HOURS]`` (default 1). BLAS single-threaded.
"""
import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from identify import ML, LinearModel, load_profile, simulate_run  # noqa: E402

LIMIT_MB, JSON_LIMIT_KB = 1024, 1024


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def long_run(truth, hours: float, dt: float = 0.01):
    t = np.arange(int(round(hours * 3600 / dt)) + 1) * dt
    phase = np.mod(t, 20.0)  # a 3211 (width 0.5 s) at the start of every 20 s
    u = np.zeros_like(t)
    a = 1.0
    for k, sign in zip((3, 2, 1, 1), (1, -1, 1, -1)):
        u[(phase >= a) & (phase < a + 0.5 * k)] = 0.02 * sign
        a += 0.5 * k
    clean = simulate_run(truth, t[:20001], u[:20001, None])
    noise = {y: 0.05 * float(np.std(clean[y])) for y in truth.profile.outputs}
    return simulate_run(truth, t, u[:, None], noise=noise, process_noise=[0.05, 0.05, 0.002, 0.0], seed=1)


def main():
    hours = float(sys.argv[1]) if len(sys.argv) > 1 else 1.0
    truth = LinearModel(load_profile("navion_cruise_long"))
    run = long_run(truth, hours)
    base = peak_mb()
    start = truth.profile.with_values(dict(zip(truth.names, truth.theta * 1.2)))
    t0 = time.perf_counter()
    res = ML(start).fit(run).result_
    wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as out:
        res.save(out)
        size_kb = (Path(out) / "result.json").stat().st_size / 1024
        json.loads((Path(out) / "result.json").read_text(), parse_constant=lambda c: 1 / 0)  # strict JSON
    peak = peak_mb()
    print(f"ML long record: Navion longitudinal, {hours:g} h at 100 Hz ({len(run)} samples), "
          f"{res.info['form']} output error, coloured-residual bounds")
    print(f"  fit: {wall:.1f} s, {res.info['iterations']} iterations, converged {res.info['converged']}")
    print(f"  peak memory: {peak:.0f} MB (after simulating the run: {base:.0f} MB); limit {LIMIT_MB} MB: "
          f"{'met' if peak < LIMIT_MB else 'NOT met'}")
    print(f"  result.json: {size_kb:.1f} kB, strict JSON; limit {JSON_LIMIT_KB} kB: "
          f"{'met' if size_kb < JSON_LIMIT_KB else 'NOT met'}")


if __name__ == "__main__":
    main()

"""The filter-error method's extended Kalman filter against output error on a state-built term.

The pitch model of tests/identify/refine/test_refine.py with a quadratic pitch damping
M_q_absq q|q| (truth -20), strong white turbulence on the u and q equations and 1 % white
measurement noise, two 20 s runs per realisation (tests/identify/estimators/test_filter_error_nonlinear.py
``simulate``). Per estimator: each parameter's mean and spread of (estimate - truth) / reported std
(a bias and how well the bound covers), the median relative error and the median wall time per
fit; output error (ML, the term from its own simulated states re-fitted until the estimates
settle, as ``identify estimate`` fits it) also counts the realisations in which it did not settle
(or its simulation diverged).

    .venv/bin/python benchmarks/filter_error_nonlinear.py [realisations, default 25]   # --help: options
"""
import os
import sys
import time
import warnings
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from identify import ML  # noqa: E402
from identify.errors import EstimationError, SimulationError  # noqa: E402
from identify.estimators.filter_error import FEM  # noqa: E402
from identify.estimators.prediction import fit_state_terms  # noqa: E402
from identify.model.pseudo_inputs import prepare  # noqa: E402
from tests.identify.estimators.test_filter_error_nonlinear import NOISE, TRUTH, nonlinear_profile, simulate  # noqa: E402
from _cli import counted  # noqa: E402


def fem(prof, runs):
    return FEM(prof, process_noise=NOISE).fit(runs).result_


def ml(prof, runs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fit_state_terms(lambda p: ML(p), prof, prepare(prof, runs))[1]


def main(n: int = 25) -> None:
    prof = nonlinear_profile()
    rows = {"FEM (extended filter)": [], "ML (output error)": []}
    failed = dict.fromkeys(rows, 0)
    names = None
    for i in range(n):
        runs = [simulate(1000 + 2 * i), simulate(1001 + 2 * i)]
        for label, fit in zip(rows, (fem, ml)):
            t0 = time.perf_counter()
            try:
                r = fit(prof, runs)
            except (EstimationError, SimulationError):  # did not settle, or its simulation diverged
                failed[label] += 1
                continue
            names = r.names
            rows[label].append(((r.theta - TRUTH) / r.std, np.abs(r.theta - TRUTH) / np.abs(TRUTH),
                                time.perf_counter() - t0))
    print(f"q|q| truth {TRUTH[-1]}, {n} realisations of 2 x 20 s, strong turbulence, 1 % white noise")
    print(f"{'':24s}" + "".join(f"{s:>12s}" for s in names))
    for label, res in rows.items():
        if not res:
            print(f"{label}: no fit succeeded")
            continue
        z = np.array([r[0] for r in res])
        rel = np.array([r[1] for r in res])
        print(f"{label}: {len(res)} fits, {failed[label]} failed (did not settle or diverged), median wall "
              f"{np.median([r[2] for r in res]):.1f} s")
        print(f"{'  mean z (bias / std)':24s}" + "".join(f"{v:12.2f}" for v in z.mean(0)))
        print(f"{'  std of z':24s}" + "".join(f"{v:12.2f}" for v in z.std(0, ddof=1)))
        print(f"{'  median rel. error':24s}" + "".join(f"{v:12.3f}" for v in np.median(rel, 0)))


def parser():
    return counted(__doc__, "realisations", 25, "noise realisations (2 runs of 20 s each)")


if __name__ == "__main__":
    main(parser().parse_args().realisations)

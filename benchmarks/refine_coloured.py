"""`identify refine` under coloured residuals: turbulence (process noise through the aircraft's own
dynamics) and filtered (coloured) measurement noise, as in flight data.

1. False alarms: the matched pitch model of tests/test_refine.py, 2 fit runs + 1 validation run of
   20 s each, turbulence + coloured measurement noise, the full catalogue; ``n`` realisations.
   Printed: each realisation's additions and largest score / threshold, the false-alarm rate of
   the coloured-residual tests and, measured on the same data, of the white-noise tests
   (``coloured=False``, the tests before issue 10).
2. Each undeclared effect of tests/test_refine.py with the same turbulence: found or not, the
   estimate against the truth, the validation (judging) error before and after.
3. The same effects with white noise only (the existing tests' data): coloured vs white tests.

Wall time per case is printed.

    .venv/bin/python benchmarks/refine_coloured.py [realisations] [parts, e.g. 123] [--method fem]   # --help

``--method fem``: every fit and test with the filter-error method (process noise on the u and q
equations, where the turbulence acts), i.e. in the innovations' metric; part 1 then compares the
FEM tests (coloured-residual noise model on the innovations) with output error's.
"""
import os
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from identify import parse_profile  # noqa: E402
from identify.refine.candidates import Lag  # noqa: E402
from identify.refine import Refine  # noqa: E402
from identify.estimators.filter_error import FEM  # noqa: E402
from tests.identify.refine.test_refine import PROFILE, TOML, TURBULENCE, make_runs, nonlinear_runs  # noqa: E402
from _cli import add_parts, counted  # noqa: E402


METHOD = "ml"


def estimator():
    """The refine estimator of this run: None (ML, refine's default) or FEM."""
    return FEM(PROFILE, process_noise={"u": None, "q": None}) if METHOD == "fem" else None


def false_alarms(n: int) -> None:
    print(f"1. matched model, turbulence {TURBULENCE.tolist()} + coloured measurement noise, "
          f"{n} realisations, full catalogue")
    found, fired = {True: 0, False: 0}, {True: 0, False: 0}
    started = time.perf_counter()
    for i in range(n):
        seeds = (100 + 3 * i, 101 + 3 * i, 102 + 3 * i)
        fit, val = make_runs(seeds=seeds, turbulence=TURBULENCE)
        line = []
        for coloured in ((True, False) if METHOD == "ml" else (True,)):  # FEM: its own (coloured) tests
            t0 = time.perf_counter()
            r = Refine(PROFILE, coloured=coloured, estimator=estimator()).fit(fit, validate=val)
            found[coloured] += not r.nothing_found
            fired[coloured] += bool(r.steps_ or r.rejected_)  # the first score test found something
            top = max(r.last_scores_, key=lambda d: d.statistic / d.threshold, default=None)
            worst = f"{top.candidate.name} {top.statistic:.1f}/{top.threshold:.1f}" if top else "-"
            added = [f"{s.effect}:{s.target}" for s in r.steps_]
            line.append(f"{'coloured' if coloured else 'white'}: added {added or 'nothing'}, "
                        f"{len(r.rejected_)} rejected, top {worst}, {time.perf_counter() - t0:.1f} s")
        print(f"  realisation {i:2d}: " + " | ".join(line), flush=True)
    for coloured in ((True, False) if METHOD == "ml" else (True,)):
        print(f"  {'coloured-residual' if coloured else 'white-noise'} tests: false alarms (an effect added) "
              f"{found[coloured]} of {n} = {100 * found[coloured] / n:.1f} %; the score test alone significant "
              f"{fired[coloured]} of {n} = {100 * fired[coloured] / n:.1f} % (family level alpha = 1 %)")
    print(f"  wall time {time.perf_counter() - started:.1f} s")


CASES = [  # name, truth runs(turbulence), kinds, options, (kind, target), parameter, truth value
    ("missing M_u", lambda tb: make_runs(parse_profile(TOML.replace("M_eta = 5.0", "M_eta = 5.0\nM_u = 0.05")),
                                         turbulence=tb), None, {}, ("derivative", "M_u"), "M_u", 0.05),
    ("0.1 s delay", lambda tb: make_runs(delay_samples=5, turbulence=tb), ("derivative", "delay", "lag", "drift"),
     {}, ("delay", "eta"), "tau_eta", 0.1),
    ("0.15 s lag", lambda tb: make_runs(Lag("eta", k=1 / 0.15).profile(PROFILE), turbulence=tb),
     ("derivative", "delay", "lag", "drift"), {}, ("lag", "eta"), "k_eta_lag", 1 / 0.15),
    ("bias on q", lambda tb: make_runs(transform=lambda r, s: r.with_channels({"q": r["q"] + 0.02}), turbulence=tb),
     ("bias", "drift", "scale", "derivative"), {"zero_shifts": False}, ("bias", "q"), "bias_q", 0.02),
    ("drift on theta", lambda tb: make_runs(transform=lambda r, s: r.with_channels(
        {"theta": r["theta"] + 0.002 * (r.time - r.time[0])}), turbulence=tb),
     ("bias", "drift", "scale", "derivative"), {}, ("drift", "theta"), "drift_theta", 0.002),
    ("15 % scale on q", lambda tb: make_runs(transform=lambda r, s: r.with_channels({"q": 1.15 * r["q"]}),
                                             turbulence=tb),
     ("bias", "drift", "scale", "derivative"), {}, ("scale", "q"), "sf_q", 0.15),
    ("M in q|q|", lambda tb: nonlinear_runs(-20.0, turbulence=tb), ("derivative", "nonlinear"), {},
     ("nonlinear", "M:q_absq"), "M_q_absq", -20.0),
    ("4 Hz vibration on q", lambda tb: make_runs(transform=lambda r, s: r.with_channels(
        {"q": r["q"] + 0.01 * np.cos(2 * np.pi * 4.0 * r.time + np.random.default_rng(100 + s).uniform(0, 6.28))}),
        turbulence=tb), ("periodic", "drift", "derivative"), {}, ("periodic", "q"), "a_cos_q", 0.01),
]


def effects(turbulence, label: str, variants=(True,)) -> None:
    print(f"{label}")
    for name, make, kinds, options, expect, param, truth in CASES:
        fit, val = make(turbulence)
        for coloured in variants:
            t0 = time.perf_counter()
            kw = dict(options, coloured=coloured, **({"kinds": kinds} if kinds else {}))
            r = Refine(PROFILE, estimator=estimator(), **kw).fit(fit, validate=val)
            wall = time.perf_counter() - t0
            step = next((s for s in r.steps_ if (s.effect, s.target) == expect), None)
            tag = "" if len(variants) == 1 else f" [{'coloured' if coloured else 'white'} tests]"
            if step is None:
                print(f"  {name}{tag}: NOT FOUND; added {[(s.effect, s.target) for s in r.steps_]}, rejected "
                      f"{[(s.effect, s.target, s.reason[:60]) for s in r.rejected_]}; {wall:.1f} s")
                continue
            est = step.parameters[param]
            v = r.error_before_["validation"]["overall"], r.error_after_["validation"]["overall"]
            print(f"  {name}{tag}: found at step {r.steps_.index(step) + 1} of {len(r.steps_)} "
                  f"({', '.join(f'{s.effect}:{s.target}' for s in r.steps_)}); {param} = {est['value']:.4g} ± "
                  f"{est['std']:.2g} (truth {truth:.4g}, {abs(est['value'] - truth) / est['std']:.1f} std); "
                  f"judging error {v[0]:.4f} -> {v[1]:.4f}; {wall:.1f} s", flush=True)


def main(n: int = 40, parts: str = "123") -> None:
    started = time.perf_counter()
    if "1" in parts:
        false_alarms(n)
    if "2" in parts:
        effects(TURBULENCE, "2. each undeclared effect with the same turbulence and coloured measurement noise")
    if "3" in parts:
        effects(None, "3. each undeclared effect with white measurement noise (1 %): coloured vs white tests",
                variants=(True, False))
    print(f"total wall time {time.perf_counter() - started:.1f} s")


def parser():
    ap = counted(__doc__, "realisations", 40, "part 1's noise realisations")
    add_parts(ap, "parts", "123", "the parts to run")
    ap.add_argument("--method", choices=("ml", "fem"), default=METHOD,
                    help="the estimator of every fit and test (fem: the filter-error method)")
    return ap


if __name__ == "__main__":
    args = parser().parse_args()
    METHOD = args.method
    print(f"estimator: {METHOD}")
    main(args.realisations, args.parts)

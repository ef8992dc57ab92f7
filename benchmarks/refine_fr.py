"""`identify refine` with the frequency-response estimator (FR) beside ML: power and false alarms.

The pitch case of tests/identify/refine (two 20 s fit runs of random 0.5 s steps, one validation
run, 1 % white measurement noise), catalogue ``derivative``, one step. Per realisation:
- null: the declared structure is the truth; anything accepted is a false alarm;
- each effect in EFFECTS added to the truth: found (the true entry accepted first) or not;
- M_u = 0.05, which FR resolves poorly, with two steps: any other entry accepted is a false alarm
  (the time-domain ratios of J fits accepted X_q there);
- the calibration of FR's own ratio: on null data, fits without and with a spurious X_q or X_eta,
  the statistic's mean (chi-square(1): 1) and its rate above the 5 % quantile 3.84, beside J's drop
  over its dispersion alone (the points taken as independent).
FR's nested likelihood ratios are its own (J's drop over its dispersion, scaled by its bootstrap's
inflation of J's bound, :meth:`IdentificationResult.compare_lr_test`). Prints per realisation and
totals, the machine load and the wall time.

    .venv/bin/python benchmarks/refine_fr.py [realisations]   # --help: options
"""
import os
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from identify import ML, parse_profile  # noqa: E402
from identify.estimators.frequency.response_fit import FR  # noqa: E402
from identify.refine import Refine  # noqa: E402
from identify.refine.candidates import Derivative  # noqa: E402
from tests.identify.refine.test_refine import PROFILE, TOML, make_runs  # noqa: E402
from _cli import counted  # noqa: E402

EFFECTS = {"null": None, "X_eta": 1.0, "X_q": 1.0, "M_u": 0.2}


def one(effect: str, value, seed: int, method: str, steps: int = 1):
    truth = PROFILE if value is None else parse_profile(TOML.replace("M_eta = 5.0", f"M_eta = 5.0\n{effect} = {value}"))
    fit, val = make_runs(truth, seeds=(100 + 3 * seed, 101 + 3 * seed, 102 + 3 * seed))
    est = FR(PROFILE) if method == "fr" else ML(PROFILE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = Refine(PROFILE, estimator=est, kinds=("derivative",), max_steps=steps).fit(fit, validate=val)
    return r


def main(n: int = 20) -> None:
    started = time.perf_counter()
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)")
    for effect, value in EFFECTS.items():
        for method in ("ml", "fr"):
            hits, t0 = 0, time.perf_counter()
            for seed in range(n):
                r = one(effect, value, seed, method)
                added = [s.target for s in r.steps_]
                hits += bool(added) if value is None else added == [effect]
                tried = "; ".join(f"{s.target} LR {s.lr_statistic:.3g}" + ("" if s.accepted else " refused")
                                  for s in r.rejected_ + r.steps_)
                print(f"  {effect:5s} {method} seed {seed:2d}: added {added} ({tried or 'nothing significant'})",
                      flush=True)
            what = "false alarms" if value is None else f"{effect} = {value} found"
            print(f"{effect} {method.upper()}: {what} in {hits} of {n}; {time.perf_counter() - t0:.1f} s", flush=True)
    for method in ("ml", "fr"):
        wrong = 0
        for seed in range(n):
            added = [s.target for s in one("M_u", 0.05, seed, method, steps=2).steps_]
            wrong += bool(set(added) - {"M_u"})
            print(f"  M_u = 0.05 {method} seed {seed:2d}: added {added}", flush=True)
        print(f"M_u = 0.05 {method.upper()} (two steps): another entry accepted in {wrong} of {n}", flush=True)
    calibration(n)
    print(f"load average at end: {os.getloadavg()[0]:.2f}; total {time.perf_counter() - started:.1f} s")


def calibration(n: int) -> None:
    """FR's nested ratio for a spurious entry on null data against chi-square(1)."""
    import numpy as np

    for extra in ("X_q", "X_eta"):
        own, independent = [], []
        for seed in range(n):
            fit, _ = make_runs(seeds=(100 + 3 * seed, 101 + 3 * seed, 102 + 3 * seed))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                null = FR(PROFILE).fit(fit).result_
                alt = FR(Derivative(extra).profile(PROFILE)).fit(fit).result_
            own.append(alt.compare_lr_test(null)[0])
            c0, c1 = null.info["criterion"], alt.info["criterion"]
            independent.append((c0["cost"] - c1["cost"]) / c1["dispersion"])
            print(f"  null data, spurious {extra} seed {seed:2d}: FR ratio {own[-1]:.3g} (points independent: "
                  f"{independent[-1]:.3g}; inflation {c1['inflation'][extra]:.3g})", flush=True)
        own, independent = np.array(own), np.array(independent)
        print(f"spurious {extra}, {n} null realisations: FR ratio mean {own.mean():.2f}, above 3.84 in "
              f"{np.mean(own > 3.84):.0%}; J's drop over its dispersion alone: mean {independent.mean():.1f}, "
              f"above 3.84 in {np.mean(independent > 3.84):.0%}", flush=True)


def parser():
    return counted(__doc__, "realisations", 20, "noise realisations per effect and estimator (and for the calibration)")


if __name__ == "__main__":
    main(parser().parse_args().realisations)

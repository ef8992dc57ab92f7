"""Wall time of `identify refine` at flight-test size: the BO 105 model (8 states, 4 inputs, 11
outputs, 37 free derivatives, unstable: multiple shooting), 4 fit runs of 12 s at 100 Hz with all
four controls excited and a 7 Hz vibration on q, plus one validation run, the full catalogue
(issue 10's target: under 2 minutes on one core). A second case adds turbulence, a third has the
turbulence without the vibration (the truth is then the declared model: anything added is false).
A fourth has no vibration and a delay on every input (0.06, 0.08, 0.05 and 0.07 s: four delays to
find, each by a profile-likelihood search; issue 29's target: under 2 minutes on one core).

Prints each case's steps, the wall time of each (with the machine's load average: the machine may
be shared), the delays found against the truth, and the progress lines refine writes to stderr.
``--method fem`` runs refine with the filter-error method, as ``identify refine --method fem`` does
(its default options; the default is ML, the command line's default).
``--baseline REF`` runs the same cases with the code of a git revision (exported to a temporary
directory) right after, in the same process's run, and prints the ratio of the wall times.

    .venv/bin/python benchmarks/refine_speed.py [cases, e.g. 123] [--baseline main]   # --help: options
"""
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from identify import LinearModel, load_profile, simulate_run  # noqa: E402
from identify.estimators.registry import build  # noqa: E402
from identify.refine import Refine  # noqa: E402
from _cli import add_parts, parser as cli_parser  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DT, LENGTH, TARGET = 0.01, 12.0, 120.0
DELAYS = {"theta_s": 0.06, "theta_c": 0.08, "theta_0": 0.05, "theta_TR": 0.07}  # case 4


def runs(turbulence: bool, vibration: bool = True, delays: dict | None = None) -> list:
    profile = load_profile("bo105_70kt")
    model = LinearModel(profile)
    t = np.arange(int(LENGTH / DT) + 1) * DT
    out = []
    for s in range(5):
        rng = np.random.default_rng(s)
        k = int(0.5 / DT)
        u = np.repeat(rng.choice([-1.0, 0.0, 1.0], size=(len(t) // k + 1, 4)), k, axis=0)[:len(t)] * 0.01
        u[:k] = 0.0
        w = np.zeros(model.n_states)
        if turbulence:  # gusts on the six force and moment equations
            w[:6] = [0.05, 0.05, 0.05, 0.02, 0.02, 0.02]
        r = simulate_run(model, t, u, noise_fraction=0.02, process_noise=w, seed=s, input_delay=delays or 0.0)
        if vibration:
            r = r.with_channels({"q": r["q"] + 0.3 * np.std(r["q"]) * np.cos(2 * np.pi * 7.0 * t + s)})
        out.append(r)
    return out


def main(cases: str = "1234", method: str = "ml") -> dict:
    walls = {}
    for case, turbulence, vibration, delays in (("1", False, True, None), ("2", True, True, None),
                                                ("3", True, False, None), ("4", False, False, DELAYS)):
        if case not in cases:
            continue
        data = runs(turbulence, vibration, delays)
        started = time.perf_counter()
        profile = load_profile("bo105_70kt")
        r = Refine(profile, estimator=build(method, profile), progress=True).fit(data[:4], validate=data[4:])
        wall = time.perf_counter() - started
        print(f"case {case}: BO 105, 8 states, 4 inputs, 4 fit runs + 1 validation run of {LENGTH:g} s at "
              f"{1 / DT:g} Hz{', 7 Hz vibration on q' if vibration else ''}{', turbulence' if turbulence else ''}"
              f"{', delays ' + str(delays) if delays else ''}; "
              f"full catalogue, {method.upper()}")
        print(f"  added {[f'{s.effect}:{s.target}' for s in r.steps_]}; rejected "
              f"{[f'{s.effect}:{s.target}' for s in r.rejected_]}; {r.tries_} tried; stopped: {r.stopped_}")
        for s in r.steps_:
            if s.effect == "delay":
                v = s.parameters[f"tau_{s.target}"]
                print(f"  delay on {s.target}: {v['value']:.4f} +- {v['std']:.4f} s (truth {(delays or {}).get(s.target, 0)})")
        walls[case] = wall
        print(f"  wall time {wall:.1f} s (target {TARGET:g} s: {'met' if wall < TARGET else 'NOT met'}; load average "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)", flush=True)
    return walls


def baseline(ref: str, cases: str, method: str = "ml") -> dict:
    """Wall time per case of the same cases with the code of git revision ``ref``."""
    with tempfile.TemporaryDirectory() as where:
        archive = subprocess.run(["git", "archive", ref], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", where], input=archive, check=True)
        env = dict(os.environ, PYTHONPATH=where)
        extra = ["--method", method] if method != "ml" else []  # older revisions had ML alone
        proc = subprocess.run([sys.executable, "benchmarks/refine_speed.py", cases, *extra], cwd=where, env=env,
                              capture_output=True, text=True)
    print(f"baseline {ref}:\n{proc.stdout}", flush=True)
    return {c: float(w) for c, w in re.findall(r"^case (\d):.*?wall time ([0-9.]+) s", proc.stdout, re.S | re.M)}


def parser():
    ap = cli_parser(__doc__)
    add_parts(ap, "cases", "1234", "the cases to run (1: vibration, 2: with turbulence, 3: turbulence alone, "
              "4: a delay on every input)")
    ap.add_argument("--baseline", default="", help="a git revision whose code runs the same cases after, for the ratio")
    ap.add_argument("--method", default="ml", choices=("ml", "fem"), help="refine's estimator (ml: the default)")
    return ap


if __name__ == "__main__":
    args = parser().parse_args()
    walls = main(args.cases, args.method)
    if args.baseline:
        old = baseline(args.baseline, args.cases, args.method)
        for case, wall in walls.items():
            print(f"case {case}: {wall:.1f} s, baseline {args.baseline} {old.get(case, float('nan')):.1f} s: "
                  f"{old.get(case, float('nan')) / wall:.2f} times faster", flush=True)

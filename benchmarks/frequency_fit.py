"""Monte Carlo of the frequency-response fit (FR) beside ML and FDEE on the S 61 4-DOF hover model.

Truth: the bundled ``s61_hover_4dof`` (the 8-state model's rigid-body reduction). Runs per
realisation: on each cyclic a D-optimal three-level sequence designed by ``signaldesign`` for the
a priori model (7 s within the 20-s record) and a logarithmic sweep 0.1-2 Hz over 20 s, all at
0.2 deg (the unstable model's response stays small over 20 s); instrument-grade white noise on the
outputs (0.05 m/s, 0.05 deg, 0.05 deg/s), new noise every realisation. A priori: the truth with
every free derivative scaled by 1 -/+ 0.2 (fixed draw), the start of every estimator.

Free set: what the frequency responses of these runs support. FR with CIFER's gates
(``prune=True``) on the first realisation decides it; the other derivatives are held at their true
values for every method, so that FR, ML (output error, states as outputs) and FDEE (equation
error in the frequency domain) estimate the same parameters from the same runs.

Figures per method and parameter over the realisations: bias (mean estimate - truth) in units of the
sample std, the sample std against the mean standard error the method reports (std/CR, ideally
0.8-1.25; ML and FDEE: Cramér-Rao bounds; FR: its residual bootstrap of 30 surrogates, after its
correction for the response estimate's own error), and the wall time per fit (this machine, under load: compare methods within the run).

    nice -n 10 python benchmarks/frequency_fit.py --realisations 50   # -> benchmarks/output/frequency_fit/

Each realisation's estimates are appended to ``results.jsonl`` as they come: an interrupted run
resumes where it stopped.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.signal import chirp  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from identify import ML, LinearModel, load_profile, simulate_run  # noqa: E402
from identify.estimators.frequency.equation_error import FDEE  # noqa: E402
from identify.estimators.frequency.response_fit import FR  # noqa: E402
from signaldesign.design import SequenceDesign  # noqa: E402

OUT = ROOT / "benchmarks" / "output" / "frequency_fit"
DT, RECORD, AMP, SEED = 0.02, 20.0, np.deg2rad(0.2), 22
DEG = np.pi / 180
NOISE = {"u": 0.05, "v": 0.05, "p": 0.05 * DEG, "q": 0.05 * DEG, "theta": 0.05 * DEG, "phi": 0.05 * DEG}
SPREAD = 0.2


def signals(model: LinearModel) -> dict[str, np.ndarray]:
    """{label: (N, 2) inputs} for the designed sequence and the sweep on each cyclic."""
    t = np.arange(0, RECORD, DT)
    out = {}
    for j, axis in enumerate(model.profile.input_names):
        d = SequenceDesign(axis, duration=7.0, record=RECORD, amplitude=AMP, dt=0.05, criterion="nominal",
                           n_iter=300, restarts=2, seed=SEED, jobs=1).fit(model)
        s = d.signals_[0]
        s.delay = 1.0
        sweep = AMP * chirp(t, 0.1, RECORD, 2.0, method="logarithmic", phi=-90)
        for label, u in (("designed", s(t)), ("sweep", sweep)):
            U = np.zeros((len(t), 2))
            U[:, j] = u
            out[f"{label} {axis}"] = U
    return out


def runs_of(truth: LinearModel, inputs: dict[str, np.ndarray], seed: int):
    t = np.arange(0, RECORD, DT)
    return [simulate_run(truth, t, U, noise=NOISE, seed=seed * 10 + k, meta={"signal": label})
            for k, (label, U) in enumerate(inputs.items())]


def free_set(apriori, runs) -> list[str]:
    fit = FR(apriori, prune=True).fit(runs).result_
    return list(fit.profile.free)


def restricted(profile, truth: LinearModel, free: list[str]):
    """The a priori profile with only ``free`` free; the others fixed at their true values."""
    true = truth.parameters()
    return replace(profile, free={k: v for k, v in profile.free.items() if k in free},
                   fixed={**profile.fixed, **{k: true[k] for k in profile.free if k not in free}})


def fit_all(profile, runs) -> dict:
    out = {}
    for name, make in (("FR", lambda: FR(profile)), ("ML", lambda: ML(profile)), ("FDEE", lambda: FDEE(profile))):
        t0 = time.perf_counter()
        try:
            r = make().fit(runs).result_
            out[name] = {"theta": r.theta.tolist(), "std": r.std.tolist(), "seconds": time.perf_counter() - t0,
                         "converged": r.converged}
        except Exception as exc:  # recorded, never silent: a failed fit is a result of the benchmark
            out[name] = {"error": f"{type(exc).__name__}: {exc}", "seconds": time.perf_counter() - t0}
    return out


def summarise(names, truth_values, rows) -> tuple[str, dict]:
    lines = ["| method | parameter | truth | mean | bias/std | std | mean CR | std/CR |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    stats = {}
    for method in ("FR", "ML", "FDEE"):
        ok = [r[method] for r in rows if "theta" in r[method]]
        failed = len(rows) - len(ok)
        if not ok:
            lines.append(f"| {method} | all {len(rows)} fits failed | | | | | | |")
            continue
        th = np.array([o["theta"] for o in ok])
        cr = np.array([o["std"] for o in ok])
        mean, std = th.mean(axis=0), th.std(axis=0, ddof=1)
        crm = np.sqrt(np.mean(cr ** 2, axis=0))
        secs = np.array([o["seconds"] for o in ok])
        stats[method] = {"n": len(ok), "failed": failed, "seconds_median": float(np.median(secs)),
                         "bias_over_std": ((mean - truth_values) / std).tolist(), "std_over_cr": (std / crm).tolist()}
        for k, n in enumerate(names):
            lines.append(f"| {method} | `{n}` | {truth_values[k]:.4g} | {mean[k]:.4g} | "
                         f"{(mean[k] - truth_values[k]) / std[k]:+.2f} | {std[k]:.3g} | {crm[k]:.3g} | "
                         f"{std[k] / crm[k]:.2f} |")
    lines += ["", "| method | fits | failed | median wall time per fit [s] |", "| --- | ---: | ---: | ---: |"]
    lines += [f"| {m} | {s['n']} | {s['failed']} | {s['seconds_median']:.3g} |" for m, s in stats.items()]
    return "\n".join(lines), stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=50)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    base = load_profile("s61_hover_4dof")
    truth = LinearModel(base)
    rng = np.random.default_rng(SEED)
    apriori = base.with_values({k: v * rng.uniform(1 - SPREAD, 1 + SPREAD) for k, v in base.free.items()})
    t0 = time.perf_counter()
    inputs = signals(LinearModel(apriori))
    print(f"signals designed in {time.perf_counter() - t0:.1f} s: {', '.join(inputs)}", flush=True)
    first = runs_of(truth, inputs, 0)
    free = free_set(apriori, first)
    profile = restricted(apriori, truth, free)
    print(f"free set from FR's gates on realisation 0: {', '.join(free)}", flush=True)
    store = args.out / "results.jsonl"
    rows = []
    if store.exists():
        rows = [json.loads(line) for line in store.read_text().splitlines() if line.strip()]
        rows = [r for r in rows if r.get("free") == free]
        print(f"resuming: {len(rows)} realisation(s) already done", flush=True)
    with open(store, "a") as f:
        for k in range(len(rows), args.realisations):
            row = {"realisation": k, "free": free, **fit_all(profile, runs_of(truth, inputs, k))}
            rows.append(row)
            f.write(json.dumps(row) + "\n")
            f.flush()
            print(f"realisation {k + 1}/{args.realisations}: " + ", ".join(
                f"{m} {row[m]['seconds']:.2f} s" + (" FAILED" if "error" in row[m] else "")
                for m in ("FR", "ML", "FDEE")),
                flush=True)
    names = list(profile.free)
    true = np.array([truth.parameters()[n] for n in names])
    table, stats = summarise(names, true, rows[:args.realisations])
    text = (f"# Frequency-response fit Monte Carlo (S 61 4-DOF), {len(rows[:args.realisations])} realisations\n\n"
            f"Runs per realisation: {', '.join(inputs)} (20 s each, 0.2 deg). Free set (FR's gates on "
            f"realisation 0): {', '.join(free)}.\n\n{table}\n")
    (args.out / "summary.md").write_text(text)
    (args.out / "summary.json").write_text(json.dumps({"free": free, "stats": stats}, indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

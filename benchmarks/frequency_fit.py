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
correction for the response estimate's own error, scaled for that correction's dependence on the estimate), and the wall time per fit (this machine, under load: compare methods within the run).

    nice -n 10 python benchmarks/frequency_fit.py --realisations 50   # -> benchmarks/output/frequency_fit/

Each realisation's estimates are appended to ``results.jsonl`` as they come: an interrupted run
resumes where it stopped.
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.signal import chirp  # noqa: E402
from scipy.stats import chi2  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from identify import ML, LinearModel, load_profile, simulate_run  # noqa: E402
from identify.estimators.frequency.equation_error import FDEE  # noqa: E402
from identify.estimators.frequency.response_fit import FR  # noqa: E402
from signaldesign.design import SequenceDesign  # noqa: E402
from _cli import count, parser as cli_parser  # noqa: E402

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
                         "converged": r.converged, "ratio_gain": r.info.get("ratio_gain")}
        except Exception as exc:  # recorded, never silent: a failed fit is a result of the benchmark
            out[name] = {"error": f"{type(exc).__name__}: {exc}", "seconds": time.perf_counter() - t0}
    return out


def summarise(names, truth_values, rows) -> tuple[str, dict]:
    """Per method and parameter: bias/std, std, the RMS reported standard error (CR), std/CR with the
    90 % interval the Monte Carlo's own sampling allows (chi-square on n - 1 degrees of freedom: 50
    realisations know a std to about +-17 % at 90 %), and the robust std/CR (1.4826 MAD: what std/CR
    would be without the tails, which a few wide realisations inflate)."""
    lines = ["| method | parameter | truth | mean | bias/std | std | mean CR | std/CR | 90 % interval | robust std/CR |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
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
        dof = len(ok) - 1
        lo, hi = np.sqrt(dof / chi2.ppf(0.95, dof)), np.sqrt(dof / chi2.ppf(0.05, dof))
        robust = 1.4826 * np.median(np.abs(th - np.median(th, axis=0)), axis=0)
        stats[method] = {"n": len(ok), "failed": failed, "seconds_median": float(np.median(secs)),
                         "bias_over_std": ((mean - truth_values) / std).tolist(), "std_over_cr": (std / crm).tolist(),
                         "std_over_cr_90": [(std * lo / crm).tolist(), (std * hi / crm).tolist()],
                         "robust_std_over_cr": (robust / crm).tolist()}
        for k, n in enumerate(names):
            lines.append(f"| {method} | `{n}` | {truth_values[k]:.4g} | {mean[k]:.4g} | "
                         f"{(mean[k] - truth_values[k]) / std[k]:+.2f} | {std[k]:.3g} | {crm[k]:.3g} | "
                         f"{std[k] / crm[k]:.2f} | {std[k] * lo / crm[k]:.2f}-{std[k] * hi / crm[k]:.2f} | "
                         f"{robust[k] / crm[k]:.2f} |")
    lines += ["", "| method | fits | failed | median wall time per fit [s] |", "| --- | ---: | ---: | ---: |"]
    lines += [f"| {m} | {s['n']} | {s['failed']} | {s['seconds_median']:.3g} |" for m, s in stats.items()]
    return "\n".join(lines), stats


def bootstrap_factors(profile, runs, n_draws: int = 10, seed: int = 0) -> np.ndarray:
    """Paired check of two simplifications of FR's bootstrap on one realisation: per surrogate, the
    refit as shipped (the estimate's bias-correction ratio held fixed, 20 evaluations) against the
    whole procedure (refit to convergence, then the ratio re-estimated from that refit's own
    simulated runs and refitted, twice, as the estimate itself does). Returns (3, p): the shipped
    spread, the whole procedure's, and the paired regression slope of the second on the first (the
    factor by which the shipped bootstrap under- or overstates the standard error)."""
    from identify.estimators.frequency.bootstrap import surrogate_noise
    from identify.estimators.frequency.estimate_error import estimate_error
    from identify.estimators.frequency.response import frequency_response
    from identify.estimators.frequency.statespace import ResponseData, fit_frequency_responses

    est = FR(profile, n_draws=0)
    est.fit(runs)
    p = est.profile_
    fr = frequency_response(runs, p.input_names, list(p.outputs))
    data = ResponseData.from_response(fr)
    fit, ratio, _ = est._debiased(fit_frequency_responses(p, data), fr, data, runs, ())
    _, predictions = est._predicted(fit, runs)
    rng = np.random.default_rng(seed)
    shipped, whole = [], []
    for _ in range(n_draws):
        draws = [r.with_channels({y: pr.modelled[:, j] + e[:, j] for j, y in enumerate(p.outputs)})
                 for r, pr in zip(runs, predictions)
                 for e in [surrogate_noise(pr.measured - pr.modelled, rng, r.matrix(p.input_names))]]
        frb = frequency_response(draws, p.input_names, list(p.outputs), omega=fr.omega, windows=fr.windows)
        d = ResponseData.from_response(frb)
        shipped.append(fit_frequency_responses(fit.profile, replace(d, H=d.H / ratio), theta0=fit.theta,
                                               max_nfev=20).theta - fit.theta)
        f = fit_frequency_responses(fit.profile, replace(d, H=d.H / ratio), theta0=fit.theta)
        for _ in range(est.bias_passes):
            _, pk = est._predicted(f, draws)
            rk, _ = estimate_error(frb, draws, pk, f, d.usable(est.min_coherence))
            f = fit_frequency_responses(fit.profile, replace(d, H=d.H / rk), theta0=f.theta)
        whole.append(f.theta - fit.theta)
    a, b = np.array(shipped), np.array(whole)
    slope = [float(np.polyfit(a[:, k], b[:, k], 1)[0]) for k in range(a.shape[1])]
    return np.array([a.std(axis=0, ddof=1), b.std(axis=0, ddof=1), slope])


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--realisations", type=count, default=50, help="noise realisations (Monte Carlo)")
    ap.add_argument("--out", type=Path, default=OUT, help="output folder (results.jsonl: a rerun resumes)")
    ap.add_argument("--factor-realisations", type=count, default=3,
                    help="realisations on which the bootstrap's simplifications are measured (0: skip)")
    return ap


def main(argv=None) -> int:
    args = parser().parse_args(argv)
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
    factors = ""
    if args.factor_realisations:
        t1 = time.perf_counter()
        fs = np.array([bootstrap_factors(profile, runs_of(truth, inputs, k)) for k in range(args.factor_realisations)])
        slope = fs[:, 2].mean(axis=0)
        gains = [r["FR"]["ratio_gain"] for r in rows[:args.realisations] if r["FR"].get("ratio_gain")]
        gain = np.mean(gains, axis=0) if gains else np.full(len(names), np.nan)
        factors = ("\nFR bootstrap with the correction ratio held fixed, against the whole procedure per surrogate "
                   f"(ratio re-estimated from each refit, refits converged), {args.factor_realisations} realisations x "
                   "10 surrogates, paired slope per parameter (how much the fixed-ratio bootstrap understates): "
                   + ", ".join(f"`{n}` {v:.3f}" for n, v in zip(names, slope))
                   + f" ({time.perf_counter() - t1:.0f} s). FR's own linearised correction of it (info.ratio_gain), "
                   f"mean over {len(gains)} fits: " + ", ".join(f"`{n}` {v:.3f}" for n, v in zip(names, gain)) + "\n")
        stats.setdefault("FR", {})["bootstrap_factor"] = slope.tolist()
        stats["FR"]["ratio_gain_mean"] = gain.tolist()
    text = (f"# Frequency-response fit Monte Carlo (S 61 4-DOF), {len(rows[:args.realisations])} realisations\n\n"
            f"Runs per realisation: {', '.join(inputs)} (20 s each, 0.2 deg). Free set (FR's gates on "
            f"realisation 0): {', '.join(free)}. Machine load (1-min average) at the end: "
            f"{os.getloadavg()[0]:.1f}.\n\n{table}\n{factors}")
    (args.out / "summary.md").write_text(text)
    (args.out / "summary.json").write_text(json.dumps({"free": free, "stats": stats}, indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

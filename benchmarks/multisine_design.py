"""Benchmark: the designed three-level sequence against today's yardstick, the optimised multisine
(phases for a small relative peak factor, Morelli), and the best 3211, by ML Monte Carlo; and all
axes in one run against one run per axis. Every figure is measured in this run, baselines included.

1. Per case (S 61 8-state hover theta_s, BO 105 70 kt theta_s, Navion delta_e; 7 s of input in a
   20 s record): the default design (``SequenceDesign``, as ``signaldesign design`` runs it), the
   optimised multisine and the best-width 3211 (both tuned on the a priori as in every comparison
   table; and an optimised multisine filling the whole 20 s record), each flown at equal peak response (largest output peak / limit = 1) on a truth the
   design did not see (the a priori with its frequencies x ``--truth``). ML (output error, initial
   state estimated, known noise) on ``--mc`` noise realisations per signal, the same noise for
   every signal. Median over parameters of the robust std / |theta|:
   * at equal peak response: one run each;
   * at equal flight time: each run lasts its input plus the settling the record leaves after a
     7 s input (13 s), and std falls as 1 / sqrt(flight time), so each std is rescaled to 20 s of
     flight (the 3211's runs are shorter: it can be flown more often).
   One summary line per case says which wins.
2. All axes in one run (``--multi s61,bo105,hover4``: the S 61's two cyclics, the BO 105's two
   cyclics, the 4-input hover model's four inputs): one 20 s run against one 20 s run per axis, every
   input at equal per-input peak response (each as large as its own response, alone, allows, as in
   a run of its own; the responses add): the multi-axis design made for that rule (``--peak
   per-input``), each axis' own design (its runs fitted together) and simultaneous orthogonal
   optimised multisines; ``--shared`` adds the design made with the limits shared by the run's whole
   response. The flight time the one run needs to reach the separate runs' median std, as a fraction
   of their total (std falls as 1 / sqrt(flight time)), measured and predicted (Cramer-Rao).

    python benchmarks/multisine_design.py                 # default designs, 50 realisations
    python benchmarks/multisine_design.py --quick-design  # smaller searches (say so when quoting)
    python benchmarks/multisine_design.py --cases "" --multi s61 --mc 200   # part 2 only
    python benchmarks/multisine_design.py --cases "" --multi hover4 --multi-quick --mc 1 --designs d/  # design...
    python benchmarks/multisine_design.py --cases "" --multi hover4 --multi-quick --mc 50 --designs d/ # ...then MC
"""
from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import dataclasses  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from identify import ML, LinearModel, load_profile, simulate_run  # noqa: E402
from signaldesign.band import excited_parameters, required_band  # noqa: E402
from signaldesign.baselines import multisine  # noqa: E402
from signaldesign.compare import reference_of, tuned_baselines  # noqa: E402
from signaldesign.design import SequenceDesign  # noqa: E402
from signaldesign.evaluate import Evaluator, record_inputs  # noqa: E402
from signaldesign.robust import frequency_scaled  # noqa: E402
from signaldesign.signal import load_signals, save_signals  # noqa: E402
from signal_design import DT, DURATION, RECORD, _information_x0_estimated, _robust_std  # noqa: E402
from _cli import count, parser as cli_parser, positive  # noqa: E402

CASES = [("s61_hover_8state", "theta_s"), ("bo105_70kt", "theta_s"), ("navion_cruise_long", "delta_e")]
SETTLE = RECORD - DURATION  # s of record after a 7 s input: the run's settling time


def _design(model, inputs, quick: bool, peak: str = "shared", certify: str = "full") -> SequenceDesign:
    """The default design with the certificate as ``signaldesign design`` prints it (``quick``: a
    smaller search and the quick certificate)."""
    kw = dict(restarts=4, n_iter=400, kicks=6, nominal_kicks=6, certify="quick") if quick else dict(certify=certify)
    d = SequenceDesign(inputs, peak=peak, **kw).fit(model)
    print(f"design on {', '.join(d.inputs)} ({'smaller search' if quick else 'default'}): "
          f"{d.seconds_:.0f} s wall; restarts' criteria {min(d.result_.trace):.2f}..{max(d.result_.trace):.2f}, "
          f"best {d.result_.objective:.2f}")
    print(d.certificate())
    return d


DESIGNS: Path | None = None  # --designs: a folder the designs are kept in and read back from


def _designed(model, inputs, quick: bool, peak: str = "shared", certify: str = "full") -> list:
    """The design's signals: read from ``DESIGNS`` when this profile, inputs, peak rule and search
    were designed before (so the Monte Carlo can run apart from a long design), else designed (and kept)."""
    names = [inputs] if isinstance(inputs, str) else list(inputs)
    path = None if DESIGNS is None else DESIGNS / (
        f"{Path(model.profile.source).stem}_{'-'.join(names)}_{peak}_{'quick' if quick else 'default'}.json")
    if path is not None and path.exists():
        print(f"design on {', '.join(names)}: read from {path} (designed by an earlier run of this benchmark)")
        return load_signals(path)
    sigs = _design(model, inputs, quick, peak=peak, certify=certify).signals_
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_signals(sigs, path)
    return sigs


def _excited(model: LinearModel, inputs) -> LinearModel:
    """The model with the parameters no input excites moved to fixed."""
    keep = set().union(*(excited_parameters(model, i) for i in inputs))
    p = model.profile
    drop = [n for i, n in enumerate(model.names) if i not in keep]
    return LinearModel(dataclasses.replace(p, free={k: v for k, v in p.free.items() if k not in drop},
                                           fixed={**p.fixed, **{k: p.free[k] for k in drop}}))


def _at_equal_peak(ev: Evaluator, sigs, per_input: bool = False):
    """The signals scaled so that the run's largest output peak / limit is 1 (``per_input``: each
    input's own response, alone, at that peak, as in a run of its own)."""
    if per_input:
        return [_at_equal_peak(Evaluator(ev.model, [s.input], ev.record, ev.dt, limits=ev.model.profile.limits), [s])[0]
                for s in sigs]
    r, _ = ev.response(sigs)
    return [dataclasses.replace(s, amplitude=s.amplitude / r) for s in sigs]


def _fits(truth: LinearModel, runs_inputs, ev: Evaluator, trials: int, seed: int):
    """ML estimates (trials, p) from ``trials`` noise realisations of the runs (one input history
    per run, fitted together); failures are counted and reported."""
    noise = dict(zip(truth.profile.outputs, ev.noise_std))
    t = np.arange(int(round(RECORD / DT)) + 1) * DT
    rows, failed = [], 0
    for trial in range(trials):
        runs = [simulate_run(truth, t, u, noise=noise, seed=seed + 1000 * trial + 7 * k)
                for k, u in enumerate(runs_inputs)]
        try:
            fit = ML(truth.profile, segment="plain", estimate_x0=True, estimate_bias=False,
                     noise_cov=ev.noise_std ** 2, coloured=False).fit(runs)
            rows.append(fit.theta_)
        except Exception as exc:  # a failed fit counts against its signal, and is reported
            failed += 1
            print(f"  trial {trial}: ML failed ({exc})")
    return np.array(rows), failed


def _median_std(E, truth) -> float:
    return float(np.median(_robust_std(E) / np.abs(truth.theta)))


def _crb_median(truth, runs_inputs, noise_std) -> float:
    M = sum(_information_x0_estimated(truth, u, noise_std) for u in runs_inputs)
    return float(np.median(np.sqrt(np.diag(np.linalg.inv(M))) / np.abs(truth.theta)))


def one_axis(name: str, inp: str, trials: int, truth_scale: float, quick: bool):
    model = LinearModel(load_profile(name))
    print(f"\n=== {model.profile.name}: {inp}, {DURATION:g} s input in a {RECORD:g} s record; truth: the a priori "
          f"with frequencies x{truth_scale:g}; {trials} realisations per signal ===")
    band = required_band(model, inp)
    ev = Evaluator(model, [inp], RECORD, DT)
    base = dict(tuned_baselines(ev, DURATION, 1.0, band.high))
    label_ms = next(k for k in base if "optimised phases" in k)
    # the multisine over the whole record too: a 7 s one starts at 0.9 rad/s, above many required bands
    whole = multisine(RECORD, (0.0, max(2 * band.high, 3.05 * 2 * np.pi / RECORD)), 1.0, inp, DT)
    signals = {"design": _designed(model, inp, quick), "optimised multisine": base[label_ms],
               "optimised multisine 20 s": [whole], "best 3211": reference_of(base.items())}
    print(f"  ({label_ms}; over the whole {RECORD:g} s record: {len(whole.params['harmonics'])} harmonics, RPF "
          f"{whole.params['relative_peak_factor']:.2f}; {next(k for k in base if k.startswith('3211'))})")
    apriori = _excited(model, [inp])
    truth = apriori if truth_scale == 1 else frequency_scaled(apriori, truth_scale)
    tev = Evaluator(truth, [inp], RECORD, DT, limits=model.profile.limits)
    rows = {}
    for label, sigs in signals.items():
        flown = _at_equal_peak(tev, sigs)
        u = record_inputs(truth, flown, RECORD, DT)
        E, failed = _fits(truth, [u], tev, trials, seed=11)
        flight = min(RECORD, max(s.end_time for s in flown) + SETTLE)
        med = _median_std(E, truth)
        rows[label] = (med, med * np.sqrt(flight / RECORD), flight, _crb_median(truth, [u], tev.noise_std), failed)
        print(f"  {label:<24} median std/|theta| {100 * med:6.2f}% (CRB {100 * rows[label][3]:.2f}%; "
              f"{failed} failed fits); flight {flight:4.1f} s -> {100 * rows[label][1]:6.2f}% at {RECORD:g} s of flight")
    for k, what in ((0, "equal peak response"), (1, "equal flight time")):
        order = sorted(rows, key=lambda lab: rows[lab][k])
        win, second = order[0], order[1]
        verdict = "wins" if win == "design" else "LOSES: the winner is " + win
        print(f"SUMMARY {name} at {what}: " + ", ".join(f"{lab} {100 * rows[lab][k]:.2f}%" for lab in rows)
              + f" median std -> the design {verdict}" + (f" (x{rows[second][k] / rows[win][k]:.2f} lower std than the "
                                                 f"{second})" if win == "design" else ""))
    return rows


MULTI = {"s61": ("s61_hover_8state", ["theta_s", "theta_c"]), "bo105": ("bo105_70kt", ["theta_s", "theta_c"]),
         "hover4": ("hover_4input", ["theta_s", "theta_c", "theta_0", "theta_TR"])}


def multi_axis(key: str, trials: int, truth_scale: float, quick: bool, shared: bool = False):
    """One simultaneous run against one run per axis at equal per-input peak response (each input
    as large as its own response allows, as in a run of its own): the multi-axis design made for that
    rule (``signaldesign design --peak per-input``), each axis' own design, and simultaneous
    orthogonal optimised multisines; with ``shared`` also the design made with the limits shared by
    the run's whole response. ML on ``trials`` realisations, all runs of a case fitted together."""
    name, inputs = MULTI[key]
    model = LinearModel(load_profile(name))
    print(f"\n=== {model.profile.name}: {', '.join(inputs)} in one {RECORD:g} s run vs one run per axis; truth "
          f"frequencies x{truth_scale:g}; {trials} realisations ===")
    joint = _designed(model, inputs, quick, peak="per-input", certify="quick")
    singles = [_designed(model, i, quick, certify="quick") for i in inputs]
    ev = Evaluator(model, inputs, RECORD, DT)
    base = dict(tuned_baselines(ev, DURATION, 1.0, max(required_band(model, i).high for i in inputs)))
    label_ms = next(k for k in base if "optimised phases" in k)
    apriori = _excited(model, inputs)
    truth = apriori if truth_scale == 1 else frequency_scaled(apriori, truth_scale)
    cases = {"one run, designed for equal per-input peak": [joint],
             "one run per axis, each axis' design": singles,
             f"one run, {label_ms}": [base[label_ms]]}
    if shared:
        cases["one run, designed with the limits shared"] = [_designed(model, inputs, quick, certify="quick")]
    out = {}
    for label, runs in cases.items():
        us = []
        for sigs in runs:  # every input at its own equal peak response on the truth
            tev = Evaluator(truth, [s.input for s in sigs], RECORD, DT, limits=model.profile.limits)
            us.append(record_inputs(truth, _at_equal_peak(tev, sigs, per_input=True), RECORD, DT))
        tev = Evaluator(truth, inputs, RECORD, DT, limits=model.profile.limits)
        E, failed = _fits(truth, us, tev, trials, seed=23)
        crb = _crb_median(truth, us, tev.noise_std)
        out[label] = (_median_std(E, truth), RECORD * len(runs), crb)
        print(f"  {label:<62} {len(runs)} run(s), {RECORD * len(runs):4.0f} s: median std/|theta| "
              f"{100 * out[label][0]:6.2f}% (CRB {100 * crb:.2f}%; measured/CRB {out[label][0] / crb:.2f}; "
              f"{failed} failed fits)")
    ss, ts, cs = out["one run per axis, each axis' design"]
    for label in [k for k in out if k.startswith("one run,")]:
        sj, tj, cj = out[label]
        need = tj * (sj / ss) ** 2  # std falls as 1/sqrt(flight time): runs of the joint design to match
        tag = "DONE-WHEN" if "designed for" in label else "         "
        print(f"{tag} multi-axis ({model.profile.name.split(',')[0]}, {label[9:]}): one simultaneous run reaches one-run-per-axis' median std in {need:.1f} s = "
              f"{100 * need / ts:.0f}% of their {ts:.0f} s (<= 60%: {'PASS' if need <= 0.6 * ts else 'FAIL'}); "
              f"predicted (CRB) {100 * tj * (cj / cs) ** 2 / ts:.0f}%")
    return out


def parser():
    ap = cli_parser(__doc__)
    ap.add_argument("--mc", type=count, default=50, help="Monte-Carlo realisations per signal (default 50)")
    ap.add_argument("--truth", type=positive, default=0.8, help="truth = a priori frequencies x this (default 0.8)")
    ap.add_argument("--quick-design", action="store_true", help="smaller design searches (4 restarts of 400)")
    ap.add_argument("--cases", default=",".join(n for n, _ in CASES), help="profiles of part 1 (comma-separated)")
    ap.add_argument("--multi", default="s61,bo105,hover4",
                    help=f"part 2's cases, comma-separated ({', '.join(MULTI)}; empty: none)")
    ap.add_argument("--multi-mc", type=count, help="part 2's realisations (default --mc)")
    ap.add_argument("--multi-quick", action="store_true", help="part 2 with the smaller design searches")
    ap.add_argument("--shared", action="store_true", help="part 2 also with the design made with the limits shared")
    ap.add_argument("--designs", metavar="DIR", help="keep every design's signals in DIR and read them back when "
                                                     "present (a long design and its Monte Carlo in separate runs)")
    return ap


def main(argv=None):
    global DESIGNS
    args = parser().parse_args(argv)
    DESIGNS = Path(args.designs) if args.designs else None
    t0 = time.perf_counter()
    for name, inp in CASES:
        if name in args.cases.split(","):
            one_axis(name, inp, args.mc, args.truth, args.quick_design)
    for key in filter(None, args.multi.split(",")):
        multi_axis(key, args.multi_mc or args.mc, args.truth, args.multi_quick, args.shared)
    print(f"\nbenchmark took {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()

"""``python -m identify``: inspect models and identify them from runs."""
from __future__ import annotations

import sys

from .cliutil import (Parser, add_threads_option, finite_float, fraction, nonnegative_float, nonnegative_int,
                      output_dir, output_file, positive_float, positive_int, run)
from .errors import EstimationError
from .model.linear import LinearModel, format_modes, residualize
from .model.profile import load_profile


def cmd_model(args) -> int:
    """Print a profile's parameters and modes; optionally its residualised reduction."""
    profile = load_profile(args.profile)
    model = LinearModel(profile)
    _print_model(model)
    if args.reduce:
        reduced = residualize(model, [s.strip() for s in args.reduce.split(",") if s.strip()])
        print()
        _print_model(LinearModel(reduced))
        if args.save_reduced:
            print(f"\nreduced profile written to {reduced.save(args.save_reduced)}")
    return 0


def _print_model(model: LinearModel) -> None:
    p = model.profile
    print(f"{p.name}\n  states:  {', '.join(f'{s} [{u}]' for s, u in p.states.items())}"
          f"\n  inputs:  {', '.join(f'{s} [{u}]' for s, u in p.inputs.items())}"
          f"\n  outputs: {', '.join(p.outputs)}"
          f"\n  {len(p.free)} free, {len(p.fixed)} fixed parameters")
    for kind, values in (("free", p.free), ("fixed", p.fixed)):
        if values:
            print(f"\n{kind} parameters:")
            print("\n".join(f"  {name:<16}{value:13.6g}" for name, value in values.items()))
    effects = _declared_effects(p)
    print("\ndeclared effects (every command applies them to the runs):" + ("" if effects else " none"))
    if effects:
        print("\n".join(f"  {line}" for line in effects))
    notes = [f"{key}: {value}" for key, value in p.meta.items() if key not in ("delays", "pseudo_inputs")]
    if notes:
        print("notes ([meta]):\n" + "\n".join(f"  {line}" for line in notes))
    if p.limits:
        print("\nresponse limits (signal design): " + ", ".join(f"{y} {v:g}" for y, v in p.limits.items()))
    print("\nmodes:")
    print(format_modes(model.modes()))


def _declared_effects(p) -> list[str]:
    """One line per input delay and pseudo-input the profile declares."""
    from .model.pseudo_inputs import specs
    lines = [f"delay on {name}: {float(tau):g} s (the aircraft sees {name}(t - {float(tau):g}))"
             for name, tau in dict(p.meta.get("delays", {})).items()]
    for name, spec in specs(p).items():
        lines.append(f"pseudo-input {name}: " + ", ".join(f"{k} = {v}" for k, v in spec.items()))
    return lines


def build_parser() -> Parser:
    parser = Parser(prog="identify", description="Identify linear aircraft models from flight-test runs.")
    sub = parser.add_subparsers(title="commands")
    p = sub.add_parser("model", help="print a profile's modes (frequency, damping)")
    p.add_argument("profile", help="profile TOML path or bundled profile name")
    p.add_argument("--reduce", metavar="STATES", help="comma-separated states to make instantaneous")
    p.add_argument("--save-reduced", metavar="TOML", type=output_file, help="write the reduced profile here")
    p.set_defaults(func=cmd_model)
    _add_estimate_parser(sub)
    _add_refine_parser(sub)
    _add_freq_parser(sub)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def cmd_estimate(args) -> int:
    """Identify a profile's free parameters from runs; write result.json, the profile and plots."""
    from .data.preprocess import slice_run, smooth
    from .estimators.plots import save_plots

    profile = _profile(args)
    runs = []
    for r in _read_runs(args.runs, args.channel_map, profile):
        if args.smooth is not None:  # every channel alike, inputs included: keeps the equations consistent
            r = smooth(r, args.smooth)
        if args.t_start is not None or args.t_end is not None:
            if "segment" in r.meta and not _overlaps(r, args.t_start, args.t_end):
                print(f"note: {r.source} lies outside --t-start/--t-end: not used", file=sys.stderr)
                continue
            r = slice_run(r, args.t_start, args.t_end)
        runs.append(r)
    if not runs:
        raise EstimationError("no run has samples between --t-start and --t-end")

    estimator = _estimator(args, profile)
    result = _fit(estimator, runs)
    print(result.summary(), flush=True)  # on screen before anything is written
    from .estimators.frequency.response import cost_report
    text, result.info["frequency_cost_J"] = cost_report(runs, {"identified": result.model,
                                                              "a priori": LinearModel(profile)})
    print("\n" + text, flush=True)
    out = result.save(args.out)
    with open(out / "summary.txt", "a") as f:  # the frequency-domain cost printed above, too
        f.write("\n" + text + "\n")
    plots = save_plots(result, out)
    print(f"\nwritten to {out}: result.json, summary.txt, identified_profile.toml, time_histories.npz, "
          f"{', '.join(p.name for p in plots)}")
    return 0


def _estimator(args, profile, show_progress: bool = True):
    """The estimator instance of ``--method`` with the options given for it (an option the method
    does not take is one clear error); progress of the iterative ones on stderr."""
    from .estimators.registry import build

    def show(it, value, theta):
        print(f"{args.method.upper()} iteration {it}: {estimator.progress_quantity} {value:.4g}",
              file=sys.stderr, flush=True)

    estimator = build(args.method, profile, progress=show if show_progress else None,
                      names={"max_iter": "--max-iter", "diff_cutoff_hz": "--diff-cutoff"},
                      max_iter=getattr(args, "max_iter", None), diff_cutoff_hz=getattr(args, "diff_cutoff", None))
    return estimator


def _fit(estimator, runs):
    """The estimator's result; a profile's state-built nonlinear terms (a refined profile's) from
    the model's simulated states where the estimator simulates (as refine fitted them), so that
    its estimates are reproduced."""
    from .estimators.prediction import fit_state_terms, state_terms

    profile = estimator.profile
    terms = state_terms(profile)
    if not (terms and estimator.simulates_state_terms):
        return estimator.fit(runs).result_
    # the estimator's own segments, fixed so that the terms are predicted over the same ones
    segment = estimator.prediction_segment(LinearModel(profile), max(r.duration for r in runs))
    print(f"note: {', '.join(terms)} built from the model's simulated states (re-fitted until "
          f"the estimates settle)", file=sys.stderr)
    return fit_state_terms(lambda p: estimator.nested(p, segment=segment), profile, runs, segment=segment)[1]


def _add_estimate_parser(sub) -> None:
    p = sub.add_parser("estimate", help="identify a profile's parameters from runs (LS, IV or ML)")
    _add_common_options(p, "run files", default_method="iv")
    p.add_argument("--smooth", type=positive_float, metavar="HZ", help="zero-phase low-pass cut-off for every channel")
    p.add_argument("--diff-cutoff", type=positive_float, metavar="HZ",
                   help="cut-off of the smoothed differentiator for states without measured derivatives")
    p.add_argument("--t-start", type=finite_float, metavar="S", help="use samples from this time on")
    p.add_argument("--t-end", type=finite_float, metavar="S", help="use samples up to this time")
    p.add_argument("--max-iter", type=positive_int, metavar="N",
                   help="iterations at most for iv (default 30) and ml (default 100)")
    p.set_defaults(func=cmd_estimate)


def _read_runs(paths, channel_map, profile):
    """Every run of the files (CSV or .mat; a file split by time gaps gives several), in SI units,
    as the profile needs them: a refined profile's delays applied and pseudo-inputs rebuilt."""
    from .data.io import load_channel_map, read_run_files
    from .model.pseudo_inputs import prepare

    return prepare(profile, read_run_files(paths, load_channel_map(channel_map) if channel_map else None, profile))


def _overlaps(run, t_start, t_end) -> bool:
    """Whether a run has two or more samples in the window (a gap's segment may have none)."""
    lo = -float("inf") if t_start is None else t_start
    hi = float("inf") if t_end is None else t_end
    return int(((run.time >= lo) & (run.time <= hi)).sum()) >= 2


def _add_common_options(p, runs_help: str, default_method: str) -> None:
    """Options of every command that reads runs (through :mod:`identify.data.io`) and estimates."""
    from .estimators.registry import METHOD_NAMES

    p.add_argument("runs", nargs="+", help=f"{runs_help} (.csv or .mat)")
    p.add_argument("--profile", required=True, help="a priori profile TOML path or bundled profile name")
    p.add_argument("--method", choices=METHOD_NAMES, default=default_method,
                   help=f"estimator (default {default_method})")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--channel-map", metavar="JSON",
                   help='{"channels": {channel: column, variable, matrix column or expression such as '
                        '"(dar - dal)/2"}, "units": {name: unit}, "time": ..., "matrix": ..., "dt": ...} '
                        'as a file or inline JSON (required for .mat data matrices)')
    p.add_argument("--fix", metavar="LIST", help="free parameters to hold at their a priori values (comma-separated)")
    p.add_argument("--free", metavar="LIST", help="fixed parameters to estimate (comma-separated)")
    p.add_argument("--outputs", metavar="LIST", help="fit these outputs only (comma-separated; default all)")


def _profile(args):
    """The a priori profile, with ``--free``, ``--fix`` and ``--outputs`` applied (each said)."""
    from .model import subset

    profile = load_profile(args.profile)
    for option, change in (("free", subset.free), ("fix", subset.fix), ("outputs", subset.with_outputs)):
        if getattr(args, option):
            profile = change(profile, getattr(args, option))
            print(f"--{option} {getattr(args, option)}: {len(profile.free)} free parameters, "
                  f"outputs {', '.join(profile.outputs)}", file=sys.stderr)
    return profile


def cmd_refine(args) -> int:
    """Fit, find what the residuals say the model lacks, add it, re-identify; write the evidence."""
    from .refine.candidates import KINDS
    from .refine.loop import Refine
    from .refine.report import write

    kinds = KINDS if args.kinds is None else tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    if not kinds:
        raise EstimationError(f"--kinds names no effect kind (catalogue: {', '.join(KINDS)})")
    profile = _profile(args)
    refiner = Refine(profile, estimator=_estimator(args, profile, show_progress=False), alpha=args.alpha,
                     kinds=kinds, max_steps=args.max_steps, zero_shifts=not args.no_zero_shifts,
                     frequencies=args.frequency, f_min=args.f_min, tau_max=args.tau_max, progress=True)
    refiner.fit(_read_runs(args.runs, args.channel_map, profile),
                validate=_read_runs(args.validate or [], args.channel_map, profile))
    if refiner.nothing_found:
        print("nothing found: no candidate effect is significant")
    for i, s in enumerate(refiner.steps_, start=1):
        params = ", ".join(f"{k} = {v['value']:.5g} ± {v['std']:.2g}" for k, v in s.parameters.items())
        print(f"step {i}: {s.effect} on {s.target}: {params} (score {s.statistic:.4g} > {s.threshold:.4g})")
    for s in refiner.rejected_:
        print(f"rejected: {s.effect} on {s.target}: {s.reason}")
    if refiner.unconverged_:
        print(f"warning: {len(refiner.unconverged_)} fit(s) inside refine did not converge "
              f"(listed in report.md): {refiner.unconverged_[0]}")
    for where in refiner.error_before_:
        print(f"{where} error (overall): {refiner.error_before_[where]['overall']:.4g} -> "
              f"{refiner.error_after_[where]['overall']:.4g}", flush=True)
    out = write(refiner, args.out)  # after the screen output: a failing write loses nothing shown
    print(f"written to {out}: refine.json, report.md, final_profile.toml")
    return 0


def _add_refine_parser(sub) -> None:
    p = sub.add_parser("refine", help="find unmodelled effects in the residuals, add them, re-identify")
    _add_common_options(p, "run files to fit", default_method="ml")
    p.add_argument("--validate", nargs="+", metavar="RUN", help="held-out runs every added effect is checked on")
    p.add_argument("--kinds", metavar="LIST", help="comma-separated effect kinds to try (default: all; "
                   "derivative, delay, lag, bias, drift, scale, nonlinear, periodic)")
    p.add_argument("--alpha", type=fraction, default=0.01, help="family-wise false-alarm level (default 0.01)")
    p.add_argument("--max-steps", type=nonnegative_int, default=6, help="effects added at most (default 6)")
    p.add_argument("--no-zero-shifts", action="store_true",
                   help="do not estimate per-run output zero shifts (then a common bias is a candidate)")
    p.add_argument("--frequency", type=positive_float, action="append", metavar="HZ",
                   help="known disturbance frequency (e.g. a rotor harmonic); default: residual spectrum peak")
    p.add_argument("--f-min", type=nonnegative_float, default=0.5, metavar="HZ", help="lowest periodic frequency searched")
    p.add_argument("--tau-max", type=positive_float, default=0.5, metavar="S", help="largest delay searched (default 0.5)")
    p.set_defaults(func=cmd_refine)


def cmd_freq(args) -> int:
    """Frequency responses and coherence of runs; Bode plots with the a priori model, CSV, J."""
    from pathlib import Path

    from .data.csvfile import read_run
    from .estimators.frequency.bode import plot_bode
    from .estimators.frequency.response import cost_report, frequency_response

    profile = load_profile(args.profile)
    runs = [read_run(f) for f in args.runs]
    f_range = None if args.f_min is None and args.f_max is None else (args.f_min or 0.05, args.f_max or 5.0)
    fr = frequency_response(runs, profile.input_names, list(profile.outputs), f_range=f_range)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    models = {"a priori": LinearModel(profile)}
    if args.identified:  # e.g. identified_profile.toml from identify estimate
        models["identified"] = LinearModel(load_profile(args.identified))
    plots = plot_bode(fr, models, out)
    fr.to_csv(out / "frequency_response.csv")
    print(f"windows {', '.join(f'{w:.3g}' for w in fr.windows)} s over {len(runs)} run(s)")
    print("\n".join(fr.resolved_lines()))
    print(cost_report(runs, models)[0])
    print(f"written to {out}: frequency_response.csv, {', '.join(p.name for p in plots)}")
    return 0


def _add_freq_parser(sub) -> None:
    p = sub.add_parser("freq", help="frequency responses with coherence (Bode plots, CSV, fit cost J)")
    p.add_argument("runs", nargs="+", help="run files (.csv)")
    p.add_argument("--profile", required=True, help="profile (inputs, outputs and the a priori model overlaid)")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--identified", metavar="TOML", help="an identified profile to overlay and judge (J) too")
    p.add_argument("--f-min", type=positive_float, metavar="HZ", help="lowest frequency (default: from the windows)")
    p.add_argument("--f-max", type=positive_float, metavar="HZ", help="highest frequency (default 0.4 x sample rate, <= 5)")
    p.set_defaults(func=cmd_freq)


def main(argv=None) -> int:
    return run(build_parser(), argv)

"""``python -m identify``: inspect models and identify them from runs."""
from __future__ import annotations

import sys

from .cliutil import (Parser, add_threads_option, finite_float, fraction, nonnegative_float, nonnegative_int,
                      output_dir, output_file, positive_float, positive_int, run, state_values)
from .errors import EstimationError
from .model.linear import LinearModel, format_modes, residualize
from .model.profile import load_profile


def cmd_model(args) -> int:
    """Print a profile's parameters and modes; optionally its residualised reduction."""
    profile = load_profile(args.profile)
    if args.at:
        profile = _at_condition(profile, args.at)
    model = LinearModel(profile)
    _print_model(model)
    if args.reduce:
        reduced = residualize(model, [s.strip() for s in args.reduce.split(",") if s.strip()])
        print()
        _print_model(LinearModel(reduced))
        if args.save_reduced:
            print(f"\nreduced profile written to {reduced.save(args.save_reduced)}")
    return 0


def _at_condition(profile, text: str):
    """A scheduled profile (``[meta.schedule]``, e.g. from ``campaign stitch``) at ``NAME=VALUE``."""
    from .errors import ProfileError
    from .model.schedule import at_condition, parse_condition, schedule_of

    name, value = parse_condition(text)
    schedule = schedule_of(profile)
    if schedule is None:
        raise ProfileError(f"{profile.source}: --at needs a scheduled profile ([meta.schedule]); this one has none")
    if name != schedule["condition"]:
        raise ProfileError(f"{profile.source}: scheduled over '{schedule['condition']}', not '{name}'")
    return at_condition(profile, value)


def _print_model(model: LinearModel) -> None:
    p = model.profile
    print(f"{p.name}\n  states:  {', '.join(f'{s} [{u}]' for s, u in p.states.items())}"
          f"\n  inputs:  {', '.join(f'{s} [{u}]' for s, u in p.inputs.items())}"
          f"\n  outputs: {', '.join(p.outputs)}"
          f"\n  {len(p.free)} free, {len(p.fixed)} fixed parameters")
    std = p.meta.get("std", {}) if isinstance(p.meta.get("std"), dict) else {}
    for kind, values in (("free", p.free), ("fixed", p.fixed)):
        if values:
            print(f"\n{kind} parameters:" + ("  (value, std)" if std and kind == "free" else ""))
            print("\n".join(f"  {name:<16}{value:13.6g}" + (f"{std[name]:12.4g}" if name in std else "")
                             for name, value in values.items()))
    trim = p.meta.get("trim")
    if isinstance(trim, dict) and trim:
        print("\ntrim:\n" + "\n".join(f"  {name:<16}{value:13.6g}" for name, value in trim.items()))
    effects = _declared_effects(p)
    print("\ndeclared effects (every command applies them to the runs):" + ("" if effects else " none"))
    if effects:
        print("\n".join(f"  {line}" for line in effects))
    notes = [f"{key}: {value}" for key, value in p.meta.items() if key not in ("delays", "pseudo_inputs", "std", "trim")]
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
    p.add_argument("--at", metavar="NAME=VALUE", help="a scheduled profile (campaign stitch) at this condition")
    p.set_defaults(func=cmd_model)
    _add_estimate_parser(sub)
    _add_refine_parser(sub)
    _add_structure_parser(sub)
    _add_freq_parser(sub)
    _add_compat_parser(sub)
    _add_hq_parsers(sub)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def cmd_estimate(args) -> int:
    """Identify a profile's free parameters from runs; write result.json, the profile and plots."""
    from .data.preprocess import slice_run, smooth

    profile = _profile(args)
    runs = []
    for r in _read_runs(args.runs, args.channel_map, profile, args):
        if args.smooth is not None:  # every channel alike, inputs included: keeps the equations consistent
            r = smooth(r, args.smooth)
        if args.t_start is not None or args.t_end is not None:
            if ("segment" in r.meta or "dropped_samples" in r.meta) and not _overlaps(r, args.t_start, args.t_end):
                print(f"note: {r.source} lies outside --t-start/--t-end: not used", file=sys.stderr)
                continue
            r = slice_run(r, args.t_start, args.t_end)
        runs.append(_trimmed(r, args.trim, profile))
    if not runs:
        raise EstimationError("no run has samples between --t-start and --t-end")

    estimator = _estimator(args, profile)
    result = _fit(estimator, runs)
    print(result.summary(), flush=True)  # on screen before anything is written
    if "report_lines" in result.info:  # the frequency-response fit's J, pruning and delays
        print("\n" + "\n".join(result.info["report_lines"]), flush=True)
    from .estimators.frequency.response import cost_report
    text, result.info["frequency_cost_J"] = cost_report(runs, {"identified": result.model,
                                                              "a priori": LinearModel(profile)})
    print("\n" + text, flush=True)
    verification = None
    if args.verify:  # VERIFY: the identified model predicts runs that took no part
        from .estimators.frequency.verify import verify
        verification = verify(result.model, _read_runs(args.verify, args.channel_map, result.profile))
        result.info["verify"] = verification.to_dict()
        print("\n" + "\n".join(verification.lines()), flush=True)
    out = result.save(args.out)
    with open(out / "summary.txt", "a") as f:  # the frequency-domain cost printed above, too
        f.write("\n" + text + "\n")
    written = ["result.json", "summary.txt", "identified_profile.toml"] + (["time_histories.npz"] if result.time else [])
    if args.plots:  # on request: drawing them costs three times the fit itself (benchmarks/ml_speed.py)
        from .estimators.plots import save_plots
        written += [p.name for p in save_plots(result, out)]
    if verification is not None:  # asked for with --verify: its plot comes with it
        from .estimators.frequency.verify import plot_verification
        from .model.profile import output_units
        written.append(plot_verification(verification, out / "verify.png", output_units(result.profile)).name)
    print(f"\nwritten to {out}: {', '.join(written)}" + ("" if args.plots else " (plots: add --plots)"))
    return 0


def _estimator(args, profile, show_progress: bool = True):
    """The estimator instance of ``--method`` with the options given for it (an option the method
    does not take is one clear error); progress of the iterative ones on stderr."""
    from .estimators.registry import build

    def show(it, value, theta):
        print(f"{args.method.upper()} iteration {it}: {estimator.progress_quantity} {value:.4g}",
              file=sys.stderr, flush=True)

    estimator = build(args.method, profile, progress=show if show_progress else None,
                      names={"max_iter": "--max-iter", "diff_cutoff_hz": "--diff-cutoff", "delays": "--fr-delays",
                             "prune": "--prune", "x0": "--x0", "n_draws": "--n-draws",
                             "formulation": "--fem-formulation"},
                      max_iter=getattr(args, "max_iter", None), diff_cutoff_hz=getattr(args, "diff_cutoff", None),
                      delays=_names(getattr(args, "fr_delays", None)) or None,
                      prune=getattr(args, "prune", None) or None, x0=getattr(args, "x0", None),
                      n_draws=getattr(args, "n_draws", None), formulation=getattr(args, "fem_formulation", None))
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
    p = sub.add_parser("estimate", help="identify a profile's parameters from runs (LS, IV, ML, FDEE, FR or FEM)")
    _add_common_options(p, "run files", default_method="iv")
    p.add_argument("--smooth", type=positive_float, metavar="HZ", help="zero-phase low-pass cut-off for every channel")
    p.add_argument("--diff-cutoff", type=positive_float, metavar="HZ",
                   help="cut-off of the smoothed differentiator for states without measured derivatives")
    p.add_argument("--t-start", type=finite_float, metavar="S", help="use samples from this time on")
    p.add_argument("--t-end", type=finite_float, metavar="S", help="use samples up to this time")
    p.add_argument("--max-iter", type=positive_int, metavar="N",
                   help="iterations at most for iv (default 30), ml and fem (default 100)")
    p.add_argument("--plots", action="store_true",
                   help="also draw time_history_run<k>.png and residuals.png (slower than the fit)")
    p.add_argument("--x0", type=state_values, metavar="STATE=VALUE,...",
                   help="known initial states, held in every run (ml, fem; adds to the profile's [initial_state])")
    p.add_argument("--verify", nargs="+", metavar="RUN", help="held-out runs the identified model must predict "
                   "(VERIFY: initial state and zero shifts fitted; Theil coefficient and J_rms reported)")
    p.add_argument("--fem-formulation", choices=("measurement", "innovation"),
                   help="fem: R the measurement noise, fitted with the derivatives (default), or the textbook's "
                        "innovation covariance, relaxed, with C K <= 1 (where the default fit is degenerate)")
    p.add_argument("--fr-delays", metavar="INPUTS", help="fr: comma-separated inputs given a fitted time delay")
    p.add_argument("--prune", action="store_true", help="fr: fix parameters that fail CIFER's gates "
                   "(insensitivity <= 10 %%, Cramér-Rao <= 20 %%) at their a priori values, one at a time")
    p.add_argument("--n-draws", type=_n_draws, metavar="N",
                   help="fr: surrogate sets of runs behind the bootstrap standard errors (default 30; 0: Tischler's "
                        "bound from J alone, which takes correlated points as independent and is too small)")
    p.set_defaults(func=cmd_estimate)


def _n_draws(text: str) -> int:
    """argparse type of --n-draws: 0 or at least 3 (a sample covariance needs three refits)."""
    import argparse

    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if n != 0 and n < 3:
        raise argparse.ArgumentTypeError(f"0 or at least 3, got {n}")
    return n


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(n.strip() for n in (text or "").split(",") if n.strip())


def _read_runs(paths, channel_map, profile, args=None):
    """Every run of the files (CSV or .mat; a file split by time gaps gives several), in SI units,
    as the profile needs them: a refined profile's delays applied and pseudo-inputs rebuilt.
    ``args`` brings the NaN policy (``--nan``) and the window (``--t-start``/``--t-end``)."""
    from .model.pseudo_inputs import prepare

    return prepare(profile, _recorded_runs(paths, channel_map, profile, args))


def _recorded_runs(paths, channel_map, profile, args=None):
    """The runs as recorded (the pilot's inputs, no declared delay applied): handling qualities
    and LOES judge the aircraft from the stick, its delays included."""
    from .data.ingest import ReadOptions
    from .data.io import load_channel_map, read_run_files

    options = ReadOptions(getattr(args, "nan", "refuse"), getattr(args, "t_start", None), getattr(args, "t_end", None))
    return read_run_files(paths, load_channel_map(channel_map) if channel_map else None, profile, options)


def _trimmed(run, trim: str, profile):
    """``run`` minus its trim values (``--trim``), the profile's pseudo-inputs (a constant, the
    time, ...) left as they are; said once per run."""
    from .data.preprocess import remove_trim
    from .model.pseudo_inputs import specs

    if trim is None:
        return run
    if trim == "none":
        return remove_trim(run, "none")  # recorded: the data were taken as perturbations already
    pseudo = set(specs(profile))
    out = remove_trim(run, trim, [n for n in run.channels if n not in pseudo])
    print(f"note: {run.source}: trim removed ({trim}) from {len(run.channels) - len(pseudo & set(run.channels))} "
          f"channel(s)", file=sys.stderr)
    return out


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
    p.add_argument("--nan", choices=("refuse", "drop", "interpolate"), default="refuse",
                   help="missing values inside the analysed window: refuse the file (default), drop their samples "
                        "(the hole splits the run) or interpolate them; outside the window the run is cut to it")
    p.add_argument("--trim", default=None, type=_trim_option, metavar="first:1s|mean|none",
                   help="remove each channel's trim value: its mean over the first seconds, over the whole run, "
                        "or none; recorded in result.json (not given: the data are used as they are)")
    p.add_argument("--channel-map", metavar="JSON",
                   help='{"channels": {channel: column, variable, matrix column or expression such as '
                        '"(dar - dal)/2"}, "units": {name: unit}, "time": ..., "matrix": ..., "dt": ...} '
                        'as a file or inline JSON (required for .mat data matrices)')
    p.add_argument("--fix", metavar="LIST", help="free parameters to hold at their a priori values (comma-separated)")
    p.add_argument("--free", metavar="LIST", help="fixed parameters to estimate (comma-separated)")
    p.add_argument("--outputs", metavar="LIST", help="fit these outputs only (comma-separated; default all)")
    p.add_argument("--turbulence", metavar="LIST", help="fem: gust states on these velocities (u,v,w; in a "
                   "flow-angle profile w and v act on alpha and beta), corners and intensities estimated; "
                   "sets the profile's [turbulence] states")
    p.add_argument("--prior-relative", type=positive_float, metavar="PCT",
                   help="a priori weighting: every free parameter's a priori value is a prior with std PCT %% of "
                        "it (at least PCT %% of a tenth of the largest of its equation's parameters of the same unit)")
    p.add_argument("--prior", metavar="FILE", help="a priori weighting: a previous result.json (or a profile with "
                   "meta.std): its estimates and stds become the prior (over the profile's [prior])")


def _profile(args):
    """The a priori profile, with ``--free``, ``--fix`` and ``--outputs`` applied (each said)."""
    from .model import subset
    from .model.prior import prior_options

    profile = load_profile(args.profile)
    for option, change in (("free", subset.free), ("fix", subset.fix), ("outputs", subset.with_outputs)):
        if getattr(args, option):
            profile = change(profile, getattr(args, option))
            print(f"--{option} {getattr(args, option)}: {len(profile.free)} free parameters, "
                  f"outputs {', '.join(profile.outputs)}", file=sys.stderr)
    profile, lines = prior_options(profile, getattr(args, "prior_relative", None), getattr(args, "prior", None))
    for line in lines:
        print(line, file=sys.stderr)
    if getattr(args, "turbulence", None):
        from .estimators.registry import estimator_class
        from .model.turbulence import with_turbulence

        if not estimator_class(args.method).models_turbulence:
            raise EstimationError(f"--turbulence is the filter-error method's model: use --method fem "
                                  f"(--method {args.method} takes every misfit for measurement noise)")
        profile = with_turbulence(profile, args.turbulence)
    return profile


def _trim_option(text: str) -> str:
    """argparse type of --trim (checked without loading numpy-heavy modules)."""
    import argparse

    from .data.preprocess import parse_trim
    from .errors import RunError

    try:
        parse_trim(text)
    except RunError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text.strip().lower()


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
                     frequencies=args.frequency, f_min=args.f_min, tau_max=args.tau_max, progress=True,
                     prune=_pruner() if args.backward else None)
    fit_runs = [_trimmed(r, args.trim, profile) for r in _read_runs(args.runs, args.channel_map, profile, args)]
    held_out = [_trimmed(r, args.trim, profile) for r in _read_runs(args.validate or [], args.channel_map, profile, args)]
    refiner.fit(fit_runs, validate=held_out)
    if refiner.nothing_found:
        print("nothing found: no candidate effect is significant")
    for i, s in enumerate(refiner.steps_, start=1):
        params = ", ".join(f"{k} = {v['value']:.5g} ± {v['std']:.2g}" for k, v in s.parameters.items())
        print(f"step {i}: {s.effect} on {s.target}: {params} (score {s.statistic:.4g} > {s.threshold:.4g})")
    for s in refiner.rejected_:
        print(f"rejected: {s.effect} on {s.target}: {s.reason}")
    for d in refiner.pruned_:
        print(f"prune: {d.term} {'fixed at 0' if d.action == 'dropped' else 'kept'} (|t| = {d.statistic:.2f}; {d.note})")
    if refiner.unconverged_:
        print(f"warning: {len(refiner.unconverged_)} fit(s) inside refine did not converge "
              f"(listed in report.md): {refiner.unconverged_[0]}")
    for where in refiner.error_before_:
        print(f"{where} error (overall): {refiner.error_before_[where]['overall']:.4g} -> "
              f"{refiner.error_after_[where]['overall']:.4g}", flush=True)
    out = write(refiner, args.out)  # after the screen output: a failing write loses nothing shown
    _add_provenance(out, fit_runs + held_out)
    print(f"written to {out}: refine.json, report.md, final_profile.toml")
    return 0


def _add_provenance(out, runs) -> None:
    """The runs' provenance into refine.json and report.md (refine's writer knows the fits, the
    readers know the files)."""
    import json
    from pathlib import Path

    from .data.provenance import provenance, provenance_lines
    from .estimators.result import dumps

    prov = provenance(runs)
    path = Path(out) / "refine.json"
    data = json.loads(path.read_text())
    data["provenance"] = prov
    path.write_text(dumps(data))
    with open(Path(out) / "report.md", "a") as f:
        f.write("\n## Data provenance\n\n```\n" + "\n".join(provenance_lines(prov)) + "\n```\n")


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
    p.add_argument("--prune", dest="backward", action="store_true",
                   help="a last step of backward elimination: fix at 0, one at a time, the parameters within 2 "
                        "std of zero whose removal does not raise the held-out error (identify structure)")
    p.set_defaults(func=cmd_refine)


def _pruner():
    from .structure.prune import Prune

    return Prune()


def cmd_structure(args) -> int:
    """Which parameters the data support and which terms they ask for: stepwise regression in
    equation error, then backward elimination in output error; the decisions and the final profile."""
    from .structure.report import write
    from .structure.search import StructureSearch

    profile = _profile(args)
    knots = _knots(args.knots)
    search = StructureSearch(profile, estimator=_estimator(args, profile, show_progress=False), alpha=args.alpha,
                             candidates=not args.no_candidates, nonlinear=_names(args.nonlinear), knots=knots,
                             level=args.level, tolerance=args.tolerance, confirm=not args.equation_error_only,
                             progress=True)
    fit_runs = [_trimmed(r, args.trim, profile) for r in _read_runs(args.runs, args.channel_map, profile, args)]
    held_out = [_trimmed(r, args.trim, profile) for r in _read_runs(args.validate or [], args.channel_map, profile, args)]
    search.fit(fit_runs, validate=held_out)
    print(search.summary())
    if getattr(search, "unconverged_", None):
        print(f"warning: {len(search.unconverged_)} fit(s) did not converge: {search.unconverged_[0]}")
    out = write(search, args.out)
    print(f"written to {out}: structure.json, final_profile.toml")
    return 0


def _knots(text: str | None) -> dict[str, list[float]]:
    """``--knots alpha=0.1,0.2;w=3`` -> {"alpha": [0.1, 0.2], "w": [3.0]}."""
    out = {}
    for part in filter(None, (p.strip() for p in (text or "").split(";"))):
        name, _, values = part.partition("=")
        try:
            out[name.strip()] = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise EstimationError(f"--knots: not numbers in {part!r} (write name=k1,k2;other=k)") from None
        if not name.strip() or not out[name.strip()]:
            raise EstimationError(f"--knots: {part!r} is not name=k1,k2")
    return out


def _add_structure_parser(sub) -> None:
    p = sub.add_parser("structure", help="model structure determination: which parameters the data support, "
                                         "which terms they ask for (stepwise regression, then output error)")
    _add_common_options(p, "run files to fit", default_method="ml")
    p.add_argument("--validate", nargs="+", metavar="RUN",
                   help="held-out runs the output-error removals are judged on (default: half of each run)")
    p.add_argument("--alpha", type=fraction, default=0.05,
                   help="stepwise regression's level: partial F to stay per term, to enter for the family of "
                        "candidates (default 0.05)")
    p.add_argument("--no-candidates", action="store_true", help="do not try undeclared A/B entries")
    p.add_argument("--nonlinear", metavar="LIST",
                   help="channels whose squares, x|x|, splines and pairwise products are candidates")
    p.add_argument("--knots", metavar="SPEC", help="spline knots of --nonlinear channels: 'alpha=0.1,0.2;w=3'")
    p.add_argument("--level", type=positive_float, default=2.0,
                   help="|estimate|/std below which output error calls a parameter unsupported (default 2)")
    p.add_argument("--tolerance", type=nonnegative_float, default=0.01,
                   help="relative rise of the held-out error a removal may cause (default 0.01)")
    p.add_argument("--equation-error-only", action="store_true", help="stop after the equation-error pass")
    p.set_defaults(func=cmd_structure)


def cmd_freq(args) -> int:
    """Frequency responses and coherence of runs; Bode plots with the a priori model, CSV, J."""
    from pathlib import Path

    import numpy as np

    from .data.csvfile import read_run
    from .estimators.frequency.bode import plot_bode
    from .estimators.frequency.response import cost_report, frequency_response

    profile = load_profile(args.profile)
    runs = [read_run(f) for f in args.runs]
    inputs, skipped = _moved_inputs(runs, profile.input_names)
    runs = [r.with_channels({u: np.zeros(len(r)) for u in profile.input_names if u not in r.channels})
            for r in runs]  # an input a run lacks was held at trim
    f_range = None if args.f_min is None and args.f_max is None else (args.f_min or 0.05, args.f_max or 5.0)
    fr = frequency_response(runs, inputs, list(profile.outputs), f_range=f_range)
    if skipped:  # said once the responses exist (a missing output is the one error line otherwise)
        print(f"note: skipped input(s) {', '.join(skipped)}: no run moves them (absent or constant); "
              f"responses to {', '.join(inputs)} only", file=sys.stderr)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    models = {"a priori": LinearModel(profile)}
    for k, path in enumerate(args.identified or []):  # e.g. identified_profile.toml from identify estimate
        label = "identified" if len(args.identified) == 1 else f"identified {k + 1} ({Path(path).parent.name})"
        models[label] = LinearModel(load_profile(path))
    plots = plot_bode(fr, models, out)
    fr.to_csv(out / "frequency_response.csv")
    print(f"windows {', '.join(f'{w:.3g}' for w in fr.windows)} s over {len(runs)} run(s)")
    print("\n".join(fr.resolved_lines()))
    print(cost_report(runs, models)[0])
    print(f"written to {out}: frequency_response.csv, {', '.join(p.name for p in plots)}")
    return 0


def _moved_inputs(runs, inputs) -> tuple[list[str], list[str]]:
    """The profile inputs some run moves (present and not constant), and those none does: a
    response to an input never moved is not estimable (its cross-spectra are empty), and keeping
    it would make every other input's response singular. A moved input absent from some run is
    taken at trim (zero) there."""
    import numpy as np

    def moved(u):
        return any(u in r.channels and np.ptp(r[u]) > 0 for r in runs)

    used = [u for u in inputs if moved(u)]
    if not used:
        raise EstimationError(f"no run moves any input of the profile ({', '.join(inputs)})")
    return used, [u for u in inputs if u not in used]


def _add_freq_parser(sub) -> None:
    p = sub.add_parser("freq", help="frequency responses with coherence (Bode plots, CSV, fit cost J)")
    p.add_argument("runs", nargs="+", help="run files (.csv)")
    p.add_argument("--profile", required=True, help="profile (inputs, outputs and the a priori model overlaid)")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--identified", metavar="TOML", action="append",
                   help="an identified profile to overlay and judge (J) too; repeat for several (e.g. ML and FR)")
    p.add_argument("--f-min", type=positive_float, metavar="HZ", help="lowest frequency (default: from the windows)")
    p.add_argument("--f-max", type=positive_float, metavar="HZ", help="highest frequency (default 0.4 x sample rate, <= 5)")
    p.set_defaults(func=cmd_freq)


def cmd_compat(args) -> int:
    """Flight-path reconstruction: sensor biases, scale factors and time skews; corrected runs."""
    from .compat import Compat
    from .compat.report import write
    from .data.ingest import ReadOptions
    from .data.io import load_channel_map, read_run_files

    runs = read_run_files(args.runs, load_channel_map(args.channel_map) if args.channel_map else None, None,
                          ReadOptions(args.nan))
    errors = None if args.errors is None else [e.strip() for e in args.errors.split(",") if e.strip()]
    compat = Compat(errors, alpha=args.alpha, max_steps=args.max_steps, segment=args.segment,
                    input_noise=_input_noise(args.input_noise),
                    progress=lambda text: print(text, file=sys.stderr, flush=True)).fit(runs)
    print(compat.result_.summary(), flush=True)
    written = write(compat.result_, runs, args.out, plots=args.plots)
    print(f"written to {args.out}: {', '.join(written)}")
    return 0


def _input_noise(text: str | None) -> dict | None:
    """``a_z=0.01,q=0.00035`` -> {channel: std}; one clear error for a malformed item."""
    if not text:
        return None
    out = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, _, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise EstimationError(f"--input-noise: '{item}' is not channel=std (e.g. q=0.00035)") from None
    return out


def _add_compat_parser(sub) -> None:
    p = sub.add_parser("compat", help="flight-path reconstruction: sensor biases, scale factors, time skews; "
                                      "corrected runs")
    p.add_argument("runs", nargs="+", help="run files (.csv or .mat) with a_x, a_y, a_z, p, q, r and any of "
                                           "V, alpha, beta, phi, theta, psi, h")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--channel-map", metavar="JSON", help="channel map (file or inline JSON), as for estimate")
    p.add_argument("--nan", choices=("refuse", "drop", "interpolate"), default="refuse",
                   help="missing values: refuse the file (default), drop their samples or interpolate them")
    p.add_argument("--errors", metavar="LIST", help="estimate exactly these sensor errors (e.g. b_q,b_alpha,"
                   "K_alpha,tau_alpha) instead of selecting them by score tests")
    p.add_argument("--alpha", type=fraction, default=0.01, help="family-wise false-alarm level (default 0.01)")
    p.add_argument("--max-steps", type=nonnegative_int, default=12, help="sensor errors added at most (default 12)")
    p.add_argument("--segment", type=positive_float, default=3.0, metavar="S",
                   help="integration segment length, each from its own initial state (default 3 s)")
    p.add_argument("--input-noise", metavar="LIST", help="white-noise std of inertial sensors for the bounds, "
                   "SI units (e.g. a_z=0.01,q=0.00035, from a data sheet); others estimated from the data")
    p.add_argument("--plots", action="store_true", help="also draw residuals_before_after.png")
    p.set_defaults(func=cmd_compat)


def cmd_hq(args) -> int:
    """ADS-33 bandwidth and phase delay, the chart, short-period LOES: of runs or of a model."""
    from .estimators.frequency.hq import hq_of_model, hq_of_response

    profile = load_profile(args.profile)
    options = dict(task=args.task, pitch=args.pitch, roll=args.roll, category=args.category, n_alpha=args.n_alpha)
    if args.boundaries:
        from .estimators.frequency.handling import load_boundaries

        try:
            options["boundaries"] = load_boundaries(args.boundaries)
        except ValueError as exc:
            raise EstimationError(str(exc)) from None
    if args.runs:
        from .estimators.frequency.response import frequency_response

        runs = _recorded_runs(args.runs, args.channel_map, profile)
        fr = frequency_response(runs, profile.input_names, list(profile.outputs), n_freq=args.n_freq)
        report = hq_of_response(fr, **options)
        model = hq_of_model(LinearModel(profile), **options) if args.with_model else None
    else:
        report, model = hq_of_model(LinearModel(profile), **options), None
    print("\n".join(report.lines() + (["model:"] + model.lines() if model else [])), flush=True)
    paths = report.save(args.out, model)
    print(f"written to {args.out}: {', '.join(p.name for p in paths)}")
    return 0


def cmd_loes(args) -> int:
    """A transfer function (chosen orders, equivalent delay, bounds) fitted to one measured response."""
    from pathlib import Path

    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from .estimators.frequency.loes import fit_transfer_function, plot_fit, short_period
    from .estimators.frequency.response import frequency_response

    profile = load_profile(args.profile)
    output, _, input_ = args.pair.partition("/")
    if output not in profile.outputs or input_ not in profile.input_names:
        raise EstimationError(f"--pair {args.pair}: give OUTPUT/INPUT of the profile (outputs "
                              f"{', '.join(profile.outputs)}; inputs {', '.join(profile.input_names)})")
    runs = _recorded_runs(args.runs, args.channel_map, profile)
    fr = frequency_response(runs, profile.input_names, list(profile.outputs), n_freq=args.n_freq)
    j, i = fr.pair(output, input_)
    band = None if args.w_min is None and args.w_max is None else (args.w_min or 0.0, args.w_max or np.inf)
    coh = np.where(fr.resolved[:, j, i], fr.coherence[:, j, i], 0.0)
    try:
        fit = fit_transfer_function(fr.omega, fr.H[:, j, i], coh, n_num=args.num, n_den=args.den,
                                    delay=not args.no_delay, tau_bounds=(0.0, args.tau_max), omega_range=band)
    except ValueError as exc:
        raise EstimationError(f"loes {args.pair}: {exc}") from None
    text = [f"{args.pair}: numerator order {args.num}, denominator order {args.den}"
            + ("" if args.no_delay else f", equivalent delay in [0, {args.tau_max:g}] s"), fit.summary()]
    if args.den == 2 and not args.no_delay:
        text += short_period(fit, args.category, args.n_alpha).lines()
    print("\n".join(text), flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "loes.md").write_text("```\n" + "\n".join(text) + "\n```\n")
    fig = plot_fit(fr.omega, fr.H[:, j, i], coh, fit, f"{args.pair}: transfer-function fit")
    FigureCanvasAgg(fig)
    fig.savefig(out / "loes.png", dpi=90)
    print(f"written to {out}: loes.md, loes.png")
    return 0


def _add_hq_parsers(sub) -> None:
    p = sub.add_parser("hq", help="handling qualities: ADS-33 bandwidth/phase delay chart, short-period LOES")
    p.add_argument("runs", nargs="*", help="run files (.csv or .mat); none: the profile's model itself")
    p.add_argument("--profile", required=True, help="profile (or identified profile) TOML path or bundled name")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--task", choices=("tracking", "other"), default="tracking",
                   help="ADS-33 task category (default tracking: target acquisition and tracking)")
    p.add_argument("--pitch", metavar="INPUT", help="pitch control (default theta_s or delta_e)")
    p.add_argument("--roll", metavar="INPUT", help="roll control (default theta_c or delta_a)")
    p.add_argument("--boundaries", metavar="FILE.json", help="ADS-33 Level 1/2 boundaries read from the "
                   "specification's figures (polylines per task and axis, with their source; see docs/frequency.md); "
                   "default: the built-in corners, UNVERIFIED")
    _add_response_options(p)
    p.add_argument("--with-model", action="store_true", help="with runs: also the profile's model, on the same charts")
    p.set_defaults(func=cmd_hq)
    p = sub.add_parser("loes", help="transfer function (LOES) with an equivalent delay fitted to one response")
    p.add_argument("runs", nargs="+", help="run files (.csv or .mat)")
    p.add_argument("--profile", required=True, help="profile naming the inputs and outputs")
    p.add_argument("--pair", required=True, metavar="OUTPUT/INPUT", help="the response fitted, e.g. q/theta_s")
    p.add_argument("--num", type=nonnegative_int, default=1, help="numerator order (default 1)")
    p.add_argument("--den", type=positive_int, default=2, help="denominator order (default 2)")
    p.add_argument("--no-delay", action="store_true", help="no equivalent time delay")
    p.add_argument("--tau-max", type=positive_float, default=0.5, metavar="S", help="largest delay (default 0.5)")
    p.add_argument("--w-min", type=positive_float, metavar="RAD_S", help="lowest frequency fitted")
    p.add_argument("--w-max", type=positive_float, metavar="RAD_S", help="highest frequency fitted")
    _add_response_options(p)
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.set_defaults(func=cmd_loes)


def _add_response_options(p) -> None:
    """Options hq and loes share: the LOES level's category and n/alpha, the response grid, the channel map."""
    p.add_argument("--category", choices=("A", "B", "C"), default="A", help="MIL-STD-1797A flight-phase category")
    p.add_argument("--n-alpha", type=positive_float, metavar="G_PER_RAD", help="normal load factor per angle of "
                   "attack (g/rad): grades the short period's CAP = omega_sp^2/(n/alpha) and frequency minimum "
                   "(without it omega_sp is not graded)")
    p.add_argument("--n-freq", type=positive_int, default=120, help="frequencies of the response grid")
    p.add_argument("--channel-map", metavar="JSON", help="channel map of the run files (as for estimate)")


def main(argv=None) -> int:
    return run(build_parser(), argv)

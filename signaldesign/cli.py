"""``python -m signaldesign``: frequency band, signal design, baselines, comparison, plots."""
from __future__ import annotations

from identify.cliutil import (Parser, add_threads_option, fraction, nonnegative_float, nonnegative_int, output_file,
                               positive_float, positive_int, progress_bar, run)
from identify.model import LinearModel
from identify.profile import load_profile

from .band import plot_band, required_band
from .baselines import make_signal
from .compare import reference_of, tuned_baselines
from .design import SequenceDesign
from .evaluate import Evaluator, format_scores, perturbed_models
from .information import default_noise, format_noise
from .signal import SignalError, load_signals, save_signals, signals_to_run
from .spectrum import half_power_band, plot_signals


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SignalError(f"{what}: expected comma-separated numbers, got '{text}'") from None


def _model(args) -> LinearModel:
    return LinearModel(load_profile(args.profile))


def cmd_band(args) -> int:
    model = _model(args)
    band = required_band(model, args.input, args.level)
    print(band.format())
    print(format_noise(model.profile, default_noise(model.profile)))
    if args.plot:
        plot_band(band, args.plot, title=f"{model.profile.name}: input {args.input}")
        print(f"plot written to {args.plot}")
    return 0


def _inputs(args) -> list[str]:
    return [s.strip() for s in args.input.split(",") if s.strip()]


def cmd_design(args) -> int:
    model = _model(args)
    inputs = _inputs(args)
    designer = SequenceDesign(inputs, args.duration, args.record, args.amplitude, args.dt,
                              args.min_width, args.max_width, min_pulse=args.min_pulse,
                              max_changes=args.max_changes, allow_double_jumps=args.allow_double_jumps,
                              criterion=args.criterion,
                              perturbations=args.perturbations if args.criterion != "nominal" else 0,
                              spread=args.spread, max_peak=args.max_peak,
                              seed=args.seed, progress=progress_bar("designing"))
    designer.candidate_widths()  # an impossible duration is reported before any work
    band = required_band(model, inputs[0])
    ev = Evaluator(model, inputs, args.record, args.dt, band=(band.low, band.high),
                   models=perturbed_models(model, args.perturbations, args.spread, args.seed))
    baselines = tuned_baselines(ev, args.duration, args.amplitude, band.high)
    reference = reference_of(baselines)
    designer.reference = reference
    designer.fit(model)
    ev.set_reference(reference)
    scores = [ev.score(s, label) for label, s in baselines]
    res = designer.result_
    scores.append(ev.score(designer.signals_, f"optimised ({res.method}), width {designer.width_:g} s"))
    print(f"{model.profile.name}: {', '.join(inputs)}, {args.duration:g} s input in a {args.record:g} s record, "
          f"amplitude {args.amplitude:g} rad; required band {band.low:.3f}..{band.high:.3f} rad/s")
    print(format_noise(model.profile, ev.noise_std))
    print(f"{ev.p} parameters scored; perturbed models: {len(ev.models)} (derivatives x 1 -/+ {args.spread:g})")
    print(format_scores(scores, "the best 3211"))
    for s in designer.signals_:
        print(f"optimised levels on {s.input}: {' '.join(f'{int(v):+d}' for v in s.levels)}")
    print(f"design took {designer.seconds_:.1f} s ({res.evaluations} candidates scored at the best width)")
    if args.out:
        save_signals(designer.signals_, args.out)
        print(f"signal written to {args.out}")
    if args.plot:
        sigs = [reference[0], designer.signals_[0]]
        plot_signals(sigs, args.plot, band=(band.low, band.high), labels=["best 3211", "optimised"])
        print(f"plot written to {args.plot}")
    return 0


def cmd_make(args) -> int:
    band = tuple(_floats(args.band, "--band")) if args.band else None
    if band is not None and len(band) != 2:
        raise SignalError(f"--band needs two frequencies low,high in rad/s, got '{args.band}'")
    pulses = [int(v) for v in _floats(args.pulses, "--pulses")] if args.pulses else None
    levels = _floats(args.levels, "--levels") if args.levels else None
    sig = make_signal(args.kind, width=args.width, amplitude=args.amplitude, input=args.input,
                      duration=args.duration, band=band, pulses=pulses, levels=levels, order=args.order,
                      dt=args.dt, delay=args.delay)
    lo, hi, peak = half_power_band(sig)
    print(f"{sig.kind} on {sig.input}: {sig.levels.size} steps of {sig.dt:g} s ({sig.duration:g} s), "
          f"amplitude {sig.amplitude:g}; half-power band {lo:.3f}..{hi:.3f} rad/s, peak at {peak:.3f} rad/s")
    save_signals(sig, args.out)
    print(f"signal written to {args.out}")
    if args.csv:
        run_ = signals_to_run(sig, args.csv_dt, max(args.record, sig.end_time))
        run_.to_csv(args.csv)
        print(f"run-compatible CSV written to {args.csv}")
    return 0


def cmd_compare(args) -> int:
    model = _model(args)
    sets = [load_signals(path) for path in args.signals]
    inputs = sorted({s.input for sig in sets for s in sig}, key=model.profile.input_names.index
                    if all(s.input in model.profile.input_names for sig in sets for s in sig) else str)
    band = required_band(model, inputs[0])
    ev = Evaluator(model, inputs, args.record, args.dt, band=(band.low, band.high),
                   models=perturbed_models(model, args.perturbations, args.spread, args.seed))
    ev.set_reference(sets[0])
    scores = [ev.score(sig, str(path)) for sig, path in zip(sets, args.signals)]
    print(f"{model.profile.name}: {args.record:g} s record; required band ({inputs[0]}) "
          f"{band.low:.3f}..{band.high:.3f} rad/s")
    print(format_noise(model.profile, ev.noise_std))
    print(format_scores(scores, args.signals[0]))
    return 0


def cmd_plot(args) -> int:
    signals, labels = [], []
    for path in args.signals:
        for s in load_signals(path):
            signals.append(s)
            labels.append(f"{path}: {s.kind} on {s.input}")
    band = None
    if args.profile:
        model = _model(args)
        b = required_band(model, signals[0].input)
        band = (b.low, b.high)
    for s, label in zip(signals, labels):
        lo, hi, peak = half_power_band(s)
        print(f"{label}: half-power band {lo:.3f}..{hi:.3f} rad/s (peak {peak:.3f} rad/s)")
    plot_signals(signals, args.out, band=band, labels=labels)
    print(f"plot written to {args.out}")
    return 0


def _record_options(p):
    p.add_argument("--record", type=positive_float, default=20.0, help="record length in s (default 20)")
    p.add_argument("--dt", type=positive_float, default=0.05, help="sample interval in s (default 0.05)")
    p.add_argument("--perturbations", type=nonnegative_int, default=24,
                   help="perturbed models for the robustness columns (default 24)")
    p.add_argument("--spread", type=nonnegative_float, default=0.3, help="derivatives scaled by 1 -/+ this (default 0.3)")
    p.add_argument("--seed", type=int, default=0)


def build_parser() -> Parser:
    parser = Parser(prog="signaldesign", description="Design flight-test input signals from an a priori model.")
    sub = parser.add_subparsers(title="commands")

    p = sub.add_parser("band", help="print the frequency band an input must excite")
    p.add_argument("--profile", required=True, help="profile TOML path or bundled profile name")
    p.add_argument("--input", required=True, help="control input (e.g. theta_s)")
    p.add_argument("--level", type=fraction, default=0.5, help="fraction of each sensitivity's peak (default 0.5)")
    p.add_argument("--plot", metavar="PNG", type=output_file, help="draw the sensitivities and the band")
    p.set_defaults(func=cmd_band)

    p = sub.add_parser("design", help="optimise a three-level pseudo-stochastic sequence and compare it")
    p.add_argument("--profile", required=True)
    p.add_argument("--input", required=True, help="control input, or two comma-separated for a multi-axis design")
    p.add_argument("--duration", type=positive_float, default=7.0, help="signal length in s (default 7)")
    p.add_argument("--amplitude", type=positive_float, default=0.02, help="amplitude in rad (default 0.02)")
    p.add_argument("--min-width", type=positive_float, default=0.3, help="smallest step width tried, s (default 0.3)")
    p.add_argument("--max-width", type=positive_float, default=1.0, help="largest step width tried, s (default 1)")
    p.add_argument("--min-pulse", type=positive_float, help="shortest hold in s (default one step)")
    p.add_argument("--max-changes", type=positive_int, help="most level changes (default unlimited)")
    p.add_argument("--allow-double-jumps", action="store_true", help="allow +1 to -1 in one step")
    p.add_argument("--criterion", choices=("nominal", "worst", "mean"), default="nominal",
                   help="optimise the a priori model, or the worst/mean over perturbed models")
    p.add_argument("--max-peak", type=positive_float, help="cap each output's peak at this multiple of the best 3211's")
    p.add_argument("--out", metavar="JSON", type=output_file, help="write the optimised signal here")
    p.add_argument("--plot", metavar="PNG", type=output_file, help="draw it against the best 3211 with spectra")
    _record_options(p)
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("make", help="write a baseline signal (doublet, 3211, multistep, steps, multisine, prts)")
    p.add_argument("kind", help="doublet, 3211 (or any digits, e.g. 2121), multistep, steps, multisine, prts")
    p.add_argument("--width", type=positive_float, help="pulse / step width in s")
    p.add_argument("--amplitude", type=positive_float, default=0.02, help="amplitude in rad (default 0.02)")
    p.add_argument("--input", default="theta_s", help="control input (default theta_s)")
    p.add_argument("--duration", type=positive_float, default=7.0, help="multisine / PRTS length in s (default 7)")
    p.add_argument("--band", help="multisine band low,high in rad/s")
    p.add_argument("--pulses", help="multistep pulse counts, e.g. 3,2,1,1")
    p.add_argument("--levels", help="step levels, e.g. 1,1,0,-1,0")
    p.add_argument("--order", type=positive_int, default=3, help="PRTS order (period 3^order - 1, default 3)")
    p.add_argument("--dt", type=positive_float, default=0.05, help="multisine time step in s (default 0.05)")
    p.add_argument("--delay", type=nonnegative_float, default=0.0, help="start time in s (default 0)")
    p.add_argument("--out", required=True, metavar="JSON", type=output_file)
    p.add_argument("--csv", metavar="CSV", type=output_file, help="also write a run-compatible CSV of the input")
    p.add_argument("--csv-dt", type=positive_float, default=0.01, help="CSV sample interval in s (default 0.01)")
    p.add_argument("--record", type=nonnegative_float, default=0.0, help="CSV length in s (default: the signal's)")
    p.set_defaults(func=cmd_make)

    p = sub.add_parser("compare", help="score signal files on a profile (first file is the reference)")
    p.add_argument("--profile", required=True)
    p.add_argument("signals", nargs="+", metavar="JSON")
    _record_options(p)
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("plot", help="draw signals and their power spectra (PNG)")
    p.add_argument("signals", nargs="+", metavar="JSON")
    p.add_argument("--out", default="signals.png", metavar="PNG", type=output_file, help="output PNG (default signals.png)")
    p.add_argument("--profile", help="shade the required band of this profile")
    p.set_defaults(func=cmd_plot)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)

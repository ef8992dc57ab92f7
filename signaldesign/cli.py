"""``python -m signaldesign``: frequency band, signal design, baselines, comparison, plots."""
from __future__ import annotations

import sys

from dataclasses import replace

from identify.cliutil import (Parser, add_threads_option, fraction, nonnegative_float, output_file, positive_float,
                               positive_int, progress_bar, run)
from identify import LinearModel, load_profile

from .band import plot_band, required_band
from .phases import PHASES
from .baselines import make_signal
from .compare import MIN_WIDTH, default_limits, information_per_second, reference_of, tuned_baselines, yardsticks
from .design import CRITERIA, PEAKS, SequenceDesign
from .evaluate import Evaluator, band_coverage, check_record, format_scores
from .robust import evaluation_set
from .information import default_noise, format_noise
from .signal import SignalError, load_signals, save_signals, signals_to_run
from .spectrum import half_power_band, plot_signals


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise SignalError(f"{what}: expected comma-separated numbers, got '{text}'") from None


def _model(args) -> LinearModel:
    if hasattr(args, "dt"):
        check_record(args.record, args.dt)  # --dt 0 is one line, before any work
    profile = load_profile(args.profile)
    if getattr(args, "prior_relative", None):  # design: the prior's information with the flight's
        from identify.model.prior import prior_options

        profile, lines = prior_options(profile, args.prior_relative)
        for line in lines:
            print(line, file=sys.stderr)
    return LinearModel(profile)


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


def _evaluator(model, inputs, args, amplitude) -> Evaluator:
    """Evaluator on the model set, with the required band per input, limits (the profile's, else
    the best-width 3211's peaks at ``amplitude``) and each model's correctly tuned 3211."""
    bands = {i: required_band(model, i) for i in inputs}
    models, labels = evaluation_set(model, seed=args.seed + 101)
    ev = Evaluator(model, inputs, args.record, args.dt, band={i: (b.low, b.high) for i, b in bands.items()},
                   models=models, model_labels=labels)
    default_limits(ev, args.duration, amplitude, args.min_pulse)
    yardsticks(ev, args.duration, args.min_pulse)
    return ev


def _designer(inputs, args, progress=None) -> SequenceDesign:
    return SequenceDesign(inputs, args.duration, args.record, args.amplitude, args.dt, args.grid, args.min_pulse,
                          args.max_changes, not args.no_double_jumps, args.criterion,
                          reference_amplitude=args.reference_amplitude, seed=args.seed, progress=progress,
                          jobs=getattr(args, "jobs", None), certify=getattr(args, "certify", "full"),
                          prior=bool(getattr(args, "with_prior", False) or getattr(args, "prior_relative", None)),
                          peak=getattr(args, "peak", "shared"))


def cmd_design(args) -> int:
    model = _model(args)
    inputs = _inputs(args)
    designer = _designer(inputs, args, progress_bar("designing"))
    designer.n_steps()  # an impossible timing is reported before any work
    ev = _evaluator(model, inputs, args, args.amplitude if args.amplitude is not None else args.reference_amplitude)
    baselines = tuned_baselines(ev, args.duration, 1.0, max(b[1] for b in ev.bands.values()),
                                min_width=args.min_pulse)
    reference = reference_of(baselines)
    ev.set_reference(reference)
    designer.limits = dict(zip(model.profile.outputs, ev.limits))
    designer.fit(model)
    scores = [ev.score(s, label) for label, s in baselines]
    scores.append(ev.score(designer.signals_, f"optimised ({designer.criterion})"))
    print(f"{model.profile.name}: {', '.join(inputs)}, {args.duration:g} s input in a {args.record:g} s record; "
          + "; ".join(f"required band ({i}) {lo:.3f}..{hi:.3f} rad/s" for i, (lo, hi) in ev.bands.items()))
    print(format_noise(model.profile, ev.noise_std))
    print(f"{ev.p} parameters scored; limits: {ev.limits_source}; model set: {len(ev.models)} models "
          f"(frequencies x 0.6..1.6, derivatives x 0.7..1.3)")
    print(format_scores(scores, "the best-width 3211"))
    print(designer.summary())
    if len(inputs) > 1:
        singles = []
        for i in inputs:  # each axis in its own run, within the same limits
            single = _designer([i], args)
            single.limits, single.certify = designer.limits, "quick"  # its certificate is not printed
            singles.append(single.fit(model).signals_)
        joint, separate = information_per_second(ev, designer.signals_, singles, args.record,
                                                 per_input=designer.peak == "per-input")
        print(f"information per second of flight (det M^(1/p) / s): {joint:.4g} with the axes in one run"
              f"{' (each input at its own peak response)' if designer.peak == 'per-input' else ''}, "
              f"{separate:.4g} with one run per axis (x{joint / separate:.2f})")
    if args.out:
        save_signals(designer.signals_, args.out)
        print(f"signal written to {args.out}")
    if args.plot:
        # the 3211 at the design's amplitude: side by side, the two show the same deflection
        optimised = designer.signals_[0]
        sigs = [replace(reference[0], amplitude=optimised.amplitude), optimised]
        band = ev.bands[sigs[0].input]
        plot_signals(sigs, args.plot, band=band, labels=["best 3211", "optimised"],
                     unit=model.profile.inputs[optimised.input])
        print(f"plot written to {args.plot} (the best 3211 at the design's amplitude; required band shaded)")
    return 0


def cmd_make(args) -> int:
    band = tuple(_floats(args.band, "--band")) if args.band else None
    if band is not None and len(band) != 2:
        raise SignalError(f"--band needs two frequencies low,high in rad/s, got '{args.band}'")
    if band is None and args.profile and args.kind.lower() == "multisine":
        band = _required_union(LinearModel(load_profile(args.profile)), _inputs(args))
    pulses = [int(v) for v in _floats(args.pulses, "--pulses")] if args.pulses else None
    levels = _floats(args.levels, "--levels") if args.levels else None
    made = make_signal(args.kind, width=args.width, amplitude=args.amplitude, input=args.input,
                       duration=args.duration, band=band, pulses=pulses, levels=levels, order=args.order,
                       dt=args.dt, delay=args.delay, phases=args.phases)
    sigs = made if isinstance(made, list) else [made]
    for sig in sigs:
        lo, hi, peak = half_power_band(sig)
        rpf = sig.params.get("relative_peak_factor")
        extra = (f"; {len(sig.params['harmonics'])} harmonics, {sig.params['phases']} phases, relative peak "
                 f"factor {rpf:.3f}" if rpf is not None else "")
        print(f"{sig.kind} on {sig.input}: {sig.levels.size} steps of {sig.dt:g} s ({sig.duration:g} s), "
              f"amplitude {sig.amplitude:g}; half-power band {lo:.3f}..{hi:.3f} rad/s, peak at {peak:.3f} rad/s"
              + extra)
    save_signals(sigs, args.out)
    print(f"signal written to {args.out}")
    if args.csv:
        run_ = signals_to_run(sigs, args.csv_dt, max(args.record, max(s.end_time for s in sigs)))
        run_.to_csv(args.csv)
        print(f"run-compatible CSV written to {args.csv} (columns: time, {', '.join(s.input for s in sigs)})")
    return 0


def _required_union(model, inputs) -> tuple[float, float]:
    """The band every input needs (``signaldesign band``): lowest low to highest high."""
    bands = [required_band(model, i) for i in inputs]
    unbounded = [b.input for b in bands if not b.bounded]
    if unbounded:
        raise SignalError(f"no required band for {', '.join(unbounded)} on {model.profile.name}; give --band")
    lo, hi = min(b.low for b in bands), max(b.high for b in bands)
    print(f"band from the profile: {lo:.3f}..{hi:.3f} rad/s ("
          + "; ".join(f"{b.input} {b.low:.3f}..{b.high:.3f}" for b in bands) + ")")
    return lo, hi


def cmd_compare(args) -> int:
    model = _model(args)
    sets = [load_signals(path) for path in args.signals]
    names = model.profile.input_names
    inputs = sorted({s.input for sig in sets for s in sig}, key=lambda i: names.index(i) if i in names else len(names))
    args.duration = max(s.duration for sig in sets for s in sig)
    ev = _evaluator(model, inputs, args, args.reference_amplitude)
    ev.set_reference(sets[0])
    scores = [ev.score(sig, str(path)) for sig, path in zip(sets, args.signals)]
    print(f"{model.profile.name}: {args.record:g} s record; "
          + "; ".join(f"required band ({i}) {lo:.3f}..{hi:.3f} rad/s" for i, (lo, hi) in ev.bands.items()))
    print(format_noise(model.profile, ev.noise_std))
    print(f"limits: {ev.limits_source}")
    print(format_scores(scores, args.signals[0]))
    return 0


def cmd_plot(args) -> int:
    signals, labels = [], []
    for path in args.signals:
        for s in load_signals(path):
            signals.append(s)
            labels.append(f"{path}: {s.kind} on {s.input}")
    band, unit = None, "rad"
    if args.profile:
        model = _model(args)
        unit = model.profile.inputs.get(signals[0].input, unit)
        b = required_band(model, signals[0].input)
        if b.bounded:
            band = (b.low, b.high)
        else:
            print(f"no required band for {b.input} (its sensitivities do not fall off within "
                  f"{b.omega[0]:g}..{b.omega[-1]:g} rad/s): none shaded, no coverage scored")
    for s, label in zip(signals, labels):
        lo, hi, peak = half_power_band(s)
        covered = f"; {100 * band_coverage(s, band):.0f}% of the required band inside it" if band else ""
        print(f"{label}: half-power band {lo:.3f}..{hi:.3f} rad/s (peak {peak:.3f} rad/s){covered}")
    plot_signals(signals, args.out, band=band, labels=labels, unit=unit)
    print(f"plot written to {args.out}")
    return 0


def _record_options(p):
    p.add_argument("--record", type=positive_float, default=20.0, help="record length in s (default 20)")
    p.add_argument("--dt", type=positive_float, default=0.05, help="sample interval in s (default 0.05)")
    p.add_argument("--min-pulse", type=positive_float, default=MIN_WIDTH,
                   help=f"shortest hold in s, also the baselines' shortest pulse (default {MIN_WIDTH:g})")
    p.add_argument("--reference-amplitude", type=positive_float, default=0.02,
                   help="without [limits] in the profile, the limits are the best-width 3211's peaks at "
                        "this amplitude (default 0.02)")
    p.add_argument("--seed", type=int, default=0)


def build_parser() -> Parser:
    parser = Parser(prog="signaldesign", description="Design flight-test input signals from an a priori model.")
    sub = parser.add_subparsers(title="commands")

    p = sub.add_parser("band", help="print the frequency band an input must excite")
    p.add_argument("--profile", required=True, help="profile TOML path or bundled profile name")
    p.add_argument("--input", required=True, help="control input (e.g. theta_s)")
    p.add_argument("--level", type=fraction, default=0.5, help="fraction of each sensitivity's peak (default 0.5)")
    p.add_argument("--plot", type=output_file, metavar="PNG", help="draw the sensitivities and the band")
    p.set_defaults(func=cmd_band)

    p = sub.add_parser("design", help="optimise a three-level sequence within the response limits and compare it")
    p.add_argument("--profile", required=True)
    p.add_argument("--input", required=True, help="control input, or several comma-separated for one multi-axis run")
    p.add_argument("--duration", type=positive_float, default=7.0, help="signal length in s (default 7)")
    p.add_argument("--amplitude", type=positive_float,
                   help="fixed amplitude in rad (default: an outcome, the largest within the limits)")
    p.add_argument("--grid", type=positive_float, default=0.1, help="level changes on this grid, s (default 0.1)")
    p.add_argument("--max-changes", type=positive_int, default=12, help="most level changes per axis (default 12)")
    p.add_argument("--no-double-jumps", action="store_true", help="forbid +1 to -1 without a hold at 0")
    p.add_argument("--criterion", choices=CRITERIA, default="robust",
                   help="robust (default): expected plus worst D-efficiency over models around the a priori "
                        "(each against the 3211 tuned on it), at least 1.22x the best tuned 3211/doublet on "
                        "the a priori; mean: expected log det only; worst: worst D-efficiency only; "
                        "nominal: the a priori only")
    p.add_argument("--with-prior", action="store_true",
                   help="maximise what the flight adds to the profile's [prior]: log det of the prior's "
                        "information plus the flight's (criterion nominal or mean)")
    p.add_argument("--prior-relative", type=positive_float, metavar="PCT",
                   help="--with-prior with every free parameter's a priori value a prior of std PCT %% "
                        "(identify's --prior-relative)")
    p.add_argument("--jobs", type=positive_int, metavar="N",
                   help="worker processes for the search's restarts (default: the available CPUs, at most "
                        "the restarts); the design is the same for any N")
    p.add_argument("--peak", choices=PEAKS, default="shared",
                   help="several inputs: shared (default: the run's whole response within the limits) or "
                        "per-input (each input as large as its own response, alone, allows, as in a run of its "
                        "own; the responses add)")
    p.add_argument("--certify", choices=("full", "quick"), default="full",
                   help="the certificate's upper bound: full (default; the semidefinite relaxation solved to "
                        "within a few log det units, about 10-40 s per model) or quick (valid, looser, seconds)")
    p.add_argument("--out", type=output_file, metavar="JSON", help="write the optimised signal here")
    p.add_argument("--plot", type=output_file, metavar="PNG", help="draw it against the best 3211 with spectra and the band")
    _record_options(p)
    p.set_defaults(func=cmd_design)

    p = sub.add_parser("make", help="write a baseline signal (doublet, 3211, multistep, steps, multisine, prts)")
    p.add_argument("kind", help="doublet, 3211 (or any digits, e.g. 2121), multistep, steps, multisine, prts")
    p.add_argument("--width", type=positive_float, help="pulse / step width in s")
    p.add_argument("--amplitude", type=positive_float, default=0.02, help="amplitude in rad (default 0.02)")
    p.add_argument("--input", default="theta_s",
                   help="control input (default theta_s); a multisine takes several, comma-separated: orthogonal "
                        "multisines with interleaved harmonics, one column each in --csv")
    p.add_argument("--duration", type=positive_float, default=7.0, help="multisine / PRTS length in s (default 7)")
    p.add_argument("--band", help="multisine band low,high in rad/s (default with --profile: the band the "
                                  "inputs need, as `signaldesign band` prints it)")
    p.add_argument("--phases", choices=PHASES, default="optimised",
                   help="multisine phases: optimised (default; Schroeder's, then optimised for a small relative "
                        "peak factor) or schroeder")
    p.add_argument("--profile", help="profile for the multisine's default band")
    p.add_argument("--pulses", help="multistep pulse counts, e.g. 3,2,1,1")
    p.add_argument("--levels", help="step levels, e.g. 1,1,0,-1,0")
    p.add_argument("--order", type=positive_int, default=3, help="PRTS order (period 3^order - 1, default 3)")
    p.add_argument("--dt", type=positive_float, default=0.05, help="multisine time step in s (default 0.05)")
    p.add_argument("--delay", type=nonnegative_float, default=0.0, help="start time in s (default 0)")
    p.add_argument("--out", type=output_file, required=True, metavar="JSON")
    p.add_argument("--csv", type=output_file, metavar="CSV", help="also write a run-compatible CSV of the input")
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
    p.add_argument("--out", type=output_file, default="signals.png", metavar="PNG", help="output PNG (default signals.png)")
    p.add_argument("--profile", help="shade the required band of this profile")
    p.set_defaults(func=cmd_plot)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)

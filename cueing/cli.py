"""``python -m cueing``: fly signals on the two-needle display (optionally with the live estimate),
practise, and recover a run from its frame log."""
from __future__ import annotations

import os
import sys
from pathlib import Path

from identify.cliutil import (Parser, add_threads_option, fraction, nonnegative_float, output_dir, output_file,
                               positive_float, positive_int, run)

from .errors import CueingError, RunAborted

DEFAULT_LEAD_IN = 2.0  # s of quiet logged before the signal: the trim the response starts from
UNATTENDED = ("pilot", "replay", "external")  # sources that need no human: may run on a fake clock
EXIT_ABORTED = 3  # the pilot ended the run early (Escape, closed window): data kept, marked aborted


def cmd_align(args) -> int:
    from identify.data.io import load_channel_map, read_run_file

    from .align import find_offset, merge
    display = read_run_file(args.display)
    recording = read_run_file(args.recording, load_channel_map(args.channel_map) if args.channel_map else None)
    found = find_offset(display, recording, args.channel, args.max_offset)
    print(f"clock offset: recording time = display time {found.offset:+.3f} s "
          f"(cross-correlation of {found.channel}: peak {found.correlation:.3f})")
    if found.doubtful:
        print(f"cueing: warning: the correlation peak {found.correlation:.3f} is weak: check that both files "
              f"hold the same {found.channel} and overlap", file=sys.stderr)
    merged = merge(display, recording, found)
    merged.to_csv(args.out)
    print(f"merged run ({merged.duration:.2f} s, {len(merged)} samples, channels "
          f"{', '.join(merged.channels)}) written to {args.out}")
    return 0


def _signals(path):
    from signaldesign.signal import load_signals
    signals = load_signals(path)
    inputs = [s.input for s in signals]
    dup = sorted({i for i in inputs if inputs.count(i) > 1})
    if dup:
        raise CueingError(f"{path}: several signals on input {', '.join(dup)}: one signal per control axis")
    return signals


def _fly_options(args) -> dict:
    if args.headless:
        os.environ["SDL_VIDEODRIVER"] = "dummy"  # off-screen even where a display exists
    if args.rate <= 0 or min(args.countdown, args.tail, args.preview, args.lead_in) < 0:
        raise CueingError("--rate must be positive; --countdown, --lead-in, --tail and --preview must not be "
                          "negative")
    if args.record is not None and not args.record > 0:
        raise CueingError(f"--record must be a positive number of seconds, got {args.record:g}")
    if not 0 <= args.skill <= 1:
        raise CueingError(f"--skill must be between 0 and 1, got {args.skill:g}")
    if args.noise < 0 or (args.screenshot_every is not None and args.screenshot_every <= 0):
        raise CueingError("--noise must not be negative and --screenshot-every must be positive")
    if args.fast and args.source.partition(":")[0] not in UNATTENDED:
        raise CueingError(f"--fast needs a source that flies itself ({', '.join(UNATTENDED)}), "
                          f"not '{args.source}'")
    model = None
    if args.profile:
        from identify import LinearModel, load_profile
        model = LinearModel(load_profile(args.profile))
    aircraft = _aircraft(args)
    if aircraft is not None and model is None and args.simulate:
        from .response import aircraft_model
        model = aircraft_model(args.simulate)  # the a priori scores the flight, not the truth
    return dict(simulate=aircraft, noise_fraction=args.noise, seed=args.seed, model=model, fast=args.fast,
                rate=args.rate, countdown=args.countdown, lead_in=args.lead_in, record=args.record, tail=args.tail,
                preview=args.preview, display="headless" if args.headless else "window",
                fullscreen=args.fullscreen, audio=not args.no_audio,
                screenshot_dir=args.screenshots, screenshot_every=args.screenshot_every,
                end_screen=0.0 if args.headless else 5.0)


def _check_amplitudes(signals, model) -> None:
    """Say (stderr) when a signal's amplitude is implausible for a test input on that control."""
    if model is None:
        return
    from signaldesign.design import implausible_amplitudes
    for s in signals:
        for line in implausible_amplitudes(model.profile, [s.input], [s.amplitude]):
            print(f"cueing: warning: {line}", file=sys.stderr)


def _aircraft(args):
    """The aircraft that responds to the stick: ``--truth`` (else ``--simulate``), with every free
    derivative scaled by its own factor in 1 -/+ ``--perturb`` (seeded by ``--seed``) when given;
    a perturbed aircraft's profile is written beside the run (``<out>.truth.toml``) and said."""
    base = getattr(args, "truth", None) or args.simulate
    spread = getattr(args, "perturb", None)
    if base is None:
        if spread:
            raise CueingError("--perturb needs the aircraft to perturb: --simulate PROFILE or --truth PROFILE")
        return None
    if not spread:
        return base
    import numpy as np

    from identify import perturbed_model

    from .response import aircraft_model
    if not 0 < spread < 1:
        raise CueingError(f"--perturb must be a fraction in (0, 1), got {spread:g}")
    model = aircraft_model(base)
    truth = perturbed_model(model, spread, np.random.default_rng(args.seed))
    truth_profile = truth.to_profile(f"{model.profile.name} - perturbed by up to {100 * spread:g} % (seed {args.seed})")
    out = getattr(args, "out", None)
    if out:
        path = Path(out).with_suffix(".truth.toml")
        truth_profile.save(path)
        print(f"flying a perturbed aircraft (every derivative x U(1 -/+ {spread:g}), seed {args.seed}): "
              f"its profile is {path}")
    return truth


def _source(args, skill: float, seed):
    from .sources import Calibration, make_source
    try:
        axes = [int(a) for a in args.axes.split(",")]
    except ValueError:
        raise CueingError(f"--axes: comma-separated joystick axis numbers, got '{args.axes}'") from None
    if not 0 <= args.dead_zone < 1 or (args.full_scale is not None and args.full_scale <= 0):
        raise CueingError("--dead-zone must be within 0..1 and --full-scale positive")
    cal = Calibration(dead_zone=args.dead_zone, full_scale=args.full_scale, invert=args.invert)
    return make_source(args.source, skill=skill, seed=seed, device=args.device, calibration=cal, axes=axes,
                       rest_seconds=args.calibrate)


def cmd_fly(args) -> int:
    from .session import fly
    signals = _signals(args.signal)
    options = _fly_options(args)
    _check_amplitudes(signals, options["model"])
    source = _source(args, args.skill, args.seed)
    try:
        if args.live:
            return _aborted(_fly_live(args, signals, options, source))
        flight = fly(signals, source, args.out, pilot=args.pilot or "", **options)
    except RunAborted as exc:
        return _aborted(exc)
    print("\n".join(flight.score.lines()[1:]))
    runner = flight.runner
    print(f"run written to {flight.path} ({flight.log.status}; {flight.run.duration:.2f} s: {runner.lead_in:g} s "
          f"lead-in, then the signal's {runner.t_end - runner.lead_in:g} s record); frame log {flight.log.path}")
    return _aborted(flight)


def _fly_live(args, signals, options: dict, source):
    """``cueing fly --live PROFILE``: fly with the live estimate, print it beside ML; the flight."""
    import numpy as np

    from .live.session import fly_live, report_path
    from .response import ExternalResponse
    opts = dict(options)
    simulate, noise, seed = opts.pop("simulate"), opts.pop("noise_fraction"), opts.pop("seed")
    response = ExternalResponse(args.live_response) if args.live_response else None
    flight, live, _ = fly_live(signals, source, args.out, args.live, simulate=simulate, response=response,
                               targets=args.targets, noise_fraction=noise, seed=seed, pilot=args.pilot or "", **opts)
    print("\n".join(flight.score.lines()[1:]))
    report = report_path(args.out)
    print(report.read_text() if report.exists() else "no live estimate (the run ended before the first re-solve)")
    times = np.array(live.times_) * 1e3
    if times.size:
        print(f"live work per frame: median {np.median(times):.2f} ms, 99th percentile {np.percentile(times, 99):.2f} ms")
    print(f"run written to {flight.path} ({flight.log.status}); frame log {flight.log.path}; live log {live.log_path}")
    return flight


def _aborted(flight) -> int:
    """Exit status of a flown run (a Flight, or the RunAborted of one that wrote nothing): 0, or
    EXIT_ABORTED with one line when the pilot ended it early."""
    if isinstance(flight, RunAborted):
        print(f"cueing: {flight}", file=sys.stderr)
    elif flight.log.aborted:
        print(f"cueing: run {flight.log.status}: the data up to then is kept in {flight.path}", file=sys.stderr)
    else:
        return 0
    return EXIT_ABORTED


def cmd_practice(args) -> int:
    from .history import append_attempt, format_history, history_path, load_history
    from .session import fly
    signals = _signals(args.signal)
    options = _fly_options(args)
    if args.attempts < 1 or not 0 <= args.learn <= 1:
        raise CueingError(f"--attempts must be at least 1 and --learn within 0..1")
    history_path(args.pilot, args.history_dir)  # a bad pilot name fails before anything is flown
    out_dir = Path(args.out_dir)
    first = None
    for i in range(args.attempts):
        skill = 1 - (1 - args.skill) * (1 - args.learn) ** i  # the simulated pilot learns towards 1
        source = _source(args, skill, None if args.seed is None else args.seed + i)
        opts = dict(options, seed=None if args.seed is None else args.seed + i)
        try:
            flight = fly(signals, source, out_dir / f"{args.pilot}_attempt{i + 1:02d}.csv", pilot=args.pilot,
                         **opts)
        except RunAborted as exc:
            flight = exc
            break
        record = {k: v for k, v in flight.score.to_dict().items() if k != "per_axis"}
        record.update(signal=flight.run.meta.get("signal", ""), source=source.describe(), run=str(flight.path),
                      status=flight.log.status)
        append_attempt(args.pilot, record, args.history_dir)
        first = first if first is not None else len(load_history(args.pilot, args.history_dir)) - 1
        if flight.log.aborted:  # the pilot stopped: no more attempts
            break
    if first is not None:  # at least one attempt was recorded
        print(format_history(load_history(args.pilot, args.history_dir)[first:]))
    return _aborted(flight)


def cmd_history(args) -> int:
    from .history import format_history, load_history, plot_learning_curve
    records = load_history(args.pilot, args.history_dir)
    print(format_history(records))
    path = plot_learning_curve(args.pilot, records, args.plot or f"{args.pilot}_learning_curve.png")
    print(f"learning curve written to {path}")
    return 0


def cmd_recover(args) -> int:
    from .flightlog import log_to_run, read_frame_log
    from .response import simulate_test_point
    log = read_frame_log(args.log)
    run_ = log_to_run(log)
    if args.simulate:
        run_ = simulate_test_point(run_, args.simulate, args.noise, args.seed)
    run_.to_csv(args.out)
    print(f"{log.status}: {len(run_)} samples ({run_.duration:.2f} s) written to {args.out}")
    return 0


def _add_fly_arguments(p) -> None:
    p.add_argument("--signal", required=True, help="signal JSON file (as signaldesign writes it)")
    p.add_argument("--source", default="mouse",
                   help="joystick, mouse, keyboard, pilot (simulated), replay:RUN.csv or external:MODULE:FUNCTION "
                        "(default: mouse)")
    p.add_argument("--preview", type=nonnegative_float, nargs="?", const=3.0, default=0.0, metavar="SECONDS",
                   help="show the next SECONDS of the sequence (default 3 when given)")
    p.add_argument("--headless", action="store_true", help="off-screen display (no window)")
    p.add_argument("--fullscreen", action="store_true", help="fill the screen (the window is resizable otherwise)")
    p.add_argument("--simulate", metavar="PROFILE", help="drive this profile's model with the flown input "
                   "(with every effect it declares: delays, pseudo-inputs)")
    p.add_argument("--truth", metavar="PROFILE", help="the aircraft that responds, when it is not --simulate's "
                   "(the a priori: --simulate or --profile, which scores the flight)")
    p.add_argument("--perturb", type=positive_float, metavar="FRACTION",
                   help="fly an aircraft off the a priori: every derivative of --truth/--simulate scaled by its "
                        "own factor in 1 -/+ FRACTION (--seed; its profile written to <out>.truth.toml)")
    p.add_argument("--noise", type=nonnegative_float, default=0.02, help="measurement noise fraction for --simulate (0.02)")
    p.add_argument("--profile", metavar="PROFILE", help="model for the information score (default: --simulate's)")
    p.add_argument("--seed", type=int, default=None, help="random seed (simulated pilot, noise)")
    p.add_argument("--skill", type=fraction, default=0.5, help="simulated pilot's skill, 0..1 (0.5)")
    p.add_argument("--pilot", help="pilot name (metadata, practice history)")
    p.add_argument("--device", type=int, default=0, help="joystick device index (0)")
    p.add_argument("--axes", default="1,0", help="joystick axis per signal axis (1,0: fore-aft, then lateral)")
    p.add_argument("--dead-zone", type=fraction, default=0.05, help="joystick dead zone, fraction of travel (0.05)")
    p.add_argument("--full-scale", type=positive_float, help="control units at full stick (default 1.5 x amplitude)")
    p.add_argument("--invert", action="store_true", help="reverse the joystick axes")
    p.add_argument("--calibrate", type=nonnegative_float, default=0.0, metavar="S",
                   help="measure the stick's centre and dead zone at rest for S seconds first")
    p.add_argument("--rate", type=positive_float, default=60.0, help="frame rate in Hz (60)")
    p.add_argument("--countdown", type=nonnegative_float, default=3.0, help="seconds of countdown before logging starts (3)")
    p.add_argument("--lead-in", type=nonnegative_float, default=DEFAULT_LEAD_IN, metavar="S",
                   help=f"seconds logged, quiet, before the signal starts ({DEFAULT_LEAD_IN:g})")
    p.add_argument("--record", type=positive_float, metavar="S",
                   help="seconds logged from the signal's start (default: the record it was designed for)")
    p.add_argument("--tail", type=nonnegative_float, default=1.0,
                   help="seconds logged at least after the sequence (1), when the record is shorter")
    p.add_argument("--no-audio", action="store_true", help="no ticks at level changes")
    p.add_argument("--screenshots", type=output_dir, metavar="DIR", help="save PNG screenshots here")
    p.add_argument("--screenshot-every", type=positive_float, metavar="S", help="seconds between screenshots")
    p.add_argument("--fast", action="store_true", help="no waiting (fake clock): simulated or replayed sources only")


def build_parser() -> Parser:
    parser = Parser(prog="cueing", description="Two-needle pilot cueing display for flight-test inputs.")
    sub = parser.add_subparsers(title="commands")
    p = sub.add_parser("fly", help="fly one run on the two-needle display",
                       description="Fly one run on the two-needle display. Escape or closing the window ends it "
                                   f"early: the data so far is kept, marked aborted, exit status {EXIT_ABORTED}.")
    _add_fly_arguments(p)
    p.add_argument("--out", required=True, type=output_file, help="run file to write (the frame log grows beside it)")
    p.add_argument("--live", metavar="PROFILE", help="identify this profile while flying (recursive "
                   "frequency-domain equation error; response from --simulate or --live-response)")
    p.add_argument("--targets", metavar="LIST", help="--live: parameters and Cramér-Rao %% targets, e.g. "
                   "M_q:10,L_p:15 (default: each moment equation's damping and control derivative at 20 %%)")
    p.add_argument("--live-response", metavar="MODULE:FUNCTION",
                   help="--live: f(t, stick) -> measured states, e.g. from a flight simulator")
    p.set_defaults(func=cmd_fly)

    p = sub.add_parser("practice", help="fly a signal several times, score each attempt, keep the history")
    _add_fly_arguments(p)
    p.add_argument("--attempts", type=positive_int, default=3, help="number of attempts (3)")
    p.add_argument("--learn", type=fraction, default=0.3,
                   help="simulated pilot: fraction of the remaining skill gap closed per attempt (0.3)")
    p.add_argument("--history-dir", help="practice history folder (default $PSEUDOSTEP_HISTORY or ~/.pseudostep/practice)")
    p.add_argument("--out-dir", type=output_dir, default="practice", help="folder for the attempts' run files (practice)")
    p.set_defaults(func=cmd_practice)

    p = sub.add_parser("history", help="show a pilot's learning curve")
    p.add_argument("pilot", help="pilot name")
    p.add_argument("--history-dir", help="practice history folder")
    p.add_argument("--plot", type=output_file, metavar="PNG", help="learning-curve image (default PILOT_learning_curve.png)")
    p.set_defaults(func=cmd_history)

    p = sub.add_parser("recover", help="turn a frame log (also of a killed run) into a run file")
    p.add_argument("log", help="frame log (*.frames.csv)")
    p.add_argument("--out", required=True, type=output_file, help="run file to write")
    p.add_argument("--simulate", metavar="PROFILE", help="add this profile's simulated response")
    p.add_argument("--noise", type=nonnegative_float, default=0.02)
    p.add_argument("--seed", type=int, default=None)
    p.set_defaults(func=cmd_recover)
    p = sub.add_parser("align", help="put the display's run file and a separate recording on one clock")
    p.add_argument("display", help="the display's run file (cueing fly --out)")
    p.add_argument("recording", help="the aircraft's recording (.csv or .mat) holding the same control input")
    p.add_argument("--channel", required=True, help="control input both files hold (the offset is found on it)")
    p.add_argument("--channel-map", metavar="JSON", help="channel map of the recording (file or inline JSON)")
    p.add_argument("--max-offset", type=positive_float, metavar="S", help="search offsets up to S seconds only")
    p.add_argument("--out", required=True, type=output_file, help="merged run file to write")
    p.set_defaults(func=cmd_align)
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)

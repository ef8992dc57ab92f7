"""``identify hq`` and ``identify loes``: handling qualities of runs or of a model; a
transfer function with an equivalent delay fitted to one response."""
from __future__ import annotations

import sys

from ..cliutil import nonnegative_int, output_dir, positive_float, positive_int
from ..errors import EstimationError
from . import options


def cmd_hq(args) -> int:
    """ADS-33 bandwidth and phase delay, the chart, short-period LOES: of runs or of a model."""
    from ..estimators.frequency.hq import aircraft_of, hq_of_model, hq_of_response
    from ..model.linear import LinearModel
    from ..model.profile import load_profile

    profile = load_profile(args.profile)
    aircraft = aircraft_of(profile.input_names, profile.meta, args.aircraft_class, args.phase, args.category)
    grading = dict(task=args.task, pitch=args.pitch, roll=args.roll, n_alpha=args.n_alpha, aircraft=aircraft)
    if args.boundaries:
        from ..estimators.frequency.handling import load_boundaries

        try:
            grading["boundaries"] = load_boundaries(args.boundaries)  # checked even where not used
        except ValueError as exc:
            raise EstimationError(str(exc)) from None
        if not aircraft.ads33:
            print(f"note: --boundaries not used: ADS-33's charts grade a rotorcraft in hover and low speed, not "
                  f"this aircraft ({aircraft.line()})", file=sys.stderr)
    if args.runs:
        from ..estimators.frequency.response import frequency_response

        runs = options.reading(args).recorded(args.runs, profile)
        fr = frequency_response(runs, profile.input_names, list(profile.outputs), n_freq=args.n_freq)
        report = hq_of_response(fr, **grading)
        model = hq_of_model(LinearModel(profile), **grading) if args.with_model else None
    else:
        report, model = hq_of_model(LinearModel(profile), **grading), None
    print("\n".join(report.lines() + (["model:"] + model.lines() if model else [])), flush=True)
    paths = report.save(args.out, model)
    print(f"written to {args.out}: {', '.join(p.name for p in paths)}")
    return 0


def cmd_loes(args) -> int:
    """A transfer function (chosen orders, equivalent delay, bounds) fitted to one measured response."""
    from pathlib import Path

    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from ..estimators.frequency.hq import aircraft_of
    from ..estimators.frequency.loes import fit_transfer_function, plot_fit, short_period
    from ..estimators.frequency.response import frequency_response
    from ..model.profile import load_profile

    profile = load_profile(args.profile)
    output, _, input_ = args.pair.partition("/")
    if output not in profile.outputs or input_ not in profile.input_names:
        raise EstimationError(f"--pair {args.pair}: give OUTPUT/INPUT of the profile (outputs "
                              f"{', '.join(profile.outputs)}; inputs {', '.join(profile.input_names)})")
    runs = options.reading(args).recorded(args.runs, profile)
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
        aircraft = aircraft_of(profile.input_names, profile.meta, args.aircraft_class, args.phase, args.category)
        text += short_period(fit, aircraft.category, args.n_alpha).lines() + [f"note: {n}" for n in aircraft.notes]
    print("\n".join(text), flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "loes.md").write_text("```\n" + "\n".join(text) + "\n```\n")
    fig = plot_fit(fr.omega, fr.H[:, j, i], coh, fit, f"{args.pair}: transfer-function fit")
    FigureCanvasAgg(fig)
    fig.savefig(out / "loes.png", dpi=90)
    print(f"written to {out}: loes.md, loes.png")
    return 0


def add_parser(sub) -> None:
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
    """Options hq and loes share: the aircraft graded, the LOES level's category and n/alpha, the
    response grid, how the runs are read."""
    p.add_argument("--aircraft-class", choices=("rotorcraft", "fixed-wing"), help="what is graded: ADS-33 bandwidth charts for a rotorcraft "
                   "in hover and low speed only (default: the profile's [meta] aircraft_class, else guessed from the "
                   "control names, said)")
    p.add_argument("--phase", metavar="PHASE", help="flight phase: hover, low-speed, forward (rotorcraft); tracking, "
                   "combat (category A), climb, cruise, loiter, descent (B), takeoff, approach, landing (C) (fixed wing); "
                   "default: the profile's [meta] flight_phase; a rotorcraft: hover")
    p.add_argument("--category", choices=("A", "B", "C"), help="MIL-STD-1797A flight-phase category (default: the "
                   "phase's, else A)")
    p.add_argument("--n-alpha", type=positive_float, metavar="G_PER_RAD", help="normal load factor per angle of "
                   "attack (g/rad): grades the short period's CAP = omega_sp^2/(n/alpha) and frequency minimum "
                   "(without it omega_sp is not graded)")
    p.add_argument("--n-freq", type=positive_int, default=120, help="frequencies of the response grid")
    options.add_reading(p)

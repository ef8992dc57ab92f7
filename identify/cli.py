"""``python -m identify``: inspect models and identify them from runs."""
from __future__ import annotations

from .cliutil import (Parser, add_threads_option, finite_float, fraction, nonnegative_float, nonnegative_int,
                      output_dir, output_file, positive_float, positive_int, run)
from .errors import EstimationError
from .model import LinearModel, format_modes, residualize
from .profile import load_profile


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
    print("\nmodes:")
    print(format_modes(model.modes()))


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
    for p in sub.choices.values():
        add_threads_option(p)
    return parser


def cmd_estimate(args) -> int:
    """Identify a profile's free parameters from runs; write result.json, the profile and plots."""
    import sys

    from .matfile import load_channel_map, read_run_file
    from .plots import save_plots
    from .preprocess import slice_run, smooth

    if args.max_iter is not None and args.method == "ls":
        raise EstimationError("--max-iter applies to the iterative methods (iv, ml); ls is one solution")
    profile = load_profile(args.profile)
    cmap = load_channel_map(args.channel_map) if args.channel_map else None
    runs = []
    for path in args.runs:
        r = read_run_file(path, cmap)
        if args.smooth is not None:  # every channel alike, inputs included: keeps the equations consistent
            r = smooth(r, args.smooth)
        if args.t_start is not None or args.t_end is not None:
            r = slice_run(r, args.t_start, args.t_end)
        runs.append(r)

    def show(it, value, theta, what="max rel. change" if args.method == "iv" else "cost"):
        print(f"{args.method.upper()} iteration {it}: {what} {value:.4g}", file=sys.stderr, flush=True)

    iterations = {} if args.max_iter is None else {"max_iter": args.max_iter}
    if args.method == "ml":
        from .ml import ML
        est = ML(profile, progress=show, **iterations)
    elif args.method == "iv":
        from .equation_error import IV
        est = IV(profile, progress=show, diff_cutoff_hz=args.diff_cutoff, **iterations)
    else:
        from .equation_error import LS
        est = LS(profile, diff_cutoff_hz=args.diff_cutoff)
    result = est.fit(runs).result_
    print(result.summary(), flush=True)  # on screen before anything is written
    out = result.save(args.out)
    plots = save_plots(result, out)
    print(f"\nwritten to {out}: result.json, identified_profile.toml, {', '.join(p.name for p in plots)}")
    return 0


def _add_estimate_parser(sub) -> None:
    p = sub.add_parser("estimate", help="identify a profile's parameters from runs (LS, IV or ML)")
    p.add_argument("runs", nargs="+", help="run files (.csv, or .mat with --channel-map)")
    p.add_argument("--profile", required=True, help="a priori profile TOML path or bundled profile name")
    p.add_argument("--method", choices=("ls", "iv", "ml"), default="iv", help="estimator (default iv)")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
    p.add_argument("--smooth", type=positive_float, metavar="HZ", help="zero-phase low-pass cut-off for every channel")
    p.add_argument("--diff-cutoff", type=positive_float, metavar="HZ",
                   help="cut-off of the smoothed differentiator for states without measured derivatives")
    p.add_argument("--t-start", type=finite_float, metavar="S", help="use samples from this time on")
    p.add_argument("--t-end", type=finite_float, metavar="S", help="use samples up to this time")
    p.add_argument("--max-iter", type=positive_int, metavar="N",
                   help="iterations at most for iv (default 30) and ml (default 50)")
    p.add_argument("--channel-map", metavar="JSON",
                   help='for .mat runs: {"channels": {channel: variable or column}, "time": ..., '
                        '"matrix": ..., "dt": ...} as a file or inline JSON')
    p.set_defaults(func=cmd_estimate)


def cmd_refine(args) -> int:
    """Fit, find what the residuals say the model lacks, add it, re-identify; write the evidence."""
    from .candidates import KINDS
    from .refine import Refine
    from .refine_report import write
    from .runs import read_run

    kinds = KINDS if args.kinds is None else tuple(k.strip() for k in args.kinds.split(",") if k.strip())
    if not kinds:
        raise EstimationError(f"--kinds names no effect kind (catalogue: {', '.join(KINDS)})")
    refiner = Refine(args.profile, method=args.method, alpha=args.alpha, kinds=kinds, max_steps=args.max_steps,
                     zero_shifts=not args.no_zero_shifts, frequencies=args.frequency, f_min=args.f_min,
                     tau_max=args.tau_max)
    refiner.fit([read_run(f) for f in args.runs], validate=[read_run(f) for f in args.validate or []])
    if refiner.nothing_found:
        print("nothing found: no candidate effect is significant")
    for i, s in enumerate(refiner.steps_, start=1):
        params = ", ".join(f"{k} = {v['value']:.5g} ± {v['std']:.2g}" for k, v in s.parameters.items())
        print(f"step {i}: {s.effect} on {s.target}: {params} (score {s.statistic:.4g} > {s.threshold:.4g})")
    for s in refiner.rejected_:
        print(f"rejected: {s.effect} on {s.target}: {s.reason}")
    for where in refiner.error_before_:
        print(f"{where} error (overall): {refiner.error_before_[where]['overall']:.4g} -> "
              f"{refiner.error_after_[where]['overall']:.4g}", flush=True)
    out = write(refiner, args.out)  # after the screen output: a failing write loses nothing shown
    print(f"written to {out}: refine.json, report.md, final_profile.toml")
    return 0


def _add_refine_parser(sub) -> None:
    p = sub.add_parser("refine", help="find unmodelled effects in the residuals, add them, re-identify")
    p.add_argument("runs", nargs="+", help="run files (.csv) to fit")
    p.add_argument("--profile", required=True, help="a priori profile TOML path or bundled profile name")
    p.add_argument("--method", choices=("ml", "ls", "iv"), default="ml", help="estimator (default ml)")
    p.add_argument("--validate", nargs="+", metavar="RUN", help="held-out runs every added effect is checked on")
    p.add_argument("--out", required=True, metavar="DIR", type=output_dir, help="output folder")
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


def main(argv=None) -> int:
    return run(build_parser(), argv)

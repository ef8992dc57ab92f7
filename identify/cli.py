"""``python -m identify``: inspect models and identify them from runs."""
from __future__ import annotations

from .cliutil import Parser, run
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
    print("\nmodes:")
    print(format_modes(model.modes()))


def build_parser() -> Parser:
    parser = Parser(prog="identify", description="Identify linear aircraft models from flight-test runs.")
    sub = parser.add_subparsers(title="commands")
    p = sub.add_parser("model", help="print a profile's modes (frequency, damping)")
    p.add_argument("profile", help="profile TOML path or bundled profile name")
    p.add_argument("--reduce", metavar="STATES", help="comma-separated states to make instantaneous")
    p.add_argument("--save-reduced", metavar="TOML", help="write the reduced profile here")
    p.set_defaults(func=cmd_model)
    _add_estimate_parser(sub)
    return parser


def cmd_estimate(args) -> int:
    """Identify a profile's free parameters from runs; write result.json, the profile and plots."""
    import sys

    from .matfile import load_channel_map, read_run_file
    from .plots import save_plots
    from .preprocess import slice_run, smooth

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

    if args.method == "ml":
        from .ml import ML
        est = ML(profile, progress=show)
    elif args.method == "iv":
        from .equation_error import IV
        est = IV(profile, progress=show, diff_cutoff_hz=args.diff_cutoff, max_iter=args.max_iter)
    else:
        from .equation_error import LS
        est = LS(profile, diff_cutoff_hz=args.diff_cutoff)
    result = est.fit(runs).result_
    print(result.summary())
    out = result.save(args.out)
    plots = save_plots(result, out)
    print(f"\nwritten to {out}: result.json, identified_profile.toml, {', '.join(p.name for p in plots)}")
    return 0


def _add_estimate_parser(sub) -> None:
    p = sub.add_parser("estimate", help="identify a profile's parameters from runs (LS, IV or ML)")
    p.add_argument("runs", nargs="+", help="run files (.csv, or .mat with --channel-map)")
    p.add_argument("--profile", required=True, help="a priori profile TOML path or bundled profile name")
    p.add_argument("--method", choices=("ls", "iv", "ml"), default="iv", help="estimator (default iv)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--smooth", type=float, metavar="HZ", help="zero-phase low-pass cut-off for every channel")
    p.add_argument("--diff-cutoff", type=float, metavar="HZ",
                   help="cut-off of the smoothed differentiator for states without measured derivatives")
    p.add_argument("--t-start", type=float, metavar="S", help="use samples from this time on")
    p.add_argument("--t-end", type=float, metavar="S", help="use samples up to this time")
    p.add_argument("--max-iter", type=int, default=30, help="IV iterations at most (default 30)")
    p.add_argument("--channel-map", metavar="JSON",
                   help='for .mat runs: {"channels": {channel: variable or column}, "time": ..., '
                        '"matrix": ..., "dt": ...} as a file or inline JSON')
    p.set_defaults(func=cmd_estimate)


def main(argv=None) -> int:
    return run(build_parser(), argv)

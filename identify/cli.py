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
    return parser


def main(argv=None) -> int:
    return run(build_parser(), argv)

"""``identify model``: a profile's parameters, declared effects and modes; its residualised reduction."""
from __future__ import annotations

from ..cliutil import output_file


def add_parser(sub) -> None:
    p = sub.add_parser("model", help="print a profile's modes (frequency, damping)")
    p.add_argument("profile", help="profile TOML path or bundled profile name")
    p.add_argument("--reduce", metavar="STATES", help="comma-separated states to make instantaneous")
    p.add_argument("--save-reduced", metavar="TOML", type=output_file, help="write the reduced profile here")
    p.add_argument("--at", metavar="NAME=VALUE", help="a scheduled profile (campaign stitch) at this condition")
    p.set_defaults(func=cmd_model)


def cmd_model(args) -> int:
    """Print a profile's parameters and modes; optionally its residualised reduction."""
    from ..model.linear import LinearModel, residualize
    from ..model.profile import load_profile

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
    from ..errors import ProfileError
    from ..model.schedule import at_condition, parse_condition, schedule_of

    name, value = parse_condition(text)
    schedule = schedule_of(profile)
    if schedule is None:
        raise ProfileError(f"{profile.source}: --at needs a scheduled profile ([meta.schedule]); this one has none")
    if name != schedule["condition"]:
        raise ProfileError(f"{profile.source}: scheduled over '{schedule['condition']}', not '{name}'")
    return at_condition(profile, value)


def _print_model(model) -> None:
    from ..model.linear import format_modes

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
    from ..model.pseudo_inputs import specs
    lines = [f"delay on {name}: {float(tau):g} s (the aircraft sees {name}(t - {float(tau):g}))"
             for name, tau in dict(p.meta.get("delays", {})).items()]
    for name, spec in specs(p).items():
        lines.append(f"pseudo-input {name}: " + ", ".join(f"{k} = {v}" for k, v in spec.items()))
    return lines

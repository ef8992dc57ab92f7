"""What the live estimate is flown for: the parameters it can estimate and their Cramér-Rao targets."""
from __future__ import annotations

from dataclasses import replace

from identify import Profile

from ..errors import CueingError

DEFAULT_TARGET = 20.0  # %: Tischler's guideline for a Cramér-Rao bound worth keeping


def flown_profile(profile: Profile, flown_inputs: list[str]) -> tuple[Profile, list[str]]:
    """The profile with the derivatives of inputs nobody flies fixed at their a priori values
    (their regressors are zero: no data can estimate them); returns it and the names fixed."""
    still = [i for i in profile.input_names if i not in flown_inputs]
    fixed = [name for name in profile.free
             if all(e.matrix == "B" and profile.input_names[e.col] in still
                    for e, _ in profile.parameter_entries(name))]
    if not fixed:
        return profile, []
    return replace(profile, free={k: v for k, v in profile.free.items() if k not in fixed},
                   fixed={**profile.fixed, **{k: profile.free[k] for k in fixed}}), fixed


def primary_derivatives(profile: Profile) -> list[str]:
    """Per moment equation (L, M, N): its largest a priori rate derivative (the damping, ``M_q``)
    and its largest control derivative (the control power, ``M_theta_s``): what a handling-qualities
    test point is flown for. Falls back to every free parameter for a profile without them."""
    rates = {"p", "q", "r"} & set(profile.states)
    picks = []
    for state in sorted(rates):
        eq = profile.state_names.index(state)
        for matrix, wanted in (("A", lambda c: profile.state_names[c] in rates), ("B", lambda c: True)):
            cands = [n for n in profile.free
                     if [(e.matrix, e.row) for e, _ in profile.parameter_entries(n)] == [(matrix, eq)]
                     and wanted(profile.parameter_entries(n)[0][0].col)]
            if cands:
                picks.append(max(cands, key=lambda n: abs(profile.free[n])))
    return picks or list(profile.free)


def parse_targets(spec: str | None, profile: Profile) -> dict[str, float]:
    """``"M_q:10,L_p"`` -> {name: target %} (DEFAULT_TARGET where none given); default: the
    primary damping and control derivatives (:func:`primary_derivatives`)."""
    if not spec:
        return {n: DEFAULT_TARGET for n in primary_derivatives(profile)}
    out = {}
    for item in (s.strip() for s in spec.split(",") if s.strip()):
        name, _, pct = item.partition(":")
        if name not in profile.free:
            raise CueingError(f"--targets: '{name}' is not a free parameter of '{profile.name}' "
                              f"(free: {', '.join(profile.free)})")
        try:
            out[name] = float(pct) if pct else DEFAULT_TARGET
        except ValueError:
            raise CueingError(f"--targets: '{item}': the target after ':' must be a number (%)") from None
        if not out[name] > 0:
            raise CueingError(f"--targets: '{item}': the target must be positive")
    if not out:
        raise CueingError("--targets names no parameter")
    return out

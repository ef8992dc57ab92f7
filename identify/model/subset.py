"""A profile narrowed for one identification: parameters held or freed, outputs chosen, and the
parameters of controls no run moves.

A flight test is flown one run per control axis, and often not on every control: a cyclics-only
test never moves collective or pedals. The parameters of an input that no run moves (its B and D
entries) have no information at all in the data; every estimator holds them at their a priori
values and says so (:func:`unflown_parameters`), instead of failing on a zero regressor or
reporting them as estimated.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import ProfileError
from .profile import Profile


def _names(text_or_list) -> list[str]:
    if isinstance(text_or_list, str):
        return [n.strip() for n in text_or_list.split(",") if n.strip()]
    return list(text_or_list or [])


def fix(profile: Profile, names) -> Profile:
    """``profile`` with the free parameters ``names`` held (moved to ``[fixed]`` at their values)."""
    names = _names(names)
    unknown = [n for n in names if n not in profile.free]
    if unknown:
        where = [f"{n} (already fixed)" if n in profile.fixed else n for n in unknown]
        raise ProfileError(f"{profile.source}: cannot fix {', '.join(where)}: not a free parameter "
                           f"(free: {', '.join(profile.free)})")
    free = {k: v for k, v in profile.free.items() if k not in names}
    if not free:
        raise ProfileError(f"{profile.source}: fixing {', '.join(names)} leaves no free parameter")
    fixed = {**profile.fixed, **{n: profile.free[n] for n in names}}
    return replace(profile, free=free, fixed=fixed)


def free(profile: Profile, names) -> Profile:
    """``profile`` with the fixed parameters ``names`` estimated (moved to ``[free]``, the value
    the a priori guess)."""
    names = _names(names)
    unknown = [n for n in names if n not in profile.fixed]
    if unknown:
        where = [f"{n} (already free)" if n in profile.free else n for n in unknown]
        raise ProfileError(f"{profile.source}: cannot free {', '.join(where)}: not a fixed parameter "
                           f"(fixed: {', '.join(profile.fixed) or 'none'})")
    return replace(profile, free={**profile.free, **{n: profile.fixed[n] for n in names}},
                   fixed={k: v for k, v in profile.fixed.items() if k not in names})


def with_outputs(profile: Profile, names) -> Profile:
    """``profile`` fitted to the outputs ``names`` only (in the profile's order; limits kept for them)."""
    names = _names(names)
    unknown = [n for n in names if n not in profile.outputs]
    if unknown:
        raise ProfileError(f"{profile.source}: output(s) {', '.join(unknown)} not in the profile "
                           f"(outputs: {', '.join(profile.outputs)})")
    if not names:
        raise ProfileError(f"{profile.source}: --outputs names no output")
    keep = tuple(y for y in profile.outputs if y in names)
    gone = {y for y in profile.outputs if y not in keep}

    def on_gone(name: str) -> bool:  # acts only on output equations left out
        entries = [e for e, _ in profile.parameter_entries(name)]
        return all(e.matrix in ("C", "D") and profile.outputs[e.row] in gone for e in entries)
    orphans = [n for n in profile.free if on_gone(n)]
    if orphans:
        raise ProfileError(f"{profile.source}: free parameter(s) {', '.join(orphans)} act only on outputs "
                           f"left out ({', '.join(sorted(gone))}): keep those outputs or fix the parameters")
    return replace(profile, outputs=keep, limits={y: v for y, v in profile.limits.items() if y in keep},
                   output_defs={y: d for y, d in profile.output_defs.items() if y in keep},
                   fixed={n: v for n, v in profile.fixed.items() if not on_gone(n)},
                   ties={n: t for n, t in profile.ties.items() if not on_gone(n)})


def input_parameters(profile: Profile) -> dict[str, list[str]]:
    """``{input: free parameters acting on it}`` (its B and D entries, ties included)."""
    out: dict[str, list[str]] = {u: [] for u in profile.input_names}
    for name in profile.free:
        for entry, _ in profile.parameter_entries(name):
            if entry.matrix in ("B", "D"):
                u = profile.input_names[entry.col]
                if name not in out[u]:
                    out[u].append(name)
    return out


def unflown_parameters(profile: Profile, runs) -> dict[str, list[str]]:
    """``{input: its free parameters}`` for every input that no run moves (constant or absent in
    every run; the pseudo-inputs of a refined profile are computed, not flown, and never count)."""
    computed = set(dict(profile.meta.get("pseudo_inputs", {})))
    acting = input_parameters(profile)
    out = {}
    for u in profile.input_names:
        if u in computed or not acting[u]:
            continue
        if not any(u in r.channels and np.ptp(r[u]) > 0 for r in runs):
            out[u] = acting[u]
    return out


def check_some_input_flown(profile: Profile, unflown: dict[str, list[str]]) -> None:
    """Raise when no run moves any input: nothing is excited, nothing can be held apart."""
    acting = [u for u, params in input_parameters(profile).items() if params
              and u not in dict(profile.meta.get("pseudo_inputs", {}))]
    if acting and set(acting) <= set(unflown):
        from ..errors import EstimationError
        names = [n for params in unflown.values() for n in params]
        raise EstimationError(f"not identifiable from these runs: no run moves any input ({', '.join(acting)}), "
                              f"so nothing is excited ({', '.join(names)} and every derivative they drive)")


def held_line(method: str, unflown: dict[str, list[str]]) -> str:
    """The one line that says which parameters are held and why."""
    names = [n for params in unflown.values() for n in params]
    return (f"{method.upper()}: {', '.join(names)} held at their a priori values: no run moves "
            f"{', '.join(unflown)} (free them again with runs that do)")


__all__ = ["fix", "free", "with_outputs", "input_parameters", "unflown_parameters", "check_some_input_flown",
           "held_line"]

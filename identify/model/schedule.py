"""Scheduled profiles: derivatives (and trim) as tables over a flight condition.

A scheduled profile is an ordinary profile (its ``[free]``/``[fixed]`` values are the model at
one condition) whose ``[meta.schedule]`` table also gives parameters as functions of one
condition, tabulated at breakpoints and interpolated linearly between them::

    [meta.schedule]
    condition = "airspeed"               # the name of the condition
    at = [35.0, 40.0, 45.0]              # breakpoints, strictly increasing
    values = { M_q = [-1.9, -2.2, -2.5] }  # one value per breakpoint, per scheduled parameter
    std = { M_q = [0.05, 0.04, 0.05] }     # optional: the tabulated standard errors
    trim = { theta = [0.05, 0.04, 0.03] }  # optional: trim values of states/inputs over the condition

:func:`at_condition` evaluates it at any condition inside the breakpoints (never beyond them:
extrapolating a schedule is refused). ``campaign stitch`` writes such profiles; ``identify
model PROFILE --at airspeed=45`` prints the model there.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import ProfileError
from .profile import Profile

KEY = "schedule"


def schedule_of(profile: Profile) -> dict | None:
    """The profile's validated schedule, or None when it has none."""
    s = profile.meta.get(KEY)
    if s is None:
        return None
    src = profile.source
    if not isinstance(s, dict) or not isinstance(s.get("condition"), str):
        raise ProfileError(f"{src}: [meta.schedule] needs condition = \"<name>\"")
    at = _vector(s.get("at"), "at", src)
    if at.size < 2 or np.any(np.diff(at) <= 0):
        raise ProfileError(f"{src}: [meta.schedule] at must hold 2 or more strictly increasing breakpoints")
    known = set(profile.free) | set(profile.fixed)
    for table in ("values", "std", "trim"):
        rows = s.get(table, {})
        if not isinstance(rows, dict):
            raise ProfileError(f"{src}: [meta.schedule] {table} must be a table of lists")
        for name, column in rows.items():
            if table != "trim" and name not in known:
                raise ProfileError(f"{src}: [meta.schedule] {table}.{name} is not a parameter of the profile")
            if _vector(column, f"{table}.{name}", src).size != at.size:
                raise ProfileError(f"{src}: [meta.schedule] {table}.{name} has {len(column)} values for "
                                   f"{at.size} breakpoints")
    return s


def at_condition(profile: Profile, value: float, name: str | None = None) -> Profile:
    """The profile at condition ``value``: every scheduled parameter interpolated; the result's
    ``meta`` records the condition, the interpolated standard errors (``meta.std``) and trim
    (``meta.trim``) and drops the schedule. A profile without a schedule is returned as it is."""
    s = schedule_of(profile)
    if s is None:
        return profile
    at = np.asarray(s["at"], float)
    cond = s["condition"]
    if not (at[0] - 1e-9 * abs(at[0]) <= value <= at[-1] + 1e-9 * abs(at[-1])):
        raise ProfileError(f"{profile.source}: {cond} = {value:g} lies outside the schedule "
                           f"({at[0]:g} .. {at[-1]:g}); a schedule is not extrapolated")
    interp = {table: {k: float(np.interp(value, at, np.asarray(v, float))) for k, v in s.get(table, {}).items()}
              for table in ("values", "std", "trim")}
    meta = {k: v for k, v in profile.meta.items() if k != KEY}
    meta["condition"] = {cond: float(value)}
    for table in ("std", "trim"):
        if interp[table]:
            meta[table] = interp[table]
    out = profile.with_values(interp["values"], name=name or f"{profile.name} at {cond} = {value:g}")
    return replace(out, meta=meta)


def parse_condition(text: str) -> tuple[str, float]:
    """``"airspeed=45"`` -> ``("airspeed", 45.0)``; one ProfileError line otherwise."""
    name, sep, value = text.partition("=")
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not sep or not name.strip() or not np.isfinite(number):
        raise ProfileError(f"--at expects NAME=NUMBER (for example airspeed=45), got '{text}'")
    return name.strip(), number


def _vector(values, where, src) -> np.ndarray:
    if not isinstance(values, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                               for v in values):
        raise ProfileError(f"{src}: [meta.schedule] {where} must be a list of numbers")
    out = np.asarray(values, float)
    if not np.all(np.isfinite(out)):
        raise ProfileError(f"{src}: [meta.schedule] {where} holds a value that is not finite")
    return out

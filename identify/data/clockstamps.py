"""Clock time stamps (``12:34:56.020``, with a date or not) as seconds from the first sample: the
time of data recorders that write the time of day instead of a number."""
from __future__ import annotations

import datetime
import re

import numpy as np

from ..errors import RunError
from . import units as U

CLOCK = re.compile(r"^(?:(?P<date>\d{4}-\d{2}-\d{2})[T ])?(?P<h>\d{1,2}):(?P<m>\d{2}):(?P<s>\d{2}(?:\.\d*)?)Z?$")
DAY = 86400.0


def clock_cell(cell: str, clock: dict) -> float:
    """Seconds of a clock stamp's day, plus its days since the first stamp's date when dated (small
    numbers: seconds since a distant epoch would lose the microseconds)."""
    m = CLOCK.match(cell.strip())
    clock["rows"] += 1
    clock.setdefault("first", cell.strip())
    seconds = int(m["h"]) * 3600 + int(m["m"]) * 60 + float(m["s"])
    if not m["date"]:
        return seconds
    clock["dated"] += 1
    try:
        day = datetime.date.fromisoformat(m["date"]).toordinal()
    except ValueError:
        return float("nan")  # refused with the other time checks, naming the line
    return (day - clock.setdefault("day0", day)) * DAY + seconds


def clock_from_first(t: np.ndarray, clock: dict, unit, source: str, where) -> str:
    """Clock stamps read by :func:`clock_cell` (``t``, in place) made seconds from the first
    sample, a midnight rollover of undated stamps (a step back by nearly a day) counted as the next
    day; returns what was done, to be said and recorded. ``where(i)``: sample i's place in the file."""
    n = len(t)
    if clock["rows"] != n or clock["dated"] not in (0, n):
        raise RunError(f"{source}: the time column mixes clock stamps ({clock['first']}) with numbers or with "
                       f"stamps {'without' if clock['dated'] else 'with'} a date: write one form")
    if unit is not None and U.canonical(unit) != "s":
        raise RunError(f"{source}: the time column holds clock stamps ({clock['first']}) but is declared in {unit}: "
                       "drop the unit")
    said = []
    if not clock["dated"]:
        back = np.flatnonzero(np.diff(t) < -DAY / 2)
        for i in back:
            t[i + 1:] += DAY
        said = [f"midnight rollover at {where(i + 1)}: 24 h added from there on" for i in back]
    t -= t[0] if np.isfinite(t[0]) else 0.0
    return (f"clock time stamps{' with a date' if clock['dated'] else ''} (first {clock['first']}) read as seconds "
            f"from the first sample" + "".join(f"; {s}" for s in said))

"""From a file's raw columns to runs: units to SI, derived channels, time jitter and gaps.

A reader (CSV or MATLAB) hands over the raw time vector and a lookup of the file's columns; the
steps every format shares happen here, in this order:

1. **Units.** A channel's declared unit (``# units:`` metadata, a header ``q [deg/s]``, or the
   channel map's ``"units"``) converts it to SI units and radians (:mod:`identify.data.units`).
2. **Channels.** The channel map names each run channel's source: a file column or variable, a
   data-matrix column (int), or an expression of them (``"da": "(dar - dal)/2"``), evaluated by a
   safe arithmetic evaluator (``+ - * /``, unary minus, parentheses, numbers, names; nothing else).
3. **Checks.** Missing or non-finite values (NaN) follow a policy (:class:`ReadOptions`): outside
   the analysis window the run is cut to the window; inside it they are refused (naming the
   channel and row), or their samples dropped (the hole splits the run) or interpolated, as
   asked, said and recorded; values equal to the channel map's ``"missing"`` markers (``-999``)
   are missing too, and an undeclared marker-like value far outside a channel's others warns. A
   column the profile does not use is left out instead, and said.
   A declared unit of another kind than the profile's (a speed for an angle) is an error. An
   angular channel taken as radians (declared ``rad`` or, undeclared, ``rad`` in the profile)
   whose values exceed what radians can physically reach gives a warning
   (:data:`identify.data.units.DEGREE_LIMITS`), and so does a pair of channels whose kinematics
   disagree by the degree factor (the integral of ``q`` against ``theta``, ``p`` against ``phi``,
   ``r`` against ``psi``), naming the unit to declare and where.
4. **Time.** A step longer than :data:`GAP_FACTOR` times the median step is a gap: the file splits
   into several runs. Within a run, time stamps off the uniform grid by up to :data:`JITTER_MAX` of
   a step are accepted and every channel is resampled onto the grid by linear interpolation (the
   jitter is recorded in the run's metadata); larger irregularity is an error. A sample rate that
   changes within the file (:func:`_rate_change`) is refused, naming where, both rates and the fix.

Warnings and notes go to stderr and into the run's ``warnings`` / ``notes`` metadata.
"""
from __future__ import annotations

import ast
import re
import sys
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ..errors import RunError
from . import units as U
from .runs import TIME, UNIFORM_RTOL, Run, check_time, uneven_steps

GAP_FACTOR = 1.5
JITTER_MAX = 0.05
NAN_POLICIES = ("refuse", "drop", "interpolate")
# (rate, angle) pairs whose kinematics agree in consistent units: d angle/dt ~ rate at small angles
KINEMATIC_PAIRS = (("q", "theta"), ("p", "phi"), ("r", "psi"))
KINEMATIC_SS_RATIO = 0.5  # the degree factor must leave at most this share of the residual the factor 1 leaves
DEGREE_FACTOR_BAND = 1.5  # a ratio within 57.3 / 1.5 .. 57.3 x 1.5 is the degree factor
COARSE_MARGIN = 0.05  # a duplicated or missing row in 20 is a row, not a coarse clock
SLOW_STEP = 1.0  # s: flight-test data sampled slower than 1 Hz show no aircraft dynamics
FAST_STEP = 1e-5  # s: no flight-test record is sampled faster than 100 kHz
# values loggers write for a missing sample; one that lies far outside a channel's other values is flagged
# the ±9..9 family; 16-bit integer extremes (an empty or saturated counter); the fill values of
# Fortran/MATLAB tools (±1e30) and netCDF's default float fill (9.96921e36)
TYPICAL_MARKERS = (-999.0, -9999.0, -99999.0, -999999.0, 999.0, 9999.0, 99999.0, 999999.0,
                   -32768.0, 32767.0, 65535.0, -1e30, 1e30, float(np.float32(9.96921e36)))
MARKER_DISTANCE = 1.0  # flagged beyond this many times the other values' range from them
RATE_WINDOW = 7  # steps in the running median that tells a sample rate from single gaps
RATE_TOL = 0.1  # a running median step off the rate by more than this share is another rate (jitter: 5 %)
RATE_MIN_STEPS = 10  # ... when it holds that many steps (fewer: lone samples between gaps)
_DERIVATIVE_OF = {"angle": "angular rate", "angular rate": "angular acceleration", "length": "speed",
                  "speed": "acceleration"}


@dataclass
class Raw:
    """A file's content before units, mapping and time checks.

    ``column(name_or_index, channel)`` returns raw values (N,) or raises RunError naming
    ``channel``; ``names`` are the file's column/variable names; ``units`` declared units keyed by
    column, variable or channel name; ``row(i)`` names sample i in errors (``line 12`` for CSV,
    ``sample 13`` for .mat).
    """

    source: str
    time: np.ndarray
    column: Callable[[object, str], np.ndarray]
    names: list[str]
    units: dict[str, str] = field(default_factory=dict)
    meta: dict[str, str] = field(default_factory=dict)
    row: Callable[[int], str] = lambda i: f"sample {i + 1}"
    time_name: str = TIME
    file_format: str = "csv"  # or "mat": where a unit is declared (hints name the right place)
    specs: dict | None = None  # the channel map's channels, column numbers made 0-based
    notes: list[str] = field(default_factory=list)  # what the reader guessed or repaired, said and recorded
    time_resolution: tuple[float, str] | None = None  # the smallest time difference the file can hold, and why
    missing: object = None  # the map's "missing": marker value(s) of missing samples, or {name: value(s)}


def is_index(v) -> bool:
    """Whether a channel map entry is a column number (an int, not a bool)."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def zero_based(channels: dict, time, base, n_columns: int, source: str):
    """The channel map's ``channels`` and ``time`` with column numbers made 0-based.

    ``base`` is the map's ``"index_base"``: 0 (Python) or 1 (MATLAB). Undeclared, numbers are
    0-based, but a map that uses numbers and never column 0, or names column ``n_columns`` (one
    past the last 0-based), reads like MATLAB's 1-based numbering and is refused: read 0-based,
    every channel would be the column next to the one meant, without a word."""
    where = f"{source}: channel map"
    numbers = {k: v for k, v in channels.items() if is_index(v)}
    if is_index(time):
        numbers[TIME] = time
    if base not in (None, 0, 1):
        raise RunError(f"{where}: \"index_base\" must be 0 (Python) or 1 (MATLAB), got {base!r}")
    if not numbers:
        return dict(channels), time
    if base is None:
        used = sorted(set(numbers.values()))
        if 0 not in used or n_columns in used:
            why = "none of them is 0" if 0 not in used else f"column {n_columns} is one past the last of {n_columns}"
            raise RunError(f"{where}: column numbers {', '.join(map(str, used))} look 1-based (MATLAB): {why}; "
                           f"declare \"index_base\": 1 (MATLAB numbering) or 0 (Python numbering)")
        return dict(channels), time
    if base == 1:
        bad = {k: v for k, v in numbers.items() if not 1 <= v <= n_columns}
        if bad:
            raise RunError(f"{where}: 1-based column numbers must lie in 1..{n_columns}: "
                           + ", ".join(f"'{k}' = {v}" for k, v in bad.items()))
    shift = {k: v - base for k, v in numbers.items()}
    return {k: shift.get(k, v) for k, v in channels.items()}, shift.get(TIME, time)


@dataclass
class ReadOptions:
    """How reading treats missing values: ``nan`` one of :data:`NAN_POLICIES` for NaN inside the
    window ``t_start .. t_end`` (s; None: open); NaN outside the window cut the run to it."""

    nan: str = "refuse"
    t_start: float | None = None
    t_end: float | None = None

    def __post_init__(self):
        if self.nan not in NAN_POLICIES:
            raise RunError(f"NaN policy must be one of {', '.join(NAN_POLICIES)}, got {self.nan!r}")

    def inside(self, t: np.ndarray) -> np.ndarray:
        lo = -np.inf if self.t_start is None else self.t_start - 1e-9
        hi = np.inf if self.t_end is None else self.t_end + 1e-9
        return (t >= lo) & (t <= hi)


def build_runs(raw: Raw, channels: dict[str, object], profile=None, options: ReadOptions | None = None) -> "Ingested":
    """Runs from ``raw``: ``channels`` maps each run channel to its source (a column name or index,
    or an expression string). One run, or several when time gaps (or dropped samples) split the file."""
    options = options or ReadOptions()
    notes, warnings = [f"{raw.source}: {n}" for n in raw.notes], []
    meta_time = {}
    t = _si_time(raw, meta_time, notes)
    values, described = {}, {}
    resolver = _Resolver(raw, channels)
    used = profile_channels(profile) if profile is not None else set(channels)
    for name in channels:
        v, how = resolver.get(name)
        bad = int(np.sum(~np.isfinite(v)))
        if bad and name not in used:  # e.g. an empty spare column of a data logger
            notes.append(f"{raw.source}: channel '{name}' has {bad} missing or non-finite value(s): left out "
                         "(the profile does not use it)")
            continue
        values[name], described[name] = v, how
    meta = {**_meta(raw, described, resolver.derived), **meta_time}
    notes += [f"{raw.source}: {line}" for line in converted_lines(described)]
    notes += resolver.marker_notes(meta)
    warnings += [w for n, w in resolver.suspects.items() if n in values or n not in channels]  # operands too
    t, values, lines, rows = _missing(t, values, raw, options, meta, resolver.marked)
    notes += lines
    t, values, rows = _one_rate(t, values, rows, raw, options, meta, notes)
    if len(rows) != len(raw.time):  # samples cut or dropped: messages still name the file's rows
        raw = replace(raw, row=lambda i, rows=rows, row=raw.row: row(int(rows[i])))
    warnings += _unit_checks(raw, t, values, described, profile)
    warnings += _plausibility(raw, t, values, used, set(profile.inputs) if profile is not None else set())
    segments = _split_gaps(t, raw, meta, notes)
    runs = []
    for k, (lo, hi) in enumerate(segments):
        seg_t = t[lo:hi]
        seg = {n: v[lo:hi] for n, v in values.items()}
        seg_meta = dict(meta)
        seg_t, seg = _regularise(seg_t, seg, raw, lo, seg_meta, notes)
        source = raw.source
        if len(segments) > 1:
            source = f"{raw.source} [segment {k + 1}/{len(segments)}]"
            seg_meta["segment"] = f"{k + 1} of {len(segments)}: t = {seg_t[0]:g}..{seg_t[-1]:g} s"
        if notes:
            seg_meta["notes"] = "; ".join(notes)
        if warnings:
            seg_meta["warnings"] = "; ".join(warnings)
        runs.append(Run(seg_t, seg, seg_meta, source))
    return Ingested(runs, [f"note: {n}" for n in notes] + [f"warning: {w}" for w in warnings])


def _missing(t, values: dict, raw: Raw, options: ReadOptions, meta: dict, marked: dict | None = None):
    """Time, channels, the notes and the file rows (indices) kept, after the NaN policy; ``marked``
    the channels whose missing-value markers were read as NaN (named in a refusal)."""
    rows = np.arange(len(t))
    if not values:
        return t, values, [], rows
    bad = np.zeros(t.shape, bool)
    for v in values.values():
        bad |= ~np.isfinite(v)
    if not bad.any():
        return t, values, [], rows
    notes = []
    inside = options.inside(t)
    if (bad & ~inside).any():
        n_out = int((bad & ~inside).sum())
        text = (f"{n_out} sample(s) with missing values outside the window t = {options.t_start}..{options.t_end} s: "
                f"the run is cut to the window")
        notes.append(f"{raw.source}: {text}")
        meta["missing_outside_window"] = text
        if inside.sum() < 2:
            raise RunError(f"{raw.source}: fewer than two samples between {options.t_start} and {options.t_end} s")
        t, rows, bad = t[inside], rows[inside], bad[inside]
        values = {n: v[inside] for n, v in values.items()}
    if not bad.any():
        return t, values, notes, rows
    if options.nan == "refuse":
        name = next(n for n, v in values.items() if not np.all(np.isfinite(v)))
        v = values[name]
        first = np.flatnonzero(~np.isfinite(v))
        what = f"missing value (marker {marked[name]} in the file)" if name in (marked or {}) else f"{v[first[0]]} value"
        raise RunError(f"{raw.source}: {raw.row(rows[first[0]])}, channel '{name}': {what} "
                       f"({first.size} missing or non-finite value(s) in the window; --nan drop or --nan "
                       f"interpolate reads them)")
    where = _listed_rows(raw, rows[bad])
    good = ~bad
    if options.nan == "interpolate":
        lo, hi = np.flatnonzero(good)[[0, -1]] if good.any() else (0, -1)
        ends = bad & ((np.arange(len(t)) < lo) | (np.arange(len(t)) > hi))
        fixed = {}
        for n, v in values.items():
            ok = np.isfinite(v)
            fixed[n] = np.where(ok, v, np.interp(t, t[ok], v[ok]) if ok.sum() >= 2 else np.nan)
        values = fixed
        text = (f"{int((bad & ~ends).sum())} sample(s) with missing values interpolated linearly in time ({where})"
                + (f"; {int(ends.sum())} at the ends dropped" if ends.any() else ""))
        meta["interpolated_samples"] = text
        good = ~ends
    else:
        text = f"{int(bad.sum())} sample(s) with missing values dropped ({where}); the hole splits the run"
        meta["dropped_samples"] = text
    notes.append(f"{raw.source}: {text}")
    if good.sum() < 2:
        raise RunError(f"{raw.source}: fewer than two samples without missing values")
    return t[good], {n: v[good] for n, v in values.items()}, notes, rows[good]


def converted_lines(described: dict) -> list[str]:
    """One line per channel converted to SI from its declared unit (said by every command)."""
    return [f"channel '{n}' converted from {u} to {U.si_unit(u)} "
            f"(x {U.UNITS[U.canonical(u)][0]:.10g})" for n, (how, u) in described.items()
            if how == "declared" and u != "SI" and U.UNITS[U.canonical(u)][0] != 1.0]


def _meta(raw: Raw, described: dict, derived: dict) -> dict[str, str]:
    """The file's metadata, ``units`` replaced by what was converted (the run is SI now: written
    again, it must not be converted twice) and the derived channels' expressions."""
    meta = {k: v for k, v in raw.meta.items() if k not in ("units", "units_declared")}  # this reading's own
    converted = [f"{n} from {u} (x {U.UNITS[U.canonical(u)][0]:.10g})" for n, (how, u) in described.items()
                 if how == "declared" and u != "SI" and U.UNITS[U.canonical(u)][0] != 1.0]
    if converted:
        meta["converted_to_si"] = ", ".join(converted)
    declared = [f"{n}={u}" for n, (how, u) in described.items() if how == "declared" and u != "SI"]
    if declared:  # as read (every other channel had none: taken as SI)
        meta["units_declared"] = ", ".join(declared)
    if derived:
        meta["derived"] = ", ".join(f"{n} = {e}" for n, e in derived.items())
    return meta


@dataclass
class Ingested:
    """A file's runs and the notes and warnings reading it raised (also in each run's metadata)."""

    runs: list[Run]
    messages: list[str]

    def all(self) -> list[Run]:
        """Every run, the messages said on stderr."""
        for line in self.messages:
            print(line, file=sys.stderr)
        return self.runs

    def one(self, reader: str) -> Run:
        """The only run; a file that time gaps split gives an error pointing to ``reader``."""
        if len(self.runs) > 1:
            raise RunError(f"{self.runs[0].meta['time_gaps']}; read it with {reader}, which returns every "
                           "segment as a run")
        return self.all()[0]


# -- time ------------------------------------------------------------------------------------------
def _si_time(raw: Raw, meta: dict, notes: list) -> np.ndarray:
    t = np.asarray(raw.time, dtype=float).ravel()
    resolution = _stored_resolution(t, raw.time_resolution)
    unit = raw.units.get(raw.time_name, raw.units.get(TIME))
    factor = 1.0
    if unit is not None:
        _, factor, kind = U.unit_info(unit, f"{raw.source}: channel '{raw.time_name}'")
        if kind != "time":
            raise RunError(f"{raw.source}: channel '{raw.time_name}': unit '{unit}' is not a time unit")
    t = _from_first_if_too_large(t, factor, raw, meta, notes) * factor
    if resolution is not None:
        t = _coarse_clock(t, resolution[0] * factor, resolution[1], raw, meta, notes)
    check_time(t, raw.source, raw.row, uniform=False)
    return t


def _from_first_if_too_large(t: np.ndarray, factor: float, raw: Raw, meta: dict, notes: list) -> np.ndarray:
    """Time stamps so large that double precision cannot hold their step evenly (Unix time in s:
    1.7e9 s holds 2.4e-7 s; a MATLAB datenum in days) are counted from the first, in their own unit
    (the difference of two close doubles is exact), and that is said: windows then count from it too."""
    finite = t[np.isfinite(t)]
    if finite.size < 2:
        return t
    step = float(np.median(np.abs(np.diff(finite))))
    if not (step > 0 and 4 * np.spacing(float(np.max(np.abs(finite)))) > UNIFORM_RTOL * step):
        return t
    t0 = float(finite[0])
    text = (f"time stamps as large as {t0 * factor:.10g} s cannot hold a uniform {step * factor:.3g} s step in double "
            f"precision: counted from the first stamp ({t0:.10g} in the file), --t-start/--t-end too")
    meta["time_origin"] = text
    notes.append(f"{raw.source}: {text}")
    return t - t0


def _stored_resolution(t: np.ndarray, given: tuple[float, str] | None) -> tuple[float, str] | None:
    """The smallest time difference the stored stamps hold (in their own unit): the file's (single
    precision, decimals written) or double precision's at the clock offset, whichever is coarser --
    a MATLAB datenum (days near 7.4e5) holds about 1e-5 s. Twice the spacing: a stamp and the grid's
    ends through the first and the last each round by half of it."""
    finite = t[np.isfinite(t)]
    if not finite.size:
        return given
    peak = float(np.max(np.abs(finite)))
    double = 2 * float(np.spacing(peak))
    if given is None or double > given[0]:
        return double, f"double precision at {peak:.10g}"
    return given


def _coarse_clock(t: np.ndarray, resolution: float, why: str, raw: Raw, meta: dict, notes: list) -> np.ndarray:
    """Time stamps stored coarser than their spacing (single precision at a large clock offset,
    too few decimals written) repeat or alternate between steps; when every stamp lies within half
    the resolution of the uniform grid through the first and the last, that grid is the time.
    A grid step within :data:`COARSE_MARGIN` of a multiple of the resolution is no coarse clock:
    its stamps would be exact but for a repeated or missing row, which stays an error or a gap
    (hence also at least 1 / COARSE_MARGIN samples: one such row then stays within the margin)."""
    if t.size <= 1 / COARSE_MARGIN or not np.all(np.isfinite(t)) or not uneven_steps(np.diff(t)).size \
            or not t[-1] > t[0]:
        return t
    grid = np.linspace(t[0], t[-1], t.size)
    off = float(np.max(np.abs(t - grid)))
    ratio = (grid[1] - grid[0]) / resolution
    # a step of many resolution units: a repeated or missing row moves the stamps by that many, far
    # beyond the half unit allowed, so only a step of a few units needs the multiple test
    exact = ratio < 1 / COARSE_MARGIN and abs(ratio - round(ratio)) <= COARSE_MARGIN
    if exact or off > 0.5 * resolution * (1 + 1e-6) + 1e-12:
        return t
    text = (f"time stamps resolve only {resolution:.3g} s ({why}), coarser than their spacing: rebuilt as the uniform "
            f"{grid[1] - grid[0]:.6g} s grid from {t[0]:.10g} to {t[-1]:.10g} s (every stamp within half a "
            f"resolution step of it, at most {off:.3g} s off)")
    meta["time_rebuilt"] = text
    notes.append(f"{raw.source}: {text}")
    return grid


def _split_gaps(t: np.ndarray, raw: Raw, meta: dict, notes: list) -> list[tuple[int, int]]:
    """Index ranges [lo, hi) between gaps (steps over GAP_FACTOR x the median step)."""
    steps = np.diff(t)
    dt = float(np.median(steps))
    gaps = np.flatnonzero(steps > GAP_FACTOR * dt)
    if not gaps.size:
        return [(0, len(t))]
    bounds = [0, *(gaps + 1).tolist(), len(t)]
    pieces = list(zip(bounds[:-1], bounds[1:]))
    kept = [(lo, hi) for lo, hi in pieces if hi - lo >= 2]
    listing = ", ".join(f"{raw.row(i + 1)} ({t[i]:g} -> {t[i + 1]:g} s)" for i in gaps[:5])
    more = f" and {gaps.size - 5} more" if gaps.size > 5 else ""
    dropped = len(pieces) - len(kept)
    meta["time_gaps"] = (f"{raw.source}: {gaps.size} time gap(s) longer than {GAP_FACTOR:g} x the {dt:.6g} s step "
                         f"at {listing}{more} split the file into {len(kept)} runs"
                         + (f" ({dropped} lone sample(s) between gaps dropped)" if dropped else ""))
    notes.append(meta["time_gaps"])
    if not kept:
        raise RunError(f"{raw.source}: time gaps leave no stretch of two or more samples")
    return kept


def _regularise(t: np.ndarray, channels: dict, raw: Raw, offset: int, meta: dict, notes: list):
    """Accept jitter up to JITTER_MAX of a step (resampling onto the uniform grid); refuse more."""
    if t.size < 3 or not uneven_steps(np.diff(t)).size:
        return t, channels
    n = t.size
    dt = (t[-1] - t[0]) / (n - 1)
    grid = t[0] + np.arange(n) * dt
    grid[-1] = t[-1]
    off = np.abs(t - grid) / dt
    worst = int(np.argmax(off))
    if off[worst] > JITTER_MAX:
        raise RunError(f"{raw.source}: {raw.row(offset + worst)}, channel '{TIME}': time stamp {t[worst]:.6g} s "
                       f"is {100 * off[worst]:.3g}% of a step off the uniform {dt:.6g} s grid (irregular "
                       f"sampling; up to {100 * JITTER_MAX:g}% jitter is resampled, a step over "
                       f"{GAP_FACTOR:g} x the median splits the run)")
    text = (f"time jitter up to {100 * off[worst]:.3g}% of the {dt:.6g} s step: resampled onto the uniform "
            "grid by linear interpolation")
    meta["time_jitter"] = f"{off[worst]:.3g}"
    meta["resampled"] = text
    notes.append(f"{raw.source}: {text}")
    return grid, {k: np.interp(grid, t, v) for k, v in channels.items()}


def _rate_change(t: np.ndarray):
    """The first change of sample rate, ``(i, step before, step after)`` with ``i`` the first step
    at the new rate, or None. The running median of :data:`RATE_WINDOW` steps ignores single gaps
    and jitter; a median off the rate by more than :data:`RATE_TOL` for :data:`RATE_MIN_STEPS`
    steps is another rate."""
    steps = np.diff(t)
    if steps.size < 2 * RATE_MIN_STEPS:
        return None
    half = RATE_WINDOW // 2
    med = np.median(np.lib.stride_tricks.sliding_window_view(np.pad(steps, half, mode="edge"), RATE_WINDOW), axis=1)
    level = float(np.median(med[:RATE_MIN_STEPS]))
    off = np.abs(med - level) > RATE_TOL * level
    i = 0
    while i < off.size:
        if not off[i]:
            i += 1
            continue
        j = i + int(np.argmin(off[i:])) if not off[i:].all() else off.size
        if j - i >= RATE_MIN_STEPS:  # the first step nearer the new rate, around where the median turned
            new = float(np.median(med[i:j]))
            near = steps[max(i - half, 0):i + half + 1]
            return max(i - half, 0) + int(np.argmax(np.abs(near - new) < np.abs(near - level))), level, new
        i = j
    return None


def _one_rate(t, values: dict, rows, raw: Raw, options: ReadOptions, meta: dict, notes: list):
    """Refuse a file whose sample rate changes (a run holds one rate: resampling one part is the
    engineer's choice of filter, not the reader's), naming where, the two rates and the fix; a
    change outside the window ``--t-start/--t-end`` cuts the run to the window, said."""
    change = _rate_change(t)
    if change is None:
        return t, values, rows
    i, before, after = change
    where = (f"the sample rate changes at {raw.row(int(rows[i]))} (t = {t[i]:.6g} s): {1 / before:.4g} Hz "
             f"(step {before:.6g} s) up to it, {1 / after:.4g} Hz (step {after:.6g} s) after it")
    inside = options.inside(t)
    if not inside.all() and inside.sum() >= 2 and _rate_change(t[inside]) is None:
        text = f"{where}, outside the window t = {options.t_start}..{options.t_end} s: the run is cut to the window"
        meta["rate_change_outside_window"] = text
        notes.append(f"{raw.source}: {text}")
        return t[inside], {n: v[inside] for n, v in values.items()}, rows[inside]
    raise RunError(f"{raw.source}: {where}; a run holds one sample rate: resample the file to one rate, or "
                   f"read one part, before or after t = {t[i]:.6g} s, with --t-start/--t-end (estimate, refine) "
                   "or by cutting the file")


# -- channels --------------------------------------------------------------------------------------
class _Resolver:
    """Each run channel's SI values from its source; ``(values, (how, unit))`` per channel where how
    is ``declared`` (a unit given) or ``undeclared``."""

    def __init__(self, raw: Raw, channels: dict):
        self.raw, self.channels = raw, channels
        self.done: dict[str, tuple] = {}
        self.busy: set[str] = set()
        self.derived: dict[str, str] = {}
        self.marked: dict[str, str] = {}  # channel: the declared marker(s) found in it
        self.marked_rows: dict[str, str] = {}
        self.suspects: dict[str, str] = {}  # channel: warning of an undeclared marker-like value

    def marker_notes(self, meta: dict) -> list[str]:
        """Notes of the declared markers read as missing (also recorded in ``meta``)."""
        if not self.marked:
            return []
        text = "; ".join(f"'{n}': {self.marked_rows[n]}" for n in self.marked)
        meta["missing_markers"] = text
        return [f"{self.raw.source}: missing-value marker(s) read as missing (NaN): {text}"]

    def _markers(self, name: str, spec, v: np.ndarray) -> np.ndarray:
        """``v`` with the declared missing-value markers made NaN; an undeclared value of
        :data:`TYPICAL_MARKERS` far outside the other values is kept and flagged."""
        declared = _declared_markers(self.raw.missing, name, spec)
        if declared is not None:
            hit = np.isin(v, declared)
            if hit.any():
                found = ", ".join(f"{m:g}" for m in np.unique(v[hit]))
                self.marked[name] = found
                self.marked_rows[name] = f"{int(hit.sum())} x {found} ({_listed_rows(self.raw, np.flatnonzero(hit))})"
                v = np.where(hit, np.nan, v)
            return v
        finite = v[np.isfinite(v)]
        for marker in TYPICAL_MARKERS:
            hit = v == marker
            others = finite[finite != marker]
            if not hit.any() or others.size < 2:
                continue
            lo, hi = float(others.min()), float(others.max())
            if min(abs(marker - lo), abs(marker - hi)) > MARKER_DISTANCE * (hi - lo) and not lo <= marker <= hi:
                self.suspects[name] = (
                    f"{self.raw.source}: channel '{name}': {int(hit.sum())} value(s) exactly {marker:g} "
                    f"({_listed_rows(self.raw, np.flatnonzero(hit))}), far outside its other values "
                    f"({lo:.6g} .. {hi:.6g}): a missing-value "
                    f"marker? Read as data; to read them as missing declare it in the channel map "
                    f"(\"missing\": {marker:g}), then --nan drop or --nan interpolate")
                break
        return v

    def get(self, name: str):
        if name in self.done:
            return self.done[name]
        if name in self.busy:
            raise RunError(f"{self.raw.source}: channel map: derived channel '{name}' refers to itself")
        self.busy.add(name)
        spec = self.channels[name]
        if isinstance(spec, str) and not _is_name(spec):
            out = self._derived(name, spec)
        else:
            out = self._plain(name, spec)
        self.busy.discard(name)
        self.done[name] = out
        return out

    def _unit(self, *keys) -> str | None:
        found = {k: self.raw.units[k] for k in keys if k is not None and k in self.raw.units}
        if len({U.canonical(u) for u in found.values()}) > 1:
            raise RunError(f"{self.raw.source}: conflicting units declared for "
                           + ", ".join(f"'{k}' ({u})" for k, u in found.items()))
        return next(iter(found.values()), None)

    def _plain(self, name: str, spec):
        raw_values = self._markers(name, spec, np.asarray(self.raw.column(spec, name), dtype=float).ravel())
        unit = self._unit(name, spec if isinstance(spec, str) else None)
        if unit is None:
            return raw_values, ("undeclared", None)
        return U.to_si(raw_values, unit, f"{self.raw.source}: channel '{name}'"), ("declared", unit)

    def _operand(self, ref: str):
        """An expression's operand: another channel of the map, else a file column/variable."""
        if ref in self.channels:
            return self.get(ref)
        if ref not in self.raw.names:
            return None
        return self._plain(ref, ref)

    def _derived(self, name: str, expr: str):
        where = f"{self.raw.source}: channel map: '{name}' = '{expr}'"
        declared = []

        def lookup(ref):
            found = self._operand(ref)
            if found is None:
                raise RunError(f"{where}: no column or channel '{ref}'")
            if found[1][0] == "declared":
                declared.append(ref)
            return found[0]

        values = np.broadcast_to(evaluate(expr, lookup, where), self.raw.time.shape).astype(float)
        self.derived[name] = expr
        unit = self.raw.units.get(name)
        if unit is None:
            return values, ("declared" if declared else "undeclared", "SI" if declared else None)
        if declared:
            raise RunError(f"{where}: a unit is declared both for '{name}' ({unit}) and for its operand(s) "
                           f"{', '.join(declared)}; declare one")
        return U.to_si(values, unit, f"{self.raw.source}: channel '{name}'"), ("declared", unit)


def _listed_rows(raw: Raw, rows: np.ndarray) -> str:
    """The file's rows ``rows`` (indices) as a message names them: the first five and how many more."""
    return ", ".join(raw.row(int(i)) for i in rows[:5]) + (f" and {rows.size - 5} more" if rows.size > 5 else "")


def _declared_markers(missing, name: str, spec):
    """The missing-value markers declared for a channel (by its name or its column's), or None."""
    if isinstance(missing, dict):
        missing = missing.get(name, missing.get(spec) if isinstance(spec, str) else None)
    if missing is None:
        return None
    return np.atleast_1d(np.asarray(missing, dtype=float))


def _is_name(spec: str) -> bool:
    return all(part.isidentifier() for part in spec.split("."))


# a number (kept) or a channel name, dotted for struct fields (replaced by a placeholder)
_TOKEN = re.compile(r"(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)|[A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*")
_BINARY = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide}


def evaluate(expr: str, lookup: Callable[[str], np.ndarray], where: str):
    """Value of an arithmetic expression over named channels: ``+ - * /``, unary ``+ -``,
    parentheses, numbers and names (dotted names for MATLAB struct fields, Python keywords allowed).
    Walks the syntax tree; anything else (calls, powers, comparisons, subscripts) is refused with
    RunError."""
    names: dict[str, str] = {}

    def placeholder(m):  # channel names may be Python keywords (``del``, ``in``): parse placeholders
        if m.group("num"):
            return m.group(0)
        return names.setdefault(m.group(0), f"_ch{len(names)}_")

    try:
        tree = ast.parse(_TOKEN.sub(placeholder, expr.strip()), mode="eval")
    except SyntaxError:
        raise RunError(f"{where}: not an arithmetic expression") from None
    real = {v: k for k, v in names.items()}

    def text(node) -> str:
        return re.sub(r"_ch\d+_", lambda m: real.get(m.group(0), m.group(0)), ast.unparse(node))

    def walk(node):
        if isinstance(node, ast.Expression):
            return walk(node.body)
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            with np.errstate(divide="ignore", invalid="ignore"):
                return _BINARY[type(node.op)](walk(node.left), walk(node.right))
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
            value = walk(node.operand)
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)) and not isinstance(node.value, bool):
            return float(node.value)
        if isinstance(node, ast.Name) and node.id in real:
            return lookup(real[node.id])
        raise RunError(f"{where}: '{text(node)}' is not allowed (only + - * / ( ), numbers and channel names)")

    return walk(tree)


# -- plausibility ----------------------------------------------------------------------------------
def profile_channels(profile) -> set[str]:
    """Every channel a profile can use: inputs, states, their derivatives and outputs."""
    return {*profile.inputs, *profile.states, *(f"{s}_dot" for s in profile.states), *profile.outputs}


def profile_quantities(profile) -> dict[str, str]:
    """The quantity (angle, angular rate, speed ...) of each channel a profile's units imply: its
    states, inputs and state derivatives ``<state>_dot``."""
    out = {}
    for name, unit in {**profile.states, **profile.inputs}.items():
        u = U.canonical(unit)
        if u is not None and U.UNITS[u][0] == 1.0:  # a profile in other than SI units is not checked
            out[name] = U.UNITS[u][1]
    for name in profile.states:
        if out.get(name) in _DERIVATIVE_OF:
            out[f"{name}_dot"] = _DERIVATIVE_OF[out[name]]
    return out


def _unit_checks(raw: Raw, t: np.ndarray, values: dict, described: dict, profile) -> list[str]:
    """Warnings: radian channels holding degree-like values (by magnitude and by kinematics).
    A declared unit of another quantity than the profile's is an error."""
    source = raw.source
    expected = profile_quantities(profile) if profile is not None else {}
    controls = set(profile.inputs) if profile is not None else set()
    out = _kinematic_checks(raw, t, values, described)
    flagged = {w.split("'")[1] for w in out}
    for name, v in values.items():
        how, unit = described[name]
        if how == "declared" and unit != "SI":
            kind = U.quantity(unit)
            if name in expected and kind != expected[name]:
                raise RunError(f"{source}: channel '{name}' is declared in {unit} ({kind}) but the profile "
                               f"expects {expected[name]} (a unit of the wrong kind: check the unit or the channel)")
            if U.canonical(unit) not in ("rad", "rad/s", "rad/s^2"):
                continue
            how = f"declared {unit}"
        elif how == "undeclared" and name in expected:
            kind, how = expected[name], "no unit declared; the profile's unit is SI"
        else:
            continue
        kind = "control angle" if kind == "angle" and name in controls else kind
        peak = U.looks_like_degrees(v, kind)
        if peak is not None and name not in flagged:
            out.append(U.degree_warning(source, name, peak, kind, how, raw.file_format))
    return out


def _plausibility(raw: Raw, t: np.ndarray, values: dict, used: set, controls: set) -> list[str]:
    """Warnings for what reads without error but cannot be flight data as taken: a sample interval
    over :data:`SLOW_STEP` (time in milliseconds read as seconds) or under :data:`FAST_STEP` (days read
    as seconds), and a used measured channel that never changes (a dead sensor or an unconnected
    column: nothing can be identified from it). A control held still is not one: flight tests fly
    one run per axis, the other controls at trim (an input no run moves is refused later)."""
    out = []
    step = float(np.median(np.diff(t)))
    if step > SLOW_STEP:
        out.append(f"{raw.source}: channel '{raw.time_name}': the time step is {step:.6g} s ({1 / step:.3g} Hz), "
                   f"too slow for flight dynamics; if the time is in milliseconds (or microseconds: 'us') declare its "
                   f"unit ({U.declare_hint(raw.time_name, 'ms', raw.file_format)})")
    elif step < FAST_STEP:  # e.g. a MATLAB datenum (days) read as seconds: 50 Hz looks like 4 MHz
        out.append(f"{raw.source}: channel '{raw.time_name}': the time step is {step:.3g} s ({1 / step:.3g} Hz), "
                   f"too fast for a flight-test record; if the time is in days (a MATLAB datenum) declare its "
                   f"unit ({U.declare_hint(raw.time_name, 'day', raw.file_format)})")
    for name, v in values.items():
        if name in used and name not in controls and v.size > 1 and np.all(v == v[0]):
            out.append(f"{raw.source}: channel '{name}' is constant ({v[0]:.6g} in all {v.size} samples): "
                       "a dead sensor or an unconnected column? Nothing is identified from it")
    return out


def _taken_as_radians(described: dict, name: str) -> bool:
    how, unit = described[name]
    return how == "undeclared" or U.canonical(unit) in ("rad", "rad/s")


def _kinematic_checks(raw: Raw, t: np.ndarray, values: dict, described: dict) -> list[str]:
    """Warnings for (rate, angle) pairs whose kinematics disagree by the degree factor: the angle's
    change regressed on the rate's integral (a rate bias and the start absorbed by a line in
    time) gives a factor near 180/pi (the angle is in degrees) or pi/180 (the rate is).

    A flag needs both: the free factor within the band around 57.3 (or 1/57.3), and the factor
    57.3 (1/57.3) fitting the angle clearly better than 1 (residual sum of squares at most
    :data:`KINEMATIC_SS_RATIO` of it). The comparison, unlike the share of variance explained,
    holds when the attitude barely moves and its noise is of the size of its motion."""
    out = []
    for rate, angle in KINEMATIC_PAIRS:
        if rate not in values or angle not in values or len(t) < 10:
            continue
        x = np.concatenate([[0.0], np.cumsum(0.5 * (values[rate][1:] + values[rate][:-1]) * np.diff(t))])
        y = values[angle] - values[angle][0]
        line = np.column_stack([t - t[0], np.ones_like(t)])

        def rss(k):  # residual of the angle after k x the rate's integral and a line in time
            r = y - k * x
            return float(np.sum((r - line @ np.linalg.lstsq(line, r, rcond=None)[0]) ** 2))

        X = np.column_stack([x, line])
        k = float(np.linalg.lstsq(X, y, rcond=None)[0][0])
        factor = 180 / np.pi
        if factor / DEGREE_FACTOR_BAND < k < factor * DEGREE_FACTOR_BAND and _taken_as_radians(described, angle):
            suspect, unit, k_unit = angle, "deg", factor
        elif 1 / (factor * DEGREE_FACTOR_BAND) < k < DEGREE_FACTOR_BAND / factor and _taken_as_radians(described, rate):
            suspect, unit, k_unit = rate, "deg/s", 1 / factor
        else:
            continue
        if not rss(k_unit) <= KINEMATIC_SS_RATIO * rss(1.0):
            continue
        out.append(f"{raw.source}: channel '{suspect}' looks like {unit}: '{angle}' changes {k:.4g} times the "
                   f"integral of '{rate}' (1 in consistent units, 57.3 or 1/57.3 when one is in degrees); declare "
                   f"its unit ({U.declare_hint(suspect, unit, raw.file_format)})")
    return out

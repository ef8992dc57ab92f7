"""Runs: measured (or simulated) time histories in the project's CSV run format.

A run file is CSV: optional metadata comment lines ``# key: value`` on top, one header row of
channel names, then one row per sample. The ``time`` column is in seconds, strictly increasing and
uniformly sampled; every other column is a channel in SI units and radians, named as in the
profile. Measured files may declare other units, derived channels, jittered or gapped time: see
:mod:`identify.data.ingest`, which turns them into runs. Reading rejects bad data with one line naming
the file, row and channel.
"""
from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RunError
from . import units as U

TIME = "time"
_UNIFORM_RTOL = 1e-6


@dataclass
class Run:
    """One run: ``time`` (N,) in s, ``channels`` {name: (N,) array}, ``meta`` {key: str}."""

    time: np.ndarray
    channels: dict[str, np.ndarray]
    meta: dict[str, str] = field(default_factory=dict)
    source: str = "<run>"

    def __post_init__(self):
        self.time = np.asarray(self.time, dtype=float)
        self.channels = {k: np.asarray(v, dtype=float) for k, v in self.channels.items()}
        _check_time(self.time, self.source)
        for name, values in self.channels.items():
            if values.shape != self.time.shape:
                raise RunError(f"{self.source}: channel '{name}' has {values.size} samples, "
                               f"time has {self.time.size}")

    @property
    def dt(self) -> float:
        """Sample interval in s."""
        return float((self.time[-1] - self.time[0]) / (len(self.time) - 1))

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def __len__(self) -> int:
        return len(self.time)

    def __getitem__(self, name: str) -> np.ndarray:
        if name == TIME:
            return self.time
        try:
            return self.channels[name]
        except KeyError:
            raise RunError(f"{self.source}: no channel '{name}'") from None

    def require(self, names, purpose: str = "the profile") -> None:
        """Raise one RunError listing every channel ``purpose`` needs that the run lacks."""
        missing = [n for n in names if n not in self.channels]
        if missing:
            raise RunError(f"{self.source}: missing channel(s) {', '.join(missing)} needed by {purpose}")

    def matrix(self, names) -> np.ndarray:
        """Channels stacked as columns: shape (N, len(names))."""
        self.require(names)
        if not names:
            return np.zeros((len(self.time), 0))
        return np.column_stack([self.channels[n] for n in names])

    def slice(self, t_start: float | None = None, t_end: float | None = None) -> "Run":
        """Sub-run with samples t_start <= t <= t_end (times kept as they are)."""
        lo = -np.inf if t_start is None else t_start - 1e-9
        hi = np.inf if t_end is None else t_end + 1e-9
        keep = (self.time >= lo) & (self.time <= hi)
        if keep.sum() < 2:
            raise RunError(f"{self.source}: fewer than two samples between {t_start} and {t_end} s")
        meta = dict(self.meta, slice=f"{self.time[keep][0]:g}..{self.time[keep][-1]:g} s")
        return Run(self.time[keep], {k: v[keep] for k, v in self.channels.items()}, meta, self.source)

    def with_channels(self, channels: dict[str, np.ndarray], **meta) -> "Run":
        """Copy with channels added or replaced and metadata updated."""
        return Run(self.time, {**self.channels, **channels}, {**self.meta, **{k: str(v) for k, v in meta.items()}},
                   self.source)

    def to_csv(self, path: str | Path, channels: list[str] | None = None) -> Path:
        """Write the run file (metadata comments, header, rows)."""
        path = Path(path)
        names = list(self.channels) if channels is None else list(channels)
        path.write_text(self.to_csv_text(names))
        return path

    def to_csv_text(self, names: list[str] | None = None) -> str:
        names = list(self.channels) if names is None else names
        out = io.StringIO()
        for key, value in self.meta.items():
            out.write(f"# {key}: {_one_line(value)}\n")
        data = np.column_stack([self.time] + [self.channels[n] for n in names])
        out.write(",".join([TIME] + names) + "\n")
        np.savetxt(out, data, delimiter=",", fmt="%.15g")
        return out.getvalue()


def read_run(path: str | Path, require: list[str] | None = None, *, channel_map: dict | None = None,
             profile=None) -> Run:
    """Read a run CSV; ``require`` lists channels that must be present (e.g. ``profile.channels``).
    A file that time gaps split into several runs is an error here: read it with :func:`read_runs`.
    ``channel_map`` and ``profile`` as in :func:`read_run_segments`."""
    run = csv_runs(path, channel_map, profile).one("read_runs")
    if require:
        run.require(require)
    return run


def read_run_segments(path: str | Path, channel_map: dict | None = None, profile=None) -> list[Run]:
    """Every run of a CSV file: one, or several when time gaps split it (:mod:`identify.data.ingest`).

    ``channel_map`` (``{"channels": {channel: column or expression}, "units": {name: unit},
    "time": column}``) adds derived or renamed channels; ``profile`` lets undeclared channels be
    checked against the profile's units (radian channels holding degrees)."""
    return csv_runs(path, channel_map, profile).all()


def csv_runs(path, channel_map=None, profile=None, options=None):
    """A CSV (or other delimited text) file's runs with the notes and warnings of reading it, not
    yet said (an :class:`~identify.data.ingest.Ingested`); ``options`` a
    :class:`~identify.data.ingest.ReadOptions` (NaN policy and window)."""
    path = Path(path)
    try:
        data = path.read_bytes()
        text = data.decode("utf-8-sig")
    except OSError as exc:
        raise RunError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise RunError(f"{path}: not a text (CSV) file") from None
    return _parse(text, str(path), channel_map, profile, options)


def read_runs(paths, require: list[str] | None = None, *, channel_map: dict | None = None,
              profile=None) -> list[Run]:
    """Runs of several files, for multi-run evaluation; a file split by time gaps gives several."""
    runs = [r for p in paths for r in read_run_segments(p, channel_map, profile)]
    for run in runs:
        run.require(require or [])
    return runs


def parse_run(text: str, source: str = "<run>") -> Run:
    """A run from CSV text (see :func:`read_run`)."""
    return _parse(text, source, None, None).one("read_runs")


def _parse(text: str, source: str, channel_map, profile, options=None):
    from .ingest import build_runs

    raw = csv_raw(text, source, channel_map)
    return build_runs(raw, csv_channels(raw, channel_map), profile, options)


# -- a CSV file's raw content (identify.data.ingest makes runs of it) ---------------------------
_BLANKS = re.compile(r"\s+(?![\[(])(?![^\[(]*[\])])")  # blanks not before or inside "[deg/s]" / "(deg/s)"
_HEADER_UNIT = re.compile(r"^(?P<name>.*?)\s*(?:\[(?P<u1>[^\]]*)\]|\((?P<u2>[^)]*)\))\s*$")


def csv_raw(text: str, source: str, channel_map: dict | None = None):
    """A CSV run file's content: ``# key: value`` metadata lines on top (``# units: q=deg/s, ...``
    declares units), a header of column names (``q [deg/s]`` / ``q (deg/s)`` declares a unit),
    one row per sample, delimited by commas (or tabs, semicolons or blanks, as the header is).

    A file without a header (numbers from the first line on, as a whitespace ``.asc`` export) is
    read only with the channel map's ``"columns"`` list naming its columns (else refused, saying
    so: its first row must not silently become the header). Time is the ``time`` (or ``t``)
    column, the map's ``"time"`` column, or ``"dt"`` (s) when the file has no time column."""
    from .ingest import Raw, zero_based

    cmap = channel_map or {}
    lines = text.lstrip("\ufeff").splitlines()
    meta, header, header_line = {}, None, 0
    for lineno, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        if line.startswith("#"):
            key, sep, value = line[1:].partition(":")
            if sep:
                meta[key.strip()] = value.strip()
            continue
        header_line, header = lineno, line
        break
    if header is None:
        raise RunError(f"{source}: no header row of channel names")
    delim = next((d for d in (",", "\t", ";") if d in header), None)  # None: blanks (units in brackets kept)
    cells = next(csv.reader([header], delimiter=delim)) if delim else _BLANKS.split(header.strip())
    trailing = len(cells) > 1 and not cells[-1].strip()  # "time,q," as spreadsheets write it
    declared = cmap.get("columns")
    numeric = all(_is_number(c) for c in (cells[:-1] if trailing else cells))
    if declared is None and numeric:
        raise RunError(f"{source}: line {header_line}: the file has no header (the first row is numbers: "
                       f"{', '.join(c.strip() for c in cells[:6])}{' ...' if len(cells) > 6 else ''}); name its "
                       f"{len(cells) - trailing} columns in the channel map: \"columns\": [\"time\", ...]")
    if declared is not None:
        if not numeric:
            raise RunError(f"{source}: line {header_line}: the channel map declares \"columns\" but the file has a "
                           f"header ({', '.join(c.strip() for c in cells[:6])}): drop \"columns\" or the header")
        if len(declared) != len(cells) - trailing:
            raise RunError(f"{source}: the channel map's \"columns\" names {len(declared)} columns, line "
                           f"{header_line} has {len(cells) - trailing}")
        cells, header_line = [str(c) for c in declared] + ([""] if trailing else []), header_line - 1
        meta["header"] = "none in the file: columns named by the channel map"
    names, units = _header(cells[:-1] if trailing else cells, source, header_line)
    _merge_units(units, U.parse_units_spec(meta["units"], f"{source}: metadata 'units'") if "units" in meta else {},
                 source)
    _merge_units(units, cmap.get("units", {}), source)
    specs, time_name = zero_based(cmap.get("channels", {}), cmap.get("time"), cmap.get("index_base"),
                                  len(names), source)
    dt = cmap.get("dt")
    if time_name is None:  # 'time' in any case, else a column 't'
        time_name = next((n for n in names if n.lower() == TIME), next((n for n in names if n.lower() == "t"), None))
    if isinstance(time_name, int):
        time_name = names[time_name] if -len(names) <= time_name < len(names) else None
    if time_name not in names and dt is None:
        raise RunError(f"{source}: no '{TIME}' column (columns: {', '.join(names)}) and no sample interval: "
                       f"name the time column (\"time\") or give \"dt\" in the channel map")
    values, line_of = _csv_values(lines, header_line, names, delim, trailing, source)

    def column(where, channel):
        if isinstance(where, int) and not isinstance(where, bool):
            if not -len(names) <= where < len(names):
                raise RunError(f"{source}: channel '{channel}': column {where} out of range ({len(names)} columns, "
                               f"0-based: {', '.join(f'{i} {n}' for i, n in enumerate(names))})")
            return values[:, where]
        if where not in names:
            raise RunError(f"{source}: channel '{channel}': no column '{where}' (columns: {', '.join(names)})")
        return values[:, names.index(where)]

    if time_name in names:
        t = column(time_name, TIME)
        if dt is not None:
            step = float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
            if not abs(step - float(dt)) <= 1e-6 * float(dt):
                raise RunError(f"{source}: the channel map's dt {dt} s disagrees with the time column "
                               f"'{time_name}' (step {step:.6g} s): drop one")
    else:
        t = np.arange(len(values)) * float(dt)
        time_name = TIME
        meta["time_from"] = f"dt = {float(dt):g} s from the channel map (the file has no time column)"
    return Raw(source, t, column, names, units, meta, lambda i: f"line {line_of[i]}", time_name, "csv", specs)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def csv_channels(raw, channel_map: dict | None) -> dict[str, object]:
    """A CSV file's run channels: every column but time, plus (or replaced by) the map's channels
    (column numbers made 0-based, see :func:`~identify.data.ingest.zero_based`)."""
    specs = {n: n for n in raw.names if n != raw.time_name}
    specs.update(raw.specs if raw.specs is not None else (channel_map or {}).get("channels", {}))
    return specs


def _header(cells: list[str], source: str, lineno: int) -> tuple[list[str], dict[str, str]]:
    names, units = [], {}
    for cell in cells:
        cell = cell.strip()
        m = _HEADER_UNIT.match(cell)
        name = m.group("name").strip() if m else cell
        if m:
            unit = m.group("u1") if m.group("u1") is not None else m.group("u2")
            U.unit_info(unit, f"{source}: line {lineno}, column '{cell}'")
            units[name] = unit.strip()
        names.append(name)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise RunError(f"{source}: line {lineno}: duplicate column(s) {', '.join(dup)}")
    return names, units


def _merge_units(units: dict, more: dict, source: str) -> None:
    for name, unit in more.items():
        if name in units and U.canonical(units[name]) != U.canonical(unit):
            raise RunError(f"{source}: channel '{name}': unit declared as both '{units[name]}' and '{unit}'")
        units[name] = unit


def _csv_values(lines, header_line, names, delim, trailing, source):
    """The data rows as an (N, columns) array; an empty cell is a missing value (NaN)."""
    rows = [(n, l) for n, l in enumerate(lines[header_line:], start=header_line + 1)
            if l.strip() and not l.startswith("#")]
    if len(rows) < 2:
        raise RunError(f"{source}: fewer than two data rows")
    values = np.empty((len(rows), len(names)))
    for r, (lineno, line) in enumerate(rows):
        cells = _cells(line, delim)
        if trailing and len(cells) == len(names) + 1 and not cells[-1].strip():
            cells.pop()
        if len(cells) != len(names):
            raise RunError(f"{source}: line {lineno}: {len(cells)} values for {len(names)} columns")
        try:
            values[r] = [float(cell) for cell in cells]
        except ValueError:
            values[r] = [_cell(cell, f"{source}: line {lineno}, channel '{name}'") for cell, name in zip(cells, names)]
    return values, [n for n, _ in rows]


def _cells(line: str, delim: str | None) -> list[str]:
    if delim is None:
        return line.split()
    return next(csv.reader([line], delimiter=delim)) if '"' in line else line.split(delim)


def _cell(cell: str, where: str) -> float:
    if not cell.strip():
        return float("nan")
    try:
        return float(cell)
    except ValueError:
        raise RunError(f"{where}: not a number ({cell.strip()!r})") from None


def _check_time(t: np.ndarray, source: str, where=lambda i: f"row {i + 1}", uniform: bool = True) -> None:
    """Time finite and strictly increasing (and, with ``uniform``, evenly sampled); ``where(i)``
    names sample i in the error."""
    if t.ndim != 1 or t.size < 2:
        raise RunError(f"{source}: need at least two time samples")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise RunError(f"{source}: {where(bad[0])}, channel '{TIME}': not finite")
    steps = np.diff(t)
    nonpos = np.flatnonzero(steps <= 0)
    if nonpos.size:
        i = nonpos[0] + 1
        kind = "repeated" if steps[i - 1] == 0 else "decreasing"
        raise RunError(f"{source}: {where(i)}, channel '{TIME}': {kind} time stamp {t[i]:g} s")
    uneven = uneven_steps(steps) if uniform else []
    if len(uneven):
        i = uneven[0] + 1
        raise RunError(f"{source}: {where(i)}, channel '{TIME}': time step {steps[i - 1]:.6g} s "
                       f"differs from the nominal {np.median(steps):.6g} s (non-uniform sampling)")


def uneven_steps(steps: np.ndarray) -> np.ndarray:
    """Indices of time steps off the median (the nominal step) by more than rounding."""
    dt = float(np.median(steps))
    return np.flatnonzero(np.abs(steps - dt) > _UNIFORM_RTOL * max(dt, 1e-12) + 1e-9)


def _one_line(value) -> str:
    return " ".join(str(value).split())

"""Reading run files in the project's CSV run format (see :mod:`identify.data.runs`): a file's raw
content (:func:`csv_raw`), made runs of by :mod:`identify.data.ingest`.

Separate from :mod:`identify.data.runs` so that the run itself knows no reader: runs <- ingest <-
csvfile, no cycle.
"""
from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from ..errors import RunError
from . import units as U
from .ingest import Raw, build_runs, zero_based
from .runs import TIME, Run


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

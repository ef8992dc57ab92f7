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
from .clockstamps import CLOCK, clock_cell, clock_from_first
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
    except OSError as exc:
        raise RunError(f"{path}: cannot read ({exc.strerror or exc})") from None
    text, note = decode(data, str(path))
    return _parse(text, str(path), channel_map, profile, options, [note] if note else [])


def decode(data: bytes, source: str) -> tuple[str, str | None]:
    """A text file's bytes as text, and a note when not UTF-8: UTF-16 with its byte-order mark (a
    spreadsheet's "Unicode text"), else Windows-1252 (an older logger's "°"); bytes that are no
    text (NUL bytes, or undecodable) are refused."""
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError:
            text = ""
        if sum(c < "\x80" for c in text) < 0.9 * len(text) or not text:  # numbers and names are ASCII
            raise RunError(f"{source}: not a text (CSV) file (a UTF-16 mark, then no UTF-16 text)")
        return text, "text encoding UTF-16 (byte-order mark)"
    try:
        return data.decode("utf-8-sig"), None
    except UnicodeDecodeError as exc:
        if b"\0" in data:
            raise RunError(f"{source}: not a text (CSV) file (binary bytes)") from None
        try:
            text = data.decode("cp1252")
        except UnicodeDecodeError:
            raise RunError(f"{source}: not a text (CSV) file (byte {exc.start}: neither UTF-8 nor "
                           "Windows-1252)") from None
        return text, f"not UTF-8 (byte {exc.start}): read as Windows-1252 text"


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


def _parse(text: str, source: str, channel_map, profile, options=None, notes=()):
    raw = csv_raw(text, source, channel_map)
    raw.notes[:0] = notes
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
    notes = []
    first = next((l for l in lines[header_line:] if l.strip() and not l.startswith("#")), "")
    delim = _delimiter(header, first)
    comma = delim != "," and _DECIMAL_COMMA.search(first) is not None
    if comma:  # "0,04;1,25": a decimal comma, as European spreadsheets write numbers
        lines = lines[:header_line] + [l.replace(",", ".") for l in lines[header_line:]]
        header = header.replace(",", ".") if _is_number(header.split(delim)[0].replace(",", ".")) else header
        notes.append(f"numbers read with a decimal comma (line {header_line + 1}: {first.strip()[:40]!r})")
    cells = _cells(header, delim) if delim else _BLANKS.split(header.strip())
    trailing = _trailing_empty(cells)  # "time,q,," as spreadsheets write it
    declared = cmap.get("columns")
    numeric = all(_is_number(c) for c in cells[:len(cells) - trailing])
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
        cells, header_line = [str(c) for c in declared] + [""] * trailing, header_line - 1
        meta["header"] = "none in the file: columns named by the channel map"
    if trailing:
        notes.append(f"{trailing} empty column(s) at the end of every line left out")
    names, units = _header(cells[:len(cells) - trailing], source, header_line)
    if declared is None:
        header_line = _units_row(lines, header_line, names, delim, trailing, units, source, notes)
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
    clock = {"col": names.index(time_name) if time_name in names else None, "rows": 0, "dated": 0}
    values, line_of = _csv_values(lines, header_line, names, delim, trailing, source, notes,
                                  text.endswith(("\n", "\r")), clock)
    if clock["rows"]:
        _clock_time(values, line_of, clock, units.get(time_name, units.get(TIME)), meta, notes, source)

    def column(where, channel):
        if isinstance(where, int) and not isinstance(where, bool):
            if not -len(names) <= where < len(names):
                raise RunError(f"{source}: channel '{channel}': column {where} out of range ({len(names)} columns, "
                               f"0-based: {', '.join(f'{i} {n}' for i, n in enumerate(names))})")
            return values[:, where]
        if where not in names:
            raise RunError(f"{source}: channel '{channel}': no column '{where}' (columns: {', '.join(names)})")
        return values[:, names.index(where)]

    resolution = None
    if time_name in names:
        t = column(time_name, TIME)
        resolution = _written_resolution(lines, line_of, names.index(time_name), delim)
        if dt is not None:  # "dt" is in s: the time column's step in its declared unit, converted
            unit = units.get(time_name, units.get(TIME))
            scale = U.unit_info(unit, f"{source}: channel '{time_name}'")[1] if unit else 1.0
            step = scale * float(np.median(np.diff(t))) if len(t) > 1 else float("nan")
            if not abs(step - float(dt)) <= 1e-6 * float(dt):
                raise RunError(f"{source}: the channel map's dt {dt} s disagrees with the time column "
                               f"'{time_name}' (step {step:.6g} s): drop one")
    else:
        t = np.arange(len(values)) * float(dt)
        time_name = TIME
        meta["time_from"] = f"dt = {float(dt):g} s from the channel map (the file has no time column)"
    return Raw(source, t, column, names, units, meta, lambda i: f"line {line_of[i]}", time_name, "csv", specs,
               notes, resolution, cmap.get("missing"))


def _written_resolution(lines, line_of, j: int, delim):
    """The resolution of column ``j`` as written (``10^-decimals``, the most decimals of any row),
    with why; None for numbers in exponent form."""
    decimals = 0
    for lineno in line_of:
        cell = _cells(lines[lineno - 1], delim)[j].strip().strip('"')
        if "e" in cell.lower():
            return None
        decimals = max(decimals, len(cell.partition(".")[2]))
    return 10.0 ** -decimals, f"written with {decimals} decimal(s)"


_DECIMAL_COMMA = re.compile(r"(?:^|[;\t\s])[-+]?\d*,\d+(?:[eE][-+]?\d+)?(?=$|[;\t\s])")


def _delimiter(header: str, first: str) -> str | None:
    """The delimiter that splits the header and the first data line into as many cells (more than
    one): a comma, tab or semicolon, tried in that order; else a comma, tab or semicolon in the
    header as before; None: blanks."""
    for d in (",", "\t", ";"):
        n = len(_cells(header, d))
        if n > 1 and n == len(_cells(first, d)):
            return d
    return next((d for d in (",", "\t", ";") if d in header), None)


def _trailing_empty(cells: list[str]) -> int:
    """How many empty cells end the header (never all of them)."""
    k = 0
    while k < len(cells) - 1 and not cells[len(cells) - 1 - k].strip():
        k += 1
    return k


def _units_row(lines, header_line, names, delim, trailing, units, source, notes) -> int:
    """A row of units under the header (``s, deg/s, g``: no number, at least one unit) is read as
    the columns' units; the header line number to read data after (moved past it)."""
    for lineno, line in enumerate(lines[header_line:], start=header_line + 1):
        if not line.strip() or line.startswith("#"):
            continue
        cells = [c.strip().strip("[]()") for c in _cells(line, delim)][:len(names)]
        if any(_is_number(c) for c in cells) or not any(c and U.canonical(c) for c in cells):
            return header_line
        if len(cells) != len(names):
            raise RunError(f"{source}: line {lineno}: a row of units? {len(cells)} cells for {len(names)} columns")
        row = {n: c for n, c in zip(names, cells) if c}
        for name, unit in row.items():
            U.unit_info(unit, f"{source}: line {lineno} (units under the header), column '{name}'")
        _merge_units(units, row, source)
        notes.append(f"line {lineno} under the header read as the columns' units ({', '.join(cells[:6])}"
                     f"{' ...' if len(cells) > 6 else ''})")
        return lineno
    return header_line


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


def _csv_values(lines, header_line, names, delim, trailing, source, notes, ends_with_break=True, clock=None):
    """The data rows as an (N, columns) array; an empty cell is a missing value (NaN). A last line
    with too few values in a file that does not end with a line break (a write cut short) is
    left out, said in ``notes``. Clock stamps (``12:34:56.020``, with a date or not) in the
    column ``clock["col"]`` are read as seconds of their day (plus the days since the first stamp's
    date), counted in ``clock``."""
    rows = [(n, l) for n, l in enumerate(lines[header_line:], start=header_line + 1)
            if l.strip() and not l.startswith("#")]
    if rows and not ends_with_break and len(_cells(rows[-1][1], delim)) < len(names):
        lineno, line = rows.pop()
        notes.append(f"line {lineno}, the last, is cut short ({len(_cells(line, delim))} values for {len(names)} "
                     "columns, no line break at the end of the file: a write cut short): left out")
    elif rows and not ends_with_break and _cut_in_last_cell(rows, delim, len(names)):
        lineno, line = rows.pop()
        notes.append(f"line {lineno}, the last, ends in a value shorter than every line before it writes that column "
                     f"({_cells(line, delim)[len(names) - 1].strip()!r}), no line break at the end of the file: "
                     "a write cut short inside its last value: left out")
    if len(rows) < 2:
        raise RunError(f"{source}: fewer than two data rows")
    values = np.empty((len(rows), len(names)))
    for r, (lineno, line) in enumerate(rows):
        cells = _cells(line, delim)
        extra = len(cells) - len(names)
        if 0 < extra <= trailing and not any(c.strip() for c in cells[len(names):]):
            del cells[len(names):]
        if len(cells) != len(names):
            raise RunError(f"{source}: line {lineno}: {len(cells)} values for {len(names)} columns")
        try:
            values[r] = [float(cell) for cell in cells]
        except ValueError:
            values[r] = [clock_cell(cell, clock) if clock and j == clock["col"] and CLOCK.match(cell.strip())
                         else _cell(cell, f"{source}: line {lineno}, channel '{name}'")
                         for j, (cell, name) in enumerate(zip(cells, names))]
    return values, [n for n, _ in rows]


CUT_CHECK_ROWS = 50  # rows before the last whose last column must all have one written width
CUT_MIN_ROWS = 20  # fewer rows: too few to call a width the column's format


def _cut_in_last_cell(rows, delim, n: int) -> bool:
    """Whether the last row's last value was cut: shorter after its decimal point than that column
    in every one of the rows before it, which all write the same number of characters there (a
    fixed format: with varying widths, %g, nothing can be told), or empty."""
    cells = _cells(rows[-1][1], delim)
    if len(cells) != n or len(rows) < CUT_MIN_ROWS:
        return False
    last = cells[-1].strip()

    def decimals(cell: str) -> int | None:
        return len(cell) - cell.find(".") - 1 if "." in cell else None

    before = [_cells(line, delim) for _, line in rows[-CUT_CHECK_ROWS - 1:-1]]
    widths = {decimals(c[n - 1].strip()) if len(c) >= n else None for c in before}
    if len(widths) != 1 or None in widths:
        return not last
    return not last or decimals(last) is None or decimals(last) < widths.pop()


_DATE_TIME = re.compile(r"(\d{4}-\d{2}-\d{2}) (\d{1,2}:\d{2}:\d{2})")  # one cell in a blank-separated file


def _clock_time(values, line_of, clock: dict, unit, meta: dict, notes: list, source: str) -> None:
    """The clock column made seconds from the first sample (in place), said and recorded."""
    j = clock["col"]
    text = clock_from_first(values[:, j], clock, unit, source, lambda i: f"line {line_of[i]}")
    meta["time_from"] = text
    notes.append(text)


def _cells(line: str, delim: str | None) -> list[str]:
    if delim is None:
        return _DATE_TIME.sub(r"\1T\2", line).split()
    return next(csv.reader([line], delimiter=delim)) if '"' in line else line.split(delim)


def _cell(cell: str, where: str) -> float:
    if not cell.strip():
        return float("nan")
    try:
        return float(cell)
    except ValueError:
        raise RunError(f"{where}: not a number ({cell.strip()!r})") from None

"""The one door through which every command reads runs: CSV run files and MATLAB ``.mat`` files.

``identify estimate`` and ``identify refine`` read through :func:`read_run_files`, the cueing
replay source through :func:`read_run_file`. A channel map (:func:`load_channel_map`) names each
channel's source (a column, a variable, a data-matrix column or an arithmetic expression of them)
and the units to convert from; both readers then apply the same steps (:mod:`identify.data.ingest`:
units to SI, derived channels, degree check, time jitter and gaps). A file that time gaps split
gives several runs.
"""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import RunError, read_text
from .matfile import mat_runs
from .csvfile import csv_runs
from .runs import Run
from .units import unit_info


KEYS = {"time", "matrix", "dt", "units", "columns", "index_base", "missing"}  # a map's keys besides "channels"


def load_channel_map(spec: str | Path) -> dict:
    """A channel map from a JSON file or JSON text.

    Form: ``{"channels": {channel: variable, column or expression}, "units": {name: unit},
    "time": variable or column, "matrix": name or pattern ("{stem}": the file's name), "dt":
    seconds, "columns": [names of a headerless text file's columns], "index_base": 0 or 1, "missing":
    marker value(s) of missing samples (-999 or [-999, 99999]), or {name: value(s)} per channel}``; a
    flat ``{channel: variable or column}`` is read as ``{"channels": ...}``.
    """
    text = str(spec)
    path = Path(text)
    source = text
    if not text.lstrip().startswith("{"):
        text = read_text(path, RunError, "channel map")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RunError(f"{source}: channel map is not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise RunError(f"{source}: channel map must be a JSON object")
    if "channels" not in data:
        # a map of the structural keys alone (e.g. "columns" naming a headerless file's columns, which
        # are then the channels) is not a flat {channel: source} map
        data = dict(data, channels={}) if set(data) & KEYS and "columns" in data else {"channels": data}
    unknown = set(data) - KEYS - {"channels"}
    if unknown:
        raise RunError(f"{source}: channel map has unknown key(s) {', '.join(sorted(unknown))}")
    if not isinstance(data["channels"], dict) or not (data["channels"] or "columns" in data):
        raise RunError(f"{source}: channel map 'channels' must be a non-empty object"
                       + (" (or give \"columns\", the names of a headerless file's columns)" if set(data) & KEYS else ""))
    units = data.get("units", {})
    if not isinstance(units, dict) or not all(isinstance(u, str) for u in units.values()):
        raise RunError(f"{source}: channel map 'units' must be an object of {{name: unit}} strings")
    for name, unit in units.items():
        unit_info(unit, f"{source}: channel map: units of '{name}'")
    columns = data.get("columns")
    if columns is not None and (not isinstance(columns, list) or not all(isinstance(c, str) and c for c in columns)):
        raise RunError(f"{source}: channel map 'columns' must be a list of column names")
    _check_missing(data.get("missing"), source)
    return data


def _check_missing(missing, source) -> None:
    """The map's "missing": a number, a list of numbers, or {name: number or list}."""
    def numbers(v):
        items = v if isinstance(v, list) else [v]
        return bool(items) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in items)

    if missing is None or numbers(missing):
        return
    if isinstance(missing, dict) and missing and all(numbers(v) for v in missing.values()):
        return
    raise RunError(f"{source}: channel map 'missing' must be a number (the value written for a missing sample, "
                   f"e.g. -999), a list of numbers, or {{channel: number or list}}, got {missing!r}")


def read_run_file(path: str | Path, channel_map: dict | None = None, profile=None, options=None) -> Run:
    """The run of a CSV run file or, with ``.mat`` suffix, a MATLAB file (v5 or v7.3) read through
    ``channel_map`` (without one every vector variable is read). ``profile`` lets channels without
    a declared unit be checked against the profile's. A file that time gaps split is an error
    here: use :func:`read_run_files`."""
    return _ingest(path, channel_map, profile, options).one("read_run_files")


def read_file_runs(path: str | Path, channel_map: dict | None = None, profile=None, options=None) -> list[Run]:
    """Every run of one CSV or ``.mat`` file (several when time gaps split it)."""
    return _ingest(path, channel_map, profile, options).all()


def read_run_files(paths, channel_map: dict | None = None, profile=None, options=None) -> list[Run]:
    """Runs from several files (CSV or ``.mat``), in order, each file's segments in turn;
    ``options`` a :class:`~identify.data.ingest.ReadOptions` (NaN policy and window)."""
    return [r for p in paths for r in read_file_runs(p, channel_map, profile, options)]


def read_runs(paths, require: list[str] | None = None, *, channel_map: dict | str | Path | None = None,
              profile=None, options=None) -> list[Run]:
    """Runs of several CSV or ``.mat`` files (:func:`read_run_files`), ``channel_map`` a map, a
    JSON file or JSON text; each run must hold the channels ``require`` lists."""
    cmap = load_channel_map(channel_map) if channel_map is not None and not isinstance(channel_map, dict) else channel_map
    runs = read_run_files(paths, cmap, profile, options)
    for run in runs:
        run.require(require or [])
    return runs


def _ingest(path, channel_map, profile, options=None):
    path = Path(path)
    if path.suffix.lower() != ".mat":
        got = csv_runs(path, channel_map, profile, options)
    else:
        cmap = channel_map or {}
        got = mat_runs(path, cmap.get("channels") or None, time=cmap.get("time"), matrix=cmap.get("matrix"),
                       dt=cmap.get("dt"), units=cmap.get("units"), meta=None, profile=profile,
                       index_base=cmap.get("index_base"), options=options, missing=cmap.get("missing"))
    digest = file_sha256(path)
    for run in got.runs:  # provenance: which bytes these numbers came from
        if run.meta.get("sha256", digest) != digest:  # a file written from another (compat's corrected runs)
            run.meta["upstream_sha256"] = run.meta["sha256"]
        run.meta["sha256"] = digest
        if channel_map and "channel_map" not in run.meta:
            run.meta["channel_map"] = json.dumps(channel_map, separators=(",", ":"))
    return got


def file_sha256(path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()

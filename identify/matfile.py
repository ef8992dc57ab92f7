"""Runs from MATLAB ``.mat`` files, the way most flight-test data arrives.

Two layouts are read (the SIDPAC / FVSysID conventions):

* named variables — one vector per channel (``t``, ``q``, ``theta_s`` ...); the channel map is
  ``{channel: variable name}``;
* a data matrix — one variable (``data``, ``Z`` or ``fdata``) with one column per channel; the map
  is ``{channel: column index}``, 0-based as in Python (MATLAB column 1 is index 0).

Time comes from a named variable or matrix column (``time=``), else from the variables ``t`` /
``time`` if present, else from a sample interval ``dt`` in s. Every problem (unreadable file, missing
variable, wrong length, NaN) raises one :class:`~identify.errors.RunError` naming the file and the
variable or column.
"""
from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np

from .errors import RunError
from .runs import Run

MATRIX_NAMES = ("data", "Z", "fdata")
TIME_NAMES = ("t", "time")


def load_channel_map(spec: str | Path) -> dict:
    """A channel map from a JSON file or JSON text.

    Form: ``{"channels": {channel: variable or column}, "time": variable or column,
    "matrix": name, "dt": seconds}``; a flat ``{channel: variable or column}`` is read as
    ``{"channels": ...}``.
    """
    text = str(spec)
    path = Path(text)
    source = text
    if not text.lstrip().startswith("{"):
        try:
            text = path.read_text()
        except OSError as exc:
            raise RunError(f"{spec}: cannot read channel map ({exc.strerror or exc})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RunError(f"{source}: channel map is not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise RunError(f"{source}: channel map must be a JSON object")
    if "channels" not in data:
        data = {"channels": data}
    unknown = set(data) - {"channels", "time", "matrix", "dt"}
    if unknown:
        raise RunError(f"{source}: channel map has unknown key(s) {', '.join(sorted(unknown))}")
    if not isinstance(data["channels"], dict) or not data["channels"]:
        raise RunError(f"{source}: channel map 'channels' must be a non-empty object")
    return data


def read_mat(path: str | Path, channels: dict[str, str | int] | None = None, *, time: str | int | None = None,
             matrix: str | None = None, dt: float | None = None, meta: dict | None = None) -> Run:
    """Read a run from a ``.mat`` file.

    ``channels`` maps run channel names to variable names (str) or data-matrix columns (int). If
    ``None``, every numeric vector variable as long as the time vector becomes a channel of its own
    name. ``time`` names the time variable or column; ``matrix`` the data-matrix variable (default:
    the first of ``data``, ``Z``, ``fdata`` present); ``dt`` the sample interval in s when the file
    holds no time.
    """
    path = Path(path)
    source = str(path)
    variables = _load(path)
    channels = dict(channels) if channels is not None else None
    uses_columns = any(isinstance(v, (int, np.integer)) and not isinstance(v, bool)
                       for v in (channels or {}).values()) or isinstance(time, int)
    data = _matrix(variables, matrix, source) if uses_columns or matrix else None

    t = _time(variables, data, time, dt, source)
    n = len(t)
    if channels is None:
        channels = {k: k for k, v in variables.items()
                    if k not in TIME_NAMES and k != time and _is_vector(v) and np.asarray(v).size == n}
        if not channels:
            raise RunError(f"{source}: no vector variables of {n} samples to read as channels")
    out = {}
    for name, where in channels.items():
        values = _column(variables, data, where, source, f"channel '{name}'")
        if values.size != n:
            raise RunError(f"{source}: channel '{name}' ({_describe(where)}) has {values.size} samples, "
                           f"time has {n}")
        _finite(values, source, f"channel '{name}' ({_describe(where)})")
        out[name] = values
    info = {"source_format": "MATLAB .mat", "channel_map": json.dumps(channels, separators=(",", ":"))}
    info.update(meta or {})
    return Run(t, out, {k: str(v) for k, v in info.items()}, source=source)


def _load(path: Path) -> dict:
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    if not path.is_file():
        raise RunError(f"{path}: no such file")
    try:
        raw = loadmat(path, squeeze_me=False)
    except (MatReadError, ValueError, OSError, TypeError, IndexError, KeyError, EOFError,
            NotImplementedError, zlib.error) as exc:  # what scipy's reader raises on a damaged file
        raise RunError(f"{path}: not a readable MATLAB .mat file ({' '.join(str(exc).split()) or type(exc).__name__})") from None
    return {k: v for k, v in raw.items() if not k.startswith("__")}


def _is_vector(v) -> bool:
    a = np.asarray(v)
    return a.dtype.kind in "fiu" and a.ndim <= 2 and sum(s > 1 for s in a.shape) == 1


def _matrix(variables: dict, name: str | None, source: str) -> np.ndarray:
    names = [name] if name else [m for m in MATRIX_NAMES if m in variables]
    if not names or names[0] not in variables:
        wanted = name or " / ".join(MATRIX_NAMES)
        raise RunError(f"{source}: no data-matrix variable '{wanted}' (variables: {', '.join(sorted(variables))})")
    m = np.asarray(variables[names[0]])
    if m.dtype.kind not in "fiu" or m.ndim != 2:
        raise RunError(f"{source}: variable '{names[0]}' is not a numeric 2-D data matrix")
    return m.astype(float)


def _column(variables: dict, data, where, source: str, what: str) -> np.ndarray:
    if isinstance(where, (int, np.integer)) and not isinstance(where, bool):
        if data is None:
            raise RunError(f"{source}: {what} names column {where} but no data matrix was read")
        if not -data.shape[1] <= where < data.shape[1]:
            raise RunError(f"{source}: {what}: column {where} out of range (the data matrix has "
                           f"{data.shape[1]} columns, 0-based)")
        return data[:, where]
    if not isinstance(where, str):
        raise RunError(f"{source}: {what}: expected a variable name or a column index, got {where!r}")
    if where not in variables:
        raise RunError(f"{source}: {what}: no variable '{where}' in the file")
    v = variables[where]
    if not _is_vector(v):
        raise RunError(f"{source}: {what}: variable '{where}' is not a numeric vector "
                       f"(shape {np.shape(v)})")
    return np.asarray(v, dtype=float).ravel()


def _time(variables: dict, data, time, dt, source: str) -> np.ndarray:
    if time is None:
        time = next((k for k in TIME_NAMES if k in variables), None)
    if time is not None:
        t = _column(variables, data, time, source, "time")
        _finite(t, source, f"time ({_describe(time)})")
        return t
    if dt is None:
        raise RunError(f"{source}: no time variable ('t' or 'time') and no sample interval (dt) given")
    if not (np.isfinite(dt) and dt > 0):
        raise RunError(f"{source}: sample interval dt must be positive, got {dt}")
    if data is not None:
        n = data.shape[0]
    else:
        lengths = {np.asarray(v).size for v in variables.values() if _is_vector(v)}
        if not lengths:
            raise RunError(f"{source}: no numeric vector variables")
        n = max(lengths)
    return np.arange(n) * float(dt)


def _finite(values: np.ndarray, source: str, what: str) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise RunError(f"{source}: {what}: {values[bad[0]]} value at sample {bad[0] + 1} "
                       f"({bad.size} non-finite value(s))")


def _describe(where) -> str:
    return f"column {where}" if isinstance(where, (int, np.integer)) else f"variable '{where}'"


def read_run_file(path: str | Path, channel_map: dict | None = None) -> Run:
    """A run from a CSV run file or, with ``.mat`` suffix, a MATLAB file read through
    ``channel_map`` (see :func:`load_channel_map`; without one every vector variable is read)."""
    from .runs import read_run

    path = Path(path)
    if path.suffix.lower() != ".mat":
        return read_run(path)
    cmap = channel_map or {}
    return read_mat(path, cmap.get("channels"), time=cmap.get("time"), matrix=cmap.get("matrix"),
                    dt=cmap.get("dt"))

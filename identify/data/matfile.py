"""Runs from MATLAB ``.mat`` files, the way most flight-test data arrives.

Two layouts are read (the SIDPAC / FVSysID conventions):

* named variables — one vector per channel (``t``, ``q``, ``theta_s`` ...); the channel map is
  ``{channel: variable name}``;
* a data matrix — one variable with one column per channel: ``data``, ``Z`` or ``fdata``, the map's
  ``"matrix"`` (a name, or a pattern such as ``"{stem}"``: the file's name without suffix, so one
  map reads every file of a data set whose matrices are named after their files), or the only
  2-D numeric variable the file holds; the map is ``{channel: column index}``, 0-based as in Python
  unless the map declares ``"index_base": 1`` (MATLAB numbering; numbers that look 1-based
  undeclared are refused).

A struct array (``flight(1).t``, ``flight(2).t`` in a 1x2 ``flight``) gives one run per element
when the map names its fields as ``flight.t``; ``flight(2).t`` names one element's field.

Time comes from a named variable or matrix column (``time=``), else from the variables ``t`` /
``time`` if present, else from a sample interval ``dt`` in s. Every problem (unreadable file, missing
variable, wrong length, NaN) raises one :class:`~identify.errors.RunError` naming the file and the
variable or column.
"""
from __future__ import annotations

import json
import re
import zlib
from pathlib import Path

import numpy as np

from ..errors import RunError
from .clockstamps import CLOCK, clock_cell, clock_from_first
from .ingest import Ingested, Raw, build_runs, is_index, zero_based
from .runs import Run

MATRIX_NAMES = ("data", "Z", "fdata")
TIME_NAMES = ("t", "time")


def read_mat(path: str | Path, channels: dict[str, str | int] | None = None, *, time: str | int | None = None,
             matrix: str | None = None, dt: float | None = None, units: dict[str, str] | None = None,
             meta: dict | None = None, profile=None, index_base: int | None = None) -> Run:
    """Read a run from a ``.mat`` file (MATLAB v5 through scipy, v7.3 through h5py).

    ``channels`` maps run channel names to variable names (str; ``s.q`` for a struct field),
    data-matrix columns (int) or arithmetic expressions of them (``"(dar - dal)/2"``). If ``None``,
    every numeric vector variable as long as the time vector becomes a channel of its own name.
    ``time`` names the time variable or column; ``matrix`` the data-matrix variable (default: the
    first of ``data``, ``Z``, ``fdata`` present); ``dt`` the sample interval in s when the file
    holds no time; ``units`` declared units by channel or variable name (converted to SI);
    ``index_base`` how ``channels``' matrix columns are numbered (0, as in Python, or 1, MATLAB's;
    None: 0, numbers that look 1-based refused). A file that time gaps split into several runs
    is an error here: use :func:`read_mat_runs`.
    """
    return mat_runs(path, channels, time=time, matrix=matrix, dt=dt, units=units, meta=meta,
                    profile=profile, index_base=index_base).one("read_mat_runs")


def read_mat_runs(path: str | Path, channels: dict[str, str | int] | None = None, *,
                  time: str | int | None = None, matrix: str | None = None, dt: float | None = None,
                  units: dict[str, str] | None = None, meta: dict | None = None, profile=None,
                  index_base: int | None = None) -> list[Run]:
    """Every run of a ``.mat`` file (several when time gaps split it); arguments as :func:`read_mat`."""
    return mat_runs(path, channels, time=time, matrix=matrix, dt=dt, units=units, meta=meta, profile=profile,
                    index_base=index_base).all()


def mat_runs(path, channels=None, *, time=None, matrix=None, dt=None, units=None, meta=None, profile=None,
             index_base=None, options=None, missing=None):
    """A ``.mat`` file's runs with the notes and warnings of reading it, not yet said
    (an :class:`~identify.data.ingest.Ingested`); arguments as :func:`read_mat`, ``index_base``
    the map's column numbering, ``options`` a :class:`~identify.data.ingest.ReadOptions`, ``missing`` the
    map's missing-value markers."""
    path = Path(path)
    variables, version = _load(path)
    elements = _struct_elements(variables, channels, time)
    if elements:
        parts = [_mat_file_runs(path, _element(variables, s, k), version, channels, time, matrix, dt, units,
                                dict(meta or {}, struct_element=f"{s}({k})"), profile, index_base, options,
                                f"{path} [{s}({k})]", missing)
                 for s, k in elements]
        return Ingested([r for p in parts for r in p.runs], [m for p in parts for m in p.messages])
    return _mat_file_runs(path, variables, version, channels, time, matrix, dt, units, meta, profile, index_base,
                          options, str(path), missing)


def _mat_file_runs(path, variables, version, channels, time, matrix, dt, units, meta, profile, index_base,
                   options, source, missing=None):
    channels = dict(channels) if channels is not None else None
    uses_columns = any(is_index(v) for v in (channels or {}).values()) or is_index(time)
    data_name = [None, None]
    data = _matrix(variables, matrix.replace("{stem}", path.stem) if matrix else None, source, data_name) \
        if uses_columns or matrix else None
    notes = [data_name[1]] if data_name[1] else []
    if data is not None:
        channels, time = zero_based(channels or {}, time, index_base, data.shape[1], source)

    time_name = time if isinstance(time, str) else (_time_name(variables) or "time")
    t, clock = _time(variables, data, time, dt, (units or {}).get(time_name), source)
    if clock:
        notes.append(clock)
    n = len(t)
    stored = variables[data_name[0]] if is_index(time) else variables.get(time_name)
    resolution = None
    if stored is not None and np.asarray(stored).dtype == np.float32:  # 24 bits: a clock offset eats them
        peak = float(np.max(np.abs(t)))
        resolution = (float(np.spacing(np.float32(peak))), f"single precision at {peak:.7g}")
    if channels is None:
        channels = {k: k for k, v in variables.items()
                    if k not in (*TIME_NAMES, time_name) and _is_vector(v) and np.asarray(v).size == n}
        if not channels:
            raise RunError(f"{source}: no vector variables of {n} samples to read as channels")

    def column(where, name):
        values = _column(variables, data, where, source, f"channel '{name}'")
        if values.size != n:
            raise RunError(f"{source}: channel '{name}' ({_describe(where)}) has {values.size} samples, "
                           f"time has {n}")
        return values

    info = {"source_format": f"MATLAB .mat {version}", "channel_map": json.dumps(channels, separators=(",", ":"))}
    if data is not None:
        info["matrix"] = data_name[0] + (f" ({data_name[1]})" if data_name[1] else "")
    if clock:
        info["time_from"] = clock
    info.update(meta or {})
    raw = Raw(source, t, column, list(variables), dict(units or {}), {k: str(v) for k, v in info.items()},
              time_name=time_name, file_format="mat", notes=notes, time_resolution=resolution, missing=missing)
    return build_runs(raw, channels, profile, options)


_ELEMENT = re.compile(r"^(?P<struct>[A-Za-z]\w*)\((?P<k>\d+)\)\.")


def _struct_elements(variables: dict, channels, time) -> list[tuple[str, int]]:
    """``[(struct, k), ...]`` when the map names fields of a struct array as ``struct.field``
    (one run per element), else []."""
    arrays = {}
    for key in variables:
        m = _ELEMENT.match(key)
        if m:
            arrays.setdefault(m.group("struct"), set()).add(int(m.group("k")))
    if not arrays:
        return []
    refs = [v for v in (channels or {}).values() if isinstance(v, str)] + ([time] if isinstance(time, str) else [])
    refs += [n for v in refs for n in re.findall(r"[A-Za-z_]\w*(?:\.\w+)+", v)]
    named = {r.split(".")[0] for r in refs if "." in r and r.split(".")[0] in arrays and r not in variables}
    if channels is None and len(arrays) == 1 and not any(not _ELEMENT.match(k) for k in variables):
        named = set(arrays)
    if len(named) > 1:
        raise RunError(f"channel map names fields of several struct arrays ({', '.join(sorted(named))}): "
                       "name one element's fields, e.g. 'flight(1).t'")
    return [(s, k) for s in named for k in sorted(arrays[s])]


def _element(variables: dict, struct: str, k: int) -> dict:
    """The variables with element ``k`` of the struct array ``struct`` readable as ``struct.field``."""
    prefix = f"{struct}({k})."
    out = {key: v for key, v in variables.items() if not key.startswith(f"{struct}(")}
    out.update({f"{struct}.{key[len(prefix):]}": v for key, v in variables.items() if key.startswith(prefix)})
    return out


def _load(path: Path) -> tuple[dict, str]:
    """The file's variables (struct fields flattened to ``struct.field``) and its format version."""
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    if not path.is_file():
        raise RunError(f"{path}: no such file")
    if _is_hdf5(path):
        return load_mat73(path), "v7.3"
    try:
        raw = loadmat(path, simplify_cells=True)
    except NotImplementedError as exc:  # a v7.3 file whose HDF5 signature was not found
        raise RunError(f"{path}: not a readable MATLAB .mat file ({exc})") from None
    except (MatReadError, ValueError, OSError, TypeError, IndexError, KeyError, EOFError,
            zlib.error) as exc:  # what scipy's reader raises on a damaged file
        raise RunError(f"{path}: not a readable MATLAB .mat file "
                       f"({' '.join(str(exc).split()) or type(exc).__name__})") from None
    skipped = []
    variables = _Variables(_flatten({k: v for k, v in raw.items() if not k.startswith("__")}, "", skipped))
    variables.skipped = skipped
    return variables, "v5"


class _Variables(dict):
    """A file's readable variables, and (``skipped``) those that are no channels: cells, text."""

    skipped: list


# -- MATLAB v7.3 ------------------------------------------------------------------------------------
_NUMERIC_CLASSES = {"double", "single", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32",
                    "uint64", "logical"}


def load_mat73(path) -> dict[str, np.ndarray]:
    """Numeric variables of a MATLAB v7.3 file (HDF5, read with h5py), struct fields as
    ``struct.field``. MATLAB stores arrays column-major, so h5py sees each one transposed; the
    transpose restores MATLAB's shape. Strings, cells and empty arrays are left out."""
    import h5py

    out = {}

    def visit(name, obj):
        if not isinstance(obj, h5py.Dataset) or name.startswith("#"):
            return
        cls = obj.attrs.get("MATLAB_class", b"double")
        cls = cls.decode() if isinstance(cls, bytes) else str(cls)
        if cls in _NUMERIC_CLASSES and "MATLAB_empty" not in obj.attrs and obj.dtype.kind in "fiub":
            out[name.replace("/", ".")] = np.asarray(obj[()]).T

    try:
        with h5py.File(path, "r") as f:
            f.visititems(visit)
    except (OSError, KeyError, ValueError) as exc:
        raise RunError(f"{path}: not a readable MATLAB v7.3 (HDF5) file ({exc})") from None
    return out


def _is_hdf5(path: Path) -> bool:
    import h5py

    try:
        return bool(h5py.is_hdf5(path))
    except OSError:
        return False


def _flatten(variables: dict, prefix: str = "", skipped: list | None = None) -> dict:
    """Struct fields as ``struct.field``, a struct array's as ``struct(k).field`` (1-based k, as
    MATLAB names them); cells and text are no channels (named in ``skipped``)."""
    out = {}
    for key, value in variables.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}.", skipped))
        elif _is_struct_array(value):
            for k, element in enumerate(np.ravel(np.asarray(value, dtype=object)) if not isinstance(value, list)
                                        else value, start=1):
                out.update(_flatten(element, f"{prefix}{key}({k}).", skipped))
        elif isinstance(value, (np.ndarray, int, float)) and np.asarray(value).dtype != object:
            out[f"{prefix}{key}"] = value
        elif isinstance(value, (list, np.ndarray)) and len(value) > 1 and all(isinstance(v, str) for v in value):
            out[f"{prefix}{key}"] = np.asarray(value, dtype=str)  # a cell array of text: clock stamps, maybe
        elif skipped is not None:
            kind = "text" if isinstance(value, str) else f"cell array of {len(value) if hasattr(value, '__len__') else 1}"
            skipped.append(f"{prefix}{key} ({kind})")
    return out


def _is_struct_array(value) -> bool:
    items = value if isinstance(value, list) else (list(np.ravel(value)) if isinstance(value, np.ndarray)
                                                    and value.dtype == object else None)
    return bool(items) and all(isinstance(v, dict) for v in items)


def _is_vector(v) -> bool:
    a = np.asarray(v)
    return a.dtype.kind in "fiu" and a.ndim <= 2 and sum(s > 1 for s in a.shape) == 1


def _matrix(variables: dict, name: str | None, source: str, found: list | None = None) -> np.ndarray:
    """The data matrix: ``name``, else the first of MATRIX_NAMES, else the file's only 2-D numeric
    non-vector variable (its name in ``found[0]``). One column per channel; a matrix of fewer rows
    than columns holds its channels in rows (a record has more samples than channels) and is read
    transposed, said in ``found[1]``."""
    names = [name] if name else [m for m in MATRIX_NAMES if m in variables]
    if not names:
        names = [k for k, v in variables.items() if np.asarray(v).ndim == 2 and np.asarray(v).dtype.kind in "fiu"
                 and not _is_vector(v)]
        if len(names) > 1:
            raise RunError(f"{source}: several data matrices ({', '.join(names)}) and none named: give \"matrix\" "
                           "in the channel map (a name, or a pattern such as \"{stem}\" for the file's name)")
    if not names or names[0] not in variables:
        wanted = name or " / ".join(MATRIX_NAMES)
        raise RunError(f"{source}: no data-matrix variable '{wanted}' (variables: {_listing(variables)})")
    if found is not None:
        found[0] = names[0]
    m = np.asarray(variables[names[0]])
    m = m[:, None] if m.ndim == 1 else m  # one column, squeezed on loading
    if m.dtype.kind not in "fiu" or m.ndim != 2:
        raise RunError(f"{source}: variable '{names[0]}' is not a numeric 2-D data matrix")
    if m.shape[0] < m.shape[1]:
        if found is not None:
            found[1] = (f"data matrix '{names[0]}' is {m.shape[0]} x {m.shape[1]}: fewer rows than columns, read "
                        f"as {m.shape[0]} channels in rows of {m.shape[1]} samples (transposed)")
        m = m.T
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
        raise RunError(f"{source}: {what}: no variable '{where}' in the file (variables: {_listing(variables)})")
    v = variables[where]
    if not _is_vector(v):
        raise RunError(f"{source}: {what}: variable '{where}' is not a numeric vector "
                       f"(shape {np.shape(v)})")
    return np.asarray(v, dtype=float).ravel()


def _time_name(variables: dict) -> str | None:
    """``t`` or ``time``, else the one struct field so named (``flight.t``)."""
    top = next((k for k in TIME_NAMES if k in variables), None)
    fields = [k for k in variables if k.rpartition(".")[2] in TIME_NAMES]
    return top or (fields[0] if len(fields) == 1 else None)


def _time(variables: dict, data, time, dt, unit, source: str) -> tuple[np.ndarray, str | None]:
    """The time vector, and what was done to it when it is text (clock stamps), else None."""
    if time is None:
        time = _time_name(variables)
    if isinstance(time, str) and np.asarray(variables.get(time, 0)).dtype.kind == "U":
        return _clock_stamps(variables[time], time, unit, source)
    if time is not None:
        t = _column(variables, data, time, source, "time")
        _finite(t, source, f"time ({_describe(time)})")
        return t, None
    if dt is None:
        raise RunError(f"{source}: no time variable ('t' or 'time') and no sample interval (dt) given "
                       f"(variables: {_listing(variables)})")
    if not (np.isfinite(dt) and dt > 0):
        raise RunError(f"{source}: sample interval dt must be positive, got {dt}")
    if data is not None:
        n = data.shape[0]
    else:
        lengths = {np.asarray(v).size for v in variables.values() if _is_vector(v)}
        if not lengths:
            raise RunError(f"{source}: no numeric vector variables")
        n = max(lengths)
    return np.arange(n) * float(dt), None


def _clock_stamps(values, name: str, unit, source: str) -> tuple[np.ndarray, str]:
    """Time stored as text (a char matrix or cell array of ``12:34:56.020``, with a date or not)
    as seconds from the first stamp, and what was done."""
    cells = [str(c).strip() for c in np.ravel(values)]
    bad = next((k for k, c in enumerate(cells) if not CLOCK.match(c)), None)
    if bad is not None:
        raise RunError(f"{source}: time variable '{name}' is text but sample {bad + 1} ({cells[bad]!r}) is no clock "
                       "stamp (12:34:56.020, or 2024-05-17 12:34:56.020): store time as numbers")
    clock = {"rows": 0, "dated": 0}
    t = np.array([clock_cell(c, clock) for c in cells])
    text = clock_from_first(t, clock, unit, f"{source}: variable '{name}'", lambda i: f"sample {i + 1}")
    _finite(t, source, f"time ('{name}')")
    return t, text


def _finite(values: np.ndarray, source: str, what: str) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise RunError(f"{source}: {what}: {values[bad[0]]} value at sample {bad[0] + 1} "
                       f"({bad.size} non-finite value(s))")


def _listing(variables: dict) -> str:
    """The file's variables with their shapes, for 'not found' errors."""
    listing = ", ".join(f"{k} {'x'.join(map(str, np.shape(v))) or 'scalar'}" for k, v in sorted(variables.items()))
    skipped = getattr(variables, "skipped", [])
    if skipped:  # a cell of channels is no channel: say how to make it one
        listing += (f"{'; ' if listing else ''}not read: {', '.join(skipped)}: save the cell's vectors as "
                    "variables or struct fields")
    return listing or "none"


def _describe(where) -> str:
    return f"column {where}" if isinstance(where, (int, np.integer)) else f"variable '{where}'"

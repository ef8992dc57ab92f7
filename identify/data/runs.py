"""Runs: measured (or simulated) time histories in the project's CSV run format.

A run file is CSV: optional metadata comment lines ``# key: value`` on top, one header row of
channel names, then one row per sample. The ``time`` column is in seconds, strictly increasing and
uniformly sampled; every other column is a channel in SI units and radians, named as in the
profile. Reading rejects bad data with one line naming the file, row and channel.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RunError

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
        _check_time(self.time, self.source, first_row=1)
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


def read_run(path: str | Path, require: list[str] | None = None) -> Run:
    """Read a run CSV; ``require`` lists channels that must be present (e.g. ``profile.channels``)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RunError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise RunError(f"{path}: not a text (CSV) file") from None
    run = parse_run(text, source=str(path))
    if require:
        run.require(require)
    return run


def read_runs(paths, require: list[str] | None = None) -> list[Run]:
    """Several runs for multi-run evaluation."""
    return [read_run(p, require) for p in paths]


def parse_run(text: str, source: str = "<run>") -> Run:
    meta, rows, first_data_line = {}, [], None
    lines = text.splitlines()
    header, header_line = None, 0
    for lineno, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        if line.startswith("#"):
            if header is None and ":" in line:
                key, _, value = line[1:].partition(":")
                meta[key.strip()] = value.strip()
            continue
        header, header_line = next(csv.reader([line])), lineno
        first_data_line = lineno + 1
        break
    if header is None:
        raise RunError(f"{source}: no header row of channel names")
    header = [h.strip() for h in header]
    if TIME not in header:
        raise RunError(f"{source}: line {header_line}: no '{TIME}' column in header")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise RunError(f"{source}: line {header_line}: duplicate column(s) {', '.join(dup)}")
    data_lines = [(n, l) for n, l in enumerate(lines[first_data_line - 1:], start=first_data_line)
                  if l.strip() and not l.startswith("#")]
    if len(data_lines) < 2:
        raise RunError(f"{source}: fewer than two data rows")
    values = np.empty((len(data_lines), len(header)))
    for r, (lineno, line) in enumerate(data_lines):
        cells = line.split(",")
        if len(cells) != len(header):
            raise RunError(f"{source}: line {lineno}: {len(cells)} values for {len(header)} columns")
        for c, cell in enumerate(cells):
            try:
                v = float(cell)
            except ValueError:
                raise RunError(f"{source}: line {lineno}, channel '{header[c]}': "
                               f"not a number ({cell.strip()!r})") from None
            if not math.isfinite(v):
                raise RunError(f"{source}: line {lineno}, channel '{header[c]}': {cell.strip()} value")
            values[r, c] = v
    line_of = [n for n, _ in data_lines]
    t = values[:, header.index(TIME)]
    _check_time(t, source, line_numbers=line_of)
    channels = {h: values[:, c] for c, h in enumerate(header) if h != TIME}
    return Run(t, channels, meta, source)


def _check_time(t: np.ndarray, source: str, first_row: int = 1, line_numbers=None) -> None:
    where = (lambda i: f"line {line_numbers[i]}") if line_numbers else (lambda i: f"row {first_row + i}")
    if t.ndim != 1 or t.size < 2:
        raise RunError(f"{source}: need at least two time samples")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise RunError(f"{source}: {where(bad[0])}, channel '{TIME}': not finite")
    steps = np.diff(t)
    dt = float(np.median(steps))  # the nominal step: the first odd step is the one to name
    if not t[-1] > t[0]:
        raise RunError(f"{source}: time does not increase")
    nonpos = np.flatnonzero(steps <= 0)
    if nonpos.size:
        i = nonpos[0] + 1
        kind = "repeated" if steps[i - 1] == 0 else "decreasing"
        raise RunError(f"{source}: {where(i)}, channel '{TIME}': {kind} time stamp {t[i]:g} s")
    uneven = np.flatnonzero(np.abs(steps - dt) > _UNIFORM_RTOL * max(dt, 1e-12) + 1e-9)
    if uneven.size:
        i = uneven[0] + 1
        raise RunError(f"{source}: {where(i)}, channel '{TIME}': time step {steps[i - 1]:.6g} s "
                       f"differs from the nominal {dt:.6g} s (non-uniform sampling)")


def _one_line(value) -> str:
    return " ".join(str(value).split())

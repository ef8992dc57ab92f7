"""Runs: measured (or simulated) time histories in the project's CSV run format.

A run file is CSV: optional metadata comment lines ``# key: value`` on top, one header row of
channel names, then one row per sample. The ``time`` column is in seconds, strictly increasing and
uniformly sampled; every other column is a channel in SI units and radians, named as in the
profile. Reading a file is :mod:`identify.data.csvfile` (its raw content) and
:mod:`identify.data.ingest` (measured files' other units, derived channels, jittered or gapped time
turned into runs); reading rejects bad data with one line naming the file, row and channel.
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import RunError

TIME = "time"
UNIFORM_RTOL = 1e-6


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
        check_time(self.time, self.source)
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
        """Raise one RunError listing every channel ``purpose`` needs that the run lacks, and the
        channels it holds (a misnamed one is then seen at once)."""
        missing = [n for n in names if n not in self.channels]
        if missing:
            held = ", ".join(list(self.channels)[:30]) + (" ..." if len(self.channels) > 30 else "")
            raise RunError(f"{self.source}: missing channel(s) {', '.join(missing)} needed by {purpose} "
                           f"(the run holds: {held or 'no channel'})")

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


def check_time(t: np.ndarray, source: str, where=lambda i: f"row {i + 1}", uniform: bool = True) -> None:
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
    return np.flatnonzero(np.abs(steps - dt) > UNIFORM_RTOL * max(dt, 1e-12) + 1e-9)


def _one_line(value) -> str:
    return " ".join(str(value).split())

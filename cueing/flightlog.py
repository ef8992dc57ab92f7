"""Crash-safe frame logs, and their conversion to the project's uniform run files.

A frame log is a CSV in the run-file style: ``# key: value`` metadata lines, a header row, then one
row per displayed frame, appended and flushed to the operating system as it happens, so a run
killed at any moment keeps everything up to its last frame; a background thread calls
``os.fsync`` every ``SYNC_INTERVAL`` s (off the frame loop, whose timing a slow disk must not
disturb), so a power loss loses at most that much. Events (device lost, pause, resume) are ``# event: t: text``
lines between the rows, and a finished run ends with ``# end: completed`` or ``# end: aborted
(reason)``; a log without an end line was killed and reads as aborted.

Columns: ``frame``; ``time`` (s, clock time since the sequence start, negative during the
countdown); ``t_signal`` (s, signal time: stops while paused); ``paused`` (0/1); and per axis
``<input>_cmd`` (what the command needle showed) and ``<input>`` (the flown control deflection).
"""
from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identify import Run
from identify.errors import read_text
from signaldesign.signal import Signal

from .errors import CueingError

FORMAT = "pseudostep-frame-log/1"
SYNC_INTERVAL = 0.1  # s between fsyncs: the most a power loss can cost
CMD = "_cmd"
LOW_RATE = 0.9  # a frame rate under this fraction of the target is flagged (on screen, log, run, score)
RATE_WINDOW = 1.0  # s over which the lowest frame rate is measured
BASE_COLUMNS = ["frame", "time", "t_signal", "paused"]


def frame_log_path(out: str | Path) -> Path:
    """The frame log written beside a run file ``out``: ``run.csv`` -> ``run.frames.csv``."""
    out = Path(out)
    return out.with_name(out.stem + ".frames.csv")


def log_columns(inputs: list[str]) -> list[str]:
    cols = list(BASE_COLUMNS)
    for name in inputs:
        cols += [name + CMD, name]
    return cols


class FrameLogWriter:
    """Append-only frame log: ``open(meta)``, ``frame(...)`` per frame, ``event``, ``close(status)``.

    Every write is flushed to the OS at once; ``fsyncs`` counts the syncs to disk, made every
    ``sync_interval`` s by a background thread and at every event and at the end.
    """

    def __init__(self, path: str | Path, inputs: list[str], sync_interval: float = SYNC_INTERVAL):
        self.path = Path(path)
        self.inputs = list(inputs)
        self.sync_interval = sync_interval
        self._file = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = None
        self.fsyncs = 0
        self.frames = 0
        self.closed_status: str | None = None

    def open(self, meta: dict) -> "FrameLogWriter":
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.path, "w", buffering=1 << 16)
        except OSError as exc:
            raise CueingError(f"{self.path}: cannot write the frame log ({exc.strerror or exc})") from None
        self._file.write(f"# format: {FORMAT}\n")
        for key, value in meta.items():
            self._file.write(f"# {key}: {' '.join(str(value).split())}\n")
        self._file.write(",".join(log_columns(self.inputs)) + "\n")
        self._sync()
        self._thread = threading.Thread(target=self._sync_loop, name="frame-log-fsync", daemon=True)
        self._thread.start()
        return self

    def frame(self, k: int, t: float, t_signal: float, paused: bool, command, flown) -> None:
        """Append one frame (``command``, ``flown``: (n_axes,) control units) and flush it."""
        cells = [str(k), f"{t:.6f}", f"{t_signal:.6f}", "1" if paused else "0"]
        for c, u in zip(command, flown):
            cells += [f"{c:.9g}", f"{u:.9g}"]
        with self._lock:
            self._file.write(",".join(cells) + "\n")
            self._file.flush()
        self.frames += 1

    def event(self, t: float, text: str) -> None:
        with self._lock:
            self._file.write(f"# event: {t:.6f}: {' '.join(text.split())}\n")
        self._sync()

    def close(self, status: str = "completed") -> None:
        if self._file is None or self._file.closed:
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.closed_status = status
        with self._lock:
            self._file.write(f"# end: {status}\n")
        self._sync()
        self._file.close()

    def _sync_loop(self) -> None:
        while not self._stop.wait(self.sync_interval):
            self._sync()

    def _sync(self) -> None:
        with self._lock:
            if self._file.closed:
                return
            self._file.flush()
            fd = self._file.fileno()
        os.fsync(fd)  # outside the lock: the frame loop never waits for the disk
        self.fsyncs += 1


@dataclass
class FrameLog:
    """A frame log read back: ``meta``, ``columns`` {name: (F,) array}, ``events`` [(t, text)],
    ``status`` (``completed`` or ``aborted ...``)."""

    path: Path
    meta: dict[str, str]
    columns: dict[str, np.ndarray]
    events: list[tuple[float, str]] = field(default_factory=list)
    status: str = "completed"

    @property
    def aborted(self) -> bool:
        return not self.status.startswith("completed")

    @property
    def time(self) -> np.ndarray:
        return self.columns["time"]

    @property
    def inputs(self) -> list[str]:
        return [c[:-len(CMD)] for c in self.columns if c.endswith(CMD)]

    def signals(self) -> list[Signal]:
        """The signals flown, from the log's own metadata (the log is self-contained)."""
        try:
            return [Signal.from_dict(d, str(self.path)) for d in json.loads(self.meta["signals_json"])]
        except (KeyError, json.JSONDecodeError):
            raise CueingError(f"{self.path}: frame log lacks its signals (signals_json)") from None

    @property
    def nominal_rate(self) -> float:
        """The target frame rate (Hz) the log was flown at (60 when the log does not say)."""
        try:
            rate = float(self.meta.get("frame_rate", 60))
        except ValueError:
            rate = np.nan
        if not (np.isfinite(rate) and rate > 0):
            raise CueingError(f"{self.path}: frame_rate '{self.meta.get('frame_rate')}' is not a rate in Hz")
        return rate

    def frame_stats(self, rate: float | None = None) -> dict[str, float]:
        """Frame count, target and achieved rate (Hz) over the whole log, the lowest rate over any
        ``RATE_WINDOW`` s (Hz) and frame-interval statistics (s)."""
        rate = rate or self.nominal_rate
        t = self.time
        steps = np.diff(t)
        if steps.size == 0:
            return {"frames": float(t.size)}
        achieved = float(steps.size / (t[-1] - t[0]))
        start = np.searchsorted(t, t - RATE_WINDOW, side="left")  # first frame within the window ending here
        full = (t - t[0] >= RATE_WINDOW) & (t > t[start])
        lowest = float(np.min((np.arange(t.size) - start)[full] / (t - t[start])[full])) if full.any() else achieved
        return {"frames": float(t.size), "rate_nominal": rate, "rate_achieved": achieved,
                "rate_lowest_1s": lowest, "interval_std": float(np.std(steps)),
                "interval_max": float(np.max(steps)), "late_frames": float(np.sum(steps > 1.5 / rate))}


def frame_rate_warning(stats: dict) -> str | None:
    """One line when the frame rate fell under ``LOW_RATE`` of the target (``frame_stats``), else None."""
    target = stats.get("rate_nominal")
    if target is None or min(stats["rate_achieved"], stats["rate_lowest_1s"]) >= LOW_RATE * target:
        return None
    return (f"frame rate low: {stats['rate_achieved']:.1f} Hz (worst second {stats['rate_lowest_1s']:.1f} Hz) "
            f"of {target:g} Hz target")


def read_frame_log(path: str | Path) -> FrameLog:
    """Read a frame log, even one cut off mid-line by a kill; one CueingError if it is unusable."""
    path = Path(path)
    text = read_text(path, CueingError, "pseudostep frame log")
    meta, events, rows, header, status = {}, [], [], None, None
    lines = text.split("\n")
    complete = lines[:-1]  # the part after the last newline is a row the kill cut short
    for n, line in enumerate(complete, start=1):
        if line.startswith("# event:"):
            t, _, what = line[len("# event:"):].strip().partition(": ")
            events.append((_number(t, path, n), what))
        elif line.startswith("# end:"):
            status = line[len("# end:"):].strip()
        elif line.startswith("#"):
            if header is None:
                key, _, value = line[1:].partition(":")
                meta[key.strip()] = value.strip()
        elif header is None:
            header = line.strip().split(",")
        elif line.strip():
            rows.append((n, line))
    if meta.get("format") != FORMAT or header is None:
        raise CueingError(f"{path}: not a pseudostep frame log")
    _check_header(header, path)
    bad = [n for n, r in rows if r.count(",") != len(header) - 1]
    if bad:  # a kill cuts only the last line, which is not among the complete ones
        raise CueingError(f"{path}: line {bad[0]}: {len(header)} columns expected")
    if not rows:
        raise CueingError(f"{path}: frame log holds no frames")
    data = np.array([[_number(c, path, n) for c in r.split(",")] for n, r in rows], dtype=float)
    if not np.all(np.isfinite(data)):
        n = rows[int(np.flatnonzero(~np.all(np.isfinite(data), axis=1))[0])][0]
        raise CueingError(f"{path}: line {n}: a frame holds a non-finite number")
    columns = {name: data[:, j] for j, name in enumerate(header)}
    if np.any(np.diff(columns["time"]) <= 0):
        raise CueingError(f"{path}: frame times are not increasing")
    if status is None:
        status = "aborted (log ends without an end line: the process was killed)"
    return FrameLog(path, meta, columns, events, status)


def _check_header(header: list[str], path: Path) -> None:
    missing = [c for c in BASE_COLUMNS if c not in header]
    axes = [c[:-len(CMD)] for c in header if c.endswith(CMD)]
    if missing or not axes or any(a not in header for a in axes) or len(set(header)) != len(header):
        raise CueingError(f"{path}: frame log header must hold {', '.join(BASE_COLUMNS)} and per axis "
                          f"<input>_cmd and <input> once each, got {','.join(header)[:120]}")


def _number(text: str, path: Path, line: int) -> float:
    try:
        return float(text)
    except ValueError:
        raise CueingError(f"{path}: line {line}: '{text[:40]}' is not a number") from None


def held_mean(t: np.ndarray, u: np.ndarray, rate: float, n: int) -> np.ndarray:
    """Per sample ``i`` of a grid ``i / rate`` (n samples) the mean over ``[i, i + 1) / rate`` of a
    stick held from each frame (times ``t`` (s), values ``u``) to the next.

    Estimators hold each sample's input over its interval; the mean keeps the input's integral over
    every interval, so the modelled response matches the flown one. Taking the last frame's value
    instead moves every change to the next grid instant: up to a sample late, and on a real clock,
    whose frames are not on the grid, a steady few-ms delay (it put ML 3-5 of its standard errors
    off the truth on a live flight; the live estimator, which uses the frame times, was not). Frames
    on the grid give their own values; times are logged to the microsecond, so a frame stamped
    within 1 us of a grid instant is taken as on it."""
    slot = np.round(t * rate) / rate
    t = np.where(np.abs(t - slot) < 1e-6, slot, t)
    edges = np.arange(n + 1) / rate
    cum = np.concatenate([[0.0], np.cumsum(u[:-1] * np.diff(t))])  # integral from t[0] to each frame

    def integral(x):
        k = np.clip(np.searchsorted(t, x, side="right") - 1, 0, t.size - 1)
        return cum[k] + u[k] * (x - t[k])

    return np.diff(integral(edges)) * rate


def log_to_run(log: FrameLog, sample_rate: float | None = None, signals: list[Signal] | None = None) -> Run:
    """Resample a frame log onto a uniform grid from the sequence start: the project's run format.

    Commanded channels ``<input>_cmd`` are the signal evaluated at the (interpolated) signal time
    of each grid instant; flown channels ``<input>`` are per sample the mean of the stick held from
    each frame until the next (the stick was sampled once per frame): see :func:`held_mean`. A run that paused also gets a ``t_signal``
    channel (signal time, s), since its time axis then runs ahead of the signal.
    """
    signals = signals or log.signals()
    rate = sample_rate or log.nominal_rate
    t, ts = log.columns["time"], log.columns["t_signal"]
    keep = t >= 0
    if keep.sum() < 2:
        raise CueingError(f"{log.path}: fewer than two frames after the sequence start")
    t_end = t[keep][-1]
    grid = np.arange(int(np.floor(t_end * rate + 1e-9)) + 1) / rate
    if grid.size < 2:
        raise CueingError(f"{log.path}: the flown part is shorter than one sample")
    t_sig = np.interp(grid, t, ts)
    channels: dict[str, np.ndarray] = {}
    for name in log.inputs:
        channels[name + CMD] = sum((s(t_sig) for s in signals if s.input == name), np.zeros(grid.size))
        channels[name] = held_mean(t, log.columns[name], rate, grid.size)
    if np.any(log.columns["paused"][keep]):  # signal time no longer equals run time: keep it
        channels["t_signal"] = t_sig
    stats = log.frame_stats()
    meta = {k: v for k, v in log.meta.items() if k not in ("format", "signals_json")}
    meta.update({"status": log.status, "sample_rate": f"{rate:g} Hz",
                 "frame_stats": ", ".join(f"{k} {v:.6g}" for k, v in stats.items()),
                 "signals_json": log.meta.get("signals_json", "")})
    if frame_rate_warning(stats):
        meta["frame_rate_warning"] = frame_rate_warning(stats)
    if log.events:
        meta["events"] = "; ".join(f"{t:.3f} s {what}" for t, what in log.events)
    return Run(grid, channels, meta, source=str(log.path))

"""The signal object every signal type returns, and its JSON / run-file forms.

A signal is a sequence of levels held for a constant time step ``dt`` on one control axis
(``input``, a profile input name), scaled by ``amplitude`` (control units). Step sequences
(doublet, 3211, pseudo-stochastic) have integer levels -1/0/+1; a multisine is the same object
with fractional levels on a fine step. The signal file (JSON, format ``pseudostep-signal/1``) holds
one or several signals (multi-axis designs) and is what ``cueing`` flies and ``identify`` can
attach to a run's metadata.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identify import Run
from identify.errors import SignalError

FORMAT = "pseudostep-signal/1"
_EDGE = 1e-9  # evaluation at a switch time belongs to the new level despite rounding


@dataclass
class Signal:
    """``levels`` (K,) held for ``dt`` s each, times ``amplitude``, starting ``delay`` s after t = 0."""

    kind: str
    input: str
    dt: float
    levels: np.ndarray
    amplitude: float = 1.0
    delay: float = 0.0
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        self.levels = np.asarray(self.levels, dtype=float)
        if self.levels.ndim != 1 or self.levels.size == 0:
            raise SignalError(f"signal '{self.kind}': levels must be a non-empty 1-D sequence")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise SignalError(f"signal '{self.kind}': time step must be positive, got {self.dt}")
        if not np.all(np.isfinite(self.levels)) or not np.isfinite(self.amplitude):
            raise SignalError(f"signal '{self.kind}': levels and amplitude must be finite")
        if not (np.isfinite(self.delay) and self.delay >= 0):
            raise SignalError(f"signal '{self.kind}': delay must be a finite time >= 0 s, got {self.delay}")

    @property
    def duration(self) -> float:
        """Length of the level sequence in s (excluding ``delay``)."""
        return self.levels.size * self.dt

    @property
    def end_time(self) -> float:
        return self.delay + self.duration

    @property
    def record(self) -> float:
        """Length (s) of the record the signal was designed for: ``params['record']`` where a design
        set it, never shorter than the signal itself (``end_time``)."""
        try:
            designed = float(self.params.get("record", 0.0)) if isinstance(self.params, dict) else 0.0
        except (TypeError, ValueError):
            designed = 0.0
        return max(designed, self.end_time) if np.isfinite(designed) else self.end_time

    @property
    def is_step_sequence(self) -> bool:
        return bool(np.all(self.levels == np.round(self.levels)))

    def level_at(self, t) -> np.ndarray:
        """Normalised level at time(s) ``t`` in s; 0 before the start and after the end."""
        t = np.asarray(t, dtype=float)
        k = np.floor((t - self.delay) / self.dt + _EDGE).astype(int)
        inside = (k >= 0) & (k < self.levels.size)
        return np.where(inside, self.levels[np.clip(k, 0, self.levels.size - 1)], 0.0)

    def __call__(self, t) -> np.ndarray:
        """Control value at time(s) ``t``: amplitude times level."""
        return self.amplitude * self.level_at(t)

    def switch_times(self) -> np.ndarray:
        """Times (s) at which the level changes, including leaving and returning to 0."""
        padded = np.concatenate([[0.0], self.levels, [0.0]])
        k = np.flatnonzero(np.diff(padded) != 0)
        return self.delay + k * self.dt

    def to_dict(self) -> dict:
        levels = self.levels.astype(int).tolist() if self.is_step_sequence else self.levels.tolist()
        return {"kind": self.kind, "input": self.input, "dt": self.dt, "amplitude": self.amplitude,
                "delay": self.delay, "levels": levels, "params": self.params}

    @classmethod
    def from_dict(cls, d: dict, source: str = "<signal>") -> "Signal":
        try:
            return cls(kind=str(d["kind"]), input=str(d["input"]), dt=float(d["dt"]),
                       levels=np.asarray(d["levels"], dtype=float), amplitude=float(d.get("amplitude", 1.0)),
                       delay=float(d.get("delay", 0.0)), params=dict(d.get("params", {})))
        except KeyError as exc:
            raise SignalError(f"{source}: signal lacks '{exc.args[0]}'") from None
        except (TypeError, ValueError) as exc:
            raise SignalError(f"{source}: malformed signal ({exc})") from None


def save_signals(signals: Signal | list[Signal], path: str | Path) -> Path:
    """Write one or several signals (one per control axis) to a signal JSON file."""
    signals = [signals] if isinstance(signals, Signal) else list(signals)
    path = Path(path)
    path.write_text(json.dumps({"format": FORMAT, "signals": [s.to_dict() for s in signals]}, indent=1))
    return path


def load_signals(path: str | Path) -> list[Signal]:
    """Read a signal JSON file; every problem raises one SignalError naming the file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise SignalError(f"{path}: cannot read signal file ({exc.strerror or exc})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SignalError(f"{path}: not a signal JSON file ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("signals"), list):
        raise SignalError(f"{path}: not a {FORMAT} file")
    if not data["signals"]:
        raise SignalError(f"{path}: holds no signal")
    return [Signal.from_dict(d, str(path)) for d in data["signals"]]


def signals_to_run(signals: Signal | list[Signal], dt: float, t_end: float, meta: dict | None = None) -> Run:
    """Sample signals on a uniform grid 0..t_end (s) as a run holding one channel per input."""
    signals = [signals] if isinstance(signals, Signal) else list(signals)
    time = np.arange(int(round(t_end / dt)) + 1) * dt
    channels: dict[str, np.ndarray] = {}
    for s in signals:
        channels[s.input] = channels.get(s.input, 0.0) + s(time)
    info = {"signal": ", ".join(f"{s.kind} on {s.input}" for s in signals), "sample_rate": f"{1 / dt:g} Hz"}
    info.update(meta or {})
    return Run(time, channels, {k: str(v) for k, v in info.items()}, source="<signal>")

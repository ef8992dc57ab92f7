"""Input sources: where the pilot needle's value comes from. One interface, several devices.

Every source has ``start(signals, preview)``, ``read(t_signal) -> (n_axes,)`` control units,
``handle_event(event) -> message or None`` (pygame events, for devices that come and go),
``paused_reason`` (None while usable) and ``describe()`` for the run's metadata.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import CueingError
from .pilot import PilotModel


class InputSource:
    """Base class: a source of control deflections, one per signal axis."""

    name = "source"
    paused_reason: str | None = None

    def start(self, signals, preview: bool = False) -> None:
        self.signals = list(signals)
        self.amplitudes = np.array([abs(s.amplitude) for s in self.signals])

    def read(self, t_signal: float) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def handle_event(self, event) -> str | None:
        return None

    def describe(self) -> str:
        return self.name

    def close(self) -> None:
        pass


class PilotSource(InputSource):
    """The simulated pilot (:class:`~cueing.pilot.PilotModel`) flying the command needle."""

    name = "pilot"

    def __init__(self, pilot: PilotModel | None = None, skill: float = 0.5, seed: int | None = None):
        self.pilot = pilot or PilotModel(skill, seed=seed)

    def start(self, signals, preview: bool = False) -> None:
        super().start(signals, preview)
        self.pilot.reset(self.amplitudes, preview)
        self._command = lambda t: np.array([s(t) for s in self.signals], float)  # noqa: E731

    def read(self, t_signal: float) -> np.ndarray:
        return self.pilot.step(t_signal, self._command)

    def describe(self) -> str:
        p = self.pilot.params
        return (f"pilot model (skill {self.pilot.skill:g}: omega_c {p.omega_c:.3g} rad/s, delay {p.delay:.3g} s, "
                f"lag {p.lag:.3g} s, remnant {p.remnant:.3g}, level error {p.level_error:.3g}"
                f"{', anticipating' if self.pilot.lead else ''})")


class ExternalSource(InputSource):
    """An external callable ``f(t_signal) -> value or (n_axes,)``: e.g. a flight simulator's stick."""

    name = "external"

    def __init__(self, func, label: str = "external"):
        if not callable(func):
            raise CueingError(f"external source '{label}' is not a function of the signal time")
        self.func = func
        self.label = label

    def read(self, t_signal: float) -> np.ndarray:
        try:
            value = np.atleast_1d(np.asarray(self.func(t_signal), float))
            return np.broadcast_to(value, (len(self.signals),)).copy()
        except (TypeError, ValueError) as exc:  # the simulator's stick gave no usable deflection
            raise CueingError(f"external source '{self.label}' at t = {t_signal:.3f} s: "
                              f"expected {len(self.signals)} number(s), got an error: {exc}") from None

    def describe(self) -> str:
        return f"external ({self.label})"


class ScriptedSource(ExternalSource):
    """Deterministic scripted deflections (tests): ``f(t_signal)``; every value read is recorded."""

    name = "scripted"

    def __init__(self, func):
        super().__init__(func, "scripted")
        self.produced: list[np.ndarray] = []

    def read(self, t_signal: float) -> np.ndarray:
        value = super().read(t_signal)
        self.produced.append(value)
        return value


class ReplaySource(InputSource):
    """Replays the flown channels of a logged run (run file or frame log) against signal time."""

    name = "replay"

    def __init__(self, path: str | Path):
        from identify.errors import RunError
        from identify.data.io import read_run_file
        from .flightlog import FORMAT, read_frame_log
        self.path = Path(path)
        try:
            with open(self.path, "rb") as f:
                head = f.read(200)
        except OSError as exc:
            raise CueingError(f"replay source: cannot read '{path}' ({exc.strerror or exc})") from None
        if FORMAT.encode() in head:
            log = read_frame_log(self.path)
            self.time, self.channels = log.columns["t_signal"], log.columns
        else:
            try:
                run = read_run_file(self.path)
            except RunError as exc:
                raise CueingError(f"replay source: {exc}") from None
            self.time, self.channels = run.time, run.channels

    def start(self, signals, preview: bool = False) -> None:
        super().start(signals, preview)
        missing = [s.input for s in self.signals if s.input not in self.channels]
        if missing:
            raise CueingError(f"{self.path}: replay source has no channel {', '.join(missing)}")

    def read(self, t_signal: float) -> np.ndarray:
        # the log keeps time to 1 us: a frame stamped at t_signal (to that resolution) is the one due
        k = int(np.clip(np.searchsorted(self.time, t_signal + 1e-6, side="right") - 1, 0, self.time.size - 1))
        return np.array([self.channels[s.input][k] for s in self.signals])

    def describe(self) -> str:
        return f"replay of {self.path}"


class KeyboardSource(InputSource):
    """Arrow keys: held left/right (axis 1) or down/up (axis 2) give the -/+ level, none gives 0;
    a third axis on a/d. More axes are refused."""

    name = "keyboard"

    def __init__(self, key_state=None):
        import pygame
        self._keys = key_state or pygame.key.get_pressed
        self.pairs = [(pygame.K_LEFT, pygame.K_RIGHT), (pygame.K_DOWN, pygame.K_UP), (pygame.K_a, pygame.K_d)]

    def start(self, signals, preview: bool = False) -> None:
        super().start(signals, preview)
        _check_axes(self, len(self.pairs), "left/right, down/up, a/d")

    def read(self, t_signal: float) -> np.ndarray:
        keys = self._keys()
        out = np.zeros(len(self.signals))
        for j, (neg, pos) in enumerate(self.pairs[:len(self.signals)]):
            out[j] = (float(keys[pos]) - float(keys[neg])) * self.amplitudes[j]
        return out


class MouseSource(InputSource):
    """The pointer: x flies the first axis, y (up: +) the second, mapped through the display's
    scales (``value_of(pos) -> (n_axes,)``, set by the runner); holds the last values while the
    window has no mouse focus. More than two axes are refused."""

    name = "mouse"

    def __init__(self, value_of=None, position=None, focused=None):
        import pygame
        self._pos = position or pygame.mouse.get_pos
        self._focused = focused or pygame.mouse.get_focused
        self.value_of = value_of  # set by the runner from the display's scales
        self.last = None

    def start(self, signals, preview: bool = False) -> None:
        super().start(signals, preview)
        _check_axes(self, 2, "x, y")
        self.last = np.zeros(len(self.signals))

    def read(self, t_signal: float) -> np.ndarray:
        if self.value_of is not None and self._focused():
            self.last = np.asarray(self.value_of(self._pos()), float)[:len(self.signals)]
        return self.last.copy()

    def describe(self) -> str:
        return "mouse (x: first axis" + (", y: second axis)" if len(getattr(self, "signals", [])) > 1 else ")")


def _check_axes(source: InputSource, most: int, how: str) -> None:
    if len(source.signals) > most:
        raise CueingError(f"the {source.name} source flies at most {most} axes ({how}), the signal has "
                          f"{len(source.signals)}: use a joystick or split the signal file")


@dataclass
class Calibration:
    """Stick axis calibration: raw axis ``centre`` and ``dead_zone`` (fractions of full travel),
    and ``full_scale`` control units at full deflection (per axis; None: 1.5 x the amplitude)."""

    centre: float = 0.0
    dead_zone: float = 0.05
    full_scale: float | None = None
    invert: bool = False

    def apply(self, raw: float, amplitude: float) -> float:
        a = raw - self.centre
        span = 1.0 - abs(self.centre) - self.dead_zone
        if abs(a) <= self.dead_zone or span <= 0:
            return 0.0
        a = np.sign(a) * min((abs(a) - self.dead_zone) / span, 1.0)
        scale = self.full_scale if self.full_scale is not None else 1.5 * amplitude
        return float((-a if self.invert else a) * scale)

    @classmethod
    def from_samples(cls, rest, dead_zone: float | None = None, **kw) -> "Calibration":
        """Calibrate from raw samples at rest (centre; dead zone 3x their spread, at least 0.02)."""
        rest = np.asarray(rest, float)
        dz = dead_zone if dead_zone is not None else max(0.02, 3 * float(np.std(rest)))
        return cls(centre=float(np.mean(rest)), dead_zone=dz, **kw)


class JoystickSource(InputSource):
    """A stick via pygame's joystick API, calibrated; pauses the run when the device disappears.

    ``axes``: joystick axis index per signal axis (default: 1, the stick's fore-aft, for the first
    signal, 0, lateral, for the second); ``calibration``: one Calibration for all axes or one per
    axis; ``rest_seconds``: if > 0, the centre and dead zone of every axis are measured from the
    stick held at rest for that long when the run starts; ``factory(index)`` opens a device
    (default ``pygame.joystick.Joystick``; tests pass a fake).
    """

    name = "joystick"

    def __init__(self, device: int = 0, axes=(1, 0), calibration=None, factory=None,
                 rest_seconds: float = 0.0):
        self.device = device
        self.axes = list(axes)
        cal = calibration or Calibration()
        self.calibrations = list(cal) if isinstance(cal, (list, tuple)) else [cal] * len(self.axes)
        self.factory = factory
        self.rest_seconds = rest_seconds
        self.joystick = None
        self.paused_reason = None

    def start(self, signals, preview: bool = False) -> None:
        import pygame
        super().start(signals, preview)
        if self.factory is None:
            pygame.joystick.init()
            if pygame.joystick.get_count() <= self.device:
                raise CueingError(f"no joystick found (source 'joystick', device {self.device}): "
                                  "connect one or use --source mouse, keyboard or pilot")
            self.factory = pygame.joystick.Joystick
        if len(self.axes) < len(self.signals) or len(self.calibrations) < len(self.signals):
            raise CueingError(f"joystick: {len(self.signals)} signal axes but {len(self.axes)} stick axes "
                              f"and {len(self.calibrations)} calibrations given")
        self._open()
        if self.rest_seconds > 0:
            self.calibrate_rest(self.rest_seconds)

    def calibrate_rest(self, seconds: float, rate: float = 100.0, sleep=None) -> list[Calibration]:
        """Measure each axis's centre and dead zone from the stick held at rest for ``seconds``."""
        import time
        sleep = sleep or time.sleep
        samples = []
        for _ in range(max(int(seconds * rate), 2)):
            samples.append([self.joystick.get_axis(a) for a in self.axes[:len(self.signals)]])
            sleep(1.0 / rate)
        samples = np.array(samples)
        self.calibrations = [Calibration.from_samples(samples[:, j], full_scale=c.full_scale, invert=c.invert)
                             for j, c in enumerate(self.calibrations[:len(self.signals)])]
        return self.calibrations

    def _open(self) -> None:
        self.joystick = self.factory(self.device)
        if hasattr(self.joystick, "init"):
            self.joystick.init()
        self.instance_id = self.joystick.get_instance_id()
        self.paused_reason = None

    def read(self, t_signal: float) -> np.ndarray:
        out = np.zeros(len(self.signals))
        if self.paused_reason is not None:
            return out
        for j, a in enumerate(self.axes[:len(self.signals)]):
            out[j] = self.calibrations[j].apply(self.joystick.get_axis(a), self.amplitudes[j])
        return out

    def handle_event(self, event) -> str | None:
        import pygame
        if event.type == pygame.JOYDEVICEREMOVED and getattr(event, "instance_id", None) == self.instance_id:
            self.paused_reason = "joystick disconnected: reconnect it to continue"
            return f"joystick {self.device} removed: run paused"
        if event.type == pygame.JOYDEVICEADDED and self.paused_reason is not None:
            if getattr(event, "device_index", self.device) == self.device:
                self._open()
                return f"joystick {self.device} reconnected: run resumed"
        return None

    def describe(self) -> str:
        name = self.joystick.get_name() if self.joystick is not None and hasattr(self.joystick, "get_name") else "?"
        cals = "; ".join(f"axis {a}: centre {c.centre:.4g}, dead zone {c.dead_zone:.3g}, full scale "
                         f"{'1.5 x amplitude' if c.full_scale is None else f'{c.full_scale:g}'}"
                         f"{', inverted' if c.invert else ''}"
                         for a, c in zip(self.axes[:len(self.signals)], self.calibrations))
        return f"joystick {self.device} ({name}), {cals}"


SOURCE_NAMES = ("joystick", "mouse", "keyboard", "pilot", "replay:RUN.csv", "external:MODULE:FUNCTION")


def make_source(spec: str, skill: float = 0.5, seed: int | None = None, device: int = 0,
                calibration: Calibration | None = None, axes=(1, 0), rest_seconds: float = 0.0) -> InputSource:
    """Build a source from its command-line name; an unknown name is one CueingError."""
    kind, _, arg = spec.partition(":")
    if kind == "pilot":
        return PilotSource(skill=skill, seed=seed)
    if kind == "keyboard":
        return KeyboardSource()
    if kind == "mouse":
        return MouseSource()
    if kind == "joystick":
        return JoystickSource(device=device, axes=axes, calibration=calibration, rest_seconds=rest_seconds)
    if kind == "replay" and arg:
        if not Path(arg).is_file():
            raise CueingError(f"replay source: no such run file '{arg}'")
        return ReplaySource(arg)
    if kind == "external" and arg.count(":") == 1:
        module, func = arg.split(":")
        try:
            return ExternalSource(getattr(importlib.import_module(module), func), arg)
        except (ImportError, AttributeError) as exc:
            raise CueingError(f"external source '{arg}': {exc}") from None
    raise CueingError(f"unknown source '{spec}' (choose from {', '.join(SOURCE_NAMES)})")

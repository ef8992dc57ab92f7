"""The frame loop: clock -> signal -> source -> log -> display, one pass per frame.

The signal is evaluated from the clock (``t_signal`` = clock time since the sequence start, minus
time spent paused), never from a frame count. Frames are scheduled on a grid anchored at the
sequence start; a late frame is shown late but with the command due at its own time stamp, and
missed grid slots are skipped, not made up. Every frame is appended to the crash-safe log before
it is drawn.

The run file spans the design's whole record: a quiet ``lead_in`` (logged, the signal not yet
started) and then the signal's ``record`` (the record it was designed for, from the signal file),
at least the sequence plus ``tail``. A frame rate under ``LOW_RATE`` of the target over any second is
shown on screen and logged as an event.
"""
from __future__ import annotations

import json
import platform
import signal
import threading
from contextlib import contextmanager
from collections import deque
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from .audio import Ticker
from .clock import MonotonicClock
from .display import BASE_SIZE, Display, FrameState
from .errors import CueingError, RunAborted
from .flightlog import LOW_RATE, FrameLogWriter, read_frame_log
from .sources import InputSource, MouseSource

DEFAULT_RATE = 60.0  # Hz
RECOVERY_MARGIN = 0.05  # a low frame rate counts as recovered at LOW_RATE + this fraction of the target
WINDOW = "window"
HEADLESS = "headless"


class Terminated(SystemExit):
    """SIGTERM during a run: the log is closed as aborted, then the program ends (status 143)."""


@contextmanager
def _sigterm_ends_the_run():
    """SIGTERM raises :class:`Terminated` while a run is flown; the handler before it is restored
    afterwards. Why: SDL takes SIGTERM when the display starts if nobody holds it, and keeps it
    after the run, turning every later ``kill`` of the program (and of design workers forked from
    it) into a quit event nobody reads."""
    if threading.current_thread() is not threading.main_thread():  # only there can it be set
        yield
        return

    def terminate(signum, frame):
        raise Terminated(128 + signum)

    previous = signal.signal(signal.SIGTERM, terminate)
    try:
        yield
    finally:  # None: a handler set outside Python (SDL's, by an earlier display)
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


@dataclass(frozen=True)
class Schedule:
    """When frames are flown and logged: ``rate`` (Hz); ``countdown``: s before the logging starts;
    ``lead_in``: s logged before the signal starts (the pilot holds still; the signals are flown
    delayed by it); ``record``: s logged from the signal's start (None: the signals' own
    ``record``), at least the sequence plus ``tail`` s."""

    rate: float = DEFAULT_RATE
    countdown: float = 3.0
    lead_in: float = 0.0
    record: float | None = None
    tail: float = 1.0


@dataclass(frozen=True)
class Screen:
    """What is drawn: ``display`` None (nothing), ``"headless"`` (off-screen Surface) or
    ``"window"`` (resizable; ``fullscreen`` fills the screen) of ``size`` px; ``preview``: s of
    preview strip (0: none); ``units`` {input: unit} labels the scales; ``end_screen``: s the
    end-of-run screen stays up in a window; ``screenshot_every``: s between PNG screenshots
    written to ``screenshot_dir``."""

    display: str | None = None
    size: tuple[int, int] = BASE_SIZE
    fullscreen: bool = False
    preview: float = 0.0
    units: dict | None = None
    end_screen: float = 0.0
    screenshot_dir: Path | str | None = None
    screenshot_every: float | None = None


def runner_options(**options) -> dict:
    """Flat keyword options (``rate=``, ``display=`` ...) as :class:`Runner`'s keywords: each field
    of :class:`Schedule` and :class:`Screen` into its config, the rest as they are."""
    out = dict(options)
    for key, config in (("schedule", Schedule), ("screen", Screen)):
        given = {f.name: out.pop(f.name) for f in fields(config) if f.name in out}
        if given:
            out[key] = replace(out.get(key, config()), **given)
    return out


class Panel(Protocol):
    """Shown right of the needles, ``width`` px wide, fed every frame (also without a display)."""

    width: int

    def update(self, k: int, t: float, t_signal: float, flown: np.ndarray, paused: bool) -> None: ...

    def draw(self, surface, rect: tuple[int, int, int, int]) -> None: ...


class Runner:
    """Flies ``signals`` with ``source``, logging every frame to ``log_path``.

    ``schedule``: :class:`Schedule` (rate, countdown, lead-in, record); ``screen``: :class:`Screen`
    (display mode, preview, screenshots); ``panels``: :class:`Panel` objects fed every frame and
    drawn left to right beside the needles; ``clock``: object with ``now()``, ``sleep_until(t)``,
    ``unix_offset()`` (default: the monotonic clock); ``events``: callable returning pending pygame
    events (default ``pygame.event.get`` whenever pygame's display is up); ``meta``: extra frame-log
    header lines. After :meth:`fly`, ``log_`` is the frame log read back and ``render_times_`` the
    per-frame drawing times (s).
    """

    def __init__(self, signals, source: InputSource, log_path, *, schedule: Schedule = Schedule(),
                 screen: Screen = Screen(), panels=(), clock=None, audio: bool = True, events=None,
                 meta: dict | None = None):
        self.schedule, self.screen = schedule, screen
        self.lead_in = float(schedule.lead_in)
        self.signals = [replace(s, delay=s.delay + self.lead_in) for s in signals]
        self.source = source
        self.log_path = Path(log_path)
        self.panels = list(panels)
        self.clock = clock or MonotonicClock()
        self.rate = float(schedule.rate)
        self.countdown = float(schedule.countdown)
        self.preview = float(screen.preview)
        self.audio = audio
        self.events = events
        self.meta = dict(meta or {})
        self.screenshot_dir = Path(screen.screenshot_dir) if screen.screenshot_dir else None
        self.inputs = [s.input for s in self.signals]
        self.record = float(schedule.record) if schedule.record is not None else max(s.record for s in signals)
        self.t_end = self.lead_in + max(self.record, max(s.end_time for s in signals) + schedule.tail)

    # -- setup ----------------------------------------------------------------------------------
    def _setup_display(self):
        self.display = None
        self.surface = None
        self.window = None
        mode = self.screen.display
        if mode is None:
            return
        import pygame
        try:
            pygame.display.init()
            pygame.font.init()
            if mode == WINDOW:
                full = self.screen.fullscreen
                self.window = pygame.display.set_mode((0, 0) if full else self.screen.size,
                                                      pygame.FULLSCREEN if full else pygame.RESIZABLE)
        except pygame.error as exc:
            raise CueingError(f"cannot open a display window ({exc}): use --headless") from None
        if mode == WINDOW:
            pygame.display.set_caption("pseudostep cueing")
            self.surface = self.window
        else:
            self.surface = pygame.Surface(self.screen.size)
        self.needle_surface = self._needles()
        self.display = Display(self.signals, self.needle_surface.get_size(), self.preview, self.screen.units)
        if isinstance(self.source, MouseSource) and self.source.value_of is None:
            self.source.value_of = self.display.value_of_pointer

    def _resize(self, size) -> None:
        """Follow a resized window (the display re-lays itself out from the surface's size)."""
        import pygame
        if self.window is not None:
            self.window = self.surface = pygame.display.get_surface()
        else:
            self.surface = pygame.Surface(size)
        self.needle_surface = self._needles()
        self.display.layout(self.needle_surface.get_size())  # now, not at the next render: the mouse maps through it

    def _needles(self):
        """The surface the needles are drawn on: all of it, or left of the panels."""
        if not self.panels:
            return self.surface
        w, h = self.surface.get_size()
        return self.surface.subsurface((0, 0, max(w - sum(p.width for p in self.panels), 1), h))

    def _draw_panels(self) -> None:
        x, h = self.needle_surface.get_width(), self.surface.get_height()
        for panel in self.panels:
            width = min(panel.width, self.surface.get_width() - x)
            panel.draw(self.surface, (x, 0, width, h))
            x += width

    def _pending_events(self):
        if self.events is not None:
            return self.events()
        import pygame
        return pygame.event.get() if pygame.display.get_init() else []

    def _log_meta(self, t0: float) -> dict:
        meta = {"signal": ", ".join(f"{s.kind} on {s.input} (step {s.dt:g} s, amplitude {s.amplitude:g})"
                                    for s in self.signals),
                "source": self.source.describe(), "frame_rate": f"{self.rate:g}",
                "countdown": f"{self.countdown:g}", "lead_in": f"{self.lead_in:g} s (quiet, before the signal)",
                "record": f"{self.record:g} s from the signal's start, run {self.t_end:g} s",
                "preview": f"{self.preview:g}",
                "clock_epoch_unix": f"{t0 + self.clock.unix_offset():.6f}", "host": platform.node()}
        meta["pilot"] = "(unnamed)"
        meta.update(self.meta)
        meta["signals_json"] = json.dumps([s.to_dict() for s in self.signals], separators=(",", ":"))
        return meta

    # -- the loop -------------------------------------------------------------------------------
    def fly(self, score_lines=None):
        """Fly one run; returns the frame log read back. ``score_lines(log) -> [str]`` fills the
        end-of-run screen. A closed window or Escape ends the run early, marked aborted; so do
        Ctrl-C and SIGTERM, which then go on to end the program."""
        with _sigterm_ends_the_run():
            return self._fly(score_lines)

    def _fly(self, score_lines):
        self._setup_display()
        self.ticker = Ticker(self.audio)
        self.source.start(self.signals, self.preview > 0)
        t0 = self.clock.now() + self.countdown  # the sequence starts here
        writer = FrameLogWriter(self.log_path, self.inputs)
        writer.open(self._log_meta(t0))
        self.render_times_: list[float] = []
        status = "completed"
        try:
            status = self._loop(writer, t0)
        except KeyboardInterrupt:
            writer.close("aborted (interrupted)")
            raise
        except Terminated:
            writer.close("aborted (terminated: SIGTERM)")
            raise
        except BaseException as exc:
            writer.close(f"aborted (error: {exc})")
            raise
        writer.close(status)
        try:
            if writer.frames == 0:  # ended before its first frame: the log is kept, but holds nothing to read
                raise RunAborted(f"run {status} before the recording started: no run file written "
                                 f"(frame log {self.log_path})")
            self.log_ = read_frame_log(self.log_path)
            if self.display is not None:
                self._show_end(score_lines(self.log_) if score_lines else [f"run {status}"])
        finally:
            self.source.close()
        return self.log_

    def _loop(self, writer: FrameLogWriter, t0: float) -> str:
        k, paused_total, pause_start, last_levels = 0, 0.0, None, None
        next_shot = 0.0
        monitor = FrameRateMonitor(self.rate)
        while True:
            now = self.clock.now()
            t = now - t0
            for event in self._pending_events():
                quit_reason = _quit_reason(event)
                if quit_reason:
                    writer.event(t, quit_reason)
                    return f"aborted ({quit_reason})"
                if _resized(event) and self.display is not None:
                    self._resize(event.size)
                    writer.event(t, f"window resized to {self.surface.get_width()} x {self.surface.get_height()} px")
                message = self.source.handle_event(event)
                if message:
                    writer.event(t, message)
            change = monitor.add(now)
            if change:
                writer.event(t, change)
            paused = self.source.paused_reason is not None
            if paused and pause_start is None:
                pause_start = t
            elif not paused and pause_start is not None:
                paused_total += t - pause_start
                pause_start = None
            t_signal = (pause_start if paused else t) - paused_total
            command = np.array([s(t_signal) for s in self.signals])
            flown = self.source.read(t_signal)
            levels = tuple(float(s.level_at(t_signal)) for s in self.signals)
            if last_levels is not None and levels != last_levels:
                self.ticker.tick()
            last_levels = levels
            writer.frame(k, t, t_signal, paused, command, flown)
            for panel in self.panels:
                panel.update(k, t, t_signal, flown, paused)
            if self.display is not None:
                state = FrameState(t, t_signal, command, flown,
                                   countdown=self.lead_in - t if t < self.lead_in else None,
                                   message=self.source.paused_reason, warning=monitor.warning, lead_in=t >= 0)
                r0 = self.clock.now()
                self.display.render(self.needle_surface, state)
                self._draw_panels()
                if self.window is not None:
                    import pygame
                    pygame.display.flip()
                self.render_times_.append(self.clock.now() - r0)
                if self.screen.screenshot_every and self.screenshot_dir and t >= next_shot:
                    self.screenshot(f"frame_{k:05d}.png")
                    next_shot = t + self.screen.screenshot_every
            if t_signal >= self.t_end:
                return "completed"
            k += 1
            # next slot on the grid anchored at t0, after the present: late frames skip slots
            slot = np.floor((self.clock.now() - t0) * self.rate + 1e-9) + 1
            self.clock.sleep_until(t0 + slot / self.rate)

    def screenshot(self, name: str) -> Path | None:
        """Save the current frame as PNG in ``screenshot_dir``."""
        if self.surface is None or self.screenshot_dir is None:
            return None
        import pygame
        self.screenshot_dir.mkdir(parents=True, exist_ok=True)
        path = self.screenshot_dir / name
        pygame.image.save(self.surface, str(path))
        return path

    def _show_end(self, lines: list[str]) -> None:
        log = self.log_
        last = log.columns
        n = len(self.signals)
        state = FrameState(float(log.time[-1]), float(last["t_signal"][-1]),
                           np.array([last[i + "_cmd"][-1] for i in self.inputs]).reshape(n),
                           np.array([last[i][-1] for i in self.inputs]).reshape(n), end_lines=lines)
        self.display.render(self.needle_surface, state)
        if self.screenshot_dir is not None:
            self.screenshot("end.png")
        if self.window is not None:
            import pygame
            pygame.display.flip()
            deadline = self.clock.now() + self.screen.end_screen
            while self.clock.now() < deadline:
                if any(e.type in (pygame.QUIT, pygame.KEYDOWN) for e in self._pending_events()):
                    break
                self.clock.sleep_until(self.clock.now() + 0.05)


class FrameRateMonitor:
    """The frame rate achieved over the last ``window`` s against ``target`` (Hz).

    :meth:`add` takes each frame's clock time and returns a line for the log when the rate falls
    under ``LOW_RATE`` of the target or recovers; ``warning`` is the on-screen text while low.
    """

    def __init__(self, target: float, window: float = 1.0):
        self.target, self.window = float(target), float(window)
        self.times: deque[float] = deque()
        self.start = None
        self.warning: str | None = None

    def add(self, now: float) -> str | None:
        self.start = now if self.start is None else self.start
        self.times.append(now)
        while self.times[0] < now - self.window:
            self.times.popleft()
        if now - self.start < self.window or len(self.times) < 2:
            return None
        rate = (len(self.times) - 1) / (self.times[-1] - self.times[0])
        # a little hysteresis: a rate hovering at the limit does not flood the log with events
        low = rate < (LOW_RATE if self.warning is None else LOW_RATE + RECOVERY_MARGIN) * self.target
        change = None
        if low and self.warning is None:
            change = f"frame rate low: {rate:.1f} Hz of {self.target:g} Hz target"
        elif not low and self.warning is not None:
            change = f"frame rate recovered: {rate:.1f} Hz"
        self.warning = f"frame rate {rate:.0f} Hz of {self.target:g} Hz" if low else None
        return change


def _resized(event) -> bool:
    import pygame
    return event.type == pygame.VIDEORESIZE


def _quit_reason(event) -> str | None:
    import pygame
    if event.type == pygame.QUIT:
        return "window closed"
    if event.type == pygame.KEYDOWN and event.key == pygame.K_ESCAPE:
        return "pilot pressed Escape"
    return None

"""The two-needle display (the seed paper's Fig. 3), drawn with pygame on any Surface.

Each signal axis gets a horizontal scale covering +/- ``SCALE_RANGE`` times the signal amplitude,
marked at the signal's levels. The **command needle** (amber) stands above the scale at the
commanded value, the **pilot needle** (cyan) hangs below it at the flown value: lined up, they
form one straight line. An optional preview strip above the command needle shows the next
``preview`` seconds of the sequence falling towards the needle, so switches can be anticipated.

The layout follows the surface it is drawn on (a resized or full-screen window re-lays itself out
on the next frame); the scale is labelled in the input's unit, radians shown as degrees.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SCALE_RANGE = 1.5  # scale half-width in amplitudes
MARGIN = 40  # px left and right of the scale
BACKGROUND = (12, 14, 20)
SCALE_COLOR = (200, 200, 200)
COMMAND_COLOR = (255, 190, 0)
PILOT_COLOR = (0, 210, 255)
PREVIEW_COLOR = (150, 110, 20)
TEXT_COLOR = (235, 235, 235)
WARN_COLOR = (255, 80, 60)
END_BOX_COLOR = (30, 34, 46)
WARNING_MARK = "!"  # an end-screen line starting with it is drawn in the warning colour
NEEDLE_WIDTH = 5
BASE_SIZE = (800, 480)  # px: the layout's reference size; text scales with the window from here
DISPLAY_UNITS = {"rad": (180.0 / np.pi, "deg"), "rad/s": (180.0 / np.pi, "deg/s")}  # shown as


@dataclass
class FrameState:
    """What one frame shows: clock time ``t`` and signal time ``t_signal`` (s), ``command`` and
    ``flown`` (n_axes,) control units, a ``countdown`` (s left) or None, a ``message`` (pause
    notice), a ``warning`` (e.g. a low frame rate), ``lead_in`` (the quiet, already recorded
    stretch before the signal) and ``end_lines`` (the score, on the end-of-run screen)."""

    t: float
    t_signal: float
    command: np.ndarray
    flown: np.ndarray
    countdown: float | None = None
    message: str | None = None
    end_lines: list[str] | None = None
    warning: str | None = None
    lead_in: bool = False


def display_unit(unit: str | None) -> tuple[float, str]:
    """(factor, label) turning a control value in ``unit`` into what the scale shows: rad as deg."""
    if not unit:
        return 1.0, "unit unknown"
    return DISPLAY_UNITS.get(unit, (1.0, unit))


def signal_units(signals, profile=None) -> dict[str, str | None]:
    """Each signal's input unit: from ``profile`` (its ``inputs`` table) or the signal's own
    ``params['units']`` (signaldesign writes it), else None."""
    out = {}
    for s in signals:
        own = s.params.get("units") if isinstance(s.params, dict) else None
        unit = profile.inputs.get(s.input) if profile is not None else None
        out[s.input] = unit or (own.get(s.input) if isinstance(own, dict) else None)
    return out


class Display:
    """Geometry and drawing for ``signals`` on a surface of ``size`` (w, h) px; ``units``
    {input: unit} labels the scales (default: :func:`signal_units`)."""

    def __init__(self, signals, size=BASE_SIZE, preview: float = 0.0, units: dict | None = None):
        self.signals = list(signals)
        self.preview = float(preview)
        units = {**signal_units(self.signals), **{k: v for k, v in (units or {}).items() if v}}
        self.units = [display_unit(units.get(s.input)) for s in self.signals]
        self.half = [SCALE_RANGE * max(abs(s.amplitude) * max(np.max(np.abs(s.levels)), 1e-12), 1e-12)
                     for s in self.signals]
        self._fonts = {}
        self.layout(size)

    def layout(self, size) -> None:
        """Place the scales for a surface of ``size`` (w, h) px."""
        self.size = (int(size[0]), int(size[1]))
        w, h = self.size
        band = h / len(self.signals)
        self.y_scale = [int(band * (j + 0.62)) for j in range(len(self.signals))]
        self.needle_len = int(min(band * 0.16, 60 * h / BASE_SIZE[1]))
        self.text_scale = float(np.clip(min(w / BASE_SIZE[0], h / BASE_SIZE[1]), 0.6, 3.0))

    # -- geometry -------------------------------------------------------------------------------
    def x_of(self, value: float, axis: int = 0) -> int:
        """Pixel column of a control value (control units) on axis ``axis``; clipped to the scale."""
        w = self.size[0]
        frac = (np.clip(value / self.half[axis], -1.0, 1.0) + 1.0) / 2.0
        return int(round(MARGIN + frac * max(w - 2 * MARGIN, 1)))

    def value_of_x(self, x: float, axis: int = 0) -> float:
        """Control value (control units) at pixel column ``x``: the mouse's mapping for axis 0."""
        w = self.size[0]
        frac = np.clip((x - MARGIN) / max(w - 2 * MARGIN, 1), 0.0, 1.0)
        return float((2 * frac - 1) * self.half[axis])

    def value_of_y(self, y: float, axis: int = 1) -> float:
        """Control value at pixel row ``y`` (top of the window: +full scale): the mouse's mapping
        for axis 1."""
        h = self.size[1]
        frac = np.clip((h - MARGIN - y) / max(h - 2 * MARGIN, 1), 0.0, 1.0)
        return float((2 * frac - 1) * self.half[axis])

    def value_of_pointer(self, pos) -> np.ndarray:
        """Control values (n_axes,) at pointer position ``pos`` (x, y) px: x flies the first
        axis, y the second."""
        out = np.zeros(len(self.signals))
        out[0] = self.value_of_x(pos[0], 0)
        if len(self.signals) > 1:
            out[1] = self.value_of_y(pos[1], 1)
        return out

    # -- drawing --------------------------------------------------------------------------------
    def render(self, surface, state: FrameState) -> None:
        import pygame
        if surface.get_size() != self.size:
            self.layout(surface.get_size())
        surface.fill(BACKGROUND)
        for j, sig in enumerate(self.signals):
            self._scale(surface, j, sig)
            if self.preview > 0 and state.end_lines is None:
                self._preview(surface, j, sig, state.t_signal)
            y = self.y_scale[j]
            xc, xp = self.x_of(state.command[j], j), self.x_of(state.flown[j], j)
            pygame.draw.rect(surface, COMMAND_COLOR, (xc - NEEDLE_WIDTH // 2, y - self.needle_len - 2,
                                                      NEEDLE_WIDTH, self.needle_len))
            pygame.draw.rect(surface, PILOT_COLOR, (xp - NEEDLE_WIDTH // 2, y + 3, NEEDLE_WIDTH, self.needle_len))
        w, h = self.size
        self._text(surface, f"t = {max(state.t_signal, 0):5.1f} s", (10, 8), 22)
        if state.countdown is not None and state.countdown > 0:
            self._text(surface, f"{int(np.ceil(state.countdown))}", (w // 2, h // 5), 90, centre=True)
            if state.lead_in:
                self._text(surface, "recording: hold still", (10, int(8 + 26 * self.text_scale)), 22)
        if state.message:
            self._text(surface, state.message, (w // 2, 30), 28, WARN_COLOR, centre=True)
        if state.warning:
            self._text(surface, state.warning, (w - 10, 8), 22, WARN_COLOR, right=True)
        if state.end_lines:
            self._end_screen(surface, state.end_lines)

    def _scale(self, surface, j: int, sig) -> None:
        import pygame
        w = self.size[0]
        y = self.y_scale[j]
        pygame.draw.line(surface, SCALE_COLOR, (MARGIN, y), (w - MARGIN, y), 2)
        factor, unit = self.units[j]
        for level in np.unique(np.concatenate([np.round(sig.levels), [0.0]])) if sig.is_step_sequence \
                else (-1.0, 0.0, 1.0):
            x = self.x_of(level * sig.amplitude, j)
            pygame.draw.line(surface, SCALE_COLOR, (x, y - 12), (x, y + 12), 2)
            self._text(surface, f"{level * sig.amplitude * factor:+.3g}" if level else "0",
                       (x, y + self.needle_len + int(16 * self.text_scale)), 18, centre=True)
        self._text(surface, f"{sig.kind} on {sig.input} [{unit}]",
                   (MARGIN, y + self.needle_len + int(36 * self.text_scale)), 20)

    def _preview(self, surface, j: int, sig, t_signal: float) -> None:
        import pygame
        y0 = self.y_scale[j] - self.needle_len - 4
        height = int(min(y0 - (self.y_scale[j] - self.size[1] / len(self.signals) * 0.62) - 4, 120))
        if height < 10:
            return
        ahead = np.linspace(0.0, self.preview, height)
        values = sig(t_signal + ahead)
        frac = (np.clip(values / self.half[j], -1.0, 1.0) + 1.0) / 2.0
        xs = np.rint(MARGIN + frac * max(self.size[0] - 2 * MARGIN, 1)).astype(int)
        points = list(zip(xs.tolist(), (y0 - np.arange(height)).tolist()))
        pygame.draw.lines(surface, PREVIEW_COLOR, False, points, 3)

    def _end_screen(self, surface, lines: list[str]) -> None:
        import pygame
        w, h = self.size
        step = int(30 * self.text_scale)
        box = pygame.Surface((w - 120, 40 + step * len(lines)))
        box.fill(END_BOX_COLOR)
        surface.blit(box, (60, 40))
        for i, line in enumerate(lines):
            self._text(surface, line, (80, 60 + step * i), 26 if i else 32,
                       WARN_COLOR if line.startswith(WARNING_MARK) else TEXT_COLOR)

    def _text(self, surface, text: str, pos, size: int, color=TEXT_COLOR, centre: bool = False,
              right: bool = False) -> None:
        import pygame
        size = max(int(round(size * self.text_scale)), 8)
        if size not in self._fonts:
            if not pygame.font.get_init():
                pygame.font.init()
            self._fonts[size] = pygame.font.Font(None, size)
        img = self._fonts[size].render(text, True, color)
        rect = img.get_rect(center=pos) if centre else img.get_rect(topright=pos) if right else \
            img.get_rect(topleft=pos)
        surface.blit(img, rect)

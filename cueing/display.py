"""The two-needle display (the seed paper's Fig. 3), drawn with pygame on any Surface.

Each signal axis gets a horizontal scale covering +/- ``SCALE_RANGE`` times the signal amplitude,
marked at the signal's levels. The **command needle** (amber) stands above the scale at the
commanded value, the **pilot needle** (cyan) hangs below it at the flown value: lined up, they
form one straight line. An optional preview strip above the command needle shows the next
``preview`` seconds of the sequence falling towards the needle, so switches can be anticipated.
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
NEEDLE_WIDTH = 5


@dataclass
class FrameState:
    """What one frame shows: clock time ``t`` and signal time ``t_signal`` (s), ``command`` and
    ``flown`` (n_axes,) control units, a ``countdown`` (s left) or None, a ``message`` (pause
    notice), and ``end_lines`` (the score, on the end-of-run screen)."""

    t: float
    t_signal: float
    command: np.ndarray
    flown: np.ndarray
    countdown: float | None = None
    message: str | None = None
    end_lines: list[str] | None = None


class Display:
    """Geometry and drawing for ``signals`` on a surface of ``size`` (w, h) px."""

    def __init__(self, signals, size=(800, 480), preview: float = 0.0):
        self.signals = list(signals)
        self.size = tuple(size)
        self.preview = float(preview)
        w, h = self.size
        band = h / len(self.signals)
        self.y_scale = [int(band * (j + 0.62)) for j in range(len(self.signals))]
        self.needle_len = int(min(band * 0.16, 60))
        self.half = [SCALE_RANGE * max(abs(s.amplitude) * max(np.max(np.abs(s.levels)), 1e-12), 1e-12)
                     for s in self.signals]
        self._fonts = {}

    # -- geometry -------------------------------------------------------------------------------
    def x_of(self, value: float, axis: int = 0) -> int:
        """Pixel column of a control value (control units) on axis ``axis``; clipped to the scale."""
        w = self.size[0]
        frac = (np.clip(value / self.half[axis], -1.0, 1.0) + 1.0) / 2.0
        return int(round(MARGIN + frac * (w - 2 * MARGIN)))

    def value_of_x(self, x: float, axis: int = 0) -> float:
        """Control value (control units) at pixel column ``x``: the mouse source's mapping."""
        w = self.size[0]
        frac = np.clip((x - MARGIN) / (w - 2 * MARGIN), 0.0, 1.0)
        return float((2 * frac - 1) * self.half[axis])

    # -- drawing --------------------------------------------------------------------------------
    def render(self, surface, state: FrameState) -> None:
        import pygame
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
        self._text(surface, f"t = {max(state.t_signal, 0):5.1f} s", (10, 8), 22)
        if state.countdown is not None and state.countdown > 0:
            self._text(surface, f"{int(np.ceil(state.countdown))}", (self.size[0] // 2, self.size[1] // 5), 90,
                       centre=True)
        if state.message:
            self._text(surface, state.message, (self.size[0] // 2, 30), 28, WARN_COLOR, centre=True)
        if state.end_lines:
            self._end_screen(surface, state.end_lines)

    def _scale(self, surface, j: int, sig) -> None:
        import pygame
        w = self.size[0]
        y = self.y_scale[j]
        pygame.draw.line(surface, SCALE_COLOR, (MARGIN, y), (w - MARGIN, y), 2)
        for level in np.unique(np.concatenate([np.round(sig.levels), [0.0]])) if sig.is_step_sequence \
                else (-1.0, 0.0, 1.0):
            x = self.x_of(level * sig.amplitude, j)
            pygame.draw.line(surface, SCALE_COLOR, (x, y - 12), (x, y + 12), 2)
            self._text(surface, f"{level * sig.amplitude:+.3g}" if level else "0", (x, y + self.needle_len + 16),
                       18, centre=True)
        self._text(surface, f"{sig.kind} on {sig.input}", (MARGIN, y + self.needle_len + 36), 20)

    def _preview(self, surface, j: int, sig, t_signal: float) -> None:
        import pygame
        y0 = self.y_scale[j] - self.needle_len - 4
        height = int(min(y0 - (self.y_scale[j] - self.size[1] / len(self.signals) * 0.62) - 4, 120))
        if height < 10:
            return
        ahead = np.linspace(0.0, self.preview, height)
        values = sig(t_signal + ahead)
        frac = (np.clip(values / self.half[j], -1.0, 1.0) + 1.0) / 2.0
        xs = np.rint(MARGIN + frac * (self.size[0] - 2 * MARGIN)).astype(int)
        points = list(zip(xs.tolist(), (y0 - np.arange(height)).tolist()))
        pygame.draw.lines(surface, PREVIEW_COLOR, False, points, 3)

    def _end_screen(self, surface, lines: list[str]) -> None:
        import pygame
        w, h = self.size
        box = pygame.Surface((w - 120, 40 + 30 * len(lines)))
        box.fill((30, 34, 46))
        surface.blit(box, (60, 40))
        for i, line in enumerate(lines):
            self._text(surface, line, (80, 60 + 30 * i), 26 if i else 32)

    def _text(self, surface, text: str, pos, size: int, color=TEXT_COLOR, centre: bool = False) -> None:
        import pygame
        if size not in self._fonts:
            if not pygame.font.get_init():
                pygame.font.init()
            self._fonts[size] = pygame.font.Font(None, size)
        img = self._fonts[size].render(text, True, color)
        rect = img.get_rect(center=pos) if centre else img.get_rect(topleft=pos)
        surface.blit(img, rect)

"""The live estimate's pygame panel, right of the needles: each targeted parameter's Cramér-Rao
bound in % of its estimate as a bar against its target, and "TEST POINT COMPLETE" once all are
below. A :class:`~cueing.runner.Panel`: the runner feeds it every frame and draws it."""
from __future__ import annotations

import time

import numpy as np

from .estimate import LiveIdentification

PANEL_WIDTH = 270  # px right of the needles
GOOD, SHORT = (60, 200, 90), (255, 170, 0)
BACKGROUND, BAR, TEXT, DIM = (20, 24, 34), (50, 55, 70), (235, 235, 235), (170, 170, 170)


class LivePanel:
    """Shows ``live`` (:class:`~cueing.live.estimate.LiveIdentification`), ``width`` px wide; the
    rendered panel is cached and redrawn only after a new estimate."""

    def __init__(self, live: LiveIdentification, width: int = PANEL_WIDTH):
        self.live = live
        self.width = width
        self._panel = None  # the rendered panel
        self._shown = None  # the estimate it shows
        self._fonts = {}

    def update(self, k: int, t: float, t_signal: float, flown, paused: bool) -> None:
        self.live.update(k, t, t_signal, flown, paused)

    def draw(self, surface, rect) -> None:
        """Blit the panel (re-rendered only after a new estimate) into ``rect`` (x, y, w, h)."""
        w0, c0 = time.perf_counter(), time.thread_time()
        # re-rendering the text costs about a millisecond: never on a frame that also solved
        stale = self.live.latest is not self._shown and not self.live.solved_this_frame
        if self._panel is None or stale or self._panel.get_size() != tuple(rect[2:]):
            self._shown = self.live.latest
            self._panel = self._render(rect[2:])
        surface.blit(self._panel, rect[:2])
        self.live.charge(time.perf_counter() - w0, time.thread_time() - c0)

    def _render(self, size):
        import pygame
        w, h = size
        live, est = self.live, self._shown
        panel = pygame.Surface((w, h))
        panel.fill(BACKGROUND)
        self._text(panel, "live estimate: waiting" if est is None else f"live estimate at {est.t:5.1f} s", (10, 8), 22)
        self._text(panel, "Cramér-Rao bound, % of estimate", (10, 30), 17, DIM)
        row_h = max(16, min(30, (h - 120) // max(len(live.targets), 1)))
        bar_x, bar_w = 92, w - 150
        for r, (name, target) in enumerate(live.targets.items()):
            y = 56 + r * row_h
            self._text(panel, name, (10, y), 19)
            pygame.draw.rect(panel, BAR, (bar_x, y + 2, bar_w, row_h - 8))
            tick = bar_x + bar_w // 2  # the target sits at mid-bar: the bar spans 0..2x target
            value = np.nan if est is None else est.relative_std[live.names.index(name)]
            if np.isfinite(value):
                fill = int(min(value / (2 * target), 1.0) * bar_w)
                pygame.draw.rect(panel, GOOD if value <= target else SHORT, (bar_x, y + 2, fill, row_h - 8))
                label = f"{value:5.1f}" if value < 1000 else ">999"
            else:
                label = "  -"
            pygame.draw.line(panel, TEXT, (tick, y - 1), (tick, y + row_h - 5), 2)
            self._text(panel, label, (bar_x + bar_w + 6, y), 19)
        complete = live.complete_at_ is not None
        box = pygame.Rect(10, h - 56, w - 20, 44)
        pygame.draw.rect(panel, GOOD if complete else (60, 60, 70), box, 0 if complete else 2)
        self._text(panel, "TEST POINT COMPLETE" if complete else "collecting ...", box.center, 24,
                   (10, 10, 10) if complete else (200, 200, 200), centre=True)
        return panel

    def _text(self, surface, text, pos, size, color=TEXT, centre=False):
        import pygame
        if size not in self._fonts:
            if not pygame.font.get_init():
                pygame.font.init()
            self._fonts[size] = pygame.font.Font(None, size)
        img = self._fonts[size].render(text, True, color)
        surface.blit(img, img.get_rect(center=pos) if centre else img.get_rect(topleft=pos))

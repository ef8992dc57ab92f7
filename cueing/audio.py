"""Audible ticks at level changes (the paper's audiovisual help); silent, never failing, without audio."""
from __future__ import annotations

import numpy as np

TICK_HZ = 1000.0
TICK_S = 0.03


class Ticker:
    """Plays a short tone on :meth:`tick`; ``enabled`` is False (and ticks are silent) when audio
    is off or the mixer cannot start. ``ticks`` counts requested ticks either way."""

    def __init__(self, enabled: bool = True):
        self.ticks = 0
        self.sound = None
        if enabled:
            self.sound = _make_sound()

    @property
    def enabled(self) -> bool:
        return self.sound is not None

    def tick(self) -> None:
        self.ticks += 1
        if self.sound is not None:
            try:
                self.sound.play()
            except Exception:  # noqa: BLE001 - audio must never stop a run
                self.sound = None


def _make_sound():
    try:
        import pygame
        if not pygame.mixer.get_init():
            pygame.mixer.init(frequency=44100, size=-16, channels=1)
        rate, _, channels = pygame.mixer.get_init()
        n = int(rate * TICK_S)
        t = np.arange(n) / rate
        # a raised-cosine envelope keeps the tick from clicking
        wave = 0.4 * np.sin(2 * np.pi * TICK_HZ * t) * np.sin(np.pi * t / TICK_S) ** 2
        pcm = (wave * 32767).astype(np.int16)
        if channels > 1:
            pcm = np.repeat(pcm[:, None], channels, axis=1)
        return pygame.mixer.Sound(buffer=np.ascontiguousarray(pcm).tobytes())
    except Exception:  # noqa: BLE001 - no audio device, no mixer: run silent
        return None

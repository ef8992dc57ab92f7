"""Clocks the runner reads time from: the real monotonic clock, or a fake one for tests.

The signal is always evaluated from the clock's time, never from a frame count, so a late or
dropped frame shows the command that is due *now*, and the sequence cannot drift.
"""
from __future__ import annotations

import time

import numpy as np

_SPIN = 0.002  # s: the last stretch before a deadline is busy-waited; OS sleep overshoots by ~0.1-1 ms


class MonotonicClock:
    """``time.perf_counter`` (monotonic, sub-microsecond) with a precise ``sleep_until``.

    ``spin``: s before each deadline spent busy-waiting instead of sleeping (sharper wake-ups on an
    idle machine, at some CPU cost; 0 to only sleep).
    """

    def __init__(self, spin: float = _SPIN):
        self.spin = float(spin)

    def now(self) -> float:
        return time.perf_counter()

    def sleep_until(self, deadline: float) -> None:
        """Return at ``deadline`` (s, this clock): sleep most of the way, spin the last 2 ms."""
        while True:
            left = deadline - time.perf_counter()
            if left <= 0:
                return
            if left > self.spin:
                time.sleep(left - self.spin)

    def unix_offset(self) -> float:
        """Unix time (s) minus this clock's time: turns clock stamps into wall-clock stamps."""
        return time.time() - time.perf_counter()


class FakeClock:
    """Deterministic clock for tests: ``sleep_until`` jumps to the deadline plus a scripted lateness.

    ``lateness``: callable ``k -> s`` (or None for none) giving how late wake-up ``k`` is,
    e.g. to simulate jitter or a dropped frame.
    """

    def __init__(self, start: float = 100.0, lateness=None, unix_start: float = 1.7e9):
        self.t = float(start)
        self.lateness = lateness
        self.wakeups = 0
        self._unix = unix_start - start

    def now(self) -> float:
        return self.t

    def sleep_until(self, deadline: float) -> None:
        late = float(self.lateness(self.wakeups)) if self.lateness else 0.0
        self.wakeups += 1
        self.t = max(self.t, deadline + late)

    def advance(self, dt: float) -> None:
        self.t += dt

    def unix_offset(self) -> float:
        return self._unix


def jitter(std: float, seed: int = 0):
    """A FakeClock ``lateness`` giving |normal(0, std)| s late wake-ups."""
    rng = np.random.default_rng(seed)
    return lambda k: abs(rng.normal(0.0, std))

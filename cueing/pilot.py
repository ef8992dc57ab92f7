"""A simulated pilot: a crossover-style human-operator model flying the command needle.

The needle shows the stick directly (a zero-order controlled element), so by the crossover law
the pilot acts as an integrator on the error he saw ``delay`` s ago, and his arm adds a
first-order neuromuscular lag::

    dz/dt = omega_c * e(t - tau),   e = g(c_target) - y
    dy/dt = (z + n(t) - y) / T_n

``omega_c`` is the crossover frequency (rad/s), ``tau`` the reaction delay (s), ``T_n`` the
neuromuscular lag (s), ``n`` the remnant (coloured noise, control units) and ``g`` a per-attempt
level gain error, different for + and - levels (pilots rarely hit both stops alike). With a
preview the pilot sees the switches coming and leads them by his own delay and lag.
``skill`` in [0, 1] sets all of them at once; each can be overridden.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

REMNANT_CORRELATION = 0.3  # s: correlation time of the remnant noise


@dataclass
class PilotParams:
    """Operator parameters: ``omega_c`` rad/s, ``delay`` s, ``lag`` s; ``remnant`` and
    ``level_error`` are fractions of the signal amplitude (standard deviations)."""

    omega_c: float
    delay: float
    lag: float
    remnant: float
    level_error: float

    @classmethod
    def from_skill(cls, skill: float) -> "PilotParams":
        s = float(np.clip(skill, 0.0, 1.0))
        return cls(omega_c=1.5 + 1.2 * s, delay=0.30 - 0.10 * s, lag=0.10,
                   remnant=0.02 + 0.10 * (1 - s), level_error=0.02 + 0.15 * (1 - s))


class PilotModel:
    """Simulated pilot for ``n_axes`` independent control axes.

    ``skill`` in [0, 1]; ``params`` overrides it; ``seed`` makes the remnant and level errors
    reproducible. Call :meth:`reset` before each attempt and :meth:`step` once per frame.
    """

    def __init__(self, skill: float = 0.5, params: PilotParams | None = None, seed: int | None = None,
                 anticipate: bool = True):
        self.skill = float(skill)
        self.params = params or PilotParams.from_skill(skill)
        self.anticipate = anticipate
        self.rng = np.random.default_rng(seed)
        self.preview = False

    @property
    def lead(self) -> float:
        """How far ahead (s) the pilot aims when he can see the sequence coming."""
        return self.params.delay + self.params.lag if (self.preview and self.anticipate) else 0.0

    def reset(self, amplitudes, preview: bool = False) -> "PilotModel":
        """Start an attempt on axes with signal ``amplitudes`` (n_axes,) in control units."""
        self.amplitude = np.abs(np.atleast_1d(np.asarray(amplitudes, float)))
        n = self.amplitude.size
        self.preview = bool(preview)
        self.gain_pos = 1.0 + self.params.level_error * self.rng.standard_normal(n)
        self.gain_neg = 1.0 + self.params.level_error * self.rng.standard_normal(n)
        self.z = np.zeros(n)
        self.y = np.zeros(n)
        self.noise = np.zeros(n)
        self._t: list[float] = []
        self._e: list[np.ndarray] = []
        self._last_t = None
        return self

    def step(self, t: float, command) -> np.ndarray:
        """Advance to signal time ``t`` (s) and return the stick (n_axes,) in control units.

        ``command``: callable ``t -> (n_axes,)`` commanded values; the pilot evaluates it at
        ``t + lead`` (preview) or at ``t`` (no preview), and reacts ``delay`` s later.
        """
        target = np.asarray(command(t + self.lead), float)
        target = target * np.where(target > 0, self.gain_pos, self.gain_neg)
        self._t.append(t)
        self._e.append(target - self.y)
        if self._last_t is None:
            self._last_t = t
            return self.y.copy()
        dt = t - self._last_t
        self._last_t = t
        p = self.params
        e_seen = self._error_at(t - p.delay)
        self.z = self.z + p.omega_c * e_seen * dt
        decay = np.exp(-dt / REMNANT_CORRELATION)
        self.noise = self.noise * decay + p.remnant * self.amplitude * np.sqrt(1 - decay ** 2) * \
            self.rng.standard_normal(self.z.size)
        self.y = self.y + (self.z + self.noise - self.y) * (1 - np.exp(-dt / p.lag))
        return self.y.copy()

    def _error_at(self, t: float) -> np.ndarray:
        times = self._t
        if t <= times[0]:
            return np.zeros_like(self.y)
        # drop history older than needed, keeping one sample before t for interpolation
        i = int(np.searchsorted(times, t)) - 1
        if i > 64:
            del self._t[:i - 1], self._e[:i - 1]
            i = 1
        t0, t1 = self._t[i], self._t[min(i + 1, len(self._t) - 1)]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return (1 - w) * self._e[i] + w * self._e[min(i + 1, len(self._e) - 1)]

    def fly(self, signals, time: np.ndarray, preview: bool = False) -> np.ndarray:
        """Fly ``signals`` (list of Signal, one per axis) over ``time`` (N,) s: flown (N, n_axes)."""
        self.reset([s.amplitude for s in signals], preview)
        command = lambda t: np.array([s(t) for s in signals], float)  # noqa: E731
        return np.array([self.step(float(t), command) for t in time])

"""The finite Fourier transform every frequency-domain estimate here is built on.

``X(w) = int_0^T x(t) e^{-jwt} dt`` over a record, at arbitrary frequencies ``w`` (rad/s; a direct
evaluation, the job a chirp-z transform does in CIFER, so a grid need not be the FFT's). Measured
signals (states, outputs) are integrated by the trapezoidal rule; inputs held over each sample (as
the cockpit's frame log and every simulation here treat them) by the exact integral of the held
signal, ``u_k (e^{-jwt_k} - e^{-jwt_k+1}) / (jw)``, which carries the hold's half-sample delay.

:class:`FourierTransform` is one object for the whole record (``fit``) and for a record growing
sample by sample (``partial_fit``, Morelli's recursive transform: one complex multiply-add per
frequency and channel): both run the same accumulation, so the live and the batch transform of the
same samples agree to rounding. :func:`fourier_sum` is the plain sum ``sum_k x_k e^{-jwt_k}`` over
the leading sample axis of stacked segments, for the windowed (tapered) spectral estimates.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ...errors import EstimationError

CHUNK = 4096  # samples per accumulation step: memory stays (CHUNK, nf)


@dataclass
class Transform:
    """Finite Fourier transforms of one record at ``omega`` (rad/s): states ``X`` (nf, n), inputs
    ``U`` (nf, m) (units x s), boundary term ``end`` (nf, n) = ``x(T) e^{-jwT} - x(0)``, ``one``
    (nf,) the transform of 1 (the zero shift's regressor), record length ``T`` (s)."""

    X: np.ndarray
    U: np.ndarray
    end: np.ndarray
    one: np.ndarray
    T: float


def record_kernel(d: np.ndarray, T: float) -> np.ndarray:
    """``int_0^T e^{-jdt} dt`` for an array of frequencies d (rad/s): the transform of 1 over a
    record of T s (at frequency differences: how far residuals at two frequencies are correlated)."""
    d = np.asarray(d, dtype=float)
    small = np.abs(d) * T < 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (1 - np.exp(-1j * d * T)) / (1j * d)
    return np.where(small, T + 0j, k)


def fourier_sum(x: np.ndarray, t: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``sum_k x[..., k, c] e^{-jw t_k}``: (..., L, c) samples at times t (L,) -> (..., nf, c).

    The discrete sum at arbitrary frequencies; for a taper that vanishes at both ends (Hann) it is
    the trapezoidal finite Fourier transform divided by the sample interval. Computed as two real
    matrix products (cosine and sine kernels, cached per grid): real data times a complex kernel
    in ``einsum`` ran an unbuffered loop that took 80 % of an FR fit (cProfile, benchmarks/frequency_fit.py)."""
    x = np.asarray(x)
    if np.iscomplexobj(x):
        return fourier_sum(x.real, t, omega) + 1j * fourier_sum(x.imag, t, omega)
    c, s = _kernels(np.ascontiguousarray(t, dtype=float).tobytes(), np.ascontiguousarray(omega, dtype=float).tobytes())
    xt = np.swapaxes(x, -1, -2)  # (..., c, L) @ (L, nf) -> (..., c, nf)
    return np.swapaxes(xt @ c, -1, -2) - 1j * np.swapaxes(xt @ s, -1, -2)


@lru_cache(maxsize=32)
def _kernels(t_bytes: bytes, omega_bytes: bytes) -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of ``outer(t, omega)`` (L, nf), read-only: the same grid recurs for every window,
    transform and bootstrap draw of a fit."""
    wt = np.outer(np.frombuffer(t_bytes), np.frombuffer(omega_bytes))
    c, s = np.cos(wt), np.sin(wt)
    c.flags.writeable = s.flags.writeable = False
    return c, s


class FourierTransform:
    """Finite Fourier transform at ``omega`` (rad/s) of states ``x`` and inputs ``u``.

    ``fit(t, x, u)`` transforms a whole record; ``partial_fit(t, x, u)`` adds samples (one: t
    scalar, x (n,), u (m,); or a block: t (k,), x (k, n), u (k, m)) to the record so far. Time is
    counted from the first sample; a sample not later than the last one is skipped (a repeated
    frame adds nothing). ``held_inputs``: inputs held over each sample (else trapezoidal like the
    states). The result is :meth:`transform` (a :class:`Transform`); ``n_samples`` counts samples used.
    """

    def __init__(self, omega, held_inputs: bool = True):
        self.omega = np.asarray(omega, dtype=float)
        self.held_inputs = held_inputs
        self.reset()

    def reset(self) -> "FourierTransform":
        self.n_samples = 0
        self.X_ = self.U_ = None
        self.t0_ = self.x0_ = self.last_ = None  # last: (tau, x, u) of the newest sample
        return self

    def fit(self, t, x, u) -> "FourierTransform":
        return self.reset().partial_fit(t, x, u)

    def partial_fit(self, t, x, u) -> "FourierTransform":
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if t.size == 0:
            return self
        x, u = np.atleast_2d(np.asarray(x, dtype=float)), np.atleast_2d(np.asarray(u, dtype=float))
        if not (len(t) == len(x) == len(u)):
            raise EstimationError(f"Fourier transform: {len(t)} times, {len(x)} state and {len(u)} input samples")
        if self.t0_ is None:
            self.t0_, self.x0_ = t[0], x[0].copy()
            self.X_ = np.zeros((len(self.omega), x.shape[1]), complex)
            self.U_ = np.zeros((len(self.omega), u.shape[1]), complex)
            self.last_ = (-np.inf, None, None)
        tau = t - self.t0_
        # strictly increasing times only: a repeated or late time stamp adds nothing
        keep = tau > np.maximum.accumulate(np.concatenate([[self.last_[0]], tau[:-1]]))
        tau, x, u = tau[keep], x[keep], u[keep]
        for k0 in range(0, len(tau), CHUNK):
            self._accumulate(tau[k0:k0 + CHUNK], x[k0:k0 + CHUNK], u[k0:k0 + CHUNK])
        return self

    def _accumulate(self, tau: np.ndarray, x: np.ndarray, u: np.ndarray) -> None:
        """Add the intervals from the last sample through these (k,) samples."""
        tp, xp, up = self.last_
        if xp is not None:  # the interval from the previous block's last sample
            tau, x, u = np.concatenate([[tp], tau]), np.vstack([xp, x]), np.vstack([up, u])
        self.last_ = (tau[-1], x[-1].copy(), u[-1].copy())
        self.n_samples += len(tau) - (xp is not None)
        if len(tau) < 2:
            return
        e = np.exp(-1j * np.outer(tau, self.omega))  # (k, nf): the multiply, one per frequency
        half = 0.5 * np.diff(tau)[:, None]
        self.X_ += (e[:-1] * half).T @ x[:-1] + (e[1:] * half).T @ x[1:]  # trapezoid
        if self.held_inputs:  # u_k held over [t_k, t_k+1]
            self.U_ += ((e[:-1] - e[1:]) / (1j * self.omega)).T @ u[:-1]
        else:
            self.U_ += (e[:-1] * half).T @ u[:-1] + (e[1:] * half).T @ u[1:]

    @property
    def T(self) -> float:
        """Record length so far (s)."""
        return 0.0 if self.last_ is None else float(self.last_[0])

    def transform(self) -> Transform:
        if self.last_ is None or self.last_[1] is None:
            raise EstimationError("Fourier transform: no samples yet")
        T = self.T
        end = np.outer(np.exp(-1j * self.omega * T), self.last_[1]) - self.x0_
        return Transform(self.X_.copy(), self.U_.copy(), end, record_kernel(self.omega, T), T)

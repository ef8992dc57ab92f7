"""Multisine phases for a small relative peak factor: Schroeder's formula, then iterative optimisation.

A multisine's information per unit of peak deflection grows as its power per unit of peak does, so
flight-test multisines (Morelli's orthogonal optimised multisines, SIDPAC ``mkmsswp``) choose the
phases of equal-power harmonics to minimise the relative peak factor (RPF)::

    RPF = (max u - min u) / (2 sqrt(2) rms(u))

1 for a single sine, 1/sqrt(2) for a square wave. Schroeder's phases are the start; then
``clipping`` iterations (clip the signal at a fraction of its peak, keep each harmonic's phase of
the clipped signal's spectrum: the spectrum is re-imposed, the peaks fall; van der Ouderaa et al.)
and a direct minimax (a smooth maximum of u and of -u, log-sum-exp with a sharpening scale,
minimised by L-BFGS over the phases) take it further. The peak factor is measured on the samples
that are flown (the signal holds each sample for ``dt``), not on a finer grid.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize
from scipy.special import logsumexp, softmax

PHASES = ("optimised", "schroeder")


def schroeder_phases(n: int) -> np.ndarray:
    """Schroeder's low-crest-factor phases for n equal-power harmonics (rad)."""
    k = np.arange(1, n + 1)
    return -np.pi * k * (k - 1) / n


def relative_peak_factor(u) -> float:
    """(max - min) / (2 sqrt(2) rms) of a signal's samples (1 for a sine); about its mean, so a
    signal with no excursion has none (nan)."""
    u = np.asarray(u, float)
    rms = float(np.sqrt(np.mean((u - u.mean()) ** 2)))
    return float(np.ptp(u) / (2 * np.sqrt(2) * rms)) if rms > 0 else float("nan")


def _waveform(phases, W):
    """Samples of sum_k sin(W[:, k] + phases[k]) (W: (n_samples, n_harmonics) angles w_k t)."""
    return np.sin(W + phases).sum(axis=1)


def _clip_iterations(phases, W, iterations: int):
    """Clip at a fraction of the peak, re-impose the harmonics' amplitudes, keep the phases (least
    squares onto sin/cos of each harmonic: exact on a whole period). The best RPF seen is kept."""
    S, C = np.sin(W), np.cos(W)
    best, best_rpf = phases, relative_peak_factor(_waveform(phases, W))
    for i in range(iterations):
        u = _waveform(phases, W)
        level = (0.9 - 0.2 * i / max(iterations - 1, 1)) * np.abs(u).max()
        c = np.clip(u, -level, level)
        # sin(w t + phi) = sin(w t) cos(phi) + cos(w t) sin(phi): phi from the projections
        phases = np.arctan2(C.T @ c, S.T @ c)
        rpf = relative_peak_factor(_waveform(phases, W))
        if rpf < best_rpf:
            best, best_rpf = phases, rpf
    return best


def _minimax(phases, W, sharpness=(8.0, 32.0, 128.0, 512.0)):
    """Minimise a smooth max(u) - min(u) (log-sum-exp at growing sharpness, in units of the rms)."""
    rms = np.sqrt(W.shape[1] / 2)
    best, best_rpf = phases, relative_peak_factor(_waveform(phases, W))
    for beta in sharpness:
        def f(ph):
            s = np.sin(W + ph)
            c = np.cos(W + ph)
            u = s.sum(axis=1) / rms
            up, dn = logsumexp(beta * u) / beta, logsumexp(-beta * u) / beta
            grad = (softmax(beta * u) - softmax(-beta * u)) @ c / rms
            return up + dn, grad
        res = minimize(f, phases, jac=True, method="L-BFGS-B", options={"maxiter": 300})
        phases = res.x
        rpf = relative_peak_factor(_waveform(phases, W))
        if rpf < best_rpf:
            best, best_rpf = phases, rpf
    return best


def optimised_phases(harmonics, t, w0: float, starts: int = 4, seed: int = 0,
                     clip_iterations: int = 60) -> np.ndarray:
    """Phases (rad, one per harmonic) of ``sum sin(k w0 t + phi_k)`` over the samples ``t`` (s) with
    a small relative peak factor: Schroeder's phases and ``starts - 1`` seeded random ones, each
    through clipping iterations and the minimax; the best is returned (never worse than
    Schroeder's: it is one of the candidates). The same arguments give the same phases."""
    harmonics = np.asarray(harmonics, float)
    W = np.outer(np.asarray(t, float), harmonics * w0)
    rng = np.random.default_rng(seed)
    cands = [schroeder_phases(harmonics.size)]
    cands += [rng.uniform(-np.pi, np.pi, harmonics.size) for _ in range(max(starts, 1) - 1)]
    best, best_rpf = cands[0], relative_peak_factor(_waveform(cands[0], W))
    if harmonics.size < 2:
        return best
    for ph in cands:
        ph = _minimax(_clip_iterations(ph, W, clip_iterations), W)
        rpf = relative_peak_factor(_waveform(ph, W))
        if rpf < best_rpf - 1e-12:
            best, best_rpf = ph, rpf
    return np.mod(best + np.pi, 2 * np.pi) - np.pi

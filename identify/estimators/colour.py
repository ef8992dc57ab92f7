"""Coloured residuals: products with the Toeplitz matrix of a residual autocorrelation, by FFT.

Morelli & Klein's correction for coloured residuals replaces the white-noise information
``J^T J / sigma^2`` by ``J^T T J``, ``T`` the Toeplitz matrix of the residuals' (biased)
autocorrelation ``r(k) = 1/N sum_t v(t) v(t+k)``. Both the equation-error estimators (per run and
equation) and output-error ML (per output and run, pooled over the run's segments) use it.

``T Z`` is a linear convolution of each column of ``Z`` (N, ...) with ``r(-(N-1)..N-1)``; it is done
as a circular one over ``n_fft >= 2N - 1`` points. The circular autocorrelation of ``v`` zero-padded
to ``n_fft`` has the spectrum ``|rfft(v, n_fft)|^2`` (real, non-negative) and equals the linear one
on lags ``|k| < N``, so no autocorrelation is ever formed: spectra of several blocks simply add
(pooling), and O(q N log N) replaces the O(q N^2) of a dense Toeplitz product.
"""
from __future__ import annotations

import numpy as np


def power(v: np.ndarray, n_fft: int) -> np.ndarray:
    """``|rfft(v, n_fft)|^2`` along axis 0: the spectrum of v's autocorrelation sums (not divided
    by the sample count), (n_fft // 2 + 1, ...). Zero padding in v adds nothing, so the powers of
    blocks of different lengths, padded to one length, add up to their pooled autocorrelation."""
    V = np.fft.rfft(v, n_fft, axis=0)
    return V.real ** 2 + V.imag ** 2


def toeplitz_apply(spectrum: np.ndarray, Z: np.ndarray, n_fft: int) -> np.ndarray:
    """``T Z`` along axis 0 of ``Z`` (N, ...), T the Toeplitz matrix of the autocorrelation whose
    spectrum (from :func:`power`, divided by the sample count) is ``spectrum``; ``n_fft >= 2N - 1``
    and the same as for the spectrum. ``spectrum`` (F, ...) broadcasts against ``Z``'s leading axes
    (e.g. (F, ny) for one autocorrelation per output, Z (N, ny, q))."""
    N = Z.shape[0]
    s = spectrum.reshape(spectrum.shape + (1,) * (Z.ndim - spectrum.ndim))
    return np.fft.irfft(s * np.fft.rfft(Z, n_fft, axis=0), n_fft, axis=0)[:N]


def autocorr_apply(v: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """``R Z`` for R the Toeplitz matrix of v's biased autocorrelation, via FFT (N, q)."""
    N = len(v)
    return toeplitz_apply(power(v, 2 * N) / N, Z, 2 * N)

"""Coloured-residual standard errors of output error (Morelli & Klein), by FFT and block algebra.

:class:`ColouredBounds` computes, after an ML fit, the covariance ``M^-1 B M^-1`` with
``B = sum over whitened outputs y and segments s of J_ys^T T_y J_ys`` (the sandwich of
:meth:`identify.estimators.output_error.OutputError.coloured_information`, which documents the
statistics). Products with the Toeplitz matrices ``T_y`` are FFT convolutions, the covariances are
formed block by block (:class:`~identify.estimators.information.BlockInformation`), and long
records are taken a group of segments, a time block or a chunk of Jacobian columns at a time.
"""
from __future__ import annotations

import numpy as np
import scipy.fft

from .colour import power
from .information import BlockCovariance, BlockInformation

COLOUR_MAX_ITER = 30  # passes of the noise-autocorrelation fixed point at most
COLOUR_TOL = 1e-2  # ... until no parameter standard error changes by more than this (relative)
COLOUR_CHUNK_FLOATS = 3_000_000  # Jacobian columns per FFT: ~24 MB of spectra
COLOUR_CACHE = 8_000_000  # spectra kept between passes up to this many floats (64 MB)


class ColouredBounds:
    """The coloured-residual covariance of one output-error problem at its estimate.

    ``prob``: the :class:`~identify.estimators.output_error.OutputError`; ``ev`` its response with
    sensitivities at the estimate; ``Wh`` the whitening (ny, ny); ``info`` the information there.
    The filter-error method passes its innovations through the same interface
    (:class:`identify.estimators.filter_error.bounds._Innovations`), its innovation sensitivities for J.
    :meth:`solve` returns the covariance, the noise autocorrelation and the number of passes.

    The fixed point for the noise autocorrelation is linear (but for the clip to a non-negative
    spectrum); its slow modes are the low frequencies that the segments' initial states absorb
    (plain passes contract them by only ~0.65 each), so the passes are preconditioned by the
    circulant approximation of the map (:func:`_preconditioner`) and combined by Anderson
    acceleration (:func:`_anderson_weights`): on the ML speed benchmark 4 passes reach the fixed
    point within 0.7 % (plain passes: 6 within 0.9 %).

    Memory: the columns of each segment's Jacobian go through the FFTs a chunk at a time
    (COLOUR_CHUNK_FLOATS); their spectra are kept between passes only while they are small
    (COLOUR_CACHE), else recomputed, so an hour at 100 Hz stays within a few hundred MB.
    """

    def __init__(self, prob, ev, Wh: np.ndarray, info: BlockInformation, extra: np.ndarray | None = None):
        self.prob, self.ev, self.Wh, self.info = prob, ev, Wh, info
        # ``extra`` (S, k, k): local information that is not the residuals' (the filter-error
        # method's information in its innovation covariance), taken as it is into B
        self.extra = extra
        L, ny, S = ev.e.shape
        self.L, self.ny, self.S = L, ny, S
        self.n_fft = scipy.fft.next_fast_len(2 * L - 1, real=True)
        self.F = self.n_fft // 2 + 1
        # one noise autocorrelation per run (its segments pooled): runs flown on different axes
        # leave residuals of different size and colour (the unmodelled part scales with the
        # response), and one pooled autocorrelation would give a sandwich that is wrong both ways
        self.run = np.asarray(prob.layout.run, dtype=int)[:S]
        self.n_runs = int(self.run.max()) + 1
        counts = np.bincount(self.run, weights=prob.mask.sum(axis=0)[:S], minlength=self.n_runs)
        self.count = np.maximum(counts, 1.0)[:, None, None]  # (runs, 1, 1)
        # the autocorrelations (even in the lag) are held as their real spectra (runs, F, ny): half
        # the floats of the n_fft lags, and an hour's record keeps one per pass for the acceleration
        P = power(Wh @ ev.e, self.n_fft)  # (F, ny, S), of the whitened residuals
        self.r = np.stack([P[..., self.run == g].sum(axis=2) for g in range(self.n_runs)]) / self.count
        self.variance = np.fft.irfft(self.r, self.n_fft, axis=1)[:, :1]  # lag 0 (runs, 1, ny)
        self.k_loc = prob.p + prob.n + ny
        cov, _ = info.covariance()
        self.cov_local = info.local(cov)  # (S, k, k)
        # columns of each segment's Jacobian are taken a chunk at a time, so that the spectra of a
        # long record (n_fft ~ 2 N) never exist for all columns at once; spectra are kept between
        # passes while they fit in COLOUR_CACHE floats (short segments: always)
        self.width = max(1, min(self.k_loc, COLOUR_CHUNK_FLOATS // (2 * self.F * ny)))  # complex: 2 floats
        self.cache_ok = S * self.F * ny * self.k_loc * 4 <= COLOUR_CACHE  # two complex spectra per column
        self.short = L * ny * self.k_loc <= COLOUR_CHUNK_FLOATS  # a segment's Jacobian may be held whole
        self.cache = {}
        self.held = None
        if self.cache_ok:  # small: every segment's Jacobian built once for all passes
            self.held = list(self._rebuilt([(0, S)], prob.local_jacobian(ev, Wh)))

    # -- the segments' Jacobians and their spectra -------------------------------------------------
    def segments(self):
        """``(s, keep, J)`` for every segment in turn, J a :class:`_SegmentJacobian`; many short
        segments have their Jacobians rebuilt a group at a time (one sensitivity recursion for the
        group), a long one a time block at a time."""
        if self.held is not None:
            return iter(self.held)
        return self._rebuilt(self.prob.segment_groups() if self.short else [(0, self.S)])

    def _rebuilt(self, groups, Jloc=None):
        prob = self.prob
        for a, b in groups:
            group = Jloc if Jloc is not None else \
                prob.local_jacobian(self.ev, self.Wh, segment=slice(a, b)) if self.short else None
            for s in range(a, b):
                keep = prob.local_index[s] >= 0
                whole = None if group is None else group[s - a, :prob.layout.length[s]][..., keep]
                yield s, keep, _SegmentJacobian(prob, self.ev, self.Wh, s, keep, whole)

    def spectra(self, s: int, c: slice, J: "_SegmentJacobian", cov_ii: np.ndarray | None):
        """Spectra (w, ny, F) of the columns c of J and of (J cov)[:, c] (None without
        ``cov_ii``, unless kept), time last (scipy's FFT along a contiguous last axis is 2x
        numpy's along a strided first one). The FFT is linear: with all columns at once the
        latter is a small product, not another FFT."""
        key = (s, c.start, c.stop)  # slices are not hashable before Python 3.12
        if key in self.cache:
            return self.cache[key]
        FJ = scipy.fft.rfft(J.columns(c), self.n_fft, axis=-1)
        if cov_ii is None:
            return FJ, None
        FG = _over_columns(cov_ii, FJ) if c == slice(None) else \
            scipy.fft.rfft(J.times(cov_ii[:, c]), self.n_fft, axis=-1)
        if self.cache_ok:
            self.cache[key] = FJ, FG
        return FJ, FG

    def chunks(self, q: int) -> list[slice]:
        w = self.width
        return [slice(None)] if w >= q else [slice(a, min(q, a + w)) for a in range(0, q, w)]

    # -- one pass of the fixed point ---------------------------------------------------------------
    def first_half(self, rho: np.ndarray, white: bool):
        """``B(rho)`` (local blocks, (S, k, k)) and the ``2 xcorr(J cov, T J)`` part of the
        correction (runs, ny, F), ``rho`` given by its spectra (runs, F, ny). For white ``rho``
        (the first pass, constant spectrum) ``T J = rho(0) J`` needs no FFT."""
        spectra = np.clip(rho, 0.0, None).transpose(0, 2, 1)  # a covariance: PSD, (runs, ny, F)
        Bl = np.zeros((self.S, self.k_loc, self.k_loc)) if self.extra is None else self.extra.copy()
        corr = np.zeros((self.n_runs, self.ny, self.F))
        shared = {}
        for s, keep, J in self.segments():
            g = self.run[s]
            spectrum = spectra[g]
            cov_ii = self.cov_local[s][np.ix_(keep, keep)]
            block = np.zeros((J.q, J.q))
            for c in self.chunks(J.q):
                FJ, FG = self.spectra(s, c, J, cov_ii)
                # the initial-state and zero-shift columns of segments of one length are the same
                # (C Phi^k and Wh): their T J is computed once per length (held segments; not for a
                # nonlinear model, whose initial-state response is each segment's own: dy_x0 (L, ny, n, S))
                shared_x0 = self.held is not None and c == slice(None) and self.ev.dy_x0.ndim == 3
                n_own = int(keep[:self.prob.p].sum()) if shared_x0 else len(FJ)
                parts = [(slice(0, n_own), self._toeplitz_times(FJ, J, c, slice(0, n_own), spectrum, rho, white))]
                if n_own < len(FJ):
                    key = (g, J.length, keep.tobytes())
                    if key not in shared:
                        shared[key] = self._toeplitz_times(FJ, J, c, slice(n_own, None), spectrum, rho, white)
                    parts.append((slice(n_own, None), shared[key]))
                for cols, (TJ, FTJ) in parts:
                    block[:, c][:, cols] = J.gram(TJ)
                    corr[g] += 2 * _real_inner(FG[cols], FTJ)
                del FJ, FG, parts, TJ, FTJ  # before the next chunk's arrays exist
            Bl[s][np.ix_(keep, keep)] += block
        return 0.5 * (Bl + Bl.transpose(0, 2, 1)), corr

    def _toeplitz_times(self, FJ, J, c, cols, spectrum, rho, white):
        """``T J`` (w, ny, l) and its spectrum for the columns c of J (``cols`` of its spectra FJ)."""
        if white:
            rho0 = spectrum[:, :1]  # (ny, 1): the variance
            return rho0 * J.columns(c)[cols], rho0 * FJ[cols]
        TJ = scipy.fft.irfft(spectrum * FJ[cols], self.n_fft, axis=-1)[..., :J.length]
        return TJ, scipy.fft.rfft(TJ, self.n_fft, axis=-1)

    def second_half(self, cov_c: BlockCovariance, corr: np.ndarray) -> np.ndarray:
        """The spectra (runs, F, ny) of ``g(rho)``: ``r`` plus the correction ``corr`` less
        ``xcorr(J cov B cov, J)``, ``cov_c = cov B cov``."""
        cov_c = self.info.local(cov_c)
        for s, keep, J in self.segments():
            cc = cov_c[s][np.ix_(keep, keep)]
            for c in self.chunks(J.q):
                FJ = self.spectra(s, c, J, self.cov_local[s][np.ix_(keep, keep)] if self.cache_ok else None)[0]
                FC = _over_columns(cc, FJ) if c == slice(None) else \
                    scipy.fft.rfft(J.times(cc[:, c]), self.n_fft, axis=-1)
                corr[self.run[s]] -= _real_inner(FC, FJ)
                del FJ, FC
        return self.r + corr.transpose(0, 2, 1) / self.count

    # -- the fixed point -------------------------------------------------------------------------
    def solve(self, max_iter: int = COLOUR_MAX_ITER, tol: float = COLOUR_TOL):
        """The covariance (:class:`BlockCovariance`), ``rho`` (L, ny) (the runs' pooled, weighted
        by their samples) and the number of passes."""
        r, info = self.r, self.info
        # Parseval: inner products of spectra weighted as the lags' (rfft bins 1.. count twice)
        weight = np.full((1, self.F, 1), 2.0)
        weight[:, 0] = weight[:, -1 if self.n_fft % 2 == 0 else 0] = 1.0
        xs, fs, Bs = [], [], []
        gram = np.zeros((max_iter, max_iter))  # of the residuals fs: no copies of them
        rho = np.broadcast_to(self.variance, r.shape)  # start: white noise of the residuals' variance
        std_old, gain = None, None
        for passes in range(1, max_iter + 1):
            B_k, corr = self.first_half(rho, white=passes == 1)
            g_k = self.second_half(info.sandwich(B_k), corr)
            if gain is None:
                gain = _preconditioner(g_k - r, self.variance)
            # the preconditioned map h(rho) = rho + P (g(rho) - rho) has the same fixed point
            xs.append(rho), fs.append(gain * (g_k - rho)), Bs.append(B_k)
            k = len(fs)
            weighted = weight * fs[-1]
            gram[k - 1, :k] = gram[:k, k - 1] = [np.vdot(weighted, f) for f in fs]
            del weighted
            # B is linear in rho: the Anderson combination's B is the same combination of the passes'
            alpha = _anderson_weights(gram[:k, :k])
            cov_c = info.sandwich(sum(a * b for a, b in zip(alpha, Bs)))
            std = np.sqrt(np.clip(np.diag(cov_c.gg)[:self.prob.p], 0, None))  # the parameters (nuisances follow)
            if std_old is not None and np.all(np.abs(std - std_old) <= tol * std_old):
                break
            std_old = std
            rho = sum(a * (x + f) for a, x, f in zip(alpha, xs, fs))
        rho_bar = sum(a * x for a, x in zip(alpha, xs))
        pooled = (rho_bar * self.count).sum(axis=0) / self.count.sum()
        return cov_c, np.fft.irfft(pooled, self.n_fft, axis=0)[:self.L], passes


def _over_columns(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``sum_q A[q, r] X[q]`` (r, ny, F) for complex spectra X (q, ny, F), as one real matrix
    product on their (re, im) pairs (4x fewer operations than a complex one)."""
    q, ny, F = X.shape
    return (A.T @ X.view(float).reshape(q, -1)).view(complex).reshape(A.shape[1], ny, F)


def _real_inner(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``Re sum_q conj(A) B`` (ny, F) of complex spectra (q, ny, F), on their (re, im) pairs."""
    _, ny, F = A.shape
    return np.einsum("qyf,qyf->yf", A.view(float), B.view(float)).reshape(ny, F, 2).sum(axis=-1)


def _preconditioner(correction: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """``1 / (1 - K(f))`` (runs, F, ny), K the share of the noise spectrum the fit removes at each
    frequency, read from the spectra (runs, F, ny) of the first pass's ``correction`` at white noise
    of ``variance`` (runs, 1, ny): the map ``rho -> r + A rho`` as a circulant (long segments) is
    ``S -> S_r + K S``."""
    K = correction / np.maximum(variance, 1e-300)
    return 1 / np.maximum(1 - K, 0.1)


def _anderson_weights(gram: np.ndarray) -> np.ndarray:
    """Weights ``alpha`` (k,), summing to 1, that minimise ``|sum alpha_i f_i|`` for residuals
    ``f_i`` of Gram matrix ``gram`` (k, k) (their inner products: long records hold no copies)."""
    k = len(gram)
    if k == 1:
        return np.ones(1)
    # alpha_j = gamma_j (j < k-1), alpha_last = 1 - sum gamma: min |f_last - sum gamma_j (f_last - f_j)|,
    # normal equations in the inner products of the differences f_last - f_j
    last = gram[-1, -1]
    A = last - gram[-1, :-1][:, None] - gram[-1, :-1][None, :] + gram[:-1, :-1]
    b = last - gram[-1, :-1]
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))  # scaled: the differences shrink pass by pass
    gamma = np.linalg.lstsq(A / np.outer(d, d), b / d, rcond=1e-13)[0] / d
    return np.append(gamma, 1 - gamma.sum())


class _SegmentJacobian:
    """The whitened local Jacobian (l, ny, q) of one segment (its estimated columns ``keep``),
    either held ``whole`` or rebuilt from the stored sensitivities a time block at a time, so
    that a long record's Jacobian never exists whole: its products are all it offers."""

    def __init__(self, prob, ev, Wh: np.ndarray, segment: int, keep: np.ndarray,
                 whole: np.ndarray | None = None):
        self.prob, self.ev, self.Wh, self.segment, self.keep, self.whole = prob, ev, Wh, segment, keep, whole
        self.length, self.q, self.ny = int(prob.layout.length[segment]), int(keep.sum()), ev.e.shape[1]
        # columns first, time last (q, ny, l): the FFTs run along a contiguous axis and the
        # products over columns are single matrix products
        self.whole_t = None if whole is None else np.ascontiguousarray(whole.transpose(2, 1, 0))

    def columns(self, c: slice) -> np.ndarray:
        """Columns c of J (w, ny, l)."""
        if self.whole_t is not None:
            return self.whole_t[c]
        return self.times(np.eye(self.q)[:, c])

    def times(self, C: np.ndarray) -> np.ndarray:
        """``J C`` (w, ny, l) for C (q, w)."""
        if self.whole_t is not None:
            return (C.T @ self.whole_t.reshape(self.q, -1)).reshape(C.shape[1], self.ny, self.length)
        out = np.empty((C.shape[1], self.ny, self.length))
        for k0, k1, J in self._blocks():
            out[..., k0:k1] = (J @ C).transpose(2, 1, 0)
        return out

    def _blocks(self):
        if self.whole is not None:
            yield 0, self.length, self.whole
            return
        for k0, k1 in self.prob.blocks(len(self.keep)):
            if k0 >= self.length:
                break
            k1 = min(k1, self.length)
            yield k0, k1, self.prob.local_jacobian(self.ev, self.Wh, k0, k1, self.segment)[0][..., self.keep]

    def gram(self, T: np.ndarray) -> np.ndarray:
        """``J^T T`` (q, w) summed over time and outputs, T (w, ny, l)."""
        w = T.shape[0]
        if self.whole_t is not None:
            return self.whole_t.reshape(self.q, -1) @ T.reshape(w, -1).T
        acc = np.zeros((self.q, w))
        for k0, k1, J in self._blocks():
            acc += J.reshape(-1, self.q).T @ np.ascontiguousarray(T[..., k0:k1].transpose(2, 1, 0)).reshape(-1, w)
        return acc

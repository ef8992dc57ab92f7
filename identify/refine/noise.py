"""Coloured residuals in refine's tests: a vector autoregressive (VAR) noise model and whitening.

Output-error residuals of flight data are never white: turbulence passes through the aircraft's
own dynamics, sensors are filtered, small unmodelled dynamics leave smooth errors. The score and
likelihood-ratio statistics of :mod:`identify.refine` assume white residuals; with coloured ones
they come out tens of times too large. They are therefore computed in the metric of a noise model
fitted to the residuals of the current model (a generalised-least-squares score test)::

    e_t / sigma = sum_{k=1..p} A_k e_{t-k} / sigma + eps_t,   eps_t white, Cov(eps) = Sigma = L L^T

``e_t`` (ny,) the residual of every output at sample t, ``sigma`` (ny,) their RMS (so the outputs'
units do not matter), ``A_k`` (ny, ny) and the order ``p`` (0..``max_order``) chosen by Akaike's
criterion on all runs pooled, raised until the innovations pass a portmanteau whiteness test
(``white`` False if they still fail at ``max_order``). A vector model, not one per output:
turbulence drives every output at once, and the cross-correlations (q and theta, v and r) matter
as much as each output's own.

The whitening ``W x_t = L^-1 (x_t - sum_k A_k x_{t-k}) / sigma`` (first ``p`` samples of each run
dropped) is applied alike to the residual and to every sensitivity column; under the null
hypothesis the whitened projected residual is then white with unit variance, so the score
statistic ``||U_c^T (I - Q Q^T) W e||^2`` is chi-square again.

Before the model is fitted, each run's mean, linear trend and the output's most prominent spectral
line are regressed out of its residual: a drift or a vibration is structure a candidate may
explain, and a noise model that absorbed it (an AR pole pair sitting on the line) would hide it.
The line is found against the spectrum's running median (:func:`line_frequency`), so a broad
turbulence hump is not mistaken for it.

With multiple shooting (an unstable model's runs cut into segments, each from its own fitted
initial state) the residual restarts at every segment: the gust response accumulated over one
segment drops to nothing at the next. A recursion run across that boundary turns the jump into a
whitened spike, in the residual and in every sensitivity column alike (they restart there too), and
the correlated spikes inflate every statistic. The model is therefore fitted and applied segment by
segment (``segment`` s, cut as :func:`identify.estimators.output_error.cut` cuts the runs), the
first ``p`` samples of each segment dropped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, stats

from ..estimators.output_error import cut

MAX_ORDER = 25  # lags: enough for turbulence through slow modes at 100 Hz (AR poles carry the memory)
PORTMANTEAU_LAGS, WHITE_LEVEL = 30, 0.01  # the innovations' whiteness check that may raise the order
LINE_WIDTH = 15  # bins either side for the running median that is the smooth background spectrum


@dataclass
class NoiseModel:
    """``sigma`` (ny,) residual RMS, ``A`` (p, ny, ny) autoregressive matrices, ``L_inv`` (ny, ny)
    the inverse Cholesky factor of the innovation covariance (of the scaled residual); ``segment``
    (s, ``inf``: whole runs) and ``dt`` (s) the multiple-shooting segments it restarts at."""

    sigma: np.ndarray
    A: np.ndarray
    L_inv: np.ndarray
    segment: float = math.inf
    dt: float = 1.0
    white: bool = True  # the innovations passed the portmanteau test (False: the order is at its limit)
    gram: np.ndarray | None = None  # (ny p, ny p) Gram matrix of the lagged data the A were fitted to
    n_innov: int = 0  # degrees of freedom of the innovation covariance (innovations less the A's count)

    @property
    def order(self) -> int:
        return int(self.A.shape[0])

    @classmethod
    def white(cls, sigma) -> "NoiseModel":
        """No colour: weights 1/sigma only (the classical score test)."""
        sigma = np.asarray(sigma, float)
        ny = len(sigma)
        return cls(sigma, np.zeros((0, ny, ny)), np.eye(ny))

    @classmethod
    def fit(cls, residuals: list[np.ndarray], dt: float, f_min: float = 0.5,
            max_order: int = MAX_ORDER, order: int | None = None, deterministic: bool = True,
            segment: float = math.inf) -> "NoiseModel":
        """Fit the VAR model to residuals (list of (N_r, ny) arrays, one per run); ``order`` fixes
        the order (else Akaike's choice up to ``max_order``); ``deterministic``: remove each run's
        mean, trend and the most prominent line first (for the score tests), else fit the
        residuals as they are (the noise model of a hypothesis, for likelihoods)."""
        runs = [np.atleast_2d(np.asarray(e, float).T).T for e in residuals]
        ny = runs[0].shape[1]
        sigma = np.sqrt(np.mean(np.vstack(runs) ** 2, axis=0))
        sigma = np.where(sigma > 0, sigma, 1.0)
        freqs = [line_frequency([e[:, j] for e in runs], dt, f_min) if deterministic else np.nan
                 for j in range(ny)]
        clean = [piece for e in runs for piece in _segments(
            _deterministic_removed(e / sigma, dt, freqs) if deterministic else e / sigma, dt, segment)]
        p_max = int(min(max_order, min(len(e) for e in clean) // 10,
                        max(sum(len(e) for e in clean) // (4 * ny) - 1, 0)))
        if order is not None:
            p_max = min(int(order), p_max)
        Y = np.vstack([e[p_max:] for e in clean])  # (n, ny)
        X = np.vstack([np.hstack([e[p_max - k:len(e) - k] for k in range(1, p_max + 1)]) if p_max
                       else np.zeros((len(e), 0)) for e in clean])  # (n, ny p_max), lag-major
        n = len(Y)
        # nested orders from one Gram matrix: the order-p fit uses its leading ny p block
        G, H, YY = X.T @ X, X.T @ Y, Y.T @ Y
        G += 1e-12 * max(np.trace(G) / max(len(G), 1), 1e-300) * np.eye(len(G))
        best, best_aic = 0, np.inf
        for p in (range(p_max + 1) if order is None else [p_max]):
            c = ny * p
            S = (YY - H[:c].T @ np.linalg.solve(G[:c, :c], H[:c])) / max(n - c, 1) if c else YY / n
            aic = n * _logdet(S) + 2.0 * c * ny
            if aic < best_aic:
                best, best_aic = p, aic
        # Akaike weighs all frequencies alike; colour left at low frequencies, in a few bins, costs it
        # little but biases the tests of smooth columns (derivatives scored 2.1 on average on the
        # turbulent BO 105 at its order 6, 0.8 at 25): raise the order until the innovations pass
        # a portmanteau whiteness test
        lengths = [len(e) - p_max for e in clean]
        while True:
            c = ny * best
            coef = np.linalg.solve(G[:c, :c], H[:c]) if c else np.zeros((0, ny))
            innov = Y - X[:, :c] @ coef
            white = order is not None or portmanteau_p(innov, lengths, best, PORTMANTEAU_LAGS) > WHITE_LEVEL
            if white or best >= p_max:
                break
            best += 1
        A = coef.T.reshape(ny, best, ny).transpose(1, 0, 2) if best else np.zeros((0, ny, ny))
        Sigma = innov.T @ innov / max(n - c, 1)
        Sigma += 1e-10 * np.trace(Sigma) / ny * np.eye(ny)  # exactly dependent outputs
        return cls(sigma, A, np.linalg.inv(np.linalg.cholesky(Sigma)), segment, dt, white,
                   G[:c, :c] if c else None, max(n - c, 1))

    def whiten(self, x: np.ndarray) -> np.ndarray:
        """``W x`` of one run: ``x`` (N, ny, ...) residual or sensitivity columns, returns
        (N - S p, ny, ...) (the first ``p`` samples of each of its S segments have no full past and
        are dropped)."""
        x = np.asarray(x, float)
        if math.isfinite(self.segment) and self.order:
            return np.concatenate([self._whiten_live(piece) for piece in _segments(x, self.dt, self.segment)])
        return self._whiten(x)

    def _whiten_live(self, x: np.ndarray) -> np.ndarray:
        """:meth:`_whiten` of one segment, columns that are zero there (another segment's initial
        state) left zero without the recursion: the whitening restarts at every segment."""
        if x.ndim != 3:
            return self._whiten(x)
        live = np.any(x != 0, axis=(0, 1))
        if live.all():
            return self._whiten(x)
        out = np.zeros((max(len(x) - self.order, 0),) + x.shape[1:])
        if live.any():
            out[:, :, live] = self._whiten(x[:, :, live])
        return out

    def _whiten(self, x: np.ndarray) -> np.ndarray:
        s = self.sigma.reshape((1, -1) + (1,) * (x.ndim - 2))
        p, N = self.order, len(x)
        if x.ndim == 2:
            z = x / s
            out = z[p:].copy()
            for k in range(1, p + 1):
                out -= z[p - k:N - k] @ self.A[k - 1].T
            return out @ self.L_inv.T
        # columns (N, ny, K): outputs first, time and columns flattened, so that each lag is one
        # matrix product over a contiguous window (a tensordot per lag transposed the block each
        # time: 60 % of a score round on the 8-state, 11-output helicopter)
        shape = x.shape
        z = np.ascontiguousarray(np.moveaxis(x / s, 1, 0).reshape(shape[1], -1))
        width = z.shape[1] // N  # columns per sample
        out = z[:, p * width:].copy()
        for k in range(1, p + 1):
            out -= self.A[k - 1] @ z[:, (p - k) * width:(N - k) * width]
        out = self.L_inv @ out
        return np.moveaxis(out.reshape((shape[1], N - p) + shape[2:]), 0, 1)

    def effective_dof(self, columns: list[np.ndarray]) -> float:
        """Degrees of freedom of this model's estimate of the noise variance along ``columns``
        (one (N_r, ny, q) array per run: fixed sequences such as a candidate's columns less their
        fit on the model's), Satterthwaite's ``2 f^2 / Var(f)`` (as Kenward and Roger's small-sample
        F test with an estimated covariance): ``f = sum_j ||W z_j||^2`` over the q columns each
        scaled to ``||W z_j|| = 1``, ``Var(f)`` by the delta method from the least-squares
        covariance of the autoregressive matrices (``Sigma`` (x) ``gram^-1``) and the Wishart spread
        of the innovation covariance (``n_innov`` dof).

        A smooth column's whitened norm hangs on the model's gain at the lowest frequencies, which a
        30 s run determines poorly for a 4-output model of order 25 (100 coefficients an equation):
        a few tens of dof, against thousands for a broadband column (a delay's).
        ``inf`` for a model without estimated colour (:meth:`white`)."""
        if not self.n_innov:
            return math.inf
        p, ny, q = self.order, len(self.sigma), columns[0].shape[2]
        S_inv = self.L_inv.T @ self.L_inv
        coef = self.A.transpose(0, 2, 1).reshape(ny * p, ny)  # as fitted: lag-major rows
        M, D = np.zeros((ny, ny)), np.zeros((ny * p, ny))
        for j in range(q):
            U, Z = [], []  # innovations (n, ny) of the column and its lags (n, ny p), runs stacked
            for col in columns:
                x = col[:, :, j] / self.sigma
                for z in (_segments(x, self.dt, self.segment) if math.isfinite(self.segment) else [x]):
                    if len(z) <= p:
                        continue
                    lags = np.hstack([z[p - k:len(z) - k] for k in range(1, p + 1)]) if p \
                        else np.zeros((len(z), 0))
                    U.append(z[p:] - lags @ coef)
                    Z.append(lags)
            u, lags = np.vstack(U), np.vstack(Z)
            f = float(np.einsum("ti,ij,tj->", u, S_inv, u))
            if f > 0:
                M += u.T @ u / f
                D -= 2.0 * lags.T @ u @ S_inv / f
        var = float(np.trace(np.linalg.inv(S_inv) @ D.T @ np.linalg.solve(self.gram, D))) if p else 0.0
        B = self.L_inv @ M @ self.L_inv.T  # Sigma^-1/2 M Sigma^-1/2
        var += 2.0 / self.n_innov * float(np.sum(B * B))
        return 2.0 * q * q / var if var > 0 else math.inf

    def variance_along(self, weights: list[np.ndarray]):
        """``Var(sum_r <e_r, g_r>)`` for noise ``e`` of this model and fixed ``weights`` ``g`` (one
        (N_r, ny) array per run, or (N_r, ny, K) for K weightings at once: then an array of K): the
        variance of a plain (unwhitened) inner product with the residual, as a change of the plain
        squared error has (:mod:`identify.refine.acceptance`).

        With ``e = sigma * H L eps`` (``H`` the autoregressive synthesis filter, ``eps`` white unit)
        the variance is ``|L^T H^T (sigma g)|^2``; ``H^T`` is the synthesis filter run backwards
        in time with the transposed matrices, ``y_t = sigma g_t + sum_k A_k^T y_{t+k}``. Segment by
        segment, as :meth:`whiten` (the residual restarts at every multiple-shooting segment)."""
        L = np.linalg.inv(self.L_inv)
        p, ny = self.order, len(self.sigma)
        A_T = self.A.reshape(p * ny, ny).T  # [A_1^T ... A_p^T], (ny, ny p)
        single = np.ndim(weights[0]) == 2
        total = 0.0
        for g in weights:
            g = np.asarray(g, float).reshape(len(g), ny, -1) * self.sigma[:, None]
            for piece in (_segments(g, self.dt, self.segment) if math.isfinite(self.segment) else [g]):
                n = len(piece)
                y = np.zeros((n + p,) + piece.shape[1:])  # y[n:] = 0: no weight after the segment's end
                y[:n] = piece
                if p:
                    for t in range(n - 1, -1, -1):
                        y[t] += A_T @ y[t + 1:t + 1 + p].reshape(p * ny, -1)
                total = total + np.sum(np.einsum("tik,ij->tjk", y[:n], L) ** 2, axis=(0, 1))
        return float(total[0]) if single else np.asarray(total, float)

    def cost(self, residuals: list[np.ndarray]) -> float:
        """Sum of squared whitened residuals over runs: twice the Gaussian negative log-likelihood
        (up to a constant) of the residuals under this noise model."""
        return float(sum(np.sum(self.whiten(e) ** 2) for e in residuals))

    def nll(self, residuals: list[np.ndarray], skip: int = 0) -> float:
        """Gaussian negative log-likelihood of residuals (constant dropped) under this noise model,
        over the samples ``t >= max(skip, order)`` of each run: comparable between noise models of
        different parameters (``skip`` = the larger order of the two)."""
        k = max(skip, self.order) - self.order
        logdet = 2.0 * float(np.sum(np.log(self.sigma))) - 2.0 * float(np.linalg.slogdet(self.L_inv)[1])
        return 0.5 * sum(float(np.sum(w[k:] ** 2)) + (len(w) - k) * logdet
                         for w in (self.whiten(e) for e in residuals))

    def to_dict(self) -> dict:
        return {"order": self.order, "sigma": self.sigma.tolist()}


def _logdet(S: np.ndarray) -> float:
    sign, val = np.linalg.slogdet(S + 1e-12 * max(np.trace(S), 1e-300) * np.eye(len(S)))
    return float(val) if sign > 0 else np.inf


def portmanteau_p(innov: np.ndarray, lengths: list[int], order: int, lags: int) -> float:
    """p-value of Hosking's multivariate portmanteau test that innovations (n, ny), stacked from
    series of ``lengths``, are white over ``lags`` lags (products within each series only):
    ``Q = n sum_h tr(C_h^T C_0^-1 C_h C_0^-1)``, chi-square with ``ny^2 (lags - order)`` dof."""
    n, ny = innov.shape
    parts = np.split(innov, np.cumsum(lengths)[:-1])
    C0_inv = np.linalg.inv(innov.T @ innov / n + 1e-12 * np.eye(ny))
    q = 0.0
    for h in range(1, lags + 1):
        Ch = sum(e[h:].T @ e[:-h] for e in parts if len(e) > h) / n
        q += n * float(np.trace(Ch.T @ C0_inv @ Ch @ C0_inv))
    return float(stats.chi2.sf(q, ny * ny * max(lags - order, 1)))


def _segments(x: np.ndarray, dt: float, segment: float) -> list[np.ndarray]:
    """One run's series cut into its multiple-shooting segments (as the output-error engine cuts it)."""
    lay = cut([len(x)], dt, segment)
    return [x[a:a + n] for a, n in zip(lay.start, lay.length)]


def _deterministic_removed(e: np.ndarray, dt: float, freqs: list[float]) -> np.ndarray:
    """``e`` (N, ny) without its mean, linear trend and, per output, the line at ``freqs[j]`` Hz."""
    t = np.arange(len(e)) * dt
    out = np.empty_like(e)
    for j, f in enumerate(freqs):
        cols = [np.ones_like(t), t - t.mean()]
        if np.isfinite(f):
            cols += [np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)]
        X = np.column_stack(cols)
        out[:, j] = e[:, j] - X @ np.linalg.lstsq(X, e[:, j], rcond=None)[0]
    return out


def line_frequency(series: list[np.ndarray], dt: float, f_min: float = 0.0, pad: int = 16) -> float:
    """Frequency (Hz) of the most prominent spectral line of one signal over runs, above ``f_min``.

    Prominent relative to the local background: the runs' averaged periodogram divided by its
    running median over ``2 LINE_WIDTH + 1`` bins, so that a broad hump of coloured noise (the
    turbulence response) is not taken for a line while a narrow vibration is. The bin found is then
    refined to a fraction of a bin by ``pad``-fold zero padding within one bin either side.
    ``nan`` if no bin lies above ``f_min``."""
    n = max(len(x) for x in series)
    freqs = np.fft.rfftfreq(n, dt)
    power = sum(np.abs(np.fft.rfft(x - x.mean(), n)) ** 2 for x in series)
    band = (freqs > f_min) & (freqs < 0.5 / dt)
    if not band.any():
        return float("nan")
    background = ndimage.median_filter(power, size=2 * LINE_WIDTH + 1, mode="mirror")
    floor = max(float(power.max()), 1e-300) * 1e-12
    ratio = np.where(band, power / np.maximum(background, floor), -np.inf)
    f0 = freqs[int(np.argmax(ratio))]
    fine = np.fft.rfftfreq(pad * n, dt)
    near = np.abs(fine - f0) <= 1.0 / (n * dt)
    fine_power = sum(np.abs(np.fft.rfft(x - x.mean(), pad * n)) ** 2 for x in series)
    return float(fine[near][np.argmax(fine_power[near])])


__all__ = ["NoiseModel", "line_frequency", "MAX_ORDER"]

"""Bounds of a filter-error fit: the Cramér-Rao covariance on the active unknowns, and ML's
coloured-residual sandwich on the innovations (:class:`~identify.estimators.coloured_bounds.ColouredBounds`),
with the reasons a bound cannot be used."""
from __future__ import annotations

import numpy as np

from ..coloured_bounds import ColouredBounds
from ..information import BlockInformation

COLOUR_FACTOR_LIMIT = 100.0  # a coloured std beyond this factor of the white one: the sandwich blew up


def colour_failure(cov_c: np.ndarray, cov: np.ndarray, bounded: np.ndarray) -> str | None:
    """Why the coloured covariance ``cov_c`` cannot be used (None: it can): not finite, or a
    standard error off the Cramér-Rao one (``cov``) by more than COLOUR_FACTOR_LIMIT either way
    (an ill-conditioned sandwich, measured once on the piloted S 61: 1e24)."""
    c, w = np.diag(cov_c)[bounded], np.diag(cov)[bounded]
    if not np.all(np.isfinite(cov_c)):
        return "the coloured-innovation correction is not finite"
    ratio = np.sqrt(np.clip(c, 0, None) / np.maximum(w, 1e-300))
    if np.any((ratio > COLOUR_FACTOR_LIMIT) | (ratio < 1 / COLOUR_FACTOR_LIMIT)):
        return (f"the coloured-innovation correction changed a standard error by a factor "
                f"{ratio.min():.3g}..{ratio.max():.3g} (an ill-conditioned sandwich)")
    return None


def inverse_information(M: np.ndarray, active: np.ndarray):
    """``M^-1`` on the active unknowns (scaled to unit diagonal; pseudo-inverse when ill
    conditioned, then listed), zeros elsewhere: ``(cov, ill)``."""
    a = active
    d = np.sqrt(np.diag(M)[a])
    Ms = M[np.ix_(a, a)] / np.outer(d, d)
    cov = np.zeros_like(M)
    ill = bool(np.linalg.cond(Ms) > 1e14)
    inv = np.linalg.pinv(Ms, hermitian=True) if ill else np.linalg.inv(Ms)
    cov[np.ix_(a, a)] = inv / np.outer(d, d)
    return cov, ill


def coloured_covariance(prob, ev, active: np.ndarray):
    """The covariance (n_beta, n_beta) of a :class:`~.filter.FilterProblem` at ``ev`` corrected for
    coloured innovations, the whitened innovations' autocorrelation (L, ny) and the number of
    passes: ML's sandwich ``M^-1 B M^-1`` (:class:`~identify.estimators.coloured_bounds.ColouredBounds`)
    with the innovations for the residuals and their sensitivities for J; the information in S (the
    noise variances') enters B as it is. White innovations: the Cramér-Rao bound within the
    scatter of their autocorrelation."""
    adapter = _Innovations(prob, ev)
    info = BlockInformation(adapter.local, prob.local_index, prob.n_beta, prob.index["x0"], active)
    cov, acf, passes = ColouredBounds(adapter, adapter, adapter.Wh, info, adapter.extra).solve()
    dense = np.zeros((prob.n_beta, prob.n_beta))
    g = info.g_index
    dense[np.ix_(g, g)] = cov.gg  # every run's x0 but with the globals (the blocks read)
    for r, xs in enumerate(info.x_index):
        dense[np.ix_(g, xs)], dense[np.ix_(xs, g)], dense[np.ix_(xs, xs)] = cov.gx[r], cov.gx[r].T, cov.xx[r]
    return dense, acf, passes


class _Innovations:
    """The filter-error problem as :class:`~identify.estimators.coloured_bounds.ColouredBounds`
    sees an output-error one (the seam): residuals ``e`` = the innovations (L, ny, R), the local
    Jacobian = the whitened innovation sensitivities over each run's local unknowns ``[theta, F,
    R, x0, zero shifts]`` (``p`` = the globals G), every run one segment; ``local`` (R, k, k) the
    information (its Gram matrices, plus the information in S on the first run's globals). The
    columns of F and R are zero in the Jacobian the sandwich sees: their sensitivities are
    functions of the noise itself (the gain's), so their rows and columns of B, and S's
    information, are taken as the Cramér-Rao ones (``extra``)."""

    def __init__(self, prob, ev):
        self.fp, self.ev_ = prob, ev
        self.mask, self.layout, self.local_index = prob.mask, prob.layout, prob.local_index
        self.p, self.n = prob.G, prob.n
        self.e = ev.nu
        self.dy_x0 = np.zeros((0, 0, 0, 0))  # ndim 4: each run's own initial-state response
        self.Wh = np.linalg.cholesky(np.linalg.inv(ev.S)).T  # Wh^T Wh = S^-1
        J = self.local_jacobian(self, self.Wh, structural=False)
        R, L, ny, k = J.shape
        J = J.reshape(R, L * ny, k)
        self.local = J.transpose(0, 2, 1) @ J  # the innovations' part of M
        SdS = np.linalg.solve(ev.S, ev.dS)
        G = prob.G
        in_S = 0.5 * prob.N * np.einsum("iab,jba->ij", SdS, SdS)  # the information in S (as M's)
        self.local[0, :G, :G] += in_S
        if prob.prior is not None:  # M holds the prior's information, B (the sandwich's meat) not
            self.local[0, np.arange(prob.p), np.arange(prob.p)] += prob.prior.precision
        noise = np.zeros(k, bool)
        noise[prob.p:G] = True
        self.extra = self.local * (noise[:, None] | noise[None, :])
        self.extra[0, :G, :G] += in_S * ~noise[:G, None] * ~noise[None, :G]

    def local_jacobian(self, ev, Wh: np.ndarray, k0: int = 0, k1: int | None = None, segment=None,
                       structural: bool = True) -> np.ndarray:
        """``Wh dnu`` (S, k1 - k0, ny, k) of the runs ``segment`` (an index, a slice, all); the
        columns of F and R zero when ``structural``."""
        segs = segment if isinstance(segment, slice) else \
            slice(None) if segment is None else slice(segment, segment + 1)
        d = self.ev_.dnu[k0:k1, :, :, segs]
        l, ny, k, S = d.shape
        J = (Wh @ d.reshape(l, ny, k * S)).reshape(l, ny, k, S).transpose(3, 0, 1, 2)
        if structural:
            J[..., self.fp.p:self.fp.G] = 0.0
        return J

    def segment_groups(self) -> list[tuple[int, int]]:
        return [(0, self.fp.n_runs)]

    def blocks(self, columns: int):
        return [(0, self.layout.L)]


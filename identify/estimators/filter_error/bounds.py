"""Bounds of a filter-error fit: the Cramér-Rao covariance on the active unknowns, and ML's
coloured-residual sandwich on the innovations (:class:`~identify.estimators.coloured_bounds.ColouredBounds`),
with the reasons a bound cannot be used."""
from __future__ import annotations

import warnings
from dataclasses import dataclass

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
    conditioned, then listed), zeros elsewhere: ``(cov, ill)``; NaN on the active ones where it
    cannot be formed (a non-finite or non-positive diagonal): never an exception."""
    a = active
    cov = np.zeros_like(M)
    diag = np.diag(M)[a]
    if not (np.all(np.isfinite(M[np.ix_(a, a)])) and np.all(diag > 0)):
        cov[np.ix_(a, a)] = np.nan
        return cov, True
    d = np.sqrt(diag)
    Ms = M[np.ix_(a, a)] / np.outer(d, d)
    ill = bool(np.linalg.cond(Ms) > 1e14)
    try:
        inv = np.linalg.pinv(Ms, hermitian=True) if ill else np.linalg.inv(Ms)
    except np.linalg.LinAlgError:
        inv, ill = np.full_like(Ms, np.nan), True
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



@dataclass
class FitBounds:
    """The bounds of a fit over all unknowns: ``std`` (reported), ``std_white`` (Cramér-Rao),
    ``std_coloured`` (None: not computed or refused), ``cov`` (the reported covariance), ``ill``,
    the innovations' autocorrelation ``acf`` and ``passes`` of the coloured correction,
    ``colour_failed`` / ``failed`` (why the coloured correction / any bound could not be formed),
    ``description`` (what the reported bounds are) and ``choice`` (why, one line)."""

    std: np.ndarray
    std_white: np.ndarray
    std_coloured: np.ndarray | None
    cov: np.ndarray
    ill: bool
    acf: np.ndarray | None = None
    passes: int = 0
    colour_failed: str | None = None
    failed: str | None = None
    description: str = ""
    choice: str = ""
    cov_white: np.ndarray | None = None  # the Cramér-Rao covariance (all unknowns)


CRAMER_RAO = "Cramér-Rao bounds from the innovations' sensitivities (noise variances included)"
COLOURED = "coloured-innovation correction (Morelli & Klein) of the Cramér-Rao bounds"


TURBULENCE_ADVICE = ("; a process-noise model that leaves them coloured can also bias the estimates beyond any "
                     "bound (measured: the Navion in gusts with white process noise on u and alpha, "
                     "benchmarks/filter_error.py): model the gusts as turbulence ([turbulence], --turbulence, "
                     "FEM's default where no process noise is declared)")


def fit_bounds(prob, ev, bounded: np.ndarray, coloured: bool | None, white: dict, stop: str,
               advice: str = "") -> FitBounds:
    """The bounds of a :class:`~.filter.FilterProblem` at ``ev`` (None: its sensitivities failed)
    on the ``bounded`` unknowns: Cramér-Rao, and the coloured-innovation sandwich where
    ``coloured`` is True, or (None, the default) where the whiteness test ``white``
    (:func:`identify.estimators.whiteness.whiteness`) finds the innovations coloured. Never raises:
    an information that cannot be formed or inverted gives NaN bounds and the reason in ``failed``.
    Inf: held (not excited, a held x0 or zero shift); NaN: F = 0 or R on its floor (on the boundary).
    ``advice``: appended to the choice where the innovations are coloured (:data:`TURBULENCE_ADVICE`
    for a white process-noise model the user declared in the profile)."""
    n, ix = prob.n_beta, prob.index
    failed, cov, ill = None, np.full((n, n), np.nan), True
    if ev is None:
        failed = f"no bound: the filter's sensitivities are not finite at the fit's last point ({stop})"
    else:
        try:
            M, _ = prob.information(ev)
            cov, ill = inverse_information(M, bounded)
        except np.linalg.LinAlgError as e:
            failed = f"no bound: the information matrix cannot be formed ({e})"
        if failed is None and not np.all(np.isfinite(np.diag(cov)[bounded])):
            failed = "no bound: the information matrix is not positive definite (not invertible)"
    cov_white = cov
    std = std_white = np.sqrt(np.clip(np.diag(cov), 0, None))
    coloured_list = white.get("coloured", [])
    use = bool(coloured_list) if coloured is None else bool(coloured)
    std_col, acf, passes, colour_failed = None, None, 0, None
    if use and failed is None:  # once, at the estimate
        try:
            cov_c, acf, passes = prob.coloured(ev, bounded)
            colour_failed = colour_failure(cov_c, cov, bounded)
        except (np.linalg.LinAlgError, ValueError) as e:
            colour_failed = f"the coloured-innovation correction failed ({e})"
        if colour_failed is None:
            cov = cov_c
            std = std_col = np.sqrt(np.clip(np.diag(cov), 0, None))
        else:
            warnings.warn(f"FEM: {colour_failed}; the Cramér-Rao bounds are reported", stacklevel=4)
    std = std.copy()
    std[~bounded] = np.inf  # a derivative no input excites, a held x0 or zero shift
    boundary = np.zeros_like(bounded)
    boundary[ix["f"]] = ~bounded[ix["f"]]
    boundary[ix["r"]] = ~bounded[ix["r"]]
    std[boundary] = np.nan  # F = 0 or R on its floor: on the boundary, the bound is not determined
    std_white = np.where(np.isfinite(std), std_white, std)  # the same held / undetermined ones
    listed = ", ".join(coloured_list)
    if failed:
        choice = failed
    elif std_col is not None:
        choice = ("coloured-innovation bounds: the innovations are coloured on " + listed +
                  " (the Cramér-Rao bounds, in info.std_white, would be too narrow)" + advice
                  if coloured is None else "coloured-innovation bounds, as asked (coloured=True)")
    elif colour_failed:
        choice = f"Cramér-Rao bounds: {colour_failed}"
    elif coloured_list:
        choice = (f"Cramér-Rao bounds, as asked (coloured=False), although the innovations are coloured on "
                  f"{listed}: they may be too narrow")
    else:
        choice = "Cramér-Rao bounds: the innovations are white on every output"
    return FitBounds(std, std_white, std_col, cov, ill, acf, passes, colour_failed, failed,
                     COLOURED if std_col is not None else CRAMER_RAO, choice, cov_white)


CK_COPIES = 1 - 1e-3  # diag(C K) above this on an output: the filter copies its measurement


def degenerate_fit(profile, r: np.ndarray, r_floor: np.ndarray, diag_ck: np.ndarray) -> str | None:
    """Why a filter-error fit is degenerate (None: it is not): R on its floor on every output, a
    filter that copies every measurement (``diag(C K)`` ~ 1), or one that copies every state (each
    state measured by an output whose R is on its floor). The innovations are then the one-sample
    increments of the data, the likelihood's curvature that of a filter without measurement noise
    on them, and the Cramér-Rao bounds of the derivatives no measure of their precision (seen:
    0.14-0.32 % of the textbook's on its DHC-2 turbulence case; on a simulated textbook-style case
    with the states copied, the derivatives 5-13 bounds off the truth)."""
    on_floor = r <= (1 + 1e-6) * r_floor
    copied = {y for y, f in zip(profile.outputs, on_floor) if f and profile.output_terms(y) == {y: 1.0}}
    if on_floor.all():
        why = "R went to its floor on every output"
    elif (diag_ck >= CK_COPIES).all():
        why = "the filter copies every measurement (diag(C K) ~ 1)"
    elif set(profile.state_names) <= copied:
        why = f"the filter copies every state (R of {', '.join(profile.state_names)} on its floor)"
    else:
        return None
    return (f"degenerate fit: {why}, so the derivatives' bounds measure nothing (not printed): the process "
            f"noise took the measurement noise's place; fit R as the innovation covariance with C K <= 1 "
            f"(FEM(formulation='innovation'), --fem-formulation innovation) or declare fewer process-noise equations")

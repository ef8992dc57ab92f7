"""Stepwise regression of one equation-error problem: candidates ranked as multivariate orthogonal
functions, entered and removed by partial F, with the predicted squared error (PSE) as stopping rule.

The methods are those of NASA SIDPAC as Morelli & Klein describe them (*Aircraft System
Identification*, ch. 5): the dependent variable ``y`` (a state derivative or a non-dimensional
coefficient, minus its known part) is regressed on a pool of named columns.

1. **Orthogonal functions.** The candidates are made mutually orthogonal, and orthogonal to the
   declared model, one at a time, each step taking the candidate whose orthogonal part ``q`` (what
   the terms already in cannot explain) removes most of the squared error, ``(q.y)^2 / (q.q)``: the
   ranking (:func:`orthogonal_ranking`), and the order in which they are offered to step 2.
2. **Stepwise regression.** From the a priori (declared) model: *backward*, the term with the
   smallest partial F below ``f_out`` leaves; *forward*, the candidate that removes most of the
   remaining squared error enters if its partial F exceeds ``f_in`` *and* the predicted squared
   error ``PSE = SSE / N + sigma_max^2 p / N`` falls (``sigma_max^2`` the variance of ``y``: the
   error of a model with no term, so a term must remove more than that much squared error to pay
   for itself); repeated until nothing moves. The partial F of a term is ``theta^2 / var(theta)``
   with ``var`` corrected for coloured residuals (Morelli & Klein's ``(X^T X)^-1 X^T R X
   (X^T X)^-1``, R the Toeplitz matrix of each block's residual autocorrelation): the residuals of
   smoothed derivatives are always coloured, and the white-residual F would let every small term in.

The per-run, per-equation zero shifts (trim, sensor bias) are nuisance: projected out of ``y`` and
of every column before anything else (the Frisch-Waugh theorem: estimates and residuals are those
of the full regression). PRESS, the sum of the leave-one-out prediction residuals
``e_i / (1 - h_ii)``, is reported for every model as a check on PSE.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..estimators.colour import autocorr_apply

_COLLINEAR = 1e-6  # a column whose part orthogonal to the model is below this fraction of it adds nothing


@dataclass
class Problem:
    """One regression: ``y`` (N,), ``columns`` {name: (N,)}, ``blocks`` (start, stop) index pairs of
    the stacked data (one per run and equation: each gets its own zero shift and its own residual
    autocorrelation). ``declared`` names the columns the a priori model holds (the rest are
    candidates); ``forced`` columns are always in (never tested)."""

    label: str
    y: np.ndarray
    columns: dict[str, np.ndarray]
    blocks: list[tuple[int, int]]
    declared: tuple[str, ...] = ()
    forced: tuple[str, ...] = ()

    def demeaned(self) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """``y`` and the columns with each block's mean removed (the zero shifts projected out)."""
        def strip(v):
            v = np.array(v, float)
            for a, b in self.blocks:
                v[a:b] -= v[a:b].mean()
            return v

        return strip(self.y), {k: strip(v) for k, v in self.columns.items()}


@dataclass
class Fit:
    """Least squares of ``y`` on ``terms``: estimates, coloured-residual and white standard
    errors, partial F per term, SSE, PSE and PRESS."""

    terms: list[str]
    theta: np.ndarray
    std: np.ndarray
    std_white: np.ndarray
    sse: float
    pse: float
    press: float

    @property
    def partial_f(self) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.std > 0, (self.theta / self.std) ** 2, np.inf)

    def value(self, name: str) -> tuple[float, float]:
        i = self.terms.index(name)
        return float(self.theta[i]), float(self.std[i])


@dataclass
class Decision:
    """One move of the search: ``action`` (enter, leave, kept, dropped, ...), the term, the statistic
    and its threshold, and the error before and after (PSE here; the output error's validation
    error in the confirmation)."""

    stage: str
    action: str
    term: str
    equation: str
    statistic: float
    threshold: float
    criterion: str
    before: float
    after: float
    declared: bool
    note: str = ""


@dataclass
class Selection:
    """What stepwise regression chose in one problem: the final fit, the orthogonal ranking
    (term, squared error removed) and every decision."""

    problem: Problem
    fit: Fit
    ranking: list[tuple[str, float]] = field(default_factory=list)
    decisions: list[Decision] = field(default_factory=list)


class Stepwise:
    """Stepwise regression with orthogonal-function ranking (see the module docstring).

    The a priori model is the start: its declared terms leave on their own partial F (below
    ``f_out``); candidates enter, best first (the orthogonal-function ranking on what the model
    leaves), on a partial F above ``f_in`` when the PSE falls too. By default both thresholds are
    chi-square(1) quantiles: ``f_out`` at ``alpha`` per term, ``f_in`` at ``alpha`` for the family
    of the problem's candidates (never below ``f_out``, else a term could enter and leave
    forever). ``coloured``: partial F with the
    coloured-residual correction (default) or the white-residual one; ``max_passes``: forward and
    backward passes at most.
    """

    def __init__(self, alpha: float = 0.05, f_in: float | None = None, f_out: float | None = None,
                 coloured: bool = True, max_passes: int = 50):
        self.alpha, self.f_in, self.f_out = alpha, f_in, f_out
        self.coloured, self.max_passes = coloured, max_passes

    def select(self, problem: Problem) -> Selection:
        y, cols = problem.demeaned()
        n_free = len(y) - len(problem.blocks)
        sigma_max2 = float(y @ y) / len(y)  # the error of the model with no term
        usable = [k for k in cols if k not in problem.forced and np.linalg.norm(cols[k]) > 0]
        declared = [k for k in usable if k in problem.declared]
        candidates = [k for k in usable if k not in problem.declared]
        f_in = self.threshold_in(len(candidates))
        # the a priori model first: its terms leave only on their own partial F; candidates are
        # ranked as orthogonal functions on what the declared model leaves unexplained
        ranking = orthogonal_ranking(y, cols, candidates, list(problem.forced) + declared)
        decisions: list[Decision] = []
        fit = self.fit(y, cols, list(problem.forced) + declared, problem.blocks, n_free, sigma_max2)
        for _ in range(self.max_passes):
            fit, left = self._backward(problem, y, cols, fit, n_free, sigma_max2, decisions)
            fit, entered = self._forward(problem, y, cols, fit, candidates, n_free, sigma_max2, decisions, f_in)
            if not (left or entered):
                break
        return Selection(problem, fit, [(t, float(s)) for t, s in ranking[1:]], decisions)

    def threshold_in(self, n_candidates: int) -> float:
        """Partial F to enter: ``f_in`` if given, else the chi-square(1) quantile at the family level
        ``alpha`` over the problem's candidates (Sidak): a pool of forty must not let two in by chance."""
        if self.f_in is not None:
            return float(self.f_in)
        level = 1 - (1 - self.alpha) ** (1 / max(n_candidates, 1))
        return max(float(stats.chi2.isf(level, 1)), self.threshold_out)

    @property
    def threshold_out(self) -> float:
        """Partial F to stay: ``f_out``, else the chi-square(1) quantile at ``alpha`` per term."""
        return float(self.f_out) if self.f_out is not None else float(stats.chi2.isf(self.alpha, 1))

    # -- the two moves ----------------------------------------------------------------------------
    def _backward(self, problem, y, cols, fit, n_free, sigma_max2, decisions):
        moved = False
        while True:
            testable = [i for i, t in enumerate(fit.terms) if t not in problem.forced]
            if not testable:
                return fit, moved
            f = fit.partial_f
            worst = min(testable, key=lambda i: f[i])
            if f[worst] >= self.threshold_out:
                return fit, moved
            name = fit.terms[worst]
            new = self.fit(y, cols, [t for t in fit.terms if t != name], problem.blocks, n_free, sigma_max2)
            decisions.append(Decision("stepwise", "leave", name, problem.label, float(f[worst]), self.threshold_out,
                                      "partial F", fit.pse, new.pse, name in problem.declared))
            fit, moved = new, True

    def _forward(self, problem, y, cols, fit, pool, n_free, sigma_max2, decisions, f_in):
        out = [c for c in pool if c not in fit.terms]
        if not out:
            return fit, False
        residual = y - _design(cols, fit.terms, len(y)) @ fit.theta
        Q = _orthonormal(_design(cols, fit.terms, len(y)))
        best, gain = None, 0.0
        for c in out:  # the candidate that removes most of the remaining squared error
            v = cols[c] - Q @ (Q.T @ cols[c])
            nv = np.linalg.norm(v)
            if nv <= _COLLINEAR * np.linalg.norm(cols[c]):
                continue
            g = float(v @ residual) ** 2 / nv ** 2
            if g > gain:
                best, gain = c, g
        if best is None:
            return fit, False
        new = self.fit(y, cols, fit.terms + [best], problem.blocks, n_free, sigma_max2)
        f = float(new.partial_f[-1])
        enters = f > f_in and new.pse < fit.pse
        decisions.append(Decision("stepwise", "enter" if enters else "not entered", best, problem.label, f, f_in,
                                  "partial F (and PSE must fall)", fit.pse, new.pse, best in problem.declared))
        return (new, True) if enters else (fit, False)

    # -- one least-squares fit ----------------------------------------------------------------------
    def fit(self, y, cols, terms, blocks, n_free, sigma_max2) -> Fit:
        """Least squares of the demeaned ``y`` on ``terms`` (zero shifts already projected out)."""
        N = len(y)
        X = _design(cols, terms, N)
        p = X.shape[1]
        if p == 0:
            sse = float(y @ y)
            return Fit([], np.zeros(0), np.zeros(0), np.zeros(0), sse, _pse(sse, 0, N, sigma_max2), sse)
        scale = np.maximum(np.linalg.norm(X, axis=0), 1e-300)
        Xs = X / scale
        U, s, Vt = np.linalg.svd(Xs, full_matrices=False)
        s = np.where(s > 1e-12 * s[0], s, np.inf)  # an exactly collinear direction gets no estimate
        coef = Vt.T @ ((U.T @ y) / s)
        residual = y - Xs @ coef
        sse = float(residual @ residual)
        Hinv = (Vt.T / s ** 2) @ Vt
        dof = max(n_free - p, 1)
        cov_white = Hinv * sse / dof
        if self.coloured:
            M = np.zeros((p, p))
            for a, b in blocks:  # per run and equation: its own residual autocorrelation
                M += Xs[a:b].T @ autocorr_apply(residual[a:b] * np.sqrt(N / dof), Xs[a:b])
            cov = Hinv @ M @ Hinv
        else:
            cov = cov_white
        leverage = np.sum(U[:, np.isfinite(s)] ** 2, axis=1)
        press = float(np.sum((residual / np.maximum(1 - leverage, 1e-12)) ** 2))
        theta = coef / scale
        std = np.sqrt(np.clip(np.diag(cov), 0, None)) / scale
        std_white = np.sqrt(np.clip(np.diag(cov_white), 0, None)) / scale
        return Fit(list(terms), theta, std, std_white, sse, _pse(sse, p, N, sigma_max2), press)


def orthogonal_ranking(y: np.ndarray, cols: dict[str, np.ndarray], pool: list[str],
                       forced: list[str]) -> list[tuple[str, float]]:
    """Rank ``pool`` as multivariate orthogonal functions (forced columns first): the list starts
    with ``("", SSE of the forced model)`` and then holds, in order, each chosen term with the
    SSE of the model up to it. Columns collinear with those chosen are left out."""
    N = len(y)
    Q = _orthonormal(_design(cols, forced, N))
    r = y - Q @ (Q.T @ y)
    out = [("", float(r @ r))]
    rest = list(pool)
    V = np.column_stack([cols[c] for c in rest]) if rest else np.zeros((N, 0))
    V = V - Q @ (Q.T @ V)
    norms0 = np.maximum(np.linalg.norm(np.column_stack([cols[c] for c in rest]), axis=0), 1e-300) if rest else None
    while rest:
        nv = np.linalg.norm(V, axis=0)
        ok = nv > _COLLINEAR * norms0
        if not ok.any():
            break
        gain = np.where(ok, (V.T @ r) ** 2 / np.where(ok, nv, 1.0) ** 2, -1.0)
        j = int(np.argmax(gain))
        qj = V[:, j] / nv[j]
        r = r - qj * (qj @ r)
        out.append((rest[j], float(r @ r)))
        keep = np.ones(len(rest), bool)
        keep[j] = False
        V = V[:, keep] - np.outer(qj, qj @ V[:, keep])
        norms0 = norms0[keep]
        rest = [c for c, k in zip(rest, keep) if k]
    return out


def _pse(sse: float, p: int, N: int, sigma_max2: float) -> float:
    return sse / N + sigma_max2 * p / N


def _design(cols, terms, N) -> np.ndarray:
    return np.column_stack([cols[t] for t in terms]) if terms else np.zeros((N, 0))


def _orthonormal(X: np.ndarray) -> np.ndarray:
    if X.shape[1] == 0:
        return X
    U, s, _ = np.linalg.svd(X, full_matrices=False)
    return U[:, s > 1e-12 * max(s[0], 1e-300)]


__all__ = ["Problem", "Fit", "Decision", "Selection", "Stepwise", "orthogonal_ranking"]

"""An upper bound on the design criterion: how far the searched sequence can be from the optimum.

log det is concave, so for any p x p W > 0 and any information M (tangent plane at W)::

    log det M <= log det W + tr(W^-1 M) - p.                                         (1)

Replacing W by c W and minimising over c > 0 gives ``log det M <= log det W + p log(tr(W^-1 M) / p)``.
For levels l (K,) the information is a quadratic form, ``M(l) = sum_kj l_k l_j G_kj``, so
``tr(W^-1 M(l)) = l^T Q_W l`` with ``(Q_W)_kj = tr(W^-1 G_kj)`` (K, K). At equal peak response the
criterion of l is ``log det M(l / r(l))``, and v = l / r(l) keeps every output within its limit:
``|a_i^T v| <= 1`` for every constraint row a_i (an output's response per unit level at one sample,
over its limit; with a fixed amplitude also the levels' box, |v_k| <= 1). Any convex combination
of these rows, ``H_mu = sum_i mu_i a_i a_i^T`` with mu >= 0, sum mu = 1, then bounds the energy:
``v^T H_mu v <= 1`` (peak >= RMS, weighted). Hence, for every flyable (or any continuous) sequence::

    criterion(l) <= log det W + p log(lambda_max(Q_W, H_mu) / p)                         (2)

with lambda_max the largest generalised eigenvalue. (2) holds for every W > 0 and every mu on the
simplex; the bound is the smallest value found by alternating two cheap steps from the searched
design (W = its information at equal peak response, mu on the rows where it meets its limits):

* W: a Frank-Wolfe step. The maximiser v of (2)'s eigenproblem (scaled to v^T H v = 1) is the
  relaxation's best direction; W moves toward M(v) by the step that maximises log det. Every W so
  built lies in the convex hull of relaxed informations, so log det W also shows how much of the
  bound a mixture of continuous inputs reaches.
* mu: the multiplicative update mu_i <- mu_i (a_i^T v)^2 (sums to 1 since v^T H v = 1): weight moves
  to the samples and outputs where the relaxed optimum hits its limits (an E-optimal-design-like
  fixed point; not monotone, so the smallest bound seen is kept).

Over a model set the criterion combines each model's term (mean with weights, plus the worst),
and every combination is non-decreasing in each term: bounding each model's term by (2) on that
model bounds the criterion. The bound covers the continuous relaxation (any input in the span of
the grid's steps, not only three-level flyable ones), so part of the gap is the price of
flyability, not a search shortfall.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eigh
from scipy.optimize import minimize_scalar

from .workers import run_tasks


@dataclass
class Bound:
    """Upper bound on an objective: ``value`` (criterion units) and ``per_model`` (n_models,) each
    model's bound on its equal-peak log det."""

    value: float
    per_model: np.ndarray


def _rows(objective, m: int) -> np.ndarray:
    """Constraint rows a_i (n_rows, K): each limited output of model m at each sample read by the
    objective (its stride), over its limit, per unit level. With a fixed amplitude A the objective
    checks the limits on the a priori only: its outputs times A, and the levels' box |l_k| <= 1."""
    A = objective.Yk[m if objective.amplitude is None else 0].T  # (samples x limited outputs, K)
    A = A[np.abs(A).max(axis=1) > 0]
    if objective.amplitude is not None:
        A = np.vstack([A * objective.amplitude, np.eye(A.shape[1])])
    return A


def _tangent(G, A, W, mu):
    """(bound (2) at W and mu, the relaxation's best direction v scaled to v^T H v = 1)."""
    p, n = G.shape[-1], A.shape[0]
    # a floor of 1e-6 of the uniform weight keeps H positive definite (still on the simplex)
    w = (1 - 1e-6) * mu + 1e-6 / n
    H = (A * w[:, None]).T @ A
    Q = np.einsum("kjab,ba->kj", G, np.linalg.inv(W))
    try:
        lam, V = eigh(0.5 * (Q + Q.T), H, subset_by_index=[Q.shape[0] - 1, Q.shape[0] - 1])
    except np.linalg.LinAlgError:
        # H singular: some levels move no limited output within the record, so nothing bounds them
        return np.inf, None
    lam, v = float(lam[0]), V[:, 0]
    sign, ld = np.linalg.slogdet(W)
    bound = ld + p * np.log(lam / p) if lam > 0 and sign > 0 else np.inf
    return bound, v / np.sqrt(v @ H @ v)


def model_bound(G: np.ndarray, A: np.ndarray, W0: np.ndarray, iterations: int = 6, rounds: int = 2,
                start=None) -> float:
    """Smallest bound (2) found on ``log det M(v)`` over ``|A v| <= 1`` for M(v) = sum v_k v_j G_kj
    (G (K, K, p, p)), from W0 (p, p) > 0 (and mu from the rows where the levels ``start`` (K,) reach
    their limits, when given): ``rounds`` of ``iterations`` mu updates at fixed W, then
    ``iterations`` Frank-Wolfe steps on W at the best mu (module docstring). Every (W, mu) tried
    gives a valid bound; the smallest is returned."""
    n = A.shape[0]
    W = np.array(W0, float)
    # start mu on the rows where W0's input presses against its limits (sharper and sharper), or uniform
    best, mu = np.inf, np.full(n, 1.0 / n)
    for q in (0, 1, 4, 16, 64):
        cand = np.abs(A @ start) ** (2 * q) if start is not None else np.full(n, 1.0)
        cand = cand / cand.sum()
        b, _ = _tangent(G, A, W, cand)
        if b < best:
            best, mu = b, cand
    for _ in range(rounds):
        best_mu = mu
        for _ in range(iterations):  # mu: toward the rows the relaxed optimum presses against
            b, v = _tangent(G, A, W, mu)
            if v is None:
                return best
            if b < best:
                best, best_mu = b, mu
            nxt = mu * (A @ v) ** 2
            mu = nxt / nxt.sum() if nxt.sum() > 0 else mu
        mu = best_mu
        for _ in range(iterations):  # W: Frank-Wolfe step toward M(v), best step length
            b, v = _tangent(G, A, W, mu)
            if v is None:
                return best
            best = min(best, b)
            Mv = np.einsum("k,j,kjab->ab", v, v, G)
            res = minimize_scalar(lambda g: -np.linalg.slogdet((1 - g) * W + g * Mv)[1], bounds=(0.0, 1.0),
                                  method="bounded", options={"xatol": 1e-4})
            W = (1 - res.x) * W + res.x * Mv
    return best


def objective_bound(objective, levels, iterations: int = 6, jobs: int = 1) -> Bound:
    """Upper bound on ``objective`` over every sequence (any levels in the span of its steps), started
    from the design ``levels``: each model's term bounded by (2) (the models in ``jobs`` worker
    processes), combined as the objective combines its terms (the nominal floor's penalty only
    lowers a value and is left out)."""
    levels = np.asarray(levels, float)
    args = [(m, levels, iterations) for m in range(objective.n_models)]
    per = np.array(run_tasks(_model_term, args, objective, None, jobs))
    shift = 2 * objective.p * np.log(objective.amplitude) if objective.amplitude is not None else 0.0
    return Bound(objective.combine(per + shift - objective.offsets, floor=False), per + shift)


def _model_term(objective, _, m: int, levels: np.ndarray, iterations: int) -> float:
    """Bound (2) on model ``m``'s equal-peak log det, from the design ``levels``."""
    G = objective.G[m]
    A = _rows(objective, m)
    r = float(np.abs(A @ levels).max())
    W0 = np.einsum("k,j,kjab->ab", levels, levels, G) / max(r, 1e-300) ** 2
    if np.linalg.slogdet(W0)[0] <= 0:  # a singular start: any positive definite W is valid
        W0 = np.einsum("kkab->ab", G) / max(np.abs(A).sum(axis=1).max(), 1e-300) ** 2
    return model_bound(G, A, W0, iterations, start=levels / max(r, 1e-300))

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
simplex, and its minimum over both is the value of the semidefinite relaxation of the design
(levels v replaced by a matrix V >= 0, the limits by ``a_i^T V a_i <= 1``: a concave maximisation
of log det M(V) over a convex set). The bound is found in two steps:

* W from the relaxation's primal: V = R R^T of rank r (Burer-Monteiro), log det M(V) minus p log
  of a smoothed largest a_i^T V a_i maximised over R by L-BFGS at sharper and sharper smoothing.
  Its value at the exact largest ``a_i^T V a_i`` is reached by a feasible V: a lower bound on the
  relaxation's optimum (``relaxed``), so bound minus relaxed is what the bound itself leaves open.
  W = M(V) at that scale (at the relaxation's optimum, its dual's W).
* mu at that W: lambda_max(Q_W, H_mu) = 1 / lambda_min(B^T diag(mu) B), B = A Q_W^(-1/2): the
  E-optimal design problem over the rows. Kiefer's phi_q criteria (q = 1, 2, 4 ... 128) approach
  lambda_min; each is raised by the multiplicative algorithm
  ``mu_i <- mu_i (b_i^T S^(-q-1) b_i / tr S^(-q))^(1/(q+1))``, started on the rows the relaxed V
  presses against (on large problems only the rows it presses hardest: ``Effort.row_work``).
* Frank-Wolfe steps on W at those weights (toward M(v), v the top generalised eigenvector), and
  the weights again. Every (W, mu) tried gives a valid bound; the smallest is kept (also at W =
  the design's own information). ``EFFORTS`` sets how many iterations each step takes.

The relaxation is wider than the design space in two ways that a certificate cannot remove: the
levels are continuous and free of the flyability rules, and V may have rank above 1 (a mixture of
inputs whose response energies add: a sine and a cosine fill every sample to its limit, which no
single input does). So no bound of this kind comes closer to a flyable design than ``relaxed``
minus the design's value: that part of the gap is the relaxation's, not the search's.

Over a model set the criterion combines each model's term (mean with weights, plus the worst),
and every combination is non-decreasing in each term: bounding each model's term by (2) on that
model bounds the criterion (each model may then take its own input: a further slack).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import eigh, qr
from scipy.optimize import minimize, minimize_scalar
from scipy.special import logsumexp, softmax

from .workers import run_tasks

@dataclass(frozen=True)
class Effort:
    """How hard the bound is minimised (any effort gives a valid bound; more effort, a smaller one):
    ``sharpness`` the relaxed primal's smoothing stages of the largest row energy (relative),
    ``maxiter`` L-BFGS iterations per stage, ``q_schedule`` the phi_q criteria toward lambda_min,
    ``mu_steps`` multiplicative updates per q, ``fw_steps`` Frank-Wolfe steps on W, ``row_work``
    rows x K^2 the weights mu may use (on larger problems, the rows the relaxed input presses most:
    weights on a subset of rows still give a valid bound, if a looser one; at least 4 K rows)."""

    sharpness: tuple = (30.0, 300.0, 3000.0)
    maxiter: int = 400
    q_schedule: tuple = (1, 2, 4, 8, 16, 32, 64, 128)
    mu_steps: int = 40
    fw_steps: int = 30
    row_work: float = 2e7  # all 3200 rows up to K = 80


EFFORTS = {"full": Effort(), "quick": Effort((100.0,), 30, (1, 4), 8, 3)}


@dataclass
class Bound:
    """Upper bound on an objective: ``value`` (criterion units) and ``per_model`` (n_models,) each
    model's bound on its equal-peak log det; ``relaxed`` (n_models,) each model's relaxed value
    reached (a lower bound on the relaxation's optimum: the bound cannot fall below it)."""

    value: float
    per_model: np.ndarray
    relaxed: np.ndarray | None = None


@dataclass
class ModelBound:
    """Bound (2) on one model's ``log det M(v)`` over ``|A v| <= 1`` (``value``, +inf when some
    level moves no limited output) and the relaxation's value reached (``relaxed``)."""

    value: float
    relaxed: float


def _rows(objective, m: int) -> np.ndarray:
    """Constraint rows a_i (n_rows, K): each limited output of model m at each sample read by the
    objective (its stride), over its limit, per unit level. With a fixed amplitude A the objective
    checks the limits on the a priori only: its outputs times A, and the levels' box |l_k| <= 1."""
    A = objective.Yk[m if objective.amplitude is None else 0].T  # (samples x limited outputs, K)
    axes = getattr(objective, "axes", None)
    if axes:  # equal per-input peak response: each input's own response within the limits
        K = objective.K
        A = np.vstack([A * (np.arange(A.shape[1]) // K == a) for a in range(axes)])
    A = A[np.abs(A).max(axis=1) > 0]
    if objective.amplitude is not None:
        A = np.vstack([A * objective.amplitude, np.eye(A.shape[1])])
    return A


def _information(G, V) -> np.ndarray:
    """M(V) = sum_kj V_kj G_kj (p, p)."""
    K, p = G.shape[0], G.shape[-1]
    # one matrix-vector product over G (memory-bound; einsum's loop was 1.5-2x slower at K = 280)
    return (np.ravel(V) @ G.reshape(K * K, p * p)).reshape(p, p)


def _q(G, W_inv) -> np.ndarray:
    """Q_kj = tr(W^-1 G_kj) (K, K) for W^-1 (p, p)."""
    K, p = G.shape[0], G.shape[-1]
    return (G.reshape(K * K, p * p) @ W_inv.T.ravel()).reshape(K, K)


def _bound_at(G, A, W, mu) -> float:
    """Bound (2) at W and mu (+inf where it cannot be evaluated)."""
    p, n = G.shape[-1], A.shape[0]
    w = (1 - 1e-9) * mu + 1e-9 / n  # a floor keeps H positive definite (still on the simplex)
    H = (A * w[:, None]).T @ A
    Q = _q(G, np.linalg.inv(W))
    try:
        lam = float(eigh(0.5 * (Q + Q.T), H, eigvals_only=True, subset_by_index=[Q.shape[0] - 1] * 2)[0])
    except np.linalg.LinAlgError:
        return np.inf
    sign, ld = np.linalg.slogdet(W)
    return ld + p * np.log(lam / p) if lam > 0 and sign > 0 else np.inf


def relaxed_primal(G, A, start, rank: int | None = None, seed: int = 0, effort: Effort = EFFORTS["full"]):
    """A good point of the semidefinite relaxation: V = R R^T (R (K, rank), default rank min(K, p + 2))
    from the design ``start`` and small seeded directions, maximising log det M(V) - p log(max_i
    a_i^T V a_i) (smoothed at ``effort.sharpness``) by L-BFGS. Returns (W = M(V) / max_i a_i^T V a_i,
    the row energies of V at that scale (n,), its value log det W: reached, so a lower bound on the
    relaxation's optimum)."""
    K, p = G.shape[0], G.shape[-1]
    r = min(K, p + 2) if rank is None else rank
    rng = np.random.default_rng(seed)
    R = np.column_stack([start] + [0.3 * np.abs(start).max() * rng.standard_normal(K) for _ in range(r - 1)])

    def scaled(R):
        E = ((A @ R) ** 2).sum(axis=1)
        return _information(G, R @ R.T) / E.max(), E / E.max()

    for beta in effort.sharpness:
        def f(x):
            R = x.reshape(K, r)
            M = _information(G, R @ R.T)
            sign, ld = np.linalg.slogdet(M)
            if sign <= 0:
                return np.inf, np.zeros_like(x)
            AR = A @ R
            E = (AR ** 2).sum(axis=1)
            top = E.max()
            smooth = top * (1 + logsumexp(beta * (E / top - 1)) / beta)  # >= the largest energy
            w = softmax(beta * E / top)
            Q = _q(G, np.linalg.inv(M))
            grad = 2 * Q @ R - 2 * p * (A.T @ (w[:, None] * AR)) / smooth
            return -(ld - p * np.log(smooth)), -grad.ravel()

        res = minimize(f, R.ravel(), jac=True, method="L-BFGS-B", options={"maxiter": effort.maxiter})
        if np.isfinite(res.fun):
            R = res.x.reshape(K, r)
    W, E = scaled(R)
    sign, ld = np.linalg.slogdet(W)
    return W, E, (ld if sign > 0 else -np.inf)


def best_weights(G, A, W, mu0, effort: Effort = EFFORTS["full"]) -> tuple[float, np.ndarray]:
    """The smallest bound (2) at W over the row weights mu found by the phi_q multiplicative
    algorithm (module docstring) from ``mu0``: (bound, its mu)."""
    Q = _q(G, np.linalg.inv(W))
    lam, U = np.linalg.eigh(0.5 * (Q + Q.T))
    if lam[0] <= 1e-12 * lam[-1]:
        return _bound_at(G, A, W, mu0), mu0
    B = A @ (U / np.sqrt(lam)) @ U.T  # rows b_i = Q^(-1/2) a_i
    mu = np.asarray(mu0, float) / np.sum(mu0)
    best, best_mu = _bound_at(G, A, W, mu), mu
    for q in effort.q_schedule:
        for _ in range(effort.mu_steps):
            s, V = np.linalg.eigh((B * mu[:, None]).T @ B)
            x = s[0] / np.maximum(s, 1e-300 * s[-1])  # powers of s relative to lambda_min: no overflow
            if not np.all(np.isfinite(x)) or s[0] <= 0:
                break
            c = ((B @ V) ** 2) @ x ** (q + 1.0)  # the common factor s_min^(-q-1) cancels below
            mu = mu * (c / np.sum(x ** float(q))) ** (1.0 / (q + 1))
            mu /= mu.sum()
        b = _bound_at(G, A, W, mu)
        if b < best:
            best, best_mu = b, mu
    return best, best_mu


def frank_wolfe(G, A, W, mu, steps: int = 30) -> tuple[float, np.ndarray]:
    """The smallest bound (2) at fixed mu over Frank-Wolfe steps on W: toward M(v), v the relaxation's
    best direction at W (top generalised eigenvector of (Q_W, H_mu), scaled to v^T H v = 1), by the
    step that maximises log det (the approximate-design problem of an ellipsoid: its optimum is the
    best W for this mu). Returns (bound, the last W)."""
    n = A.shape[0]
    w = (1 - 1e-9) * mu + 1e-9 / n
    H = (A * w[:, None]).T @ A
    best = np.inf
    for _ in range(steps):
        Q = _q(G, np.linalg.inv(W))
        try:
            lam, V = eigh(0.5 * (Q + Q.T), H, subset_by_index=[Q.shape[0] - 1] * 2)
        except np.linalg.LinAlgError:
            break
        sign, ld = np.linalg.slogdet(W)
        if sign <= 0 or lam[0] <= 0:
            break
        best = min(best, ld + W.shape[0] * np.log(lam[0] / W.shape[0]))
        v = V[:, 0] / np.sqrt(V[:, 0] @ H @ V[:, 0])
        Mv = _information(G, np.outer(v, v))
        res = minimize_scalar(lambda g: -np.linalg.slogdet((1 - g) * W + g * Mv)[1], bounds=(0.0, 1.0),
                              method="bounded", options={"xatol": 1e-5})
        W = (1 - res.x) * W + res.x * Mv
    return best, W


def model_bound(G: np.ndarray, A: np.ndarray, W0: np.ndarray, start=None, rank: int | None = None,
                effort: Effort = EFFORTS["full"]) -> ModelBound:
    """Smallest bound (2) found on ``log det M(v)`` over ``|A v| <= 1`` for M(v) = sum v_k v_j G_kj
    (G (K, K, p, p)): at W0 (p, p) > 0 (e.g. the design's information at equal peak response) and
    at the relaxed primal's W (from the levels ``start`` (K,), default the first singular
    direction of A), mu from :func:`best_weights` (module docstring)."""
    n, K = A.shape
    # a level (or combination) that moves no limited output can grow without end: no finite bound
    sv = np.linalg.svd(A, compute_uv=False)
    if sv.size < K or sv[-1] <= 1e-12 * sv[0]:
        return ModelBound(np.inf, np.inf)
    start = np.linalg.svd(A)[2][0] if start is None else np.asarray(start, float)
    W, E, relaxed = relaxed_primal(G, A, start, rank, effort=effort)
    m = max(int(effort.row_work / K ** 2), 4 * K)  # (Effort.row_work): the most pressed, and a spread
    keep = np.unique(np.concatenate([np.argsort(E)[::-1][:m // 2], np.linspace(0, n - 1, m - m // 2).astype(int),
                                     _spanning_rows(A)]))
    A, E = A[keep], E[keep]
    mu0 = 0.5 * softmax(300.0 * E) + 0.5 / keep.size
    best, mu = best_weights(G, A, W, mu0, effort)
    best = min(best, best_weights(G, A, np.asarray(W0, float), mu0, effort)[0])
    # then the best W for these weights (Frank-Wolfe), and the best weights for that W
    b, W = frank_wolfe(G, A, W, mu, effort.fw_steps)
    best = min(best, b, best_weights(G, A, W, mu, effort)[0])
    return ModelBound(float(best), float(relaxed))


def _spanning_rows(A: np.ndarray) -> np.ndarray:
    """K rows of A (n, K) of full column rank (QR with column pivoting of A^T): a subset of rows
    that misses some level's direction leaves H_mu singular and the bound infinite (the pressed rows
    of a four-input run spanned 244 of its 280 levels)."""
    n, K = A.shape
    if n <= K:
        return np.arange(n)
    return np.sort(qr(A.T, mode="r", pivoting=True)[1][:K])


def objective_bound(objective, levels, jobs: int = 1, effort: str = "full") -> Bound:
    """Upper bound on ``objective`` over every sequence (any levels in the span of its steps), started
    from the design ``levels``: each model's term bounded by (2) (the models in ``jobs`` worker
    processes), combined as the objective combines its terms (the nominal floor's penalty only
    lowers a value and is left out). ``effort``: a key of :data:`EFFORTS`."""
    levels = np.asarray(levels, float)
    args = [(m, levels, EFFORTS[effort]) for m in range(objective.n_models)]
    found = run_tasks(_model_term, args, objective, None, jobs)
    per = np.array([b.value for b in found])
    relaxed = np.array([b.relaxed for b in found])
    shift = 2 * objective.p * np.log(objective.amplitude) if objective.amplitude is not None else 0.0
    # an infinite model bound bounds nothing (the combination would read it as -inf: a "bound" below
    # the design, certifying 1)
    value = objective.combine(per + shift - objective.offsets, floor=False) if np.all(per < np.inf) else np.inf
    return Bound(value, per + shift, relaxed + shift)


def _model_term(objective, _, m: int, levels: np.ndarray, effort: Effort) -> ModelBound:
    """Bound (2) on model ``m``'s equal-peak log det, from the design ``levels``."""
    G = objective.G[m]
    A = _rows(objective, m)
    r = float(np.abs(A @ levels).max())
    W0 = np.einsum("k,j,kjab->ab", levels, levels, G) / max(r, 1e-300) ** 2
    if np.linalg.slogdet(W0)[0] <= 0:  # a singular start: any positive definite W is valid
        W0 = np.einsum("kkab->ab", G) / max(np.abs(A).sum(axis=1).max(), 1e-300) ** 2
    return model_bound(G, A, W0, start=levels / max(r, 1e-300), effort=effort)

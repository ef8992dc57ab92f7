"""A priori weighting in the estimators: the prior's residuals, information, the data's share and
the prior-data conflict tests.

The profile's prior (:mod:`identify.model.prior`) says ``theta_j ~ N(mu_j, s_j^2)`` independently
for the parameters it names. Every estimator treats it as one more measurement of those
parameters (Maine & Iliff's a priori weighting in MMLE; Theil and Goldberger's mixed estimation,
Morelli & Klein 4.x): the cost gains ``1/2 sum_j ((theta_j - mu_j) / s_j)^2``, the information
``P^-1 = diag(1 / s^2)``, and the estimate is the posterior mode. Where the estimator fits the
data alone (:func:`combine`, frequency-response fits) the prior is combined with the data's
estimate by the same weighting (the linearised posterior at the data's estimate).

In the parameters' space, after the nuisance unknowns (initial states, zero shifts) are
eliminated, with ``M_d`` the data's (white-residual) information, ``A = (M_d + P^-1)^-1`` the
posterior's white covariance and ``D`` the data's part of the posterior covariance (``A B A``
with ``B`` the data's sandwich meat: ``M_d`` for white residuals, Morelli & Klein's coloured
correction otherwise), the estimate is ``theta = W theta_data + (I - W) mu`` with the data's
weight ``W = A M_d = I - A P^-1``, and:

* posterior covariance ``D + A P^-1 A`` (the prior is a measurement with white error);
* **data share** of parameter j: ``W_jj = 1 - A_jj / s_j^2`` (0: the prior alone decides, 1: the
  data alone; with white residuals also 1 - posterior / prior variance). Under
  ``DECIDED_BY_PRIOR`` the prior decides the estimate (said in the summary);
* **conflict**: ``r = theta - mu`` on the prior's parameters. Under the null (the prior honest:
  ``mu - theta_true ~ N(0, P)`` independent of the data's errors) ``r = e_data - W (mu - theta_true)``,
  so ``Cov r = D + W P W^T`` -- for white residuals ``P - A`` (the prior's variance minus the
  posterior's), much smaller than ``P`` where the data share is small: the prior's own std is not
  the spread to judge ``r`` by. Per parameter ``z_j = r_j / sqrt(Cov r_jj)`` (two-sided, normal);
  globally ``r^T (Cov r)^+ r ~ chi^2(df)`` over the directions the data inform (eigenvalues of
  the prior-scaled ``Cov r`` over ``INFORMED``: there the data add at least that share). A conflict
  is declared when the global test or a parameter's test rejects at ``CONFLICT_LEVEL`` (1 %; a
  per-parameter level: an honest prior on k informed parameters raises a false alarm in about
  k % of flights, measured in ``benchmarks/prior.py``); the parameters named are those whose own
  test rejects, else the three largest |z|.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

DECIDED_BY_PRIOR = 0.5  # data share under which the prior decides a parameter's estimate
CONFLICT_LEVEL = 0.01   # significance of the per-parameter and global conflict tests
INFORMED = 0.01         # a direction enters the global test when the data add this share to it
SHARE_DEFINITION = ("W_jj, the diagonal of the data's weight W = (M_d + P^-1)^-1 M_d in the estimate "
                    "theta = W theta_data + (I - W) prior (white-residual information; then also "
                    "1 - posterior variance / prior variance): 0 the prior alone, 1 the data alone")


@dataclass
class PriorTerm:
    """The prior over a fit's free parameters ``names``: centres ``mean`` and ``std`` (p,), NaN
    and inf where a parameter has none."""

    names: list[str]
    mean: np.ndarray
    std: np.ndarray

    @property
    def has(self) -> np.ndarray:
        return np.isfinite(self.std)

    @property
    def precision(self) -> np.ndarray:
        return np.where(self.has, 1 / np.where(self.has, self.std, 1.0) ** 2, 0.0)

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """``(mu - theta) / s`` on the parameters with a prior (0 elsewhere): the extra residuals."""
        return np.where(self.has, (np.nan_to_num(self.mean) - theta) / np.where(self.has, self.std, 1.0), 0.0)

    def cost(self, theta: np.ndarray) -> float:
        """``1/2 sum ((theta - mu) / s)^2``."""
        return 0.5 * float(np.sum(self.residuals(theta) ** 2))

    def gradient(self, theta: np.ndarray) -> np.ndarray:
        """``P^-1 (mu - theta)``: the prior's part of ``J^T R^-1 e`` (the descent direction's sign)."""
        return self.precision * (np.nan_to_num(self.mean) - theta)


def prior_term(profile, names: list[str] | None = None) -> PriorTerm | None:
    """The profile's prior over ``names`` (default its free parameters); None when it has none
    for them (refine's added effects have none unless given)."""
    names = list(profile.free) if names is None else list(names)
    table = {k: v for k, v in profile.prior.items() if k in names}
    if not table:
        return None
    mean = np.array([table[n]["value"] if n in table else np.nan for n in names])
    std = np.array([table[n]["std"] if n in table else np.inf for n in names])
    return PriorTerm(names, mean, std)


# -- the posterior and its record -------------------------------------------------------------
def posterior(term: PriorTerm, theta: np.ndarray, A: np.ndarray, D: np.ndarray,
              active: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """The posterior covariance ``D + A P^-1 A`` and the record (``info["prior"]``) of a fit
    with the prior: per parameter prior, data share and conflict test, and the global test.
    ``A`` (p, p) the posterior white covariance (M_d + P^-1)^-1, ``D`` (p, p) the data's part of
    the posterior covariance; ``active`` the parameters the fit moved (others, held at their
    prior centre, are the prior alone: covariance P, share 0)."""
    p = len(theta)
    active = np.ones(p, bool) if active is None else np.asarray(active, bool)
    prec = term.precision
    A, D = np.where(np.outer(active, active), A, 0.0), np.where(np.outer(active, active), D, 0.0)
    cov = D + (A * prec) @ A.T  # A need not be symmetric (IV: (Z^T X / s^2 + P^-1)^-1)
    held = ~active & term.has
    cov[held, held] = term.std[held] ** 2
    W = np.eye(p) - A * prec[None, :]
    W[~active] = 0.0
    share = np.where(term.has, np.clip(np.diag(W), 0.0, 1.0), 1.0)
    share[held] = 0.0
    conflict = _conflict(term, theta, W, D, share)
    params = {}
    for j, n in enumerate(term.names):
        if not term.has[j]:
            continue
        params[n] = {"prior": {"value": float(term.mean[j]), "std": float(term.std[j])},
                     "posterior": {"value": float(theta[j]), "std": float(np.sqrt(max(cov[j, j], 0.0)))},
                     "data_share": float(share[j]), "decided_by_prior": bool(share[j] < DECIDED_BY_PRIOR),
                     **conflict["per_parameter"].get(n, {})}
    record = {"parameters": params, "data_share_definition": SHARE_DEFINITION,
              "decided_by_prior": [n for n, v in params.items() if v["decided_by_prior"]],
              "without_prior": [n for n, h in zip(term.names, term.has) if not h],
              "conflict": {k: v for k, v in conflict.items() if k != "per_parameter"}}
    return cov, record


def _conflict(term: PriorTerm, theta: np.ndarray, W: np.ndarray, D: np.ndarray, share: np.ndarray) -> dict:
    """The conflict tests (see the module notes) on the parameters with a prior."""
    pr = np.flatnonzero(term.has)
    s = term.std[pr]
    r = (theta[pr] - term.mean[pr]) / s  # in prior stds
    Wp = W[np.ix_(pr, pr)] * s[None, :] / s[:, None]  # S^-1 W S: W P W^T prior-scaled
    V = D[np.ix_(pr, pr)] / np.outer(s, s) + Wp @ Wp.T  # Cov r, prior-scaled
    V = 0.5 * (V + V.T)
    per, z_all = {}, np.full(len(pr), np.nan)
    for i, j in enumerate(pr):
        if V[i, i] > INFORMED ** 2 and share[j] > 0:
            z_all[i] = r[i] / np.sqrt(V[i, i])
            per[term.names[j]] = {"conflict_z": float(z_all[i]),
                                  "conflict_p": float(2 * stats.norm.sf(abs(z_all[i])))}
        else:
            per[term.names[j]] = {"conflict_z": None, "conflict_p": None,
                                  "conflict_note": "the data add nothing to the prior: no test"}
    lam, U = np.linalg.eigh(V)
    keep = lam > INFORMED
    chi2 = float(np.sum((U[:, keep].T @ r) ** 2 / lam[keep])) if keep.any() else 0.0
    df = int(keep.sum())
    p_global = float(stats.chi2.sf(chi2, df)) if df else 1.0
    rejected = [term.names[pr[i]] for i in np.argsort(-np.abs(np.nan_to_num(z_all)))
                if np.isfinite(z_all[i]) and 2 * stats.norm.sf(abs(z_all[i])) < CONFLICT_LEVEL]
    detected = bool(rejected) or p_global < CONFLICT_LEVEL
    drivers = rejected or ([term.names[pr[i]] for i in np.argsort(-np.abs(np.nan_to_num(z_all)))[:3]
                            if np.isfinite(z_all[i])] if detected else [])
    return {"per_parameter": per, "detected": detected, "drivers": drivers,
            "global": {"chi2": chi2, "df": df, "p": p_global}, "level": CONFLICT_LEVEL,
            "test": "per parameter z = (posterior - prior) / its std under an honest prior (Cov = D + W P W^T); "
                    "global chi-square over the directions the data inform"}


def combine(term: PriorTerm, theta_d: np.ndarray, cov_d: np.ndarray, info_d: np.ndarray | None = None):
    """The prior combined with a data-only estimate ``theta_d`` (p,) of covariance ``cov_d``
    (p, p; inf/NaN rows where the data say nothing): ``(theta, A, D)`` for :func:`posterior`.
    ``info_d`` the data's (white) information M_d if known, else the inverse of ``cov_d``."""
    p = len(theta_d)
    ok = np.all(np.isfinite(cov_d), axis=1) & np.isfinite(theta_d)
    M = np.zeros((p, p))
    if info_d is not None:
        M = np.where(np.outer(ok, ok), info_d, 0.0)
    elif ok.any():
        M[np.ix_(ok, ok)] = np.linalg.pinv(cov_d[np.ix_(ok, ok)], hermitian=True)
    prec = term.precision
    A = np.linalg.pinv(M + np.diag(prec), hermitian=True)
    C = np.where(np.outer(ok, ok), cov_d, 0.0)
    theta = A @ (M @ np.where(ok, theta_d, 0.0) + prec * np.nan_to_num(term.mean))
    D = A @ M @ C @ M @ A
    free = ~ok & ~term.has  # neither the data nor the prior: the data-only value stays, not determined
    theta[free] = theta_d[free]
    D[free, :], D[:, free] = np.nan, np.nan
    return theta, A, D


# -- reporting ------------------------------------------------------------------------------------
def summary_lines(record: dict) -> list[str]:
    """The summary's prior section: per parameter prior, posterior and data share, the parameters
    the prior decides, and the conflict said with the parameters that drive it."""
    params = record["parameters"]
    if not params:
        return []
    lines = ["", f"a priori weighting ({len(params)} parameters with a prior; data share: 0 prior only, 1 data only)",
             f"{'parameter':<18}{'prior':>12}{'prior std':>11}{'posterior':>12}{'post. std':>11}{'data share':>11}"
             f"{'conflict z':>11}"]
    for n, v in params.items():
        z = v.get("conflict_z")
        flag = "  prior decides" if v["decided_by_prior"] else ""
        lines.append(f"{n:<18}{v['prior']['value']:12.5g}{v['prior']['std']:11.3g}{v['posterior']['value']:12.5g}"
                     f"{v['posterior']['std']:11.3g}{v['data_share']:11.2f}"
                     f"{'-' if z is None else f'{z:.2f}':>11}{flag}")
    if record["decided_by_prior"]:
        lines.append(f"decided by the prior (data share < {DECIDED_BY_PRIOR:g}): {', '.join(record['decided_by_prior'])}")
    if record["without_prior"]:
        lines.append(f"without a prior (the data alone): {', '.join(record['without_prior'])}")
    if record.get("how"):
        lines.append(f"prior: {record['how']}")
    lines.append(conflict_line(record))
    return lines


def conflict_line(record: dict) -> str:
    c = record["conflict"]
    g = c["global"]
    if c["detected"]:
        return (f"PRIOR-DATA CONFLICT: the data contradict the prior on {', '.join(c['drivers'])} "
                f"(global chi2 {g['chi2']:.1f} on {g['df']} df, p = {g['p']:.2g}; level {c['level']:g})")
    return f"prior-data conflict: none (global chi2 {g['chi2']:.1f} on {g['df']} df, p = {g['p']:.2g})"


def combined_with_prior(result, profile):
    """``result`` (a data-only fit) with ``profile``'s prior combined into it (:func:`combine`):
    the posterior estimate, covariance and the prior's record; unchanged without a prior. The
    fit metrics and time histories stay those of the data's estimate (said in the record)."""
    from dataclasses import replace

    term = prior_term(profile, result.names)
    if term is None:
        return result
    theta, A, D = combine(term, np.asarray(result.theta, float), result.parameter_covariance())
    cov, record = posterior(term, theta, A, D)
    record["how"] = ("the prior combined with the data's estimate and covariance (linearised posterior); "
                     "the fit metrics and time histories are of the data's estimate")
    return replace(result, theta=theta, std=np.sqrt(np.clip(np.diag(cov), 0, None)), covariance=cov,
                   info={**result.info, "prior": record})

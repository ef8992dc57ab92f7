"""What refine measures on a model's prediction: errors, likelihoods, the validation split, the
identifiability check before the first fit and the residual left after candidate columns.

The prediction itself (a model on runs, state-built terms from its simulated states) is the
estimator's: :mod:`identify.estimators.prediction`.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..estimators.prediction import ModelFit, block_design, evaluate
from ..model.profile import Profile

MIN_SAMPLES = 50  # per run: fewer leave the residual tests without power


def unexplained(residuals: list[np.ndarray], shared: list[np.ndarray], nuisance: list[np.ndarray],
                sigma: np.ndarray) -> list[np.ndarray]:
    """Residuals (N_r, ny) per run minus their least-squares fit on the columns ``shared``
    (N_r, ny, k, common to all runs) and ``nuisance`` (N_r, ny, k_r, per run), weighted 1/sigma."""
    w = np.tile(1.0 / sigma, sum(len(e) for e in residuals))
    C = block_design(shared, nuisance) * w[:, None]
    C /= np.maximum(np.linalg.norm(C, axis=0), 1e-300)
    e = np.concatenate([r.ravel() for r in residuals]) * w
    G = C.T @ C
    coef = np.linalg.solve(G + 1e-10 * np.trace(G) / len(G) * np.eye(len(G)), C.T @ e)
    clean = (e - C @ coef) / w
    parts = np.split(clean, np.cumsum([r.size for r in residuals])[:-1])
    return [c.reshape(r.shape) for c, r in zip(parts, residuals)]


def errors(evaluation: ModelFit, outputs, scale: np.ndarray) -> dict:
    """RMS error per output and the normalised ``overall`` (see the module docstring)."""
    E = np.vstack(evaluation.residuals)
    rms = np.sqrt(np.mean(E ** 2, axis=0))
    out = {y: float(r) for y, r in zip(outputs, rms)}
    out["overall"] = float(np.sqrt(np.mean((rms / scale) ** 2)))
    return out


def neg_log_likelihood(residuals: list[np.ndarray]) -> float:
    """Concentrated Gaussian negative log-likelihood with a diagonal noise covariance estimated
    from the residuals: (N/2) sum_y log(mean e_y^2)."""
    E = np.vstack(residuals)
    return 0.5 * E.shape[0] * float(np.sum(np.log(np.maximum(np.mean(E ** 2, axis=0), 1e-300))))


def split_validation(runs: list[Run]) -> tuple[list[Run], list[Run]]:
    """Validation runs into a *choosing* and a *judging* part: alternate runs when there are
    several; one run is cut in two halves in time (first half chooses) when each half keeps
    ``MIN_SAMPLES``, else it only judges."""
    if len(runs) >= 2:
        return runs[0::2], runs[1::2]
    if len(runs) == 1 and len(runs[0]) >= 2 * MIN_SAMPLES:
        r = runs[0]
        mid = r.time[len(r) // 2]
        first, second = r.slice(None, mid - 0.5 * r.dt), r.slice(mid, None)
        return ([replace(first, source=f"{r.source} [first half]")],
                [replace(second, source=f"{r.source} [second half]")])
    return [], list(runs)


def check_identifiable(p: Profile, runs: list[Run], zero_shifts: bool, segment: float) -> None:
        """The fitted model's parameters must be identifiable beside the nuisance: rank test of the
        weighted sensitivity matrix, naming the parameters in its null space."""
        ev = evaluate(p, runs, zero_shifts, segment, jacobian=True)
        J = block_design(ev.dy, ev.nuisance)
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        Jw = J * np.tile(1 / np.where(sigma > 0, sigma, 1.0), len(J) // len(sigma))[:, None]
        names = p.free_names
        npar = len(names)
        # parameters beside the nuisance (initial states, zero shifts): project those out first, so
        # that an unobservable state's initial value is not mistaken for an unidentifiable parameter
        U, sn, _ = np.linalg.svd(Jw[:, npar:], full_matrices=False)
        Q = U[:, sn > 1e-10 * max(sn.max(initial=0.0), 1e-300)]
        Jp = Jw[:, :npar] - Q @ (Q.T @ Jw[:, :npar])
        Jp = Jp / np.maximum(np.linalg.norm(Jw[:, :npar], axis=0), 1e-300)
        _, s, Vt = np.linalg.svd(Jp, full_matrices=False)
        if s[-1] < 1e-7 * max(s[0], 1e-300) or s[0] == 0:
            null = Vt[s < 1e-7 * max(s[0], 1e-300)] if s[0] > 0 else Vt
            worst = [names[i] for i in np.flatnonzero(np.max(np.abs(null), axis=0) > 0.1)]
            raise EstimationError(f"profile '{p.name}': free parameters not identifiable from these runs "
                                  f"(no information separates {', '.join(worst)}); "
                                  f"fix some or add excitation")


__all__ = ["errors", "neg_log_likelihood", "unexplained", "split_validation", "check_identifiable", "MIN_SAMPLES"]

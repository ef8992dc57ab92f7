"""Fisher information of a test input about a model's free parameters, and D-efficiency.

For white measurement noise with standard deviations ``sigma`` (ny,), the Fisher information of
outputs y(theta) sampled at N instants is ``M = sum_k dy_k^T diag(1/sigma^2) dy_k``; its inverse
bounds the covariance of any unbiased estimate (Cramér-Rao). D-efficiency compares inputs by
``(det M / det M_ref)^(1/p)``: the factor by which the reference's test time would have to grow
to carry the same information.
"""
from __future__ import annotations

import numpy as np

from identify.model import LinearModel
from identify.sensitivity import output_sensitivities


def fisher_information(model: LinearModel, u: np.ndarray, dt: float, noise_std=None, x0=None) -> np.ndarray:
    """Fisher information (p, p) of inputs ``u`` (N, m) held over ``dt`` s about ``model.theta``.

    ``noise_std``: measurement noise standard deviation per output (ny,) (default 1 for all).
    """
    sens = output_sensitivities(model, u, dt, x0)
    w = np.ones(model.n_outputs) if noise_std is None else 1.0 / np.asarray(noise_std, float) ** 2
    return np.einsum("kyi,y,kyj->ij", sens.dy, w, sens.dy)


def log_det(M: np.ndarray) -> float:
    """log det of a Fisher information; -inf when it is singular (a parameter is not excited)."""
    sign, value = np.linalg.slogdet(M)
    return float(value) if sign > 0 else -np.inf


def d_efficiency(M: np.ndarray, M_ref: np.ndarray) -> float:
    """(det M / det M_ref)^(1/p): above 1 means M carries more information than M_ref."""
    return float(np.exp((log_det(M) - log_det(M_ref)) / M.shape[0]))


def cramer_rao_std(M: np.ndarray) -> np.ndarray:
    """Cramér-Rao standard errors sqrt(diag(M^-1))."""
    return np.sqrt(np.diag(np.linalg.pinv(M)))

"""Fisher information of a test input about a model's free parameters, and D-efficiency.

For white measurement noise with standard deviations ``sigma`` (ny,), the Fisher information of
outputs y(theta) sampled at N instants is ``M = sum_k dy_k^T diag(1/sigma^2) dy_k``; its inverse
bounds the covariance of any unbiased estimate (Cramér-Rao). D-efficiency compares inputs by
``(det M / det M_ref)^(1/p)``: the factor by which the reference's test time would have to grow
to carry the same information.
"""
from __future__ import annotations

import numpy as np

from identify import LinearModel, output_sensitivities, output_units


def fisher_information(model: LinearModel, u: np.ndarray, dt: float, noise_std=None, x0=None) -> np.ndarray:
    """Fisher information (p, p) of inputs ``u`` (N, m) held over ``dt`` s about ``model.theta``.

    ``noise_std``: measurement noise standard deviation per output (ny,) (default: the assumed
    sensor noise by unit, :func:`default_noise`, so that m/s and rad/s outputs weigh as their
    sensors make them).
    """
    sens = output_sensitivities(model, u, dt, x0)
    noise_std = default_noise(model.profile) if noise_std is None else noise_std
    w = 1.0 / np.asarray(noise_std, float) ** 2
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


# Assumed measurement noise (1 sigma) per unit: typical flight-test sensor levels after
# anti-alias filtering. One place, printed by the command line, overridable per output.
DEFAULT_NOISE_BY_UNIT = {
    "rad": 0.0035,  # 0.2 deg attitude / rotor tilt
    "rad/s": 0.0035,  # 0.2 deg/s rate gyro
    "rad/s^2": 0.02,  # differentiated rates
    "m/s": 0.2,  # airspeed components near hover are poorly measured
    "m/s^2": 0.05,  # accelerometers after smoothing
}
_FALLBACK_NOISE = 0.01


def default_noise(profile, overrides: dict[str, float] | None = None) -> np.ndarray:
    """Measurement noise standard deviation (ny,) per output from :data:`DEFAULT_NOISE_BY_UNIT`."""
    units = output_units(profile)
    overrides = overrides or {}
    return np.array([overrides.get(y, DEFAULT_NOISE_BY_UNIT.get(units[y], _FALLBACK_NOISE))
                     for y in profile.outputs])


def format_noise(profile, noise_std) -> str:
    """One line listing the assumed noise per output, for printing alongside results."""
    units = output_units(profile)
    return "assumed noise (1 sigma): " + ", ".join(
        f"{y} {s:g} {units[y] or '?'}" for y, s in zip(profile.outputs, noise_std))


def relative_cramer_rao(M: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Cramér-Rao standard errors relative to the parameter values |theta| (p,)."""
    return cramer_rao_std(M) / np.maximum(np.abs(theta), 1e-12)

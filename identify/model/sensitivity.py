"""Output sensitivities dy/dtheta of a linear model, all parameters in one vectorised pass.

Differentiating the exact ZOH recursion ``x[k+1] = Phi x[k] + Gamma u[k]`` with respect to
parameter i gives ``S_i[k+1] = Phi S_i[k] + dPhi_i x[k] + dGamma_i u[k]``. ``dPhi_i`` and
``dGamma_i`` come exactly from one batched matrix exponential of the block-triangular matrices
``[[A, 0, B], [dA_i, A, dB_i], [0, 0, 0]] dt`` (Van Loan), so the sensitivities are the exact
derivatives of the discrete simulation, not finite differences. Output error ML and signal design
both use this.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from .linear import LinearModel
from .simulate import DIVERGENCE_LIMIT, check_divergence, propagate


@dataclass
class Sensitivities:
    """``y`` (N, ny) outputs; ``x`` (N, n) states; ``dy`` (N, ny, p) d y / d theta;
    ``dy_x0`` (N, ny, n) d y / d x0 (present when asked for)."""

    y: np.ndarray
    x: np.ndarray
    dy: np.ndarray
    dy_x0: np.ndarray | None = None


def discretize_with_derivatives(model: LinearModel, dt: float, hold: str = "held"):
    """``Phi`` (n, n), ``Gamma`` (n, m), ``dPhi`` (p, n, n), ``dGamma`` (p, n, m).

    ``hold="linear"`` (inputs interpolated linearly between samples, first-order hold): ``Gamma``
    (n, 2m) and ``dGamma`` (p, n, 2m) act on ``[u[k]; u[k+1]]`` (:func:`~identify.model.simulate.held_inputs`)."""
    n, m, p = model.n_states, model.n_inputs, len(model.names)
    linear = hold == "linear"
    size = 2 * n + m * (2 if linear else 1)
    M = np.zeros((max(p, 1), size, size))
    M[:, :n, :n] = model.A
    M[:, :n, 2 * n:2 * n + m] = model.B
    M[:, n:2 * n, n:2 * n] = model.A
    if p:
        M[:, n:2 * n, :n] = model.dA
        M[:, n:2 * n, 2 * n:2 * n + m] = model.dB
    if linear:  # the input's slope (u[k+1] - u[k]) / dt is a state of the augmented exponential
        M[:, 2 * n:2 * n + m, 2 * n + m:] = np.eye(m) / dt
    E = expm(M * dt)  # batched over parameters
    if linear:  # x[k+1] = Phi x + Ga u[k] + Gb (u[k+1] - u[k])
        E = np.concatenate([E[..., :2 * n], E[..., 2 * n:2 * n + m] - E[..., 2 * n + m:], E[..., 2 * n + m:]], axis=-1)
    Phi, Gamma = E[0, :n, :n], E[0, :n, 2 * n:]
    dPhi, dGamma = E[:p, n:2 * n, :n], E[:p, n:2 * n, 2 * n:]
    return Phi, Gamma, dPhi, dGamma


def output_sensitivities(model: LinearModel, u: np.ndarray, dt: float, x0=None,
                         initial_state: bool = False, limit: float = DIVERGENCE_LIMIT) -> Sensitivities:
    """Outputs and their exact sensitivities to every free parameter (and optionally to x0).

    ``u``: (N, m) inputs held over each interval; ``x0``: (n,) initial state.
    """
    u = np.asarray(u, dtype=float).reshape(len(u), model.n_inputs)
    n = model.n_states
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    Phi, Gamma, dPhi, dGamma = discretize_with_derivatives(model, dt)
    x = propagate(Phi, u @ Gamma.T, x0)
    check_divergence(x, dt, model.profile.state_names, limit)
    forcing = np.einsum("pij,kj->kip", dPhi, x) + np.einsum("pij,kj->kip", dGamma, u)
    S = propagate(Phi, forcing, np.zeros((n, len(model.names))))
    y = x @ model.C.T + u @ model.D.T
    dy = (np.einsum("yi,kip->kyp", model.C, S) + np.einsum("pyi,ki->kyp", model.dC, x)
          + np.einsum("pyj,kj->kyp", model.dD, u))
    dy_x0 = None
    if initial_state:
        powers = propagate(Phi, np.zeros((len(u), n, n)), np.eye(n))  # Phi^k
        dy_x0 = np.einsum("yi,kij->kyj", model.C, powers)
    return Sensitivities(y, x, dy, dy_x0)

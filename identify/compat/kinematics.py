"""Rigid-body kinematics of flight-path reconstruction.

States ``x = (u, v, w, phi, theta, psi, h)``: body-axis velocities (m/s), Euler angles (rad),
height (m, up). Inputs are the measured specific forces ``a_x, a_y, a_z`` (m/s^2, body axes, as
accelerometers at the CG read them: ``a_z`` about -g in level flight) and body rates ``p, q, r``
(rad/s)::

    u' = a_x - g sin(theta) + r v - q w
    v' = a_y + g cos(theta) sin(phi) + p w - r u
    w' = a_z + g cos(theta) cos(phi) + q u - p v
    phi'   = p + tan(theta) (q sin(phi) + r cos(phi))
    theta' = q cos(phi) - r sin(phi)
    psi'   = (q sin(phi) + r cos(phi)) / cos(theta)
    h'     = u sin(theta) - v sin(phi) cos(theta) - w cos(phi) cos(theta)

Outputs ``V = |(u, v, w)|``, ``alpha = atan2(w, u)``, ``beta = asin(v / V)``, ``phi``, ``theta``,
``psi``, ``h``. No wind: the air data are taken as inertial (a steady wind shows as biases).
Integration: classical Runge-Kutta over each sample interval with the inputs interpolated
linearly between samples, for a batch of initial states and input corrections at once
(the finite-difference sensitivities of :mod:`.fit` are one batch).
"""
from __future__ import annotations

import numpy as np

G0 = 9.80665
INPUTS = ("a_x", "a_y", "a_z", "p", "q", "r")
STATES = ("u", "v", "w", "phi", "theta", "psi", "h")
OUTPUTS = ("V", "alpha", "beta", "phi", "theta", "psi", "h")
STATE_UNITS = ("m/s", "m/s", "m/s", "rad", "rad", "rad", "m")


def derivatives(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``x'`` (7, B) for states ``x`` (7, B) and inputs ``a`` (6, B) (state-major: each row a
    contiguous vector over the batch, the fast layout for the time loop)."""
    u, v, w, phi, th, _, _ = x
    ax, ay, az, p, q, r = a
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
    qr = q * sphi + r * cphi
    out = np.empty_like(x)
    out[0] = ax - G0 * sth + r * v - q * w
    out[1] = ay + G0 * cth * sphi + p * w - r * u
    out[2] = az + G0 * cth * cphi + q * u - p * v
    out[3] = p + sth / cth * qr
    out[4] = q * cphi - r * sphi
    out[5] = qr / cth
    out[6] = u * sth - (v * sphi + w * cphi) * cth
    return out


def integrate(x0: np.ndarray, inputs: np.ndarray, dt: float) -> np.ndarray:
    """States (B, N, 7) from initial states ``x0`` (B, 7) and inputs (B, N, 6) sampled every
    ``dt`` s (RK4, inputs linear between samples)."""
    B, N, _ = inputs.shape
    a = np.ascontiguousarray(inputs.transpose(1, 2, 0))  # (N, 6, B)
    out = np.empty((N, 7, B))
    x = np.array(x0, dtype=float).T.copy()
    out[0] = x
    half, sixth = 0.5 * dt, dt / 6
    for k in range(N - 1):
        a0, a1 = a[k], a[k + 1]
        am = 0.5 * (a0 + a1)
        k1 = derivatives(x, a0)
        k2 = derivatives(x + half * k1, am)
        k3 = derivatives(x + half * k2, am)
        k4 = derivatives(x + dt * k3, a1)
        x = x + sixth * (k1 + 2 * (k2 + k3) + k4)
        out[k + 1] = x
    return out.transpose(2, 0, 1)


def outputs(states: np.ndarray) -> np.ndarray:
    """Outputs (..., 7) in :data:`OUTPUTS` order from states (..., 7)."""
    u, v, w = states[..., 0], states[..., 1], states[..., 2]
    V = np.sqrt(u * u + v * v + w * w)
    return np.stack([V, np.arctan2(w, u), np.arcsin(np.clip(v / np.maximum(V, 1e-9), -1, 1)),
                     states[..., 3], states[..., 4], states[..., 5], states[..., 6]], axis=-1)


def initial_state(measured: dict[str, float]) -> np.ndarray:
    """States (7,) from the first measured outputs (absent ones 0)."""
    V, al, be = (measured.get(k, 0.0) for k in ("V", "alpha", "beta"))
    return np.array([V * np.cos(al) * np.cos(be), V * np.sin(be), V * np.sin(al) * np.cos(be),
                     measured.get("phi", 0.0), measured.get("theta", 0.0), measured.get("psi", 0.0),
                     measured.get("h", 0.0)])

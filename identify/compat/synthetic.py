"""A synthetic flight for flight-path reconstruction, with known sensor errors.

The motion comes from a linear Navion-like model (longitudinal: airspeed, angle of attack, pitch
rate and attitude driven by the elevator; lateral: sideslip, roll and yaw rates, bank driven by
aileron and rudder) forced by turbulence: a vertical gust angle, a first-order (Dryden-like,
1 s correlation time) state of the model driven by white noise, so the forces it causes are
continuous in time as a real gust's are. The full states are the trim plus these perturbations; the body rates and the
accelerometers' specific forces are then computed from them by the exact rigid-body relations,
so the measurements are kinematically consistent (to the integration of the inputs between
samples), as a real aircraft's are. Sensor errors and noise are added last.
"""
from __future__ import annotations

import numpy as np

from ..data.runs import Run
from .kinematics import G0

U0, ALPHA0 = 53.6, 0.03  # m/s, rad (level flight: theta0 = alpha0)
# longitudinal x = (V, alpha, q, theta), inputs (de, alpha_gust)
A_LON = np.array([[-0.045, 1.96, 0.0, -G0], [-0.37 / U0, -2.02, 1.0, 0.0], [0.0, -12.4, -2.97, 0.0],
                  [0.0, 0.0, 1.0, 0.0]])
B_LON = np.array([[0.0, 1.96], [-0.16, -2.02], [-11.9, -12.4], [0.0, 0.0]])
# lateral x = (beta, p, r, phi), inputs (da, dr)
A_LAT = np.array([[-0.254, 0.0, -1.0, G0 / U0], [-16.0, -8.4, 2.19, 0.0], [4.5, -0.35, -0.76, 0.0],
                  [0.0, 1.0, 0.0, 0.0]])
B_LAT = np.array([[0.0, 0.0155], [29.0, 2.55], [-0.22, -4.6], [0.0, 0.0]])
ERRORS = {"K_alpha": 1.05, "b_alpha": np.radians(1.0), "b_q": np.radians(0.2), "tau_alpha": 0.06}
# a flight-test IMU's noise at 50 Hz (gyros 0.02 deg/s, accelerometers 0.01 m/s^2) and air-data,
# attitude and height sensors' noise
NOISE = {"a_x": 0.01, "a_y": 0.01, "a_z": 0.01, "p": np.radians(0.02), "q": np.radians(0.02),
         "r": np.radians(0.02), "V": 0.1, "alpha": np.radians(0.1), "beta": np.radians(0.1),
         "phi": np.radians(0.05), "theta": np.radians(0.05), "psi": np.radians(0.05), "h": 0.3}


def _simulate(A, B, u, dt):
    from scipy.linalg import expm

    n, m = B.shape
    E = expm(np.block([[A, B], [np.zeros((m, n + m))]]) * dt)
    Phi, Gam = E[:n, :n], E[:n, n:]
    x = np.zeros((len(u), n))
    for k in range(len(u) - 1):
        x[k + 1] = Phi @ x[k] + Gam @ u[k]
    return x, x @ A.T + u @ B.T  # states and their derivatives (the held input's)


def _pulses(t, t0, width, amp, pattern=(3, 2, 1, 1)):
    u, a = np.zeros_like(t), t0
    for k, n in enumerate(pattern):
        u[(t >= a) & (t < a + n * width)] = amp * (-1) ** k
        a += n * width
    return u


def flight(duration: float = 30.0, dt: float = 0.02, gust_deg: float = 0.5, seed: int = 0,
           errors: dict | None = None, noise: bool = True) -> tuple[Run, Run]:
    """``(measured, true)`` runs: channels a_x, a_y, a_z, p, q, r, V, alpha, beta, phi, theta,
    psi, h (SI) and the controls de, da, dr. ``errors`` (default :data:`ERRORS`: alpha-vane scale
    1.05, bias 1 deg and a 60 ms skew, q bias 0.2 deg/s) are applied to the measured run only;
    ``noise`` adds :data:`NOISE`. The true run holds the errorless, noiseless channels."""
    errors = ERRORS if errors is None else errors
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration / dt)) + 1) * dt
    de = _pulses(t, 2.0, 0.5, np.radians(2.0))
    da = _pulses(t, 12.0, 1.0, np.radians(3.0), (1, 1))
    dr = _pulses(t, 20.0, 1.0, np.radians(3.0), (1, 1))
    # the gust angle as a fifth longitudinal state: alpha_g' = (-alpha_g + sigma sqrt(2 T) w) / T
    T = 1.0
    A = np.zeros((5, 5))
    A[:4, :4], A[:4, 4], A[4, 4] = A_LON, B_LON[:, 1], -1 / T
    B = np.zeros((5, 2))
    B[:4, 0], B[4, 1] = B_LON[:, 0], np.radians(gust_deg) * np.sqrt(2 / T) / np.sqrt(dt)
    xl, dxl = _simulate(A, B, np.column_stack([de, rng.standard_normal(len(t))]), dt)
    xt, dxt = _simulate(A_LAT, B_LAT, np.column_stack([da, dr]), dt)
    V, al, be = U0 + xl[:, 0], ALPHA0 + xl[:, 1], xt[:, 0]
    Vd, ald, bed = dxl[:, 0], dxl[:, 1], dxt[:, 0]
    phi, th = xt[:, 3], ALPHA0 + xl[:, 3]
    phid, thd, psid = xt[:, 1], xl[:, 2], xt[:, 2]  # Euler-angle rates
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (psid[1:] + psid[:-1]) * dt)])
    ca, sa, cb, sb = np.cos(al), np.sin(al), np.cos(be), np.sin(be)
    u, v, w = V * ca * cb, V * sb, V * sa * cb
    ud = Vd * ca * cb - V * sa * cb * ald - V * ca * sb * bed
    vd = Vd * sb + V * cb * bed
    wd = Vd * sa * cb + V * ca * cb * ald - V * sa * sb * bed
    sphi, cphi, sth, cth = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
    p = phid - psid * sth
    q = thd * cphi + psid * sphi * cth
    r = -thd * sphi + psid * cphi * cth
    ax = ud + G0 * sth - r * v + q * w
    ay = vd - G0 * cth * sphi - p * w + r * u
    az = wd - G0 * cth * cphi - q * u + p * v
    hd = u * sth - v * sphi * cth - w * cphi * cth
    h = 1000.0 + np.concatenate([[0.0], np.cumsum(0.5 * (hd[1:] + hd[:-1]) * dt)])
    true = {"a_x": ax, "a_y": ay, "a_z": az, "p": p, "q": q, "r": r, "V": V, "alpha": al, "beta": be,
            "phi": phi, "theta": th, "psi": psi, "h": h, "de": de, "da": da, "dr": dr}
    meas = {k: v.copy() for k, v in true.items()}
    if errors.get("tau_alpha"):
        meas["alpha"] = np.interp(t - errors["tau_alpha"], t, meas["alpha"])
    meas["alpha"] = errors.get("K_alpha", 1.0) * meas["alpha"] + errors.get("b_alpha", 0.0)
    for name, value in errors.items():
        kind, _, ch = name.partition("_")
        if kind == "b" and ch != "alpha":
            meas[ch] = meas[ch] + value
        elif kind in ("K", "tau") and ch != "alpha":
            raise ValueError(f"synthetic flight: only the alpha vane has scale and skew errors, not {name}")
    if noise:
        for ch, s in NOISE.items():
            meas[ch] = meas[ch] + s * rng.standard_normal(len(t))
    info = {"synthetic": "identify.compat.synthetic.flight", "seed": str(seed)}
    return Run(t, meas, dict(info, sensor_errors=str(errors)), "synthetic flight"), Run(t, true, info, "true flight")

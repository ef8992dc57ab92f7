"""State-space model fitted to frequency responses (CIFER's DERIVID): cost J, Cramér-Rao and insensitivity.

The profile's structure ``dx/dt = A x + B u(t - tau)``, ``y = C x + D u(t - tau)`` (``A, B, C, D``
affine in the free parameters theta; ``tau`` an optional equivalent delay per input) has the
response ``H(jw) = (C (jwI - A)^-1 B + D) diag(e^{-jw tau})``. :func:`fit_frequency_responses` finds
theta (and the delays) that minimise the mean over input/output pairs of Tischler's cost::

    J_pair = 20 / n_w sum_w W_gamma [ (|H_m|dB - |H|dB)^2 + 0.01745 (phase_m - phase)^2 (deg) ],
    W_gamma = (1.58 (1 - exp(-gamma^2)))^2,

over the points each pair has that are **resolved** (a valid window), **coherent** (coherence
>= 0.6) and accurate (random error <= 0.2, when known); a pair with fewer than ``MIN_POINTS``
such points is not fitted and is listed once, as are
pairs the model has no path for. Gauss-Newton with the exact Jacobian (``dH = dC R B + C R dA R B
+ C R dB + dD``, ``R = (jwI - A)^-1``) inside ``scipy.optimize.least_squares``; delays bounded to
``[0, tau_max]``.

Accuracy (Tischler & Remple): the Cramér-Rao bound from the Gauss-Newton information ``F = G^T G /
s^2`` (``G`` the Jacobian of the weighted residuals, ``s^2 = sum r^2 / (n_r - p)`` the residual
variance of the fit, the usual estimate when the point errors are not known), reported as CR %
``= 100 CR / |theta|``; the insensitivity ``1 / sqrt(F_ii)`` in % likewise. CIFER's gates: CR <= 20 %,
insensitivity <= 10 %. This bound takes the points as independent; neighbouring points of a composite
response are not, so it is too small (3-4 times on the S 61 benchmark): it serves the gates here,
and :class:`~.response_fit.FR` replaces it by the bootstrap of :mod:`.bootstrap`. With
``prune=True`` the parameters the data cannot move at the start values
(insensitivity over its gate there, with the start's residual variance: a conservative screen) are
fixed first, then after each fit the worst offender (largest insensitivity %, else largest
CR %) is fixed at its a priori value, the model re-fitted, and so on until every free parameter
passes; each step is recorded with its reason and the J it leaves.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np
from scipy.optimize import least_squares

from ...model.linear import LinearModel
from ...model.profile import Profile
from ..result import CR_GUIDELINE, INSENSITIVITY_GUIDELINE

MIN_COHERENCE = 0.6
MAX_RANDOM_ERROR = 0.2  # as J's judgement (response.MAX_RANDOM_ERROR)
MIN_POINTS = 5  # as J's judgement (response.MIN_POINTS): fewer points say nothing about a pair
W_GAIN, W_PHASE = 1.0, 0.01745
DB = 20 / np.log(10)
CR_GATE, INSENSITIVITY_GATE = CR_GUIDELINE, INSENSITIVITY_GUIDELINE  # %: CIFER's gates


@dataclass
class ResponseData:
    """Measured responses to fit: ``omega`` (nf,) rad/s, ``H`` (nf, ny, nu) complex, ``coherence``
    (nf, ny, nu), ``resolved`` (nf, ny, nu) bool (a valid estimate), names of ``inputs``/``outputs``."""

    omega: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    resolved: np.ndarray
    inputs: list[str]
    outputs: list[str]
    random_error: np.ndarray | None = None  # (nf, ny, nu) normalised random error of |H|, if known

    @classmethod
    def from_response(cls, fr) -> "ResponseData":
        """From a composite frequency response (any object with these attributes)."""
        return cls(fr.omega, fr.H, fr.coherence, fr.resolved, list(fr.inputs), list(fr.outputs), fr.random_error)

    def usable(self, min_coherence: float = MIN_COHERENCE) -> np.ndarray:
        """Resolved, coherent and (when the random errors are known) accurate points, as J judges them."""
        ok = self.resolved & np.isfinite(self.H) & (self.coherence >= min_coherence)
        return ok if self.random_error is None else ok & (self.random_error <= MAX_RANDOM_ERROR)


def response_and_jacobian(model: LinearModel, omega: np.ndarray, yi: list[int], ui: list[int],
                   tau: np.ndarray | None = None, jacobian: bool = False):
    """``H`` (nf, ny, nu) of the model (rows ``yi``, columns ``ui``) with input delays ``tau`` (nu,);
    with ``jacobian`` also ``dH/dtheta`` (p, nf, ny, nu) and ``dH/dtau`` (nf, ny, nu) (the
    derivative of column i w.r.t. its own delay)."""
    n = model.n_states
    s = 1j * np.asarray(omega, dtype=float)
    R = np.linalg.inv(s[:, None, None] * np.eye(n) - model.A)  # (nf, n, n)
    B, C, D = model.B[:, ui], model.C[yi], model.D[np.ix_(yi, ui)]
    RB = R @ B  # (nf, n, nu)
    G = C @ RB + D  # (nf, ny, nu); matrix products, not einsum: batched BLAS over frequencies
    phase = np.exp(-s[:, None] * (np.zeros(len(ui)) if tau is None else tau)[None, :])  # (nf, nu)
    H = G * phase[:, None, :]
    if not jacobian:
        return H
    CR = C @ R  # (nf, ny, n)
    dA, dB, dC, dD = model.dA, model.dB[:, :, ui], model.dC[:, yi], model.dD[:, yi][:, :, ui]
    # batched over (parameter, frequency): a three-operand einsum here looped over every index
    # product and was a quarter of an FR fit's time
    dG = dC[:, None] @ RB[None] + CR[None] @ (dA[:, None] @ RB[None] + dB[:, None]) + dD[:, None]
    dH = dG * phase[None, :, None, :]
    dtau = -s[:, None, None] * H
    return H, dH, dtau


@dataclass
class FrequencyFit:
    """Result of :func:`fit_frequency_responses`. ``theta`` (p,) all free parameters of ``profile``
    (pruned ones at their a priori values), ``std``/``insensitivity`` (p,) (NaN for pruned ones),
    ``tau`` {input: s} fitted delays with ``tau_std``; ``J`` {pair: J}, ``J_mean``; ``n_points``
    {pair: n}; ``left_out`` {pair: reason}; ``pruned`` [(name, reason, J_mean after)]; ``notes``."""

    profile: Profile
    theta: np.ndarray
    std: np.ndarray
    insensitivity: np.ndarray
    covariance: np.ndarray
    tau: dict[str, float]
    tau_std: dict[str, float]
    J: dict[str, float]
    J_mean: float
    n_points: dict[str, int]
    left_out: dict[str, str]
    pruned: list[tuple[str, str, float]] = field(default_factory=list)
    converged: bool = True
    iterations: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return self.profile.free_names

    @property
    def model(self) -> LinearModel:
        return LinearModel(self.profile, self.theta)

    def accuracy(self) -> dict[str, dict]:
        """CR % and insensitivity % per free parameter and the gates each fails."""
        return gates(self.names, self.theta, self.std, self.insensitivity)

    def cost_lines(self) -> list[str]:
        lines = [f"frequency-response fit: J per pair over {sum(self.n_points.values())} resolved coherent points "
                 f"(J <= 100 fits), mean J {self.J_mean:.1f}"]
        lines += [f"  {k:<22}{v:10.1f}  ({self.n_points[k]} points)" for k, v in self.J.items()]
        if self.left_out:
            lines.append("  not fitted: " + "; ".join(f"{k} ({v})" for k, v in self.left_out.items()))
        screened = [n for n, _, J in self.pruned if not np.isfinite(J)]
        if screened:
            lines.append(f"  fixed at a priori before fitting (insensitivity > {INSENSITIVITY_GATE:g} % at the start "
                         f"values: the data do not move them): {', '.join(screened)}")
        for name, reason, J in self.pruned:
            if np.isfinite(J):
                lines.append(f"  fixed at a priori: {name} ({reason}); mean J then {J:.1f}")
        return lines


def gates(names: list[str], theta: np.ndarray, std: np.ndarray, insensitivity: np.ndarray) -> dict[str, dict]:
    """Per parameter the Cramér-Rao % and insensitivity % and CIFER's gates it fails."""
    out = {}
    with np.errstate(divide="ignore", invalid="ignore"):
        cr = 100 * std / np.abs(theta)
        ins = 100 * insensitivity / np.abs(theta)
    for n, c, i in zip(names, cr, ins):
        over = ([f"CR > {CR_GATE:g} %"] if not c <= CR_GATE else []) + \
               ([f"insensitivity > {INSENSITIVITY_GATE:g} %"] if not i <= INSENSITIVITY_GATE else [])
        out[n] = {"cramer_rao_pct": float(c), "insensitivity_pct": float(i), "over_gates": over}
    return out


def fit_frequency_responses(profile: Profile, data: ResponseData, *, theta0: np.ndarray | None = None,
                            delays: tuple[str, ...] = (), tau_max: float = 0.3,
                            min_coherence: float = MIN_COHERENCE, prune: bool = False,
                            max_nfev: int = 200) -> FrequencyFit:
    """Fit ``profile``'s free parameters (and input delays ``delays``) to ``data`` (see the module notes)."""
    model = LinearModel(profile, theta0)
    outs = [y for y in data.outputs if y in profile.outputs]
    ins = [u for u in data.inputs if u in profile.input_names]
    unknown = [u for u in delays if u not in ins]
    if unknown:
        raise ValueError(f"delays named for input(s) not in the data: {', '.join(unknown)}")
    yi = [profile.outputs.index(y) for y in outs]
    ui = [profile.input_names.index(u) for u in ins]
    dj = [data.outputs.index(y) for y in outs]
    di = [data.inputs.index(u) for u in ins]
    usable = data.usable(min_coherence)[:, dj][:, :, di]
    Hd = data.H[:, dj][:, :, di]
    W = (1.58 * (1 - np.exp(-data.coherence[:, dj][:, :, di]))) ** 2  # coherence is gamma^2
    H0, dH0, _ = response_and_jacobian(model, data.omega, yi, ui, jacobian=True)
    pairs, left_out = [], {}
    for a, y in enumerate(outs):
        for b, u in enumerate(ins):
            n = int(usable[:, a, b].sum())
            key = f"{y}/{u}"
            if not (np.any(np.abs(H0[:, a, b]) > 0) or np.any(np.abs(dH0[:, :, a, b]) > 0)):
                left_out[key] = "the model has no path"
            elif n < MIN_POINTS:
                left_out[key] = f"{n} resolved coherent points"
            else:
                pairs.append((a, b, key))
    if not pairs:
        raise ValueError("frequency-response fit: no input/output pair has resolved coherent points")
    def solve(m, active, nfev, tau0=None):
        return _solve(m, data.omega, Hd, W, usable, pairs, yi, ui, ins, delays, tau_max, active, nfev, tau0=tau0)

    active = np.ones(len(profile.free), bool)
    pruned = []
    if prune:  # screen at the start values: what the data cannot move at all is not fitted
        # with the start's residual variance alone (its misfit already makes it conservative)
        screen = solve(model, active, 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ins_pct = np.nan_to_num(100 * screen["ins"] / np.abs(model.theta), nan=np.inf)
        for k in np.flatnonzero(ins_pct > INSENSITIVITY_GATE):
            if active.sum() > 1:
                active[k] = False
                pruned.append((profile.free_names[k], f"insensitivity {ins_pct[k]:.3g} % > "
                               f"{INSENSITIVITY_GATE:g} % at the start values (screened before fitting)",
                               float("nan")))
    fit = solve(model, active, max_nfev)
    while prune:
        acc = _gates(fit["theta"], fit["std"], fit["ins"], active)
        if not acc:
            break
        name_i, reason = acc
        active[name_i] = False
        theta = fit["theta"].copy()
        theta[name_i] = model.theta[name_i]
        fit = solve(model.with_theta(theta), active, max_nfev, tau0=fit["tau"])
        pruned.append((profile.free_names[name_i], reason, fit["J_mean"]))
    p = profile
    if pruned:  # the pruned parameters become fixed in the identified structure
        names = [n for n, _, _ in pruned]
        p = replace(profile, free={k: v for k, v in profile.free.items() if k not in names},
                    fixed={**profile.fixed, **{n: float(fit["theta"][profile.free_names.index(n)]) for n in names}})
    keep = active
    tau = {u: float(t) for u, t in zip(delays, fit["tau"])}
    tau_std = {u: float(t) for u, t in zip(delays, fit["tau_std"])}
    notes = [] if fit["converged"] else [f"optimiser stopped before convergence: {fit['message']}"]
    at_bound = [u for u, t in tau.items() if t <= 1e-9 or t >= tau_max - 1e-9]
    if at_bound:
        notes.append(f"delay at its bound (0 or {tau_max:g} s): {', '.join(at_bound)}")
    return FrequencyFit(p, fit["theta"][keep], fit["std"][keep], fit["ins"][keep],
                        fit["cov"][np.ix_(keep, keep)], tau, tau_std, fit["J"], fit["J_mean"], fit["n"], left_out,
                        pruned, fit["converged"], fit["nfev"], notes)


def _gates(theta, std, ins, active) -> tuple[int, str] | None:
    """The active parameter to fix next (largest insensitivity % over its gate, else largest CR %)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        cr = np.where(active, 100 * std / np.abs(theta), -np.inf)
        iv = np.where(active, 100 * ins / np.abs(theta), -np.inf)
    cr, iv = np.nan_to_num(cr, nan=np.inf), np.nan_to_num(iv, nan=np.inf)
    if active.sum() <= 1:
        return None
    if np.max(iv) > INSENSITIVITY_GATE:
        k = int(np.argmax(iv))
        return k, f"insensitivity {iv[k]:.3g} % > {INSENSITIVITY_GATE:g} %"
    if np.max(cr) > CR_GATE:
        k = int(np.argmax(cr))
        return k, f"Cramér-Rao {cr[k]:.3g} % > {CR_GATE:g} % (correlated with others)"
    return None


def _solve(model, omega, Hd, W, usable, pairs, yi, ui, ins, delays, tau_max, active, max_nfev, tau0=None):
    """One Gauss-Newton fit of the active parameters and the delays; cost, bounds and per-pair J."""
    d_idx = [ins.index(u) for u in delays]
    theta_all = model.theta.copy()
    n_act = int(active.sum())
    sel = [(a, b, key, usable[:, a, b]) for a, b, key in pairs]
    n_pairs = len(sel)

    def unpack(x):
        theta = theta_all.copy()
        theta[active] = x[:n_act]
        tau = np.zeros(len(ins))
        tau[d_idx] = x[n_act:]
        return theta, tau

    def residuals(x, jac=False):
        theta, tau = unpack(x)
        m = model.with_theta(theta)
        out = response_and_jacobian(m, omega, yi, ui, tau, jacobian=jac)
        H = out[0] if jac else out
        r, G = [], []
        for a, b, key, use in sel:
            scale = np.sqrt(20 / use.sum() * W[use, a, b] / n_pairs)
            ratio = H[use, a, b] / Hd[use, a, b]
            with np.errstate(divide="ignore", invalid="ignore"):
                r.append(np.concatenate([scale * DB * np.log(np.abs(ratio)),
                                         scale * np.sqrt(W_PHASE) * np.degrees(np.angle(ratio))]))
            if jac:
                dlog = out[1][:, use, a, b][active] / H[use, a, b]  # (p_act, n): d log H
                cols = [dlog]
                if d_idx:
                    dt = np.zeros((len(d_idx), use.sum()), complex)
                    if b in d_idx:
                        dt[d_idx.index(b)] = out[2][use, a, b] / H[use, a, b]
                    cols.append(dt)
                dl = np.vstack(cols)
                G.append(np.hstack([scale * DB * dl.real, scale * np.sqrt(W_PHASE) * np.degrees(dl.imag)]).T)
        r = np.concatenate(r)
        return (r, np.vstack(G)) if jac else r

    x0 = np.concatenate([theta_all[active], np.zeros(len(d_idx)) if tau0 is None else np.asarray(tau0, float)])
    lo = np.concatenate([np.full(n_act, -np.inf), np.zeros(len(d_idx))])
    hi = np.concatenate([np.full(n_act, np.inf), np.full(len(d_idx), tau_max)])
    x0 = np.clip(x0, lo + 1e-9, hi - 1e-9) if d_idx else x0
    if max_nfev:
        sol = least_squares(lambda x: residuals(x), x0, jac=lambda x: residuals(x, True)[1], bounds=(lo, hi),
                            x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=max_nfev, method="trf")
    else:  # evaluate only (the screen at the start values)
        sol = SimpleNamespace(x=x0, success=True, message="not fitted", nfev=0)
    r, G = residuals(sol.x, True)
    theta, tau = unpack(sol.x)
    # per-pair J (the residuals are scaled by 1/n_pairs: undo it)
    J, n, k = {}, {}, 0
    for a, b, key, use in sel:
        m = 2 * int(use.sum())
        J[key] = float(n_pairs * np.sum(r[k:k + m] ** 2))
        n[key] = int(use.sum())
        k += m
    J_mean = float(np.mean(list(J.values())))
    s2 = np.sum(r ** 2) / max(len(r) - G.shape[1], 1)
    F = G.T @ G / max(s2, 1e-300)
    try:
        cov_x = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        cov_x = np.linalg.pinv(F)
    p = len(theta_all)
    cov = np.full((p, p), np.nan)
    idx = np.flatnonzero(active)
    cov[np.ix_(idx, idx)] = cov_x[:n_act, :n_act]
    std = np.full(p, np.nan)
    ins_all = np.full(p, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        std[idx] = np.sqrt(np.maximum(np.diag(cov_x)[:n_act], 0))
        ins_all[idx] = 1 / np.sqrt(np.diag(F)[:n_act])
        tau_std = np.sqrt(np.maximum(np.diag(cov_x)[n_act:], 0))
    return dict(theta=theta, tau=tau[d_idx], tau_std=tau_std, std=std, ins=ins_all, cov=cov, J=J, J_mean=J_mean,
                n=n, converged=bool(sol.success), message=sol.message, nfev=int(sol.nfev))

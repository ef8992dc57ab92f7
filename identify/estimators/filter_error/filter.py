"""The steady-state Kalman filter of the filter-error method: innovations, their sensitivities, the
Fisher information (the derivation: :mod:`identify.estimators.filter_error`).

:class:`FilterProblem` is the problem of a profile over runs: the unknowns' layout, their start,
the filter at one point (:class:`Filtered`) with the innovations' derivatives from one recursion
and the gain's from one discrete Lyapunov equation; :class:`NonlinearFilterProblem` the extended
filter of a profile with state-built terms (:mod:`.nonlinear`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from ...model.linear import LinearModel
from ...model.profile import Profile
from ...model.sensitivity import discretize_with_derivatives
from ...model.simulate import discretize, held_inputs, propagate
from ..output_error import cut, pad
from .base import F_START
from .bounds import coloured_covariance
from .nonlinear import StateTerms

GAIN_STEP = 1e-5  # relative step of the central differences of Qd


class Filtered:
    """The filter at one beta: ``nu`` (L, ny, R) innovations (0 on padding), ``x`` (L, n, R)
    predicted states, ``S`` (ny, ny), ``P`` (n, n), ``K`` (n, ny) filter gain, ``cost``;
    with the Jacobian ``dnu`` (L, ny, k, R) over each run's local unknowns and ``dS`` (G, ny, ny)."""

    def __init__(self, beta, model, nu, x, S, P, K, cost):
        self.beta, self.model, self.nu, self.x, self.S, self.P, self.K, self.cost = beta, model, nu, x, S, P, K, cost
        self.dnu = self.dS = None


class FilterProblem:
    """The filter-error problem of a profile over runs (each run one recursion, all run together).

    ``u``, ``z``: lists of (N_r, m) inputs and (N_r, ny) outputs; ``noise_states`` the states with
    process noise; ``hold`` the inputs between samples ("held" or "linear").
    Unknowns ``beta = [theta (p), F (nf), R diag (ny), x0 per run (R, n), zero shifts per run (R, ny)]``;
    each run's local unknowns are ``[theta, F, R, x0 of the run, its zero shifts]`` (k columns).
    """

    def __init__(self, profile: Profile, u, z, dt: float, noise_states: list[str], hold: str = "held"):
        self.profile, self.dt, self.hold = profile, float(dt), hold
        self.model0 = m0 = LinearModel(profile)
        self.n, self.m, self.ny, self.p = m0.n_states, m0.n_inputs, m0.n_outputs, len(m0.names)
        self.noise_states = list(noise_states)
        self.w_idx = [profile.state_names.index(s) for s in noise_states]
        self.nf = len(noise_states)
        self.layout = lay = cut([len(zr) for zr in z], dt, math.inf)
        self.n_runs = R = lay.n_segments
        self.U = pad(lay, [held_inputs(ur, hold) for ur in u])  # (L, m or 2m, R)
        self.Z = pad(lay, z)
        self.mask = pad(lay, [np.ones((len(zr), 1)) for zr in z])[:, 0, :]
        self.N = float(self.mask.sum())
        p, nf, ny, n = self.p, self.nf, self.ny, self.n
        self.G = p + nf + ny  # globals: theta, F, R
        start = self.G
        self.index = {"theta": np.arange(p), "f": p + np.arange(nf), "r": p + nf + np.arange(ny),
                      "x0": start + np.arange(R * n).reshape(R, n),
                      "b": start + R * n + np.arange(R * ny).reshape(R, ny)}
        self.n_beta = start + R * (n + ny)
        self.k = self.G + n + ny
        self.local_index = np.hstack([np.tile(np.arange(self.G), (R, 1)), self.index["x0"], self.index["b"]])
        self.prior = None  # a PriorTerm (identify.estimators.prior): its residuals join the cost

    def unpack(self, beta):
        """``theta`` (p,), ``F`` (nf,), ``x0`` (n, R), ``b`` (ny, R), ``R`` diag (ny,)."""
        ix = self.index
        return beta[ix["theta"]], beta[ix["f"]], beta[ix["x0"]].T, beta[ix["b"]].T, beta[ix["r"]]

    def start(self, noise: dict, x0_fixed: dict, estimate_x0: bool, estimate_bias: bool):
        """The start beta and the unknowns that move (``active``): x0 from the measured outputs that
        are plain states (else 0) unless fixed; zero shifts from the profile; F from the profile or
        a share of the state's measured rms; R from the outputs' variance (relaxed at once)."""
        p, ix = self.profile, self.index
        beta = np.zeros(self.n_beta)
        active = np.ones(self.n_beta, bool)
        beta[ix["theta"]] = self.model0.theta
        rms = np.sqrt(np.sum(self.Z ** 2, axis=(0, 2)) / self.N)
        for i, s in enumerate(self.noise_states):
            y = p.outputs.index(s) if s in p.outputs else None
            scale = rms[y] if y is not None and rms[y] > 0 else 1.0
            beta[ix["f"][i]] = noise[s] if noise[s] is not None else F_START * scale * math.sqrt(2.0)
        beta[ix["r"]] = np.maximum(rms ** 2, 1e-300)  # relaxed from the first innovations at once
        for j, y in enumerate(p.outputs):
            if y in p.states and p.output_terms(y) == {y: 1.0}:
                beta[ix["x0"][:, p.state_names.index(y)]] = self.Z[0, j, :]
            value, est = p.zero_shift(y)
            beta[ix["b"][:, j]] = value
            active[ix["b"][:, j]] = est and estimate_bias
        for s, v in x0_fixed.items():
            beta[ix["x0"][:, p.state_names.index(s)]] = v
            active[ix["x0"][:, p.state_names.index(s)]] = False
        if not estimate_x0:
            active[ix["x0"]] = False
        return beta, active

    # -- the filter ------------------------------------------------------------------------------
    def _noise_cov(self, A, f):
        """``Phi`` (q, n, n) and ``Qd`` (q, n, n) of a stack of q state matrices A (q, n, n) and
        process-noise values F (q, nf), by Van Loan's exponential, all q at once."""
        q, n = A.shape[0], self.n
        FF = np.zeros((q, n, n))
        FF[:, self.w_idx, self.w_idx] = f ** 2
        M = np.zeros((q, 2 * n, 2 * n))
        M[:, :n, :n], M[:, :n, n:], M[:, n:, n:] = -A, FF, A.transpose(0, 2, 1)
        E = expm(M * self.dt)
        Phis = E[:, n:, n:].transpose(0, 2, 1)
        Qd = Phis @ E[:, :n, n:]
        return Phis, 0.5 * (Qd + Qd.transpose(0, 2, 1))

    def _gain(self, A, C, f, r):
        """Predictor gain Kp (n, ny), innovation covariance S (ny, ny), a priori covariance P
        (n, n) and Phi, Qd of one model."""
        with np.errstate(over="ignore", invalid="ignore"):
            Phi, Qd = (a[0] for a in self._noise_cov(A[None], f[None]))
        if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(Qd))):
            raise np.linalg.LinAlgError("the model's exponential overflows")
        P = solve_discrete_are(Phi.T, C.T, Qd, np.diag(r))
        S = C @ P @ C.T + np.diag(r)
        return Phi @ np.linalg.solve(S, C @ P).T, S, P

    def evaluate(self, beta, jacobian: bool = False, noise: bool = False) -> Filtered:
        """Innovations at ``beta``; with ``jacobian`` their derivatives with respect to theta, F,
        x0 and zero shifts (and R with ``noise``). Raises LinAlgError/ValueError when the Riccati
        equation has no stabilising solution."""
        theta, f, x0, b, r = self.unpack(beta)
        model = self.model0.with_theta(theta)
        if jacobian:
            Phi, Gamma, dPhi, dGamma = discretize_with_derivatives(model, self.dt, self.hold)
        else:
            Phi, Gamma = discretize(model.A, model.B, self.dt, self.hold)
        Kp, S, P = self._gain(model.A, model.C, f, r)
        C, D = model.C, model.D
        Dh = np.hstack([D, np.zeros_like(D)]) if self.hold == "linear" else D  # D acts on u[k] only
        Abar = Phi - Kp @ C
        zb = self.Z - b[None]
        with np.errstate(over="ignore", invalid="ignore"):
            x = propagate(Abar, (Gamma - Kp @ Dh) @ self.U + Kp @ zb, x0)
            nu = np.where(self.mask[:, None, :] > 0, zb - C @ x - Dh @ self.U, 0.0)
        if not np.all(np.isfinite(nu)):
            raise np.linalg.LinAlgError("the filter's prediction is not finite")
        Sinv = np.linalg.inv(S)
        cost = 0.5 * float(np.einsum("kir,ij,kjr->", nu, Sinv, nu)) + 0.5 * self.N * np.linalg.slogdet(S)[1]
        if self.prior is not None:
            cost += self.prior.cost(beta[:self.p])
        K = np.linalg.solve(Phi, Kp) if np.linalg.cond(Phi) < 1e12 else P @ np.linalg.solve(S, C).T
        ev = Filtered(beta, model, nu, x, S, P, K, cost)
        ev.Kp = Kp
        if jacobian:
            self._jacobian(ev, Phi, Gamma, dPhi, dGamma, Kp, Dh, noise)
        return ev

    def _jacobian(self, ev: Filtered, Phi, Gamma, dPhi, dGamma, Kp, Dh, noise: bool) -> None:
        """``ev.dnu`` (L, ny, k, R) and ``ev.dS`` (G, ny, ny): one recursion with Abar for all columns."""
        theta, f, x0, b, r = self.unpack(ev.beta)
        model, n, ny, p, nf, G = ev.model, self.n, self.ny, self.p, self.nf, self.G
        dKp, dS = self._gain_derivatives(ev, Phi, Kp, dPhi, noise)
        mu = self.U.shape[1]
        dPhi_g, dGamma_g = np.zeros((G, n, n)), np.zeros((G, n, mu))
        dC_g, dD_g = np.zeros((G, ny, n)), np.zeros((G, ny, mu))
        dPhi_g[:p], dGamma_g[:p], dC_g[:p], dD_g[:p, :, :self.m] = dPhi, dGamma, model.dC, model.dD
        C = model.C
        dAbar = dPhi_g - dKp @ C - Kp @ dC_g
        dGu = dGamma_g - dKp @ Dh - Kp @ dD_g
        zb = self.Z - b[None]
        x, L, R = ev.x, self.Z.shape[0], self.n_runs
        forcing = np.zeros((L, n, self.k, R))
        forcing[:, :, :G] = (_stacked(dAbar, x) + _stacked(dGu, self.U) + _stacked(dKp, zb)).transpose(0, 2, 1, 3)
        forcing[:, :, G + n:] = -Kp[None, :, :, None]
        start = np.zeros((n, self.k, R))
        start[:, G:G + n] = np.eye(n)[:, :, None]
        sens = propagate(Phi - Kp @ C, forcing.reshape(L, n, -1), start.reshape(n, -1))
        dnu = -(C @ sens).reshape(L, ny, self.k, R)
        dnu[:, :, :G] -= (_stacked(dC_g, x) + _stacked(dD_g, self.U)).transpose(0, 2, 1, 3)
        dnu[:, :, G + n:] -= np.eye(ny)[None, :, :, None]
        dnu *= self.mask[:, None, None, :]
        if not (np.all(np.isfinite(dnu)) and np.all(np.isfinite(dS))):
            raise np.linalg.LinAlgError("the filter's sensitivities are not finite")
        ev.dnu, ev.dS = dnu, dS

    def _gain_derivatives(self, ev: Filtered, Phi, Kp, dPhi, noise: bool):
        """``dKp`` (G, n, ny) and ``dS`` (G, ny, ny) (zero for R unless ``noise``), analytic: at the
        steady state ``P = Abar P Abar^T + Kp R Kp^T + Qd`` with Kp optimal, so (Kp held)
        ``dP = Abar dP Abar^T + Xi``, ``Xi = dAbar P Abar^T + Abar P dAbar^T + Kp dR Kp^T + dQd``,
        ``dAbar = dPhi - Kp dC``: one discrete Lyapunov equation, all G right-hand sides at once.
        ``dQd`` by central differences of Van Loan's exponential (exact in F, which enters
        squared), batched; no Riccati solve and no re-filtering."""
        theta, f, _, _, r = self.unpack(ev.beta)
        p, nf, ny, n, G = self.p, self.nf, self.ny, self.n, self.G
        model, P, S = ev.model, ev.P, ev.S
        C = model.C
        dPhi_g, dC_g, dR = np.zeros((G, n, n)), np.zeros((G, ny, n)), np.zeros((G, ny, ny))
        dPhi_g[:p], dC_g[:p] = dPhi, model.dC
        if noise:
            dR[p + nf + np.arange(ny), np.arange(ny), np.arange(ny)] = 1.0
        # dQd: theta through A, F through F F^T (central differences; Qd is quadratic in F)
        h = GAIN_STEP * np.maximum(np.abs(np.concatenate([theta, f])), 1e-3 * max(np.abs(theta).max(), 1e-12))
        As = np.concatenate([model.A + h[:p, None, None] * model.dA, np.repeat(model.A[None], nf, 0)])
        fs = np.concatenate([np.repeat(f[None], p, 0), f + np.diag(h[p:])])
        Am = np.concatenate([model.A - h[:p, None, None] * model.dA, np.repeat(model.A[None], nf, 0)])
        fm = np.concatenate([np.repeat(f[None], p, 0), f - np.diag(h[p:])])
        dQd = np.zeros((G, n, n))
        with np.errstate(over="ignore", invalid="ignore"):  # not finite: reported by the caller
            dQd[:p + nf] = (self._noise_cov(As, fs)[1] - self._noise_cov(Am, fm)[1]) / (2 * h[:, None, None])
        Abar = Phi - Kp @ C
        dA = dPhi_g - Kp @ dC_g
        Xi = dA @ P @ Abar.T
        Xi = Xi + Xi.transpose(0, 2, 1) + Kp @ dR @ Kp.T + dQd
        lyap = np.eye(n * n) - np.kron(Abar, Abar)  # vec(Abar X Abar^T) = (Abar x Abar) vec(X), row-major
        dP = np.linalg.solve(lyap, Xi.reshape(G, n * n).T).T.reshape(G, n, n)
        dS = dC_g @ P @ C.T + C @ dP @ C.T + (dC_g @ P @ C.T).transpose(0, 2, 1) + dR
        dKp = (dPhi_g @ P @ C.T + Phi @ dP @ C.T + Phi @ (dC_g @ P).transpose(0, 2, 1) - Kp @ dS) @ np.linalg.inv(S)
        return dKp, dS

    # -- Fisher information ------------------------------------------------------------------------
    def information(self, ev: Filtered):
        """Fisher information ``M`` (n_beta, n_beta) and ``g = -dJ/dbeta`` (n_beta,)."""
        # S's own Cholesky factor: that of inv(S) failed on an ill-conditioned S a step had just
        # lowered the cost with (refine, Navion in gusts with a pilot, a delay's re-fit)
        Wh = np.linalg.inv(np.linalg.cholesky(ev.S))  # Wh^T Wh = S^-1
        Sinv = Wh.T @ Wh
        L, ny, k, R = ev.dnu.shape
        Jw = (Wh @ ev.dnu.reshape(L, ny, k * R)).reshape(L, ny, k, R).transpose(3, 0, 1, 2).reshape(R, L * ny, k)
        ew = (Wh @ ev.nu).transpose(2, 0, 1).reshape(R, L * ny)
        M, g = np.zeros((self.n_beta, self.n_beta)), np.zeros(self.n_beta)
        for rr in range(R):
            idx = self.local_index[rr]
            M[np.ix_(idx, idx)] += Jw[rr].T @ Jw[rr]
            g[idx] -= Jw[rr].T @ ew[rr]
        G = self.G
        SdS = Sinv @ ev.dS  # (G, ny, ny)
        M[:G, :G] += 0.5 * self.N * np.einsum("iab,jba->ij", SdS, SdS)
        outer = np.einsum("kir,kjr->ij", ev.nu, ev.nu)
        g[:G] -= 0.5 * np.einsum("iab,ba->i", SdS, self.N * np.eye(ny) - Sinv @ outer)
        if self.prior is not None:  # the prior's residuals on theta
            p = self.p
            M[np.arange(p), np.arange(p)] += self.prior.precision
            g[:p] += self.prior.gradient(ev.beta[:p])
        return M, g

    def coloured(self, ev: Filtered, active: np.ndarray):
        """The covariance (n_beta, n_beta) corrected for coloured innovations, the whitened
        innovations' autocorrelation (L, ny) and the number of passes (:func:`.bounds.coloured_covariance`)."""
        return coloured_covariance(self, ev, active)

    def per_run(self, arr: np.ndarray) -> list[np.ndarray]:
        """(L, ny, R) back to one (N_r, ny) array per run."""
        return [arr[:n_r, :, r].copy() for r, n_r in enumerate(self.layout.length)]


def _stacked(mats: np.ndarray, series: np.ndarray) -> np.ndarray:
    """``mats`` (G, a, b) times ``series`` (L, b, R) for every g at once: (L, G, a, R), one matmul."""
    G, a, b = mats.shape
    return (mats.reshape(G * a, b) @ series).reshape(series.shape[0], G, a, series.shape[2])



class NonlinearFilterProblem(StateTerms, FilterProblem):
    """:class:`FilterProblem` of a profile with state-built terms: the extended Kalman filter
    (:mod:`.nonlinear`)."""

    Filtered = Filtered

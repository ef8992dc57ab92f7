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
        self.dnu = self.dS = self.diffuse_grad = None


class FilterProblem:
    """The filter-error problem of a profile over runs (each run one recursion, all run together).

    ``u``, ``z``: lists of (N_r, m) inputs and (N_r, ny) outputs; ``noise_states`` the states with
    process noise; ``hold`` the inputs between samples ("held" or "linear").
    Unknowns ``beta = [theta (p), F (nf), R diag (ny), x0 per run (R, n), zero shifts per run (R, ny)]``;
    each run's local unknowns are ``[theta, F, R, x0 of the run, its zero shifts]`` (k columns).
    """

    diffuse_supported = True  # the extended filter and the textbook's formulation: the profile likelihood only

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
        # the diffuse likelihood (:meth:`diffuse_term`): per run (R, n + ny), the initial states and
        # zero shifts integrated out; None: the profile likelihood (them estimated with the rest)
        self.diffuse = None
        # states (indices) whose start is a draw from their stationary distribution (a gust:
        # variance F^2 / (2 omega), omega = -A[j, j]): that prior joins the diffuse likelihood
        self.stationary: list[int] = []

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
        if self.diffuse is not None:
            s2, _ = self._stationary(model, f)
            cost += self.diffuse_term(Abar, Kp, C, Sinv, s2)
            on = np.isfinite(s2)
            cost += 0.5 * float(np.sum(x0[on] ** 2 / s2[on, None])) + 0.5 * self.n_runs * float(np.sum(np.log(s2[on])))
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
        if self.diffuse is not None:
            s2, ds2 = self._stationary(model, f)
            ev.diffuse_grad = self._diffuse_gradient_exact(Phi - Kp @ C, Kp, C, np.linalg.inv(ev.S), dAbar, dKp,
                                                           dC_g, dS, s2, ds2, x0)

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

    # -- the diffuse likelihood ----------------------------------------------------------------------
    def _stationary(self, model, f):
        """The stationary variances ``s2`` (n,) of the ``stationary`` states' starts (NaN for the
        others, and for a state without process noise) and their derivatives ``ds2`` (G, n)."""
        n, p = self.n, self.p
        s2, ds2 = np.full(n, np.nan), np.zeros((self.G, n))
        for j in self.stationary:
            i = self.w_idx.index(j)
            omega, F = -model.A[j, j], f[i]
            if not omega > 0:
                raise np.linalg.LinAlgError(f"the gust state {self.profile.state_names[j]} is not stable")
            if F == 0:
                continue
            s2[j] = F ** 2 / (2 * omega)
            ds2[:p, j] = s2[j] / omega * model.dA[:, j, j]  # d omega = -dA[j, j]
            ds2[p + i, j] = 2 * s2[j] / F
        return s2, ds2

    def diffuse_term(self, Abar, Kp, C, Sinv, s2=None) -> float:
        """``0.5 sum_r log det(H_r^T S^-1 H_r + Lambda)``: what the negative log-likelihood gains when
        each run's initial states and zero shifts (the columns ``diffuse`` (R, n + ny) lists) are
        integrated out instead of estimated (de Jong's diffuse likelihood, REML for a state-space
        model): with a flat prior, but a ``stationary`` state's start with its stationary one
        (precision ``Lambda = 1 / s2``; its own ``0.5 x0^2 / s2 + 0.5 log s2`` per run is added by
        :meth:`evaluate`, the estimated x0 being the mode). ``H_r`` = d(innovations)/d(those
        unknowns) of run r; they enter the innovations linearly, so the integral is exact.
        Estimated with the rest (the profile likelihood), they take up part of the slow
        disturbances and the noise's parameters follow (a gust's corner too high and its intensity
        too low on short runs); integrated flat, a gust's start lets its corner run to zero."""
        return self._diffuse_parts(Abar, Kp, C, Sinv, s2)[0]

    def _diffuse_parts(self, Abar, Kp, C, Sinv, s2=None):
        """The term, the sensitivities ``sens`` (L, n, k, R) of the states to the nuisance, ``H``
        (L, ny, k, R) and each run's inverse Gram matrix on its integrated columns (R, k, k; zero
        elsewhere)."""
        n, ny, R = self.n, self.ny, self.n_runs
        L, k = self.Z.shape[0], n + ny
        start = np.zeros((n, k, R))
        start[:, :n] = np.eye(n)[:, :, None]
        forcing = np.zeros((L, n, k, R))
        forcing[:, :, n:] = -Kp[:, :, None]
        sens = propagate(Abar, forcing.reshape(L, n, -1), start.reshape(n, -1)).reshape(L, n, k, R)
        H = -(C @ sens.reshape(L, n, -1)).reshape(L, ny, k, R)
        H[:, :, n:] -= np.eye(ny)[:, :, None]
        H *= self.mask[:, None, None, :]
        Wh = np.linalg.cholesky(Sinv).T  # Wh^T Wh = S^-1
        Hw = (Wh @ H.reshape(L, ny, -1)).reshape(L, ny, k, R).transpose(3, 0, 1, 2).reshape(R, L * ny, k)
        gram = Hw.transpose(0, 2, 1) @ Hw  # (R, k, k)
        if s2 is not None:  # a stationary start's prior precision
            idx = np.flatnonzero(np.isfinite(s2))
            gram[:, idx, idx] += 1 / s2[idx]
        total, inv = 0.0, np.zeros((R, k, k))
        for r in range(R):
            keep = self.diffuse[r]
            if keep.any():
                w, V = np.linalg.eigh(gram[r][np.ix_(keep, keep)])
                w = np.maximum(w, 1e-12 * max(w.max(), 1e-300))
                total += 0.5 * float(np.sum(np.log(w)))
                inv[r][np.ix_(keep, keep)] = (V / w) @ V.T
        return total, sens, H, inv

    def _diffuse_gradient_exact(self, Abar, Kp, C, Sinv, dAbar, dKp, dC, dS, s2, ds2, x0) -> np.ndarray:
        """d(:meth:`diffuse_term`)/d(globals) (G,) from the globals' derivatives of the filter
        (``dAbar`` (G, n, n), ``dKp`` (G, n, ny), ``dC`` (G, ny, n), ``dS`` (G, ny, ny)): with
        ``E = S^-1 H Gram^-1``, ``d(0.5 log det Gram) = sum_l <E_l, dH_l> - 0.5 <dS, T>``,
        ``T = sum_l S^-1 H_l Gram^-1 H_l^T S^-1``; the sensitivities' own derivatives enter through
        one backward (adjoint) recursion, ``lam_j = Abar^T lam_{j+1} + C^T E_{j+1}``."""
        _, sens, H, inv = self._diffuse_parts(Abar, Kp, C, Sinv, s2)
        L, ny, k, R = H.shape
        n = self.n
        E = np.einsum("ij,ljbr,rbc->licr", Sinv, H, inv, optimize=True)  # (L, ny, k, R)
        Ef, Hf = E.reshape(L, ny, k * R), H.reshape(L, ny, k * R)
        T = np.einsum("lac,lbc->ab", Ef, Hf, optimize=True) @ Sinv  # sum_l E_l H_l^T S^-1
        B = (C.T @ Ef)  # (L, n, k R)
        mu = propagate(Abar.T, np.concatenate([B[:0:-1], np.zeros((1, n, k * R))]), np.zeros((n, k * R)))
        lam = mu[::-1]  # lam_j = sum_{l > j} (Abar^T)^(l-1-j) B_l
        sf = sens.reshape(L, n, k * R)
        lam_sens = np.einsum("lac,lbc->ab", lam, sf, optimize=True)  # (n, n)
        lam_b = lam.reshape(L, n, k, R)[:, :, n:].sum(axis=(0, 3))  # (n, ny)
        E_sens = np.einsum("lac,lbc->ab", Ef, sf, optimize=True)  # (ny, n)
        grad = (-np.einsum("gab,ab->g", dC, E_sens) - np.einsum("gab,ab->g", dAbar, lam_sens)
                + np.einsum("gab,ab->g", dKp, lam_b) - 0.5 * np.einsum("gab,ab->g", dS, T))
        on = np.flatnonzero(np.isfinite(s2))  # the stationary starts: prior and its precision in the Gram
        d_s2 = (-0.5 * np.sum(x0[on] ** 2, axis=1) / s2[on] ** 2 + 0.5 * R / s2[on]
                - 0.5 * inv[:, on, on].sum(axis=0) / s2[on] ** 2)
        return grad + ds2[:, on] @ d_s2

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
        if self.diffuse is not None:
            g[:G] -= ev.diffuse_grad
            s2, _ = self._stationary(ev.model, ev.beta[self.index["f"]])
            on = np.flatnonzero(np.isfinite(s2))
            cols = self.index["x0"][:, on]  # (R, len(on)): the stationary starts' prior
            g[cols] -= ev.beta[cols] / s2[on]
            M[cols, cols] += 1 / s2[on]
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

    diffuse_supported = False

    Filtered = Filtered

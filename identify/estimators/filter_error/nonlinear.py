"""The filter-error method for profiles with state-built nonlinear terms: an extended Kalman filter.

A refined profile may hold pseudo-inputs that are products with a state factor (``q|q|``,
``q eta``; :mod:`identify.model.pseudo_inputs`): ``dx/dt = A x + B_u u + B_f f(x, u) + F w``,
``y = C x + D_u u + D_f f(x, u) + b + v``. The linear filter of
:mod:`identify.estimators.filter_error.filter` cannot carry them; this mixin gives its
:class:`~identify.estimators.filter_error.filter.FilterProblem` the extended filter of Jategaonkar's
filter-error method for nonlinear systems (*Flight Vehicle System Identification*, ch. 5):

* the state is predicted through the nonlinear model, sample by sample, the terms evaluated on
  the filter's own states, never on the measurements (whose noise would bias them)::

      nu[k]   = z[k] - b - C x~[k] - D_u u[k] - D_f f(x~[k], u[k])      (innovation)
      x^[k]   = x~[k] + K nu[k]                                        (corrected state)
      x~[k+1] = Phi x^[k] + Gamma_u u[k] + Gamma_f f(x^[k], u[k])      (terms held over the sample)

* the gain is constant: the steady-state gain of the model linearised at the operating point
  (states at trim, zero; channel factors at their mean over the data), ``A_lin = A + B_f J0``,
  ``C_lin = C + D_f J0`` with ``J0 = df/dx`` there (zero for ``q|q|`` and for a state times a
  zero-mean input: then the linear model's own gain). F, R, the Riccati solution and the gain's
  derivatives are the linear method's, on the linearised model;
* the cost is the negative log-likelihood of the innovations, as for the linear filter;
* the innovations' sensitivities propagate alongside the filter, one recursion for all unknowns
  and runs: with ``J(x)`` the terms' state Jacobian on the filter's own states,
  ``dnu = e_nu - (C + D_f J(x~)) dx~``, ``dx^ = dx~ + dK nu + K dnu``,
  ``dx~[k+1] = (Phi + Gamma_f J(x^)) dx^ + dPhi x^ + dGamma_u u + dGamma_f f(x^)``: exact for the
  constant gain, no finite-difference re-filtering.

For ``f = 0`` (a term's coefficient at zero) the filter is the linear one, so refine's score test of
a state-built candidate is the sensitivity above at its null value.
"""
from __future__ import annotations

import numpy as np

from ...model.sensitivity import discretize_with_derivatives
from ...model.simulate import discretize
from ..output_error import pad
from ..prediction import state_terms


class Linearised:
    """A model's matrices with its state-built terms linearised at the operating point:
    ``A + B_f J0`` and ``C + D_f J0`` (and their constant derivatives), B and D unchanged."""

    def __init__(self, model, cols, J0):
        self.names, self.theta = model.names, model.theta
        self.n_states, self.n_inputs, self.n_outputs = model.n_states, model.n_inputs, model.n_outputs
        self.B, self.D, self.dB, self.dD = model.B, model.D, model.dB, model.dD
        self.A = model.A + model.B[:, cols] @ J0
        self.C = model.C + model.D[:, cols] @ J0
        self.dA = model.dA + model.dB[:, :, cols] @ J0
        self.dC = model.dC + model.dD[:, :, cols] @ J0


class StateTerms:
    """Mixin for :class:`~identify.estimators.filter_error.filter.FilterProblem`: the extended Kalman
    filter (module notes). ``runs``: the runs the problem is built from (the terms' channel factors).
    The subclass sets ``Filtered``, the linear method's result type (that module imports this one)."""

    def __init__(self, profile, u, z, dt, noise_states, hold, runs):
        super().__init__(profile, u, z, dt, noise_states, hold)
        state = {s: i for i, s in enumerate(profile.state_names)}
        terms = state_terms(profile)
        self.term_names = list(terms)
        self.cols = [profile.input_names.index(n) for n in terms]
        nt, L, R = len(terms), self.Z.shape[0], self.n_runs
        # per term: a constant factor per sample (the product of its channel factors) and its states
        self.const = np.ones((L, nt, R))
        self.state_factors = []
        for t, spec in enumerate(terms.values()):
            absolute = spec.get("abs", [False] * len(spec["product"]))
            factors = []
            for f, a in zip(spec["product"], absolute):
                if f in state:
                    factors.append((state[f], bool(a)))
                    continue
                c = pad(self.layout, [np.asarray(r[f], float)[:, None] for r in runs])[:, 0, :]
                self.const[:, t] *= np.abs(c) if a else c
            self.state_factors.append(factors)
        # the terms are the filter's, not the measured products the runs hold
        mu = self.U.shape[1]
        self.term_cols = self.cols + ([self.m + c for c in self.cols] if mu == 2 * self.m else [])
        self.U[:, self.term_cols] = 0.0
        mean = np.sum(self.const * self.mask[:, None, :], axis=(0, 2)) / self.N
        _, self.J0 = self.terms(np.zeros((self.n, 1)), mean[:, None])
        self.J0 = self.J0[:, :, 0]
        self.linear_at_trim = not np.any(self.J0)

    def terms(self, x, const, jacobian: bool = True):
        """``f`` (..., nt, R) and (with ``jacobian``) its state Jacobian ``J`` (..., nt, n, R) at states
        ``x`` (..., n, R), ``const`` (..., nt, R) the terms' channel factors: any number of samples at once."""
        f = const.copy()
        J = np.zeros(const.shape[:-1] + (self.n,) + const.shape[-1:]) if jacobian else None
        for t, factors in enumerate(self.state_factors):
            vals = [np.abs(x[..., i, :]) if a else x[..., i, :] for i, a in factors]
            for v in vals:
                f[..., t, :] *= v
            if not jacobian:
                continue
            for j, (i, a) in enumerate(factors):  # the product rule
                d = const[..., t, :] * (np.sign(x[..., i, :]) if a else 1.0)
                for l, v in enumerate(vals):
                    if l != j:
                        d = d * v
                J[..., t, i, :] += d
        return f, J

    def _split(self, Gamma, D):
        """``Gamma_u`` (term columns zeroed), ``Gamma_f`` (n, nt) (held over the sample), ``D_u``, ``D_f``."""
        Gu = Gamma.copy()
        Gu[..., self.term_cols] = 0.0
        Gf = Gamma[..., self.cols]
        if Gamma.shape[-1] == 2 * self.m:  # linear hold: a term held over the sample uses both columns
            Gf = Gf + Gamma[..., [self.m + c for c in self.cols]]
        Du = D.copy()
        Du[..., self.cols] = 0.0
        return Gu, Gf, Du, D[..., self.cols]

    def evaluate(self, beta, jacobian: bool = False, noise: bool = False):
        """The linear method's ``evaluate`` (same unknowns, result and errors) by the extended filter."""
        theta, f, x0, b, r = self.unpack(beta)
        model = self.model0.with_theta(theta)
        lin = Linearised(model, self.cols, self.J0)
        if jacobian:
            Phi, Gamma, dPhi, dGamma = discretize_with_derivatives(model, self.dt, self.hold)
            Phil, _, dPhil, _ = (Phi, Gamma, dPhi, dGamma) if self.linear_at_trim else \
                discretize_with_derivatives(lin, self.dt, self.hold)
        else:
            Phi, Gamma = discretize(model.A, model.B, self.dt, self.hold)
            Phil = Phi if self.linear_at_trim else discretize(lin.A, lin.B, self.dt, self.hold)[0]
        Kp, S, P = self._gain(lin.A, lin.C, f, r)
        K = np.linalg.solve(Phil, Kp)  # the filter's gain: x^ = x~ + K nu
        Dh = np.hstack([model.D, np.zeros_like(model.D)]) if self.hold == "linear" else model.D
        Gu, Gf, Du, Df = self._split(Gamma, Dh)
        with np.errstate(over="ignore", invalid="ignore"):
            x, xh, nu = self._filter(model.C, Phi, Gu, Gf, Du, Df, K, x0, b)
        if not np.all(np.isfinite(nu)):
            raise np.linalg.LinAlgError("the extended filter's prediction is not finite")
        Sinv = np.linalg.inv(S)
        cost = 0.5 * float(np.einsum("kir,ij,kjr->", nu, Sinv, nu)) + 0.5 * self.N * np.linalg.slogdet(S)[1]
        ev = self.Filtered(beta, lin,  # the linear method's result type
                            nu, x, S, P, K, cost)
        ev.Kp = Kp
        if jacobian:
            dKp, ev.dS = self._gain_derivatives(ev, Phil, Kp, dPhil, noise)
            dPhil_g = np.zeros((self.G, self.n, self.n))
            dPhil_g[:self.p] = dPhil
            dK = np.linalg.solve(Phil, dKp - dPhil_g @ K)
            ev.dnu = self._sensitivities(model, Phi, Gamma, dPhi, dGamma, Dh, K, dK, x, xh, nu)
            if not (np.all(np.isfinite(ev.dnu)) and np.all(np.isfinite(ev.dS))):
                raise np.linalg.LinAlgError("the extended filter's sensitivities are not finite")
        return ev

    def _filter(self, C, Phi, Gu, Gf, Du, Df, K, x0, b):
        """The extended filter over all runs at once: predicted and corrected states (L, n, R) and
        the innovations (L, ny, R)."""
        L, n, R = self.Z.shape[0], self.n, self.n_runs
        drive, yu, zb = Gu @ self.U, Du @ self.U, self.Z - b[None]
        x, xh, nu = np.zeros((L, n, R)), np.zeros((L, n, R)), np.zeros((L, self.ny, R))
        xk = np.array(x0, float)
        for k in range(L):
            on = self.mask[k] > 0  # padding after a shorter run's end: held at zero
            xk = np.where(on, xk, 0.0)
            x[k] = xk
            nu[k] = np.where(on, zb[k] - C @ xk - yu[k] - Df @ self.terms(xk, self.const[k], False)[0], 0.0)
            xh[k] = xk + K @ nu[k]
            xk = Phi @ xh[k] + drive[k] + Gf @ self.terms(xh[k], self.const[k], False)[0]
        return x, xh, nu

    def _sensitivities(self, model, Phi, Gamma, dPhi, dGamma, Dh, K, dK, x, xh, nu):
        """``dnu`` (L, ny, k, R) over each run's local unknowns [theta, F, R, x0, zero shifts]."""
        ft, Jt = self.terms(x, self.const)  # the terms and their Jacobians on the filter's states
        fh, Jh = self.terms(xh, self.const)
        L, n, ny, R, p, G, k = self.Z.shape[0], self.n, self.ny, self.n_runs, self.p, self.G, self.k
        mu = self.U.shape[1]
        dPhi_g, dGamma_g = np.zeros((G, n, n)), np.zeros((G, n, mu))
        dC_g, dD_g = np.zeros((G, ny, n)), np.zeros((G, ny, mu))
        dPhi_g[:p], dGamma_g[:p], dC_g[:p], dD_g[:p, :, :self.m] = dPhi, dGamma, model.dC, model.dD
        Gu, Gf, Du, Df = self._split(Gamma, Dh)
        dGu, dGf, dDu, dDf = self._split(dGamma_g, dD_g)
        # the parts that do not depend on the sensitivities themselves, all samples at once: (L, R, ., k)
        e_nu, e_h, e_x = np.zeros((L, R, ny, k)), np.zeros((L, R, n, k)), np.zeros((L, R, n, k))
        e_nu[..., :G] = -(np.einsum("gyn,lnr->lryg", dC_g, x) + np.einsum("gyu,lur->lryg", dDu, self.U)
                          + np.einsum("gyt,ltr->lryg", dDf, ft))
        e_nu[..., G + n:] = -np.eye(ny)
        e_h[..., :G] = np.einsum("gny,lyr->lrng", dK, nu)
        e_x[..., :G] = (np.einsum("gnm,lmr->lrng", dPhi_g, xh) + np.einsum("gnu,lur->lrng", dGu, self.U)
                        + np.einsum("gnt,ltr->lrng", dGf, fh))
        Ct = model.C + np.einsum("yt,ltnr->lryn", Df, Jt)  # the outputs' Jacobian on the predicted state
        Ph = Phi + np.einsum("nt,ltmr->lrnm", Gf, Jh)  # the transition's on the corrected state
        on = self.mask[:, :, None, None] > 0  # (L, R, 1, 1)
        dnu = np.zeros((L, R, ny, k))
        s = np.zeros((R, n, k))
        s[:, :, G:G + n] = np.eye(n)
        for i in range(L):
            s = np.where(on[i], s, 0.0)
            dnu[i] = np.where(on[i], e_nu[i] - Ct[i] @ s, 0.0)
            s = Ph[i] @ (s + K @ dnu[i] + e_h[i]) + e_x[i]
        return dnu.transpose(0, 2, 3, 1)


__all__ = ["StateTerms", "Linearised"]

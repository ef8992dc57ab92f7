"""The textbook's formulation of the filter-error method: R as the innovation covariance, C K <= 1.

Jategaonkar (*Flight Vehicle System Identification*, ch. 5) and Maine & Iliff estimate the
innovation covariance, not the measurement noise: for given derivatives and F it is the
innovations' own covariance ``S = 1/N sum nu nu^T`` (relaxation, between the Gauss-Newton steps),
and the gain comes from the continuous-time Riccati equation with S in the place of the
measurement noise::

    A P + P A^T - P C^T (S dt)^-1 C P + F F^T = 0,     K = P C^T S^-1,     Kp = Phi K

The unknowns that step are the derivatives, F, the initial states and zero shifts, on the
information of the innovations alone (S held within a step); after each accepted step S is
relaxed and F compensated (``F_i`` scaled by ``sqrt(sum_k C_ki^2 S_kk(new) / sum_k C_ki^2
S_kk(old))``, so that the gain stays where the step left it). The measurement noise is implied,
``R = (I - C K) S``, and a physically admissible filter needs ``diag(C K) <= 1``: a trial point
beyond it is rejected (the damping rises), and after a relaxation F is scaled down until it
holds. R can therefore never go to a floor and the filter never copies the data without saying so
(``diag_CK`` at 1): the degenerate fit of the default formulation (R on its floor on every
output, :func:`~.bounds.degenerate_fit`) does not arise, and the bounds are the Cramér-Rao ones
of the innovations' information, as the textbook prints them.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import expm, solve_continuous_are

from ...errors import EstimationError
from .filter import FilterProblem
from .solver import FilterSolver

S_CHANGE_TOL = 1e-3  # the relaxed S has settled when no variance moves by more than this (relative)
CK_MAX = 1.0  # diag(C K) at most: R = (I - C K) S >= 0


class InnovationFilterProblem(FilterProblem):
    """:class:`FilterProblem` with the gain from the continuous Riccati equation in the relaxed
    innovation covariance ``S_relaxed`` (set by :class:`InnovationSolver`; the beta's R entries
    unused, their sensitivities zero)."""

    diffuse_supported = False

    S_relaxed: np.ndarray | None = None

    def _gain(self, A, C, f, r):
        S = self.S_relaxed if self.S_relaxed is not None else np.diag(r)
        FF = np.zeros((self.n, self.n))
        FF[self.w_idx, self.w_idx] = f ** 2
        with np.errstate(over="ignore", invalid="ignore"):
            Phi = expm(A * self.dt)
        if not np.all(np.isfinite(Phi)):
            raise np.linalg.LinAlgError("the model's exponential overflows")
        P = solve_continuous_are(A.T, C.T, FF, S * self.dt)
        K = P @ np.linalg.solve(S, C).T
        return Phi @ K, S, P

    def _gain_derivatives(self, ev, Phi, Kp, dPhi, noise: bool):
        """``dKp`` (G, n, ny), ``dS`` zero (held): the derivative of the continuous Riccati solution,
        ``Acl dP + dP Acl^T = -(dA P + P dA^T - P dC^T W C P - P C^T W dC P + dFF)`` with
        ``Acl = A - P C^T W C``, ``W = (S dt)^-1``: one Lyapunov system for all unknowns."""
        theta, f, _, _, _ = self.unpack(ev.beta)
        p, nf, ny, n, G = self.p, self.nf, self.ny, self.n, self.G
        model, P, S = ev.model, ev.P, ev.S
        A, C = model.A, model.C
        W = np.linalg.inv(S * self.dt)
        dA, dC, dFF = np.zeros((G, n, n)), np.zeros((G, ny, n)), np.zeros((G, n, n))
        dA[:p], dC[:p] = model.dA, model.dC
        for i, j in enumerate(self.w_idx):
            dFF[p + i, j, j] = 2 * f[i]
        PCW = P @ C.T @ W
        rhs = dA @ P
        rhs = rhs + rhs.transpose(0, 2, 1) - P @ dC.transpose(0, 2, 1) @ W @ C @ P
        rhs = rhs - PCW @ dC @ P + dFF
        rhs = 0.5 * (rhs + rhs.transpose(0, 2, 1))
        Acl = A - PCW @ C
        eye = np.eye(n)
        lyap = np.kron(Acl, eye) + np.kron(eye, Acl)  # vec(Acl X + X Acl^T), row-major
        dP = np.linalg.solve(lyap, -rhs.reshape(G, n * n).T).T.reshape(G, n, n)
        Sinv = np.linalg.inv(S)
        K = P @ C.T @ Sinv
        dK = (dP @ C.T + P @ dC.transpose(0, 2, 1)) @ Sinv
        dPhi_g = np.zeros((G, n, n))
        dPhi_g[:p] = dPhi
        return dPhi_g @ K + Phi @ dK, np.zeros((G, ny, ny))


class InnovationSolver(FilterSolver):
    """:class:`FilterSolver` of the textbook's formulation (module notes): S relaxed after each
    step and F compensated, ``diag(C K) <= 1`` kept, converged only once S has settled."""

    def __init__(self, fem, prob: InnovationFilterProblem, beta, active, **options):
        options.pop("r_start", None)
        self.s_change = np.inf
        active = active.copy()
        active[prob.index["r"]] = False  # S is relaxed, never stepped
        super().__init__(fem, prob, beta, active, **options)
        self.active[prob.index["r"]] = False

    def _relax(self) -> None:
        """S from the current innovations, F compensated, F scaled down until C K <= 1."""
        prob = self.prob
        self.r_floor = np.zeros(prob.ny)
        if self.hold_noise:
            return
        nu = self.ev.nu
        S_new = np.einsum("kir,kjr->ij", nu, nu) / prob.N
        S_old = prob.S_relaxed if prob.S_relaxed is not None else np.diag(self.beta[prob.index["r"]])
        if not (np.all(np.isfinite(S_new)) and np.all(np.linalg.eigvalsh(S_new) > 0)):
            raise EstimationError("FEM (innovation formulation): the innovations' covariance is singular")
        C2 = self.ev.model.C ** 2
        f = prob.index["f"]
        for i, j in enumerate(prob.w_idx if prob.S_relaxed is not None else ()):  # not from the start's R
            old, new = C2[:, j] @ np.diag(S_old), C2[:, j] @ np.diag(S_new)
            if old > 0 and new > 0:
                self.beta[f[i]] *= np.sqrt(new / old)
        prob.S_relaxed = S_new
        self.beta[prob.index["r"]] = np.diag(S_new)
        self.s_change = float(np.max(np.abs(np.diag(S_new) / np.diag(S_old) - 1)))
        for _ in range(60):
            self.ev = self._evaluate(self.beta, jacobian=False)
            if self.ev is not None and self._admissible(self.ev):
                return
            self.beta[f] *= 0.8
        raise EstimationError("FEM (innovation formulation): no process noise keeps C K <= 1 at this S")

    @staticmethod
    def _admissible(ev) -> bool:
        return bool(np.all(np.diag(ev.model.C @ ev.K) <= CK_MAX + 1e-9))

    def _try(self, beta):
        ev = self._evaluate(beta, jacobian=False)
        if ev is None or not self._admissible(ev):
            return None, np.inf
        return ev, ev.cost

    def _accept(self, ev) -> bool:
        if not super()._accept(ev):
            return False
        try:
            self._relax()
        except EstimationError:
            return False
        self.ev, self._info = self._evaluate(self.beta, jacobian=True), None
        if self.ev is None:
            return False
        try:
            self._info = self.prob.information(self.ev)
        except np.linalg.LinAlgError:
            return False
        self.cost = self.ev.cost
        self.history[-1] = self.ev.cost
        return True

    def _settled(self) -> bool:
        return self.hold_noise or self.s_change < S_CHANGE_TOL

    def _flat(self, in_se: float) -> str | None:
        return super()._flat(in_se) if self._settled() else None

    def _before_test(self, g) -> None:
        """No variance to release: S is relaxed."""

    def _boundary(self) -> None:
        """F at zero held there, as the default formulation; no R floor."""
        for i, j in enumerate(self.prob.index["f"]):
            if self.active[j] and abs(self.beta[j]) < 1e-3 * self.scale0[j]:
                self.beta[j], self.active[j] = 0.0, False
                self.at_zero.append(self.prob.noise_states[i])

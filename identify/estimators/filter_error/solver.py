"""The filter-error fit on the one Levenberg-Marquardt solver (:mod:`identify.estimators.lm`):
theta, F, R, each run's initial state and zero shifts stepped together on the Fisher information;
R started by relaxation from the innovations, a variance on its floor and an F at zero held there
(the boundary of the admissible noise)."""
from __future__ import annotations

import numpy as np

from ...errors import EstimationError
from ..lm import LevenbergMarquardt
from .base import F_ZERO, R_FLOOR
from .bounds import inverse_information

FLAT_STEPS, FLAT_COST = 3, 1e-3  # converged when this many steps each lower the cost by less (log-likelihood units)


class FilterSolver(LevenbergMarquardt):
    """Levenberg-Marquardt on the Fisher information (theta, F, R, x0, zero shifts), R started by
    relaxation from the innovations (the solver's trust region and convergence test, plus a flat
    valley's: :meth:`_flat`).

    ``nuisance_only``: the derivatives held (a prediction's noise fit); ``hold_noise``: F and R
    given (a held-out prediction), never relaxed nor released; ``start_noise``: F and R of a fit
    given as the start, not relaxed, then stepped; ``r_start``: R's start where F compensation
    falls below the floor ("gain_held" or "floor", :meth:`_relax`)."""

    name = "FEM"

    def __init__(self, fem, prob, beta, active, nuisance_only: bool = False,
                 hold_noise: bool = False, start_noise: bool = False, r_start: str = "gain_held"):
        self.fem, self.prob, self.beta = fem, prob, beta.copy()
        self.max_iter, self.tol, self.progress, self.verbose = fem.max_iter, fem.tol, fem.progress, fem.verbose
        self.p = prob.p
        # parameters stepped in their logarithm (a gust's corner stays positive): the scaled system
        # is the same in either coordinate, only the step's map differs (_try) and its trust radius
        names = prob.model0.names
        self.log_idx = np.array([names.index(n) for n in fem.positive if n in names], int)
        self.hold_noise, self.start_noise, self.r_start = hold_noise, start_noise, r_start
        self.floor_bound: list[str] = []  # the outputs where F compensation fell below the floor (_relax)
        self.starts = None  # identify.estimators.filter_error.starts' record when it fitted from several starts
        self._init_iteration()
        self._info = None  # the information at the current point, formed when it was accepted
        self.ev = self._evaluate(self.beta, jacobian=False)
        if self.ev is None:
            raise EstimationError("FEM: the a priori model's Kalman filter has no steady state (the Riccati "
                                  "equation has no stabilising solution): the outputs must observe every "
                                  "unstable mode, and a mode on the stability boundary (an integrator) needs "
                                  "process noise on one of its states")
        self._relax()
        self.ev = self._evaluate(self.beta, jacobian=True)
        if self.ev is None:
            raise EstimationError("FEM: the a priori model's filter sensitivities are not finite")
        try:
            M, _ = prob.information(self.ev)
        except np.linalg.LinAlgError as e:
            raise EstimationError(f"FEM: the start's information matrix cannot be formed ({e})") from None
        # a derivative no input excites (zero sensitivity) is held, std = inf, as in ML; the
        # threshold is relative to the derivatives' own information (the variances' is of
        # another scale altogether)
        d = np.diag(M)
        th = prob.index["theta"]
        self.active = active & (d > 1e-300)
        self.active[th] &= d[th] > 1e-26 * d[th].max()
        if not nuisance_only and not self.active[:prob.p].any():
            raise EstimationError("FEM: no free parameter influences the outputs of these runs "
                                  "(are the inputs all zero?)")
        if fem.diffuse and prob.diffuse_supported:  # the globals' cost: the diffuse likelihood
            prob.diffuse = np.array([self.active[prob.local_index[r][prob.G:]] for r in range(prob.n_runs)])
            prob.stationary = [prob.profile.state_names.index(s) for s in fem.stationary_start
                               if s in prob.noise_states and self.active[prob.index["x0"][0, prob.profile.state_names.index(s)]]]
            self.ev = self._evaluate(self.beta, jacobian=True)
        ix = prob.index
        self._nuisance_step(M, prob)
        self.scale0 = np.abs(beta)
        self.at_zero = []  # states whose process noise went to the boundary F = 0
        self.moving = np.zeros(prob.n_beta, bool)  # step-bounded: theta, F and R
        self.moving[ix["theta"]] = self.moving[ix["f"]] = self.moving[ix["r"]] = True

    def _evaluate(self, beta, jacobian: bool):
        try:  # a trial point may overflow the exponential or the Riccati solver: rejected, not reported
            with np.errstate(all="ignore"):
                return self.prob.evaluate(beta, jacobian=jacobian, noise=jacobian)
        except (np.linalg.LinAlgError, ValueError):
            return None

    def _relax(self) -> None:
        """R's start: the innovations' mean squares minus the process noise's share (C P C^T).

        That share comes from the P of the current R: far too large a start R (the outputs' whole
        variance) leaves the filter almost open-loop, P of a velocity with process noise grows to
        its open-loop spread and the difference falls below zero, so the variance would start on
        its floor with ``(C K)_jj = 1``: the filter follows that output exactly, a boundary the
        steps never leave (seen: R of w at 1.6e-10 and a likelihood 6000 below the fit's at the
        same derivatives). For such an output (listed in ``floor_bound``) R comes from the
        innovation covariance with the gain held instead (``r_start="gain_held"``, Maine & Iliff's
        form, ``R = (I - C K) S_hat``, at the steady state ``I - C K = R S^-1``: a multiplicative
        step, positive while ``diag(C K) < 1``), or stays on the floor (``"floor"``, FEM's second
        start, from the process noise's side: :mod:`.starts`). With ``start_noise`` (F and R
        of a fit, given) no relaxation: the start is already consistent."""
        prob, ev = self.prob, self.ev
        ms = np.einsum("kir,kir->i", ev.nu, ev.nu) / prob.N
        self.r_floor = np.zeros(prob.ny) if self.hold_noise else R_FLOOR * np.maximum(ms, 1e-300)
        if self.hold_noise or self.start_noise:
            return
        C = ev.model.C
        compensated = ms - np.diag(C @ ev.P @ C.T)
        low = compensated <= self.r_floor
        S_hat = np.einsum("kir,kjr->ij", ev.nu, ev.nu) / prob.N
        gain_held = np.diag((np.eye(prob.ny) - C @ ev.K) @ S_hat)
        start = gain_held if self.r_start == "gain_held" else compensated
        self.beta[prob.index["r"]] = np.maximum(np.where(low, start, compensated), self.r_floor)
        self.floor_bound += [y for y, b in zip(prob.profile.outputs, low) if b and y not in self.floor_bound]
        self.ev = self._evaluate(self.beta, jacobian=False)
        if self.ev is None:
            raise EstimationError("FEM: the filter has no steady state after the noise covariance was relaxed")

    def _nuisance_step(self, M, prob) -> None:
        """Initial states and zero shifts enter the innovations linearly: one exact step fits them
        to the start model (as ML does), then R is relaxed again from the new innovations."""
        nuisance = self.active.copy()
        nuisance[:prob.G] = False
        if not nuisance.any():
            return
        _, g = prob.information(self.ev)
        saved, self.active = self.active, nuisance
        step = self._solve(M, g, 0.0)
        self.active = saved
        ev = self._evaluate(self.beta + step, jacobian=False)
        if ev is not None and ev.cost < self.ev.cost:
            self.beta, self.ev = self.beta + step, ev
            self._relax()
            self.ev = self._evaluate(self.beta, jacobian=True)

    # -- the solver's hooks (identify.estimators.lm) -------------------------------------------
    def _begin(self) -> None:
        self.cost = self.ev.cost
        self.history.append(self.ev.cost)

    def _information(self):
        return self._info if self._info is not None else self.prob.information(self.ev)

    def _solve(self, M, g, lam) -> np.ndarray:
        a = self.active
        d = np.sqrt(np.diag(M)[a])
        Ms = M[np.ix_(a, a)] / np.outer(d, d) + lam * np.eye(a.sum())
        step = np.zeros_like(g)
        try:
            step[a] = np.linalg.solve(Ms, g[a] / d) / d
        except np.linalg.LinAlgError:
            step[a] = np.linalg.lstsq(Ms, g[a] / d, rcond=None)[0] / d
        return step

    def _scale(self, M) -> np.ndarray:
        cov, _ = inverse_information(M, self.active)
        sigma = np.sqrt(np.clip(np.nan_to_num(np.diag(cov)), 0, None))  # not formed: the values' scale alone
        scale = np.maximum(np.maximum(np.abs(self.beta), self.scale0), sigma)
        scale[self.log_idx] = self.beta[self.log_idx]  # the radius in the logarithm: a factor e^0.5 at most
        return scale

    @property
    def bounded(self):
        return self.moving & self.active

    def _try(self, beta):
        r, c = self.prob.index["r"], self.log_idx
        beta = beta.copy()
        # the step d(log b) = step / b, taken in the logarithm: b exp(step / b) > 0
        beta[c] = self.beta[c] * np.exp((beta[c] - self.beta[c]) / self.beta[c])
        beta[r] = np.maximum(beta[r], self.r_floor)  # a variance stays positive
        ev = self._evaluate(beta, jacobian=False)
        return ev, (ev.cost if ev is not None else np.inf)

    def _accept(self, ev) -> bool:
        """Move to ``ev``; False (the previous point kept, the fit stopped as diverged) where its
        sensitivities or its information cannot be formed."""
        previous = self.beta, self.ev, self.active.copy(), list(self.at_zero)
        self.beta = ev.beta.copy()
        self._boundary()
        self.ev, self._info = self._evaluate(self.beta, jacobian=True), None
        if self.ev is not None:
            try:
                self._info = self.prob.information(self.ev)
            except np.linalg.LinAlgError:
                self.ev = None
        if self.ev is None:
            self.beta, self.ev, self.active, self.at_zero = previous
            return False
        self.cost = self.ev.cost
        self.history.append(self.ev.cost)
        return True

    def _flat(self, in_se: float) -> str | None:
        drops = -np.diff(self.history[-FLAT_STEPS - 1:])
        if len(drops) == FLAT_STEPS and np.all(drops < FLAT_COST):
            # a flat valley (e.g. a zero shift, an initial state and a gust's F nearly
            # collinear): the undamped step is long along an almost undetermined direction, yet
            # no step changes the likelihood by anything a test could see
            valley = "; a flat valley along a nearly undetermined direction" if in_se >= 0.1 else ""
            return (f"cost: the last {FLAT_STEPS} steps lowered the negative log-likelihood by less "
                    f"than {FLAT_COST:g} each (the next Gauss-Newton step: {in_se:.2g} standard "
                    f"errors{valley})")
        return None

    def _before_test(self, g) -> None:
        """A variance pushed onto its floor (:meth:`_boundary`) is released when the gradient
        points back inside (the likelihood rises with the variance): an active set, so that an
        early, wild step cannot pin a variance to its floor."""
        if self.hold_noise:
            return
        r = self.prob.index["r"]
        self.active[r] |= g[r] > 0

    def _boundary(self) -> None:
        """An F that falls to a negligible share of its start is at the boundary F = 0 (calm air
        on that state): its information vanishes as F^2 there, so it is held at 0, not stepped.
        Likewise a measurement variance the step pushes onto its floor (R_FLOOR)."""
        for i, j in enumerate(self.prob.index["f"]):
            if self.active[j] and abs(self.beta[j]) < F_ZERO * self.scale0[j]:
                self.beta[j], self.active[j] = 0.0, False
                self.at_zero.append(self.prob.noise_states[i])
        r = self.prob.index["r"]  # a variance pushed onto its floor is held there (until _before_test releases it)
        self.active[r] &= self.beta[r] > (1 + 1e-9) * self.r_floor

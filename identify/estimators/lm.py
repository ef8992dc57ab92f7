"""The one Levenberg-Marquardt solver of the likelihood estimators (ML, FEM, compat's kinematics).

Trust-region control (Madsen, Nielsen & Tingleff's LM, on Marquardt's scaled system): the
damping starts at ``INITIAL_DAMPING`` times the largest diagonal of the scaled information
matrix; a trial step is taken only when the ratio of the actual to the predicted (quadratic
model) decrease of the cost exceeds ``MIN_GAIN_RATIO``, and the damping then falls (good
agreement) or rises (poor); no step may move an unknown by more than a trust radius times its
scale (``max(|value|, |start|, sigma)``, sigma its white Cramér-Rao bound at the current point),
so a far a priori model cannot throw the iteration into another basin. The radius starts at
``MAX_REL_STEP``, halves after a step with a gain ratio below 0.25 and doubles back (never beyond
``MAX_REL_STEP``) after one that reached it with a ratio above 0.75. (Letting it grow further was
tried: on a noise-free S 61 case with one derivative 60 x off it took 8-fold steps into a worse
basin and did not converge in 200 iterations; capped, 31.)

Convergence is judged on the undamped Gauss-Newton step: it must move no unknown by more than
``tol_se`` (``STEP_TOL_SE`` unless the problem sets its own) of its standard error (its length
in the information metric bounds every unknown's move, ``|step_i| / sigma_i <= sqrt(step^T M
step)``, Cauchy-Schwarz), or no parameter
by more than ``tol`` relative. A problem may add its own test (ML: the relaxed noise covariance
settled first; FEM: a flat valley). Anything else is not convergence: ``max_iter`` reached, no
step lowering the cost while the gradient still predicts a decrease ("stalled"), or a point
whose sensitivities are not finite ("diverged"). The reason is ``stop``, one line, recorded in
every result's ``info["stop"]``.

A problem is a subclass that supplies the information and the trial evaluations (the hooks
below); this module holds the iteration, the trust region and the tests.
"""
from __future__ import annotations

import math

import numpy as np

MAX_DAMPING = 1e10
INITIAL_DAMPING = 1e-3  # LM's tau: the first damping, relative to the scaled information's diagonal
MIN_GAIN_RATIO = 1e-3  # a step is taken when it achieves this share of its predicted decrease
MAX_REL_STEP = 0.5  # no step moves an unknown by more than this share of its scale
STEP_TOL_SE = 1e-3  # converged: the next Gauss-Newton step moves no unknown by this many std errors
STALL_TOL_SE = 1e-2  # ... or no step lowers the cost and the next would move them by less than this


class LevenbergMarquardt:
    """The iteration. Settings (set by the subclass): ``name`` (for messages), ``max_iter``,
    ``tol``, ``progress`` (callable ``(iteration, cost, theta)`` or None), ``verbose``; state:
    ``beta`` (all unknowns), ``active`` (those that move), ``p`` (the leading parameters the
    relative-step test reads), ``cost`` (what a trial must lower).

    Hooks: :meth:`_information` ``(M, g)`` at the current point; :meth:`_solve` the damped
    normal equations; :meth:`_predicted` the quadratic model's decrease; :meth:`_scale` and
    :attr:`bounded` the trust region's scale and the unknowns it bounds; :meth:`_try` a trial
    point ``(evaluation, cost)``; :meth:`_accept` the move (False: its sensitivities failed);
    :meth:`_begin`, :meth:`_settled`, :meth:`_flat`, :meth:`_before_test`, :meth:`_finish`.

    After :meth:`run`: ``converged``, ``stop`` (the reason, one line), ``iterations``, ``history``
    (negative log-likelihood per iteration), ``step_history`` (undamped step in std errors),
    ``lam``, ``rejected``, ``max_rel_step``, ``M`` (the information at the end)."""

    name = "LM"
    max_iter, tol, progress, verbose = 100, 1e-8, None, False
    tol_se = STEP_TOL_SE  # converged: the next step under this many standard errors

    def _init_iteration(self) -> None:
        self.history, self.step_history = [], []
        self.iterations, self.converged, self.stop, self.lam, self.rejected = 0, False, "max_iter", 0.0, 0
        self.max_rel_step, self.radius = 0.0, MAX_REL_STEP

    # -- hooks ---------------------------------------------------------------------------------
    def _information(self):
        raise NotImplementedError

    def _solve(self, M, g, lam: float) -> np.ndarray:
        raise NotImplementedError

    def _predicted(self, M, g, step) -> float:
        """Decrease of the cost the Gauss-Newton (quadratic) model predicts for ``step``."""
        return float(g @ step - 0.5 * step @ M @ step)

    def _scale(self, M) -> np.ndarray:
        raise NotImplementedError

    @property
    def bounded(self):
        """The unknowns the trust radius bounds (an index into ``beta`` and the scale)."""
        return slice(0, self.p)

    def _try(self, beta):
        """``(evaluation, cost)`` at a trial point; evaluation None where it fails."""
        raise NotImplementedError

    def _accept(self, ev) -> bool:
        raise NotImplementedError

    def _begin(self) -> None:
        """Before the first step (the exact step of the nuisance, the first record)."""

    def _settled(self) -> bool:
        """False while a quantity outside the steps (a relaxed noise covariance) still moves."""
        return True

    def _flat(self, in_se: float) -> str | None:
        """A problem's own convergence test after the step tests (None: not converged)."""
        return None

    def _before_test(self, g) -> None:
        """Before each convergence test (FEM: a variance released from its floor)."""

    def _finish(self) -> None:
        """After the iteration (ML: why it did not converge)."""

    # -- the iteration -------------------------------------------------------------------------
    def _step_length(self, M, g) -> float:
        """Length of the undamped Gauss-Newton step in standard errors."""
        return math.sqrt(max(float(g @ self._solve(M, g, 0.0)), 0.0))

    def _converged(self, M, g) -> str | None:
        """The reason the undamped Gauss-Newton step says we are at the minimum, or None."""
        if not self._settled():
            return None
        step = self._solve(M, g, 0.0)
        in_se = math.sqrt(max(float(g @ step), 0.0))
        self.step_history.append(in_se)
        th = self.active[:self.p]  # none (a fit of the nuisance alone): in_se decides
        rel = float(np.max(np.abs(step[:self.p][th]) / (np.abs(self.beta[:self.p][th]) + 1e-6))) if th.any() \
            else np.inf
        if in_se < self.tol_se:
            return f"gradient: the next step is {in_se:.1e} standard errors"
        if rel < self.tol:
            return f"step: the next step is {rel:.1e} of the parameters"
        return self._flat(in_se)

    def run(self) -> None:
        self._begin()
        M, g = self._information()
        self.lam = INITIAL_DAMPING  # the scaled information has unit diagonal: tau times its largest element
        while True:
            self._before_test(g)
            reason = self._converged(M, g)
            if reason:
                self.converged, self.stop = True, reason
                break
            if self.iterations >= self.max_iter:
                self.stop = f"max_iter: {self.max_iter} iterations without convergence"
                break
            found = self._trial(M, g)
            self.iterations += 1
            if found is None:
                # no damped step lowers the cost: at the minimum to the cost's numerical precision,
                # unless the undamped step would still move the estimates by a noticeable share of
                # their standard errors (a Jacobian that disagrees with the cost)
                in_se = self._step_length(M, g)
                if in_se < STALL_TOL_SE:
                    self.converged = True
                    self.stop = (f"gradient: no step lowers the cost (numerical precision); the next would be "
                                 f"{in_se:.1e} standard errors")
                else:
                    self.stop = f"stalled: no step lowers the cost although {in_se:.2g} standard errors remain"
                break
            ev, rho, rel = found
            if not self._accept(ev):
                self.stop = "diverged: the sensitivities are not finite at the last step"
                break
            M, g = self._information()
            if self.progress is not None:
                self.progress(self.iterations, self.history[-1], self.beta[:self.p].copy())
            if self.verbose:
                print(f"{self.name} iteration {self.iterations:3d}: -log likelihood {self.history[-1]:.10g}  "
                      f"step {rel:.2e}  damping {self.lam:.1e}  gain ratio {rho:.2f}")
        self.M = M
        self._finish()

    def _trial(self, M, g):
        """The damped step, shortened to the trust radius, that lowers the cost by at least
        ``MIN_GAIN_RATIO`` of the decrease predicted for it: ``(evaluation, gain ratio, relative
        step)`` with ``beta`` moved, or None when the damping limit is reached first (the damping
        ``lam`` rises along the way, and falls or rises after the step by its gain ratio)."""
        nu, cost = 2.0, self.cost
        scale = self._scale(M)
        mv = self.bounded
        while self.lam <= MAX_DAMPING:
            step = self._solve(M, g, self.lam)
            rel = float(np.max(np.abs(step[mv]) / scale[mv], initial=0.0))
            shorten = min(1.0, self.radius / max(rel, 1e-300))
            step *= shorten
            pred = self._predicted(M, g, step)
            if pred > 0:
                ev, c = self._try(self.beta + step)
                if ev is not None and np.isfinite(c) and cost - c > MIN_GAIN_RATIO * pred:
                    rho = (cost - c) / pred
                    self.lam *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
                    taken = rel * shorten
                    self.max_rel_step = max(self.max_rel_step, taken)
                    if rho > 0.75 and taken >= 0.99 * self.radius:
                        self.radius = min(2 * self.radius, MAX_REL_STEP)
                    elif rho < 0.25:
                        self.radius = max(0.5 * self.radius, 1e-6)
                    return ev, rho, taken
                self.rejected += 1
            self.lam, nu = max(self.lam, INITIAL_DAMPING) * nu, 2 * nu
        return None

"""Output-error maximum likelihood (ML): the paper's modified Newton-Raphson method.

The model's outputs, simulated from the measured inputs, are fitted to the measured outputs by
minimising the negative log-likelihood for white Gaussian measurement noise of covariance R::

    J(theta, x0, b) = 1/2 sum_k e_k^T R^-1 e_k + N/2 log det R,   e_k = z_k - y_k

Newton-Raphson with the Gauss-Newton approximation of the Hessian (``M = J^T R^-1 J``, the Fisher
information) moves the derivatives ``theta``, the initial states ``x0`` and the output zero shifts
``b`` together under Levenberg-Marquardt trust-region control (:mod:`.lm`, :class:`OutputErrorSolver`). R is
estimated by *relaxation*: after each step, R = diag(mean residual^2), the R that minimises J for
the current residuals. The Cramér-Rao bounds are the square roots of the diagonal of M^-1 (the
full matrix, initial states and zero shifts included as nuisance parameters). M is never formed
whole: a segment's initial states couple only to its own segment, and the normal equations are
solved by eliminating them segment by segment (Schur complement,
:mod:`identify.estimators.information`), so an hour in 3 s segments (~9000 unknowns) costs
memory and time in proportion to the record, not to its square or cube.

Coloured residuals: M^-1 holds only for white residuals. Flight data are never quite white
(smoothing, unmodelled dynamics, turbulence), and the bounds then come out too small (2.3x in the
BO 105 study with smoothed data). With ``coloured=True`` (default) the standard errors follow
Morelli & Klein's correction for coloured residuals in output error::

    Cov = M^-1 [ sum over outputs y and segments s of J_ys^T T_y J_ys ] M^-1

``J_ys`` the whitened sensitivities of output y over segment s, ``T_y`` the Toeplitz matrix of the
autocorrelation of output y's whitened noise in the run of segment s, pooled over that run's
segments (segments and outputs taken as independent of each other; each run its own, as runs
flown on different axes leave residuals of different size: with one pooled over an S 61 fit of
one run per cyclic the bounds were 0.3-1.6x the spread over realisations, with one per run
0.7-1.5x, tests/identify/estimators/test_ml_runs_noise.py), estimated from the residuals' autocorrelation with
the part the fit itself removes added back (it matters for short segments with many unknowns;
:meth:`identify.estimators.output_error.OutputError.coloured_information`). Computed once, after convergence, by
FFT (:mod:`identify.estimators.colour`, as the equation-error estimators do); the iteration itself is the
same. For white residuals ``T_y`` ~ I and both bounds agree (within the estimation scatter of the
autocorrelation, a few %); both are reported (``info["std_white"]``, ``info["std_coloured"]``).
``coloured=False`` skips the correction (it costs about as much as the fit: the fixed point for
the noise autocorrelation takes ~4 passes over the sensitivities, each a few FFTs per segment).

Unstable models (most helicopters) diverge when simulated over a long run, and the cost of an
unstable model over 20 s is far from quadratic in its parameters. ML then uses multiple shooting
(:mod:`identify.estimators.output_error`): each run is cut into segments of a few seconds, each simulated from
its own estimated initial state. This is chosen automatically from the a priori model's modes.
"""
from __future__ import annotations

import math
import time as _time
import warnings
from pathlib import Path

import numpy as np

from ..data.runs import Run
from ..errors import ConvergenceWarning, EstimationError, SimulationError
from ..model.linear import LinearModel
from ..model.profile import Profile
from .advice import colour_advice, follows_inputs
from .base import Estimator
from .lm import MAX_REL_STEP, LevenbergMarquardt  # noqa: F401  (MAX_REL_STEP: the step bound ML reports)
from .output_error import OutputError, auto_segment
from .prior import posterior, prior_term
from .result import IdentificationResult, fit_metrics
from .whiteness import whiteness

R_CHANGE_TOL = 1e-3  # relaxation has settled when no variance moves by more than this (relative)
# a fit whose estimate and likelihood alone are used (refine's delay search): the next step under
# this many standard errors (the likelihood then within 1e-4 of its optimum) and R settled to this
# (relative); the full tolerances cost as many iterations again (steps and R converge together,
# linearly, by about a third per iteration where model errors dominate the residuals)
SEARCH_TOL = 1e-2
RELAX_FLOOR = 1e-20  # smallest relaxed variance, relative to the output's mean square


class ML(Estimator):
    """Output-error maximum-likelihood estimator.

    ``segment``: None (automatic: plain output error for a stable model, multiple shooting for an
    unstable one), a segment length in s, or ``math.inf``/``"plain"`` (one segment per run).
    ``max_iter``: iterations at most (not converged by then: a :class:`ConvergenceWarning`,
    ``info["converged"]`` False with the reason in ``info["stop"]``); convergence when the next
    Gauss-Newton step is under 1e-3 standard errors, or under ``tol`` relative to the parameters.
    ``estimate_x0``/``estimate_bias``: estimate initial states (of every segment) and per-run
    output zero shifts; ``x0`` ``{state: value}`` initial states held at known values in every run
    (with the profile's ``[initial_state]``; later multiple-shooting segments keep theirs free),
    and the profile's ``[zero_shifts]`` say which outputs have none or a known one. ``noise_cov``:
    ``"relax"`` (estimate R) or the measurement-noise
    covariance, (ny,) variances or (ny, ny), in output units squared; ``relax_from`` (ny,)
    variances R's relaxation starts from (a neighbouring model's fit: refine's searches), else
    from the residuals of the a priori model. ``tol_se``: converged once the relaxed variances
    move by less than ``tol_se`` (relative) and the next step is under ``tol_se`` standard errors
    (default ``R_CHANGE_TOL``; ``SEARCH_TOL`` in refine's nested fits without bounds, whose
    estimate and likelihood alone are used).
    ``advice``: the colour note ``info["estimator_advice"]`` when the residuals are strongly
    coloured (its cause test fits ~100 least-squares FIRs; refine skips it for its candidates' fits).
    ``progress``: callable ``(iteration, cost, theta)`` called after each iteration with the
    negative log-likelihood ``cost`` (constant terms dropped); ``verbose`` prints the same.

    After ``fit(runs)``: ``result_`` (an IdentificationResult with per-run ``time``,
    ``measured``, ``modelled``; with multiple shooting the modelled outputs restart at every
    segment's estimated initial state), ``covariance_`` (p, p) Cramér-Rao covariance of theta,
    ``problem_`` (the :class:`~identify.estimators.output_error.OutputError` solved) and ``beta_`` (all unknowns).
    ``result_.info`` holds the form used, segments with their initial states, per-run zero shifts,
    the noise covariance, iterations, convergence and the cost history. A parameter that no input
    excites (zero sensitivity, e.g. the derivatives of a cyclic not flown) stays at its a priori
    value with std = inf and is listed in ``info["not_excited"]``.

    ``coloured``: standard errors (``result_.std``, ``covariance_``, the x0 and zero-shift stds)
    corrected for coloured residuals (Morelli & Klein, see the module notes; default True) or the
    plain Cramér-Rao bounds ``M^-1`` (False, which skips the correction's cost). With True both
    are in ``info["std_coloured"]`` and ``info["std_white"]`` (theta only);
    ``info["noise_autocorrelation"]`` (L, ny) is the whitened noise autocorrelation per output
    behind the correction (the runs' averaged, weighted by their samples), lag 0 first.
    """

    method = "ml"
    weighs_prior = True  # the prior's residuals in the cost (identify.estimators.prior)
    simulates_state_terms = True  # output error: a term built from states comes from the simulated ones
    progress_quantity = "cost"

    def __init__(self, profile: Profile | str | Path, *, segment: float | str | None = None,
                 max_iter: int = 100, tol: float = 1e-8, estimate_x0: bool = True,
                 estimate_bias: bool = True, noise_cov="relax", coloured: bool = True, progress=None,
                 verbose: bool = False, x0: dict | None = None, advice: bool = True, relax_from=None,
                 tol_se: float = R_CHANGE_TOL):
        super().__init__(profile)
        self.segment, self.max_iter, self.tol, self.tol_se = segment, max_iter, tol, tol_se
        self.relax_from = relax_from
        self.estimate_x0, self.estimate_bias = estimate_x0, estimate_bias
        self.noise_cov, self.coloured = noise_cov, coloured
        self.progress, self.verbose, self.x0, self.advice = progress, verbose, x0, advice
        self.covariance_ = self.problem_ = self.beta_ = None

    def nested(self, profile, *, zero_shifts: bool = True, segment: float = math.inf,
               bounds: bool = True, advice: bool = True, start=None) -> "ML":
        """Refine's nested fit: the loop's zero shifts and segments (so that likelihoods before and
        after an added effect compare); without ``bounds`` the coloured-residual correction is
        skipped and the fit converges to ``SEARCH_TOL`` (only its estimate and likelihood are
        used), without ``advice`` the colour note (a candidate's fit needs neither); ``start`` the
        result of a neighbouring model's fit (a search's), whose relaxed R starts this one's."""
        noise = (start.info.get("noise_cov") if start is not None and isinstance(self.noise_cov, str) else None)
        return self.clone(profile, estimate_bias=zero_shifts, segment=segment, coloured=self.coloured and bounds,
                          advice=self.advice and advice, tol_se=self.tol_se if bounds else max(self.tol_se, SEARCH_TOL),
                          relax_from=self.relax_from if noise is None else np.diag(noise).copy())

    def prediction_segment(self, model: LinearModel, duration: float) -> float:
        """Its own ``segment`` if given, else the automatic choice for ``model`` (multiple shooting
        for an unstable one)."""
        seg = self.segment if self.segment is not None else auto_segment(model, duration)
        return math.inf if seg == "plain" else float(seg)

    def _validate(self) -> None:
        super()._validate()
        self.segment_ = _check_segment(self.segment)
        if not (isinstance(self.max_iter, (int, np.integer)) and self.max_iter >= 1):
            raise EstimationError(f"ML: max_iter must be a positive integer, got {self.max_iter!r}")
        for name in ("tol", "tol_se"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise EstimationError(f"ML: {name} must be positive, got {getattr(self, name)!r}")
        self.relax_from_ = None if self.relax_from is None else np.asarray(self.relax_from, float).ravel()
        if self.relax_from_ is not None and (len(self.relax_from_) != len(self.profile_.outputs)
                                             or not np.all(np.isfinite(self.relax_from_) & (self.relax_from_ > 0))):
            raise EstimationError(f"ML: relax_from must be {len(self.profile_.outputs)} positive variances, one per "
                                  f"output")
        self.noise_cov_ = _check_noise_cov(self.noise_cov, len(self.profile_.outputs))

    # -- fitting ---------------------------------------------------------------------------------
    def _fit(self, runs: list[Run]) -> IdentificationResult:
        started = _time.perf_counter()
        p = self.profile_
        dt = common_dt(runs)
        u = [finite_channels(run, p.input_names) for run in runs]
        z = [finite_channels(run, list(p.outputs)) for run in runs]
        model0 = LinearModel(p)
        segment = self.segment_
        if segment is None:
            segment = auto_segment(model0, max(run.duration for run in runs))
        if not self.estimate_x0 and math.isfinite(segment) and any(r.duration > segment for r in runs):
            raise EstimationError("ML: multiple shooting needs the segment initial states: "
                                  "use estimate_x0=True or segment='plain'")
        if p.input_hold != "held" or any(r.meta.get("input_hold", "held") != "held" for r in runs):
            raise EstimationError("ML: inputs interpolated linearly between samples (input_hold = 'linear') "
                                  "are supported by --method fem only; ML holds them")
        prob = OutputError(p, u, z, dt, segment, bool(self.estimate_x0), bool(self.estimate_bias))
        prob.prior = prior_term(p)  # None without one: the data alone
        beta = prob.initial_beta(model0.theta)
        held = _held(prob, beta, {**p.initial_state, **(self.x0 or {})})
        form = "plain" if prob.layout.n_segments == len(runs) else "multiple shooting"
        try:
            ev = prob.evaluate(beta)
        except SimulationError as exc:
            hint = "shorter segments (ML(segment=<s>))" if form == "multiple shooting" \
                else "multiple shooting (ML(segment=<s>))"
            raise EstimationError(f"ML ({form}): the a priori model diverges: {exc}; "
                                  f"use {hint} or better a priori values") from None
        solver = OutputErrorSolver(self, prob, ev, z)
        solver.active &= ~held
        solver.run()
        if not solver.converged:
            warnings.warn(f"ML ({form}) did not converge: {solver.stop}; the estimates are not final "
                          f"(raise max_iter, or start from better a priori values)", ConvergenceWarning,
                          stacklevel=3)
        self.problem_, self.beta_ = prob, solver.beta
        return self._result(runs, prob, solver, form, segment, _time.perf_counter() - started, u)

    def _result(self, runs, prob: OutputError, sv: "OutputErrorSolver", form: str, segment: float,
                wall: float, u: list[np.ndarray]) -> IdentificationResult:
        p, P = self.profile_, prob.p
        cov_white, ill = sv.M.covariance()  # blocks: never (n_beta, n_beta) for a long record
        std_white, std_col, acf, passes = _std(cov_white, sv.active), None, None, 0
        cov, std = cov_white, std_white
        if self.coloured:  # once, after convergence
            cov, acf, passes = prob.coloured_information(sv.ev, sv.Wh, sv.M)
            std = std_col = _std(cov, sv.active)
        self.covariance_ = cov.gg[:P, :P].copy()
        theta, x0, b = prob.unpack(sv.beta)
        prior = None
        if prob.prior is not None:  # the information holds the prior's: A = (M_d + P^-1)^-1
            A = cov_white.gg[:P, :P]
            D = self.covariance_ if self.coloured else A - (A * prob.prior.precision) @ A
            self.covariance_, prior = posterior(prob.prior, theta, A, D, sv.active[:P])
            std = std.copy()
            std[:P] = np.sqrt(np.clip(np.diag(self.covariance_), 0, None))
        _, x0_std, b_std = prob.unpack(std)
        lay = prob.layout
        measured = [zr.copy() for zr in prob.per_run(prob.Z)]
        modelled = prob.per_run(sv.ev.y)
        residuals = [z - y for z, y in zip(measured, modelled)]
        segments = [{"run": int(lay.run[s]), "t_start": float(runs[lay.run[s]].time[lay.start[s]]),
                     "samples": int(lay.length[s]),
                     "x0": dict(zip(p.state_names, map(float, x0[:, s]))),
                     "x0_std": dict(zip(p.state_names, map(float, x0_std[:, s]))) if self.estimate_x0 else None}
                    for s in range(lay.n_segments)]
        first = [next(s for s in segments if s["run"] == r) for r in range(len(runs))]
        R = np.linalg.inv(sv.Wh.T @ sv.Wh)
        info = {
            "form": form,
            "segment_length": segment if math.isfinite(segment) else None,
            "n_segments": lay.n_segments,
            "iterations": sv.iterations,
            "converged": sv.converged,
            "stop": sv.stop,
            "cost": sv.history,  # negative log-likelihood per iteration
            "weighted_cost": sv.wls_history,  # 1/2 sum e^T R^-1 e with that iteration's R
            "log_det_R": sv.log_det_history,
            "damping": sv.lam,
            "rejected_steps": sv.rejected,
            "max_relative_step": sv.max_rel_step,  # largest step taken, share of the parameter scale
            "gauss_newton_step_se": sv.step_history,  # length of the next undamped step, std errors
            "modelled": "simulated over each whole run" if form == "plain" else
            f"restarted at every multiple-shooting segment (every {segment:.3g} s) from its estimated initial state",
            "initial_states": [s["x0"] for s in first],
            "segments": segments,
            "zero_shifts": [dict(zip(p.outputs, map(float, b[:, r]))) for r in range(len(runs))],
            "zero_shift_std": [dict(zip(p.outputs, map(float, b_std[:, r]))) for r in range(len(runs))]
            if self.estimate_bias else None,
            "noise_cov": R,
            "noise_std": dict(zip(p.outputs, map(float, np.sqrt(np.diag(R))))),
            "noise_cov_estimated": self.noise_cov_ is None,
            "not_excited": [n for n, a in zip(prob.model0.names, sv.active[:P]) if not a],
            "ill_conditioned": ill,
            "standard_errors": "coloured-residual correction (Morelli & Klein)" if self.coloured
            else "white residuals (Cramér-Rao)",
            "std_white": std_white[:P],
            "std_coloured": None if std_col is None else std_col[:P],
            "noise_autocorrelation": acf,
            "colour_passes": passes,
            "whiteness": whiteness(residuals, list(p.outputs)),
            "estimator_advice": None if not self.advice else colour_advice(
                std_white[:P], None if std_col is None else std_col[:P],
                lambda: follows_inputs(residuals, u, prob.dt, list(p.outputs))),
            "wall_time": wall,
        }
        if prior is not None:
            info["prior"] = prior
        return IdentificationResult(
            method=self.method, profile=p, theta=theta.copy(), std=std[:P], runs=[r.source for r in runs],
            covariance=self.covariance_.copy(),
            fit=fit_metrics(list(p.outputs), measured, modelled), info=info,
            time=[r.time.copy() for r in runs], measured=measured, modelled=modelled)


class OutputErrorSolver(LevenbergMarquardt):
    """The output-error problem on the one Levenberg-Marquardt solver (:mod:`.lm`: trust region,
    convergence test, stop reasons), with noise-covariance relaxation: after each step R =
    diag(mean residual^2); converged only once R has settled (no variance moving by more than
    ``tol_se``, relative) and the undamped step is under ``tol_se`` standard errors.

    ``ml`` supplies the settings (``noise_cov_``, ``relax_from_``, ``max_iter``, ``tol``,
    ``tol_se``, ``progress``, ``verbose``); ``prob`` any problem on the engine's seam (:mod:`.output_error`; compat's
    kinematics too).
    """

    name = "ML"
    requires_parameters = True  # ML: a fit of initial states alone is an error (compat's first fit is one)

    def __init__(self, ml: ML, prob: OutputError, ev, z):
        self.ml, self.prob, self.ev, self.beta = ml, prob, ev, ev.beta.copy()
        self.max_iter, self.tol, self.progress, self.verbose = ml.max_iter, ml.tol, ml.progress, ml.verbose
        self.p, self.tol_se = prob.p, ml.tol_se
        self.relax = ml.noise_cov_ is None
        self.ms = np.array([np.mean(zr ** 2, axis=0) for zr in z]).mean(axis=0)
        self.warm = ml.relax_from_ if self.relax else None  # R to start from, not the a priori residuals'
        self.Wh = self._relaxed_weighting(self.warm) if self.relax else _whitening(ml.noise_cov_)
        self._init_iteration()
        self.wls_history, self.log_det_history = [], []
        self.r_change = np.inf
        M, _ = prob.information(ev, self.Wh)
        # a parameter no input excites has no influence at all: hold it, report std = inf
        self.active = M.active
        if self.requires_parameters and not self.active[:prob.p].any():
            raise EstimationError("ML: no free parameter influences the outputs of these runs "
                                  "(are the inputs all zero?)")
        self.M = M
        self.theta0 = np.abs(ev.beta[:prob.p])

    def _relaxed_weighting(self, r=None) -> np.ndarray:
        """The weighting of R = diag(mean residual^2) (or of the variances ``r``)."""
        r = np.sum(self.ev.e ** 2, axis=(0, 2)) / self.prob.mask.sum() if r is None else r
        r = np.maximum(r, RELAX_FLOOR * np.maximum(self.ms, 1e-300))
        self._r = r
        return np.diag(1 / np.sqrt(r))

    def _cost(self, ev) -> float:
        return self.prob.cost(ev, self.Wh)

    # -- the solver's hooks (identify.estimators.lm) -------------------------------------------
    def _information(self):
        return self.prob.information(self.ev, self.Wh, self.active)

    def _solve(self, M, g, lam) -> np.ndarray:
        """Solve ``(Ms + lam I) s = g / d`` on the active unknowns, Ms = M scaled to unit
        diagonal (Marquardt: damping on the scaled diagonal), by block elimination of the
        segments' initial states (:class:`~identify.estimators.information.BlockInformation`)."""
        return M.solve(g, lam, self.active)

    def _predicted(self, M, g, step) -> float:
        return float(g @ step - 0.5 * step @ M.matvec(step))

    def _try(self, beta):
        """Residuals at a trial point (no sensitivities: most trials of a hard start are rejected,
        and a long record holds one set of sensitivities at a time); :meth:`_accept` takes those
        of the one kept."""
        try:
            ev = self.prob.evaluate(beta, jacobian=False)
        except SimulationError:
            return None, np.inf
        c = self._cost(ev)
        return ev, (c if np.isfinite(c) else np.inf)

    def _scale(self, M) -> np.ndarray:
        """Scale of each parameter for the step bound: max(|theta|, |theta a priori|, sigma),
        sigma its white Cramér-Rao bound at the current point (marginal: correlated parameters may
        move together by far more than one's bound with the others held)."""
        P = self.prob.p
        cov, _ = M.covariance()
        sigma = np.sqrt(np.clip(cov.diag()[:P], 0, None))
        return np.maximum(np.maximum(np.abs(self.beta[:P]), self.theta0), sigma)

    def _begin(self) -> None:
        """Initial states and zero shifts enter linearly: one exact step fits them to the a priori model."""
        P = self.prob.p
        nuisance = self.active.copy()
        nuisance[:P] = False
        if nuisance.any():
            M, g = self.prob.information(self.ev, self.Wh, self.active)
            ev, c = self._try(self.beta + M.solve(g, 0.0, nuisance))
            if ev is not None and c < self._cost(self.ev):
                self._move(ev)
            if self.relax and self.warm is None:
                self.Wh = self._relaxed_weighting()
        self.cost = self._cost(self.ev)
        self._record(self.cost)

    def _settled(self) -> bool:
        return not (self.relax and self.r_change >= self.tol_se)

    def _accept(self, ev) -> bool:
        self._move(ev)
        self.r_change = 0.0
        if self.relax:
            r_old = self._r
            self.Wh = self._relaxed_weighting()
            self.r_change = float(np.max(np.abs(self._r / r_old - 1)))
        self.cost = self._cost(self.ev)
        self._record(self.cost)
        return True

    def _finish(self) -> None:
        if not self.converged:
            self.stop += self._drifting(self.M)

    def _drifting(self, M) -> str:
        """When not converged: the parameters the runs cannot determine (white std error over
        10 x the estimate), along which the likelihood may keep rising (an estimate running off to
        infinity, e.g. a rotor time constant that the data cannot tell from instantaneous)."""
        P = self.prob.p
        cov, _ = M.covariance()
        rel = np.sqrt(np.clip(cov.diag()[:P], 0, None)) / np.maximum(np.abs(self.beta[:P]), 1e-300)
        bad = [self.prob.names()[i] for i in np.argsort(-rel)[:4] if rel[i] > 10]
        return (f"; not determined by these runs (std error > 10 x estimate), the likelihood may rise "
                f"without bound along them: {', '.join(bad)}" if bad else "")

    def _move(self, ev) -> None:
        """Move to the trial point ``ev``, with its sensitivities."""
        self.ev = None  # the old sensitivities go before the new ones are computed
        self.ev = self.prob.evaluate(ev.beta)
        self.beta = ev.beta.copy()

    def _record(self, cost: float) -> None:
        """Log the weighted cost, log det R and the negative log-likelihood they make."""
        log_det = float(-2 * np.sum(np.log(np.abs(np.diag(self.Wh)))))  # Wh is triangular
        self.wls_history.append(float(cost))
        self.log_det_history.append(log_det)
        self.history.append(float(cost) + 0.5 * float(self.prob.mask.sum()) * log_det)



# -- helpers ---------------------------------------------------------------------------------------
def _held(prob: OutputError, beta: np.ndarray, x0_fixed: dict) -> np.ndarray:
    """Unknowns the profile fixes, set in ``beta``: each run's initial state (``[initial_state]``,
    the ``x0`` option; the first segment of the run) and the zero shifts ``[zero_shifts]`` holds."""
    p, held = prob.profile, np.zeros(prob.n_beta, bool)
    bad = [s for s in x0_fixed if s not in p.states]
    if bad:
        raise EstimationError(f"ML: x0: {', '.join(bad)} not a state of the profile (states: {', '.join(p.states)})")
    index = np.array(prob.local_index)
    first = [int(np.flatnonzero(prob.layout.run == r)[0]) for r in range(prob.n_runs)]
    for s, value in x0_fixed.items():
        col = index[first, prob.p + p.state_names.index(s)]
        if prob.estimate_x0:
            beta[col], held[col] = value, True
        prob.x0_held[p.state_names.index(s), first] = value
    for j, y in enumerate(p.outputs):
        value, estimated = p.zero_shift(y)
        col = index[first, prob.p + prob.n + j]
        if prob.estimate_bias:
            beta[col], held[col] = value, not estimated
        prob.b_held[j] = value
    return held


def _std(cov, active: np.ndarray) -> np.ndarray:
    """Standard errors from a :class:`~identify.estimators.information.BlockCovariance`; inf where held,
    NaN where the variance is not positive (not determined: never a printed 0)."""
    var = cov.diag()
    std = np.full(var.shape, np.nan)
    np.sqrt(var, out=std, where=var > 0)
    std[~active] = np.inf
    return std


def _whitening(R: np.ndarray) -> np.ndarray:
    """``Wh`` with ``Wh^T Wh = R^-1`` (inverse of R's Cholesky factor)."""
    return np.linalg.inv(np.linalg.cholesky(R))


def _check_segment(segment):
    if segment is None or segment == "auto":
        return None
    if segment == "plain":
        return math.inf
    try:
        value = float(segment)
    except (TypeError, ValueError):
        raise EstimationError(f"ML: segment must be None, 'plain' or a length in s, got {segment!r}") from None
    if not value > 0:
        raise EstimationError(f"ML: segment length must be positive, got {segment!r}")
    return value


def _check_noise_cov(noise_cov, ny: int):
    if isinstance(noise_cov, str):
        if noise_cov != "relax":
            raise EstimationError(f"ML: noise_cov must be 'relax' or a covariance, got {noise_cov!r}")
        return None
    R = np.asarray(noise_cov, dtype=float)
    if R.shape == (ny,):
        R = np.diag(R)
    if R.shape != (ny, ny) or not np.all(np.isfinite(R)):
        raise EstimationError(f"ML: noise_cov must be {ny} variances or a {ny}x{ny} matrix, got shape {R.shape}")
    if not np.allclose(R, R.T) or np.any(np.linalg.eigvalsh(R) <= 0):
        raise EstimationError("ML: noise_cov must be symmetric positive definite")
    return R


def common_dt(runs: list[Run]) -> float:
    """The runs' common sample interval (s); one clear error when they differ."""
    dts = [run.dt for run in runs]
    if max(dts) - min(dts) > 1e-6 * max(dts):
        listing = ", ".join(f"{d:g} s in {r.source}" for d, r in zip(dts, runs))
        raise EstimationError(f"ML: runs have different sample intervals ({listing}); resample them to one rate")
    return float(np.mean(dts))


def finite_channels(run: Run, names: list[str]) -> np.ndarray:
    """(N, len(names)) of the run's channels; one clear error naming the first non-finite sample."""
    data = run.matrix(names)
    bad = ~np.isfinite(data)
    if bad.any():
        k, j = np.argwhere(bad)[0]
        raise EstimationError(f"{run.source}: channel '{names[j]}' is not finite at t = {run.time[k]:g} s")
    return data

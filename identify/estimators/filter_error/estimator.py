"""The filter-error estimator (:class:`FEM`): validation, the fit, refine's protocol of nested
fits, the result (the derivation: :mod:`identify.estimators.filter_error`)."""
from __future__ import annotations

import math
import time as _time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...data.runs import Run
from ...errors import ConvergenceWarning, EstimationError
from ...model import pseudo_inputs as pi
from ...model.profile import VELOCITY_STATES, Profile
from ...model.turbulence import default_states, with_turbulence
from ...model.simulate import discretize, held_inputs, propagate
from ..base import Estimator
from ..ml import common_dt, finite_channels
from ..output_error import pad
from ..prior import posterior, prior_term
from ..result import IdentificationResult, fit_metrics
from ..whiteness import whiteness
from .base import PROCESS_NOISE_CONVENTION, ProcessNoiseModel
from .bounds import TURBULENCE_ADVICE, degenerate_fit, fit_bounds
from .filter import FilterProblem, NonlinearFilterProblem
from .innovation import InnovationFilterProblem, InnovationSolver
from .solver import FilterSolver
from . import turbulence
from .starts import fit_from_starts

INNOVATION_CACHE = 8  # refine's predictions kept per estimator (profile x runs)
FORMULATIONS = ("measurement", "innovation")  # R the measurement noise (ML), or the innovation covariance (textbook)
NOISE_PARTS = ("f", "r", "corner")  # a ModelFit's noise: F, R and the estimated gust corners (turbulence)


class FEM(Estimator):
    """Filter-error maximum-likelihood estimator (process and measurement noise).

    ``process_noise``: None (the profile's ``[process_noise]``, else its velocity states) or
    ``{state: F start value or None}`` (``{}``: no process noise; FEM is then output error).
    ``x0``: ``{state: value}`` initial states held fixed in every run (with the profile's
    ``[initial_state]``); ``estimate_x0``/``estimate_bias`` as ML (False holds all of them;
    per-output zero shifts follow the profile's ``[zero_shifts]``). ``max_iter``, ``tol``,
    ``progress``, ``verbose`` as ML. ``coloured``: None (default) the standard errors corrected for
    coloured innovations (ML's Morelli & Klein sandwich on the innovations, :meth:`FilterProblem.coloured`)
    where the innovations fail the whiteness test (:mod:`identify.estimators.whiteness`, per
    output, ``info["whiteness"]``), else the Cramér-Rao bounds; True the correction always, False
    never. Both are then in ``info["std_coloured"]`` and ``info["std_white"]`` (theta only), the
    choice in one line (``info["bounds_choice"]``). A degenerate fit (R on its floor on every
    output, or a filter that copies the data) has its derivatives' bounds marked not meaningful
    (NaN, ``info["degenerate"]`` says why). ``diffuse``: each run's initial states and zero shifts
    integrated out of the likelihood that fits the derivatives and the noise (de Jong's diffuse
    likelihood, :meth:`FilterProblem.diffuse_term`), then estimated given them; with
    ``stationary_start`` (states with process noise and a first-order equation, the gusts) those
    states' starts are instead draws from their stationary distribution (variance F^2 / (2 omega)).
    Both on for a profile's ``[turbulence]`` with ``likelihood = "diffuse"``: estimated alongside,
    the nuisance takes up the gusts' slow part (corners too high, intensities too low on short
    runs); integrated flat, a gust's start lets its corner run to zero (a random walk).
    ``positive``: free parameters stepped in their logarithm, so that they stay positive (a gust's
    corner: at or below zero the gust is no longer a stationary process); their start must be positive.

    After ``fit(runs)``: ``result_`` (``modelled`` = the filter's one-step predictions, so the
    residuals are the innovations), ``covariance_`` (p, p), ``beta_`` (all unknowns), ``problem_``.
    ``result_.info``: ``process_noise`` {state: {F, std}}, ``measurement_noise`` {output:
    {variance, std}}, ``innovation_cov``, ``kalman_gain``, ``diag_CK``, ``r_start`` (the
    starts' -log L, the restart's among them, and the one kept, where R's start fell below its
    floor), per-run initial states and zero shifts with their stds, convergence as ML (``converged``, ``stop``; a
    :class:`ConvergenceWarning` when not converged). ``result_.profile`` is the a priori profile
    with the fitted F as its ``[process_noise]``: ``identified_profile()`` starts the next fit there.
    """

    method = "fem"
    models_turbulence = True  # a profile's [turbulence]: the gust states' model (.turbulence)
    weighs_prior = True  # the prior's residuals in the cost (identify.estimators.prior)

    def __init__(self, profile: Profile | str | Path, *, process_noise: dict | None = None, x0: dict | None = None,
                 max_iter: int = 100, tol: float = 1e-8, estimate_x0: bool = True, estimate_bias: bool = True,
                 progress=None, verbose: bool = False, coloured: bool | None = None,
                 formulation: str = "measurement", diffuse: bool = False, stationary_start: tuple = (),
                 positive: tuple = ()):
        super().__init__(profile)
        self.diffuse, self.stationary_start, self.positive = diffuse, tuple(stationary_start), tuple(positive)
        self.process_noise, self.x0, self.coloured = process_noise, x0, coloured
        self.formulation = formulation
        self.max_iter, self.tol = max_iter, tol
        self.estimate_x0, self.estimate_bias = estimate_x0, estimate_bias
        self.progress, self.verbose = progress, verbose
        self.covariance_ = self.problem_ = self.beta_ = None

    def _validate(self) -> None:
        super()._validate()
        self.profile_, self.default_turbulence_ = default_turbulence(self.profile_, self.process_noise)
        p = self.profile_
        if not (isinstance(self.max_iter, (int, np.integer)) and self.max_iter >= 1):
            raise EstimationError(f"FEM: max_iter must be a positive integer, got {self.max_iter!r}")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise EstimationError(f"FEM: tol must be positive, got {self.tol!r}")
        if self.formulation not in FORMULATIONS:
            raise EstimationError(f"FEM: formulation must be one of {', '.join(FORMULATIONS)}, got {self.formulation!r}")
        self.noise_model_ = self.noise_model(p)
        noise = self.noise_model_.states
        x0 = {**p.initial_state, **(self.x0 or {})}
        filtered = self.noise_model_.filter_profile(p)
        for what, names, q in (("process_noise", noise, filtered), ("x0", x0, p)):
            bad = [s for s in names if s not in q.states]
            if bad:
                raise EstimationError(f"FEM: {what}: {', '.join(bad)} not a state of the profile "
                                      f"(states: {', '.join(q.states)})")
        self.process_noise_, self.x0_ = noise, {s: float(v) for s, v in x0.items()}
        bad = [n for n in self.positive if n not in p.free or not p.free[n] > 0]
        if bad:
            raise EstimationError(f"FEM: positive: {', '.join(bad)} must be free parameters with a positive start")

    def noise_model(self, p: Profile) -> ProcessNoiseModel:
        """The process-noise model of profile ``p`` (:mod:`.base`: the seam where a turbulence model
        plugs in): the ``process_noise`` option, else the profile's ``[process_noise]``, else its
        velocity states; a state named without a start value starts from the profile's (a fitted
        profile's F)."""
        if self.process_noise is not None:
            noise, source = dict(self.process_noise), "the process_noise option"
        else:
            noise, source = p.process_noise_states(), "[process_noise]" if p.process_noise else "default: velocity states"
        noise = {s: p.process_noise.get(s) if v is None else v for s, v in noise.items()}
        if not noise and self.process_noise is None and not p.turbulence:  # never output error in silence
            raise EstimationError(
                f"FEM: no process noise declared and the profile has no velocity state ({', '.join(VELOCITY_STATES)}): "
                f"declare the equations that take it in the profile's [process_noise] (e.g. p = 0.1 and r = 0.1 "
                f"for a lateral case), or turbulence in [turbulence] / --turbulence; without either FEM would be "
                f"output error (--method ml)")
        return ProcessNoiseModel(noise, source)

    # -- fitting ---------------------------------------------------------------------------------
    def _problem(self, runs: list[Run]):
        """The filter-error problem of the validated profile on ``runs``, its start and its unknowns."""
        p = self.noise_model_.filter_profile(self.profile_)
        holds = {r.meta.get("input_hold", p.input_hold) for r in runs}
        if len(holds) > 1 or not holds <= {"held", "linear"}:
            raise EstimationError(f"FEM: the runs' input_hold differ or are unknown ({', '.join(sorted(holds))}); "
                                  f"use one of held, linear for all runs")
        u = [finite_channels(r, p.input_names) for r in runs]
        z = [finite_channels(r, list(p.outputs)) for r in runs]
        args = (p, u, z, common_dt(runs), list(self.process_noise_), holds.pop())
        # state-built terms (q|q|): the extended filter (.nonlinear)
        if self.formulation == "innovation" and _state_terms(p):
            raise EstimationError("FEM: the innovation formulation is for linear profiles; this one has state-built "
                                  "terms (use the default formulation)")
        prob = NonlinearFilterProblem(*args, runs) if _state_terms(p) else \
            InnovationFilterProblem(*args) if self.formulation == "innovation" else FilterProblem(*args)
        prob.prior = prior_term(p)  # None without one: the data alone
        beta, active = prob.start(self.process_noise_, self.x0_, self.estimate_x0, self.estimate_bias)
        return prob, beta, active

    def _fit(self, runs: list[Run]) -> IdentificationResult:
        if self.profile_.turbulence:  # the gust states' model, handed back on the user's profile
            return turbulence.fit(self, runs)
        started = _time.perf_counter()
        prob, beta, active = self._problem(runs)
        solver = self._solve(prob, beta, active)
        if not solver.converged:
            warnings.warn(f"FEM did not converge: {solver.stop}; the estimates are not final "
                          f"(raise max_iter, or start from better a priori values)", ConvergenceWarning, stacklevel=3)
        self.problem_, self.beta_ = prob, solver.beta
        return self._result(runs, prob, solver, _time.perf_counter() - started)

    def _solve(self, prob: FilterProblem, beta, active, **options) -> FilterSolver:
        """The fit from the start, and from the noise's other starts where the likelihood can have
        two optima (:func:`.starts.fit_from_starts`)."""
        if isinstance(prob, InnovationFilterProblem):  # S relaxed, no R floor: one start
            solver = InnovationSolver(self, prob, beta, active, **options)
            solver.run()
            return solver
        return fit_from_starts(self, prob, beta, active, **options)

    # -- the protocol of nested fits (refine; identify.estimators.base) ---------------------------
    simulates_state_terms = False  # state-built terms come from the filter's own states ...
    builds_state_terms = True  # ... inside each fit (the extended filter): one fit, no settling loop
    progress_quantity = "cost"

    def nested(self, profile, *, zero_shifts: bool = True, segment: float = math.inf, bounds: bool = True,
               advice: bool = True, start=None) -> "FEM":
        """Refine's nested fit: the loop's zero shifts (the filter needs no segments)."""
        return self.clone(profile, estimate_bias=zero_shifts, coloured=self.coloured if bounds else False)

    def prediction_segment(self, model, duration: float) -> float:
        """Whole runs: the filter stabilises the prediction of an unstable model."""
        return math.inf

    def prediction(self, profile, runs: list[Run], *, zero_shifts: bool = True, segment: float = math.inf,
                   start=None, noise: dict | None = None, noise_start: dict | None = None):
        """The profile's one-step-ahead prediction of ``runs``: residuals are the innovations, with
        the nuisance (F, R, each run's initial state and zero shifts) fitted, the derivatives held.
        ``noise``: the ``ModelFit.noise`` (F and R) of the same profile's prediction of the fitting
        runs, held: the prediction of held-out data by the fitted model, its filter gain included
        (only each run's initial state and zero shifts are fitted there). ``noise_start``: F and R
        of the fit that gave the profile (:meth:`fitted_noise`), the start of their fit on the same
        runs: the fit's own optimum, where a start from scratch can end in another local optimum of
        the noise's likelihood (seen: 6000 below the fit's at the same derivatives)."""
        return self._innovations(profile, runs, zero_shifts, jacobian=False, noise=noise, start=noise_start)[0]

    @staticmethod
    def fitted_noise(result: IdentificationResult) -> dict | None:
        """The fitted F and R of a FEM ``result`` as ``ModelFit.noise`` holds them."""
        pn, mn = result.info.get("process_noise"), result.info.get("measurement_noise")
        if pn is None or mn is None:
            return None
        gusts = result.info.get("turbulence", {}).get("gusts", {}).values()
        return {"f": np.array([v["F"] for v in pn.values()]), "r": np.array([v["variance"] for v in mn.values()]),
                "corner": np.array([g["corner"] for g in gusts if g["corner_estimated"]])}

    def sensitivities(self, profile, runs: list[Run], null, *, zero_shifts: bool = True, segment: float = math.inf):
        """The prediction with ``dy`` (N_r, ny, p) = -d(innovations)/d(derivatives) and ``nuisance``
        (N_r, ny, k) = -d(innovations)/d(F, R, the run's initial state and zero shifts) per run
        (F and R are shared by the runs; as per-run columns the score test is a little conservative).
        A candidate term built from states (q|q|) gets its column from the extended filter at the
        term's null value: the term on the filter's own states, never on the measured ones.
        F and R start from the ``null`` prediction's (its residuals are the score test's): the
        columns of the same filter, not of another local optimum of the noise's likelihood."""
        start = getattr(null, "noise", None)
        return self._innovations(profile, runs, zero_shifts, jacobian=True, start=start)[0]

    def input_response(self, profile, runs: list[Run], *, segment: float, input_name: str, transform,
                       noise_start: dict | None = None):
        """Per run (N_r, ny): the filter's one-step prediction's response to ``transform(u, dt)`` of
        one input (the others zero, from rest), with the gain of the profile's fitted noise: how
        the innovations would change (with the opposite sign) were that input added.
        ``noise_start`` as :meth:`prediction`'s."""
        fit, prob, ev = self._innovations(profile, runs, True, jacobian=False, start=noise_start)
        j = prob.profile.input_names.index(input_name)
        u = [np.zeros((len(r), prob.m)) for r in runs]
        for ur, run in zip(u, runs):
            ur[:, j] = transform(run[input_name], run.dt)
        U = pad(prob.layout, [held_inputs(ur, prob.hold) for ur in u])
        model, Kp = ev.model, ev.Kp
        Dh = np.hstack([model.D, np.zeros_like(model.D)]) if prob.hold == "linear" else model.D
        Phi, Gamma = discretize(model.A, model.B, prob.dt, prob.hold)
        x = propagate(Phi - Kp @ model.C, (Gamma - Kp @ Dh) @ U, np.zeros((prob.n, prob.n_runs)))
        return prob.per_run(model.C @ x + Dh @ U)

    def _innovations(self, profile, runs: list[Run], zero_shifts: bool, jacobian: bool, noise: dict | None = None,
                     start: dict | None = None):
        """``(ModelFit, problem, filtered)`` of the profile's derivatives on ``runs``, the nuisance
        fitted, F and R too unless ``noise`` holds them; ``start``: F and R to start their fit
        from, not relaxed (cached per profile and runs: refine asks for the same prediction
        several ways)."""
        from ..prediction import ModelFit  # the protocol's result type

        def values(d):
            return None if d is None else tuple(tuple(map(float, d.get(part, ()))) for part in NOISE_PARTS)

        held, begin = values(noise), None if noise is not None else values(start)
        key = (profile.to_toml(), zero_shifts, jacobian, held, begin,
               tuple((r.source, len(r), hash(r.matrix(profile.channels).tobytes())) for r in runs))
        cache = self.__dict__.setdefault("_innovation_cache", {})
        if key in cache:
            return cache[key]
        while len(cache) >= INNOVATION_CACHE:
            cache.pop(next(iter(cache)))
        est = self.clone(profile, estimate_bias=zero_shifts)
        est._validate()
        runs = est.check_runs(runs)
        if est.profile_.turbulence:  # the gust states' model (declared or the default); its corners are nuisance here
            est = turbulence.augmented_estimator(est, runs)
            est._validate()
        n_der = len(profile.free)  # the derivatives, held; the rest of theta (gust corners) is nuisance
        prob, beta, active = est._problem(runs)
        active[prob.index["theta"][:n_der]] = False
        index = {"f": prob.index["f"], "r": prob.index["r"], "corner": prob.index["theta"][n_der:]}
        for given in (held, begin):  # the fitted model's noise (its filter gain) held, or the start
            for part, vals in zip(NOISE_PARTS, given or ()):
                if len(vals) != len(index[part]):
                    raise EstimationError(f"FEM: the given noise has {len(vals)} values of {part}, "
                                          f"the profile {len(index[part])}")
                beta[index[part]] = vals
                active[index[part]] &= given is begin
        solver = est._solve(prob, beta, active, nuisance_only=True, hold_noise=held is not None,
                            start_noise=begin is not None)
        try:
            ev = prob.evaluate(solver.beta, jacobian=jacobian, noise=jacobian)
        except (np.linalg.LinAlgError, ValueError):
            raise EstimationError(f"FEM: the prediction's noise fit failed ({solver.stop})") from None
        _, f, x0, b, rv = prob.unpack(solver.beta)
        fit = ModelFit(residuals=prob.per_run(ev.nu), modelled=prob.per_run(prob.Z - ev.nu),
                       x0=[x0[:, r][None] for r in range(prob.n_runs)], bias=[b[:, r] for r in range(prob.n_runs)],
                       runs=runs, noise={"f": f.copy(), "r": rv.copy(), "corner": solver.beta[index["corner"]].copy(),
                                         "r_start": solver.starts})
        if jacobian:
            G, n, ny = prob.G, prob.n, prob.ny
            L, _, k, R = ev.dnu.shape
            cols = np.r_[n_der:G, G:G + n + ny]  # corners, F, R, x0, zero shifts
            keep = solver.active[prob.local_index[0][cols]]  # held x0, zero shifts, F = 0: no column
            fit.dy = prob.per_run(-ev.dnu[:, :, :n_der].reshape(L, ny * n_der, R))
            fit.dy = [d.reshape(len(d), ny, n_der) for d in fit.dy]
            nuis = -ev.dnu[:, :, cols[keep]]
            fit.nuisance = [d.reshape(len(d), ny, -1) for d in prob.per_run(nuis.reshape(L, ny * keep.sum(), R))]
        cache[key] = (fit, prob, ev)
        return cache[key]

    def _result(self, runs, prob: FilterProblem, sv: FilterSolver, wall: float) -> IdentificationResult:
        p, P = self.profile_, prob.p
        beta = sv.beta.copy()
        ix = prob.index
        beta[ix["f"]] = np.abs(beta[ix["f"]])  # F enters as F F^T: its sign is not determined
        try:
            ev = prob.evaluate(beta, jacobian=True, noise=True)
        except (np.linalg.LinAlgError, ValueError):  # no sensitivities at the last point: no bounds, said
            ev = None
        last = ev if ev is not None else sv.ev
        bounded = sv.active.copy()
        bounded[ix["r"]] &= beta[ix["r"]] > sv.r_floor  # a variance on its floor has no bound
        white = whiteness(prob.per_run(last.nu), list(p.outputs))
        # a white model from the profile (not the option a turbulence model or a benchmark passes)
        advice = TURBULENCE_ADVICE if self.process_noise is None and not self.profile_.turbulence else ""
        bd = fit_bounds(prob, ev, bounded, self.coloured, white, sv.stop, advice)
        std, std_white, std_col, cov = bd.std, bd.std_white, bd.std_coloured, bd.cov
        reasons = {f"F of {s}": "at the boundary F = 0 (no process noise found on it), bound not determined"
                   for s in sv.at_zero}
        innovation = isinstance(prob, InnovationFilterProblem)
        if innovation:  # R implied by the relaxed S and the gain: no bound of its own
            beta[ix["r"]] = np.diag((np.eye(prob.ny) - last.model.C @ last.K) @ last.S)
            reasons.update({f"R of {y}": "implied, R = (I - C K) S (the innovation formulation): no bound of its own"
                            for y in p.outputs})
        else:
            reasons.update({f"R of {y}": "on its floor (no measurement noise found), bound not determined"
                            for y, b_ in zip(p.outputs, bounded[ix["r"]]) if not b_})
        degenerate = None if innovation else degenerate_fit(p, beta[ix["r"]], sv.r_floor, np.diag(last.model.C @ last.K))
        if bd.failed:  # the information could not be formed or inverted: NaN bounds with the reason
            reasons.update({n: bd.failed for n, a in zip(prob.model0.names, bounded[:P]) if a})
        self.covariance_, self.covariance_all_ = cov[:P, :P].copy(), cov  # all: a turbulence model's corners and F
        theta, f, x0, b, r = prob.unpack(beta)
        prior = None
        if prob.prior is not None and bd.failed is None:  # M holds the prior's information: A = (M_d + P^-1)^-1
            A = bd.cov_white[:P, :P]
            D = self.covariance_ if std_col is not None else A - (A * prob.prior.precision) @ A
            self.covariance_, prior = posterior(prob.prior, theta, A, D, bounded[:P])
            std[:P] = np.where(bounded[:P], np.sqrt(np.clip(np.diag(self.covariance_), 0, None)), std[:P])
        if degenerate:  # the derivatives' bounds are no measure of precision: said, not printed
            reasons.update({n: f"not meaningful: {degenerate}" for n, a in zip(prob.model0.names, bounded[:P]) if a})
            std[:P][bounded[:P]] = np.nan
        _, f_std, x0_std, b_std, r_std = prob.unpack(std)
        measured = prob.per_run(prob.Z)
        modelled = prob.per_run(prob.Z - last.nu)
        C, K = last.model.C, last.K
        fitted_noise = dict(zip(prob.noise_states, map(float, f)))
        info = {
            "form": "filter error (steady-state Kalman filter)" + (
                "; the textbook's formulation: R the innovation covariance, relaxed, C K <= 1" if innovation else ""),
            "formulation": self.formulation,
            "iterations": sv.iterations,
            "converged": sv.converged,
            "stop": sv.stop,
            "cost": sv.history,  # negative log-likelihood of the innovations per iteration
            "damping": sv.lam,
            "rejected_steps": sv.rejected,
            "gauss_newton_step_se": sv.step_history,
            "modelled": "one-step-ahead predictions of the Kalman filter (residuals = innovations)",
            "input_hold": prob.hold,
            "process_noise_model": self.noise_model_.describe(fitted_noise),  # which model was fitted, one line
            "process_noise_convention": PROCESS_NOISE_CONVENTION,
            "process_noise": {s: {"F": float(v), "std": float(e)} for s, v, e in zip(prob.noise_states, f, f_std)},
            "measurement_noise": {y: {"variance": float(v), "std": float(e)} for y, v, e in zip(p.outputs, r, r_std)},
            "noise_cov": np.diag(r),
            "noise_std": dict(zip(p.outputs, map(float, np.sqrt(r)))),
            "noise_cov_estimated": True,
            "innovation_cov": last.S,
            "kalman_gain": K,  # x_corrected = x_predicted + K nu
            "diag_CK": np.diag(C @ K),  # <= 1: physically admissible
            "initial_states": [dict(zip(p.state_names, map(float, x0[:, k]))) for k in range(prob.n_runs)],
            "initial_state_std": [dict(zip(p.state_names, map(float, x0_std[:, k]))) for k in range(prob.n_runs)],
            "initial_states_fixed": sorted(self.x0_),
            "zero_shifts": [dict(zip(p.outputs, map(float, b[:, k]))) for k in range(prob.n_runs)],
            "zero_shift_std": [dict(zip(p.outputs, map(float, b_std[:, k]))) for k in range(prob.n_runs)],
            "not_excited": [n for n, a in zip(prob.model0.names, sv.active[:P]) if not a],
            # where F compensation put a start of R below its floor (or the first start failed): the
            # starts' -log L, the one kept, the failures, and their one line (.starts); None: one start
            "r_start": sv.starts,
            "r_start_choice": None if sv.starts is None else sv.starts["line"],
            "not_determined": reasons,
            "degenerate": degenerate,  # why the fit is degenerate (None: it is not)
            "ill_conditioned": bd.ill,
            "whiteness": white,  # of the innovations, per output (.whiteness)
            "standard_errors": bd.description,
            "bounds_choice": bd.choice,  # why these bounds (one line)
            "coloured_failed": bd.colour_failed,  # why the coloured correction was not used (None: it was, or not asked)
            "std_white": std_white[:P],
            "std_coloured": None if std_col is None else std_col[:P],
            "noise_autocorrelation": bd.acf,  # of the whitened innovations (L, ny), lag 0 first
            "colour_passes": bd.passes,
            "wall_time": wall,
        }
        if prior is not None:
            info["prior"] = prior
        return IdentificationResult(
            # the profile keeps its a priori derivatives; its [process_noise] holds the fitted F, so
            # that identified_profile() starts the next fit (refine's nested fits) from it
            method=self.method, profile=replace(p, process_noise={s: float(v) for s, v in zip(prob.noise_states, f)}),
            theta=theta.copy(), std=std[:P], runs=[r.source for r in runs],
            covariance=self.covariance_.copy(), fit=fit_metrics(list(p.outputs), measured, modelled), info=info,
            time=[r.time.copy() for r in runs], measured=measured, modelled=modelled,
            simulated=_open_loop(prob, last.model, x0, b))


def default_turbulence(p: Profile, process_noise: dict | None) -> tuple[Profile, bool]:
    """``(profile, defaulted)``: with no process noise declared (no ``process_noise`` option, no
    ``[process_noise]``, no ``[turbulence]``) the profile with gust states on its velocities
    (:func:`identify.model.turbulence.default_states`), else as it is. Why: turbulence acts through
    the derivatives on the velocities (a relative wind), which white noise on the velocity equations
    does not share: on the Navion in flow angles, white noise on u and alpha left the derivatives
    26 % off (median; RMS z 2.98 with its coloured bounds, a bias of up to 4.8 Monte-Carlo std), the
    gust states 2.2 % (RMS z 1.02; benchmarks/filter_error.py, 10 realisations, docs/filter_error.md)."""
    if process_noise is not None or p.process_noise or p.turbulence:
        return p, False
    states = default_states(p)
    return (with_turbulence(p, states), True) if states else (p, False)


def _state_terms(p: Profile) -> list[str]:
    """A profile's pseudo-inputs built from its states (products with a state factor)."""
    return [n for n, s in pi.specs(p).items() if set(s.get("product", ())) & set(p.states)]


def _open_loop(prob: FilterProblem, model, x0: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """The model's open-loop simulation of every run (N_r, ny) from its fitted initial state with
    its zero shifts: what the one-step predictions are not (nothing fed back). Not finite (an
    unstable model diverging) or a profile with state-built terms (the extended filter's): left out."""
    if isinstance(prob, NonlinearFilterProblem):
        return []
    Dh = np.hstack([model.D, np.zeros_like(model.D)]) if prob.hold == "linear" else model.D
    Phi, Gamma = discretize(model.A, model.B, prob.dt, prob.hold)
    with np.errstate(all="ignore"):
        x = propagate(Phi, Gamma @ prob.U, x0)
        y = model.C @ x + Dh @ prob.U + b[None]
    sim = prob.per_run(y)
    return sim if all(np.all(np.isfinite(s)) for s in sim) else []


"""Filter-error method (FEM): maximum likelihood with process noise (Maine & Iliff; Jategaonkar ch. 5).

Output error (:mod:`identify.estimators.ml`) takes every misfit for measurement noise; flight data
are flown in turbulence, whose response output error cannot tell from a wrong derivative. The
filter-error method models both noises::

    dx/dt = A x + B u + F w          w: unit white noise (power spectral density 1)
    y     = C x + D u + b + v        v: white measurement noise, covariance R (diagonal)

F is diagonal on the states with process noise (``[process_noise]`` of the profile; default the
velocity equations u, v, w), F_i in the state-derivative unit times sqrt(s) (a white gust forcing
of F_i^2 per rad/s of bandwidth). Discretised exactly (matrix exponentials: ``Phi``, ``Gamma`` for
the inputs held or linear between samples; ``Qd = int_0^dt e^{A s} F F^T e^{A^T s} ds`` by Van
Loan), the steady-state Kalman filter in predictor form propagates the state::

    P  = solve_discrete_are(Phi^T, C^T, Qd, R)     (a priori state error covariance)
    S  = C P C^T + R                               (innovation covariance)
    Kp = Phi P C^T S^-1                            (predictor gain; K = P C^T S^-1 the filter's)
    x[k+1] = Phi x[k] + Gamma u[k] + Kp nu[k],     nu[k] = z[k] - C x[k] - D u[k] - b

and the cost is the negative log-likelihood of the innovations over all runs (constant dropped),
``J = 1/2 sum nu^T S^-1 nu + N/2 log det S``. The filter is a stable system driven by the inputs
and the measurements, so an unstable aircraft needs no multiple shooting: the filter stabilises
the prediction.

Unknowns: the derivatives theta, F, each run's initial state (those the profile's
``[initial_state]`` or the ``x0`` option do not fix) and each run's zero shifts (per output, as
the profile's ``[zero_shifts]`` says). They move by Levenberg-Marquardt steps on the Fisher
information (Gauss-Newton on the innovations, plus the information of S, which moves with theta
and F: ``M_ij = sum dnu_i^T S^-1 dnu_j + N/2 tr(S^-1 dS_i S^-1 dS_j)``); trust region and
convergence test are ML's (step under 1e-3 standard errors, the noise covariance settled).

R starts by *relaxation* from the first innovations, with the process noise's share removed
("F compensation"): ``R_jj = mean(nu_j^2) - (C P C^T)_jj`` (floored at a tiny positive share of
mean(nu_j^2)); from then on its variances are unknowns of the same scoring steps (relaxation
alone stalled on a wrong fixed point in the tests: with R held, the likelihood's dependence on
it through the gain is lost). Where that start falls below the floor, R starts from the innovation
covariance with the gain held; the likelihood can then have two optima, and FEM also fits from the
process noise's side (F from the states' whole rms, R on its floor), then once more from the better
fit's derivatives with the noise started afresh from that side, keeping the higher likelihood
(:meth:`FEM._solve`, ``info["r_start"]``). R >= 0 keeps the filter physically admissible:
``C K = I - R S^-1`` has ``diag(C K) = 1 - R_jj (S^-1)_jj <= 1`` (reported as ``info["diag_CK"]``).
An F that falls to ~0 (calm air on that state) or a variance pushed onto its floor is held
there: a boundary estimate, its bound "not determined" (NaN, listed in ``info["not_determined"]``).

Sensitivities: the filter is linear in its state, ``x[k+1] = Abar x[k] + (Gamma - Kp D) u[k] +
Kp (z[k] - b)`` with ``Abar = Phi - Kp C``, so the derivatives of the innovations with respect
to all unknowns come from one recursion with Abar, all parameters and runs propagated together as
trailing columns (as the output-error engine does): ``dx[k+1] = Abar dx[k] + dAbar x[k] + ...``.
``dPhi`` and ``dGamma`` are exact (Van Loan, :func:`~identify.model.sensitivity.discretize_with_derivatives`);
the gain's and S's derivatives come from the derivative of the Riccati solution, one discrete
Lyapunov equation for all unknowns at once (:meth:`FilterProblem._gain_derivatives`), with only
Qd's derivatives by central differences of a batched matrix exponential: no re-filtering and no
extra Riccati solve.

Bounds: the Cramér-Rao bounds from the same information at the estimate, the measurement-noise
variances included as unknowns (their sensitivities through the gain as above), so
F and R are reported with their bounds. For F = 0 (no process noise) and a stable model the
filter's gain is zero and FEM is output-error ML (plain form).

Outputs that are state derivatives (p_dot, a_y) use the model's noise-free derivative
``C x + D u`` (the convention of Maine & Iliff and Jategaonkar: continuous white noise has no
finite sample value; its effect on such outputs is absorbed by R).

Profiles with state-built nonlinear terms (q|q|): the extended Kalman filter of
:mod:`identify.estimators.filter_error_nonlinear` (:class:`NonlinearFilterProblem`), the rest as above.
"""
from __future__ import annotations

import math
import time as _time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.linalg import expm, solve_discrete_are

from ..data.runs import Run
from ..errors import ConvergenceWarning, EstimationError
from ..model import pseudo_inputs as pi
from ..model.linear import LinearModel
from ..model.profile import Profile
from ..model.turbulence import augment
from ..model.sensitivity import discretize_with_derivatives
from ..model.simulate import discretize, held_inputs, propagate
from .base import Estimator
from . import filter_error_turbulence
from .filter_error_nonlinear import StateTerms
from .ml import (INITIAL_DAMPING, MAX_DAMPING, MAX_REL_STEP, MIN_GAIN_RATIO, STALL_TOL_SE,
                 STEP_TOL_SE, common_dt, finite_channels)
from .coloured_bounds import ColouredBounds
from .information import BlockInformation
from .output_error import cut, pad
from .result import IdentificationResult, fit_metrics

PROCESS_NOISE_CONVENTION = ("F in dx/dt = A x + B u + F w, w unit white noise (power spectral density 1); "
                            "F diagonal on the listed states, in the state-derivative unit times sqrt(s)")
R_FLOOR = 1e-6  # smallest measurement variance, relative to the output's mean square innovation
F_START = 0.3  # default start of F_i: this share of the state's measured rms times sqrt(2 / 1 s)
F_ZERO = 1e-3  # an F below this share of its start value is at the boundary F = 0: held there
FLAT_STEPS, FLAT_COST = 3, 1e-3  # converged when this many steps each lower the cost by less (log-likelihood units)
INNOVATION_CACHE = 8  # refine's predictions kept per estimator (profile x runs)
GAIN_STEP = 1e-5  # relative step of the central differences of Qd
# Where F compensation puts a start of R below its floor the likelihood can have two optima (the
# model's misfit taken by the measurement noise, or by the process noise with q and theta tracked
# tightly), and neither the gain-held start of R nor the floor found the better on every seed: FEM
# also runs from the process-noise side, F from the states' whole measured rms (F_WIDE instead of
# F_START) with R on its floor, and keeps the higher likelihood (docs/filter_error.md, "Two optima")
F_WIDE = 1.0
R_STARTS = {"gain_held": ("gain_held", 1.0), "wide_f": ("floor", F_WIDE / F_START)}  # name: (R's start, F's factor)
START_NAMES = {"gain_held": "R = (I - C K) S_hat", "wide_f": f"F x{F_WIDE / F_START:.3g} with R on its floor",
               "restart": "the best fit's derivatives, F and R as wide_f"}
# Both starts begin at the a priori derivatives; on refine's blind lag_de (seed 3) both ended on the
# worse optimum (-log L 1987 above), and the process-noise side's start from the better fit's
# derivatives reached the better one: FEM restarts there once more (docs/filter_error.md)
RESTART = ("floor", F_WIDE / F_START)  # (R's start, F's factor), as wide_f; None: no restart (benchmarks measure both)
NOISE_PARTS = ("f", "r", "corner")  # a ModelFit's noise: F, R and the estimated gust corners (turbulence)
SAME_OPTIMUM = 1.0  # -log L within this of the best: the same optimum (a likelihood ratio far from significant)


class FEM(Estimator):
    """Filter-error maximum-likelihood estimator (process and measurement noise).

    ``process_noise``: None (the profile's ``[process_noise]``, else its velocity states) or
    ``{state: F start value or None}`` (``{}``: no process noise; FEM is then output error).
    ``x0``: ``{state: value}`` initial states held fixed in every run (with the profile's
    ``[initial_state]``); ``estimate_x0``/``estimate_bias`` as ML (False holds all of them;
    per-output zero shifts follow the profile's ``[zero_shifts]``). ``max_iter``, ``tol``,
    ``progress``, ``verbose`` as ML. ``coloured``: standard errors corrected for coloured
    innovations (ML's Morelli & Klein sandwich on the innovations, :meth:`FilterProblem.coloured`)
    or (default) the plain Cramér-Rao bounds; both are then in ``info["std_coloured"]`` and
    ``info["std_white"]`` (theta only). Opt-in: measured, it helps with coloured measurement noise
    but over-widens the velocity derivatives' bounds (median 1.6-1.9x) on the piloted S 61 case of
    benchmarks/filter_error.py, where the plain bounds are calibrated (docs/filter_error.md).

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
    models_turbulence = True

    def __init__(self, profile: Profile | str | Path, *, process_noise: dict | None = None, x0: dict | None = None,
                 max_iter: int = 100, tol: float = 1e-8, estimate_x0: bool = True, estimate_bias: bool = True,
                 progress=None, verbose: bool = False, coloured: bool = False):
        super().__init__(profile)
        self.process_noise, self.x0, self.coloured = process_noise, x0, coloured
        self.max_iter, self.tol = max_iter, tol
        self.estimate_x0, self.estimate_bias = estimate_x0, estimate_bias
        self.progress, self.verbose = progress, verbose
        self.covariance_ = self.problem_ = self.beta_ = None

    def _validate(self) -> None:
        super()._validate()
        p = self.profile_
        if not (isinstance(self.max_iter, (int, np.integer)) and self.max_iter >= 1):
            raise EstimationError(f"FEM: max_iter must be a positive integer, got {self.max_iter!r}")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise EstimationError(f"FEM: tol must be positive, got {self.tol!r}")
        noise = p.process_noise_states() if self.process_noise is None else dict(self.process_noise)
        # a state named without a start value starts from the profile's (a fitted profile's F)
        noise = {s: p.process_noise.get(s) if v is None else v for s, v in noise.items()}
        x0 = {**p.initial_state, **(self.x0 or {})}
        for what, names in (("process_noise", noise), ("x0", x0)):
            bad = [s for s in names if s not in p.states]
            if bad:
                raise EstimationError(f"FEM: {what}: {', '.join(bad)} not a state of the profile "
                                      f"(states: {', '.join(p.states)})")
        self.process_noise_, self.x0_ = noise, {s: float(v) for s, v in x0.items()}

    # -- fitting ---------------------------------------------------------------------------------
    def _problem(self, runs: list[Run]):
        """The filter-error problem of the validated profile on ``runs``, its start and its unknowns."""
        p = self.profile_
        holds = {r.meta.get("input_hold", p.input_hold) for r in runs}
        if len(holds) > 1 or not holds <= {"held", "linear"}:
            raise EstimationError(f"FEM: the runs' input_hold differ or are unknown ({', '.join(sorted(holds))}); "
                                  f"use one of held, linear for all runs")
        u = [finite_channels(r, p.input_names) for r in runs]
        z = [finite_channels(r, list(p.outputs)) for r in runs]
        args = (p, u, z, common_dt(runs), list(self.process_noise_), holds.pop())
        # state-built terms (q|q|): the extended filter (identify.estimators.filter_error_nonlinear)
        prob = NonlinearFilterProblem(*args, runs) if _state_terms(p) else FilterProblem(*args)
        beta, active = prob.start(self.process_noise_, self.x0_, self.estimate_x0, self.estimate_bias)
        return prob, beta, active

    def _fit(self, runs: list[Run]) -> IdentificationResult:
        if self.profile_.turbulence:  # the gust states' model, handed back on the user's profile
            return filter_error_turbulence.fit(self, runs)
        started = _time.perf_counter()
        prob, beta, active = self._problem(runs)
        solver = self._solve(prob, beta, active)
        if not solver.converged:
            warnings.warn(f"FEM did not converge: {solver.stop}; the estimates are not final "
                          f"(raise max_iter, or start from better a priori values)", ConvergenceWarning, stacklevel=3)
        self.problem_, self.beta_ = prob, solver.beta
        return self._result(runs, prob, solver, _time.perf_counter() - started)

    def _solve(self, prob: "FilterProblem", beta, active, **options) -> "_Solver":
        """The fit from the start (``_Solver``); where F compensation put a start of R below its
        floor (``_Solver.floor_bound``) from every start of R_STARTS too, the highest likelihood
        kept: the likelihood can have two optima there, and each single start missed the better one
        on some seeds; then once more from the better fit's derivatives (``RESTART``), since
        both starts from the a priori derivatives can miss it too. The starts' -log L and the one
        kept in ``solver.starts``, said in one line."""
        solver = _Solver(self, prob, beta, active, **options)
        solver.run()
        if not solver.floor_bound:
            return solver
        tried, failed = {"gain_held": solver}, {}
        for name, start in R_STARTS.items():
            if name not in tried:
                self._try(name, start, beta, prob, active, tried, failed, **options)
        b = beta.copy()
        b[:prob.p] = tried[_kept(tried)].beta[:prob.p]
        # the a priori derivatives' starts missed it too (refine_blind lag_de seed 3); from the same
        # derivatives (held: a nuisance-only prediction) the restart would repeat the wide_f start
        if RESTART is not None and not np.array_equal(b[:prob.p], beta[:prob.p]):
            self._try("restart", RESTART, b, prob, active, tried, failed, **options)
        kept = _kept(tried)
        best = tried[kept]
        best.starts = {"floor_bound": list(solver.floor_bound), "kept": kept,
                       "cost": {k: float(v.history[-1]) for k, v in tried.items()}, "failed": failed}
        costs = ", ".join(f"{START_NAMES[k]}: {v.history[-1]:.6g}" for k, v in tried.items())
        warnings.warn(f"FEM: the F-compensated start of R ({', '.join(solver.floor_bound)}) fell below its floor "
                      f"(the likelihood can have two optima): fitted from {len(tried)} starts, -log L {costs}; "
                      f"kept {START_NAMES[kept]}"
                      + (f" ({', '.join(failed)} failed)" if failed else ""), stacklevel=4)
        return best

    def _try(self, name, start, beta, prob, active, tried, failed, **options) -> None:
        """The fit from ``beta`` with ``start`` = (R's start, F's factor), into ``tried[name]``, or
        its error into ``failed[name]`` (a start whose filter has no steady state: the others stand)."""
        r_start, f_factor = start
        b = beta.copy()
        b[prob.index["f"]] *= f_factor
        try:
            tried[name] = _Solver(self, prob, b, active, r_start=r_start, **options)
            tried[name].run()
        except EstimationError as e:
            tried.pop(name, None)
            failed[name] = str(e)

    # -- the protocol of nested fits (refine; identify.estimators.base) ---------------------------
    simulates_state_terms = False  # state-built terms come from the filter's own states ...
    builds_state_terms = True  # ... inside each fit (the extended filter): one fit, no settling loop
    progress_quantity = "cost"

    def nested(self, profile, *, zero_shifts: bool = True, segment: float = math.inf, bounds: bool = True) -> "FEM":
        """Refine's nested fit: the loop's zero shifts (the filter needs no segments)."""
        return self.clone(profile, estimate_bias=zero_shifts, coloured=self.coloured and bounds)

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
        corners = [g["corner"] for g in result.info.get("turbulence", {}).get("gusts", {}).values() if g["corner_estimated"]]
        return {"f": np.array([v["F"] for v in pn.values()]), "r": np.array([v["variance"] for v in mn.values()]),
                "corner": np.array(corners)}

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
        from .prediction import ModelFit  # the protocol's result type

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
        k = len(profile.free)  # the derivatives; the rest of theta (gust corners) is nuisance
        if profile.turbulence:
            gm = augment(profile, runs)
            est = self.clone(gm.augmented, estimate_bias=zero_shifts, process_noise=gm.noise_states())
            est._validate()
        prob, beta, active = est._problem(runs)
        active[prob.index["theta"][:k]] = False
        index = {"f": prob.index["f"], "r": prob.index["r"], "corner": prob.index["theta"][k:]}
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
            cols = np.r_[k:G, G:G + n + ny]
            keep = solver.active[prob.local_index[0][cols]]  # held x0, zero shifts, F = 0: no column
            fit.dy = prob.per_run(-ev.dnu[:, :, :k].reshape(L, ny * k, R))
            fit.dy = [d.reshape(len(d), ny, k) for d in fit.dy]
            nuis = -ev.dnu[:, :, cols[keep]]
            fit.nuisance = [d.reshape(len(d), ny, -1) for d in prob.per_run(nuis.reshape(L, ny * keep.sum(), R))]
        cache[key] = (fit, prob, ev)
        return cache[key]

    def _result(self, runs, prob: "FilterProblem", sv: "_Solver", wall: float) -> IdentificationResult:
        p, P = self.profile_, prob.p
        beta = sv.beta.copy()
        ix = prob.index
        beta[ix["f"]] = np.abs(beta[ix["f"]])  # F enters as F F^T: its sign is not determined
        try:
            ev = prob.evaluate(beta, jacobian=True, noise=True)
        except (np.linalg.LinAlgError, ValueError):
            raise EstimationError(f"FEM: the fit failed ({sv.stop}): no bounds at its last point") from None
        bounded = sv.active.copy()
        bounded[ix["r"]] &= beta[ix["r"]] > sv.r_floor  # a variance on its floor has no bound
        M, _ = prob.information(ev)
        cov, ill = _covariance(M, bounded)
        std = std_white = np.sqrt(np.clip(np.diag(cov), 0, None))
        std_col, acf, passes, colour_failed = None, None, 0, None
        if self.coloured:  # once, at the estimate
            cov_c, acf, passes = prob.coloured(ev, bounded)
            colour_failed = _colour_failure(cov_c, cov, bounded)
            if colour_failed is None:
                cov = cov_c
                std = std_col = np.sqrt(np.clip(np.diag(cov), 0, None))
            else:
                warnings.warn(f"FEM: {colour_failed}; the Cramér-Rao bounds are reported", stacklevel=3)
        std[~bounded] = np.inf  # a derivative no input excites, a held x0 or zero shift
        boundary = np.zeros_like(bounded)
        boundary[ix["f"]] = ~bounded[ix["f"]]
        boundary[ix["r"]] = ~bounded[ix["r"]]
        std[boundary] = np.nan  # F = 0 or R on its floor: on the boundary, the bound is not determined
        std_white = np.where(np.isfinite(std), std_white, std)  # the same held / undetermined ones
        self.covariance_, self.covariance_all_ = cov[:P, :P].copy(), cov
        theta, f, x0, b, r = prob.unpack(beta)
        _, f_std, x0_std, b_std, r_std = prob.unpack(std)
        measured = prob.per_run(prob.Z)
        modelled = prob.per_run(prob.Z - ev.nu)
        C, K = ev.model.C, ev.K
        info = {
            "form": "filter error (steady-state Kalman filter)",
            "iterations": sv.iterations,
            "converged": sv.converged,
            "stop": sv.stop,
            "cost": sv.history,  # negative log-likelihood of the innovations per iteration
            "damping": sv.lam,
            "rejected_steps": sv.rejected,
            "gauss_newton_step_se": sv.step_history,
            "modelled": "one-step-ahead predictions of the Kalman filter (residuals = innovations)",
            "input_hold": prob.hold,
            "process_noise_convention": PROCESS_NOISE_CONVENTION,
            "process_noise_model": (f"white process noise on the equations of {', '.join(prob.noise_states)} (F "
                                    f"estimated; no turbulence declared)" if prob.noise_states else
                                    "none: no process noise (output error)"),
            "process_noise": {s: {"F": float(v), "std": float(e)} for s, v, e in zip(prob.noise_states, f, f_std)},
            "measurement_noise": {y: {"variance": float(v), "std": float(e)} for y, v, e in zip(p.outputs, r, r_std)},
            "noise_cov": np.diag(r),
            "noise_std": dict(zip(p.outputs, map(float, np.sqrt(r)))),
            "noise_cov_estimated": True,
            "innovation_cov": ev.S,
            "kalman_gain": K,  # x_corrected = x_predicted + K nu
            "diag_CK": np.diag(C @ K),  # <= 1: physically admissible
            "initial_states": [dict(zip(p.state_names, map(float, x0[:, k]))) for k in range(prob.n_runs)],
            "initial_state_std": [dict(zip(p.state_names, map(float, x0_std[:, k]))) for k in range(prob.n_runs)],
            "initial_states_fixed": sorted(self.x0_),
            "zero_shifts": [dict(zip(p.outputs, map(float, b[:, k]))) for k in range(prob.n_runs)],
            "zero_shift_std": [dict(zip(p.outputs, map(float, b_std[:, k]))) for k in range(prob.n_runs)],
            "not_excited": [n for n, a in zip(prob.model0.names, sv.active[:P]) if not a],
            # where F compensation put a start of R below its floor: the starts' -log L, the one kept
            # (FEM._solve); None where it did not (one start)
            "r_start": sv.starts,
            "not_determined": {**{f"F of {s}": "at the boundary F = 0 (no process noise found on it), bound not "
                                                 "determined" for s in sv.at_zero},
                               **{f"R of {y}": "on its floor (no measurement noise found), bound not determined"
                                  for y, b_ in zip(p.outputs, bounded[ix["r"]]) if not b_}},
            "ill_conditioned": ill,
            "standard_errors": ("coloured-innovation correction (Morelli & Klein) of the Cramér-Rao bounds"
                                if std_col is not None else
                                "Cramér-Rao bounds from the innovations' sensitivities (noise variances included)"),
            "coloured_failed": colour_failed,  # why the coloured correction was not used (None: it was, or not asked)
            "std_white": std_white[:P],
            "std_coloured": None if std_col is None else std_col[:P],
            "noise_autocorrelation": acf,  # of the whitened innovations (L, ny), lag 0 first
            "colour_passes": passes,
            "wall_time": wall,
        }
        return IdentificationResult(
            # the profile keeps its a priori derivatives; its [process_noise] holds the fitted F, so
            # that identified_profile() starts the next fit (refine's nested fits) from it
            method=self.method, profile=replace(p, process_noise={s: float(v) for s, v in zip(prob.noise_states, f)}),
            theta=theta.copy(), std=std[:P], runs=[r.source for r in runs],
            covariance=self.covariance_.copy(), fit=fit_metrics(list(p.outputs), measured, modelled), info=info,
            time=[r.time.copy() for r in runs], measured=measured, modelled=modelled)


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
        return M, g

    def coloured(self, ev: Filtered, active: np.ndarray):
        """The covariance (n_beta, n_beta) corrected for coloured innovations, the whitened
        innovations' autocorrelation (L, ny) and the number of passes: ML's sandwich ``M^-1 B M^-1``
        (:class:`~identify.estimators.coloured_bounds.ColouredBounds`) with the innovations for the
        residuals and their sensitivities for J; the information in S (the noise variances') enters
        B as it is. White innovations: the Cramér-Rao bound within the scatter of their
        autocorrelation."""
        adapter = _Innovations(self, ev)
        info = BlockInformation(adapter.local, self.local_index, self.n_beta,
                                self.index["x0"], active)
        cov, acf, passes = ColouredBounds(adapter, adapter, adapter.Wh, info, adapter.extra).solve()
        dense = np.zeros((self.n_beta, self.n_beta))
        g = info.g_index
        dense[np.ix_(g, g)] = cov.gg  # every run's x0 but with the globals (the blocks read)
        for r, xs in enumerate(info.x_index):
            dense[np.ix_(g, xs)], dense[np.ix_(xs, g)], dense[np.ix_(xs, xs)] = cov.gx[r], cov.gx[r].T, cov.xx[r]
        return dense, acf, passes

    def per_run(self, arr: np.ndarray) -> list[np.ndarray]:
        """(L, ny, R) back to one (N_r, ny) array per run."""
        return [arr[:n_r, :, r].copy() for r, n_r in enumerate(self.layout.length)]


class _Innovations:
    """The filter-error problem as :class:`~identify.estimators.coloured_bounds.ColouredBounds`
    sees an output-error one (the seam): residuals ``e`` = the innovations (L, ny, R), the local
    Jacobian = the whitened innovation sensitivities over each run's local unknowns ``[theta, F,
    R, x0, zero shifts]`` (``p`` = the globals G), every run one segment; ``local`` (R, k, k) the
    information (its Gram matrices, plus the information in S on the first run's globals). The
    columns of F and R are zero in the Jacobian the sandwich sees: their sensitivities are
    functions of the noise itself (the gain's), so their rows and columns of B, and S's
    information, are taken as the Cramér-Rao ones (``extra``)."""

    def __init__(self, prob: FilterProblem, ev: Filtered):
        self.fp, self.ev_ = prob, ev
        self.mask, self.layout, self.local_index = prob.mask, prob.layout, prob.local_index
        self.p, self.n = prob.G, prob.n
        self.e = ev.nu
        self.dy_x0 = np.zeros((0, 0, 0, 0))  # ndim 4: each run's own initial-state response
        self.Wh = np.linalg.cholesky(np.linalg.inv(ev.S)).T  # Wh^T Wh = S^-1
        J = self.local_jacobian(self, self.Wh, structural=False)
        R, L, ny, k = J.shape
        J = J.reshape(R, L * ny, k)
        self.local = J.transpose(0, 2, 1) @ J  # the innovations' part of M
        SdS = np.linalg.solve(ev.S, ev.dS)
        G = prob.G
        in_S = 0.5 * prob.N * np.einsum("iab,jba->ij", SdS, SdS)  # the information in S (as M's)
        self.local[0, :G, :G] += in_S
        noise = np.zeros(k, bool)
        noise[prob.p:G] = True
        self.extra = self.local * (noise[:, None] | noise[None, :])
        self.extra[0, :G, :G] += in_S * ~noise[:G, None] * ~noise[None, :G]

    def local_jacobian(self, ev, Wh: np.ndarray, k0: int = 0, k1: int | None = None, segment=None,
                       structural: bool = True) -> np.ndarray:
        """``Wh dnu`` (S, k1 - k0, ny, k) of the runs ``segment`` (an index, a slice, all); the
        columns of F and R zero when ``structural``."""
        segs = segment if isinstance(segment, slice) else \
            slice(None) if segment is None else slice(segment, segment + 1)
        d = self.ev_.dnu[k0:k1, :, :, segs]
        l, ny, k, S = d.shape
        J = (Wh @ d.reshape(l, ny, k * S)).reshape(l, ny, k, S).transpose(3, 0, 1, 2)
        if structural:
            J[..., self.fp.p:self.fp.G] = 0.0
        return J

    def segment_groups(self) -> list[tuple[int, int]]:
        return [(0, self.fp.n_runs)]

    def blocks(self, columns: int):
        return [(0, self.layout.L)]


class NonlinearFilterProblem(StateTerms, FilterProblem):
    """:class:`FilterProblem` of a profile with state-built terms: the extended Kalman filter
    (:mod:`identify.estimators.filter_error_nonlinear`)."""

    Filtered = Filtered


class _Solver:
    """Levenberg-Marquardt on the Fisher information (theta, F, R, x0, zero shifts), R started by
    relaxation from the innovations (ML's trust-region rules and convergence test,
    :class:`identify.estimators.ml._Solver`)."""

    def __init__(self, fem: FEM, prob: FilterProblem, beta, active, nuisance_only: bool = False,
                 hold_noise: bool = False, start_noise: bool = False, r_start: str = "gain_held"):
        self.fem, self.prob, self.beta = fem, prob, beta.copy()
        self.hold_noise = hold_noise  # F and R given (a held-out prediction): never relaxed nor released
        self.start_noise = start_noise  # F and R of a fit given as the start: not relaxed, then stepped
        self.r_start = r_start  # R's start where F compensation falls below the floor: "gain_held" or "floor"
        self.floor_bound: list[str] = []  # the outputs where it did (_relax)
        self.starts = None  # FEM._solve's record when it fitted from several starts
        self.history, self.step_history = [], []
        self.iterations, self.converged, self.stop, self.lam, self.rejected = 0, False, "max_iter", 0.0, 0
        self.radius = MAX_REL_STEP
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
        M, _ = prob.information(self.ev)
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
        ix = prob.index
        self._nuisance_step(M, prob)
        self.scale0 = np.abs(beta)
        self.at_zero = []  # states whose process noise went to the boundary F = 0
        self.moving = np.zeros(prob.n_beta, bool)  # step-bounded: theta and F
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
        start, from the process noise's side: :meth:`FEM._solve`). With ``start_noise`` (F and R
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

    def _step(self, M, g, lam) -> np.ndarray:
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
        cov, _ = _covariance(M, self.active)
        sigma = np.sqrt(np.clip(np.diag(cov), 0, None))
        return np.maximum(np.maximum(np.abs(self.beta), self.scale0), sigma)

    def run(self) -> None:
        prob, fem = self.prob, self.fem
        self.history.append(self.ev.cost)
        M, g = prob.information(self.ev)
        self.lam = INITIAL_DAMPING
        while True:
            self._release(g)
            step0 = self._step(M, g, 0.0)
            in_se = math.sqrt(max(float(g @ step0), 0.0))
            self.step_history.append(in_se)
            th = self.active[:prob.p]  # none in a prediction's noise fit: then the step in std errors only
            rel = float(np.max(np.abs(step0[:prob.p][th]) / (np.abs(self.beta[:prob.p][th]) + 1e-6))) if th.any() \
                else np.inf
            if in_se < STEP_TOL_SE or rel < fem.tol:
                self.converged = True
                self.stop = (f"gradient: the next step is {in_se:.1e} standard errors" if in_se < STEP_TOL_SE
                             else f"step: the next step is {rel:.1e} of the parameters")
                break
            drops = -np.diff(self.history[-FLAT_STEPS - 1:])
            if len(drops) == FLAT_STEPS and np.all(drops < FLAT_COST):
                # a flat valley (e.g. a zero shift, an initial state and a gust's F nearly
                # collinear): the undamped step is long along an almost undetermined direction, yet
                # no step changes the likelihood by anything a test could see
                self.converged = True
                valley = "; a flat valley along a nearly undetermined direction" if in_se >= 0.1 else ""
                self.stop = (f"cost: the last {FLAT_STEPS} steps lowered the negative log-likelihood by less "
                             f"than {FLAT_COST:g} each (the next Gauss-Newton step: {in_se:.2g} standard "
                             f"errors{valley})")
                break
            if self.iterations >= fem.max_iter:
                self.stop = f"max_iter: {fem.max_iter} iterations without convergence"
                break
            found = self._trial(M, g)
            self.iterations += 1
            if found is None:
                if in_se < STALL_TOL_SE:
                    self.converged = True
                    self.stop = (f"gradient: no step lowers the cost (numerical precision); the next would be "
                                 f"{in_se:.1e} standard errors")
                else:
                    self.stop = f"stalled: no step lowers the cost although {in_se:.2g} standard errors remain"
                break
            self._boundary()
            self.ev = self._evaluate(self.beta, jacobian=True)
            if self.ev is None:  # the step's model has no finite sensitivities: a failed fit
                self.ev = found
                self.stop = "diverged: the filter's sensitivities are not finite at the last step"
                break
            self.history.append(self.ev.cost)
            M, g = prob.information(self.ev)
            if fem.progress is not None:
                fem.progress(self.iterations, self.history[-1], self.beta[:prob.p].copy())
            if fem.verbose:
                print(f"FEM iteration {self.iterations:3d}: -log likelihood {self.history[-1]:.10g}  "
                      f"damping {self.lam:.1e}  next step {in_se:.2e} std errors")
        self.M = M

    def _boundary(self) -> None:
        """An F that falls to a negligible share of its start is at the boundary F = 0 (calm air
        on that state): its information vanishes as F^2 there, so it is held at 0, not stepped.
        Likewise a measurement variance the step pushes onto its floor (R_FLOOR)."""
        for i, j in enumerate(self.prob.index["f"]):
            if self.active[j] and abs(self.beta[j]) < F_ZERO * self.scale0[j]:
                self.beta[j], self.active[j] = 0.0, False
                self.at_zero.append(self.prob.noise_states[i])
        r = self.prob.index["r"]  # a measurement variance pushed onto its floor is held there ...
        self.active[r] &= self.beta[r] > (1 + 1e-9) * self.r_floor

    def _nuisance_step(self, M, prob) -> None:
        """Initial states and zero shifts enter the innovations linearly: one exact step fits them
        to the start model (as ML does), then R is relaxed again from the new innovations."""
        nuisance = self.active.copy()
        nuisance[:prob.G] = False
        if not nuisance.any():
            return
        _, g = prob.information(self.ev)
        saved, self.active = self.active, nuisance
        step = self._step(M, g, 0.0)
        self.active = saved
        ev = self._evaluate(self.beta + step, jacobian=False)
        if ev is not None and ev.cost < self.ev.cost:
            self.beta, self.ev = self.beta + step, ev
            self._relax()
            self.ev = self._evaluate(self.beta, jacobian=True)

    def _release(self, g) -> None:
        """... until the gradient points back inside (the likelihood rises with the variance):
        an active set, so that an early, wild step cannot pin a variance to its floor."""
        if self.hold_noise:
            return
        r = self.prob.index["r"]
        self.active[r] |= g[r] > 0

    def _trial(self, M, g):
        """The damped, step-bounded step that lowers the cost by MIN_GAIN_RATIO of its predicted
        decrease (its evaluation), or None when the damping limit is reached (ML's rules)."""
        nu, cost = 2.0, self.ev.cost
        scale = self._scale(M)
        mv = self.moving & self.active
        while self.lam <= MAX_DAMPING:
            step = self._step(M, g, self.lam)
            rel = float(np.max(np.abs(step[mv]) / scale[mv])) if mv.any() else 0.0
            step *= min(1.0, self.radius / max(rel, 1e-300))
            pred = float(g @ step - 0.5 * step @ M @ step)
            if pred > 0:
                beta = self.beta + step
                r = self.prob.index["r"]
                beta[r] = np.maximum(beta[r], self.r_floor)  # a variance stays positive
                ev = self._evaluate(beta, jacobian=False)
                if ev is not None and np.isfinite(ev.cost) and cost - ev.cost > MIN_GAIN_RATIO * pred:
                    rho = (cost - ev.cost) / pred
                    self.lam *= max(1 / 3, 1 - (2 * rho - 1) ** 3)
                    if rho > 0.75 and rel >= 0.99 * self.radius:
                        self.radius = min(2 * self.radius, MAX_REL_STEP)
                    elif rho < 0.25:
                        self.radius = max(0.5 * self.radius, 1e-6)
                    self.beta = beta
                    return ev
                self.rejected += 1
            self.lam, nu = max(self.lam, INITIAL_DAMPING) * nu, 2 * nu
        return None


def _kept(tried: dict) -> str:
    """The first start at the best optimum (ties: the earlier start, the default first)."""
    low = min(v.history[-1] for v in tried.values())
    return next(k for k, v in tried.items() if v.history[-1] <= low + SAME_OPTIMUM)


def _state_terms(p: Profile) -> list[str]:
    """A profile's pseudo-inputs built from its states (products with a state factor)."""
    return [n for n, s in pi.specs(p).items() if set(s.get("product", ())) & set(p.states)]


def _stacked(mats: np.ndarray, series: np.ndarray) -> np.ndarray:
    """``mats`` (G, a, b) times ``series`` (L, b, R) for every g at once: (L, G, a, R), one matmul."""
    G, a, b = mats.shape
    return (mats.reshape(G * a, b) @ series).reshape(series.shape[0], G, a, series.shape[2])


COLOUR_FACTOR_LIMIT = 100.0  # a coloured std beyond this factor of the white one: the sandwich blew up


def _colour_failure(cov_c: np.ndarray, cov: np.ndarray, bounded: np.ndarray) -> str | None:
    """Why the coloured covariance ``cov_c`` cannot be used (None: it can): not finite, or a
    standard error off the Cramér-Rao one (``cov``) by more than COLOUR_FACTOR_LIMIT either way
    (an ill-conditioned sandwich, measured once on the piloted S 61: 1e24)."""
    c, w = np.diag(cov_c)[bounded], np.diag(cov)[bounded]
    if not np.all(np.isfinite(cov_c)):
        return "the coloured-innovation correction is not finite"
    ratio = np.sqrt(np.clip(c, 0, None) / np.maximum(w, 1e-300))
    if np.any((ratio > COLOUR_FACTOR_LIMIT) | (ratio < 1 / COLOUR_FACTOR_LIMIT)):
        return (f"the coloured-innovation correction changed a standard error by a factor "
                f"{ratio.min():.3g}..{ratio.max():.3g} (an ill-conditioned sandwich)")
    return None


def _covariance(M: np.ndarray, active: np.ndarray):
    """``M^-1`` on the active unknowns (scaled to unit diagonal; pseudo-inverse when ill
    conditioned, then listed), zeros elsewhere: ``(cov, ill)``."""
    a = active
    d = np.sqrt(np.diag(M)[a])
    Ms = M[np.ix_(a, a)] / np.outer(d, d)
    cov = np.zeros_like(M)
    ill = bool(np.linalg.cond(Ms) > 1e14)
    inv = np.linalg.pinv(Ms, hermitian=True) if ill else np.linalg.inv(Ms)
    cov[np.ix_(a, a)] = inv / np.outer(d, d)
    return cov, ill

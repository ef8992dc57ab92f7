"""Close the loop: find the structure left in the residuals, name the effect, add it, re-identify.

``Refine(profile).fit(runs, validate=val_runs)`` fits the declared model (ML by default), then
repeats:

1. residuals of every output on every run (the model simulated from the inputs by the segmented
   output-error engine :class:`identify.estimators.output_error.OutputError`, with each segment's initial state
   and, by default, each run's output zero shifts fitted by linear least squares weighted by each
   output's noise, as ML weights them);
2. a vector autoregressive noise model of those residuals (:mod:`identify.refine.noise`), and a score
   (Lagrange-multiplier) test of every candidate of the catalogue (:mod:`identify.refine.candidates`) at its
   null value in the metric of that noise model (a GLS score test, valid for coloured residuals:
   turbulence, filtered sensors), against the chi-square threshold at a Šidák-corrected family
   level ``alpha`` over all candidates tested;
3. the most significant candidate (nonlinear terms ranked below simpler explanations) is
   estimated (ML re-fit; a delay by a 1-D profile-likelihood search over tau, and a lag fitted
   too), and kept only if (a) the likelihood ratio of the re-fit in the same noise metric, (b) the
   Wald statistic of its estimate with ML's coloured-residual (Morelli-Klein) standard errors both
   exceed the threshold, (c) it lowers the error on the *choosing* part of the validation data and
   (d) it lowers the error on the *judging* part, which takes no other part in the loop;

until no candidate is significant, ``max_steps`` effects were added or ``3 max_steps`` candidates
were tried. Every try keeps its evidence (:class:`Step`).

Errors are RMS per output and ``overall`` = the RMS over outputs of each output's RMS divided by
the standard deviation of its measured signal on the fit runs (so outputs in different units
count alike); the same scale is used before and after and on validation runs. ``validation`` in
the error tables is the judging data.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import stats

from ..data.runs import Run
from ..errors import EstimationError, PseudostepError
from ..estimators.output_error import OutputError, auto_segment
from ..estimators.registry import estimator_class
from ..estimators.result import IdentificationResult
from ..model.linear import LinearModel
from ..model.profile import Profile, load_profile
from . import diagnostics as dg
from .candidates import KINDS, Candidate, Context, catalogue, extend_all, prepare_runs
from .noise import NoiseModel

MIN_SAMPLES = 50  # per run: fewer leave the residual tests without power
SIMPLER_FIRST = math.log(100.0)
TOP_ALTERNATIVE = 3  # candidates also tested in the metric of their own alternative noise model  # a nonlinear term ranks as if its p-value were 100 times larger


# -- evaluation of a model on runs (nuisance by linear least squares) -----------------------------
@dataclass
class Evaluation:
    """A profile's model on runs: ``residuals``/``modelled`` (N_r, ny) per run, ``x0`` (S_r, n)
    and ``bias`` (ny,) per run; with ``jacobian``: ``dy`` (N_r, ny, p) output sensitivities to the
    free parameters and ``nuisance`` (N_r, ny, n S_r [+ ny]) to the segment initial states and
    the zero shifts, per run (the columns of the score test)."""

    residuals: list[np.ndarray]
    modelled: list[np.ndarray]
    x0: list[np.ndarray]
    bias: list[np.ndarray]
    dy: list[np.ndarray] | None = None
    nuisance: list[np.ndarray] | None = None


def _problem(profile: Profile, runs: list[Run], segment: float, zero_shifts: bool, inputs=None) -> OutputError:
    u = [r.matrix(profile.input_names) for r in runs] if inputs is None else inputs
    z = [r.matrix(list(profile.outputs)) for r in runs]
    return OutputError(profile, u, z, runs[0].dt, segment, estimate_x0=True, estimate_bias=zero_shifts)


def _nuisance_columns(prob: OutputError, theta: np.ndarray) -> list[np.ndarray]:
    """d y / d (segment initial states, zero shifts) per run, (N_r, ny, n S_r [+ ny])."""
    lay, n, ny = prob.layout, prob.n, prob.ny
    resp = prob.initial_state_response(theta)
    out = []
    for r in range(prob.n_runs):
        segs = np.flatnonzero(lay.run == r)
        N = int(lay.length[segs].sum())
        cols = np.zeros((N, ny, n * len(segs) + (ny if prob.estimate_bias else 0)))
        for i, s in enumerate(segs):
            a, length = int(lay.start[s]), int(lay.length[s])
            cols[a:a + length, :, i * n:(i + 1) * n] = resp[:length]
        if prob.estimate_bias:
            cols[:, :, n * len(segs):] = np.eye(ny)
        out.append(cols)
    return out


def evaluate(profile: Profile, runs: list[Run], zero_shifts: bool = True, segment: float = math.inf,
             jacobian: bool = False) -> Evaluation:
    """Simulate the profile's model (a priori values = the estimates) over runs, each cut into
    segments of at most ``segment`` s (``inf``: whole runs) as ML cuts them; every segment's
    initial state and (``zero_shifts``) each run's output biases are the weighted least-squares
    fit to the measured outputs, exact because the outputs are linear in them."""
    prob = _problem(profile, runs, segment, zero_shifts)
    theta = LinearModel(profile).theta
    beta = np.concatenate([theta, np.zeros(prob.n_beta - prob.p)])
    forced = prob.per_run(prob.evaluate(beta, jacobian=False).y)
    nuis = _nuisance_columns(prob, theta)
    res, mod, x0s, biases, coefs = [], [], [], [], []
    n, ny = prob.n, prob.ny
    for run, y, nu in zip(runs, forced, nuis):
        z = run.matrix(list(profile.outputs))
        # weighted as ML weights them: outputs in different units and noise levels must not let
        # the largest numbers (m/s) set the initial states at the expense of the rest (rad);
        # weights from the channels' spread first, then relaxed once to the residuals' RMS
        w = 1.0 / np.maximum(z.std(axis=0), 1e-12)
        for _ in range(2):
            X = (nu * w[None, :, None]).reshape(-1, nu.shape[2])
            coef, *_ = np.linalg.lstsq(X, ((z - y) * w).ravel(), rcond=None)
            fitted = y + (nu.reshape(-1, nu.shape[2]) @ coef).reshape(z.shape)
            w = 1.0 / np.maximum(np.sqrt(np.mean((z - fitted) ** 2, axis=0)), 1e-12 * np.max(1 / w))
        res.append(z - fitted)
        mod.append(fitted)
        n_seg = (nu.shape[2] - (ny if zero_shifts else 0)) // n
        x0s.append(coef[:n * n_seg].reshape(n_seg, n))
        biases.append(coef[n * n_seg:] if zero_shifts else np.zeros(ny))
        coefs.append(coef)
    ev = Evaluation(res, mod, x0s, biases)
    if jacobian:
        full = np.concatenate([theta, np.concatenate([x.ravel() for x in x0s])]
                              + ([np.concatenate(biases)] if zero_shifts else []))
        jac = prob.evaluate(full, jacobian=True).dy_theta  # (L, ny, p, S) at the fitted x0
        L, _, p, S = jac.shape
        ev.dy = [d.reshape(len(d), ny, p) for d in prob.per_run(jac.reshape(L, ny * p, S))]
        ev.nuisance = nuis
    return ev


def unexplained(residuals: list[np.ndarray], shared: list[np.ndarray], nuisance: list[np.ndarray],
                sigma: np.ndarray) -> list[np.ndarray]:
    """Residuals (N_r, ny) per run minus their least-squares fit on the columns ``shared``
    (N_r, ny, k, common to all runs) and ``nuisance`` (N_r, ny, k_r, per run), weighted 1/sigma."""
    w = np.tile(1.0 / sigma, sum(len(e) for e in residuals))
    C = dg.block_design(shared, nuisance) * w[:, None]
    C /= np.maximum(np.linalg.norm(C, axis=0), 1e-300)
    e = np.concatenate([r.ravel() for r in residuals]) * w
    G = C.T @ C
    coef = np.linalg.solve(G + 1e-10 * np.trace(G) / len(G) * np.eye(len(G)), C.T @ e)
    clean = (e - C @ coef) / w
    parts = np.split(clean, np.cumsum([r.size for r in residuals])[:-1])
    return [c.reshape(r.shape) for c, r in zip(parts, residuals)]


def errors(evaluation: Evaluation, outputs, scale: np.ndarray) -> dict:
    """RMS error per output and the normalised ``overall`` (see the module docstring)."""
    E = np.vstack(evaluation.residuals)
    rms = np.sqrt(np.mean(E ** 2, axis=0))
    out = {y: float(r) for y, r in zip(outputs, rms)}
    out["overall"] = float(np.sqrt(np.mean((rms / scale) ** 2)))
    return out


def neg_log_likelihood(residuals: list[np.ndarray]) -> float:
    """Concentrated Gaussian negative log-likelihood with a diagonal noise covariance estimated
    from the residuals: (N/2) sum_y log(mean e_y^2)."""
    E = np.vstack(residuals)
    return 0.5 * E.shape[0] * float(np.sum(np.log(np.maximum(np.mean(E ** 2, axis=0), 1e-300))))


def split_validation(runs: list[Run]) -> tuple[list[Run], list[Run]]:
    """Validation runs into a *choosing* and a *judging* part: alternate runs when there are
    several; one run is cut in two halves in time (first half chooses) when each half keeps
    ``MIN_SAMPLES``, else it only judges."""
    if len(runs) >= 2:
        return runs[0::2], runs[1::2]
    if len(runs) == 1 and len(runs[0]) >= 2 * MIN_SAMPLES:
        r = runs[0]
        mid = r.time[len(r) // 2]
        first, second = r.slice(None, mid - 0.5 * r.dt), r.slice(mid, None)
        return ([replace(first, source=f"{r.source} [first half]")],
                [replace(second, source=f"{r.source} [second half]")])
    return [], list(runs)


# -- steps ----------------------------------------------------------------------------------------
@dataclass
class Step:
    """One tried effect with its evidence; ``accepted`` or rejected with the ``reason``."""

    effect: str
    target: str
    parameters: dict  # name -> {"value", "std"}
    statistic: float
    threshold: float
    dof: int
    p_value: float
    lr_statistic: float
    error_before: dict
    error_after: dict
    accepted: bool = True
    reason: str = ""
    tested: int = 0
    runner_up: list = field(default_factory=list)
    wald: float = float("nan")
    why: str = ""  # the physical reason of a nonlinear term
    noise_order: int = 0
    metric: str = "residual"  # the noise model of the test: of the residual, or of the candidate's alternative
    held_out: dict = field(default_factory=dict)  # data -> (cost before, cost after), noise-model metric

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("effect", "target", "parameters", "statistic", "threshold", "dof",
                                              "p_value", "lr_statistic", "wald", "error_before", "error_after",
                                              "held_out", "accepted", "reason", "tested", "runner_up", "why",
                                              "noise_order", "metric")}


class Refine:
    """Iterative model refinement (see the module docstring).

    Options: ``method`` (``ml``) or ``estimator`` (a class ``E(profile, **estimator_options)``
    with ``fit(runs).result_``); ``alpha`` family-wise false-alarm level per iteration (0.01);
    ``kinds`` the catalogue kinds to try; ``max_steps``; ``zero_shifts`` whether per-run output
    biases are nuisance parameters (then a common ``bias`` is not testable and is skipped);
    ``frequencies`` (Hz) known disturbance frequencies (else the periodic candidate's frequency
    is the residual spectrum's most prominent line above ``f_min`` Hz, counted as one test per
    frequency bin); ``tau_max`` (s) largest delay searched; ``segment`` (s) the multiple-shooting
    segment length used by every fit and test (default: ML's automatic choice for the declared
    model); ``coloured``: the tests in the metric of a noise model fitted to the residuals (True)
    or for white residuals (False, the classical tests); ``progress``: print step, candidate and
    elapsed time on stderr.

    After ``fit``: ``steps_`` (accepted :class:`Step` s), ``rejected_`` (candidates that passed the
    score test but failed a later check), ``tries_``, ``stopped_`` (the reason the loop ended),
    ``result_`` the final identification, ``profile_`` the final model (values = estimates),
    ``initial_result_``, ``error_before_``/``error_after_`` ({"fit", "choosing", "validation"}),
    ``data_`` (which runs fitted, chose and judged), ``diagnostics_``.
    """

    def __init__(self, profile: Profile | str | Path, method: str = "ml", estimator=None,
                 estimator_options: dict | None = None, alpha: float = 0.01, kinds=KINDS,
                 max_steps: int = 6, zero_shifts: bool = True, frequencies=None, f_min: float = 0.5,
                 tau_max: float = 0.5, nonlinear_products: bool = True, segment=None, coloured: bool = True,
                 progress: bool = False, verbose: bool = False):
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        unknown = set(kinds) - set(KINDS)
        if unknown:
            raise EstimationError(f"unknown effect kind(s) {', '.join(sorted(unknown))} "
                                  f"(catalogue: {', '.join(KINDS)})")
        if not 0 < alpha < 1:
            raise EstimationError(f"alpha must be between 0 and 1, got {alpha}")
        if not (isinstance(max_steps, (int, np.integer)) and max_steps >= 1):
            raise EstimationError(f"max_steps must be a positive integer, got {max_steps!r}")
        if not (tau_max > 0 and f_min >= 0 and all(f > 0 for f in (frequencies or []))):
            raise EstimationError("tau_max and the disturbance frequencies must be positive, f_min not negative")
        self.method = method
        self.estimator = estimator
        self.estimator_options = dict(estimator_options or {})
        self.alpha, self.kinds, self.max_steps = alpha, tuple(kinds), max_steps
        self.zero_shifts = zero_shifts
        self.frequencies = list(frequencies or [])
        self.f_min, self.tau_max = f_min, tau_max
        self.nonlinear_products = nonlinear_products
        self.segment = segment
        self.coloured = coloured
        self.progress = progress or verbose

    # -- public -------------------------------------------------------------------------------
    def fit(self, runs, validate=None) -> "Refine":
        runs = [runs] if isinstance(runs, Run) else list(runs)
        validate = [validate] if isinstance(validate, Run) else list(validate or [])
        self._started = time.perf_counter()
        self._check(runs, validate)
        choose, judge = split_validation(validate)
        self._data = {"fit": runs, "choosing": choose, "validation": judge}
        self._raw, self._val = runs, validate
        self._cache: dict = {}
        self.evaluations_ = 0
        self.data_ = {key: [r.source for r in rs] for key, rs in self._data.items()}
        self.segment_ = self._segment(runs)
        self._check_identifiable(self.profile)  # a priori values: before spending a fit on it
        self._say(f"fitting the declared model ({len(self.profile.free)} parameters, {len(runs)} runs)")
        est = self._estimate(self.profile, prepare_runs(self.profile, runs))
        self.initial_result_ = est
        current = _keep_meta(est.identified_profile(self.profile.name), self.profile)
        self._scale = np.array([np.std(np.concatenate([r[y] for r in runs])) or 1.0 for y in self.profile.outputs])
        self.steps_, self.rejected_ = [], []
        excluded: set[str] = set()
        ev0 = self._eval(current)
        self.error_before_ = self._errors(current)
        diag = {"before": self._diagnose(current, ev0)}
        result = est
        self.tries_ = 0
        self.last_scores_: list[dict] = []
        self.noise_orders_: list[int] = []
        while True:
            if len(self.steps_) >= self.max_steps:
                self.stopped_ = f"{self.max_steps} effects added (max_steps)"
                break
            if self.tries_ >= 3 * self.max_steps:
                self.stopped_ = (f"try limit: {self.tries_} candidates tried, {len(self.rejected_)} rejected "
                                 f"(3 x max_steps)")
                break
            self._say(f"step {len(self.steps_) + 1}: score tests")
            tested = self._score(current, excluded)
            self.last_scores_ = tested
            significant = [t for t in tested if t["statistic"] > t["threshold"]]
            if not significant:
                top = max(tested, key=lambda t: t["statistic"] / t["threshold"], default=None)
                self.stopped_ = "no candidate significant" + (
                    f" (closest: {top['candidate'].name}, score {top['statistic']:.3g} / threshold "
                    f"{top['threshold']:.3g})" if top else "")
                break
            best = min(significant, key=_rank)
            self.tries_ += 1
            self._say(f"step {len(self.steps_) + 1}: fitting {best['candidate'].name} "
                      f"(score {best['statistic']:.3g} > {best['threshold']:.3g}, try {self.tries_})")
            step, new_profile, new_result = self._try(current, best, tested)
            self._say(f"  {'accepted' if step.accepted else 'rejected: ' + step.reason}")
            if step.accepted:
                self.steps_.append(step)
                current, result = new_profile, new_result
            else:
                self.rejected_.append(step)
                excluded.add(best["candidate"].name)
        self.profile_ = current
        self.result_ = result
        self.error_after_ = self._errors(current)
        ev1 = self._eval(current)
        diag["after"] = self._diagnose(current, ev1)
        self.diagnostics_ = diag
        self.final_evaluation_ = {"fit": ev1, "before": ev0, "time": [r.time for r in runs]}
        self._say(f"done: {len(self.steps_)} added, {len(self.rejected_)} rejected; {self.stopped_}")
        return self

    @property
    def nothing_found(self) -> bool:
        return not self.steps_

    def _say(self, msg: str) -> None:
        if self.progress:
            print(f"refine [{time.perf_counter() - self._started:7.1f} s] {msg}", file=sys.stderr, flush=True)

    # -- checks ------------------------------------------------------------------------------
    def _check(self, runs: list[Run], validate: list[Run]) -> None:
        if not runs:
            raise EstimationError("refine: no runs given")
        for run in prepare_runs(self.profile, runs + validate):
            run.require(self.profile.channels, f"profile '{self.profile.name}'")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; refine needs at least "
                                      f"{MIN_SAMPLES} per run to test the residuals")

    def _check_identifiable(self, p: Profile) -> None:
        """The fitted model's parameters must be identifiable beside the nuisance: rank test of the
        weighted sensitivity matrix, naming the parameters in its null space."""
        ev = evaluate(p, prepare_runs(p, self._raw), self.zero_shifts, self.segment_, jacobian=True)
        J = dg.block_design(ev.dy, ev.nuisance)
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        Jw = J * np.tile(1 / np.where(sigma > 0, sigma, 1.0), len(J) // len(sigma))[:, None]
        names = p.free_names
        npar = len(names)
        # parameters beside the nuisance (initial states, zero shifts): project those out first, so
        # that an unobservable state's initial value is not mistaken for an unidentifiable parameter
        U, sn, _ = np.linalg.svd(Jw[:, npar:], full_matrices=False)
        Q = U[:, sn > 1e-10 * max(sn.max(initial=0.0), 1e-300)]
        Jp = Jw[:, :npar] - Q @ (Q.T @ Jw[:, :npar])
        Jp = Jp / np.maximum(np.linalg.norm(Jw[:, :npar], axis=0), 1e-300)
        _, s, Vt = np.linalg.svd(Jp, full_matrices=False)
        if s[-1] < 1e-7 * max(s[0], 1e-300) or s[0] == 0:
            null = Vt[s < 1e-7 * max(s[0], 1e-300)] if s[0] > 0 else Vt
            worst = [names[i] for i in np.flatnonzero(np.max(np.abs(null), axis=0) > 0.1)]
            raise EstimationError(f"profile '{p.name}': free parameters not identifiable from these runs "
                                  f"(no information separates {', '.join(worst)}); "
                                  f"fix some or add excitation")

    # -- estimation and evaluation -------------------------------------------------------------
    def _segment(self, runs: list[Run]) -> float:
        """One segmentation for every fit and test of the loop (ML's automatic choice for the
        declared model unless given), so that costs before and after a step compare."""
        seg = self.estimator_options.get("segment", self.segment)
        if seg is None:
            seg = auto_segment(LinearModel(self.profile), max(r.duration for r in runs)) \
                if self.estimator is None and self.method == "ml" else math.inf
        return math.inf if seg == "plain" else float(seg)

    def _estimate(self, profile: Profile, runs: list[Run], bounds: bool = True) -> IdentificationResult:
        """Fit ``profile``; ``bounds=False`` when only the estimate and its likelihood are used
        (the fits inside a delay search), which spares ML's coloured-residual correction."""
        cls = self.estimator or estimator_class(self.method)
        options = dict(self.estimator_options)
        if self.estimator is None and self.method == "ml":
            if not bounds:
                options.setdefault("coloured", False)
            # the same nuisance and the same segments as the score test and the evaluations, so
            # that likelihoods before and after a step compare
            options.setdefault("estimate_bias", self.zero_shifts)
            options.setdefault("segment", self.segment_)
        return cls(profile, **options).fit(runs).result_

    def _eval(self, p: Profile, data: str = "fit") -> Evaluation:
        """The profile on one data set (``fit``, ``choosing``, ``validation``) with the loop's
        segments and nuisance; every (model, data set) pair is simulated once."""
        key = (p.to_toml(), data)
        if key not in self._cache:
            self.evaluations_ += 1
            self._cache[key] = evaluate(p, prepare_runs(p, self._data[data]), self.zero_shifts, self.segment_)
        return self._cache[key]

    def _errors(self, p: Profile) -> dict:
        return {data: errors(self._eval(p, data), p.outputs, self._scale)
                for data in ("fit", "choosing", "validation") if self._data[data]}

    def _diagnose(self, p: Profile, ev: Evaluation) -> dict:
        dt = self._raw[0].dt
        white = dg.whiteness(ev.residuals)
        mt = dg.mean_trend(ev.residuals, [r.time for r in self._raw])
        sp = dg.spectral_peak(ev.residuals, dt, self.f_min)
        return {y: {"ljung_box_p": float(white["p_value"][j]), "mean": float(mt["mean"][j]),
                    "trend_per_s": float(mt["trend"][j]), "t_trend": float(mt["t_trend"][j]),
                    "peak_hz": float(sp["frequency"][j]), "peak_p": float(sp["p_value"][j])}
                for j, y in enumerate(p.outputs)}

    # -- score tests -------------------------------------------------------------------------
    def _candidates(self, p: Profile, runs: list[Run], ev: Evaluation, excluded: set[str]) -> list[Candidate]:
        context = Context(runs, ev.residuals, self.dt, self.f_min, tuple(self.frequencies), self.nonlinear_products)
        return [c for c in catalogue(p, context, self.kinds) if c.name not in excluded]

    def _score(self, p: Profile, excluded: set[str]) -> list[dict]:
        """Score statistic, threshold and p-value of every candidate at the fitted profile ``p``.

        Two noise models, hence two families of tests, Šidák-corrected together: the *residual*
        model (fitted to the residuals, lines and trends removed) tests every candidate; it is
        valid under the null, but where one effect dominates the residual the model learns the
        effect as colour (a 0.1 s delay in white noise: score 5477 in the white metric, 4 in this
        one). So the ``TOP_ALTERNATIVE`` candidates that explain most of the residual in the white
        metric are tested once more in the metric of an *alternative* model, fitted to the
        residuals with that candidate's own least-squares fit removed (one or two columns, which
        leave the noise estimate nearly unbiased under the null; removing every candidate's columns
        at once biased it so that smooth terms scored up to 75 for a threshold of 22)."""
        runs = prepare_runs(p, self._raw)
        ev = self._eval(p)
        cands = self._candidates(p, runs, ev, excluded)
        ext_p, linear = extend_all(p, [c for c in cands if c.linear])
        ext_runs = runs
        for c in linear:
            ext_runs = c.runs(ext_runs)
        evj = evaluate(ext_p, ext_runs, self.zero_shifts, self.segment_, jacobian=True)
        self.evaluations_ += 1
        # per run (N_r, ny, columns): the model's parameters, then every candidate's columns (the
        # output sensitivities of the extended profile, then those the other candidates supply)
        own = [(c, c.score_columns(self, p)) for c in cands if not c.linear]
        dy = [np.concatenate([d] + [cols[r] for _, cols in own], axis=2) for r, d in enumerate(evj.dy)]
        nb = len(p.free)
        col = {name: i - nb for i, name in enumerate(ext_p.free_names)}
        groups = [(c, [col[k] for k in c.params]) for c in linear]
        width = len(ext_p.free) - nb
        for c, cols in own:
            groups.append((c, list(range(width, width + cols[0].shape[2]))))
            width += cols[0].shape[2]
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        sigma = np.where(sigma > 0, sigma, 1.0)
        design = (ev.residuals, dy, evj.nuisance, nb)
        white = NoiseModel.white(sigma)
        null = NoiseModel.fit(ev.residuals, self.dt, self.f_min) if self.coloured else white
        self.noise_orders_.append(null.order)
        self._say(f"  {len(cands)} candidates, residual noise model order {null.order}")
        tested = self._tests(null, design, groups, "residual")
        if self.coloured:
            plain = sorted(self._tests(white, design, groups, "white"), key=lambda t: t["log_p"])
            for t in plain[:TOP_ALTERNATIVE]:
                c, cols = next(g for g in groups if g[0] is t["candidate"])
                keep = list(range(nb)) + [nb + k for k in cols]
                alt = NoiseModel.fit(unexplained(ev.residuals, [d[:, :, keep] for d in dy], evj.nuisance, sigma),
                                     self.dt, self.f_min)
                tested += self._tests(alt, design, [(c, cols)], "alternative")
        # Šidák over every elementary hypothesis of both families: a periodic candidate is the best
        # of n_tests frequencies, so it is compared with the same per-hypothesis threshold as the others
        n_tests = sum(t["candidate"].n_tests for t in tested)
        level = 1.0 - (1.0 - self.alpha) ** (1.0 / max(n_tests, 1))
        best: dict[str, dict] = {}
        for t in tested:
            t["n_tests"], t["level"] = n_tests, level
            t["threshold"] = dg.sidak_threshold(self.alpha, n_tests, t["dof"])
            t["p_value"] = float(math.exp(t["log_p"]))
            name = t["candidate"].name
            if name not in best or t["log_p"] < best[name]["log_p"]:
                best[name] = t
        return list(best.values())

    def _tests(self, noise: NoiseModel, design: tuple, groups: list[tuple], metric: str) -> list[dict]:
        """Score tests of candidate column ``groups`` in the metric of ``noise``; ``design`` =
        (residuals, per-run columns [model | candidates], per-run nuisance columns, model count)."""
        residuals, dy, nuisance, nb = design
        dyw = [noise.whiten(d) for d in dy]
        sb = dg.ScoreBase.build([noise.whiten(e) for e in residuals],
                                dg.block_design([d[:, :, :nb] for d in dyw], [noise.whiten(nu) for nu in nuisance]),
                                sigma=np.ones(len(noise.sigma)))
        J = np.concatenate([d[:, :, nb:].reshape(len(d) * d.shape[1], -1) for d in dyw])
        used = sorted({k for _, cols in groups for k in cols})
        where = {k: i for i, k in enumerate(used)}
        J = J[:, used]
        out = []
        for (c, cols), (stat, q) in zip(groups, sb.statistics(J, [[where[k] for k in cols] for _, cols in groups])):
            if q == 0:
                continue  # lies in the span of the model and its nuisance parameters: not testable
            q = max(q, c.null_dof or 0)
            out.append({"candidate": c, "statistic": stat, "dof": q, "log_p": float(stats.chi2.logsf(stat, q)),
                        "noise": noise, "metric": metric,
                        # a linearised estimate: where a non-linear candidate's search starts
                        "hint": None if c.linear else sb.linear_estimate(J[:, [where[cols[0]]]])})
        return out

    # -- what candidates ask of the loop ------------------------------------------------------
    @property
    def dt(self) -> float:
        return self._raw[0].dt

    def input_response(self, p: Profile, input_name: str, transform) -> list[np.ndarray]:
        """Per fit run (N_r, ny): the model's response to ``transform(u, dt)`` of one input (the
        others zero), each segment from rest (its initial state is a nuisance parameter anyway)."""
        runs = prepare_runs(p, self._raw)
        j = p.input_names.index(input_name)
        inputs = []
        for run in runs:
            u = np.zeros((len(run), len(p.inputs)))
            u[:, j] = transform(run[input_name], run.dt)
            inputs.append(u)
        prob = _problem(p, runs, self.segment_, False, inputs)
        beta = np.concatenate([LinearModel(p).theta, np.zeros(prob.n_beta - prob.p)])
        return prob.per_run(prob.evaluate(beta, jacobian=False).y)

    def refit(self, ext_p: Profile, p: Profile, bounds: bool = True) -> tuple[Profile, IdentificationResult]:
        """ML re-fit of an extended profile: the fitted profile (named as ``p``) and the result."""
        result = self._estimate(ext_p, prepare_runs(ext_p, self._raw), bounds=bounds)
        return _keep_meta(result.identified_profile(p.name), ext_p), result

    def residuals(self, p: Profile) -> list[np.ndarray]:
        return self._eval(p).residuals

    # -- one step ----------------------------------------------------------------------------
    def _try(self, p: Profile, best: dict, tested: list[dict]):
        """Estimate the selected candidate and check it: likelihood ratio and Wald statistic,
        error on the choosing data, then (once, for the option that passed) the judging data.

        A delay-type candidate yields two fits, delay and lag, tried in order of likelihood."""
        cand: Candidate = best["candidate"]
        noise = best["noise"]
        before = self._errors(p)
        runner_up = [{"effect": t["candidate"].kind, "target": t["candidate"].target,
                      "statistic": t["statistic"], "threshold": t["threshold"]}
                     for t in sorted(tested, key=_rank)[1:4]]
        common = dict(statistic=best["statistic"], threshold=best["threshold"], dof=best["dof"],
                      p_value=best["p_value"], tested=len(tested), runner_up=runner_up,
                      why=cand.spec.get("why", ""), metric=best["metric"])
        try:
            options = cand.estimate(self, p, noise, best["hint"])
        except PseudostepError as exc:  # e.g. an equation-error method and an output-only effect
            step = Step(cand.kind, cand.target, {}, lr_statistic=float("nan"), error_before=before,
                        error_after=before, accepted=False, reason=f"could not be estimated: {exc}", **common)
            return step, p, None
        first = None
        for new_p, result, params, kind in options:
            # in the metric of the noise model that selected the candidate: likelihood ratio on the
            # fit runs, prediction errors (twice the negative log-likelihood) on the held-out data
            lr = noise.cost(self.residuals(p)) - noise.cost(self.residuals(new_p))
            held = {data: (noise.cost(self._eval(p, data).residuals), noise.cost(self._eval(new_p, data).residuals))
                    for data in ("choosing", "validation") if self._data[data]}
            wald = float(sum((v["value"] / v["std"]) ** 2 if v["std"] > 0 else math.inf for v in params.values()))
            step = Step(kind, cand.target, params, lr_statistic=float(lr), error_before=before,
                        error_after=self._errors(new_p), wald=wald, held_out=held, noise_order=noise.order, **common)
            reason = self._refusal(step, stats.chi2.isf(best["level"], len(params)))
            if not reason:
                # the judging data see only the candidate the rest has chosen: once, pass or fail
                if "validation" in held and held["validation"][1] >= held["validation"][0]:
                    reason = ("did not lower the prediction error on the judging data (noise-model cost "
                              f"{held['validation'][0]:.6g} -> {held['validation'][1]:.6g})")
                step.accepted, step.reason = not reason, reason
                return step, new_p, result
            step.accepted, step.reason = False, reason
            first = first or (step, new_p, result)
        return first

    @staticmethod
    def _refusal(step: Step, wald_threshold: float) -> str:
        """Why a fitted candidate is refused before the judging data ('' if it is not)."""
        if step.lr_statistic < step.threshold:
            return (f"likelihood ratio {step.lr_statistic:.3g} of the re-fit (in the test's noise-model metric) "
                    f"below the threshold {step.threshold:.3g}")
        if step.wald < wald_threshold:
            return (f"estimate not significant by its coloured-residual bound (Wald {step.wald:.3g} < "
                    f"{wald_threshold:.3g})")
        if "choosing" in step.held_out and step.held_out["choosing"][1] >= step.held_out["choosing"][0]:
            b, a = step.held_out["choosing"]
            return f"prediction error on the choosing data not reduced (noise-model cost {b:.6g} -> {a:.6g})"
        return ""


def _rank(t: dict) -> tuple:
    """Order of preference among significant candidates: smallest p-value first, a nonlinear term
    (more complex than a derivative, delay, bias, drift, scale or vibration) as if its p-value were
    100 times larger."""
    return (t["log_p"] + SIMPLER_FIRST * t["candidate"].complexity, -t["statistic"])


def _keep_meta(p: Profile, template: Profile) -> Profile:
    """Identified profile with the template's meta (delays, pseudo-inputs, periodic frequencies)."""
    return replace(p, meta={**dict(p.meta), **dict(template.meta)})


__all__ = ["Refine", "Step", "Evaluation", "evaluate", "errors", "neg_log_likelihood", "estimator_class",
           "split_validation"]

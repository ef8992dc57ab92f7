"""Close the loop: find the structure left in the residuals, name the effect, add it, re-identify.

``Refine(profile).fit(runs, validate=val_runs)`` fits the declared model (ML by default), then
repeats:

1. residuals of every output on every run (the model simulated from the inputs, with each
   segment's initial state and, by default, each run's output zero shifts fitted by linear least
   squares weighted by each output's noise, as ML weights them);
2. a score (Lagrange-multiplier) test of every candidate of the catalogue
   (:mod:`identify.refine.candidates`) at its null value, from exact output sensitivities, against the
   chi-square threshold at a Šidák-corrected family level ``alpha`` over all candidates tested;
3. the most significant candidate is estimated (ML re-fit; a delay by a 1-D profile-likelihood
   search over tau with ML re-fits, and a lag fitted too — the better of the two is kept),
   confirmed by the likelihood-ratio of the re-fit at the same threshold, and checked on the
   validation runs: an effect that does not reduce their error is rejected;

until no candidate is significant. Every step keeps its evidence (:class:`Step`). Residual
whiteness, mean/trend and spectral peaks before and after are in ``diagnostics_``.

Errors are RMS per output and ``overall`` = the RMS over outputs of each output's RMS divided by
the standard deviation of its measured signal on the fit runs (so outputs in different units
count alike); the same scale is used before and after and on validation runs.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import stats

from ..data.runs import Run
from ..errors import EstimationError, PseudostepError
from ..estimators.output_error import auto_segment, cut
from ..estimators.registry import estimator_class
from ..estimators.result import IdentificationResult
from ..model.linear import LinearModel
from ..model.profile import Profile, load_profile
from ..model.sensitivity import output_sensitivities
from . import diagnostics as dg
from .candidates import KINDS, Candidate, Delay, Lag, Periodic, catalogue, prepare_runs

MIN_SAMPLES = 50  # per run: fewer leave the residual tests without power


# -- evaluation of a model on runs (nuisance by linear least squares) -----------------------------
@dataclass
class Evaluation:
    """A profile's model on runs: ``residuals``/``modelled`` (N_r, ny) per run, ``x0`` (n,) and
    ``bias`` (ny,) per run, ``sens`` the output sensitivities used (for the score test)."""

    residuals: list[np.ndarray]
    modelled: list[np.ndarray]
    x0: list[np.ndarray]  # (S, n) per run: one initial state per segment
    bias: list[np.ndarray]


def segments(n_samples: int, dt: float, segment: float) -> list[slice]:
    """Sample ranges of one run cut as multiple-shooting ML cuts it (:func:`identify.estimators.output_error.cut`)."""
    lay = cut([n_samples], dt, segment)
    return [slice(int(a), int(a + n)) for a, n in zip(lay.start, lay.length)]


def run_design(model: LinearModel, u: np.ndarray, dt: float, segs: list[slice], x0s=None,
               zero_shifts: bool = True, sensitivities: bool = True):
    """Outputs and sensitivities of one run, each segment simulated from its own initial state.

    Returns ``y`` (N, ny), ``dy`` (N, ny, p) (None unless ``sensitivities``) and ``nuis``
    (N, ny, n S [+ ny]): d y / d x0 of every segment (zero outside it) and, with ``zero_shifts``,
    d y / d bias."""
    n, ny = model.n_states, model.n_outputs
    N = len(u)
    x0s = np.zeros((len(segs), n)) if x0s is None else np.asarray(x0s).reshape(len(segs), n)
    y = np.zeros((N, ny))
    dy = np.zeros((N, ny, len(model.names))) if sensitivities else None
    nuis = np.zeros((N, ny, n * len(segs) + (ny if zero_shifts else 0)))
    target = model if sensitivities else _fixed(model)
    for i, (sg, x0) in enumerate(zip(segs, x0s)):
        s = output_sensitivities(target, u[sg], dt, x0, initial_state=True)
        y[sg] = s.y
        if sensitivities:
            dy[sg] = s.dy
        nuis[sg, :, i * n:(i + 1) * n] = s.dy_x0
    if zero_shifts:
        nuis[:, :, n * len(segs):] = np.eye(ny)
    return y, dy, nuis


def evaluate(profile: Profile, runs: list[Run], zero_shifts: bool = True, segment: float = math.inf) -> Evaluation:
    """Simulate the profile's model (a priori values = the estimates) over runs, each cut into
    segments of at most ``segment`` s (``inf``: whole runs) as ML cuts them; every segment's
    initial state and (``zero_shifts``) each run's output biases are the weighted least-squares
    fit to the measured outputs, exact because the outputs are linear in them."""
    model = LinearModel(profile)
    res, mod, x0s, biases = [], [], [], []
    ny, n = model.n_outputs, model.n_states
    for run in runs:
        u = run.matrix(profile.input_names)
        z = run.matrix(list(profile.outputs))
        segs = segments(len(run), run.dt, segment)
        y, _, nuis = run_design(model, u, run.dt, segs, zero_shifts=zero_shifts, sensitivities=False)
        # weighted as ML weights them: outputs in different units and noise levels must not let
        # the largest numbers (m/s) set the initial states at the expense of the rest (rad);
        # weights from the channels' spread first, then relaxed once to the residuals' RMS
        w = 1.0 / np.maximum(z.std(axis=0), 1e-12)
        for _ in range(2):
            X = (nuis * w[None, :, None]).reshape(-1, nuis.shape[2])
            beta, *_ = np.linalg.lstsq(X, ((z - y) * w).ravel(), rcond=None)
            fitted = y + (nuis.reshape(-1, nuis.shape[2]) @ beta).reshape(z.shape)
            w = 1.0 / np.maximum(np.sqrt(np.mean((z - fitted) ** 2, axis=0)), 1e-12 * np.max(1 / w))
        y = fitted
        res.append(z - y)
        mod.append(y)
        x0s.append(beta[:n * len(segs)].reshape(len(segs), n))
        biases.append(beta[n * len(segs):] if zero_shifts else np.zeros(ny))
    return Evaluation(res, mod, x0s, biases)


def _fixed(model: LinearModel) -> LinearModel:
    """The same matrices without free parameters (no sensitivities to compute)."""
    p = model.profile
    values = dict(zip(model.names, map(float, model.theta)))
    return LinearModel(replace(p, free={}, fixed={**p.fixed, **values}))


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


# -- steps ----------------------------------------------------------------------------------------
@dataclass
class Step:
    """One accepted (or rejected) effect with its evidence."""

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

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in ("effect", "target", "parameters", "statistic", "threshold", "dof",
                                              "p_value", "lr_statistic", "error_before", "error_after",
                                              "accepted", "reason", "tested", "runner_up")}


class Refine:
    """Iterative model refinement (see the module docstring).

    Options: ``method`` (``ml``) or ``estimator`` (a class ``E(profile, **estimator_options)``
    with ``fit(runs).result_``); ``alpha`` family-wise false-alarm level per iteration (0.01);
    ``kinds`` the catalogue kinds to try; ``max_steps``; ``zero_shifts`` whether per-run output
    biases are nuisance parameters (then a common ``bias`` is not testable and is skipped);
    ``frequencies`` (Hz) known disturbance frequencies (else the periodic candidate's frequency
    is the residual spectrum's peak above ``f_min`` Hz, counted as one test per frequency bin);
    ``tau_max`` (s) largest delay searched; ``segment`` (s) the multiple-shooting segment length
    used by every fit and test (default: ML's automatic choice for the declared model).

    After ``fit``: ``steps_`` (accepted :class:`Step` s), ``rejected_`` (candidates that passed the
    score test but failed the likelihood-ratio or validation check), ``result_`` the final
    identification, ``profile_`` the final model (values = estimates), ``initial_result_``,
    ``error_before_``/``error_after_`` ({"fit": ..., "validation": ...}), ``diagnostics_``.
    """

    def __init__(self, profile: Profile | str | Path, method: str = "ml", estimator=None,
                 estimator_options: dict | None = None, alpha: float = 0.01, kinds=KINDS,
                 max_steps: int = 6, zero_shifts: bool = True, frequencies=None, f_min: float = 0.5,
                 tau_max: float = 0.5, nonlinear_products: bool = True, segment=None, verbose: bool = False):
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
        self.verbose = verbose

    # -- public -------------------------------------------------------------------------------
    def fit(self, runs, validate=None) -> "Refine":
        runs = [runs] if isinstance(runs, Run) else list(runs)
        validate = [validate] if isinstance(validate, Run) else list(validate or [])
        self._check(runs, validate)
        self._raw, self._val = runs, validate
        self.segment_ = self._segment(runs)
        self._check_identifiable(self.profile)  # a priori values: before spending a fit on it
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
        tries = 0
        self.stopped_ = "step limit reached"
        self.last_scores_: list[dict] = []
        while len(self.steps_) < self.max_steps and tries < 3 * self.max_steps:
            tries += 1
            tested = self._score(current, excluded)
            significant = [t for t in tested if t["statistic"] > t["threshold"]]
            if not significant:
                self.stopped_, self.last_scores_ = "no candidate significant", tested
                break
            best = min(significant, key=lambda t: (t["log_p"], -t["statistic"]))
            step, new_profile, new_result = self._try(current, best, tested)
            if step.accepted:
                self.steps_.append(step)
                current, result = new_profile, new_result
            else:
                self.rejected_.append(step)
                excluded.add(best["candidate"].name)
        self.profile_ = current
        self.result_ = result
        self.error_after_ = self._errors(current)
        diag["after"] = self._diagnose(current, self._eval(current))
        self.diagnostics_ = diag
        self.final_evaluation_ = {
            "fit": self._eval(current),
            "before": ev0,
            "time": [r.time for r in runs],
        }
        return self

    @property
    def nothing_found(self) -> bool:
        return not self.steps_

    # -- checks ------------------------------------------------------------------------------
    def _check(self, runs: list[Run], validate: list[Run]) -> None:
        if not runs:
            raise EstimationError("refine: no runs given")
        for run in runs + validate:
            run.require(self.profile.channels, f"profile '{self.profile.name}'")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; refine needs at least "
                                      f"{MIN_SAMPLES} per run to test the residuals")

    def _check_identifiable(self, p: Profile) -> None:
        """The fitted model's parameters must be identifiable beside the nuisance: rank test of the
        weighted sensitivity matrix, naming the parameters in its null space."""
        runs = prepare_runs(p, self._raw)
        ev = evaluate(p, runs, self.zero_shifts, self.segment_)
        model = LinearModel(p)
        shared, nuis = [], []
        for run, x0 in zip(runs, ev.x0):
            _, dy, nu = run_design(model, run.matrix(p.input_names), run.dt,
                                   segments(len(run), run.dt, self.segment_), x0, self.zero_shifts)
            shared.append(dy)
            nuis.append(nu)
        J = dg.block_design(shared, nuis)
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        Jw = J * np.tile(1 / np.where(sigma > 0, sigma, 1.0), len(J) // len(sigma))[:, None]
        npar = len(model.names)
        # parameters beside the nuisance (initial states, zero shifts): project those out first, so
        # that an unobservable state's initial value is not mistaken for an unidentifiable parameter
        U, sn, _ = np.linalg.svd(Jw[:, npar:], full_matrices=False)
        Q = U[:, sn > 1e-10 * max(sn.max(initial=0.0), 1e-300)]
        Jp = Jw[:, :npar] - Q @ (Q.T @ Jw[:, :npar])
        Jp = Jp / np.maximum(np.linalg.norm(Jw[:, :npar], axis=0), 1e-300)
        _, s, Vt = np.linalg.svd(Jp, full_matrices=False)
        if s[-1] < 1e-7 * max(s[0], 1e-300) or s[0] == 0:
            null = Vt[s < 1e-7 * max(s[0], 1e-300)] if s[0] > 0 else Vt
            worst = [model.names[i] for i in np.flatnonzero(np.max(np.abs(null), axis=0) > 0.1)]
            raise EstimationError(f"profile '{p.name}': free parameters not identifiable from these runs "
                                  f"(no information separates {', '.join(worst)}); "
                                  f"fix some or add excitation")

    # -- estimation --------------------------------------------------------------------------
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

    def _eval(self, p: Profile, runs: list[Run] | None = None) -> Evaluation:
        """The profile on the fit runs (or ``runs``), with the loop's segments and nuisance."""
        return evaluate(p, prepare_runs(p, self._raw if runs is None else runs), self.zero_shifts, self.segment_)

    def _errors(self, p: Profile) -> dict:
        out = {"fit": errors(self._eval(p), p.outputs, self._scale)}
        if self._val:
            out["validation"] = errors(self._eval(p, self._val),
                                       p.outputs, self._scale)
        return out

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
        cands = [c for c in catalogue(p, runs, self.kinds, self.nonlinear_products) if c.name not in excluded]
        if "periodic" in self.kinds:
            cands += [c for c in self._periodic(p, ev) if c.name not in excluded]
        return cands

    def _periodic(self, p: Profile, ev: Evaluation) -> list[Periodic]:
        dt = self._raw[0].dt
        done = set(dict(p.meta.get("periodic", {})))
        out = []
        for j, y in enumerate(p.outputs):
            if y in done:
                continue
            if self.frequencies:
                out += [Periodic(y, f, n_runs=len(self._raw)) for f in self.frequencies[:1]]
                continue
            f = dg.dominant_frequency([e[:, j] for e in ev.residuals], dt, self.f_min)
            n_bins = int(np.sum((np.fft.rfftfreq(min(len(e) for e in ev.residuals), dt) > self.f_min)))
            # the frequency was chosen as the spectrum's maximum: count every bin as a test, twice
            # for the sub-bin search
            out.append(Periodic(y, f, n_tests=2 * max(n_bins, 1), n_runs=len(self._raw)))
        return out

    def _score(self, p: Profile, excluded: set[str]) -> list[dict]:
        """Score statistic, threshold and p-value of every candidate at the fitted profile ``p``."""
        runs = prepare_runs(p, self._raw)
        ev = evaluate(p, runs, self.zero_shifts, self.segment_)
        cands = self._candidates(p, runs, ev, excluded)
        linear = []
        ext_p, ext_runs = p, runs
        for c in cands:
            if not c.linear:
                continue
            try:
                ext_p, ext_runs = c.apply(ext_p, ext_runs)
                linear.append(c)
            except PseudostepError:
                continue  # a candidate that cannot be built on these runs is not tested
        model = LinearModel(ext_p)
        base_idx = list(range(len(p.free)))
        col = {name: i for i, name in enumerate(model.names)}
        shared, nuis, cand_cols = [], [], []
        base_model = LinearModel(p)
        for run, ext_run, x0 in zip(runs, ext_runs, ev.x0):
            segs = segments(len(run), run.dt, self.segment_)
            _, dy, nu = run_design(model, ext_run.matrix(ext_p.input_names), run.dt, segs, x0, self.zero_shifts)
            shared.append(dy[:, :, base_idx])
            nuis.append(nu)
            cand_cols.append(dy)
        sb = dg.ScoreBase.build(ev.residuals, dg.block_design(shared, nuis))
        stack = lambda arrs: np.concatenate([a.reshape(-1, a.shape[-1]) for a in arrs])  # noqa: E731
        Jall = stack(cand_cols)
        tested = []
        for c in cands:
            if c.linear and c in linear:
                Jc = Jall[:, [col[k] for k in c.params]]
            elif isinstance(c, Delay):
                Jc = stack([self._delay_sensitivity(base_model, run, c.target)[:, :, None] for run in runs])
            else:
                continue
            stat, q = sb.statistic(Jc)
            if q == 0:
                continue  # lies in the span of the model and its nuisance parameters: not testable
            if isinstance(c, Delay):
                c.spec["tau0"] = sb.linear_estimate(Jc)
            q = max(q, c.null_dof or 0)
            tested.append({"candidate": c, "statistic": stat, "dof": q,
                           "log_p": float(stats.chi2.logsf(stat, q))})
        # Šidák over every elementary hypothesis: a periodic candidate is the best of n_tests
        # frequencies, so it is compared with the same per-hypothesis threshold as the others
        n_tests = sum(t["candidate"].n_tests for t in tested)
        for t in tested:
            t["n_tests"] = n_tests
            t["threshold"] = dg.sidak_threshold(self.alpha, n_tests, t["dof"])
            t["p_value"] = float(math.exp(t["log_p"]))
        if self.verbose:
            top = sorted(tested, key=lambda t: t["log_p"])[:5]
            print("score:", [(t["candidate"].name, round(t["statistic"], 1), round(t["threshold"], 1))
                             for t in top])
        return tested

    def _delay_sensitivity(self, model: LinearModel, run: Run, input_name: str) -> np.ndarray:
        """dy/dtau at tau = 0: the response to -du/dt of the delayed input (N, ny), each segment
        from rest (its initial state is a nuisance parameter anyway)."""
        p = model.profile
        u = np.zeros((len(run), model.n_inputs))
        j = p.input_names.index(input_name)
        u[:, j] = -np.gradient(run[input_name], run.dt)
        y, _, _ = run_design(model, u, run.dt, segments(len(run), run.dt, self.segment_), sensitivities=False)
        return y

    # -- one step ----------------------------------------------------------------------------
    def _try(self, p: Profile, best: dict, tested: list[dict]):
        """Estimate the selected candidate and check it (likelihood ratio, validation runs).

        A delay-type candidate yields two fits, delay and lag, tried in order of likelihood: the
        first that passes both checks is kept."""
        cand: Candidate = best["candidate"]
        nll0 = neg_log_likelihood(self._eval(p).residuals)
        before = self._errors(p)
        runner_up = [{"effect": t["candidate"].kind, "target": t["candidate"].target,
                      "statistic": t["statistic"], "threshold": t["threshold"]}
                     for t in sorted(tested, key=lambda t: t["log_p"])[1:4]]
        try:
            if isinstance(cand, Delay):
                options = self._fit_delay_or_lag(p, cand)
            else:
                ext_p, _ = cand.apply(p, [])
                result = self._estimate(ext_p, prepare_runs(ext_p, self._raw))
                new_p = _keep_meta(result.identified_profile(p.name), ext_p)
                params = {k: {"value": float(result.theta[result.names.index(k)]),
                              "std": float(result.std[result.names.index(k)])} for k in cand.params}
                options = [(neg_log_likelihood(self._eval(new_p).residuals), new_p, result, params, cand.kind)]
        except PseudostepError as exc:  # e.g. an equation-error method and an output-only effect
            step = Step(cand.kind, cand.target, {}, best["statistic"], best["threshold"], best["dof"],
                        best["p_value"], float("nan"), before, before, accepted=False,
                        reason=f"could not be estimated: {exc}", tested=len(tested), runner_up=runner_up)
            return step, p, None
        first = None
        for nll1, new_p, result, params, kind in options:
            lr = 2 * (nll0 - nll1)
            after = self._errors(new_p)
            step = Step(kind, cand.target, params, best["statistic"], best["threshold"], best["dof"],
                        best["p_value"], float(lr), before, after, tested=len(tested), runner_up=runner_up)
            if lr < best["threshold"]:
                step.accepted, step.reason = False, (f"likelihood-ratio {lr:.3g} of the re-fit below the "
                                                     f"threshold {best['threshold']:.3g}")
            elif self._val and after["validation"]["overall"] >= before["validation"]["overall"]:
                step.accepted, step.reason = False, (
                    f"validation error not reduced ({before['validation']['overall']:.4g} -> "
                    f"{after['validation']['overall']:.4g})")
            if self.verbose:
                print(f"step {kind}:{cand.target} {params} LR={lr:.1f} accepted={step.accepted} {step.reason}")
            first = first or (step, new_p, result)
            if step.accepted:
                return step, new_p, result
        return first

    def _nll(self, p: Profile) -> float:
        return neg_log_likelihood(self._eval(p).residuals)

    def _fit_delay_or_lag(self, p: Profile, cand: Delay) -> list[tuple]:
        """Delay by profile likelihood (ML re-fit at each tau), lag by ML: both fits as
        ``(nll, profile, result, parameters, kind)``, the more likely first."""
        dt = self._raw[0].dt
        fits: dict[float, tuple] = {}

        def at(tau: float):
            key = round(float(tau), 9)
            if key not in fits:
                d = Delay(cand.target, tau)
                ext_p = d.profile(p, {d.params[0]: tau})
                res = self._estimate(ext_p, prepare_runs(ext_p, self._raw), bounds=False)
                prof = _keep_meta(res.identified_profile(p.name), ext_p)
                fits[key] = (self._nll(prof), prof, res)
            return fits[key]

        options = []
        if "delay" in self.kinds:
            tau = self._search_delay(at, best_tau0=cand.spec.get("tau0", 0.0), dt=dt)
            # Cramér-Rao bound from the curvature of the profile likelihood (central difference,
            # shifted off the bound tau = 0)
            h = max(dt / 2, 0.05 * tau)
            c = tau if tau >= h else h
            curv = (at(c + h)[0] - 2 * at(c)[0] + at(c - h)[0]) / h ** 2
            std = 1 / math.sqrt(curv) if curv > 0 else math.inf
            nll, prof, _ = at(tau)
            res = self._estimate(prof, prepare_runs(prof, self._raw))  # the same fit, with its bounds
            options.append((nll, prof, res, {f"tau_{cand.target}": {"value": tau, "std": std}}, "delay"))
        if "lag" in self.kinds:
            tau0 = options[0][3][f"tau_{cand.target}"]["value"] if options else 0.1
            lag = Lag(cand.target, k=1.0 / max(tau0, 2 * dt))
            ext_p = lag.profile(p)
            try:
                res = self._estimate(ext_p, prepare_runs(ext_p, self._raw))
                prof = _keep_meta(res.identified_profile(p.name), ext_p)
                i = res.names.index(lag.params[0])
                options.append((self._nll(prof), prof, res,
                                {lag.params[0]: {"value": float(res.theta[i]), "std": float(res.std[i])}}, "lag"))
            except PseudostepError:
                pass  # a lag that diverges or cannot be fitted is not the effect
        if not options:
            raise EstimationError(f"neither a delay nor a lag on '{cand.target}' could be fitted")
        return sorted(options, key=lambda o: o[0])


    def _search_delay(self, nll_at, best_tau0: float, dt: float) -> float:
        """Minimise the profile likelihood over tau in [0, tau_max]: a coarse grid first (the
        score test's linearised estimate ``best_tau0`` is only good for small delays, and the
        profile likelihood of a large one is not quadratic from 0), then successive parabolas
        through three ML re-fits around the best grid point."""
        f = lambda t: nll_at(float(np.clip(t, 0.0, self.tau_max)))[0]  # noqa: E731
        grid = np.unique(np.clip(np.r_[np.linspace(0.0, self.tau_max, 11), best_tau0], 0.0, self.tau_max))
        tau = float(min(grid, key=f))
        h = max(dt, 0.5 * self.tau_max / 10)
        for _ in range(6):
            pts = np.clip([tau - h, tau, tau + h], 0.0, self.tau_max)
            vals = [f(t) for t in pts]
            with warnings.catch_warnings():  # repeated points at the bounds: the fallback handles it
                warnings.simplefilter("ignore", np.exceptions.RankWarning)
                a, b, _ = np.polyfit(pts, vals, 2)
            new = -b / (2 * a) if a > 0 else pts[int(np.argmin(vals))]
            new = float(np.clip(new, max(tau - 2 * h, 0.0), min(tau + 2 * h, self.tau_max)))
            done = abs(new - tau) < dt / 100  # well inside the statistical error of any usable delay
            tau, h = new, max(dt / 10, min(h, 2 * abs(new - tau)))
            if done:
                break
        # keep the best point evaluated (the parabola may overshoot on a rough cost)
        cands = [tau] + [t for t in np.clip([tau - h, tau + h], 0, self.tau_max)]
        return float(min(cands, key=f))


def _keep_meta(p: Profile, template: Profile) -> Profile:
    """Identified profile with the template's meta (delays, pseudo-inputs, periodic frequencies)."""
    return replace(p, meta={**dict(p.meta), **dict(template.meta)})


__all__ = ["Refine", "Step", "Evaluation", "evaluate", "errors", "neg_log_likelihood", "estimator_class"]

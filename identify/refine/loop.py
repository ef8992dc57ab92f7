"""Close the loop: find the structure left in the residuals, name the effect, add it, re-identify.

``Refine(profile).fit(runs, validate=val_runs)`` fits the declared model (ML by default), then repeats:

1. residuals of every output on every run, a true prediction (:mod:`identify.refine.evaluation`: the
   model simulated from the inputs, each segment's initial state and each run's zero shifts fitted,
   terms built from states computed from the model's simulated states, never the measured ones);
2. a vector autoregressive noise model of those residuals (:mod:`identify.refine.noise`), and a score
   test of every candidate (:mod:`identify.refine.candidates`) at its null value in that noise model's
   metric (a GLS score test, valid for coloured residuals), against the chi-square threshold at a
   Šidák-corrected family level ``alpha`` over all candidates tested;
3. the most significant candidate (nonlinear terms ranked below simpler explanations) is
   estimated (ML re-fit; a delay by a profile-likelihood search over tau, and a lag fitted too),
   and kept only if (a) the likelihood ratio of the re-fit in the same metric, (b) the Wald
   statistic of its estimate with ML's coloured-residual (Morelli-Klein) bounds both exceed the
   threshold, (c) it lowers the prediction error on the *choosing* part of the validation data and
   (d) on the *judging* part (no other part in the loop), each by more than the 95 % chi-square
   quantile of its parameter count;

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
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

from ..data.runs import Run
from ..errors import ConvergenceWarning, EstimationError, PseudostepError
from ..estimators.output_error import auto_segment
from ..estimators.registry import estimator_class
from ..estimators.result import IdentificationResult
from ..model.linear import LinearModel
from ..model.profile import Profile, load_profile
from . import diagnostics as dg
from .candidates import KINDS, Candidate, Context, Delay, catalogue, extend_all, prepare_runs
from .evaluation import (MIN_SAMPLES, ModelFit, check_identifiable, errors, evaluate, feedback_bounds, input_response,
                         predict, settle, simulated_terms, split_validation, state_terms, unexplained)
from .noise import NoiseModel
from .steps import Step

SIMPLER_FIRST = math.log(100.0)  # a nonlinear term ranks as if its p-value were 100 times larger
TOP_ALTERNATIVE = 3  # candidates also tested in the metric of their own alternative noise model


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
        self.profile = profile
        self.method = method
        self.estimator = estimator
        self.estimator_options = estimator_options
        self.alpha, self.kinds, self.max_steps = alpha, kinds, max_steps
        self.zero_shifts = zero_shifts
        self.frequencies = frequencies
        self.f_min, self.tau_max = f_min, tau_max
        self.nonlinear_products = nonlinear_products
        self.segment = segment
        self.coloured = coloured
        self.progress = progress
        self.verbose = verbose

    # -- public -------------------------------------------------------------------------------
    def fit(self, runs, validate=None) -> "Refine":
        runs = [runs] if isinstance(runs, Run) else list(runs)
        validate = [validate] if isinstance(validate, Run) else list(validate or [])
        self._started = time.perf_counter()
        self._validate_options()
        self.unconverged_: list[str] = []
        self._check(runs, validate)
        choose, judge = split_validation(validate)
        self._data = {"fit": runs, "choosing": choose, "validation": judge}
        self._raw, self._val = runs, validate
        self._cache: dict = {}
        self.evaluations_ = 0
        self.data_ = {key: [r.source for r in rs] for key, rs in self._data.items()}
        self.segment_ = self._segment(runs)
        # a priori values: before spending a fit on it
        check_identifiable(self.declared_, prepare_runs(self.declared_, runs), self.zero_shifts, self.segment_)
        self._say(f"fitting the declared model ({len(self.declared_.free)} parameters, {len(runs)} runs)")
        current, est = self.refit(self.declared_, self.declared_)
        if self._segment(runs, current) < self.segment_:  # the fit diverges faster than the a priori
            self.segment_ = self._segment(runs, current)
            self._say(f"the fitted model diverges faster: segments cut to {self.segment_:.3g} s, re-fitting")
            current, est = self.refit(self.declared_, self.declared_)
        self.initial_result_ = est
        self._scale = np.array([np.std(np.concatenate([r[y] for r in runs])) or 1.0 for y in self.declared_.outputs])
        self.steps_, self.rejected_ = [], []
        excluded: set[str] = set()
        ev0 = self._eval(current)
        self.error_before_ = self._errors(current)
        diag = {"before": dg.summary(ev0.residuals, [r.time for r in runs], self.dt, self.f_min, current.outputs)}
        result = est
        self.tries_ = 0
        self.last_scores_: list[dict] = []
        self.noise_orders_, self.noise_white_ = [], []  # per step: the order, whether its innovations were white
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
                noise = best["noise"]
            else:
                self.rejected_.append(step)
                excluded.add(best["candidate"].name)
        if sum(s.effect == "delay" for s in self.steps_) > 1:
            current, result = self._reestimate_delays(current, result, noise)
        self.profile_ = current
        self.result_ = result
        self.error_after_ = self._errors(current)
        ev1 = self._eval(current)
        diag["after"] = dg.summary(ev1.residuals, [r.time for r in runs], self.dt, self.f_min, current.outputs)
        self.diagnostics_ = diag
        self.final_evaluation_ = {"fit": ev1, "before": ev0, "time": [r.time for r in runs]}
        self._say(f"done: {len(self.steps_)} added, {len(self.rejected_)} rejected; {self.stopped_}")
        return self

    @property
    def nothing_found(self) -> bool:
        return not self.steps_

    def _say(self, msg: str) -> None:
        if self.progress or self.verbose:
            print(f"refine [{time.perf_counter() - self._started:7.1f} s] {msg}", file=sys.stderr, flush=True)

    # -- checks ------------------------------------------------------------------------------
    def _validate_options(self) -> None:
        """Options checked and normalised at ``fit`` (scikit-learn style: ``__init__`` only stores)."""
        unknown = set(self.kinds) - set(KINDS)
        if unknown:
            raise EstimationError(f"unknown effect kind(s) {', '.join(sorted(unknown))} "
                                  f"(catalogue: {', '.join(KINDS)})")
        if not 0 < self.alpha < 1:
            raise EstimationError(f"alpha must be between 0 and 1, got {self.alpha}")
        if not (isinstance(self.max_steps, (int, np.integer)) and self.max_steps >= 1):
            raise EstimationError(f"max_steps must be a positive integer, got {self.max_steps!r}")
        if not (self.tau_max > 0 and self.f_min >= 0 and all(f > 0 for f in (self.frequencies or []))):
            raise EstimationError("tau_max and the disturbance frequencies must be positive, f_min not negative")
        self.declared_ = self.profile if isinstance(self.profile, Profile) else load_profile(self.profile)
        self._kinds, self._frequencies = tuple(self.kinds), tuple(self.frequencies or ())
        self._estimator_options = dict(self.estimator_options or {})

    def _check(self, runs: list[Run], validate: list[Run]) -> None:
        if not runs:
            raise EstimationError("refine: no runs given")
        for run in prepare_runs(self.declared_, runs + validate):
            run.require(self.declared_.channels, f"profile '{self.declared_.name}'")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; refine needs at least "
                                      f"{MIN_SAMPLES} per run to test the residuals")

    # -- estimation and evaluation -------------------------------------------------------------
    def _segment(self, runs: list[Run], fitted: Profile | None = None) -> float:
        """One segmentation for every fit and test of the loop (ML's automatic choice for the
        declared model, or for its first ``fitted`` model where that diverges faster, unless
        given), so that costs before and after a step compare."""
        seg = self._estimator_options.get("segment", self.segment)
        if seg is None:
            seg = auto_segment(LinearModel(fitted or self.declared_), max(r.duration for r in runs)) \
                if self.estimator is None and self.method == "ml" else math.inf
        return math.inf if seg == "plain" else float(seg)

    def _estimate(self, profile: Profile, runs: list[Run], bounds: bool = True) -> IdentificationResult:
        """Fit ``profile``; ``bounds=False`` when only the estimate and its likelihood are used
        (the fits inside a delay search), which spares ML's coloured-residual correction."""
        cls = self.estimator or estimator_class(self.method)
        options = dict(self._estimator_options)
        if self.estimator is None and self.method == "ml":
            if not bounds:
                options.setdefault("coloured", False)
            # the same nuisance and the same segments as the score test and the evaluations, so
            # that likelihoods before and after a step compare
            options.setdefault("estimate_bias", self.zero_shifts)
            options.setdefault("segment", self.segment_)
        with warnings.catch_warnings():
            # recorded below, once per fit, instead of interleaved with the progress lines
            warnings.simplefilter("ignore", ConvergenceWarning)
            result = cls(profile, **options).fit(runs).result_
        if not result.converged:
            free = ", ".join(n for n in result.names if n not in self.declared_.free) or "declared model"
            note = f"fit with {free} did not converge ({result.info.get('stop', 'no reason given')})"
            self.unconverged_.append(note)
            self._say(f"  warning: {note}")
        return result

    def _eval(self, p: Profile, data: str = "fit") -> ModelFit:
        """The profile on one data set (``fit``, ``choosing``, ``validation``) with the loop's
        segments and nuisance, as a true prediction (state-built terms from the model's simulated
        states: :func:`identify.refine.evaluation.predict`); every (model, data set) pair is simulated once."""
        key = (p.to_toml(), data)
        if key not in self._cache:
            self.evaluations_ += 1
            self._cache[key] = predict(p, prepare_runs(p, self._data[data]), self.zero_shifts, self.segment_)
        return self._cache[key]

    def _errors(self, p: Profile) -> dict:
        return {data: errors(self._eval(p, data), p.outputs, self._scale)
                for data in ("fit", "choosing", "validation") if self._data[data]}

    # -- score tests -------------------------------------------------------------------------
    def _candidates(self, p: Profile, runs: list[Run], ev: ModelFit, excluded: set[str]) -> list[Candidate]:
        context = Context(runs, ev.residuals, self.dt, self.f_min, self._frequencies, self.nonlinear_products)
        return [c for c in catalogue(p, context, self._kinds) if c.name not in excluded]

    def _score(self, p: Profile, excluded: set[str]) -> list[dict]:
        """Score statistic, threshold and p-value of every candidate at the fitted profile ``p``.

        Two noise models, two families of tests, Šidák-corrected together: the *residual* model
        (lines and trends removed) tests every candidate, but learns an effect that dominates the
        residual as colour (a 0.1 s delay: score 5477 white, 4 in its metric); so the
        ``TOP_ALTERNATIVE`` candidates that explain most of the residual's energy are tested again
        in an *alternative* model fitted with that candidate's own least-squares fit removed (all
        candidates' columns removed at once biased it: smooth terms scored 75 for a threshold of 22)."""
        ev = self._eval(p)
        cands = self._candidates(p, ev.runs, ev, excluded)
        ext_p, linear = extend_all(p, [c for c in cands if c.linear])
        ext_runs = ev.runs
        for c in linear:
            ext_runs = c.runs(ext_runs)
        # a state-built term's column from the simulated states (at the null value, the model's own):
        # an instrumental-variable score, uncorrelated with the gusts the measured states carry
        ext_runs = simulated_terms(ext_p, ext_runs, ev, state_terms(ext_p), self.segment_)
        evj = evaluate(ext_p, ext_runs, self.zero_shifts, self.segment_, jacobian=True)
        self.evaluations_ += 1
        # per run (N_r, ny, columns): the model's parameters, then every candidate's columns
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
        null = NoiseModel.fit(ev.residuals, self.dt, self.f_min, segment=self.segment_) if self.coloured \
            else NoiseModel.white(sigma)
        self.noise_orders_.append(null.order), self.noise_white_.append(null.white)
        self._say(f"  {len(cands)} candidates, residual noise model order {null.order}"
                  + ("" if null.white else " (its limit: the innovations are still not white)"))
        tested = self._tests(null, design, groups, "residual")
        if self.coloured:
            energy = dg.residual_energy(ev.residuals, [d[:, :, nb:] for d in dy], [g for _, g in groups], sigma)
            for c, cols in [groups[i] for i in np.argsort(energy)[::-1][:TOP_ALTERNATIVE]]:
                keep = list(range(nb)) + [nb + k for k in cols]
                alt = NoiseModel.fit(unexplained(ev.residuals, [d[:, :, keep] for d in dy], evj.nuisance, sigma),
                                     self.dt, self.f_min, segment=self.segment_)
                tested += self._tests(alt, design, [(c, cols)], "alternative")
        # Šidák over every elementary hypothesis of both families (a periodic candidate: n_tests bins)
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
        used = sorted({k for _, cols in groups for k in cols})  # whiten only the columns tested
        where = {k: i for i, k in enumerate(used)}
        dyw = [noise.whiten(d[:, :, list(range(nb)) + [nb + k for k in used]]) for d in dy]
        sb = dg.ScoreBase.build([noise.whiten(e) for e in residuals],
                                dg.block_design([d[:, :, :nb] for d in dyw], [noise.whiten(nu) for nu in nuisance]),
                                sigma=np.ones(len(noise.sigma)))
        J = np.concatenate([d[:, :, nb:].reshape(len(d) * d.shape[1], -1) for d in dyw])
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
        """Per fit run (N_r, ny): the response to ``transform(u, dt)`` of one input (the others
        zero), each segment from rest (:func:`identify.refine.evaluation.input_response`)."""
        return input_response(p, prepare_runs(p, self._raw), self.segment_, input_name, transform)

    def refit(self, ext_p: Profile, p: Profile, bounds: bool = True) -> tuple[Profile, IdentificationResult]:
        """ML re-fit of an extended profile: the fitted profile (named as ``p``) and the result.
        State-built terms come from the simulated states of the model being fitted (:func:`settle`)."""
        def fit(prof: Profile):
            runs = self._eval(prof).runs if state_terms(prof) else prepare_runs(prof, self._raw)
            result = self._estimate(prof, runs, bounds=bounds)
            return _keep_meta(result.identified_profile(p.name), ext_p), result

        if not state_terms(ext_p):
            return fit(ext_p)
        fitted, result = settle(fit, ext_p)
        if bounds:
            # the loop evaluates the fitted model anyway: its cached prediction is the bounds' base
            result = feedback_bounds(result, fitted, prepare_runs(fitted, self._raw), self.zero_shifts, self.segment_,
                                     base=self._eval(fitted))
        return fitted, result

    def residuals(self, p: Profile) -> list[np.ndarray]:
        return self._eval(p).residuals

    def _reestimate_delays(self, p: Profile, result: IdentificationResult, noise):
        """A delay found early was searched without the effects found after it (the demo: 0.104 s
        for a 0.1 s delay, 5 standard errors off, before the other cyclic's delay was added):
        search each again in the final model, the others held, and report the new estimate."""
        for step in (s for s in self.steps_ if s.effect == "delay"):
            delays = dict(p.meta["delays"])
            tau = delays.pop(step.target)
            without = replace(p, meta={**p.meta, "delays": delays})
            new_p, new_result, params, _ = Delay(step.target, lag=False).estimate(self, without, noise, hint=tau)[0]
            if noise.cost(self.residuals(new_p)) <= noise.cost(self.residuals(p)):
                p, result, step.parameters = new_p, new_result, params
            self._say(f"delay on {step.target} searched again in the final model: {tau:.4g} -> "
                      f"{step.parameters[f'tau_{step.target}']['value']:.4g} s")
        return p, result

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
            [self._eval(o[0], d) for o in options for d in self._data if self._data[d]]  # a diverging term: refused
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
            reason = cand.implausible(params) or self._refusal(step, stats.chi2.isf(best["level"], len(params)))
            if not reason:
                # the judging data see only the candidate the rest has chosen: once, pass or fail
                reason = _held_out_refusal(held, "validation", "judging", len(params))
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
        return _held_out_refusal(step.held_out, "choosing", "choosing", len(step.parameters))


def _held_out_refusal(held: dict, data: str, label: str, dof: int) -> str:
    """Refusal unless the model with the effect predicts held-out ``data`` better by more than the
    95 % chi-square quantile of its parameter count (in cost = twice the negative log-likelihood):
    a null effect, its parameters estimated elsewhere, makes held-out predictions worse on average
    and better by that much in fewer than 5 % of cases; a plain decrease passed half of them."""
    if data not in held:
        return ""
    before, after = held[data]
    need = float(stats.chi2.isf(0.05, max(dof, 1)))
    if before - after > need:
        return ""
    return (f"did not lower the prediction error on the {label} data by more than {need:.3g} "
            f"(noise-model cost {before:.6g} -> {after:.6g})")


def _rank(t: dict) -> tuple:
    """Order of preference among significant candidates: smallest p-value first, a nonlinear term
    (more complex than a derivative, delay, bias, drift, scale or vibration) as if its p-value were
    100 times larger."""
    return (t["log_p"] + SIMPLER_FIRST * t["candidate"].complexity, -t["statistic"])


def _keep_meta(p: Profile, template: Profile) -> Profile:
    """Identified profile with the template's meta (delays, pseudo-inputs, periodic frequencies)."""
    return replace(p, meta={**dict(p.meta), **dict(template.meta)})


__all__ = ["Refine", "Step"]

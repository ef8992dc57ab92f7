"""Close the loop: find the structure left in the residuals, name the effect, add it, re-identify.

``Refine(profile, estimator=ML(profile)).fit(runs, validate=val_runs)`` fits the declared model with
the estimator *instance* it is given (ML by default; it is cloned for every fit and never asked
which it is, see :mod:`identify.estimators.base`), then repeats:

1. residuals of every output on every run, the estimator's prediction (output error: the model
   simulated, state-built terms from its simulated states; :mod:`identify.estimators.prediction`),
   asked through a :class:`~identify.refine.fitting.Fitting` that caches every (model, data set) pair;
2. a vector autoregressive noise model of those residuals (:mod:`identify.refine.noise`) and a score
   test of every candidate (:mod:`identify.refine.candidates`) in its metric, at a Šidák-corrected
   family level ``alpha`` (:mod:`identify.refine.scoring`);
3. the most significant candidate (nonlinear terms ranked below simpler explanations) is
   estimated (a delay by a profile-likelihood search, and a lag fitted too) and kept only if
   (:mod:`identify.refine.acceptance`) every number is determined, the likelihood ratio and Wald
   statistic pass the threshold, it predicts the *choosing* data better in the test's metric, no
   held-out error the report shows rises beyond its noise, and the *judging* data's plain error
   (the report's validation error) falls beyond its noise (a paired test); without validation
   runs a third of each run is held out for this (:func:`~identify.refine.evaluation.hold_out`);

until no candidate is significant, ``max_steps`` effects were added or ``3 max_steps`` candidates
were tried. Every try keeps its evidence (:class:`Step`). Each accepted kind then has a last look at
the final model (:meth:`Candidate.revisit`: the delays are searched again among the later effects).

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
from ..errors import EstimationError, PseudostepError
from ..estimators.base import HeldWarning, expand_held
from ..model.linear import LinearModel
from ..model.profile import Profile, load_profile
from ..model.pseudo_inputs import prepare
from ..model.subset import check_some_input_flown, fix, free, held_line, unflown_parameters
from . import diagnostics as dg
from .acceptance import error_change, error_refusal, failed_refit, held_out_refusal, second_attempt, undetermined
from .candidates import KIND_CLASSES, KINDS
from .evaluation import HELD_OUT_NOTE, MIN_SAMPLES, check_identifiable, errors, hold_out, split_validation
from .fitting import Fitting
from .noise import NoiseModel
from .scoring import ScoreTest, score_candidates
from .steps import Step

LABELS = {"choosing": "choosing", "validation": "judging"}
ERROR_REFUSALS = ("makes the", "does not lower", "lowers the")  # error_refusal's: other missing effects may cause them


class Refine:
    """Iterative model refinement (see the module docstring).

    Options: ``estimator`` an estimator *instance* (default ``ML(profile)``) whose options every
    fit keeps (:meth:`~identify.estimators.base.Estimator.nested` adds the loop's nuisance and
    segments); ``alpha`` family-wise false-alarm level per iteration (0.01); ``kinds`` the
    catalogue kinds to try; ``max_steps``; ``zero_shifts`` whether per-run output biases are
    nuisance parameters (then a common ``bias`` is not testable and is skipped); ``frequencies``
    (Hz) known disturbance frequencies (else the periodic candidate's frequency is the residual
    spectrum's most prominent line above ``f_min`` Hz, counted as one test per frequency bin);
    ``tau_max`` (s) largest delay searched; ``segment`` (s) the multiple-shooting segment length
    used by every fit and test (default: the estimator's own choice for the declared model,
    :meth:`~identify.estimators.base.Estimator.prediction_segment`); ``coloured``: the tests in
    the metric of a noise model fitted to the residuals (True) or for white residuals (False, the
    classical tests); ``progress``: print step, candidate and elapsed time on stderr; ``prune``: a
    last step of backward elimination (an object with ``run(fitting, profile, result, say)`` returning
    the pruned profile, its result and the decisions, :class:`identify.structure.prune.Prune`).

    After ``fit``: ``steps_`` (accepted :class:`Step` s), ``rejected_`` (candidates that passed the
    score test but failed a later check), ``tries_``, ``stopped_`` (the reason the loop ended),
    ``result_`` the final identification, ``profile_`` the final model (values = estimates),
    ``initial_result_``, ``error_before_``/``error_after_`` ({"fit", "choosing", "validation"}),
    ``data_`` (which runs fitted, chose and judged), ``runs_``/``validation_runs_`` (the runs),
    ``diagnostics_``, ``last_scores_`` (the last round's :class:`ScoreTest` s), ``fitting_`` (the
    :class:`~identify.refine.fitting.Fitting` of the loop), ``estimator_`` (the instance used),
    ``notes_`` (what the user was told: data held out, undetermined statistics), ``pruned_`` (the
    backward elimination's decisions).
    """

    def __init__(self, profile: Profile | str | Path, estimator=None, alpha: float = 0.01, kinds=KINDS,
                 max_steps: int = 6, zero_shifts: bool = True, frequencies=None, f_min: float = 0.5,
                 tau_max: float = 0.5, nonlinear_products: bool = True, segment=None, coloured: bool = True,
                 progress: bool = False, verbose: bool = False, prune=None):
        self.profile, self.estimator, self.prune = profile, estimator, prune
        self.alpha, self.kinds, self.max_steps = alpha, kinds, max_steps
        self.zero_shifts, self.frequencies, self.f_min, self.tau_max = zero_shifts, frequencies, f_min, tau_max
        self.nonlinear_products, self.segment, self.coloured = nonlinear_products, segment, coloured
        self.progress, self.verbose = progress, verbose

    # -- public -------------------------------------------------------------------------------
    def fit(self, runs, validate=None) -> "Refine":
        runs = [runs] if isinstance(runs, Run) else list(runs)
        validate = [validate] if isinstance(validate, Run) else list(validate or [])
        self._started = time.perf_counter()
        self._validate_options()
        self._check(runs, validate)
        self.notes_, self.undetermined_scores_ = [], {}
        if not validate:  # the loop's choices are still checked on data the fit never saw
            runs, validate = hold_out(runs, self.declared_.input_names)
            self._note(HELD_OUT_NOTE[bool(validate)])
        self._hold(runs)
        choose, judge = split_validation(validate, self.declared_.input_names)
        self.runs_, self.validation_runs_ = runs, validate
        self.data_ = {"fit": [r.source for r in runs], "choosing": [r.source for r in choose],
                      "validation": [r.source for r in judge]}
        self.segment_ = self._segment(runs)
        self.fitting_ = Fitting(self.estimator_, {"fit": runs, "choosing": choose, "validation": judge},
                                self.declared_, zero_shifts=self.zero_shifts, segment=self.segment_,
                                tau_max=self.tau_max, held=tuple(self.undeterminable_), say=self._say)
        # a priori values: before spending a fit on it
        check_identifiable(self.declared_, prepare(self.declared_, runs), self.zero_shifts, self.segment_)
        self._say(f"fitting the declared model ({len(self.declared_.free)} parameters, {len(runs)} runs)")
        current, est = self.fitting_.refit(self.declared_, self.declared_, advice=True)
        if self._segment(runs, current) < self.segment_:  # the fit diverges faster than the a priori
            self.segment_ = self.fitting_.segment = self._segment(runs, current)
            self._say(f"the fitted model diverges faster: segments cut to {self.segment_:.3g} s, re-fitting")
            current, est = self.fitting_.refit(self.declared_, self.declared_, advice=True)
        self.initial_result_ = est
        if est.info.get("estimator_advice"):  # output error on strongly coloured residuals
            self._say(f"note: {est.info['estimator_advice']}; refine --method fem tests in the innovations' metric")
        self._scale = np.array([np.std(np.concatenate([r[y] for r in runs])) or 1.0 for y in self.declared_.outputs])
        self.steps_, self.rejected_ = [], []
        self.error_before_ = self._errors(current)
        times, ev0 = [r.time for r in runs], self.fitting_.prediction(current)
        diag = {"before": dg.summary(ev0.residuals, times, self.fitting_.dt, self.f_min, current.outputs)}
        current, result = self._loop(current, est)
        self.pruned_ = []
        if self.prune is not None:  # backward elimination, any object with run(fitting, profile, result, say)
            current, result, self.pruned_ = self.prune.run(self.fitting_, current, result, self._say)
        self.profile_, self.result_ = current, result
        if self.undeterminable_:
            result.info["undeterminable"] = dict(self.undeterminable_)
        if self.held_:  # the final model keeps them free, at their a priori values, for runs that move them
            self.profile_ = free(current, [n for names in self.held_.values() for n in names])
            self.result_ = expand_held(result, self.profile_, self.held_, self.held_note_)
        self.error_after_, ev1 = self._errors(current), self.fitting_.prediction(current)
        diag["after"] = dg.summary(ev1.residuals, times, self.fitting_.dt, self.f_min, current.outputs)
        self.diagnostics_ = diag
        self.final_evaluation_ = {"fit": ev1, "before": ev0, "time": times}
        self._say(f"done: {len(self.steps_)} added, {len(self.rejected_)} rejected; {self.stopped_}")
        return self

    def _loop(self, current: Profile, result):
        """Score, fit and check candidates until none is significant or a limit is reached; then
        each accepted kind's last look at the final model."""
        excluded, deferred = set(), set()
        self.tries_ = 0
        self.last_scores_: list[ScoreTest] = []
        self.noise_orders_, self.noise_white_ = [], []  # per step: the order, whether its innovations were white
        noise = None
        while True:
            if len(self.steps_) >= self.max_steps:
                self.stopped_ = f"{self.max_steps} effects added (max_steps)"
                break
            if self.tries_ >= 3 * self.max_steps:
                self.stopped_ = (f"try limit: {self.tries_} candidates tried, {len(self.rejected_)} rejected "
                                 "(3 x max_steps)")
                break
            self._say(f"step {len(self.steps_) + 1}: score tests")
            tested = self._score(current, excluded)
            if tested is None:
                self.stopped_ = "the score tests could not be computed at the current model (see the notes)"
                break
            significant = [t for t in tested if t.significant]
            if not significant:
                top = max(tested, key=lambda t: t.statistic / t.threshold, default=None)
                self.stopped_ = "no candidate significant" + (
                    f" (closest: {top.candidate.name}, score {top.statistic:.3g} / threshold "
                    f"{top.threshold:.3g})" if top else "")
                break
            best = min(significant, key=ScoreTest.rank)
            self.tries_ += 1
            self._say(f"step {len(self.steps_) + 1}: fitting {best.candidate.name} "
                      f"(score {best.statistic:.3g} > {best.threshold:.3g}, try {self.tries_})")
            step, new_profile, new_result = self._try(current, result, best, tested)
            self._say(f"  {'accepted' if step.accepted else 'rejected: ' + step.reason}")
            if step.accepted:  # a candidate the held-out errors refused may be right beside this one
                self.steps_.append(step)
                current, result, noise = new_profile, new_result, best.noise
                excluded -= deferred
            else:
                self.rejected_.append(step)
                excluded.add(best.candidate.name)
                deferred |= {best.candidate.name} if step.reason.startswith(ERROR_REFUSALS) else set()
        self.fitting_.forget("score tests")  # every candidate's columns: not needed after the loop
        for kind in dict.fromkeys(KIND_CLASSES[s.effect] for s in self.steps_):
            current, result = kind.revisit(self.fitting_, current, result, noise, self.steps_)
        return current, result

    nothing_found = property(lambda self: not self.steps_)

    evaluations_ = property(lambda self: self.fitting_.evaluations)

    unconverged_ = property(lambda self: self.fitting_.unconverged)

    def _note(self, msg: str) -> None:
        """A note the user must see whatever the progress option (and ``refine.json`` keeps)."""
        self.notes_.append(msg)
        print(f"refine: {msg}", file=sys.stderr, flush=True)

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
        if self.estimator is None:
            from ..estimators.ml import ML  # the default estimator; any instance is cloned alike
            self.estimator_ = ML(self.declared_)
        elif callable(getattr(self.estimator, "nested", None)):
            self.estimator_ = self.estimator
        else:
            raise EstimationError(f"estimator must be an estimator instance (e.g. ML(profile)), got {self.estimator!r}")
        self.kinds_, self.frequencies_ = tuple(self.kinds), tuple(self.frequencies or ())

    def _check(self, runs: list[Run], validate: list[Run]) -> None:
        if not runs:
            raise EstimationError("refine: no runs given")
        for run in prepare(self.declared_, runs + validate):
            run.require(self.declared_.channels, f"profile '{self.declared_.name}'")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; refine needs at least "
                                      f"{MIN_SAMPLES} per run to test the residuals")

    def _hold(self, runs: list[Run]) -> None:
        """Fix at their a priori values (said once) the parameters of inputs no fitting run moves,
        and what the estimator says it cannot determine from these runs
        (:meth:`~identify.estimators.base.Estimator.determinable`; kept in ``undeterminable_`` and
        the result): no fit, test or candidate of the loop moves them."""
        self.held_ = unflown_parameters(self.declared_, prepare(self.declared_, runs))
        check_some_input_flown(self.declared_, self.held_)
        self.held_note_ = held_line("refine", self.held_) if self.held_ else ""
        if self.held_:
            self._say(self.held_note_)
            warnings.warn(self.held_note_, HeldWarning, stacklevel=3)
            self.declared_ = fix(self.declared_, [n for names in self.held_.values() for n in names])
        self.declared_, self.undeterminable_ = self.estimator_.determinable(self.declared_,
                                                                             prepare(self.declared_, runs))
        if self.undeterminable_:
            self._say(f"{len(self.undeterminable_)} parameter(s) the {self.estimator_.method.upper()} estimator cannot "
                      "determine from these runs, held at their a priori values: "
                      + "; ".join(f"{n} ({r})" for n, r in self.undeterminable_.items()))

    def _segment(self, runs: list[Run], fitted: Profile | None = None) -> float:
        """One segmentation for every fit and test of the loop (the estimator's choice for the
        declared model, or for its first ``fitted`` model where that diverges faster, unless
        given), so that costs before and after a step compare."""
        if self.segment is not None:
            return math.inf if self.segment == "plain" else float(self.segment)
        model = LinearModel(fitted or self.declared_)
        return self.estimator_.prediction_segment(model, max(r.duration for r in runs))

    def _errors(self, p: Profile) -> dict:
        return {data: errors(self.fitting_.prediction(p, data), p.outputs, self._scale)
                for data, runs in self.fitting_.data.items() if runs}

    def _score(self, p: Profile, excluded: set[str]) -> list[ScoreTest] | None:
        """Every candidate's score test at the fitted ``p`` (:func:`identify.refine.scoring.score_candidates`);
        None where they cannot be computed (said once, in the notes)."""
        try:
            found = score_candidates(self.fitting_, p, self.kinds_, excluded, alpha=self.alpha,
                                     coloured=self.coloured, f_min=self.f_min, frequencies=self.frequencies_,
                                     products=self.nonlinear_products)
        except PseudostepError as exc:  # e.g. a filter with no steady state for the extended model
            self._note(f"the score tests could not be computed at the current model: {exc}; refinement stops here")
            self.last_scores_ = []
            return None
        self.noise_orders_.append(found.noise.order), self.noise_white_.append(found.noise.white)
        self._say(f"  {found.n_candidates} candidates, residual noise model order {found.noise.order}"
                  + ("" if found.noise.white else " (its cap: the innovations are still not white, the tests are "
                     "outside their validity and accept nothing without held-out data)"))
        for t in found.tests:  # an undetermined statistic is never significance: refused, said once
            if not math.isfinite(t.statistic) and t.candidate.name not in self.undetermined_scores_:
                self.undetermined_scores_[t.candidate.name] = f"score statistic {t.statistic}"
                self._note(f"{t.candidate.name}: score statistic {t.statistic} is not determined; not a candidate")
        self.last_scores_ = [t for t in found.tests if math.isfinite(t.statistic)]
        return self.last_scores_

    # -- one step ----------------------------------------------------------------------------
    def _try(self, p: Profile, null_result, best: ScoreTest, tested: list[ScoreTest]):
        """Estimate the selected candidate and check it: likelihood ratio and Wald statistic,
        error on the choosing data, then (once, for the option that passed) the judging data.

        The likelihood ratio is the estimator's own where its result states one for the nested pair
        (:meth:`~identify.estimators.result.IdentificationResult.compare_lr_test`: the criterion
        it minimised, e.g. FR's J); else that of the residuals in the test's noise-model metric
        (the likelihood output and filter error maximise).

        A candidate may yield several fits (a delay: delay and lag), and a candidate whose
        ``rivals`` explain the same residual to first order (a lag on an input, a lag on one
        sensor) brings the most significant rival's fits too: all are tried in order of their
        likelihood in the test's metric (non-nested explanations with as many parameters: the
        likelier first), so that the score, which sees only the first order, does not decide
        between them."""
        fitting = self.fitting_
        before = self._errors(p)
        held_data = [d for d in ("choosing", "validation") if fitting.data[d]]
        def unestimated(exc) -> Step:
            return Step(best.candidate.kind, best.candidate.target, {}, lr_statistic=float("nan"),
                        error_before=before, error_after=before, accepted=False,
                        reason=f"could not be estimated: {exc}", **_common(best, tested))

        try:
            options = self._options(p, best, held_data)
        except PseudostepError as exc:  # e.g. an equation-error method and an output-only effect
            return unestimated(exc), p, None
        first = None  # the refusal recorded: the chosen candidate's own first fit's (a rival's if it has none)
        for test, option in options:
            try:  # its bounds now: the options were fitted to rank them
                option = option.bounded()
                [fitting.prediction(option.profile, d) for d in ["fit"] + held_data]
            except PseudostepError as exc:
                if test is best and (first is None or first[3] is not best):
                    first = (unestimated(exc), p, None, test)
                continue  # a rival's: as when its fit diverges on some data set
            step, new_p, result, changes = self._evidence(p, null_result, test, option, before, held_data,
                                                          _common(test, tested))
            reason = step.reason or test.candidate.implausible(step.parameters) or self._refusal(step, test, changes)
            if not reason:
                # the judging data see only the candidate the rest has chosen: once, pass or fail
                reason = self._confirmation(step, changes, test.noise)
                step.accepted, step.reason = not reason, reason
                return step, new_p, result
            step.accepted, step.reason = False, reason
            if first is None or (test is best and first[3] is not best):
                first = (step, new_p, result, test)
        return first[:3]

    def _options(self, p: Profile, best: ScoreTest, held_data: list):
        """``[(test, Fitted)]``: the fits of ``best`` and of its most significant rival
        (:meth:`Candidate.as_rival`, tested in ``best``'s metric), the likeliest first, fitted to
        rank them (their bounds when checked: :meth:`Fitted.bounded`); a fit that diverges on some
        data set is dropped (the rival's), or refuses the candidate (its own)."""
        fitting = self.fitting_
        own = best.candidate.estimate(fitting, p, best.noise, best.hint, bounds=False)
        [fitting.prediction(o.profile, d) for o in own for d in ["fit"] + held_data]
        options = [(best, o) for o in own]
        rivals = [t for t in sorted(self.last_scores_, key=ScoreTest.rank)
                  if t.significant and t.candidate.kind in best.candidate.rivals][:1]
        for t in rivals:
            rival = replace(t, noise=best.noise)  # one metric for every option's likelihood
            try:
                fits = t.candidate.as_rival().estimate(fitting, p, best.noise, t.hint, bounds=False)
                [fitting.prediction(o.profile, d) for o in fits for d in ["fit"] + held_data]
            except PseudostepError:
                continue  # a rival that cannot be fitted is no better explanation
            self._say(f"  also fitted: its rival {t.candidate.name} (score {t.statistic:.3g})")
            options += [(rival, o) for o in fits]
        return sorted(options, key=lambda to: best.noise.cost(fitting.residuals(to[1].profile)))

    def _evidence(self, p: Profile, null_result, best: ScoreTest, option: tuple, before: dict, held_data: list,
                  common: dict) -> tuple:
        """One fitted option's :class:`Step`: the likelihood ratio in the metric of the noise model
        that selected the candidate (or the estimator's own criterion), the Wald statistic, the
        held-out prediction costs in that metric and the plain errors' changes
        (:func:`~identify.refine.acceptance.error_change`); ``reason`` set where the fit failed or a
        number is not determined. ``(step, profile, result, changes)``: the fit kept (a second attempt
        may replace it) and the plain errors' changes ({data: ErrorChange})."""
        cand, noise, fitting = best.candidate, best.noise, self.fitting_
        new_p, result, params, kind = option.profile, option.result, option.parameters, option.kind
        null_cost = noise.cost(fitting.residuals(p))
        own = result.compare_lr_test(null_result) if null_result is not None else None
        lr = null_cost - noise.cost(fitting.residuals(new_p)) if own is None else own[0]
        failed = failed_refit(result, lr, null_cost, best.threshold, own is not None)
        attempts = []
        if failed and own is None and lr < 0 and math.isfinite(lr):
            new_p, result, params, lr, failed, attempts = second_attempt(
                fitting, self.estimator_.method.upper(), cand, p, noise, null_cost, best.threshold,
                (new_p, result, params, lr, failed), held_data)
        held = {data: (noise.cost(fitting.residuals(p, data)), noise.cost(fitting.residuals(new_p, data)))
                for data in held_data}
        # the size of the prediction change there: the spread of the held-out cost change
        spread = {data: noise.cost([a - b for a, b in zip(fitting.residuals(p, data), fitting.residuals(new_p, data))])
                  for data in held_data}
        # a delay's own bound in the test's metric (``std_profile``): its ``std`` also carries the
        # estimator's errors in the other parameters, which do not make the delay less present
        wald = float(sum((v["value"] / s) ** 2 if (s := v.get("std_profile", v["std"])) > 0 else math.nan
                         for v in params.values()))
        plain = NoiseModel.fit(fitting.residuals(new_p), fitting.dt, deterministic=False, segment=fitting.segment)
        changes = {data: error_change(fitting.residuals(p, data), fitting.residuals(new_p, data), p.outputs,
                                      self._scale, plain) for data in held_data}
        step = Step(kind, cand.target, params, lr_statistic=float(lr) if not failed else float("nan"),
                    error_before=before, error_after=self._errors(new_p), wald=wald, held_out=held,
                    held_change=spread, noise_order=noise.order, noise_white=noise.white,
                    lr_criterion=result.info["criterion"]["kind"] if own is not None else "", attempts=attempts,
                    error_change={d: c.to_dict() for d, c in changes.items()}, **common)
        step.reason = failed or undetermined(params, {"Wald statistic": wald})
        return step, new_p, result, changes

    @staticmethod
    def _refusal(step: Step, best: ScoreTest, changes: dict) -> str:
        """Why a fitted candidate is refused before the judging data ('' if it is not)."""
        wald_threshold = stats.chi2.isf(best.level, len(step.parameters))
        if step.lr_statistic < step.threshold:
            metric = step.lr_criterion or "the test's noise-model metric"
            return (f"likelihood ratio {step.lr_statistic:.3g} of the re-fit (in {metric}) below the threshold "
                    f"{step.threshold:.3g}")
        if step.wald < wald_threshold:
            return (f"estimate not significant by its coloured-residual bound (Wald {step.wald:.3g} < "
                    f"{wald_threshold:.3g})")
        return held_out_refusal(step.held_out, step.held_change, "choosing", "choosing") or \
            error_refusal({d: c for d, c in changes.items() if d == "choosing"}, LABELS)

    @staticmethod
    def _confirmation(step: Step, changes: dict, noise) -> str:
        """The judging data's verdict ('' to accept; :func:`~identify.refine.acceptance.error_refusal`).
        Without judging data the tests decide alone, unless they are outside their validity (the
        residual noise model at its order cap, innovations still not white)."""
        if "validation" in changes:
            return error_refusal(changes, LABELS, "validation", step.held_out, step.held_change)
        if not noise.white:
            return ("no held-out data to confirm it, and the tests are outside their validity (the residual noise "
                    "model reached its order cap with innovations still not white): nothing is accepted on them alone")
        return ""


def _common(test: ScoreTest, tested: list[ScoreTest]) -> dict:
    """A step's score-test record: its statistic, threshold, the next three candidates."""
    runner_up = [{"effect": t.candidate.kind, "target": t.candidate.target, "statistic": t.statistic,
                  "threshold": t.threshold} for t in sorted(tested, key=ScoreTest.rank) if t is not test][:3]
    return dict(statistic=test.statistic, threshold=test.threshold, dof=test.dof, p_value=test.p_value,
                tested=len(tested), runner_up=runner_up, why=test.candidate.spec.get("why", ""),
                metric=test.metric, nu=test.nu if math.isfinite(test.nu) else None)


__all__ = ["Refine", "Step", "ScoreTest"]

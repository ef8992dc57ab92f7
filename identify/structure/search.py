"""Model structure determination: which parameters the data support, and which terms they ask for.

``StructureSearch(profile, estimator=ML(profile)).fit(runs, validate=val_runs)``:

1. **equation error** (fast): every dynamic equation regressed on the profile's free parameters and
   a candidate pool (:mod:`identify.structure.pool`: undeclared A/B entries; squares, x|x|, splines
   and products of the channels named in ``nonlinear``) by stepwise regression with orthogonal
   functions, partial F and PSE (:mod:`identify.structure.regression`). Declared parameters the
   regression drops are fixed at zero, candidates it takes are added;
2. **output error** (the estimator instance given, ML by default, FEM in turbulence): the chosen
   structure is fitted and the parameters it does not support are fixed at zero one at a time,
   each removal checked on held-out data (:mod:`identify.structure.prune`);
3. the final structure re-fitted on every fitting run.

Held-out data: the ``validate`` runs, else each fitting run cut in two where its input excitation
is shared half and half (:func:`identify.refine.evaluation.split_validation`, as refine splits its
validation runs: one run per control axis, so a split by whole runs would judge some inputs on
data that never moved them); the output-error steps then fit on one half and judge on the other
before the final fit on all of it. Parameters of inputs no run moves are held at their a priori
values (said), as every estimator holds them.

After ``fit``: ``declared_`` (the a priori profile), ``pool_`` (the candidate terms),
``selections_`` (per equation group: the stepwise regression's fit, ranking and decisions),
``chosen_`` (the profile after equation error), ``profile_`` (the final profile, values =
estimates), ``result_`` (its fit), ``decisions_`` (every decision, in order), ``errors_``
(held-out overall errors of the declared, the chosen and the final model), ``data_``,
``equation_error_seconds_``, ``held_``.
"""
from __future__ import annotations

import math
import sys
import time
import warnings

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..estimators.base import HeldWarning
from ..model import coefficients
from ..model.linear import LinearModel
from ..model.profile import Profile, load_profile
from ..model.pseudo_inputs import prepare
from ..model.subset import check_some_input_flown, fix, held_line, unflown_parameters
from ..refine.evaluation import MIN_SAMPLES, split_validation
from ..refine.fitting import Fitting
from . import pool as pl
from .equation_error import held_out_error, problems, select
from .prune import Prune, output_scale, overall_error
from .regression import Decision, Stepwise


class StructureSearch:
    """Structure determination (see the module docstring).

    Options: ``estimator`` an estimator instance for the output-error steps (default
    ``ML(profile)``); ``alpha`` the stepwise regression's level (partial F thresholds, see
    :class:`~identify.structure.regression.Stepwise`; ``f_in``/``f_out`` override them);
    ``candidates`` whether undeclared A/B entries are candidates; ``nonlinear`` channel names for
    nonlinear candidates and ``knots`` ``{channel: [spline knots]}``; ``level`` the |estimate|/std
    below which output error calls a parameter unsupported and ``tolerance`` the held-out error's
    relative rise a removal may cause (:class:`~identify.structure.prune.Prune`); ``diff_cutoff_hz`` the differentiator's
    cut-off; ``confirm`` False: equation error only; ``progress``: say each stage on stderr.
    """

    def __init__(self, profile: Profile | str, estimator=None, *, alpha: float = 0.05, f_in: float | None = None,
                 f_out: float | None = None, candidates: bool = True, nonlinear=(), knots=None,
                 level: float = 2.0, tolerance: float = 0.01, diff_cutoff_hz: float | None = None, confirm: bool = True,
                 progress: bool = False):
        self.profile, self.estimator = profile, estimator
        self.alpha, self.f_in, self.f_out = alpha, f_in, f_out
        self.candidates, self.nonlinear, self.knots = candidates, nonlinear, knots
        self.level, self.tolerance = level, tolerance
        self.diff_cutoff_hz, self.confirm, self.progress = diff_cutoff_hz, confirm, progress

    # -- public -------------------------------------------------------------------------------------
    def fit(self, runs, validate=None) -> "StructureSearch":
        runs = [runs] if isinstance(runs, Run) else list(runs)
        validate = [validate] if isinstance(validate, Run) else list(validate or [])
        self._validate_options(runs)
        self._hold_unflown(runs)
        fit_runs, held_out = (runs, validate) if validate else self._split(runs)
        self.data_ = {"equation error": [r.source for r in runs], "output-error fit": [r.source for r in fit_runs],
                      "held out": [r.source for r in held_out], "final fit": [r.source for r in runs]}
        self.decisions_: list[Decision] = []
        self.skipped_ = ""
        self._equation_error(runs, held_out if validate else [])
        self.errors_ = {}
        if self.confirm and coefficients.spec(self.declared_.meta, self.declared_.source) is not None:
            self.skipped_ = ("coefficient form: the linear model holds one reference condition, the coefficient "
                             "model several trims; output-error confirmation skipped, decisions by equation error")
            self._say(self.skipped_)
        if not self.confirm or self.skipped_:  # the equation-error estimates are the result
            self.profile_ = self.chosen_.with_values({k: v for k, (v, _) in self.ee_estimates_.items()})
            self.result_ = None
            return self
        self._output_error(fit_runs, held_out)
        if not validate:  # the decisions were taken on half of each run: the final fit uses all of it
            self._say("final fit on every run")
            final = self._fitting(runs, [])
            self.profile_, self.result_ = final.refit(self.profile_, self.profile_, advice=True)
        return self

    # -- the stages ---------------------------------------------------------------------------------
    def _equation_error(self, runs: list[Run], validate: list[Run]) -> None:
        p = self.declared_
        measured = {s for s in p.state_names if all(s in r.channels for r in runs)}
        terms = pl.derivative_terms(p, measured) if self.candidates else []
        one_signed = {x for x in self.nonlinear if all(np.all(r[x] >= 0) for r in runs)
                      or all(np.all(r[x] <= 0) for r in runs)}
        terms += pl.nonlinear_terms(p, list(self.nonlinear), self.knots_, one_signed)
        self.pool_ = terms
        ext = pl.extended(p, terms)
        self._say(f"equation error: {len(p.free)} declared parameters, {len(terms)} candidates")
        started = time.perf_counter()
        stepwise = Stepwise(alpha=self.alpha, f_in=self.f_in, f_out=self.f_out)
        self.selections_ = select(ext, p, prepare(ext, runs), stepwise, self.diff_cutoff_hz)
        self.equation_error_seconds_ = time.perf_counter() - started
        self.equation_error_held_out_ = {}
        if validate:  # each equation's held-out error, the declared terms against the selected ones
            held = {pr.label: pr for pr in problems(ext, p, prepare(ext, validate), self.diff_cutoff_hz)}
            for s in self.selections_:
                declared = [n for n in s.problem.columns if n in p.free]
                self.equation_error_held_out_[s.problem.label] = {
                    "declared": held_out_error(s.problem, held[s.problem.label], declared),
                    "selected": held_out_error(s.problem, held[s.problem.label], s.fit.terms)}
        kept, added = {}, {}
        self.ee_estimates_ = {}  # {name: (estimate, coloured-residual std)} of the selected terms
        for s in self.selections_:
            self.decisions_ += s.decisions
            for name, value, std in zip(s.fit.terms, s.fit.theta, s.fit.std):
                (kept if name in p.free else added)[name] = float(value)
                self.ee_estimates_[name] = (float(value), float(std))
        in_regression = {n for s in self.selections_ for n in s.problem.columns}
        dropped = [n for n in p.free if n in in_regression and n not in kept]
        chosen = p.with_values({n: 0.0 for n in dropped})
        chosen = fix(chosen, dropped) if dropped else chosen
        self.chosen_ = pl.with_terms(chosen, added, terms)
        self.dropped_ee_, self.added_ee_ = dropped, list(added)
        self._say(f"  equation error ({self.equation_error_seconds_:.2g} s): dropped {', '.join(dropped) or 'none'}; "
                  f"added {', '.join(added) or 'none'}")

    def _output_error(self, fit_runs: list[Run], held_out: list[Run]) -> None:
        p = self.chosen_
        fitting = self._fitting(fit_runs, held_out, p)
        scale = output_scale(fitting.data["fit"], self.declared_.outputs)
        self._say(f"output error: fitting the declared model ({len(self.declared_.free)} parameters)")
        declared_fit, _ = fitting.refit(self.declared_, self.declared_)
        self._say(f"output error: fitting the chosen structure ({len(p.free)} parameters)")
        current, result = fitting.refit(p, p)
        self.errors_ = {"declared": overall_error(fitting.residuals(declared_fit, "choosing"), scale),
                        "chosen": overall_error(fitting.residuals(current, "choosing"), scale)}
        current, result, decisions = Prune(self.level, self.tolerance).run(fitting, current, result,
                                                                 self._say)
        self.decisions_ += decisions
        self.errors_["final"] = overall_error(fitting.residuals(current, "choosing"), scale)
        self.profile_, self.result_ = current, result
        self.unconverged_ = fitting.unconverged

    # -- helpers ------------------------------------------------------------------------------------
    def _fitting(self, fit_runs, held_out, p=None) -> Fitting:
        p = p or self.declared_
        segment = self.estimator_.prediction_segment(LinearModel(p), max(r.duration for r in fit_runs))
        return Fitting(self.estimator_, {"fit": fit_runs, "choosing": held_out, "validation": []}, self.declared_,
                       zero_shifts=True, segment=segment, say=self._say)

    def _split(self, runs: list[Run]) -> tuple[list[Run], list[Run]]:
        """Each run in two where its input excitation is halved: one half fits, the other judges
        (alternating, so that both parts hold every control axis's run)."""
        short = [r.source for r in runs if len(r) < 2 * MIN_SAMPLES]
        if short:
            raise EstimationError(f"run(s) {', '.join(short)} too short to hold out a part (fewer than "
                                  f"{2 * MIN_SAMPLES} samples): give --validate runs")
        fit_part, judge = split_validation(runs, self.declared_.input_names)
        self._say(f"no validation runs: each run cut in two, {len(fit_part)} parts fit and {len(judge)} judge "
                  f"the output-error steps (every part holds its run's inputs)")
        return fit_part, judge

    def _validate_options(self, runs: list[Run]) -> None:
        if not runs:
            raise EstimationError("structure: no runs given")
        if not 0 < self.alpha < 1:
            raise EstimationError(f"alpha must be between 0 and 1, got {self.alpha}")
        if not self.level > 0:
            raise EstimationError(f"level must be positive, got {self.level}")
        self.declared_ = self.profile if isinstance(self.profile, Profile) else load_profile(self.profile)
        if self.estimator is None:
            from ..estimators.ml import ML  # the default; any instance is cloned alike

            self.estimator_ = ML(self.declared_)
        else:
            self.estimator_ = self.estimator
        names = list(self.nonlinear or ())
        missing = [n for n in names if not all(n in r.channels for r in runs)]
        if missing:
            raise EstimationError(f"--nonlinear names channel(s) not in every run: {', '.join(missing)}")
        self.knots_ = {k: [float(v) for v in vs] for k, vs in dict(self.knots or {}).items()}
        if set(self.knots_) - set(names):
            raise EstimationError(f"knots given for {', '.join(sorted(set(self.knots_) - set(names)))}, "
                                  f"which --nonlinear does not name")

    def _hold_unflown(self, runs: list[Run]) -> None:
        self.held_ = unflown_parameters(self.declared_, prepare(self.declared_, runs))
        check_some_input_flown(self.declared_, self.held_)
        if self.held_:
            note = held_line("structure", self.held_)
            self._say(note)
            warnings.warn(note, HeldWarning, stacklevel=3)
            self.declared_ = fix(self.declared_, [n for names in self.held_.values() for n in names])

    def _say(self, msg: str) -> None:
        if self.progress:
            print(msg, file=sys.stderr, flush=True)

    # -- results ------------------------------------------------------------------------------------
    @property
    def dropped_(self) -> list[str]:
        """Declared free parameters the final profile holds fixed at zero."""
        return [n for n in self.declared_.free if n not in self.profile_.free]

    @property
    def added_(self) -> list[str]:
        return [n for n in self.profile_.free if n not in self.declared_.free]

    @property
    def kept_(self) -> list[str]:
        return [n for n in self.declared_.free if n in self.profile_.free]

    def table(self) -> list[dict]:
        """One row per declared parameter and candidate that entered: its fate and why."""
        final = dict(zip(self.result_.names, zip(self.result_.theta, self.result_.std))) if self.result_ \
            else self.ee_estimates_
        rows = []
        for name in list(self.declared_.free) + self.added_ee_:
            last = [d for d in self.decisions_ if d.term == name and d.action in ("leave", "enter", "dropped", "kept")]
            fate = "kept" if name in self.kept_ else "dropped" if name in self.dropped_ else \
                "added" if name in self.added_ else "added, then dropped"
            row = {"parameter": name, "declared": name in self.declared_.free, "fate": fate}
            if name in final:
                row.update(value=float(final[name][0]), std=float(final[name][1]))
            if last:
                d = last[-1]
                row.update(stage=d.stage, statistic=d.statistic, threshold=d.threshold, criterion=d.criterion,
                           error_before=d.before, error_after=d.after, note=d.note)
            rows.append(row)
        return rows

    def summary(self) -> str:
        lines = [f"structure of '{self.declared_.name}': {len(self.kept_)} declared parameters kept, "
                 f"{len(self.dropped_)} dropped (fixed at 0), {len(self.added_)} added",
                 f"equation-error pass: {self.equation_error_seconds_:.2g} s, {len(self.pool_)} candidates"]
        for row in self.table():
            value = f"{row['value']:.5g} ± {row['std']:.2g}" if "value" in row else "0 (fixed)"
            why = (f"  [{row['stage']}: {row['statistic']:.3g} vs {row['threshold']:.3g}]"
                   if "stage" in row and math.isfinite(row["statistic"]) else "")
            lines.append(f"  {row['fate']:<20} {row['parameter']:<22} {value}{why}")
        for label, e in getattr(self, "equation_error_held_out_", {}).items():
            lines.append(f"equation {label}: held-out equation error (relative RMS) declared {e['declared']:.4g}, "
                         f"selected {e['selected']:.4g}")
        if self.skipped_:
            lines.append(f"note: {self.skipped_}")
        if self.errors_:
            lines.append("held-out error (overall): declared {declared:.4g}, after equation error {chosen:.4g}, "
                         "final {final:.4g}".format(**self.errors_))
        return "\n".join(lines)


__all__ = ["StructureSearch"]

"""Optimised three-level pseudo-stochastic sequences: most information per unit of response,
robust to the a priori model's errors.

The design problem (Kaletka & Rix section 4: wide band, short, flyable; small perturbations):
maximise the Fisher information's log det subject to every output's peak |y| over the whole record
staying within its limit, with levels -1/0/+1 switching on a fine grid, holds of at least
``min_pulse`` s and at most ``max_changes`` level changes. Without a fixed amplitude the amplitude
is an outcome: information grows with amplitude squared and the peak with amplitude, so the best
sequence maximises information at equal peak response, and is then flown at the amplitude that
brings its largest peak/limit to 1. By default the criterion is the expected log det over a set of
models around the a priori (:func:`~signaldesign.robust.design_set`: frequencies x 0.6..1.6,
derivatives x 0.7..1.3), each model scaling the sequence to its own peak response.
"""
from __future__ import annotations

import os
import time
import warnings

import numpy as np

from identify import LinearModel

from .baselines import doublet, m3211
from .bound import EFFORTS, objective_bound
from .compare import width_grid, tune, default_limits, yardsticks
from .evaluate import DesignError, Evaluator, check_record
from .flyable import LEVELS, Flyability, count_sequences, enumerate_sequences  # noqa: F401 (re-exported)
from .quadform import Objective, PerInputObjective, StepBasis
from .robust import design_set
from .search import SearchResult, anneal, exhaustive, polish  # noqa: F401 (re-exported)
from .workers import check_jobs

CRITERIA = ("robust", "mean", "worst", "nominal")
PEAKS = ("shared", "per-input")


PLAUSIBLE_CONTROL = np.radians(20.0)  # rad: beyond this a control deflection is no small test input


def implausible_amplitudes(profile, inputs, amplitudes) -> list[str]:
    """One line per input whose amplitude no test input has: a control angle beyond 20 degrees
    (Kaletka & Rix's inputs are small perturbations about trim, where the linear model holds; a
    cyclic's whole travel is about that). The output limits allowed it: they are too loose, or the
    input's unit is wrong. Inputs in other units are not judged."""
    out = []
    for name, a in zip(inputs, np.atleast_1d(amplitudes)):
        unit = profile.inputs.get(name, "")
        if unit in ("rad", "deg"):
            rad = a if unit == "rad" else np.radians(a)
            if abs(rad) > PLAUSIBLE_CONTROL:
                out.append(f"amplitude {np.degrees(rad):.1f} deg on {name} is implausible for a test input "
                           f"(> {np.degrees(PLAUSIBLE_CONTROL):.0f} deg: far outside small perturbations; "
                           f"check the profile's [limits] and the unit of {name}, '{unit}')")
    return out


class SequenceDesign:
    """Optimised three-level sequence(s), one per input axis, designed together for one run.

    Parameters: ``duration`` s of signal starting ``delay`` s into a ``record`` s record sampled
    every ``dt`` s; levels switch on a ``grid`` s grid (a multiple of dt); holds last at least
    ``min_pulse`` s; at most ``max_changes`` level changes per axis. ``amplitude`` (rad, one per
    axis or one for all) fixes the deflection; None makes it an outcome. ``limits`` ({output: peak})
    default to the profile's ``[limits]``, else to the peaks of the best-width 3211 at
    ``reference_amplitude``. ``criterion``: ``robust`` (default: over ``models``, default the
    design set, each model's equal-peak log det relative to the 3211 tuned on it; maximise the
    mean with ``apriori_weight`` on the a priori plus ``worst_weight`` times the minimum, a
    log-sum-exp soft minimum at ``softness`` log-det units when positive, while keeping at least
    ``nominal_margin`` times the D-efficiency of the best tuned 3211/doublet on the a priori when the
    amplitude is free; the nominal optimum seeds the search), ``mean`` (expected log det only),
    ``worst`` (worst relative D-efficiency only) or ``nominal`` (the a priori only). ``draws`` and
    ``extreme_draws`` size the design set (:func:`~signaldesign.robust.design_set`). The search:
    ``restarts`` annealing runs of ``n_iter`` proposals, each polished, then ``kicks`` rounds of
    iterated local search from the best restarts (:func:`~signaldesign.search.anneal`);
    ``nominal_kicks`` rounds in the robust criterion's nominal pre-search; the summary says whether
    the restarts agree within ``agreement`` (a D-efficiency fraction; ``spread_efficiency_`` after
    ``fit``). ``peak``: with several inputs, ``shared`` (the run's whole response within the
    limits, one amplitude) or ``per-input`` (each input as large as its own response, alone,
    allows, as in a run of its own; the responses add; the robust yardsticks are the 3211 flown the
    same way; :class:`~signaldesign.quadform.PerInputObjective`). ``jobs`` worker processes run
    the restarts (default: the available CPUs, at most ``restarts``); the design is the same for
    any number. ``certify``: the upper bound's effort, ``quick`` (default: valid, looser,
    seconds) or ``full`` (``signaldesign design``'s default: a few log det units from the
    relaxation's value, 10-40 s per model; :data:`~signaldesign.bound.EFFORTS`).

    After ``fit``: ``signals_``, ``amplitude_`` (per axis), ``levels_``, ``peaks_`` and ``limits_``
    (ny,) on the a priori at the flown amplitude, ``binding_`` (output at its limit), ``result_``
    (SearchResult; ``trace`` the restarts' objectives), ``bound_`` (:class:`~signaldesign.bound.Bound`:
    an upper bound on the criterion over every input in the span of the grid's steps), ``gap_``
    (criterion units from the design to the optimum: 0 for an exhaustive search, else at most the
    bound minus the design's value), ``efficiency_bound_`` (exp(-gap / (p x total weight)): the
    design's D-efficiency is at least this fraction of the optimum's), ``evaluator_``, ``basis_``,
    ``models_`` and ``model_labels_``, ``width_`` (the grid), ``seconds_``, ``cpu_seconds_``,
    ``nominal_gain_`` (D-efficiency on the a priori against the best tuned 3211/doublet).
    """

    def __init__(self, inputs="theta_s", duration: float = 7.0, record: float = 20.0, amplitude=None,
                 dt: float = 0.05, grid: float = 0.1, min_pulse: float = 0.3, max_changes: int | None = 12,
                 allow_double_jumps: bool = True, criterion: str = "robust", models=None, model_labels=None,
                 limits: dict | None = None, reference_amplitude: float = 0.02, exhaustive_limit: int = 6000,
                 n_iter: int = 1000, restarts: int = 10, seed: int = 0, noise_std=None, delay: float = 0.0,
                 progress=None, apriori_weight: float = 0.5, worst_weight: float = 1.0, softness: float = 0.0,
                 draws: int = 2, extreme_draws: int = 3, nominal_margin: float | None = 1.22, kicks: int = 20,
                 nominal_kicks: int = 20, jobs: int | None = None, prior: bool = False, certify: str = "quick",
                 peak: str = "shared", agreement: float = 0.01):
        self.inputs = [inputs] if isinstance(inputs, str) else list(inputs)
        self.duration, self.record, self.amplitude, self.dt = duration, record, amplitude, dt
        self.grid, self.min_pulse, self.max_changes = grid, min_pulse, max_changes
        self.allow_double_jumps, self.criterion = allow_double_jumps, criterion
        self.models, self.model_labels, self.limits = models, model_labels, limits
        self.reference_amplitude = reference_amplitude
        self.exhaustive_limit, self.n_iter, self.restarts, self.seed = exhaustive_limit, n_iter, restarts, seed
        self.noise_std, self.delay, self.progress = noise_std, delay, progress
        self.apriori_weight, self.worst_weight, self.softness = apriori_weight, worst_weight, softness
        self.draws, self.extreme_draws, self.nominal_margin = draws, extreme_draws, nominal_margin
        self.kicks, self.nominal_kicks, self.jobs, self.certify = kicks, nominal_kicks, jobs, certify
        self.prior, self.peak = prior, peak
        self.agreement = agreement

    # -- validation ---------------------------------------------------------------------------------
    def n_steps(self) -> int:
        """Grid steps in the duration, after checking every timing option (one DesignError line)."""
        check_record(self.record, self.dt)
        for name, v in (("duration", self.duration), ("grid", self.grid), ("min pulse", self.min_pulse)):
            if not (np.isfinite(v) and v > 0):
                raise DesignError(f"{name} must be positive, got {v:g} s")
        sub = self.grid / self.dt
        if abs(sub - round(sub)) > 1e-9 * sub or round(sub) < 1:
            raise DesignError(f"grid {self.grid:g} s is not a multiple of the {self.dt:g} s time step")
        K = int(round(self.duration / self.grid))
        if K < 2:
            raise DesignError(f"duration {self.duration:g} s holds fewer than two {self.grid:g} s grid steps")
        if self.min_pulse > self.duration:
            raise DesignError(f"minimum pulse {self.min_pulse:g} s exceeds the duration {self.duration:g} s")
        if self.delay + K * self.grid > self.record + 1e-9:
            raise DesignError(f"a {self.duration:g} s signal does not fit in the {self.record:g} s record")
        if self.max_changes is not None and self.max_changes < 2:
            raise DesignError(f"max changes {self.max_changes}: a sequence needs at least 2 (leave 0, return)")
        self._jobs()
        if self.criterion not in CRITERIA:
            raise DesignError(f"unknown criterion '{self.criterion}' ({', '.join(CRITERIA)})")
        if self.peak not in PEAKS:
            raise DesignError(f"unknown peak rule '{self.peak}' ({', '.join(PEAKS)})")
        if self.peak == "per-input" and self.amplitude is not None:
            raise DesignError("per-input peak response makes every input's amplitude an outcome: "
                              "leave the amplitude free")
        if self.certify not in EFFORTS:
            raise DesignError(f"unknown certificate effort '{self.certify}' ({', '.join(EFFORTS)})")
        if self.amplitude is not None:
            amps = np.atleast_1d(np.asarray(self.amplitude, float))
            if not np.all(np.isfinite(amps) & (amps > 0)):
                raise DesignError(f"amplitude must be positive, got {self.amplitude}")
        return K

    def _jobs(self) -> int:
        """Worker processes for the search: ``jobs``, default the available CPUs, at most one per
        restart (the result is the same for any number)."""
        return min(check_jobs(self.jobs), max(self.restarts, 1))

    def flyability(self) -> Flyability:
        steps = max(1, int(np.ceil(self.min_pulse / self.grid - 1e-9)))
        return Flyability(steps, self.max_changes, 2 if self.allow_double_jumps else 1)

    # -- fit ----------------------------------------------------------------------------------------
    def fit(self, model: LinearModel) -> "SequenceDesign":
        t0, c0 = time.perf_counter(), _cpu_seconds()
        K = self.n_steps()
        fly = self.flyability()
        ev = Evaluator(model, self.inputs, self.record, self.dt, self.noise_std, limits=self.limits)
        default_limits(ev, self.duration, self.amplitude if self.amplitude is not None else self.reference_amplitude,
                       self.min_pulse)
        prior_information = self._prior_information(model, ev)  # checked before any work
        models, labels = self._model_set(model)
        basis = StepBasis(ev, self.grid, K, self.delay, models)
        offsets = None
        if self.criterion in ("worst", "robust") and not self._per_input():
            yard = Evaluator(model, self.inputs, self.record, self.dt, self.noise_std, models=models,
                             limits=dict(zip(model.profile.outputs, ev.limits)))
            offsets = yardsticks(yard, self.duration, self.min_pulse, jobs=self._jobs()).yardstick_log_dets
        amp = None if self.amplitude is None else float(np.atleast_1d(self.amplitude)[0])
        if self.amplitude is not None and np.ptp(np.atleast_1d(self.amplitude)) > 0:
            raise DesignError("a fixed amplitude must be the same on every axis (scale the inputs' units)")
        starts, classic = self._starts(ev, basis)
        kind = PerInputObjective if self._per_input() else Objective
        # per input, the classic inputs and the design are scored alike: each input at its own peak
        per_input_nominal = kind(basis, "nominal", stride=1) if self._per_input() else None
        if per_input_nominal is not None:
            classic = [float(per_input_nominal(s)) for s in starts]
            if self.criterion in ("worst", "robust"):  # each model's yardstick: the 3211 flown by that rule
                if not starts:
                    raise DesignError(f"duration {self.duration:g} s is too short for the 3211 yardstick of "
                                      f"{self.min_pulse:g} s pulses")
                offsets = kind(basis, "mean", stride=1).terms(starts[0])
        floor = None
        if self.criterion == "robust":
            # the nominal optimum seeds the robust search; the floor keeps the robust design at least
            # ``nominal_margin`` times as informative as the best tuned classic input on the a priori
            nominal = kind(basis, "nominal", amplitude=amp, stride=2)
            best, _ = self._search(nominal, fly, starts, n_iter=2 * self.n_iter, kicks=self.nominal_kicks)
            starts = [best.levels] + starts
            if self.nominal_margin is not None and amp is None:
                floor = max(classic) - offsets[0] + basis.evaluator.p * float(np.log(self.nominal_margin))
        objective = kind(basis, self.criterion, amplitude=amp, offsets=offsets,
                              weights=prior_weights(len(models), self.apriori_weight),
                              worst_weight=self.worst_weight, softness=self.softness, nominal_floor=floor,
                              stride=2, prior_information=prior_information)
        result, gap = self._search(objective, fly, starts)
        amplitude, r0 = objective.feasible_amplitude(result.levels)
        if not r0 > 0:
            raise DesignError("the designed sequence moves no output that has a response limit"
                              + (" on one of its inputs" if self._per_input() else ""))
        flown = self._flown(basis, result.levels, amplitude)
        peaks = basis.peaks(flown)
        # per input: each input alone within the limits (together the responses add)
        ratios = (np.max([basis.peaks(self._flown(basis, result.levels, amplitude, axis=a))
                          for a in range(len(self.inputs))], axis=0) if self._per_input() else peaks) / ev.limits
        if ratios.max() > 1 + 1e-9:
            i = int(np.argmax(ratios))
            y = model.profile.outputs[i]
            raise DesignError(
                f"infeasible: the search found no flyable sequence at amplitude {amplitude:g} that keeps {y} "
                f"within its limit {ev.limits[i]:g} (smallest peak found {peaks[i]:.3g}); lower the amplitude below "
                f"{amplitude / ratios.max():.3g} or leave it free")
        exact = objective.exact()
        # the certificate (after the feasibility check: no minutes of work before an error); an
        # exhaustive search needs none (gap 0), its bound is only shown
        if objective.prior_information is None:
            self.bound_ = objective_bound(exact, result.levels, jobs=self._jobs(),
                                          effort="quick" if gap is not None else self.certify)
            self.gap_ = gap if gap is not None else max(0.0, self.bound_.value - exact(result.levels))
        else:  # the relaxation's bound rests on log det's scale invariance, which the prior breaks
            self.bound_, self.gap_ = None, gap if gap is not None else float("nan")
        self.levels_, self.amplitude_ = result.levels, np.broadcast_to(amplitude, (len(self.inputs),)).copy()
        self.peaks_, self.limits_ = peaks, ev.limits
        self.binding_ = model.profile.outputs[int(np.argmax(ratios))]
        self.implausible_ = implausible_amplitudes(model.profile, self.inputs, self.amplitude_)
        for line in self.implausible_:
            warnings.warn(line, stacklevel=2)
        self.result_, self.basis_, self.evaluator_, self._objective_ = result, basis, ev, objective
        # D-efficiency on the a priori against the best tuned 3211 or doublet (the floor's reference)
        nominal_ld = (per_input_nominal(result.levels) if per_input_nominal is not None
                      else ev.equal_peak_log_det(basis.signals(result.levels, amplitude)))
        self.nominal_gain_ = float(np.exp((nominal_ld - max(classic)) / ev.p)) if classic else float("nan")
        self.models_, self.model_labels_ = models, labels
        self.width_ = self.grid
        params = {"criterion": self.criterion, "method": result.method, "duration": self.duration,
                  "record": self.record, "grid": self.grid, "min_pulse": self.min_pulse,
                  "max_changes": self.max_changes, "binding_limit": self.binding_, "peak": self.peak,
                  "restarts_spread": float(np.ptp(result.trace)) if result.trace else 0.0,
                  "units": {i: model.profile.inputs[i] for i in self.inputs}}
        self.signals_ = basis.signals(result.levels, amplitude, params=params)
        self.seconds_ = time.perf_counter() - t0
        self.cpu_seconds_ = _cpu_seconds() - c0  # this process and its workers: the machine may be shared
        return self

    def _per_input(self) -> bool:
        return self.peak == "per-input" and len(self.inputs) > 1

    @staticmethod
    def _flown(basis, levels, amplitude, axis=None) -> np.ndarray:
        """Levels times each axis' amplitude (``axis``: that axis alone, the others at rest)."""
        K = basis.n_steps
        scale = np.repeat(np.broadcast_to(np.asarray(amplitude, float), (len(basis.inputs),)), K)
        if axis is not None:
            scale = scale * (np.arange(scale.size) // K == axis)
        return np.asarray(levels, float) * scale

    def _prior_information(self, model, ev) -> np.ndarray | None:
        """With ``prior``: the profile's prior information ``diag(1 / std^2)`` over the scored
        parameters (0 where a parameter has none); the criterion must be one without per-model
        yardsticks (nominal or mean: the yardsticks are informations without the prior)."""
        if not self.prior:
            return None
        if self.criterion not in ("nominal", "mean"):
            raise DesignError(f"a design with the prior's information needs the criterion nominal or mean "
                              f"(not {self.criterion}: its yardsticks are designs without the prior)")
        table = model.profile.prior
        if not table:
            raise DesignError(f"{model.profile.source}: the profile declares no [prior] to design with")
        return np.diag([1 / table[n]["std"] ** 2 if n in table else 0.0 for n in ev.names])

    def _model_set(self, model):
        if self.criterion == "nominal":
            return [model], ["a priori"]
        if self.models is not None:
            models = list(self.models)
            return models, list(self.model_labels or [f"model {i}" for i in range(len(models))])
        return design_set(model, seed=self.seed + 1, draws=self.draws, extreme_draws=self.extreme_draws)

    def _starts(self, ev: Evaluator, basis: StepBasis) -> tuple[list[np.ndarray], list[float]]:
        """The best-width 3211 and doublet (tuned on the a priori at equal peak response) rounded
        onto the grid: the search starts from the classic inputs, so it cannot end below them.
        Also their equal-peak log dets on the a priori (at their tuned widths, off the grid)."""
        out, lds = [], []
        for factory, pulses, parts in ((m3211, 7, (3, 2, 1, 1)), (doublet, 2, (1, 1))):
            widths = width_grid(self.min_pulse, self.duration / pulses, self.dt)
            if not widths.size:
                continue
            _, w, ld = tune(factory, widths, ev, self.inputs, 1.0, max_pairs=64)
            lds.append(ld)
            ws = [float(x) for x in str(w).split("/")]
            ws = ws * len(self.inputs) if len(ws) == 1 else ws
            out.append(np.concatenate([_on_grid(parts, wa, basis.width, basis.n_steps) for wa in ws]))
        return out, lds

    def _search(self, objective: Objective, fly: Flyability, starts, n_iter=None,
                kicks=None) -> tuple[SearchResult, float | None]:
        """Exhaustive when the (single-axis) sequence space is small (gap 0), annealing otherwise."""
        K = objective.basis.n_steps
        limit = self.exhaustive_limit // max(objective.n_models, 1)
        n = count_sequences(K, fly, limit) if len(self.inputs) == 1 else None
        if n == 0:
            raise DesignError(f"no flyable sequence: min pulse {self.min_pulse:g} s and max changes "
                              f"{self.max_changes} leave none in {self.duration:g} s")
        if n is not None:
            return exhaustive(objective.exact(), fly, limit), 0.0
        # anneal on peaks read every other sample, then polish on every sample
        found = anneal(objective, fly, n_iter or self.n_iter, self.restarts, self.seed, starts, self.progress,
                       kicks=self.kicks if kicks is None else kicks, jobs=self._jobs())
        exact = objective.exact()
        found.levels, found.objective = polish(exact, fly, found.levels)
        found.evaluations += exact.evaluations
        return found, None

    def summary(self) -> str:
        """The design's levels, amplitude and peak responses against the limits."""
        p = self.evaluator_.model.profile
        lines = []
        for s in self.signals_:
            lines.append(f"optimised levels on {s.input} ({s.dt:g} s grid, {_changes(s.levels)} changes): "
                         + " ".join(f"{int(v):+d}" for v in s.levels))
        lines.append(f"amplitude {', '.join(f'{a:.4g}' for a in self.amplitude_)} "
                     f"({'fixed' if self.amplitude is not None else self._amplitude_rule()}); "
                     f"limits: {self.evaluator_.limits_source}")
        cells = [f"{y} {pk:.3g}/{lim:.3g}" + (" BINDS" if y == self.binding_ else "")
                 for y, pk, lim in zip(p.outputs, self.peaks_, self.limits_) if np.isfinite(lim)]
        whole = " (the run's whole response: the inputs' add; BINDS: at its limit under one input alone)"
        lines.append("peak response / limit on the a priori" + (whole if self._per_input() else "") + ": "
                     + ", ".join(cells))
        lines += [f"WARNING: {line}" for line in self.implausible_]
        res = self.result_
        how = ("exhaustive: exact optimum among flyable sequences" if res.method == "exhaustive" else
               f"annealing, {len(res.trace)} restarts ending within {max(res.trace) - min(res.trace):.3f} "
               f"of each other in the criterion ({self._agreement_text()})")
        if self.prior:
            how += "; the criterion: log det of the prior's information plus the flight's at the amplitude flown"
        floor = (f", floor {self.nominal_margin:g}x" if self.criterion == "robust" and self.nominal_margin
                 and self.amplitude is None else "")
        if floor and self.nominal_gain_ < self.nominal_margin * (1 - 1e-6):
            floor += " NOT REACHED: the search found no flyable sequence above it"
        lines.append(f"on the a priori: D-efficiency {self.nominal_gain_:.3f}x the best tuned 3211/doublet{floor}")
        lines.append(f"criterion {self.criterion} over {len(self.models_)} model(s); {how}; "
                     f"{res.evaluations} candidates scored in {self.seconds_:.1f} s")
        lines.append(self.certificate())
        return "\n".join(lines)

    @property
    def spread_efficiency_(self) -> float:
        """The worst restart's D-efficiency relative to the best restart's (1: every restart agrees)."""
        spread = max(self.result_.trace) - min(self.result_.trace)
        return float(np.exp(-spread / (self.evaluator_.p * self._weight())))

    def _agreement_text(self) -> str:
        eff = self.spread_efficiency_
        verdict = ("they agree" if eff >= 1 - self.agreement - 1e-12 else
                   f"they DISAGREE beyond {100 * self.agreement:g} %: a better optimum may exist")
        return f"the worst restart reaches D-efficiency {eff:.3f} of the best; {verdict}"

    def _amplitude_rule(self) -> str:
        if self._per_input():
            return "outcome: each input the largest its own response, alone, allows (equal per-input peak response)"
        return "outcome: the largest within the limits"

    def certificate(self) -> str:
        """One line: the D-efficiency the design is certified to reach relative to the optimum, from
        the upper bound, and how much of the gap the relaxation itself holds."""
        if self.result_.method == "exhaustive":
            shown = "" if self.bound_ is None else f"; the continuous relaxation's bound is {self.bound_.value:.2f}"
            return f"certified D-efficiency 1.000 of the optimum among flyable sequences (exhaustive search{shown})"
        if self.bound_ is None:
            return ("certified D-efficiency: none (no upper bound with the prior's information: the relaxation's "
                    "bound needs log det's scale invariance, which the prior breaks)")
        if not np.isfinite(self.bound_.value):
            return ("certified D-efficiency: none (the semidefinite relaxation's upper bound could not be made finite: "
                    "some model's bound is infinite)")
        w = self._weight()
        relaxed = self.relaxed_value_
        slack = "" if not np.isfinite(relaxed) else (
            f"; the relaxation reaches {relaxed:.2f} (each model's relaxed input), so a bound of this kind "
            f"certifies at most {np.exp(-max(0.0, relaxed - self.result_.objective) / (self.evaluator_.p * w)):.3g} "
            f"(the relaxation's own gap: continuous levels, mixtures of inputs) and this one leaves "
            f"{self.bound_.value - relaxed:.2f} open" + (" (--certify full tightens it)" if self.certify == "quick" else ""))
        return (f"certified D-efficiency >= {self.efficiency_bound_:.3g} of the optimum's (criterion "
                f"{self.result_.objective:.2f}, semidefinite-relaxation upper bound {self.bound_.value:.2f}, "
                f"gap {self.gap_:.2f} = {self.evaluator_.p} parameters x {w:g} x log(1/{self.efficiency_bound_:.3g}))"
                + slack)

    @property
    def relaxed_value_(self) -> float:
        """The criterion combined from each model's relaxed value reached (the bound cannot fall
        below it; inf where a model is unbounded)."""
        if self.bound_.relaxed is None:
            return float("nan")
        exact = self._objective_.exact()
        return float(exact.combine(self.bound_.relaxed - exact.offsets, floor=False))

    def _weight(self) -> float:
        return 1.0 + (self.worst_weight if self.criterion == "robust" else 0.0)

    @property
    def efficiency_bound_(self) -> float:
        """Lower bound on the design's D-efficiency relative to the optimum: exp(-gap / (p w)), w the
        total weight of the criterion's log dets (1; 1 + worst weight for robust)."""
        return float(np.exp(-self.gap_ / (self.evaluator_.p * self._weight())))


def prior_weights(n_models: int, apriori_weight: float) -> np.ndarray:
    """Weights of the expected log det: ``apriori_weight`` on the a priori (model 0, the best single
    guess), the rest spread evenly over the other models of the set."""
    if n_models == 1:
        return np.ones(1)
    if not 0 <= apriori_weight < 1:
        raise DesignError(f"a priori weight must be in [0, 1), got {apriori_weight:g}")
    return np.concatenate([[apriori_weight], np.full(n_models - 1, (1 - apriori_weight) / (n_models - 1))])


def _on_grid(pulses, width: float, grid: float, n_steps: int) -> np.ndarray:
    """Alternating-sign multistep of ``pulses`` x ``width`` s as levels on the grid (switch times
    rounded to the grid, truncated to ``n_steps``)."""
    levels = np.zeros(n_steps)
    t, sign = 0.0, 1.0
    for n in pulses:
        a, b = int(round(t / grid)), int(round((t + n * width) / grid))
        levels[a:min(b, n_steps)] = sign
        t, sign = t + n * width, -sign
    return levels


def _cpu_seconds() -> float:
    """CPU s of this process and of its finished child processes (the search's workers)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _changes(levels) -> int:
    return int(np.count_nonzero(np.diff(np.concatenate([[0], levels, [0]]))))

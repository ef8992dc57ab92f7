"""Common base of the estimators (LS, IV, ML): scikit-learn style objects.

``Estimator(profile, **options).fit(runs)`` returns the estimator itself; the result is the
attribute ``result_`` (an :class:`~identify.estimators.result.IdentificationResult`), with ``theta_``
and ``std_`` as shortcuts and ``summary()`` printing the parameter table.

As in scikit-learn, ``__init__`` only stores its arguments (a profile may be a :class:`Profile`, a
TOML path or a bundled name); ``fit`` validates them (:meth:`Estimator._validate`: the loaded
profile is ``profile_``, converted options end in ``_``) and raises the one-line error there.

The protocol refine (and any tool that compares nested models) relies on, so that it never asks
which estimator it holds -- a new estimator (filter error, a frequency-response fit) plugs in by
subclassing :class:`Estimator` and overriding what differs:

``get_params()`` / ``clone(profile, **changes)``
    scikit-learn's: the constructor arguments, and a new unfitted estimator with the same ones for
    another (an extended) profile. Refine holds one estimator instance and clones it per fit.
``nested(profile, *, zero_shifts, segment, bounds, advice, start)``
    the estimator for one of refine's nested fits: ``clone(profile)`` adjusted so that the
    likelihoods of fits before and after an added effect compare (the same nuisance: per-run zero
    shifts or not; the same multiple-shooting ``segment``); ``bounds=False`` when only the estimate
    and its likelihood are used (may skip costly standard errors, and stop once the likelihood is
    far inside one unit of its optimum); ``start`` the result of a neighbouring model's fit (a
    search's), whose noise estimate may start this one's. Default: ``clone(profile)``.
``prediction_segment(model, duration)``
    the segment length (s) the estimator's predictions restart at (``inf``: whole runs).
``prediction(profile, runs, *, zero_shifts, segment, start)``
    the model's prediction of the runs as a :class:`~identify.estimators.prediction.ModelFit`:
    residuals per run with the nuisance fitted. The residuals are what the estimator minimises
    and what refine tests: by default output error (the model simulated from the inputs, each
    segment's initial state and zero shifts fitted; state-built pseudo-inputs from the simulated
    states, ``start`` runs holding a nearby model's). A filter-error estimator returns its
    one-step-ahead innovations instead, with the noise parameters it fitted in ``ModelFit.noise``;
    refine passes those back as ``noise=`` to predict held-out runs with the fitted model's noise
    (its filter gain) held (only estimators that fill ``ModelFit.noise`` are asked so).
``sensitivities(profile, runs, null, *, zero_shifts, segment)``
    the prediction of an extended ``profile`` (its added parameters at their null values) with
    ``dy`` (its residuals' sensitivities to the parameters) and ``nuisance`` (to the nuisance):
    the score tests' columns, at ``null``, the prediction of the model without the extension.
``input_response(profile, runs, *, segment, input_name, transform)``
    per run the model's response to a transformed input (a delay's score column, ``-du/dt``).
``simulates_state_terms``
    whether pseudo-inputs built from states are taken from the model's simulated states when
    fitting (output error) rather than from the measured channels (equation error).
``builds_state_terms``
    whether the estimator computes such pseudo-inputs itself, inside each fit, from its own state
    estimates (the extended filter of FEM): then one fit is the estimate and its bounds, no
    re-fitting until the simulated terms settle.
``progress_quantity``
    what the ``progress`` callback's value is (``cost``, ``max rel. change``), for messages.
``determinable(profile, runs)``
    the structure refine fits and extends, and ``{parameter: reason}`` for the parameters the
    estimator cannot determine from these runs (held at their a priori values for the whole
    refinement). Default: the profile as declared, nothing held. The frequency-response fit
    holds what fails CIFER's gates: unpruned, its nested fits diverge along those directions.
"""
from __future__ import annotations

import inspect
import math
import warnings
from pathlib import Path

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..model.profile import Profile, load_profile
from ..model.pseudo_inputs import prepare
from ..model.subset import check_some_input_flown, fix, held_line, unflown_parameters
from .prior import combined_with_prior
from .result import IdentificationResult

MIN_SAMPLES = 10


class HeldWarning(UserWarning):
    """Parameters held at their a priori values because no run moves their input."""


def expand_held(reduced: IdentificationResult, full: Profile, unflown: dict[str, list[str]],
                line: str) -> IdentificationResult:
    """The result of a fit on ``full`` with the unflown inputs' parameters held, back on ``full``:
    held parameters at their a priori values with an infinite standard error (no information),
    uncorrelated with the rest; ``info["held"]`` and ``info["held_note"]`` say which and why."""
    names = full.free_names
    idx = [names.index(n) for n in reduced.names]
    theta = np.array(list(full.free.values()), float)
    std = np.full(len(names), np.inf)
    theta[idx], std[idx] = reduced.theta, reduced.std
    cov = np.zeros((len(names), len(names)))
    np.fill_diagonal(cov, np.inf)
    cov[np.ix_(idx, idx)] = reduced.covariance if reduced.covariance is not None else np.diag(reduced.std ** 2)
    info = {**reduced.info, "held": unflown, "held_note": line}
    if "not_excited" in info:  # ML's list of parameters without influence: the held ones have none
        info["not_excited"] = [n for n in names if n in set(info["not_excited"]) | set(full.free) - set(reduced.names)]
    return IdentificationResult(reduced.method, full, theta, std, reduced.fit, info, reduced.runs, cov,
                                reduced.time, reduced.measured, reduced.modelled)


class Estimator:
    """Base class: holds the profile (structure + a priori values) and checks the runs."""

    method = "base"
    models_turbulence = False  # whether a profile's [turbulence] is part of the estimator's model (FEM)
    simulates_state_terms = False
    builds_state_terms = False
    progress_quantity = "value"
    # whether the fit itself weighs the profile's [prior] (its residuals in the cost); else ``fit``
    # combines the prior with the data's estimate afterwards (identify.estimators.prior.combine)
    weighs_prior = False

    def __init__(self, profile: Profile | str | Path):
        self.profile = profile
        self.result_: IdentificationResult | None = None

    def fit(self, runs: Run | list[Run]) -> "Estimator":
        self._validate()
        runs = self.check_runs(runs)
        unflown = unflown_parameters(self.profile_, runs)
        if unflown:
            self.result_ = self._fit_holding(runs, unflown)
        else:
            self.result_ = self._fit(runs)
        if not self.weighs_prior:  # the profile's [prior], combined with the data's estimate
            self.result_ = combined_with_prior(self.result_, self.profile_)
        from ..data.provenance import provenance

        info = self.result_.info
        info.setdefault("provenance", provenance(runs))  # into result.json with the estimates
        if "wall_time" in info:  # how long this machine took: a fact of the run, beside its files, not a result
            info["provenance"]["wall_time_s"] = info.pop("wall_time")
        if self.profile_.turbulence and not self.models_turbulence:
            line = (f"{self.method.upper()}: the profile's [turbulence] is modelled by the filter-error method only "
                    f"(--method fem); {self.method.upper()} took the gusts' response for measurement noise")
            warnings.warn(line, stacklevel=2)
            info["turbulence_not_modelled"] = line
        return self

    def _fit_holding(self, runs: list[Run], unflown: dict[str, list[str]]) -> IdentificationResult:
        """Controls no run moves: their parameters carry no information; fit with them held at
        their a priori values (said, recorded) and return the result on the whole profile."""
        check_some_input_flown(self.profile_, unflown)
        line = held_line(self.method, unflown)
        warnings.warn(line, HeldWarning, stacklevel=3)
        full, held = self.profile_, [n for params in unflown.values() for n in params]
        if len(held) == len(full.free):
            raise EstimationError(f"{line}: no free parameter is left to estimate")
        # the same estimator on the profile with those parameters fixed; its fitted state is kept,
        # then the full profile's restored (``_validate`` rebuilds what depends on it)
        sub = self.clone(fix(full, held))
        sub._validate()
        reduced = sub._fit(runs)
        self.__dict__.update({k: v for k, v in sub.__dict__.items() if k.endswith("_")})
        self._validate()
        return expand_held(reduced, full, unflown, line)

    def _validate(self) -> None:
        """Load the profile (``profile_``) and check the options; subclasses add theirs."""
        self.profile_ = self.profile if isinstance(self.profile, Profile) else load_profile(self.profile)

    def _fit(self, runs: list[Run]) -> IdentificationResult:  # pragma: no cover - abstract
        raise NotImplementedError

    def check_runs(self, runs: Run | list[Run], channels: list[str] | None = None) -> list[Run]:
        """One or several runs, each holding the channels the profile needs and enough samples."""
        runs = [runs] if isinstance(runs, Run) else list(runs)
        if not runs:
            raise EstimationError("no runs given")
        if not self.profile_.free:
            raise EstimationError(f"{self.profile_.source}: the profile has no free parameters")
        # an input no run records was not flown: zero (its parameters are then held, see fit);
        # one recorded in some runs only is a missing channel, reported below
        absent = [u for u in self.profile_.input_names if not any(u in r.channels for r in runs)
                  and u not in dict(self.profile_.meta.get("pseudo_inputs", {}))]
        if absent:
            runs = [r.with_channels({u: np.zeros(len(r)) for u in absent},
                                    not_recorded=f"{', '.join(absent)} (not flown: taken as zero)") for r in runs]
        # as the profile needs them: inputs delayed by its meta.delays, its pseudo-inputs (a refined
        # model's nonlinear terms, drifts, vibrations) computed from the runs' own channels
        runs = prepare(self.profile_, runs)
        for run in runs:
            run.require(channels or self.profile_.channels, f"profile '{self.profile_.name}'")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; at least {MIN_SAMPLES} needed")
        return runs

    # -- the protocol of nested fits (see the module notes) ------------------------------------
    @classmethod
    def param_names(cls) -> list[str]:
        """Named constructor arguments, those a ``**options`` passes on to a base class included."""
        names = []
        for klass in cls.__mro__:
            if "__init__" not in vars(klass):
                continue
            params = inspect.signature(klass.__init__).parameters.values()
            names += [p.name for p in params if p.name != "self" and p.name not in names
                      and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
            if not any(p.kind == p.VAR_KEYWORD for p in params):
                break
        return names

    def get_params(self) -> dict:
        """The constructor arguments (scikit-learn's ``get_params(deep=False)``)."""
        return {n: getattr(self, n) for n in self.param_names()}

    def clone(self, profile=None, **changes) -> "Estimator":
        """A new, unfitted estimator with the same arguments, for ``profile`` (default the same)."""
        unknown = set(changes) - set(self.param_names())
        if unknown:
            raise EstimationError(f"{type(self).__name__} has no option(s) {', '.join(sorted(unknown))}")
        params = {**self.get_params(), **changes}
        if profile is not None:
            params["profile"] = profile
        return type(self)(**params)

    def nested(self, profile, *, zero_shifts: bool = True, segment: float = math.inf,
               bounds: bool = True, advice: bool = True, start=None) -> "Estimator":
        return self.clone(profile)

    def prediction_segment(self, model, duration: float) -> float:
        return math.inf

    def determinable(self, profile, runs: list[Run]) -> tuple[Profile, dict[str, str]]:
        return profile, {}

    def prediction(self, profile, runs: list[Run], *, zero_shifts: bool = True, segment: float = math.inf,
                   start: list[Run] | None = None):
        from .prediction import predict  # output error, loaded only when asked

        return predict(profile, runs, zero_shifts, segment, start=start)

    @staticmethod
    def fitted_noise(result) -> dict | None:
        """Noise parameters a fit estimated that its prediction re-fits (a filter's F and R, as
        ``ModelFit.noise``), handed back as the prediction's ``noise_start``; None: none."""
        return None

    def sensitivities(self, profile, runs: list[Run], null, *, zero_shifts: bool = True,
                      segment: float = math.inf):
        from .prediction import evaluate, simulated_terms, state_terms

        # a state-built term's column from the null model's simulated states (the model's own at
        # the null value): an instrumental-variable score, uncorrelated with the gusts the
        # measured states carry
        runs = simulated_terms(profile, runs, null, state_terms(profile), segment)
        return evaluate(profile, runs, zero_shifts, segment, jacobian=True)

    def input_response(self, profile, runs: list[Run], *, segment: float, input_name: str, transform):
        from .prediction import input_response

        return input_response(profile, runs, segment, input_name, transform)

    @property
    def theta_(self) -> np.ndarray:
        return self._fitted().theta

    @property
    def std_(self) -> np.ndarray:
        return self._fitted().std

    def summary(self, truth: dict[str, float] | None = None) -> str:
        return self._fitted().summary(truth)

    def _fitted(self) -> IdentificationResult:
        if self.result_ is None:
            raise EstimationError(f"{type(self).__name__} is not fitted yet: call fit(runs) first")
        return self.result_

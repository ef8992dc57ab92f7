"""Common base of the estimators (LS, IV, ML): scikit-learn style objects.

``Estimator(profile, **options).fit(runs)`` returns the estimator itself; the result is the
attribute ``result_`` (an :class:`~identify.estimators.result.IdentificationResult`), with ``theta_``
and ``std_`` as shortcuts and ``summary()`` printing the parameter table.

As in scikit-learn, ``__init__`` only stores its arguments (a profile may be a :class:`Profile`, a
TOML path or a bundled name); ``fit`` validates them (:meth:`Estimator._validate`: the loaded
profile is ``profile_``, converted options end in ``_``) and raises the one-line error there.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..model.profile import Profile, load_profile
from ..model.pseudo_inputs import prepare
from .result import IdentificationResult

MIN_SAMPLES = 10


class Estimator:
    """Base class: holds the profile (structure + a priori values) and checks the runs."""

    method = "base"

    def __init__(self, profile: Profile | str | Path):
        self.profile = profile
        self.result_: IdentificationResult | None = None

    def fit(self, runs: Run | list[Run]) -> "Estimator":
        self._validate()
        runs = self.check_runs(runs)
        self.result_ = self._fit(runs)
        from ..data.provenance import provenance

        self.result_.info.setdefault("provenance", provenance(runs))  # into result.json with the estimates
        return self

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
        # as the profile needs them: inputs delayed by its meta.delays, its pseudo-inputs (a refined
        # model's nonlinear terms, drifts, vibrations) computed from the runs' own channels
        runs = prepare(self.profile_, runs)
        for run in runs:
            run.require(channels or self.profile_.channels, f"profile '{self.profile_.name}'")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; at least {MIN_SAMPLES} needed")
        return runs

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

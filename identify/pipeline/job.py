"""One identification job: its runs, a priori profile, method and options, how the runs are read.

``Job(...).estimate()`` fits and checks (:class:`Estimation`), ``Job(...).refine()`` closes the
loop (:class:`Refinement`); both results are complete when returned (nothing is added to them
afterwards by a caller) and ``save(out)`` writes them. The command line, the campaign and Python
callers build the same Job, so the same job gives the same result.json on every path.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .reading import Reading


@dataclass
class Job:
    """``runs`` the files fitted (.csv or .mat); ``profile`` a :class:`~identify.model.profile.Profile`,
    a TOML path or a bundled name; ``method`` a registered estimator (``identify.estimators.registry``)
    with its ``options`` (constructor arguments; None: the default); ``reading`` how the files are
    read and prepared; ``verify`` held-out files the identified model must predict (VERIFY)."""

    runs: list[str | Path]
    profile: object
    method: str = "ml"
    options: dict = field(default_factory=dict)
    reading: Reading = field(default_factory=Reading)
    verify: list[str | Path] = field(default_factory=list)

    def profile_(self):
        from ..model.profile import Profile, load_profile

        return self.profile if isinstance(self.profile, Profile) else load_profile(self.profile)

    def estimator(self, profile=None, progress=None, names: dict[str, str] | None = None):
        """The estimator instance of ``method`` with ``options`` (an option the method does not
        take is one error, naming it as ``names`` maps it, e.g. to its command-line flag)."""
        from ..estimators.registry import build

        return build(self.method, profile or self.profile_(), progress=progress, names=names, **self.options)

    def estimate(self, progress=None, names: dict[str, str] | None = None) -> "Estimation":
        """Read, prepare, fit, check: the :class:`Estimation` (see :mod:`identify.pipeline.estimation`)."""
        from .estimation import estimate

        profile = self.profile_()
        runs = self.reading.prepared(self.runs, profile)
        held = self.reading.prepared(self.verify, profile, window=False) if self.verify else []
        return estimate(self.estimator(profile, progress, names), runs, held)

    def refine(self, validate=(), names: dict[str, str] | None = None, **options) -> "Refinement":
        """Fit, find unmodelled effects, add them, re-identify (:class:`~identify.refine.loop.Refine`
        with ``options``, ``validate`` held-out files every added effect is checked on)."""
        from ..refine.loop import Refine
        from .refinement import Refinement

        profile = self.profile_()
        runs = self.reading.prepared(self.runs, profile)
        held = self.reading.prepared(list(validate), profile, window=False) if validate else []
        refiner = Refine(profile, estimator=self.estimator(profile, names=names), **options)
        return Refinement(refiner.fit(runs, validate=held))

"""The result of ``Job.refine``: the fitted :class:`~identify.refine.loop.Refine` and its writer."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class Refinement:
    refiner: object

    @property
    def result(self):
        """The final model's :class:`~identify.estimators.result.IdentificationResult`."""
        return self.refiner.result_

    def save(self, out: str | Path) -> Path:
        """``refine.json`` (with the data's provenance), ``report.md``, ``final_profile.toml``, plots."""
        from ..refine.report import write

        return write(self.refiner, out)

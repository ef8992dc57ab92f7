"""The evidence of one tried effect in the refinement loop (:class:`Step`), kept whether the effect
was accepted or rejected, for the report and ``refine.json``."""
from __future__ import annotations

from dataclasses import dataclass, field, fields


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
    held_change: dict = field(default_factory=dict)  # data -> cost of the prediction change alone (its size)
    attempts: list = field(default_factory=list)  # the re-fits of a fit that ended below the null, in order
    lr_criterion: str = ""  # the estimator's own criterion of the likelihood ratio ('': the noise-model metric)
    nu: float | None = None  # dof of the noise level along it where the test's law is F (None: chi-square)
    noise_white: bool = True  # the test's noise model whitened the residuals (False: at its order cap)
    error_change: dict = field(default_factory=dict)  # data -> the plain error's change and its noise

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

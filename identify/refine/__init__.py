"""Refine: find the structure left in the residuals, name the effect, add it, re-identify."""
from .loop import Evaluation, Refine, Step, errors, estimator_class, evaluate, neg_log_likelihood, run_design, segments

__all__ = ["Evaluation", "Refine", "Step", "errors", "estimator_class", "evaluate", "neg_log_likelihood",
           "run_design", "segments"]

"""Refine: find the structure left in the residuals, name the effect, add it, re-identify."""
from ..estimators.registry import estimator_class
from .evaluation import ModelFit, errors, evaluate, neg_log_likelihood, split_validation
from .loop import Refine, Step

__all__ = ["ModelFit", "Refine", "Step", "errors", "estimator_class", "evaluate", "neg_log_likelihood",
           "split_validation"]

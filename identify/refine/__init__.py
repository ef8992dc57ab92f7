"""Refine: find the structure left in the residuals, name the effect, add it, re-identify."""
from .evaluation import errors, neg_log_likelihood, split_validation
from .fitting import Fitting
from .loop import Refine, Step
from .scoring import ScoreTest

__all__ = ["Fitting", "Refine", "ScoreTest", "Step", "errors", "neg_log_likelihood", "split_validation"]

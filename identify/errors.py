"""Exceptions that the command lines turn into one clear line and exit status 2.

Every error pseudostep raises on bad input derives from :class:`PseudostepError`; its message
names the file, row, channel, parameter or state at fault, so the user never needs a traceback.
"""


class PseudostepError(Exception):
    """Base class for errors caused by the user's input, not by a bug."""


class ProfileError(PseudostepError):
    """A profile (a priori model TOML) is malformed."""


class RunError(PseudostepError):
    """A run file (measured data) is malformed or lacks a channel."""


class SimulationError(PseudostepError):
    """A simulation diverged or cannot be carried out."""


class EstimationError(PseudostepError):
    """An estimator cannot proceed (unidentifiable parameters, too few samples, divergence)."""


class ConvergenceWarning(UserWarning):
    """An iterative estimator stopped before convergence: its estimates are not final. The result
    says so too (``info["converged"]`` False, the reason in ``info["stop"]`` and ``summary()``)."""

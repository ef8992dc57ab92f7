"""Former path of the frequency-domain equation error, kept only so the cockpit's live room imports
until it calls :class:`identify.estimators.frequency.equation_error.FDEE` (``partial_fit``) itself."""
from .frequency.equation_error import FDEE, LiveEstimate, RecursiveFDEE

__all__ = ["FDEE", "LiveEstimate", "RecursiveFDEE"]

"""Method name -> estimator class, the one table used by the command line and by refine."""
from __future__ import annotations

from ..errors import EstimationError
from .equation_error import IV, LS
from .frequency_ee import FDEE
from .ml import ML

METHODS = {"ml": ML, "ls": LS, "iv": IV, "fdee": FDEE}


def estimator_class(method: str):
    """The estimator class of a method name (``ml``, ``ls``, ``iv``, ``fdee``)."""
    try:
        return METHODS[method]
    except KeyError:
        raise EstimationError(f"unknown method '{method}' (choose from {', '.join(METHODS)})") from None

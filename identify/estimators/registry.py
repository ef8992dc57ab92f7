"""Method name -> estimator class, the one table used by the command line and by refine.

The classes are imported when asked for (:func:`estimator_class`): the command line lists the
method names in ``--help`` without loading the estimators (and scipy.signal with them).
"""
from __future__ import annotations

import importlib

from ..errors import EstimationError

# method name -> (module under identify.estimators, class)
_CLASSES = {"ml": ("ml", "ML"), "ls": ("equation_error", "LS"), "iv": ("equation_error", "IV"),
            "fdee": ("frequency_ee", "FDEE"), "fem": ("filter_error", "FEM")}
METHOD_NAMES = tuple(_CLASSES)


def estimator_class(method: str):
    """The estimator class of a method name (``ml``, ``ls``, ``iv``, ``fdee``)."""
    try:
        module, name = _CLASSES[method]
    except KeyError:
        raise EstimationError(f"unknown method '{method}' (choose from {', '.join(_CLASSES)})") from None
    return getattr(importlib.import_module(f".{module}", __package__), name)


def __getattr__(name: str):
    if name == "METHODS":  # {name: class}: imports every estimator
        return {m: estimator_class(m) for m in _CLASSES}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

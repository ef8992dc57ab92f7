"""Method name -> estimator class, the one table the command line builds estimators from.

The names are a plain tuple (``--help`` lists them without loading any estimator, and scipy.signal
with them); the classes are imported when first asked for (:func:`estimator_classes`), by plain
imports that the layer test reads. :func:`build` makes an estimator *instance* from a name and
the command line's options; everything after that (refine included) holds the instance.
"""
from __future__ import annotations

from ..errors import EstimationError

METHOD_NAMES = ("ml", "ls", "iv", "fdee", "fr")


def estimator_classes() -> dict[str, type]:
    """``{method name: class}``; imports every estimator."""
    from .equation_error import IV, LS
    from .frequency.equation_error import FDEE
    from .frequency.response_fit import FR
    from .ml import ML

    classes = {"ml": ML, "ls": LS, "iv": IV, "fdee": FDEE, "fr": FR}
    assert tuple(classes) == METHOD_NAMES
    return classes


def estimator_class(method: str) -> type:
    """The estimator class of a method name (``ml``, ``ls``, ``iv``, ``fdee``)."""
    if method not in METHOD_NAMES:
        raise EstimationError(f"unknown method '{method}' (choose from {', '.join(METHOD_NAMES)})")
    return estimator_classes()[method]


def build(method: str, profile, *, progress=None, names: dict[str, str] | None = None, **options):
    """An estimator instance of ``method`` for ``profile``. ``options`` (their value None: not
    given) must be parameters of that estimator, else one clear error naming them as the caller
    calls them (``names``: parameter -> e.g. its command-line flag); ``progress`` (a callable
    ``(iteration, value, theta)``) is passed where the estimator reports progress."""
    cls = estimator_class(method)
    accepted = set(cls.param_names())
    given = {k: v for k, v in options.items() if v is not None}
    unknown = sorted(set(given) - accepted)
    if unknown:
        called = ", ".join((names or {}).get(k, k) for k in unknown)
        raise EstimationError(f"{called} does not apply to {method} "
                              f"(its options: {', '.join(sorted(accepted - {'profile', 'progress'}))})")
    if progress is not None and "progress" in accepted:
        given["progress"] = progress
    return cls(profile, **given)


def __getattr__(name: str):
    if name == "METHODS":  # {name: class}: imports every estimator
        return estimator_classes()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["METHOD_NAMES", "build", "estimator_class", "estimator_classes"]

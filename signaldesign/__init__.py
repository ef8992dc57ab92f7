"""signaldesign: required frequency band and optimised three-level input signals (before the flight).

Builds on :mod:`identify` (models, sensitivities); never imports :mod:`cueing`. Names are imported
on first use (module ``__getattr__``), so ``signaldesign --help`` answers at once.
"""
from __future__ import annotations

from identify._version import __version__  # noqa: F401 (one version for the whole project)

import importlib

_LAZY = {
    **dict.fromkeys(["Signal", "SignalError", "load_signals", "save_signals", "signals_to_run"], "signal"),
    **dict.fromkeys(["BandError", "required_band"], "band"),
    **dict.fromkeys(["doublet", "m3211", "make_signal", "multisine", "multistep", "orthogonal_multisines", "prts",
                     "step_sequence"], "baselines"),
    **dict.fromkeys(["Flyability", "SequenceDesign"], "design"),
    **dict.fromkeys(["DesignError", "Evaluator", "perturbed_models"], "evaluate"),
    **dict.fromkeys(["energy_spectrum", "half_power_band", "in_band_fraction"], "spectrum"),
}
__all__ = list(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'signaldesign' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

"""signaldesign: required frequency band and optimised three-level input signals (before the flight).

Builds on :mod:`identify` (models, sensitivities); never imports :mod:`cueing`.
"""
from .signal import Signal, SignalError, load_signals, save_signals, signals_to_run

__all__ = ["Signal", "SignalError", "load_signals", "save_signals", "signals_to_run"]

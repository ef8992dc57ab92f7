"""signaldesign: required frequency band and optimised three-level input signals (before the flight).

Builds on :mod:`identify` (models, sensitivities); never imports :mod:`cueing`.
"""
from .signal import Signal, SignalError, load_signals, save_signals, signals_to_run
from .band import BandError, required_band
from .baselines import doublet, m3211, make_signal, multisine, multistep, orthogonal_multisines, prts, step_sequence
from .design import Flyability, SequenceDesign
from .evaluate import DesignError, Evaluator, perturbed_models
from .spectrum import energy_spectrum, half_power_band, in_band_fraction

__all__ = ["Signal", "SignalError", "load_signals", "save_signals", "signals_to_run",
           "BandError", "required_band", "doublet", "m3211", "make_signal", "multisine", "multistep",
           "orthogonal_multisines", "prts", "step_sequence", "Flyability", "SequenceDesign", "DesignError",
           "Evaluator", "perturbed_models", "energy_spectrum", "half_power_band", "in_band_fraction"]

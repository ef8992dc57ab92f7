"""identify: models, runs, simulation and estimation (after the flight). The base layer.

Typical use::

    from identify import load_profile, LinearModel, read_run
    model = LinearModel(load_profile("s61_hover_8state"))
    est = Job(["run_lon.csv"], "profile.toml", method="ml", reading=Reading(trim="first:1s")).estimate()
    print(est.text()); est.save("out")     # what ``identify estimate`` prints and writes

Names are imported on first use (module ``__getattr__``): ``import identify`` and the command
lines' ``--help`` stay fast, and scipy.signal, python-control and matplotlib load only when a
function that needs them runs.
"""
from __future__ import annotations

import importlib

from ._version import __version__
from .errors import ConvergenceWarning, EstimationError, ProfileError, PseudostepError, RunError, SimulationError

# public name -> submodule that defines it
_LAZY = {
    **dict.fromkeys(["Run"], "data.runs"),
    **dict.fromkeys(["read_run"], "data.csvfile"),
    **dict.fromkeys(["read_runs", "read_run_files"], "data.io"),  # .csv and .mat, through the one reader
    **dict.fromkeys(["Job", "Reading"], "pipeline"),  # one identification: read, prepare, fit, check, write
    **dict.fromkeys(["IdentificationResult"], "estimators.result"),
    **dict.fromkeys(["LinearModel", "Mode", "format_modes", "modes_of", "residualize"], "model.linear"),
    **dict.fromkeys(["Profile", "load_profile", "output_units", "parse_profile"], "model.profile"),
    **dict.fromkeys(["output_sensitivities"], "model.sensitivity"),
    **dict.fromkeys(["delay_inputs", "discretize", "perturbed_model", "simulate", "simulate_run"], "model.simulate"),
    # data processing and estimators (plots stay in identify.estimators.plots)
    **dict.fromkeys(["read_mat"], "data.matfile"),
    **dict.fromkeys(["add_derivatives", "cg_correction", "processing_steps", "replay", "smooth",
                     "smooth_derivative"], "data.preprocess"),
    **dict.fromkeys(["IV", "LS", "state_derivatives"], "estimators.equation_error"),
    **dict.fromkeys(["ML"], "estimators.ml"),  # output-error maximum likelihood
    # the frequency home: equation error (batch, streamed for the cockpit), frequency responses
    **dict.fromkeys(["FDEE"], "estimators.frequency.equation_error"),
    **dict.fromkeys(["FrequencyResponse", "frequency_response", "fit_cost"], "estimators.frequency.response"),
}

__all__ = ["__version__", "ConvergenceWarning", "EstimationError", "ProfileError", "PseudostepError", "RunError",
           "SimulationError", *_LAZY]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'identify' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # once imported, a plain attribute
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))

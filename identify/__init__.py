"""identify: models, runs, simulation and estimation (after the flight). The base layer.

Typical use::

    from identify import load_profile, LinearModel, read_run
    model = LinearModel(load_profile("s61_hover_8state"))
"""
from .data.runs import Run, read_run, read_runs
from .errors import ConvergenceWarning, EstimationError, ProfileError, PseudostepError, RunError, SimulationError
from .estimators.result import IdentificationResult
from .model.linear import LinearModel, Mode, format_modes, modes_of, residualize
from .model.profile import Profile, load_profile, output_units, parse_profile
from .model.sensitivity import output_sensitivities
from .model.simulate import delay_inputs, discretize, perturbed_model, simulate, simulate_run

__all__ = ["ConvergenceWarning", "EstimationError", "ProfileError", "PseudostepError", "RunError", "SimulationError",
           "LinearModel", "Mode", "format_modes", "modes_of", "residualize", "Profile", "load_profile",
           "output_units", "parse_profile", "IdentificationResult", "Run", "read_run", "read_runs",
           "output_sensitivities", "delay_inputs", "discretize", "perturbed_model", "simulate", "simulate_run"]

# data processing and equation-error estimators (plots stay in identify.estimators.plots: matplotlib is slow to import)
from .data.matfile import read_mat  # noqa: E402
from .data.preprocess import add_derivatives, cg_correction, processing_steps, replay, smooth, smooth_derivative  # noqa: E402
from .estimators.equation_error import IV, LS, state_derivatives  # noqa: E402

__all__ += ["IV", "LS", "state_derivatives", "read_mat", "add_derivatives", "cg_correction",
            "processing_steps", "replay", "smooth", "smooth_derivative"]

# output-error maximum likelihood
from .estimators.ml import ML  # noqa: E402

__all__ += ["ML"]

# frequency-domain equation error, batch and recursive (the cockpit's live estimate)
from .estimators.frequency_ee import FDEE, RecursiveFDEE  # noqa: E402

__all__ += ["FDEE", "RecursiveFDEE"]

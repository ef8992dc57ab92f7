"""identify: models, runs, simulation and estimation (after the flight). The base layer.

Typical use::

    from identify import load_profile, LinearModel, read_run
    model = LinearModel(load_profile("s61_hover_8state"))
"""
from .errors import ConvergenceWarning, EstimationError, ProfileError, PseudostepError, RunError, SimulationError
from .model import LinearModel, Mode, format_modes, modes_of, residualize
from .profile import Profile, load_profile, parse_profile
from .result import IdentificationResult
from .runs import Run, read_run, read_runs
from .sensitivity import output_sensitivities
from .simulate import discretize, simulate, simulate_run

__all__ = ["ConvergenceWarning", "EstimationError", "ProfileError", "PseudostepError", "RunError", "SimulationError",
           "LinearModel", "Mode", "format_modes", "modes_of", "residualize", "Profile", "load_profile",
           "parse_profile", "IdentificationResult", "Run", "read_run", "read_runs",
           "output_sensitivities", "discretize", "simulate", "simulate_run"]

# data processing and equation-error estimators (plots stay in identify.plots: matplotlib is slow to import)
from .equation_error import IV, LS, state_derivatives  # noqa: E402
from .matfile import read_mat  # noqa: E402
from .preprocess import add_derivatives, cg_correction, processing_steps, replay, smooth, smooth_derivative  # noqa: E402

__all__ += ["IV", "LS", "state_derivatives", "read_mat", "add_derivatives", "cg_correction",
            "processing_steps", "replay", "smooth", "smooth_derivative"]

# output-error maximum likelihood
from .ml import ML  # noqa: E402

__all__ += ["ML"]

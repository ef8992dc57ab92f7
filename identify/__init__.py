"""identify: models, runs, simulation and estimation (after the flight). The base layer.

Typical use::

    from identify import load_profile, LinearModel, read_run
    model = LinearModel(load_profile("s61_hover_8state"))
"""
from .errors import EstimationError, ProfileError, PseudostepError, RunError, SimulationError
from .model import LinearModel, Mode, format_modes, modes_of, residualize
from .profile import Profile, load_profile, parse_profile
from .result import IdentificationResult
from .runs import Run, read_run, read_runs
from .sensitivity import output_sensitivities
from .simulate import discretize, simulate, simulate_run

__all__ = ["EstimationError", "ProfileError", "PseudostepError", "RunError", "SimulationError",
           "LinearModel", "Mode", "format_modes", "modes_of", "residualize", "Profile", "load_profile",
           "parse_profile", "IdentificationResult", "Run", "read_run", "read_runs",
           "output_sensitivities", "discretize", "simulate", "simulate_run"]

"""The model wing: profiles (a priori models), the linear model and its modes, simulation, sensitivities."""
from .linear import LinearModel, Mode, format_modes, modes_of, residualize

__all__ = ["LinearModel", "Mode", "format_modes", "modes_of", "residualize"]

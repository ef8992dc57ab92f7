"""The filter-error family's conventions and its seam for the process-noise model.

:class:`ProcessNoiseModel` says what the filter's process noise is: which states of the profile
the filter runs on carry white process noise (F), and that profile itself. The white model on the
listed equations (``[process_noise]``, the ``process_noise`` option) runs on the user's profile.
A profile's ``[turbulence]`` (gust states augmenting the profile, the derivatives on the velocities
acting on the air-relative velocity, process noise on the gust states:
:mod:`identify.model.turbulence`) is fitted by :mod:`.turbulence`: FEM on the augmented profile,
whose process noise is this white model on the gust states, the result handed back on the user's
profile.
"""
from __future__ import annotations

PROCESS_NOISE_CONVENTION = ("F in dx/dt = A x + B u + F w, w unit white noise (power spectral density 1); "
                            "F diagonal on the listed states, in the state-derivative unit times sqrt(s)")
R_FLOOR = 1e-6  # smallest measurement variance, relative to the output's mean square innovation
F_START = 0.3  # default start of F_i: this share of the state's measured rms times sqrt(2 / 1 s)
F_ZERO = 1e-3  # an F below this share of its start value is at the boundary F = 0: held there


class ProcessNoiseModel:
    """White process noise on listed states of the profile: ``states`` ``{state: F start or None}``
    (None: from the state's measured rms, :data:`F_START`); ``source`` where the list came from
    (``"[process_noise]"``, ``"option"``, ``"default"``: the velocity states)."""

    kind = "equations"

    def __init__(self, states: dict, source: str):
        self.states, self.source = dict(states), source

    def filter_profile(self, profile):
        """The profile the filter runs on (this model: the user's own)."""
        return profile

    def describe(self, fitted: dict | None = None) -> str:
        """One line: which process-noise model is fitted (``fitted``: {state: F} after the fit)."""
        if not self.states:
            return "process noise: none (output error)"
        names = ", ".join(self.states if fitted is None else
                          (f"{s} (F {v:.3g})" if v else f"{s} (F at 0)" for s, v in fitted.items()))
        return f"process noise: white, on the equations of {names} ({self.source})"

"""The aircraft's response to the flown stick: a profile's model simulated, or an external function.

Every simulated response in cueing goes through :func:`simulate_profile` (identify's exact
zero-order-hold simulation): the live source frame by frame (:class:`SimulatedAircraft`) and the
test point after the flight (:func:`simulate_test_point`). Honouring a profile's declared delays
and pseudo-inputs is a change to that one function; the live source hands it one frame interval
from its current state, so a declared delay will also need it to hand over the inputs of the last
delay's worth of frames.
"""
from __future__ import annotations

import importlib

import numpy as np

from identify import LinearModel, Profile, Run, load_profile, simulate_run

from .errors import CueingError
from .flightlog import CMD


def aircraft_model(profile) -> LinearModel:
    """The simulated aircraft: a LinearModel, a Profile or a profile's name or path."""
    if isinstance(profile, LinearModel):
        return profile
    return LinearModel(profile if isinstance(profile, Profile) else load_profile(profile))


def simulate_profile(model: LinearModel, time: np.ndarray, u: np.ndarray, x0=None, **options) -> Run:
    """``model`` driven by ``u`` (N, m; held over each interval) on ``time`` (N,, s) from the state
    ``x0`` (n,; zeros by default) at ``time[0]``: a run with the inputs and every state and output.
    ``options`` go to :func:`identify.simulate_run` (``noise_fraction``, ``seed``, ``meta`` ...)."""
    return simulate_run(model, time, u, x0, **options)


def _columns(model: LinearModel, inputs: list[str]) -> list[int]:
    p = model.profile
    unknown = [i for i in inputs if i not in p.input_names]
    if unknown:
        raise CueingError(f"profile '{p.name}' has no input {', '.join(unknown)} "
                          f"(its inputs: {', '.join(p.input_names)})")
    return [p.input_names.index(i) for i in inputs]


class SimulatedAircraft:
    """A profile's model flown frame by frame: the input held from one frame to the next (as the
    run file records it), the states measured with white noise of ``noise_fraction`` times each
    state's standard deviation in the response to the commanded signals flown exactly."""

    def __init__(self, model: LinearModel, signals, rate: float, noise_fraction: float = 0.02,
                 seed: int | None = None):
        self.model = model
        self.inputs = [s.input for s in signals]
        self.columns = _columns(model, self.inputs)
        self.noise = noise_fraction * self._response_scale(signals, rate)
        self.rng = np.random.default_rng(seed)
        self.x = np.zeros(model.n_states)
        self.last: tuple[float, np.ndarray] | None = None  # (t, u (m,)) of the previous frame

    def _u(self, flown) -> np.ndarray:
        u = np.zeros(self.model.n_inputs)
        u[self.columns] = flown
        return u

    def _response_scale(self, signals, rate: float) -> np.ndarray:
        t = np.arange(0, max(s.end_time for s in signals) + 1.0, 1 / rate)
        u = np.zeros((len(t), self.model.n_inputs))
        for s, c in zip(signals, self.columns):
            u[:, c] = s(t)
        run = simulate_profile(self.model, t, u, derivatives=False)
        return np.array([run[s].std() for s in self.model.profile.state_names])

    def describe(self) -> str:
        return f"simulation of '{self.model.profile.name}'"

    def read(self, t: float, flown) -> np.ndarray:
        """Measured states (n,) at time t, the stick ``flown`` (n_axes,) being held from now on."""
        u = self._u(flown)
        if self.last is not None and t > self.last[0]:
            held = np.vstack([self.last[1], self.last[1]])
            run = simulate_profile(self.model, np.array([self.last[0], t]), held, self.x, derivatives=False)
            self.x = np.array([run[s][-1] for s in self.model.profile.state_names])
        self.last = (t, u)
        return self.x + self.noise * self.rng.standard_normal(self.x.size)


class ExternalResponse:
    """A function ``f(t, flown) -> states`` (n,), e.g. a flight simulator's measured response."""

    def __init__(self, spec: str):
        spec = spec.removeprefix("external:")
        module, _, name = spec.rpartition(":")
        try:
            self.func = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError, ValueError) as exc:
            raise CueingError(f"--live-response '{spec}': {exc}") from None
        self.spec = spec

    def describe(self) -> str:
        return f"external ({self.spec})"

    def read(self, t: float, flown) -> np.ndarray:
        try:
            return np.asarray(self.func(t, np.asarray(flown)), dtype=float)
        except Exception as exc:  # a simulator's failure ends the run with one line, not a traceback
            raise CueingError(f"--live-response '{self.spec}' at t = {t:.3f} s: {exc}") from None


def simulate_test_point(run: Run, profile, noise_fraction: float = 0.02, seed: int | None = None) -> Run:
    """Drive ``profile``'s model with the run's flown inputs; add every response channel.

    Profile inputs the run does not hold are zero (the pilot held them still).
    """
    model = aircraft_model(profile)
    p = model.profile
    _columns(model, [c for c in run.channels if c + CMD in run.channels])
    u = np.column_stack([run.channels.get(name, np.zeros(len(run))) for name in p.input_names])
    sim = simulate_profile(model, run.time, u, noise_fraction=noise_fraction, seed=seed,
                           meta={**run.meta, "source_of_response": "simulation"})
    extra = {c: v for c, v in run.channels.items() if c not in sim.channels}
    return Run(sim.time, {**sim.channels, **extra}, {**run.meta, **sim.meta,
                                                   "simulated_profile": p.name}, source=run.source)

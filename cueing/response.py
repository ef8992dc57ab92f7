"""The aircraft's response to the flown stick: a profile's model simulated, or an external function.

The simulated aircraft is the model, with every effect its profile declares (``[meta]``): input
delays (the aircraft sees ``u(t - tau)``; zero, the trim value, before the record) and
pseudo-inputs (constants, time, products of inputs and of states -- the latter fed back from the
simulated states, as refine's output-error fits compute them -- and sinusoids, at phase zero from
the record's start: a simulation has no measured vibration to take a phase from). The test point
after the flight (:func:`simulate_test_point`, through :func:`simulate_profile`) and the live
source frame by frame (:class:`SimulatedAircraft`) step the same exact zero-order hold. The
recorded inputs are the flown ones, undelayed; pseudo-inputs are not recorded (every command
rebuilds them from the profile).
"""
from __future__ import annotations

import importlib

import numpy as np

from identify import LinearModel, Profile, Run, delay_inputs, discretize, load_profile, simulate_run
from identify.model import pseudo_inputs as pi

from .errors import CueingError
from .flightlog import CMD


def aircraft_model(profile) -> LinearModel:
    """The simulated aircraft: a LinearModel, a Profile or a profile's name or path."""
    if isinstance(profile, LinearModel):
        return profile
    return LinearModel(profile if isinstance(profile, Profile) else load_profile(profile))


def declared_delays(profile: Profile) -> dict[str, float]:
    return {k: float(v) for k, v in dict(profile.meta.get("delays", {})).items()}


def _product(spec: dict, value) -> float:
    """A product pseudo-input from ``value(channel)``."""
    out = 1.0
    for f, a in zip(spec["product"], spec.get("abs", [False] * len(spec["product"]))):
        v = value(f)
        out *= abs(v) if a else v
    return out


def _pseudo(name: str, spec: dict, t: float, value) -> float:
    """One pseudo-input at ``t`` s from the record's start; ``value(channel)`` reads inputs and states."""
    if "constant" in spec:
        return float(spec["constant"])
    if "time" in spec:
        return t
    if "product" in spec:
        return _product(spec, value)
    if "sinusoid" in spec:
        w = 2 * np.pi * float(spec["frequency"])
        return float(np.sin(w * t) if spec.get("quadrature") else np.cos(w * t))
    raise CueingError(f"pseudo-input '{name}': unknown description {spec}")


def simulate_profile(model: LinearModel, time: np.ndarray, u: np.ndarray, x0=None, **options) -> Run:
    """``model`` driven by ``u`` (N, m; held over each interval; pseudo-input columns ignored) on
    ``time`` (N,, s) from the state ``x0`` (n,; zeros by default) at ``time[0]``, with the
    profile's declared delays and pseudo-inputs: a run with the flown inputs and every state and
    output. ``options`` go to :func:`identify.simulate_run` (``noise_fraction``, ``seed``, ``meta`` ...)."""
    p = model.profile
    specs = pi.specs(p)
    delays = declared_delays(p)
    if not specs:
        return simulate_run(model, time, u, x0, input_delay=delays, **options)
    # the aircraft's inputs: delayed flown inputs, then every pseudo-input (state products fed
    # back sample by sample through the same zero-order hold simulate_run steps)
    u = np.array(u, dtype=float)
    seen = u.copy()
    for name, tau in delays.items():
        j = p.input_names.index(name)
        seen[:, j] = delay_inputs(time, u[:, j], tau, before=0.0)
    col = {n: p.input_names.index(n) for n in specs}
    states = {s: i for i, s in enumerate(p.state_names)}
    x = np.zeros(model.n_states) if x0 is None else np.array(x0, float)
    Phi, Gamma = discretize(model.A, model.B, float(time[1] - time[0]))
    inputs = {n: i for i, n in enumerate(p.input_names)}
    for k in range(len(time)):
        value = lambda f: x[states[f]] if f in states else seen[k, inputs[f]]  # noqa: E731
        for n, spec in specs.items():
            seen[k, col[n]] = _pseudo(n, spec, float(time[k] - time[0]), value)
        x = Phi @ x + Gamma @ seen[k]
    run = simulate_run(model, time, seen, x0, **options)
    flown = {n: u[:, j] for j, n in enumerate(p.input_names) if n not in specs}
    channels = {k: v for k, v in run.channels.items() if k not in specs}
    meta = {**run.meta, "declared_effects": f"delays {delays or 'none'}; pseudo-inputs {', '.join(specs)}"}
    return Run(run.time, {**channels, **flown}, meta, run.source)


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
        p = model.profile
        self.delays = np.array([declared_delays(p).get(n, 0.0) for n in p.input_names])
        self.specs = pi.specs(p)
        self.frames: list[tuple[float, np.ndarray]] = []  # (t, u) flown, as long as the longest delay needs
        self.t0: float | None = None
        self._steps: dict[float, tuple[np.ndarray, np.ndarray]] = {}

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
        if self.t0 is None:
            self.t0 = t
        if self.last is not None and t > self.last[0]:
            self._advance(self.last[0], t)
        self.last = (t, u)
        self.frames.append((t, u))
        keep = t - self.delays.max() - 1.0  # older frames no delayed input reaches any more
        while len(self.frames) > 2 and self.frames[1][0] < keep:
            self.frames.pop(0)
        return self.x + self.noise * self.rng.standard_normal(self.x.size)

    def _seen(self, s: float) -> np.ndarray:
        """The inputs the aircraft sees at time ``s``: each flown input its delay earlier (zero, the
        trim value, before the first frame), then the pseudo-inputs."""
        seen = np.zeros(self.model.n_inputs)
        times = np.array([f[0] for f in self.frames])
        for j, tau in enumerate(self.delays):
            k = np.searchsorted(times, s - tau + 1e-12, side="right") - 1
            seen[j] = self.frames[k][1][j] if k >= 0 else 0.0
        p = self.model.profile
        states = {n: i for i, n in enumerate(p.state_names)}
        inputs = {n: i for i, n in enumerate(p.input_names)}
        value = lambda f: self.x[states[f]] if f in states else seen[inputs[f]]  # noqa: E731
        for n, spec in self.specs.items():
            seen[inputs[n]] = _pseudo(n, spec, s - self.t0, value)
        return seen

    def _advance(self, a: float, b: float) -> None:
        """Step the state from ``a`` to ``b`` s exactly, the inputs held between the instants where
        a delayed input changes."""
        times = np.array([f[0] for f in self.frames])
        cuts = sorted({a, b} | {float(tk + tau) for tau in set(self.delays) for tk in times if a < tk + tau < b})
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            Phi, Gamma = self._step(hi - lo)
            self.x = Phi @ self.x + Gamma @ self._seen(lo)

    def _step(self, h: float) -> tuple[np.ndarray, np.ndarray]:
        key = round(h, 9)  # frame intervals repeat: discretise each once
        if key not in self._steps:
            if len(self._steps) > 512:
                self._steps.clear()
            self._steps[key] = discretize(self.model.A, self.model.B, h)
        return self._steps[key]


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

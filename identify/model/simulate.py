"""Exact zero-order-hold simulation of linear models, and simulated runs from a known truth.

A truth may differ from the a priori model the way a real aircraft does: derivatives off their a
priori values (:func:`perturbed_model`) and a control-system delay on the inputs
(:func:`delay_inputs`, ``simulate_run(..., input_delay=)``).

Inputs are held constant over each sample interval (ZOH), which is how step signals are flown and
how sampled data are commonly treated; discretisation uses the matrix exponential of the augmented
matrix ``[[A, B], [0, 0]] dt`` (scipy.linalg.expm), so the discrete model is exact, not an
integration scheme with step-size error.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from ..data.runs import Run
from ..errors import SimulationError
from .linear import LinearModel
from .profile import DOT

DIVERGENCE_LIMIT = 1e6


def discretize(A: np.ndarray, B: np.ndarray, dt: float, hold: str = "held") -> tuple[np.ndarray, np.ndarray]:
    """ZOH discretisation: returns ``Phi`` (n, n) and ``Gamma`` (n, m). ``hold="linear"`` (inputs
    interpolated linearly between samples, first-order hold): ``Gamma`` (n, 2m) acts on
    ``[u[k]; u[k+1]]`` (:func:`held_inputs`)."""
    n, m = B.shape
    if hold == "linear":
        M = np.zeros((n + 2 * m, n + 2 * m))
        M[:n, :n], M[:n, n:n + m], M[n:n + m, n + m:] = A, B, np.eye(m) / dt
        E = expm(M * dt)  # x[k+1] = Phi x + Ga u[k] + Gb (u[k+1] - u[k])
        return E[:n, :n], np.hstack([E[:n, n:n + m] - E[:n, n + m:], E[:n, n + m:]])
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    return E[:n, :n], E[:n, n:]


def held_inputs(u: np.ndarray, hold: str = "held") -> np.ndarray:
    """What ``Gamma`` of :func:`discretize` acts on: ``u`` (N, m) itself (held), or ``[u[k];
    u[k+1]]`` (N, 2m) (linear; the last sample held)."""
    if hold != "linear":
        return u
    return np.concatenate([u, np.concatenate([u[1:], u[-1:]])], axis=1)


def propagate(Phi: np.ndarray, forcing: np.ndarray, z0: np.ndarray) -> np.ndarray:
    """Solve ``z[k+1] = Phi z[k] + forcing[k]`` for k = 0..N-2.

    ``forcing`` has shape (N, n, ...) (trailing axes are independent columns propagated together,
    e.g. one per parameter sensitivity); ``z0`` has shape (n, ...). Returns z of shape (N, n, ...).
    The recursion is sequential in time, so it runs as one matrix product per sample over all
    columns at once.
    """
    z = np.empty(forcing.shape)
    z[0] = z0
    for k in range(forcing.shape[0] - 1):
        z[k + 1] = Phi @ z[k] + forcing[k]
    return z


def check_divergence(x: np.ndarray, dt: float, names: list[str], limit: float = DIVERGENCE_LIMIT) -> None:
    """Raise SimulationError naming the state and time where ``|x|`` first exceeds ``limit``."""
    bad = ~np.isfinite(x) | (np.abs(x) > limit)
    if bad.any():
        k, j = np.argwhere(bad)[0][:2]
        raise SimulationError(
            f"simulation diverged: state '{names[j]}' exceeds {limit:g} at t = {k * dt:.3f} s "
            f"(unstable model over a long record: use a stabilised estimator or shorter runs)")


def delay_inputs(time: np.ndarray, u: np.ndarray, delay: float, before: float | None = None) -> np.ndarray:
    """``u(t - delay)`` on the samples ``time`` (N,); ``u`` (N,) or (N, m), ``delay`` in s (>= 0).

    A delay of a whole number of samples (uniform ``time``) shifts exactly; any other delay
    interpolates linearly. Before the record the input is ``before`` (default: its first sample
    held; a simulated perturbation from trim uses 0, the trim value)."""
    u = np.asarray(u, dtype=float)
    if delay == 0:
        return u.copy()
    dt = (time[-1] - time[0]) / (len(time) - 1)
    shift = int(round(delay / dt))
    uniform = np.allclose(np.diff(time), dt, rtol=1e-9, atol=0.0)
    fill = u[:1] if before is None else np.full_like(u[:1], before)
    if uniform and shift >= 1 and abs(shift * dt - delay) <= 1e-6 * delay:
        return np.concatenate([np.repeat(fill, min(shift, len(u)), axis=0), u[:-shift]])[:len(u)]
    columns = u.reshape(len(u), -1)
    out = np.column_stack([np.interp(time - delay, time, c, left=f) for c, f in zip(columns.T, fill.reshape(-1))])
    return out.reshape(u.shape)


def perturbed_model(model: LinearModel, spread: float, rng: np.random.Generator) -> LinearModel:
    """``model`` with every free derivative scaled by its own factor drawn uniformly from
    1 -/+ ``spread`` (a real aircraft off its a priori model)."""
    return model.with_theta(model.theta * rng.uniform(1 - spread, 1 + spread, model.theta.size))


@dataclass
class Simulation:
    """Result of :func:`simulate`: ``x`` (N, n), ``xdot`` (N, n), ``y`` (N, ny)."""

    x: np.ndarray
    xdot: np.ndarray
    y: np.ndarray


def simulate(model: LinearModel, u: np.ndarray, dt: float, x0=None, w: np.ndarray | None = None,
             limit: float = DIVERGENCE_LIMIT, hold: str = "held") -> Simulation:
    """Simulate ``dx/dt = A x + B u + w``, ``y = C x + D u`` with w held over each interval and u
    held (``hold="held"``) or interpolated linearly between samples (``"linear"``).

    ``u``: (N, m) inputs; ``w``: optional (N, n) process disturbance (state-derivative units);
    ``x0``: (n,) initial state (zeros by default).
    """
    u = np.asarray(u, dtype=float).reshape(len(u), model.n_inputs)
    n = model.n_states
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    A, B = model.A, model.B
    Phi, Gamma = discretize(A, B, dt, hold)
    forcing = held_inputs(u, hold) @ Gamma.T
    if w is not None:
        forcing = forcing + w @ discretize(A, np.eye(n), dt)[1].T
    x = propagate(Phi, forcing, x0)
    check_divergence(x, dt, model.profile.state_names, limit)
    xdot = x @ A.T + u @ B.T + (0 if w is None else w)
    y = x @ model.C.T + u @ model.D.T
    return Simulation(x, xdot, y)


def simulate_run(model: LinearModel, time: np.ndarray, u: np.ndarray, x0=None, *,
                 noise: dict[str, float] | None = None, noise_fraction: float = 0.0,
                 bias: dict[str, float] | None = None, process_noise: float | np.ndarray = 0.0,
                 seed: int | None = None, meta: dict | None = None, derivatives: bool = True,
                 input_delay: float | dict[str, float] = 0.0, hold: str = "held") -> Run:
    """A run simulated from a known truth, with optional measurement errors.

    The run holds the inputs, every state, every state derivative (``<state>_dot``; leave them out
    with ``derivatives=False`` to imitate a flight without such sensors, so that equation error
    differentiates the rates) and every defined output. ``noise`` gives absolute white-noise standard deviations per channel;
    ``noise_fraction`` adds noise of that fraction of each non-input channel's standard deviation;
    ``bias`` adds constant offsets; ``process_noise`` is the standard deviation (scalar or per
    state) of a white disturbance on the state derivatives. Inputs stay exact unless named in
    ``noise`` or ``bias``. ``input_delay`` (s, one for every input or ``{input: s}``) is a
    control-system delay: the run records the inputs as given, the aircraft responds to them that
    much later (zero, the trim value, before the record). ``hold``: the inputs between samples,
    ``"held"`` (a stepped command) or ``"linear"`` (a measured surface position).
    """
    p = model.profile
    time = np.asarray(time, dtype=float)
    dt = float((time[-1] - time[0]) / (len(time) - 1))
    rng = np.random.default_rng(seed)
    u = np.asarray(u, dtype=float).reshape(len(time), model.n_inputs)
    w = None
    if np.any(np.asarray(process_noise) > 0):
        w = rng.standard_normal((len(time), model.n_states)) * np.asarray(process_noise, dtype=float)
    delays = input_delay if isinstance(input_delay, dict) else dict.fromkeys(p.input_names, input_delay)
    unknown = set(delays) - set(p.input_names)
    if unknown:
        raise SimulationError(f"input_delay names no input of '{p.name}': {', '.join(sorted(unknown))}")
    if any(not (d >= 0) for d in delays.values()):
        raise SimulationError(f"input_delay must not be negative, got {input_delay}")
    felt = np.column_stack([delay_inputs(time, u[:, j], float(delays.get(name, 0.0)), before=0.0)
                            for j, name in enumerate(p.input_names)]) if any(delays.values()) else u
    sim = simulate(model, felt, dt, x0, w, hold=hold)
    channels = {name: u[:, j] for j, name in enumerate(p.input_names)}
    channels.update({s: sim.x[:, j] for j, s in enumerate(p.state_names)})
    if derivatives:
        channels.update({s + DOT: sim.xdot[:, j] for j, s in enumerate(p.state_names)})
    channels.update({y: sim.y[:, j] for j, y in enumerate(p.outputs)})
    inputs = set(p.input_names)
    for name in list(channels):
        std = (noise or {}).get(name, 0.0)
        if noise_fraction and name not in inputs:
            std = np.hypot(std, noise_fraction * np.std(channels[name]))
        offset = (bias or {}).get(name, 0.0)
        if std or offset:
            channels[name] = channels[name] + offset + std * rng.standard_normal(len(time))
    info = {"profile": p.name, "source": "simulation", "sample_rate": f"{1 / dt:g} Hz",
            "noise_fraction": noise_fraction, "process_noise": process_noise, "seed": seed}
    if noise:
        info["noise"] = noise
    if bias:
        info["bias"] = bias
    if any(delays.values()):
        info["input_delay"] = {k: v for k, v in delays.items() if v}
    info.update(meta or {})
    return Run(time, channels, {k: str(v) for k, v in info.items()}, source=f"<simulated {p.name}>")

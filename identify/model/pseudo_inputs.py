"""Pseudo-inputs: input channels a profile computes from a run's own channels, and input delays.

A refined model (``identify refine``'s ``final_profile.toml``) has inputs no sensor records: a
constant for a bias, the time for a drift, products of measured channels for nonlinear terms,
sinusoids for a vibration; and inputs the aircraft sees late. The profile says how to rebuild each
one in its ``meta`` table, so the model can be used on plain measured runs by every command::

    [meta]
    delays = { theta_s = 0.08 }                         # s: the input u(t - tau)
    [meta.pseudo_inputs]
    one = { constant = 1.0 }
    t = { time = 1 }                                    # s from the run's start
    q_absq = { product = ["q", "q"], abs = [false, true] }   # q |q|
    alpha_k1 = { spline = "alpha", knot = 0.21 }        # max(alpha - 0.21, 0): a slope change
    cos_q = { sinusoid = "q", frequency = 4.0 }         # cos(2 pi f t + phi_r)
    sin_q = { sinusoid = "q", frequency = 4.0, quadrature = true }

``phi_r`` is the phase of the measured output (``sinusoid``) at ``frequency`` in run ``r`` (a
vibration's phase differs from run to run). :func:`prepare` applies the delays and adds every
missing pseudo-input channel; the estimators call it on every run they are given, as refine does.
The description is the profile's: no channel name is ever parsed.
"""
from __future__ import annotations

import json

import numpy as np

from ..data.runs import Run
from ..errors import ProfileError
from .profile import Profile
from .simulate import delay_inputs

APPLIED = "delays_applied"  # run metadata: the input delays (s) already applied, as JSON


def constant(value: float = 1.0) -> dict:
    return {"constant": float(value)}


def time() -> dict:
    return {"time": 1}


def product(factors, absolute=None) -> dict:
    """The product of channels ``factors``, each in absolute value where ``absolute`` says so."""
    factors = list(factors)
    return {"product": factors, "abs": [bool(a) for a in (absolute or [False] * len(factors))]}


def spline(factor: str, knot: float) -> dict:
    """The linear spline term ``max(x - knot, 0)`` of channel ``factor``: a slope that changes at
    ``knot`` (a lift curve's break near stall), computed from the measured channel."""
    return {"spline": factor, "knot": float(knot)}


def sinusoid(output: str, frequency: float, quadrature: bool = False) -> dict:
    return {"sinusoid": output, "frequency": float(frequency), "quadrature": bool(quadrature)}


def specs(profile: Profile) -> dict[str, dict]:
    """``{pseudo-input name: spec}`` of a profile (empty for a plain one)."""
    table = profile.meta.get("pseudo_inputs", {})
    if not isinstance(table, dict):
        raise ProfileError(f"{profile.source}: meta.pseudo_inputs must be a table of "
                           f"{{name = {{constant|time|product|sinusoid = ...}}}} (a list of names, written "
                           f"by refine before its pseudo-inputs described themselves, cannot be rebuilt: "
                           f"re-run refine)")
    return dict(table)


def channel(name: str, spec: dict, run: Run) -> np.ndarray:
    """The (N,) channel of one pseudo-input ``spec`` on ``run``."""
    t = run.time - run.time[0]
    if "constant" in spec:
        return np.full(len(run), float(spec["constant"]))
    if "time" in spec:
        return t
    if "product" in spec:
        out = np.ones(len(run))
        for f, a in zip(spec["product"], spec.get("abs", [False] * len(spec["product"]))):
            out = out * (np.abs(run[f]) if a else run[f])
        return out
    if "spline" in spec:
        return np.maximum(run[spec["spline"]] - float(spec["knot"]), 0.0)
    if "sinusoid" in spec:
        w = 2 * np.pi * float(spec["frequency"])
        phase = _phase(run[spec["sinusoid"]], t, w)
        return np.sin(w * t + phase) if spec.get("quadrature") else np.cos(w * t + phase)
    raise ProfileError(f"pseudo-input '{name}': unknown description {spec} (constant, time, product, spline or sinusoid)")


def _phase(z: np.ndarray, t: np.ndarray, w: float) -> float:
    """Phase (rad) of the measured signal at angular frequency ``w``, mean and trend removed."""
    X = np.column_stack([np.ones_like(t), t])
    z = z - X @ np.linalg.lstsq(X, z, rcond=None)[0]
    return float(np.angle(np.sum(z * np.exp(-1j * w * t))))


def delay_run(run: Run, input_name: str, tau: float) -> Run:
    """``run`` with ``input_name`` replaced by u(t - tau) (the first value held before the start;
    :func:`identify.model.simulate.delay_inputs`)."""
    return run.with_channels({input_name: delay_inputs(run.time, run[input_name], tau)})


def prepare(profile: Profile, runs: list[Run]) -> list[Run]:
    """Runs as the profile needs them: inputs delayed by ``meta.delays`` and every pseudo-input of
    ``meta.pseudo_inputs`` the run does not hold computed from its channels."""
    table = specs(profile)
    delays = {k: float(v) for k, v in dict(profile.meta.get("delays", {})).items()}
    out = []
    for run in runs:
        # idempotent: a run records the delays already applied to it (refine prepares runs, then
        # hands them to an estimator, which prepares what it is given)
        applied = json.loads(run.meta.get(APPLIED, "{}"))
        if delays and applied != delays:
            for name, tau in delays.items():
                if tau != applied.get(name, 0.0):
                    run = delay_run(run, name, tau - applied.get(name, 0.0))
            run = run.with_channels({}, **{APPLIED: json.dumps({**applied, **delays})})
        extra = {name: channel(name, spec, run) for name, spec in table.items() if name not in run.channels}
        out.append(run.with_channels(extra) if extra else run)
    return out


__all__ = ["constant", "time", "product", "spline", "sinusoid", "specs", "channel", "delay_run", "prepare"]

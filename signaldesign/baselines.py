"""Baseline input signals: doublets, multisteps (3211 ...), arbitrary step sequences,
multisines (phases optimised for a small relative peak factor, or Schroeder's; orthogonal across
axes) and pseudo-random ternary sequences (PRTS).

Every function returns a :class:`~signaldesign.signal.Signal` (or a list of them, one per axis):
levels held for a constant time step ``dt`` times an ``amplitude`` in control units (rad).
"""
from __future__ import annotations

import itertools

import numpy as np

from .phases import PHASES, optimised_phases, relative_peak_factor, schroeder_phases
from .signal import Signal, SignalError


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise SignalError(f"{name} must be positive, got {value:g}")
    return value


def step_sequence(levels, width: float, amplitude: float = 1.0, input: str = "theta_s",
                  delay: float = 0.0, kind: str = "steps") -> Signal:
    """An arbitrary step sequence: ``levels`` (K,) each held ``width`` s."""
    width = _positive("step width", width)
    return Signal(kind, input, width, np.asarray(levels, float), amplitude, delay, {"width": width})


def multistep(pulses, width: float, amplitude: float = 1.0, input: str = "theta_s",
              delay: float = 0.0, first: int = 1) -> Signal:
    """Alternating-sign multistep given as pulse lengths in units of ``width`` s.

    ``pulses=(3, 2, 1, 1)`` is the 3211, ``(1, 1)`` the doublet; the first pulse has sign ``first``.
    """
    pulses = [int(n) for n in pulses]
    if not pulses or min(pulses) < 1:
        raise SignalError(f"multistep pulse counts must be positive integers, got {pulses}")
    width = _positive("pulse width", width)
    levels = np.concatenate([np.full(n, first * (-1) ** i) for i, n in enumerate(pulses)])
    name = "".join(map(str, pulses)) if max(pulses) < 10 else "-".join(map(str, pulses))
    return Signal(f"multistep {name}", input, width, levels, amplitude, delay,
                  {"pulses": pulses, "width": width})


def doublet(width: float, amplitude: float = 1.0, input: str = "theta_s", delay: float = 0.0) -> Signal:
    """Doublet: +1 for ``width`` s, then -1 for ``width`` s (total 2 ``width``)."""
    s = multistep((1, 1), width, amplitude, input, delay)
    s.kind = "doublet"
    return s


def m3211(width: float, amplitude: float = 1.0, input: str = "theta_s", delay: float = 0.0) -> Signal:
    """The 3211: pulses of 3, 2, 1 and 1 ``width`` s with alternating signs (total 7 ``width``)."""
    s = multistep((3, 2, 1, 1), width, amplitude, input, delay)
    s.kind = "3211"
    return s


def multisine(duration: float, band: tuple[float, float], amplitude: float = 1.0, input: str = "theta_s",
              dt: float = 0.05, harmonics=None, delay: float = 0.0, phases: str = "optimised") -> Signal:
    """Multisine of equal-power harmonics of 2 pi / ``duration`` inside ``band`` (rad/s), with
    ``phases`` ``optimised`` (default: Schroeder's, then optimised for a small relative peak factor,
    :mod:`signaldesign.phases`) or ``schroeder``.

    Levels are sampled every ``dt`` s and scaled so that the peak level is 1 (``amplitude`` is the
    peak control deflection, as for the step signals). ``harmonics`` picks the harmonic numbers
    explicitly (used by :func:`orthogonal_multisines`). ``params['relative_peak_factor']`` is the
    flown samples' (max - min) / (2 sqrt(2) rms).
    """
    duration, dt = _positive("duration", duration), _positive("time step", dt)
    if phases not in PHASES:
        raise SignalError(f"multisine phases '{phases}': expected one of {', '.join(PHASES)}")
    w0 = 2 * np.pi / duration
    if harmonics is None:
        lo, hi = band
        harmonics = np.arange(max(1, int(np.ceil(lo / w0 - 1e-9))), int(np.floor(hi / w0 + 1e-9)) + 1)
    harmonics = np.asarray(harmonics, int)
    if harmonics.size == 0:
        raise SignalError(f"multisine: no harmonic of {w0:.3f} rad/s (duration {duration:g} s) lies in "
                          f"the band {band[0]:.3f}..{band[1]:.3f} rad/s; lengthen the signal")
    n_steps = int(round(duration / dt))
    if 2 * harmonics.max() >= n_steps:
        raise SignalError(f"multisine: harmonic {harmonics.max() * w0:.3f} rad/s is at or above the "
                          f"{np.pi / dt:.3f} rad/s Nyquist frequency of the {dt:g} s time step; shorten --dt")
    t = (np.arange(n_steps) + 0.5) * dt
    phi = optimised_phases(harmonics, t, w0) if phases == "optimised" else schroeder_phases(harmonics.size)
    levels = np.sin(np.outer(t, harmonics * w0) + phi).sum(axis=1)
    levels /= np.abs(levels).max()
    return Signal("multisine", input, dt, levels, amplitude, delay,
                  {"harmonics": harmonics.tolist(), "base_frequency": w0, "band": list(map(float, band)),
                   "phases": phases, "relative_peak_factor": relative_peak_factor(levels)})


def orthogonal_multisines(inputs, duration: float, band, amplitude=1.0, dt: float = 0.05,
                          phases: str = "optimised", delay: float = 0.0) -> list[Signal]:
    """Multisines on several axes at once with interleaved (disjoint) harmonics: input i of n takes
    harmonics i, i + n, i + 2n, ... of the band, so the axes are mutually orthogonal over
    ``duration`` and each axis' response is separable in the data; each axis' phases as
    :func:`multisine`'s ``phases``."""
    w0 = 2 * np.pi / duration
    all_h = np.arange(max(1, int(np.ceil(band[0] / w0 - 1e-9))), int(np.floor(band[1] / w0 + 1e-9)) + 1)
    if all_h.size < len(inputs):
        raise SignalError(f"orthogonal multisines: only {all_h.size} harmonic(s) in the band for "
                          f"{len(inputs)} axes; lengthen the signal or widen the band")
    amps = np.broadcast_to(np.asarray(amplitude, float), (len(inputs),))
    return [multisine(duration, band, a, name, dt, all_h[i::len(inputs)], delay, phases)
            for i, (name, a) in enumerate(zip(inputs, amps))]


def _ternary_msequence(order: int) -> np.ndarray:
    """One period (3^order - 1) of a maximal-length sequence over GF(3), values 0, 1, 2."""
    period = 3 ** order - 1
    for coeffs in itertools.product(range(3), repeat=order):
        if coeffs[0] == 0:  # constant term must be non-zero for a maximal sequence
            continue
        state = [0] * (order - 1) + [1]
        out = []
        for _ in range(period):
            out.append(state[0])
            state = state[1:] + [sum(c * s for c, s in zip(coeffs, state)) % 3]
        seq = np.array(out)
        # maximal: each non-zero state appears once, so the first repeat of the start is at `period`
        states = {tuple(np.roll(seq, -i)[:order]) for i in range(period)}
        if len(states) == period:
            return seq
    raise AssertionError(f"no primitive polynomial of degree {order} over GF(3)")  # pragma: no cover


def prts(duration: float, order: int = 3, amplitude: float = 1.0, input: str = "theta_s",
         delay: float = 0.0) -> Signal:
    """Pseudo-random ternary sequence: one period (3^order - 1 steps) of a GF(3) m-sequence mapped
    0, 1, 2 -> 0, +1, -1, with the step width chosen so the period lasts ``duration`` s."""
    duration = _positive("duration", duration)
    if not 2 <= int(order) <= 6:
        raise SignalError(f"PRTS order must be 2..6, got {order}")
    seq = _ternary_msequence(int(order))
    # one period of a periodic sequence: rotate it to start on a level change from 0, not idle
    start = next(i for i in range(seq.size) if seq[i - 1] == 0 and seq[i] != 0)
    seq = np.roll(seq, -start)
    levels = np.where(seq == 2, -1.0, seq.astype(float))
    width = duration / levels.size
    return Signal("prts", input, width, levels, amplitude, delay, {"order": int(order), "width": width})


def make_signal(kind: str, *, width: float | None = None, amplitude: float = 1.0, input: str = "theta_s",
                duration: float = 7.0, band=None, pulses=None, levels=None, order: int = 3,
                dt: float = 0.05, delay: float = 0.0, phases: str = "optimised") -> Signal | list[Signal]:
    """Build any baseline by name: ``doublet``, ``3211`` (or any digits such as ``2121``),
    ``multistep`` (with ``pulses``), ``steps`` (with ``levels``), ``multisine`` (with ``band`` and
    ``phases``), ``prts``. A multisine on several inputs (a list, or comma-separated names) is a
    list of orthogonal multisines, one per input (harmonics interleaved)."""
    kind = kind.lower()
    inputs = [i.strip() for i in input.split(",") if i.strip()] if isinstance(input, str) else list(input)
    if not inputs:
        raise SignalError("no input named")
    if len(inputs) > 1 and kind != "multisine":
        raise SignalError(f"signal '{kind}' is on one input; several inputs ({', '.join(inputs)}) take a multisine")
    input = inputs[0]
    needs_width = kind in ("doublet", "multistep", "steps") or kind.isdigit()
    if needs_width and width is None:
        raise SignalError(f"signal '{kind}' needs a pulse width (--width)")
    if kind == "doublet":
        return doublet(width, amplitude, input, delay)
    if kind == "3211":
        return m3211(width, amplitude, input, delay)
    if kind.isdigit():
        return multistep([int(c) for c in kind], width, amplitude, input, delay)
    if kind == "multistep":
        if not pulses:
            raise SignalError("signal 'multistep' needs pulse counts (--pulses 3,2,1,1)")
        return multistep(pulses, width, amplitude, input, delay)
    if kind == "steps":
        if levels is None or len(levels) == 0:
            raise SignalError("signal 'steps' needs levels (--levels 1,0,-1,...)")
        return step_sequence(levels, width, amplitude, input, delay)
    if kind == "multisine":
        if band is None:
            raise SignalError("signal 'multisine' needs a band (--band 0.3,3 rad/s)")
        if len(inputs) > 1:
            return orthogonal_multisines(inputs, duration, band, amplitude, dt, phases, delay)
        return multisine(duration, band, amplitude, input, dt, delay=delay, phases=phases)
    if kind == "prts":
        return prts(duration, order, amplitude, input, delay)
    raise SignalError(f"unknown signal kind '{kind}' (doublet, 3211, <digits>, multistep, steps, "
                      f"multisine, prts)")

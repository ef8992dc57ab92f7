"""Tuned baseline signals, the response limits they set when a profile has none, the per-model
yardsticks of the robust columns, and information per second of flight.

Baselines are tuned on the a priori model the same way the optimised sequence is: the pulse
width of each doublet, 3211 and PRTS is the one (on the time-step grid, within the duration, no
pulse under the pilot's minimum) that maximises log det of the Fisher information at equal peak
response. The multisine spans the harmonics of
2 pi / duration up to twice the required band's top (at least three), with Schroeder's phases and
with phases optimised for a small relative peak factor (RPF, :mod:`signaldesign.phases`). Several axes get the same
signal type at once (the paper's "combined input"): doublets and 3211s with their widths tuned
jointly per axis (identical signals on two axes cannot separate the axes' control derivatives),
orthogonal multisines, and a PRTS rotated by a third of its period on the second axis.
"""
from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np

from .baselines import doublet, m3211, multisine, orthogonal_multisines, prts
from .evaluate import DesignError, Evaluator, tune_width
from .workers import run_tasks


MIN_WIDTH = 0.3  # s: the shortest pulse a pilot flies accurately (the designer's default min pulse)


def width_grid(lo: float, hi: float, dt: float) -> np.ndarray:
    i0, i1 = max(int(np.ceil(lo / dt - 1e-9)), 1), int(np.floor(hi / dt + 1e-9))
    return np.round(np.arange(i0, i1 + 1) * dt, 10)


def _on_axes(factory, inputs, amplitude):
    """Signals of one type on every axis from one width per axis (or one width for all)."""
    amps = np.broadcast_to(np.asarray(amplitude, float), (len(inputs),))

    def build(w):
        widths = np.broadcast_to(np.asarray(w, float), (len(inputs),))
        return [factory(float(wi), a, name) for wi, name, a in zip(widths, inputs, amps)]
    return build


def tune(factory, widths, ev: Evaluator, inputs, amplitude, max_pairs: int = 400, model=None):
    """Best widths: one per axis tuned jointly on a coarsened grid when there are several axes
    (identical signals on two axes cannot tell their control derivatives apart), else the grid."""
    build = _on_axes(factory, inputs, amplitude)
    if len(inputs) == 1:
        sigs, w, ld = tune_width(build, widths, ev, model)
        return sigs, f"{w:g}", ld
    step = max(1, int(np.ceil(widths.size / max_pairs ** (1 / len(inputs)))))
    coarse = widths[::step]
    combos = [tuple(c) for c in itertools.product(coarse, repeat=len(inputs))]
    sigs, w, ld = tune_width(build, combos, ev, model)
    return sigs, "/".join(f"{x:g}" for x in w), ld


def tuned_baselines(ev: Evaluator, duration: float, amplitude, band_high: float | None = None,
                    prts_order: int | None = None, min_width: float = MIN_WIDTH) -> list[tuple[str, list]]:
    """[(label, signals)] for the best doublet, best 3211, the Schroeder and the optimised multisine
    (orthogonal across axes) and the best PRTS; no
    pulse shorter than ``min_width`` s (the pilot's shortest pulse, as for the optimised sequence).
    The PRTS has 26 steps (order 3) when they fit in the duration at that width, else 8."""
    dt, inputs = ev.dt, ev.inputs
    out = []
    widths = width_grid(min_width, duration / 2, dt)
    if widths.size:
        sigs, w, _ = tune(doublet, widths, ev, inputs, amplitude)
        out.append((f"doublet, best width {w} s", sigs))
    widths = width_grid(min_width, duration / 7, dt)
    if widths.size:
        sigs, w, _ = tune(m3211, widths, ev, inputs, amplitude)
        out.append((f"3211, best width {w} s", sigs))
    w0 = 2 * np.pi / duration
    top = max(3.05 * w0, 2 * band_high if band_high else 0.0)
    for phases in ("schroeder", "optimised"):
        if len(inputs) == 1:
            ms = [multisine(duration, (0.0, top), float(np.atleast_1d(amplitude)[0]), inputs[0], dt, phases=phases)]
        else:
            ms = orthogonal_multisines(inputs, duration, (0.0, max(top, (len(inputs) * 3 + 0.05) * w0)), amplitude,
                                       dt, phases)
        rpf = "/".join(f"{s.params['relative_peak_factor']:.2f}" for s in ms)
        out.append((f"multisine {len(ms[0].params['harmonics'])} harmonics, {phases} phases (RPF {rpf})", ms))
    if prts_order is None:
        prts_order = 3 if 26 * min_width <= duration + 1e-9 else 2
    period = 3 ** prts_order - 1
    widths = width_grid(min_width, duration / period, dt)
    if widths.size:
        def factory(w, a, name):
            return prts(period * w, prts_order, a, name)

        def on_axes(w):
            sigs = _on_axes(factory, inputs, amplitude)(w)
            # decorrelate the axes by rotating the period (not by half of it: over GF(3) that is
            # the negated sequence, perfectly anti-correlated)
            for k, s in enumerate(sigs[1:], start=1):
                s.levels = np.roll(s.levels, k * (period // 3))
            return sigs
        sigs, w, _ = tune_width(on_axes, widths, ev)
        out.append((f"PRTS {period} steps, best width {w:g} s", sigs))
    if not any(label.startswith("3211") for label, _ in out):
        raise DesignError(f"duration {duration:g} s is too short for a 3211 of {min_width:g} s pulses")
    return out


def widths_3211(duration: float, min_width: float, dt: float) -> np.ndarray:
    """Pulse widths of a 3211 that fits in ``duration`` s, none under ``min_width`` s."""
    widths = width_grid(min_width, duration / 7, dt)
    if not widths.size:
        raise DesignError(f"duration {duration:g} s is too short for a 3211 of {min_width:g} s pulses "
                          f"(at least {7 * min_width:g} s)")
    return widths


def default_limits(ev: Evaluator, duration: float, amplitude, min_width: float = MIN_WIDTH) -> Evaluator:
    """Without response limits, the peaks of the best-width 3211 (tuned on the a priori by log
    det at ``amplitude``) become the limits: every comparison is then at the 3211's response."""
    if ev.has_limits:
        return ev
    sigs, w, _ = tune(m3211, widths_3211(duration, min_width, ev.dt), ev, ev.inputs, amplitude)
    peaks = ev.peaks(sigs)
    limits = {y: float(v) for y, v in zip(ev.model.profile.outputs, peaks) if v > 0}
    amps = "/".join(f"{a:g}" for a in np.broadcast_to(np.asarray(amplitude, float), (len(ev.inputs),)))
    return ev.set_limits(limits, f"peak response of the best-width 3211 ({w} s) at amplitude {amps}")


def yardsticks(ev: Evaluator, duration: float, min_width: float = MIN_WIDTH, jobs: int = 1) -> Evaluator:
    """For every model of the evaluator's set, the equal-peak log det of the best-width 3211 tuned
    on that model (the correctly tuned 3211: what a signal loses against it is a priori error);
    the models in ``jobs`` worker processes."""
    widths = widths_3211(duration, min_width, ev.dt)
    lds = run_tasks(_yardstick, [(m, widths) for m in ev.models], ev, None, jobs)
    return ev.set_yardsticks(lds)


def _yardstick(ev: Evaluator, _, model, widths) -> float:
    return tune(m3211, widths, ev, ev.inputs, 1.0, max_pairs=64, model=model)[2]


def reference_of(baselines) -> list:
    """The best 3211: the reference every D-efficiency and peak ratio is relative to."""
    return next(s for label, s in baselines if label.startswith("3211"))


def equal_peak_information(ev: Evaluator, signals) -> np.ndarray:
    """Fisher information (p, p) of one run flown at equal peak response (largest peak/limit = 1)."""
    r, _ = ev.response(signals)
    return ev.information(signals) / r ** 2


def per_input_peak(ev: Evaluator, signals) -> list:
    """The signals of one run each scaled so that its own response, alone, has its largest output
    peak / limit at 1 (as in a run of its own; together the responses add)."""
    out = []
    for s in signals:
        r, _ = ev.response([s] + [replace(o, amplitude=0.0) for o in signals if o is not s])
        out.append(replace(s, amplitude=s.amplitude / r))
    return out


def information_per_second(ev: Evaluator, joint, separate, record: float,
                           per_input: bool = False) -> tuple[float, float]:
    """D-optimal information per second of flight, det(M)^(1/p) / time: the ``joint`` signals
    flown in one run of ``record`` s, against each of ``separate`` (one signal list per run) flown
    in its own run (their informations add; the time is one record per run). Every run is at
    equal peak response, so the limits are shared within a run; with ``per_input`` the joint run
    has each input at its own equal peak response (:func:`per_input_peak`)."""
    from .information import log_det

    p = ev.p
    Mj = ev.information(per_input_peak(ev, joint)) if per_input else equal_peak_information(ev, joint)
    joint_rate = np.exp(log_det(Mj) / p) / record
    M = sum(equal_peak_information(ev, s) for s in separate)
    return float(joint_rate), float(np.exp(log_det(M) / p) / (record * len(separate)))

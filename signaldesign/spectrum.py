"""Power spectrum, half-power bandwidth and in-band power of any signal (the paper's Figs 2 and 6).

A signal is piecewise constant, so its Fourier transform is exact and closed-form::

    U(w) = amplitude * dt * sinc(w dt / 2) * sum_k level_k exp(-j w (k + 1/2) dt) * exp(-j w delay)

with sinc(x) = sin(x)/x. The energy spectrum is |U(w)|^2 (control units^2 s^2); by Parseval its
integral over 0..inf is pi times the signal energy integral u^2 dt, which gives in-band fractions
without truncation error.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from .signal import Signal, SignalError


def energy_spectrum(signal: Signal, omega) -> np.ndarray:
    """|U(omega)|^2 at frequencies ``omega`` (rad/s), shape of ``omega``."""
    omega = np.asarray(omega, dtype=float)
    w = omega.reshape(-1)
    h = signal.dt
    centres = (np.arange(signal.levels.size) + 0.5) * h
    # chunk over frequency so a long multisine on a fine grid stays small in memory
    out = np.empty(w.size)
    for i in range(0, w.size, 2048):
        wi = w[i:i + 2048]
        U = np.exp(-1j * np.outer(wi, centres)) @ signal.levels
        out[i:i + 2048] = np.abs(U) ** 2 * (h * np.sinc(wi * h / (2 * np.pi))) ** 2
    return (signal.amplitude ** 2 * out).reshape(omega.shape)


def energy(signal: Signal) -> float:
    """Time-domain energy integral of u^2 dt (control units^2 s)."""
    return float(signal.amplitude ** 2 * signal.dt * np.sum(signal.levels ** 2))


def frequency_grid(signal: Signal, points: int = 4000) -> np.ndarray:
    """Frequencies (rad/s) from 0 to well past the first spectral null of one step."""
    top = 4 * 2 * np.pi / max(signal.dt, signal.duration / 200)
    return np.linspace(0.0, top, points)


def half_power_band(signal: Signal) -> tuple[float, float, float]:
    """(w_low, w_high, w_peak) in rad/s: the contiguous range around the spectral peak where the
    power is at least half the peak. ``w_low`` is 0 when the spectrum is half-power at 0 already."""
    if energy(signal) == 0:
        raise SignalError(f"signal '{signal.kind}' is identically zero: it has no bandwidth")
    grid = frequency_grid(signal)
    P = energy_spectrum(signal, grid)
    i = int(np.argmax(P))
    lo_b, hi_b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    if i == 0:
        w_peak = 0.0
    else:
        res = minimize_scalar(lambda w: -energy_spectrum(signal, w), bounds=(lo_b, hi_b), method="bounded",
                              options={"xatol": 1e-10 * hi_b})
        w_peak = float(res.x)
    half = 0.5 * float(energy_spectrum(signal, w_peak))

    def f(w):
        return float(energy_spectrum(signal, w)) - half

    below = np.flatnonzero(P[:i + 1] < half)
    w_low = 0.0 if below.size == 0 else brentq(f, grid[below[-1]], max(grid[below[-1] + 1], w_peak), xtol=1e-12)
    above = np.flatnonzero(P[i:] < half)
    if above.size == 0:  # pragma: no cover - the grid always reaches past the sinc null
        raise SignalError(f"signal '{signal.kind}': half-power point lies beyond {grid[-1]:.3g} rad/s")
    k = i + above[0]
    w_high = brentq(f, max(grid[k - 1], w_peak), grid[k], xtol=1e-12)
    return float(w_low), float(w_high), w_peak


def in_band_fraction(signal: Signal, band: tuple[float, float], points: int = 4001) -> float:
    """Fraction of the signal's energy at frequencies inside ``band`` (rad/s), exact by Parseval."""
    lo, hi = map(float, band)
    w = np.linspace(lo, hi, points)
    inside = np.trapezoid(energy_spectrum(signal, w), w)
    return float(inside / (np.pi * energy(signal)))


def plot_signals(signals: list[Signal], path, band=None, labels=None, title: str = "", unit: str = "rad") -> None:
    """Time histories (top, in the inputs' ``unit``) and normalised power spectra over a log
    frequency axis with half-power points (bottom), as the paper's Figs 2 and 6; the required band,
    if given, is shaded. Writes a PNG."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    labels = labels or [f"{s.kind} on {s.input}" for s in signals]
    fig = Figure(figsize=(8, 7))
    FigureCanvasAgg(fig)  # drawn off-screen, no pyplot state
    ax_t, ax_f = fig.subplots(2, 1)
    top = max(frequency_grid(s)[-1] for s in signals) / 4
    lows = [half_power_band(s)[0] for s in signals] + ([band[0]] if band is not None else [])
    bottom = max(min([lo for lo in lows if lo > 0] or [top / 100]) / 5, top / 1e4)
    w = np.geomspace(bottom, top, 1500)
    for s, label in zip(signals, labels):
        t = np.linspace(0, s.end_time, 2000)
        line, = ax_t.step(t, s(t), where="post", label=f"{label} (amplitude {s.amplitude:.3g} {unit})")
        P = energy_spectrum(s, w)
        lo, hi, _ = half_power_band(s)
        ax_f.plot(w, P / P.max(), color=line.get_color(), label=f"{label}: {lo:.2f}..{hi:.2f} rad/s")
        ax_f.axvline(hi, color=line.get_color(), ls=":", lw=1)
        if lo > 0:
            ax_f.axvline(lo, color=line.get_color(), ls=":", lw=1)
    if band is not None:
        ax_f.axvspan(*band, color="0.85", zorder=0, label=f"required band {band[0]:.2f}..{band[1]:.2f} rad/s")
    ax_f.axhline(0.5, color="k", lw=0.5, ls="--")
    ax_f.set_xscale("log")
    ax_t.set(xlabel="time [s]", ylabel=f"control [{unit}]", title=title or "input signals")
    ax_f.set(xlabel="frequency [rad/s]", ylabel="power / peak [-]", xlim=(bottom, top), ylim=(0, 1.05))
    ax_t.legend(fontsize=7)
    ax_f.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)

"""The frequency band a test must excite, from an a priori model's output sensitivities.

For input j, the output sensitivity to free parameter i in the frequency domain is the derivative
of the transfer function, with ``R(w) = (jw I - A)^-1``::

    dG_i/dtheta_i (jw) = dC_i R b + C R (dA_i R b + dB_i[:, j]) + dD_i[:, j],   b = B[:, j]

Each is scaled by the parameter value (a relative change) and by the assumed measurement noise
per output, then combined over outputs as a root sum of squares: its square is exactly the
spectral density of that parameter's diagonal Fisher information per unit input power. A
parameter's band is where this stays above ``level`` (default one half) of its peak; the required
band spans the parameters' bands.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from identify import LinearModel, Mode
from identify.errors import BandError

from .information import default_noise


def input_index(model: LinearModel, input: str) -> int:
    """Column of ``input`` in B; BandError naming the choices otherwise."""
    names = model.profile.input_names
    if input not in names:
        raise BandError(f"{model.profile.source}: no input '{input}' (inputs: {', '.join(names)})")
    return names.index(input)


def frequency_sensitivities(model: LinearModel, input: str, omega, noise_std=None) -> np.ndarray:
    """Noise-weighted relative sensitivity magnitudes (W, p): sqrt(sum_y |theta_i dG_yi(jw)|^2 / sigma_y^2)."""
    j = input_index(model, input)
    omega = np.asarray(omega, dtype=float)
    sigma = default_noise(model.profile) if noise_std is None else np.asarray(noise_std, float)
    n = model.n_states
    R = np.linalg.inv(1j * omega[:, None, None] * np.eye(n) - model.A)  # (W, n, n)
    x = R @ model.B[:, j]  # (W, n)
    forcing = np.einsum("pnk,wk->wnp", model.dA, x) + model.dB[:, :, j].T[None]  # (W, n, p)
    dx = R @ forcing  # (W, n, p)
    dy = (np.einsum("yn,wnp->wyp", model.C, dx) + np.einsum("pyn,wn->wyp", model.dC, x)
          + model.dD[:, :, j].T[None])
    dy = dy * model.theta / sigma[:, None]
    return np.sqrt(np.sum(np.abs(dy) ** 2, axis=1))


@dataclass
class ParameterBand:
    """One parameter's significant band (rad/s), its peak frequency and the mode nearest the peak."""

    name: str
    low: float
    high: float
    peak: float
    mode: Mode | None
    open_low: bool = False  # still above the level at the analysis grid's lowest frequency
    open_high: bool = False  # ... at its highest: the band goes on beyond what was analysed

    @property
    def text(self) -> str:
        lo = f"<{self.low:.3f}" if self.open_low else f"{self.low:.3f}"
        hi = f">{self.high:.3f}" if self.open_high else f"{self.high:<.3f}"
        return f"{lo}..{hi}"


@dataclass
class RequiredBand:
    """Result of :func:`required_band`: ``low``..``high`` rad/s, per-parameter bands, the modes that
    drive the band, parameters this input does not excite, and the curves for plotting."""

    input: str
    low: float
    high: float
    level: float
    parameters: list[ParameterBand]
    modes: list[Mode]
    unexcited: list[str]
    omega: np.ndarray = field(repr=False)
    curves: np.ndarray = field(repr=False)  # (W, p) normalised to each parameter's peak

    @property
    def bounded(self) -> bool:
        """False when no parameter's band closes at one end (or both) within the analysed range:
        ``low``/``high`` are then the grid's edges, not a band."""
        return any(not b.open_low for b in self.parameters) and any(not b.open_high for b in self.parameters)

    def format(self) -> str:
        hz = f"{self.low / (2 * np.pi):.3f} .. {self.high / (2 * np.pi):.3f} Hz"
        if self.bounded:
            head = (f"required band for input {self.input}: {self.low:.3f} .. {self.high:.3f} rad/s ({hz}; "
                    f"sensitivities above {self.level:g} of their peak, from the parameters whose band closes)")
        else:
            head = (f"no required band for input {self.input}: no parameter's sensitivity falls below {self.level:g} "
                    f"of its peak {'below' if all(b.open_low for b in self.parameters) else 'above'} the analysed "
                    f"range {self.omega[0]:g}..{self.omega[-1]:g} rad/s (shown: {self.low:.3f} .. {self.high:.3f} rad/s)")
        lines = [head]
        lines.append(f"  {'parameter':<18} {'band [rad/s]':>16} {'peak [rad/s]':>13}  nearest mode")
        for b in self.parameters:
            m = _mode_label(b.mode)
            lines.append(f"  {b.name:<18} {b.text:>16} {b.peak:13.3f}  {m}")
        open_low = [b.name for b in self.parameters if b.open_low]
        open_high = [b.name for b in self.parameters if b.open_high]
        if open_low:
            lines.append(f"open below {self.omega[0]:g} rad/s (sensitivity still rising toward steady state: "
                         f"the response's low-frequency content, i.e. record length, identifies them): "
                         f"{', '.join(open_low)}")
        if open_high:
            lines.append(f"open above {self.omega[-1]:g} rad/s (sensitivity flat up to the analysed range's end: "
                         f"any input excites them): {', '.join(open_high)}")
        lines.append("modes driving the band: " + "; ".join(_mode_label(m) for m in self.modes))
        if self.unexcited:
            lines.append(f"not excited by {self.input} (left out): {', '.join(self.unexcited)}")
        return "\n".join(lines)


def _mode_label(m: Mode | None) -> str:
    if m is None:
        return "-"
    kind = "oscillatory" if m.oscillatory else "real"
    return f"{m.frequency:.3f} rad/s {kind}, damping {m.damping:.3f}{'' if m.stable else ' UNSTABLE'}"


def _nearest_mode(modes: list[Mode], w: float) -> Mode | None:
    if not modes:
        return None
    return min(modes, key=lambda m: abs(np.log(max(m.frequency, 1e-6) / max(w, 1e-6))))


def excited_parameters(model: LinearModel, input: str, rtol: float = 1e-9) -> list[int]:
    """Indices of the free parameters whose outputs respond to ``input`` at all (structurally)."""
    omega = np.geomspace(0.05, 20, 12)
    s = frequency_sensitivities(model, input, omega, np.ones(model.n_outputs))
    scale = s.max() if s.size else 0.0
    return [i for i in range(len(model.names)) if s[:, i].max() > rtol * scale]


def required_band(model: LinearModel, input: str, level: float = 0.5, noise_std=None,
                  omega=None) -> RequiredBand:
    """The band input ``input`` must excite to identify the model's free parameters."""
    if not 0 < level < 1:
        raise BandError(f"band level must be between 0 and 1, got {level:g}")
    omega = np.geomspace(0.01, 100.0, 1200) if omega is None else np.asarray(omega, float)
    keep = excited_parameters(model, input)
    if not keep:
        raise BandError(f"{model.profile.source}: input '{input}' excites none of the free parameters")
    s = frequency_sensitivities(model, input, omega, noise_std)[:, keep]
    curves = s / s.max(axis=0)
    modes = model.modes()
    bands = []
    for col, i in enumerate(keep):
        c = curves[:, col]
        k = int(np.argmax(c))
        lo, hi = k, k  # contiguous range around the peak above the level
        while lo > 0 and c[lo - 1] >= level:
            lo -= 1
        while hi < c.size - 1 and c[hi + 1] >= level:
            hi += 1
        bands.append(ParameterBand(model.names[i], float(omega[lo]), float(omega[hi]), float(omega[k]),
                                   _nearest_mode(modes, omega[k]), lo == 0, hi == c.size - 1))
    # the band from the ends that close: a grid edge is where the analysis stopped, not a band's
    # edge (the grid's edge only when no parameter's band closes at that end; ``bounded`` says so)
    lows = [b.low for b in bands if not b.open_low] or [float(omega[0])]
    highs = [b.high for b in bands if not b.open_high] or [float(omega[-1])]
    low, high = min(lows), max(highs)
    driving = [m for m in modes if low / 1.5 <= m.frequency <= high * 1.5]
    unexcited = [n for i, n in enumerate(model.names) if i not in keep]
    return RequiredBand(input, low, high, level, bands, driving, unexcited, omega, curves)


def plot_band(band: RequiredBand, path, title: str = "") -> None:
    """Normalised sensitivity magnitude per parameter over frequency, with the band shaded (PNG)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9, 5.5))
    FigureCanvasAgg(fig)  # drawn off-screen, no pyplot state
    ax = fig.subplots()
    for col, b in enumerate(band.parameters):
        ax.semilogx(band.omega, band.curves[:, col], lw=1, label=b.name)
    if band.bounded:
        ax.axvspan(band.low, band.high, color="0.88", zorder=0, label="required band")
    else:
        ax.text(0.5, 0.97, "no required band: the sensitivities do not fall off within the analysed range",
                transform=ax.transAxes, ha="center", va="top", fontsize=9, color="r")
    ax.axhline(band.level, color="k", ls="--", lw=0.7)
    for m in band.modes:
        ax.axvline(m.frequency, color="r", ls=":", lw=0.8)
    ax.set(xlabel="frequency [rad/s]", ylabel="|sensitivity| / peak",
           title=title or f"output sensitivities to the parameters, input {band.input}")
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)

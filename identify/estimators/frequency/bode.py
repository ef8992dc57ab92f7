"""Bode plots of a measured frequency response with coherence, models overlaid (PNG).

Drawn on matplotlib's Agg canvas directly (no pyplot state), as every figure of the library.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib import ticker
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ...model.linear import LinearModel
from .response import MIN_COHERENCE, FrequencyResponse, model_response


def plot_bode(fr: FrequencyResponse, models: dict[str, LinearModel] | None = None, outdir: str | Path = ".",
              min_coherence: float = MIN_COHERENCE, units: dict[str, str] | None = None) -> list[Path]:
    """One PNG per flown input (``bode_<input>.png``), a grid with a row per output: magnitude (dB of
    output unit per input unit), phase (deg) and coherence against frequency (Hz, log axis), the
    models overlaid. Inputs no run moves get no figure (and a stale one is removed).

    ``units`` {channel: unit} labels the magnitude axes; default from the first model's profile.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    models = models or {}
    if units is None and models:
        from ...model.profile import output_units

        prof = next(iter(models.values())).profile
        units = {**prof.inputs, **output_units(prof)}
    units = units or {}
    responses = {}
    for label, m in models.items():
        outs = [y for y in fr.outputs if y in m.profile.outputs]
        ins = [u for u in fr.inputs if u in m.profile.input_names]
        responses[label] = (outs, ins, model_response(m, fr.omega, ins, outs))
    f_hz = fr.omega / (2 * np.pi)
    paths = []
    for i, u in enumerate(fr.inputs):
        path = outdir / f"bode_{u}.png"
        if u in fr.unmoved:
            path.unlink(missing_ok=True)
            continue
        ny = len(fr.outputs)
        fig = Figure(figsize=(11.0, 2.1 * ny + 0.9))
        FigureCanvasAgg(fig)
        axes = fig.subplots(ny, 3, sharex=True, squeeze=False)
        for j, y in enumerate(fr.outputs):
            coherent = fr.coherence[:, j, i] >= min_coherence
            mag, ph = fr.magnitude_db[:, j, i], fr.phase_deg[:, j, i]
            a_m, a_p, a_c = axes[j]
            a_m.semilogx(f_hz, np.where(coherent, mag, np.nan), "k-", lw=1.5, label="flight data")
            a_m.semilogx(f_hz, mag, "k:", lw=0.8)
            a_p.semilogx(f_hz, np.where(coherent, ph, np.nan), "k-", lw=1.5)
            a_p.semilogx(f_hz, ph, "k:", lw=0.8)
            for (label, (outs, ins, Hm)), style in zip(responses.items(), ("C1--", "C0-", "C2-.", "C4:")):
                if y in outs and u in ins:
                    h = Hm[:, outs.index(y), ins.index(u)]
                    with np.errstate(divide="ignore"):
                        a_m.semilogx(f_hz, 20 * np.log10(np.abs(h)), style, lw=1.2, label=label)
                    a_p.semilogx(f_hz, _phase_near(h, ph), style, lw=1.2)
            for a in (a_m, a_p, a_c):
                _shade_unresolved(a, f_hz, fr.resolved[:, j, i])
            a_c.semilogx(f_hz, fr.coherence[:, j, i], "k-")
            a_c.axhline(min_coherence, color="0.6", ls=":")
            a_c.set_ylim(0, 1.05)
            ratio = f"{units.get(y) or '-'} per {units.get(u) or '-'}"
            a_m.set_ylabel(f"{y}/{u}\n|H| [dB, {ratio}]", fontsize=8)
            a_p.set_ylabel("phase [deg]", fontsize=8)
            a_c.set_ylabel("coherence [-]", fontsize=8)
        for a in axes[-1]:
            a.set_xlabel("frequency [Hz]")
            a.xaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
            a.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
            a.xaxis.set_minor_formatter(ticker.NullFormatter())
        axes[0, 0].set_title("magnitude", fontsize=9)
        axes[0, 1].set_title("phase", fontsize=9)
        axes[0, 2].set_title("coherence", fontsize=9)
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(f"frequency responses to {u} (solid: coherence >= {min_coherence}; "
                     f"grey: no valid window, nothing estimated)", fontsize=10)
        fig.tight_layout()
        fig.savefig(path, dpi=80)
        paths.append(path)
    return paths


def _shade_unresolved(ax, f_hz: np.ndarray, resolved: np.ndarray) -> None:
    """Grey bands over the frequencies without a valid estimate (edges half-way in log frequency)."""
    edges = np.sqrt(f_hz[1:] * f_hz[:-1])
    edges = np.concatenate([[f_hz[0] ** 2 / edges[0]], edges, [f_hz[-1] ** 2 / edges[-1]]]) if f_hz.size > 1 \
        else np.array([f_hz[0] / 1.1, f_hz[0] * 1.1])
    k = 0
    while k < f_hz.size:
        if resolved[k]:
            k += 1
            continue
        k1 = k
        while k1 < f_hz.size and not resolved[k1]:
            k1 += 1
        ax.axvspan(edges[k], edges[k1], color="0.88", lw=0)
        k = k1


def _phase_near(h: np.ndarray, reference_deg: np.ndarray) -> np.ndarray:
    """Unwrapped model phase (deg) shifted by whole turns to lie near the data's."""
    ph = np.degrees(np.unwrap(np.angle(h)))
    ok = np.isfinite(reference_deg)
    if ok.any():
        ph += 360 * np.round(np.median(reference_deg[ok] - ph[ok]) / 360)
    return ph

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
from .response import MIN_COHERENCE, FrequencyResponse


def plot_bode(fr: FrequencyResponse, models: dict[str, LinearModel] | None = None, outdir: str | Path = ".",
              min_coherence: float = MIN_COHERENCE) -> list[Path]:
    """One PNG per input: magnitude, phase and coherence of every output, models overlaid."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    models = models or {}
    responses = {}
    for label, m in models.items():
        outs = [y for y in fr.outputs if y in m.profile.outputs]
        ins = [u for u in fr.inputs if u in m.profile.input_names]
        responses[label] = (outs, ins, m.frequency_response(fr.omega, ins, outs))
    f_hz = fr.omega / (2 * np.pi)
    paths = []
    for i, u in enumerate(fr.inputs):
        ny = len(fr.outputs)
        fig = Figure(figsize=(3.2 * ny, 7.5))
        FigureCanvasAgg(fig)
        axes = fig.subplots(3, ny, sharex=True, squeeze=False)
        for j, y in enumerate(fr.outputs):
            coherent = fr.coherence[:, j, i] >= min_coherence
            mag, ph = fr.magnitude_db[:, j, i], fr.phase_deg[:, j, i]
            a_m, a_p, a_c = axes[0, j], axes[1, j], axes[2, j]
            a_m.semilogx(f_hz, np.where(coherent, mag, np.nan), "k-", lw=1.5, label="flight data")
            a_m.semilogx(f_hz, mag, "k:", lw=0.8)
            a_p.semilogx(f_hz, np.where(coherent, ph, np.nan), "k-", lw=1.5)
            a_p.semilogx(f_hz, ph, "k:", lw=0.8)
            for (label, (outs, ins, Hm)), style in zip(responses.items(), ("C1--", "C0-", "C2-.")):
                if y in outs and u in ins:
                    h = Hm[:, outs.index(y), ins.index(u)]
                    a_m.semilogx(f_hz, 20 * np.log10(np.abs(h)), style, lw=1.2, label=label)
                    a_p.semilogx(f_hz, _phase_near(h, ph), style, lw=1.2)
            for a in (a_m, a_p, a_c):
                _shade_unresolved(a, f_hz, fr.resolved[:, j, i])
            a_c.semilogx(f_hz, fr.coherence[:, j, i], "k-")
            a_c.axhline(min_coherence, color="0.6", ls=":")
            a_c.set_ylim(0, 1.05)
            a_m.set_title(f"{y} / {u}")
            a_c.set_xlabel("frequency [Hz]")
            a_c.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
            a_c.xaxis.set_minor_formatter(ticker.NullFormatter())
        axes[0, 0].set_ylabel("magnitude [dB]")
        axes[1, 0].set_ylabel("phase [deg]")
        axes[2, 0].set_ylabel("coherence")
        axes[0, 0].legend(fontsize=7)
        fig.suptitle(f"frequency responses to {u} (solid: coherence >= {min_coherence}; "
                     f"grey: no valid window, nothing estimated)")
        fig.tight_layout()
        path = outdir / f"bode_{u}.png"
        fig.savefig(path, dpi=90)
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

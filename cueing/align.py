"""The display's run file and the aircraft's own recording on one clock.

The cockpit display logs the stick it saw on its own clock; the data-acquisition system records the
aircraft (and usually the control positions) on another, started at another moment. Both hold the
same physical control input, so the offset between the clocks is the lag that lines the two up
best: the peak of their normalised cross-correlation, refined between samples by a parabola
through the peak and its neighbours. The merged run is the recording's samples over the time the
display logged, on the display's clock (t = 0 where the display's log starts), with the display's
channels (``theta_s_cmd``, the designed input) interpolated onto it; a channel both files hold
keeps the recording's values, the display's copy is added as ``<name>_display``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identify import Run

from .errors import CueingError

WEAK_CORRELATION = 0.9  # below this the offset is reported as doubtful


@dataclass
class Alignment:
    """``offset`` s: recording time = display time + offset; ``correlation`` at that lag (-1..1)."""

    offset: float
    correlation: float
    channel: str

    @property
    def doubtful(self) -> bool:
        return not self.correlation >= WEAK_CORRELATION


def _on_grid(run: Run, name: str, dt: float) -> np.ndarray:
    t = np.arange(run.time[0], run.time[-1] + 1e-9, dt)
    x = np.interp(t, run.time, run[name])
    return x - x.mean()


def find_offset(display: Run, recording: Run, channel: str, max_offset: float | None = None) -> Alignment:
    """The clock offset between ``display`` and ``recording`` from ``channel`` held by both."""
    for run in (display, recording):
        if channel not in run.channels:
            raise CueingError(f"{run.source}: no channel '{channel}' to align on "
                              f"(channels: {', '.join(run.channels)})")
    dt = min(display.dt, recording.dt)
    a, b = _on_grid(display, channel, dt), _on_grid(recording, channel, dt)
    if not (np.any(a) and np.any(b)):
        raise CueingError(f"'{channel}' does not move in {display.source if not np.any(a) else recording.source}: "
                          "nothing to align on")
    n = a.size + b.size - 1
    size = 1 << (n - 1).bit_length()
    xc = np.fft.irfft(np.fft.rfft(b, size) * np.conj(np.fft.rfft(a, size)), size)
    lags = np.r_[np.arange(0, b.size), np.arange(-a.size + 1, 0)]  # lag k: b[i + k] ~ a[i]
    xc = np.r_[xc[:b.size], xc[size - a.size + 1:]]
    # normalised by the display's whole energy and the recording's over the overlap: a lag that
    # leaves part of the display's log outside the recording scores lower (no chance match of a
    # short overlap wins), and the peak is 1 when the recording holds the whole log exactly
    cb = np.r_[0, np.cumsum(b * b)]
    lo_a, hi_a = np.clip(-lags, 0, a.size), np.clip(b.size - lags, 0, a.size)
    energy = np.sqrt(float(a @ a) * (cb[np.clip(hi_a + lags, 0, b.size)] - cb[np.clip(lo_a + lags, 0, b.size)]))
    overlap = hi_a - lo_a
    shift = recording.time[0] - display.time[0]
    offsets = lags * dt + shift
    ok = (energy > 0) & (overlap >= max(a.size // 2, 2))
    if max_offset is not None:
        ok &= np.abs(offsets) <= max_offset
    if not ok.any():
        raise CueingError("the two records do not overlap by half the display's log at any offset"
                          + (f" within {max_offset:g} s" if max_offset is not None else ""))
    rho = np.where(ok, xc / np.where(energy > 0, energy, 1.0), -np.inf)
    k = int(np.argmax(rho))
    frac = 0.0
    if 0 < k < rho.size - 1 and np.isfinite(rho[k - 1]) and np.isfinite(rho[k + 1]):
        den = rho[k - 1] - 2 * rho[k] + rho[k + 1]
        frac = 0.5 * (rho[k - 1] - rho[k + 1]) / den if den < 0 else 0.0
    return Alignment(float(offsets[k] + frac * dt), float(rho[k]), channel)


def merge(display: Run, recording: Run, alignment: Alignment) -> Run:
    """The recording over the display's span, on the display's clock, with the display's channels."""
    t = recording.time - alignment.offset
    keep = (t >= display.time[0] - 1e-9) & (t <= display.time[-1] + 1e-9)
    if keep.sum() < 2:
        raise CueingError("the recording holds no samples over the display's log at this offset")
    t = t[keep]
    channels = {k: v[keep] for k, v in recording.channels.items()}
    for name, values in display.channels.items():
        channels[name + "_display" if name in channels else name] = np.interp(t, display.time, values)
    meta = {**recording.meta, "aligned_with": display.source, "clock_offset_s": f"{alignment.offset:.4f}",
            "alignment": f"cross-correlation of {alignment.channel}, peak {alignment.correlation:.3f}",
            "time_base": "the display's clock (recording time minus the offset)"}
    return Run(t, channels, meta, f"{recording.source} aligned with {display.source}")

"""Practice scoring: how well a flown input matches the designed one, and what information it kept.

All measures work on a uniform run holding ``<input>_cmd`` (designed) and ``<input>`` (flown):

- ``rms``: RMS tracking error per axis, as a fraction of the amplitude;
- per-switch timing error (s): when the flown input crosses halfway between the old and the new
  level, minus the switch time (positive: late), searched from half a step before the switch to
  one step after it; a switch not crossed in that window counts as missed;
- level error (fractions of the amplitude): magnitude of the mean flown level over the settled
  second half of each hold minus the commanded magnitude (positive: overshoot), separately for +
  and - holds, and their asymmetry (+ error minus - error);
- in-band spectral fidelity: 1 - sum(|F_flown| - |F_design|)^2 / sum |F_design|^2 over the band the
  signal was designed for (``params['band']`` in rad/s, else up to 1/(2 dt)): 1 is the designed
  amplitude spectrum exactly; pure delay does not count against it;
- information retained: D-efficiency of the flown input relative to the designed one for a model
  (signaldesign's Fisher information), over the parameters the design excites.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from identify import Run
from signaldesign.information import d_efficiency, fisher_information

from .flightlog import CMD


@dataclass
class PracticeScore:
    """Scores of one run (see the module doc); ``per_axis`` holds the per-axis details."""

    rms: float
    timing_mean: float
    timing_std: float
    timing_max: float
    switches: int
    missed: int
    level_error_pos: float
    level_error_neg: float
    asymmetry: float
    spectral_fidelity: float
    d_efficiency: float | None = None
    per_axis: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)

    def lines(self) -> list[str]:
        """Short lines for the end-of-run screen and the console."""
        out = ["Run score",
               f"RMS tracking error   {100 * self.rms:5.1f} % of amplitude",
               f"switch timing        {1000 * self.timing_mean:+5.0f} ms mean, {1000 * self.timing_std:4.0f} ms std"
               f" ({self.missed} of {self.switches} missed)",
               f"level error (+ / -)  {100 * self.level_error_pos:+5.1f} % / {100 * self.level_error_neg:+5.1f} %"
               f"  (asymmetry {100 * self.asymmetry:+5.1f} %)",
               f"spectral fidelity    {self.spectral_fidelity:5.3f}"]
        if self.d_efficiency is not None:
            out.append(f"information retained {100 * self.d_efficiency:5.1f} % (D-efficiency)")
        return out


def switch_timing(t: np.ndarray, flown: np.ndarray, signal, t_signal: np.ndarray | None = None) -> np.ndarray:
    """Timing error (s) at each switch of ``signal``; NaN where the flown input never got halfway."""
    ts = t if t_signal is None else t_signal
    sw = signal.switch_times()
    errors = np.full(sw.size, np.nan)
    window = signal.dt
    for i, s in enumerate(sw):
        before = signal.level_at(s - 1e-6) * signal.amplitude
        after = signal.level_at(s + 1e-6) * signal.amplitude
        half = 0.5 * (before + after)
        sel = np.flatnonzero((ts >= s - 0.5 * window) & (ts <= s + window))
        if sel.size == 0:
            continue
        crossed = (flown[sel] - half) * np.sign(after - before) > 0
        # only a crossing from the old side counts: sitting on the new side all along (a pilot who
        # never followed the previous level) is a miss, not a perfectly timed switch
        cross = np.flatnonzero(crossed[1:] & ~crossed[:-1]) + 1
        if cross.size:
            errors[i] = ts[sel[cross[0]]] - s
    return errors


def level_errors(ts: np.ndarray, flown: np.ndarray, signal) -> tuple[float, float, float]:
    """Settled level magnitude error on + and on - holds, and their difference (fractions of amplitude)."""
    a = abs(signal.amplitude) or 1.0
    edges = np.concatenate([signal.switch_times(), [np.inf]])
    pos, neg = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        level = float(signal.level_at(lo + 1e-6))
        if level == 0 or not np.isfinite(hi):
            continue
        sel = (ts >= 0.5 * (lo + hi)) & (ts < hi)
        if sel.any():
            achieved = np.mean(flown[sel]) * np.sign(signal.amplitude) / a
            (pos if level > 0 else neg).append(achieved * np.sign(level) - abs(level))
    e_pos = float(np.mean(pos)) if pos else np.nan
    e_neg = float(np.mean(neg)) if neg else np.nan
    return e_pos, e_neg, e_pos - e_neg


def spectral_fidelity(designed: np.ndarray, flown: np.ndarray, dt: float, band=None) -> float:
    """In-band amplitude-spectrum match (1 = identical); ``band`` (lo, hi) in rad/s."""
    f = np.fft.rfftfreq(designed.size, dt) * 2 * np.pi
    lo, hi = band
    sel = (f >= lo) & (f <= hi)
    Fd, Ff = np.abs(np.fft.rfft(designed))[sel], np.abs(np.fft.rfft(flown))[sel]
    energy = np.sum(Fd ** 2)
    return float(1.0 - np.sum((Ff - Fd) ** 2) / energy) if energy > 0 else np.nan


def signal_band(signal) -> tuple[float, float]:
    """The band (rad/s) a signal was designed for: ``params['band']`` or (0, pi / dt)."""
    band = signal.params.get("band") if isinstance(signal.params, dict) else None
    if band is not None and len(band) == 2:
        return float(band[0]), float(band[1])
    return 0.0, float(np.pi / signal.dt)


def information_retained(model, run: Run, signals) -> float:
    """D-efficiency of the flown inputs relative to the designed ones for ``model`` (LinearModel).

    Profile inputs not flown stay zero; parameters the design leaves unexcited are left out.
    """
    names = model.profile.input_names
    u_design = np.zeros((len(run), len(names)))
    u_flown = np.zeros_like(u_design)
    for s in signals:
        j = names.index(s.input)
        u_design[:, j] = run[s.input + CMD]
        u_flown[:, j] = run[s.input]
    M_d = fisher_information(model, u_design, run.dt)
    M_f = fisher_information(model, u_flown, run.dt)
    d = np.diag(M_d)
    keep = d > 1e-10 * d.max()
    return d_efficiency(M_f[np.ix_(keep, keep)], M_d[np.ix_(keep, keep)])


def score_run(run: Run, signals, model=None) -> PracticeScore:
    """Score a flown run against ``signals``; with ``model`` also the information retained."""
    t = run.time
    ts = run["t_signal"] if "t_signal" in run.channels else t
    axes = []
    for s in signals:
        a = abs(s.amplitude) or 1.0
        designed, flown = run[s.input + CMD], run[s.input]
        timing = switch_timing(t, flown, s, ts)
        e_pos, e_neg, asym = level_errors(ts, flown, s)
        axes.append({"input": s.input, "rms": float(np.sqrt(np.mean((flown - designed) ** 2)) / a),
                     "timing": timing.tolist(), "level_error_pos": e_pos, "level_error_neg": e_neg,
                     "asymmetry": asym,
                     "spectral_fidelity": spectral_fidelity(designed, flown, run.dt, signal_band(s))})
    timing = np.concatenate([np.asarray(ax["timing"], float) for ax in axes])
    hit = timing[np.isfinite(timing)]
    mean = lambda key: float(np.nanmean([ax[key] for ax in axes]))  # noqa: E731
    return PracticeScore(rms=mean("rms"), timing_mean=float(np.mean(hit)) if hit.size else np.nan,
                 timing_std=float(np.std(hit)) if hit.size else np.nan,
                 timing_max=float(np.max(np.abs(hit))) if hit.size else np.nan,
                 switches=int(timing.size), missed=int(np.sum(~np.isfinite(timing))),
                 level_error_pos=mean("level_error_pos"), level_error_neg=mean("level_error_neg"),
                 asymmetry=mean("asymmetry"), spectral_fidelity=mean("spectral_fidelity"),
                 d_efficiency=information_retained(model, run, signals) if model is not None else None,
                 per_axis=axes)

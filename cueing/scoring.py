"""Practice scoring: how well a flown input matches the designed one, and what information it kept.

All measures work on a uniform run holding ``<input>_cmd`` (designed) and ``<input>`` (flown):

- ``rms``: RMS tracking error per axis, as a fraction of the amplitude;
- per-switch timing error (s): when the flown input crosses halfway between the old and the new
  level, minus the switch time (positive: late), searched from half the preceding hold before the
  switch to ``MAX_LAG`` s after it (a human's lag, not the step width, sizes the window) or to the
  next switch asking for the same crossing; a switch not crossed in that window counts as missed;
- lag (s): the delay of the flown input behind the designed one that lines them up best (the
  peak of their cross-correlation within +/- ``MAX_LAG``): defined even when every switch is missed;
- level error (fractions of the amplitude): magnitude of the mean flown level over the settled
  second half of each hold, taken the pilot's lag later (the hold as he flew it: a late level is
  the lag's, not the level's), minus the commanded magnitude (positive: overshoot), separately for
  + and - holds, and their asymmetry (+ error minus - error);
- in-band spectral fidelity: 1 - sum(|F_flown| - |F_design|)^2 / sum |F_design|^2 over the band the
  signal was designed for (``params['band']`` in rad/s, else up to 1/(2 dt)): 1 is the designed
  amplitude spectrum exactly; pure delay does not count against it;
- peak response (``peak_ratio``): the largest output peak the flown input drives on the model,
  against the designed input's (each output's peak over its ``[limits]`` entry, or over the
  designed input's own peak where the profile gives none): the design's amplitude was set so that
  the designed input's largest peak meets its limit;
- raw D-efficiency (``d_efficiency``): the flown input's Fisher information about the parameters
  the design excites relative to the designed one's (det ratio to the 1/p). Information grows with
  the response squared, so the raw figure rewards driving the aircraft harder than the design
  allowed (overshoot, or a lag that lets an unstable mode grow);
- information retained: the raw D-efficiency at the designed peak response,
  ``d_efficiency / peak_ratio**2`` -- the comparison every design table makes (equal peak
  response). Under 100 %: the flown shape (lag, rounded steps, level errors) lost information;
  over 100 %: the flown shape carries more per unit of peak response than the design.
  raw = retained x peak_ratio², so the three figures never contradict each other.
- frame rate: achieved and worst-second rate against the target, flagged under 90 %.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from scipy.signal import correlate, correlation_lags

from identify import Run
from signaldesign.information import d_efficiency, fisher_information

from .flightlog import CMD, LOW_RATE, frame_rate_warning

MAX_LAG = 1.5  # s: the latest a pilot's answer to a switch still counts as one


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
    lag: float = np.nan
    d_efficiency: float | None = None
    peak_ratio: float | None = None
    frame_rate: float | None = None
    frame_rate_lowest: float | None = None
    frame_rate_target: float | None = None
    per_axis: list[dict] = field(default_factory=list)

    @property
    def information_retained(self) -> float | None:
        """D-efficiency at the designed peak response: ``d_efficiency / peak_ratio**2``."""
        if self.d_efficiency is None or not self.peak_ratio:
            return None
        return self.d_efficiency / self.peak_ratio ** 2

    @property
    def frame_rate_low(self) -> bool:
        return self.frame_rate_target is not None and \
            min(self.frame_rate, self.frame_rate_lowest) < LOW_RATE * self.frame_rate_target

    def to_dict(self) -> dict:
        return {**asdict(self), "information_retained": self.information_retained,
                "frame_rate_low": self.frame_rate_low}

    def lines(self) -> list[str]:
        """Short lines for the end-of-run screen and the console; warnings start with ``!``."""
        if self.switches == self.missed:
            timing = f"switch timing        none of {self.switches} followed within {MAX_LAG:g} s"
        else:
            timing = (f"switch timing        {1000 * self.timing_mean:+5.0f} ms mean, {1000 * self.timing_std:4.0f} ms"
                      f" std ({self.missed} of {self.switches} missed)")
        out = ["Run score",
               f"RMS tracking error   {100 * self.rms:5.1f} % of amplitude", timing,
               f"lag (cross-corr.)    {1000 * self.lag:+5.0f} ms" if np.isfinite(self.lag) else
               "lag (cross-corr.)    - (the flown input never moved)",
               f"level error (+ / -)  {100 * self.level_error_pos:+5.1f} % / {100 * self.level_error_neg:+5.1f} %"
               f"  (asymmetry {100 * self.asymmetry:+5.1f} %)",
               f"spectral fidelity    {self.spectral_fidelity:5.3f}"]
        if self.information_retained is not None:
            out += [f"information retained {100 * self.information_retained:5.1f} % (at the designed peak response)",
                    f"peak response        {100 * self.peak_ratio:5.1f} % of the designed "
                    f"(raw D-efficiency {100 * self.d_efficiency:.1f} %)"]
            if self.peak_ratio > 1.05:
                out.append(f"! the flown input drove the aircraft {100 * (self.peak_ratio - 1):.0f} % beyond the "
                           "designed peak response (the limits assume the designed input)")
        if self.frame_rate_low:
            out.append("! " + frame_rate_warning({"rate_nominal": self.frame_rate_target,
                                                   "rate_achieved": self.frame_rate,
                                                   "rate_lowest_1s": self.frame_rate_lowest}))
        return out


def switch_timing(t: np.ndarray, flown: np.ndarray, signal, t_signal: np.ndarray | None = None,
                  max_lag: float = MAX_LAG) -> np.ndarray:
    """Timing error (s) at each switch of ``signal``; NaN where the flown input did not get halfway
    from the old level to the new one within ``max_lag`` s (see the module doc)."""
    ts = t if t_signal is None else t_signal
    sw = signal.switch_times()
    before = signal(sw - 1e-6)
    after = signal(sw + 1e-6)
    half, direction = 0.5 * (before + after), np.sign(after - before)
    errors = np.full(sw.size, np.nan)
    used = {}  # crossing (direction, halfway level) -> when an earlier switch's answer made it
    for i, s in enumerate(sw):
        key = (direction[i], round(half[i] / (abs(signal.amplitude) or 1.0), 9))
        hold = s - sw[i - 1] if i else max_lag
        end = s + max_lag
        # a later switch asking for the same crossing takes over: its crossing is not this one's,
        # nor is the one an earlier switch asking for the same crossing already had
        same = np.flatnonzero((direction[i + 1:] == direction[i]) & np.isclose(half[i + 1:], half[i]))
        if same.size:
            end = min(end, sw[i + 1 + same[0]])
        sel = np.flatnonzero((ts >= s - 0.5 * min(hold, max_lag)) & (ts > used.get(key, -np.inf)) & (ts <= end))
        if sel.size == 0:
            continue
        side = np.sign((flown[sel] - half[i]) * direction[i])  # -1 old side, +1 new side
        # only a crossing from the old side counts: sitting on the new side all along (a pilot who
        # never followed the previous level) is a miss, not a perfectly timed switch; nor does
        # leaving the halfway line itself (an answer to an earlier switch towards it)
        last_side = side[np.maximum.accumulate(np.where(side != 0, np.arange(side.size), 0))]  # 0: none yet
        cross = np.flatnonzero((side[1:] > 0) & (last_side[:-1] < 0)) + 1
        if cross.size:
            errors[i] = ts[sel[cross[0]]] - s
            used[key] = ts[sel[cross[0]]]
    return errors


def tracking_lag(designed: np.ndarray, flown: np.ndarray, dt: float, max_lag: float = MAX_LAG) -> float:
    """Delay (s) of ``flown`` behind ``designed`` (both (N,), sampled every ``dt`` s): the peak of
    their cross-correlation within +/- ``max_lag``, refined between samples by a parabola; NaN only
    when either input is constant (nothing to line up)."""
    d, f = designed - np.mean(designed), flown - np.mean(flown)
    if not (np.any(d) and np.any(f)):
        return np.nan
    c = correlate(f, d, mode="full")
    lags = correlation_lags(f.size, d.size, mode="full")
    keep = np.abs(lags) <= max_lag / dt
    c, lags = c[keep], lags[keep]
    k = int(np.argmax(c))
    shift = 0.0
    if 0 < k < c.size - 1:
        curv = c[k - 1] - 2 * c[k] + c[k + 1]
        shift = 0.5 * (c[k - 1] - c[k + 1]) / curv if curv < 0 else 0.0
    return float((lags[k] + shift) * dt)


def level_errors(ts: np.ndarray, flown: np.ndarray, signal, lag: float = 0.0) -> tuple[float, float, float]:
    """Settled level magnitude error on + and on - holds, and their difference (fractions of
    amplitude); each hold's settled second half taken ``lag`` s later (the pilot's lag)."""
    lag = float(lag) if np.isfinite(lag) and lag > 0 else 0.0
    if ts.size > 1:  # whole samples: a fraction of one would pull the next hold's first sample in
        step = float(np.median(np.diff(ts)))
        lag = round(lag / step) * step
    a = abs(signal.amplitude) or 1.0
    edges = np.concatenate([signal.switch_times(), [np.inf]])
    pos, neg = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        level = float(signal.level_at(lo + 1e-6))
        if level == 0 or not np.isfinite(hi):
            continue
        sel = (ts >= 0.5 * (lo + hi) + lag) & (ts < hi + lag)
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


def _inputs(model, run: Run, signals) -> tuple[np.ndarray, np.ndarray]:
    """Designed and flown inputs (N, m); profile inputs not flown stay zero."""
    names = model.profile.input_names
    u_design = np.zeros((len(run), len(names)))
    u_flown = np.zeros_like(u_design)
    for s in signals:
        j = names.index(s.input)
        u_design[:, j] = run[s.input + CMD]
        u_flown[:, j] = run[s.input]
    return u_design, u_flown


def information_retained(model, run: Run, signals) -> float:
    """Raw D-efficiency of the flown inputs relative to the designed ones for ``model``
    (LinearModel), over the parameters the design excites (see the module doc)."""
    u_design, u_flown = _inputs(model, run, signals)
    M_d = fisher_information(model, u_design, run.dt)
    M_f = fisher_information(model, u_flown, run.dt)
    d = np.diag(M_d)
    keep = d > 1e-10 * d.max()
    return d_efficiency(M_f[np.ix_(keep, keep)], M_d[np.ix_(keep, keep)])


def peak_ratio(model, run: Run, signals) -> float:
    """Largest output peak of the flown input's response over the designed input's (each output's
    peak over its limit; over the designed peak where the profile has no limit for it)."""
    from identify import simulate
    u_design, u_flown = _inputs(model, run, signals)
    y_d = np.abs(simulate(model, u_design, run.dt).y).max(axis=0)
    y_f = np.abs(simulate(model, u_flown, run.dt).y).max(axis=0)
    limits = np.array([model.profile.limits.get(y, np.nan) for y in model.profile.outputs])
    scale = np.where(np.isfinite(limits), limits, y_d)
    moved = scale > 0
    if not moved.any() or not (y_d[moved] > 0).any():
        return float("nan")
    return float((y_f[moved] / scale[moved]).max() / (y_d[moved] / scale[moved]).max())


def score_run(run: Run, signals, model=None, frame_stats: dict | None = None) -> PracticeScore:
    """Score a flown run against ``signals``; with ``model`` also the information retained, with
    ``frame_stats`` (:meth:`FrameLog.frame_stats`) the frame rate achieved."""
    t = run.time
    ts = run["t_signal"] if "t_signal" in run.channels else t
    axes = []
    for s in signals:
        a = abs(s.amplitude) or 1.0
        designed, flown = run[s.input + CMD], run[s.input]
        timing = switch_timing(t, flown, s, ts)
        lag = tracking_lag(designed, flown, run.dt)
        e_pos, e_neg, asym = level_errors(ts, flown, s, lag)
        axes.append({"input": s.input, "rms": float(np.sqrt(np.mean((flown - designed) ** 2)) / a),
                     "timing": timing.tolist(), "level_error_pos": e_pos, "level_error_neg": e_neg,
                     "asymmetry": asym, "lag": lag,
                     "spectral_fidelity": spectral_fidelity(designed, flown, run.dt, signal_band(s))})
    timing = np.concatenate([np.asarray(ax["timing"], float) for ax in axes])
    hit = timing[np.isfinite(timing)]
    mean = lambda key: _nanmean([ax[key] for ax in axes])  # noqa: E731
    return PracticeScore(rms=mean("rms"), timing_mean=float(np.mean(hit)) if hit.size else np.nan,
                 timing_std=float(np.std(hit)) if hit.size else np.nan,
                 timing_max=float(np.max(np.abs(hit))) if hit.size else np.nan,
                 switches=int(timing.size), missed=int(np.sum(~np.isfinite(timing))),
                 level_error_pos=mean("level_error_pos"), level_error_neg=mean("level_error_neg"),
                 asymmetry=mean("asymmetry"), spectral_fidelity=mean("spectral_fidelity"), lag=mean("lag"),
                 d_efficiency=information_retained(model, run, signals) if model is not None else None,
                 peak_ratio=peak_ratio(model, run, signals) if model is not None else None,
                 per_axis=axes, **_frame_rates(frame_stats))


def _nanmean(values) -> float:
    values = np.asarray(values, float)
    return float(np.mean(values[np.isfinite(values)])) if np.isfinite(values).any() else np.nan


def _frame_rates(stats: dict | None) -> dict:
    if not stats or "rate_nominal" not in stats:
        return {}
    return {"frame_rate": stats["rate_achieved"], "frame_rate_lowest": stats["rate_lowest_1s"],
            "frame_rate_target": stats["rate_nominal"]}

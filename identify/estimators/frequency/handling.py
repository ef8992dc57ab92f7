"""Handling qualities from an attitude frequency response: ADS-33 bandwidth and phase delay, the chart.

ADS-33E-PRF's small-amplitude attitude criterion (Tischler & Remple ch. 3 and 15) reads two numbers
off the Bode plot of attitude per control (``theta/theta_s``, ``phi/theta_c``):

* ``omega_180``: the frequency where the phase crosses -180 deg;
* phase-margin bandwidth ``omega_BW_phase``: the phase crosses -135 deg (45 deg of phase margin);
* gain-margin bandwidth ``omega_BW_gain``: the gain has risen 6 dB above its value at ``omega_180``
  (the frequency where it is |H(omega_180)| x 2);
* bandwidth ``omega_BW``: the lesser of the two (rate response types; for attitude-command types the
  specification takes the phase bandwidth, and a gain bandwidth below it marks a PIO tendency --
  both are reported);
* phase delay ``tau_p = -(phase(2 omega_180) + 180 deg) / (2 omega_180)`` (phase in rad): how fast
  the phase rolls off beyond the crossover, the effect of delays and high-order lags.

The inputs are arrays (``omega`` rad/s, complex ``H``, optional ``coherence``), so the figures come
equally from flight data or from a model's response. Only frequencies with an estimate (finite H)
and, when a coherence is given, coherence >= ``min_coherence`` are read; a crossing the data do not
reach is "not determined" (NaN and a reason), never extrapolated. Crossings are interpolated
linearly in log frequency between the two points that bracket them.

Level boundaries (:data:`ADS33_BOUNDARIES`): the corner points of the hover/low-speed pitch and roll
charts, simplified to their rectangular corners (minimum bandwidth, maximum phase delay per level);
the sloped high-bandwidth parts of the original charts are not drawn. **Every corner value is
UNVERIFIED** (:data:`ADS33_UNVERIFIED`): written from memory of Tischler & Remple's reproductions
of ADS-33E-PRF's hover/low-speed bandwidth charts (para. 3.3.2.1, a number also from memory), not
checked against ADS-33E-PRF itself. The public references searched (docs, pages and code corpora,
Nov 2026: ADS-33E-PRF's table of contents is public, its charts' values were not found, nor open
code that encodes them) could not confirm them; every level read from them says so on screen, in
``hq.md`` and on the chart.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

MIN_COHERENCE = 0.6

# task category -> axis -> ((Level 1 min bandwidth rad/s, max phase delay s), (Level 2 ...))
ADS33_BOUNDARIES = {
    "tracking": {"pitch": ((2.0, 0.14), (1.0, 0.24)), "roll": ((2.5, 0.12), (1.5, 0.20))},
    "other": {"pitch": ((2.0, 0.20), (1.0, 0.30)), "roll": ((2.0, 0.20), (1.0, 0.30))},
}
TASK_NAMES = {"tracking": "target acquisition and tracking", "other": "all other MTEs (UCE 1, fully attended)"}
# (task, axis) whose corners were not checked against ADS-33E-PRF: all of them (see the module notes);
# a pair leaves this set only with the specification's figure cited beside its values above
ADS33_UNVERIFIED = frozenset((task, axis) for task, axes in ADS33_BOUNDARIES.items() for axis in axes)


def boundary_status(axis: str, task: str = "tracking") -> str:
    """"" for boundaries checked against the specification, else the marker every level read from
    them carries."""
    return "UNVERIFIED boundaries" if (task, axis) in ADS33_UNVERIFIED else ""


@dataclass
class Bandwidth:
    """ADS-33 bandwidth figures of one attitude response (rad/s, s); NaN where not determined,
    with the reasons in ``notes``."""

    omega_180: float
    omega_bw_phase: float
    omega_bw_gain: float
    phase_delay: float
    sign_inverted: bool = False
    notes: list[str] = field(default_factory=list)
    # when the phase is past -135 deg already at the lowest usable frequency: the bandwidth lies below it
    bandwidth_below: float = float("nan")

    @property
    def bandwidth(self) -> float:
        """The lesser of the phase and gain bandwidths (NaN if the phase bandwidth is not determined;
        the phase bandwidth alone if the gain one cannot be had because omega_180 is not reached)."""
        if not np.isfinite(self.omega_bw_phase):
            return float("nan")
        return float(np.nanmin([self.omega_bw_phase, self.omega_bw_gain]))

    @property
    def gain_limited(self) -> bool:
        return bool(np.isfinite(self.omega_bw_gain) and self.omega_bw_gain < self.omega_bw_phase)

    def level(self, axis: str, task: str = "tracking") -> int | None:
        """ADS-33 level (1, 2 or 3) of (bandwidth, phase delay); None if either is not determined,
        except Level 3 when the bandwidth is known to lie below the Level 2 minimum."""
        if np.isfinite(self.bandwidth_below) and self.bandwidth_below < _boundaries(axis, task)[1][0]:
            return 3
        return ads33_level(self.bandwidth, self.phase_delay, axis, task)

    def to_dict(self) -> dict:
        return {"omega_180": self.omega_180, "omega_bw_phase": self.omega_bw_phase,
                "omega_bw_gain": self.omega_bw_gain, "bandwidth": self.bandwidth,
                "phase_delay": self.phase_delay, "gain_limited": self.gain_limited,
                "sign_inverted": self.sign_inverted, "bandwidth_below": self.bandwidth_below,
                "notes": list(self.notes)}


def bandwidth(omega: np.ndarray, H: np.ndarray, coherence: np.ndarray | None = None,
              min_coherence: float = MIN_COHERENCE) -> Bandwidth:
    """ADS-33 bandwidth and phase delay of an attitude response ``H`` (nf,) at ``omega`` (nf,) rad/s.

    A response whose low-frequency phase starts near +90 deg (a negative control sign convention)
    is read as ``-H`` and ``sign_inverted`` says so.
    """
    omega, H = np.asarray(omega, dtype=float), np.asarray(H, dtype=complex)
    use = np.isfinite(H) & (np.abs(H) > 0)
    if coherence is not None:
        use &= np.asarray(coherence) >= min_coherence
    notes = []
    if use.sum() < 2:
        return Bandwidth(*[float("nan")] * 4, notes=["fewer than 2 usable frequencies"])
    w, h = omega[use], H[use]
    phase = np.degrees(np.unwrap(np.angle(h)))
    # the branch and the sign from the middle of the band (in log frequency), where an attitude
    # response lags by 90-270 deg; its low end may be ruled by slow (even unstable) modes
    mid = int(np.argmin(np.abs(np.log(w) - 0.5 * (np.log(w[0]) + np.log(w[-1])))))
    phase -= 360 * np.floor((phase[mid] + 270) / 360)  # middle point in [-270, 90)
    inverted = bool(phase[mid] > -45)  # a leading attitude response: a sign convention
    if inverted:
        phase -= 180
        notes.append("response sign inverted (negative control gain convention)")
    gain_db = 20 * np.log10(np.abs(h))
    w180 = _crossing(w, phase, -180.0)
    w135 = _crossing(w, phase, -135.0)
    below = float("nan")
    if not np.isfinite(w135):
        if -180 < phase[0] < -135:  # between the bandwidth and omega_180 already (lower: a slow mode's branch)
            below = float(w[0])
            notes.append(f"phase already past -135 deg at the lowest usable frequency {w[0]:.3g} rad/s: "
                         f"the phase bandwidth lies below it (not determined further)")
        elif phase[0] <= -180:
            notes.append(f"phase already past -180 deg at the lowest usable frequency {w[0]:.3g} rad/s: "
                         "the crossovers lie below the data (or a slow mode's phase hides them): not determined")
        else:
            notes.append(f"phase does not fall through -135 deg within {w[0]:.3g}..{w[-1]:.3g} rad/s: "
                         "phase bandwidth not determined")
    if not np.isfinite(w180):
        notes.append(f"phase does not fall through -180 deg within {w[0]:.3g}..{w[-1]:.3g} rad/s: "
                     "gain bandwidth and phase delay not determined")
        return Bandwidth(float("nan"), w135, float("nan"), float("nan"), inverted, notes, below)
    g180 = _interp_log(w180, w, gain_db)
    w_gain = _crossing(w, gain_db, g180 + 6.0)
    if not np.isfinite(w_gain):
        notes.append("gain does not rise 6 dB above its value at omega_180 in the data: "
                     "gain bandwidth not determined")
    if 2 * w180 > w[-1]:
        notes.append(f"2 x omega_180 = {2 * w180:.3g} rad/s lies beyond the usable data "
                     f"(<= {w[-1]:.3g} rad/s): phase delay not determined")
        tau = float("nan")
    else:
        tau = float(-np.radians(_interp_log(2 * w180, w, phase) + 180.0) / (2 * w180))
    return Bandwidth(w180, w135, w_gain, tau, inverted, notes, below)


def _crossing(w: np.ndarray, y: np.ndarray, level: float) -> float:
    """The lowest frequency where y falls through ``level`` (from above), linear in log w; NaN if
    none. A rise through it (a slow mode's phase lead) is not a crossover."""
    d = y - level
    idx = np.nonzero((d[:-1] > 0) & (d[1:] <= 0))[0]
    if idx.size == 0:
        return float("nan")
    k = idx[0]
    a = d[k] / (d[k] - d[k + 1])
    return float(np.exp(np.log(w[k]) + a * (np.log(w[k + 1]) - np.log(w[k]))))


def _interp_log(w0: float, w: np.ndarray, y: np.ndarray) -> float:
    return float(np.interp(np.log(w0), np.log(w), y))


def ads33_level(omega_bw: float, tau_p: float, axis: str, task: str = "tracking") -> int | None:
    """Level 1, 2 or 3 of a (bandwidth rad/s, phase delay s) point on the simplified ADS-33 chart
    (:data:`ADS33_BOUNDARIES`); None when either figure is not determined."""
    if not (np.isfinite(omega_bw) and np.isfinite(tau_p)):
        return None
    for level, (w_min, tau_max) in enumerate(_boundaries(axis, task), start=1):
        if omega_bw >= w_min and tau_p <= tau_max:
            return level
    return 3


def _boundaries(axis: str, task: str):
    try:
        return ADS33_BOUNDARIES[task][axis]
    except KeyError:
        raise ValueError(f"no ADS-33 boundaries for axis '{axis}', task '{task}' "
                         f"(axes pitch, roll; tasks {', '.join(ADS33_BOUNDARIES)})") from None


def ads33_chart(points: dict[str, Bandwidth], axis: str, task: str = "tracking"):
    """The ADS-33 bandwidth vs phase-delay chart of ``axis`` for ``task`` with ``points``
    ({label: Bandwidth}) plotted; an Agg :class:`matplotlib.figure.Figure` (no pyplot state).
    Points not determined are listed in the legend as such instead of being drawn."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.6))
    ax = fig.add_subplot(1, 1, 1)
    (w1, t1), (w2, t2) = _boundaries(axis, task)
    w_hi, t_hi = 6.0, 0.4
    for pts in points.values():
        if np.isfinite(pts.bandwidth):
            w_hi = max(w_hi, 1.1 * pts.bandwidth)
        if np.isfinite(pts.phase_delay):
            t_hi = max(t_hi, 1.1 * pts.phase_delay)
    ax.fill_between([w1, w_hi], 0, t1, color="#d8f0d8", lw=0)
    ax.plot([w1, w1, w_hi], [0, t1, t1], "k-", lw=1.2)
    ax.plot([w2, w2, w_hi], [0, t2, t2], "k--", lw=1.2)
    ax.text(0.5 * (w1 + w_hi), 0.5 * t1, "Level 1", ha="center", va="center")
    ax.text(0.5 * (w2 + w1), 0.5 * t1, "Level 2", ha="center", va="center")
    ax.text(0.5 * w2, 0.5 * t2, "Level 3", ha="center", va="center")
    for k, ((label, b), marker) in enumerate(zip(points.items(), "o^sDv>")):
        colour = ("C3", "C0", "C2", "C4", "C1", "C5")[k]
        if np.isfinite(b.bandwidth) and np.isfinite(b.phase_delay):
            lvl = b.level(axis, task)
            ax.plot(b.bandwidth, b.phase_delay, marker, ms=9, mfc=colour, mec="k",
                    label=f"{label}: {b.bandwidth:.2f} rad/s, {b.phase_delay:.3f} s (Level {lvl})")
        elif np.isfinite(b.bandwidth_below) and np.isfinite(b.phase_delay):
            ax.plot(b.bandwidth_below, b.phase_delay, "<", ms=9, mfc=colour, mec="k",
                    label=f"{label}: < {b.bandwidth_below:.2f} rad/s, {b.phase_delay:.3f} s "
                          f"(Level {b.level(axis, task) or '?'})")
        else:
            ax.plot([], [], marker, mfc="none", mec="0.5", label=f"{label}: not determined")
    ax.set_xlim(0, w_hi)
    ax.set_ylim(0, t_hi)
    ax.set_xlabel("bandwidth $\\omega_{BW}$ [rad/s]")
    ax.set_ylabel("phase delay $\\tau_p$ [s]")
    status = boundary_status(axis, task)
    ax.set_title(f"ADS-33 {axis} attitude, hover/low speed: {TASK_NAMES.get(task, task)}"
                 + (f"\n{status}: corners not checked against ADS-33E-PRF" if status else ""), fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(True, color="0.9")
    fig.tight_layout()
    return fig

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

User-supplied boundaries (:func:`load_boundaries`, ``identify hq --boundaries FILE.json``): the Level
1 and Level 2 boundaries per task category and axis as polylines of (bandwidth rad/s, phase delay s)
points read from the specification's figure, with the figure named in a required ``source``. A
polyline ``(w_1, t_1) ... (w_n, t_n)`` must be monotone: bandwidth and phase delay both non-decreasing
from point to point (no point repeated), so it runs up and to the right as the charts' boundaries do,
and the Level 1 one must lie on the good side of the Level 2 one. It bounds the region of points
(w, t) with ``t <= t_B(w)``, where ``t_B(w)`` is:

* below ``w_1``: none (the boundary starts with a vertical line from (w_1, 0) up to its first point);
* between points: linear interpolation in (w, t) along the segment reaching past ``w``; at a vertical
  segment (two points at the same bandwidth), its top;
* beyond ``w_n``: ``t_n`` (the last segment continues horizontally to any higher bandwidth).

A point on the boundary counts as inside (as the built-in corners' ``>=`` and ``<=``). Level 1: inside
the Level 1 boundary; else Level 2: inside the Level 2 one; else Level 3. The built-in corners are the
two-point polylines ``(w_min, 0), (w_min, t_max)``. Levels read from a user file carry "boundaries:
<source> (user-supplied)" instead of UNVERIFIED; the report records the file and its source.
"""
from __future__ import annotations

import json
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

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


@dataclass(frozen=True)
class Boundaries:
    """ADS-33 Level 1 and Level 2 boundaries: ``polylines[(task, axis)] = (level 1, level 2)``, each an
    (n, 2) array of (bandwidth rad/s, phase delay s) points (see the module notes for how a point is
    graded); ``source`` where the values come from; ``path`` the file read (None: built in)."""

    polylines: dict
    source: str
    path: str | None = None

    @property
    def user_supplied(self) -> bool:
        return self.path is not None

    def pair(self, axis: str, task: str) -> tuple[np.ndarray, np.ndarray]:
        try:
            return self.polylines[(task, axis)]
        except KeyError:
            have = ", ".join(f"{t}/{a}" for t, a in self.polylines)
            raise ValueError(f"no ADS-33 boundaries for task '{task}', axis '{axis}' in {self.where()} "
                             f"(it has {have})") from None

    def level(self, omega_bw: float, tau_p: float, axis: str, task: str = "tracking") -> int | None:
        """Level 1, 2 or 3 of a (bandwidth, phase delay) point; None when either is not determined."""
        if not (np.isfinite(omega_bw) and np.isfinite(tau_p)):
            return None
        for level, line in enumerate(self.pair(axis, task), start=1):
            if tau_p <= delay_limit(line, omega_bw):
                return level
        return 3

    def status(self, axis: str, task: str = "tracking") -> str:
        """The marker every level read from these boundaries carries: UNVERIFIED (built-in corners not
        checked) or the user's source; "" for built-in boundaries checked against the specification."""
        if self.user_supplied:
            return f"boundaries: {self.source} (user-supplied)"
        return "UNVERIFIED boundaries" if (task, axis) in ADS33_UNVERIFIED else ""

    def where(self) -> str:
        return f"the boundaries file {self.path}" if self.user_supplied else "the built-in boundaries"

    def to_dict(self) -> dict:
        return {"source": self.source, "path": self.path, "user_supplied": self.user_supplied,
                "boundaries": {f"{t}/{a}": {"level1": l1.tolist(), "level2": l2.tolist()}
                               for (t, a), (l1, l2) in self.polylines.items()}}


def delay_limit(line: np.ndarray, omega: float) -> float:
    """The largest phase delay inside a monotone boundary polyline at bandwidth ``omega`` (-inf below
    its first point's bandwidth; its last point's delay beyond its last bandwidth)."""
    w, t = line[:, 0], line[:, 1]
    k = int(np.searchsorted(w, omega, side="right")) - 1  # the last point at or below omega
    if k < 0:
        return -np.inf
    if k == len(w) - 1:
        return float(t[-1])
    return float(t[k] + (t[k + 1] - t[k]) * (omega - w[k]) / (w[k + 1] - w[k]))


BUILTIN_BOUNDARIES = Boundaries(
    {(task, axis): tuple(np.array([[w, 0.0], [w, t]]) for w, t in corners)
     for task, axes in ADS33_BOUNDARIES.items() for axis, corners in axes.items()},
    "memory of Tischler & Remple's reproductions of ADS-33E-PRF's hover/low-speed charts (UNVERIFIED)")


def load_boundaries(path: str | Path) -> Boundaries:
    """User-supplied ADS-33 boundaries from a JSON file::

        {"source": "ADS-33E-PRF Figure 2, para 3.3.2.1",
         "boundaries": {"tracking": {"pitch": {"level1": [[w, t], ...], "level2": [[w, t], ...]},
                                     "roll": {...}},
                        "other": {...}}}

    Tasks among :data:`TASK_NAMES`, axes pitch and roll (any subset; a report needing one the file
    lacks fails); every polyline monotone (module notes), Level 1 inside Level 2. Anything else is
    refused with the reason (ValueError), never replaced by the built-in values."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"boundaries file {path}: {exc}") from None
    where = f"boundaries file {path}"
    _keys(doc, {"source", "boundaries"}, where)
    source = doc["source"]
    if not isinstance(source, str) or not source.strip():
        raise ValueError(f"{where}: 'source' must name where the values were read (e.g. the specification's "
                         "figure and paragraph)")
    polylines = {}
    _keys(doc["boundaries"], set(TASK_NAMES), f"{where}: boundaries", required=False)
    for task, axes in doc["boundaries"].items():
        _keys(axes, {"pitch", "roll"}, f"{where}: boundaries.{task}", required=False)
        for axis, levels in axes.items():
            at = f"{where}: boundaries.{task}.{axis}"
            _keys(levels, {"level1", "level2"}, at)
            pair = tuple(_polyline(levels[k], f"{at}.{k}") for k in ("level1", "level2"))
            _inside(*pair, at)
            polylines[(task, axis)] = pair
    if not polylines:
        raise ValueError(f"{where}: no boundaries given")
    return Boundaries(polylines, source.strip(), str(path))


def _keys(obj, allowed: set, where: str, required: bool = True) -> None:
    if not isinstance(obj, dict):
        raise ValueError(f"{where}: expected an object with keys {', '.join(sorted(allowed))}")
    unknown = set(obj) - allowed
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (allowed: {', '.join(sorted(allowed))})")
    missing = allowed - set(obj) if required else set()
    if missing:
        raise ValueError(f"{where}: missing key(s) {', '.join(sorted(missing))}")


def _polyline(points, where: str) -> np.ndarray:
    """A validated (n, 2) boundary polyline: finite, non-negative, monotone, no point repeated."""
    if not isinstance(points, list) or not points or not all(
            isinstance(p, list) and len(p) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                        for v in p) for p in points):
        raise ValueError(f"{where}: expected a non-empty list of [bandwidth rad/s, phase delay s] pairs")
    line = np.array(points, dtype=float)
    if not np.all(np.isfinite(line)) or np.any(line < 0):
        raise ValueError(f"{where}: bandwidths and phase delays must be finite and >= 0")
    for k in range(1, len(line)):
        (w0, t0), (w1, t1) = line[k - 1], line[k]
        if w1 < w0 or t1 < t0:
            raise ValueError(f"{where}: point {k} ({w1:g} rad/s, {t1:g} s) goes back from point {k - 1} "
                             f"({w0:g} rad/s, {t0:g} s): a boundary polyline must be monotone (bandwidth and "
                             "phase delay non-decreasing)")
        if w1 == w0 and t1 == t0:
            raise ValueError(f"{where}: point {k} repeats point {k - 1} ({w0:g} rad/s, {t0:g} s)")
    return line


def _inside(level1: np.ndarray, level2: np.ndarray, where: str) -> None:
    """The Level 1 region must lie inside the Level 2 one: its delay limit nowhere above Level 2's.
    Both limits are linear between the bandwidths of their points, so those bandwidths and points
    just below each suffice."""
    grid = np.unique(np.concatenate([level1[:, 0], level2[:, 0]]))
    for w in np.concatenate([grid, grid * (1 - 1e-9)]):
        t1, t2 = delay_limit(level1, w), delay_limit(level2, w)
        if t1 > t2 + 1e-12:
            raise ValueError(f"{where}: at {w:.4g} rad/s the Level 1 boundary allows a phase delay of {t1:.4g} s, "
                             f"more than Level 2's {'none' if t2 == -np.inf else f'{t2:.4g} s'}: the Level 1 "
                             "region must lie inside the Level 2 one")


def boundary_status(axis: str, task: str = "tracking", boundaries: Boundaries | None = None) -> str:
    """The marker every level read from the boundaries carries ("" for built-in boundaries checked
    against the specification): see :meth:`Boundaries.status`."""
    return (boundaries or BUILTIN_BOUNDARIES).status(axis, task)


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

    def level(self, axis: str, task: str = "tracking", boundaries: Boundaries | None = None) -> int | None:
        """ADS-33 level (1, 2 or 3) of (bandwidth, phase delay); None if either is not determined,
        except Level 3 when the bandwidth is known to lie below the Level 2 boundary's least bandwidth."""
        b = boundaries or BUILTIN_BOUNDARIES
        if np.isfinite(self.bandwidth_below) and self.bandwidth_below < b.pair(axis, task)[1][0, 0]:
            return 3
        return b.level(self.bandwidth, self.phase_delay, axis, task)

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


def ads33_level(omega_bw: float, tau_p: float, axis: str, task: str = "tracking",
                boundaries: Boundaries | None = None) -> int | None:
    """Level 1, 2 or 3 of a (bandwidth rad/s, phase delay s) point on the ADS-33 chart (the built-in
    corners :data:`ADS33_BOUNDARIES` unless ``boundaries``); None when either figure is not determined."""
    return (boundaries or BUILTIN_BOUNDARIES).level(omega_bw, tau_p, axis, task)


def ads33_chart(points: dict[str, Bandwidth], axis: str, task: str = "tracking", boundaries: Boundaries | None = None):
    """The ADS-33 bandwidth vs phase-delay chart of ``axis`` for ``task`` with ``points``
    ({label: Bandwidth}) plotted on the boundaries' polylines (built-in corners unless ``boundaries``);
    an Agg :class:`matplotlib.figure.Figure` (no pyplot state). Points not determined are listed in the
    legend as such instead of being drawn."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.6))
    ax = fig.add_subplot(1, 1, 1)
    bounds = boundaries or BUILTIN_BOUNDARIES
    line1, line2 = bounds.pair(axis, task)
    w_hi = max(6.0, 1.1 * max(line1[-1, 0], line2[-1, 0]))
    t_hi = max(0.4, 1.25 * max(line1[-1, 1], line2[-1, 1]))
    for pts in points.values():
        if np.isfinite(pts.bandwidth):
            w_hi = max(w_hi, 1.1 * pts.bandwidth)
        if np.isfinite(pts.phase_delay):
            t_hi = max(t_hi, 1.1 * pts.phase_delay)
    (x1, y1), (x2, y2) = (_drawn(line, w_hi) for line in (line1, line2))
    ax.fill_between(x1, 0, y1, color="#d8f0d8", lw=0)
    ax.plot(x1, y1, "k-", lw=1.2)
    ax.plot(x2, y2, "k--", lw=1.2)
    w1, w2 = line1[0, 0], line2[0, 0]
    ax.text(0.5 * (w1 + w_hi), 0.5 * delay_limit(line1, 0.5 * (w1 + w_hi)), "Level 1", ha="center", va="center")
    ax.text(0.5 * (w2 + w1), 0.5 * delay_limit(line2, 0.5 * (w2 + w1)), "Level 2", ha="center", va="center")
    ax.text(0.5 * w2, 0.5 * line2[-1, 1], "Level 3", ha="center", va="center")
    for k, ((label, b), marker) in enumerate(zip(points.items(), "o^sDv>")):
        colour = ("C3", "C0", "C2", "C4", "C1", "C5")[k]
        if np.isfinite(b.bandwidth) and np.isfinite(b.phase_delay):
            lvl = b.level(axis, task, bounds)
            ax.plot(b.bandwidth, b.phase_delay, marker, ms=9, mfc=colour, mec="k",
                    label=f"{label}: {b.bandwidth:.2f} rad/s, {b.phase_delay:.3f} s (Level {lvl})")
        elif np.isfinite(b.bandwidth_below) and np.isfinite(b.phase_delay):
            ax.plot(b.bandwidth_below, b.phase_delay, "<", ms=9, mfc=colour, mec="k",
                    label=f"{label}: < {b.bandwidth_below:.2f} rad/s, {b.phase_delay:.3f} s "
                          f"(Level {b.level(axis, task, bounds) or '?'})")
        else:
            ax.plot([], [], marker, mfc="none", mec="0.5", label=f"{label}: not determined")
    ax.set_xlim(0, w_hi)
    ax.set_ylim(0, t_hi)
    ax.set_xlabel("bandwidth $\\omega_{BW}$ [rad/s]")
    ax.set_ylabel("phase delay $\\tau_p$ [s]")
    status = bounds.status(axis, task)
    if status and not bounds.user_supplied:
        status += ": corners not checked against ADS-33E-PRF"
    ax.set_title("\n".join([f"ADS-33 {axis} attitude, hover/low speed: {TASK_NAMES.get(task, task)}",
                            *textwrap.wrap(status, 75)]), fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(True, color="0.9")
    fig.tight_layout()
    return fig


def _drawn(line: np.ndarray, w_hi: float) -> tuple[np.ndarray, np.ndarray]:
    """A boundary polyline as drawn: from the bandwidth axis up to its first point, through its
    points, on horizontally to ``w_hi``."""
    x, y = line[:, 0], line[:, 1]
    if y[0] > 0:
        x, y = np.r_[x[0], x], np.r_[0.0, y]
    return np.r_[x, max(w_hi, x[-1])], np.r_[y, y[-1]]

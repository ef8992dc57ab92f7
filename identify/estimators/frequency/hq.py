"""``identify hq``: handling-qualities figures of runs or of a model, as markdown and PNG.

Per attitude axis (pitch: the longitudinal control, roll: the lateral one) the attitude response is
read from the rate response, ``theta/delta = (q/delta) / (jw)`` (hover and low speed: the attitude
rate is the body rate to first order), the rate being measured with less drift than the attitude
(an attitude channel carries the unstable modes' slow divergence, which no window removes); without
a rate output the attitude output itself is used. From it :func:`.handling.bandwidth` gives the
ADS-33 bandwidth and phase delay, plotted on the chart of the chosen task category. The pitch-rate
response is also fitted by a short-period LOES ``K (s + 1/T_theta2) e^{-tau s} / (s^2 + 2 zeta omega s +
omega^2)`` over 1-10 rad/s (MIL-STD-1797A's 0.1-10 rad/s above the phugoid, which this form has
not) with its level; a LOES that does not fit
(J > 100: no short-period-like response, as in hover) is reported as such.

From runs the responses are the composite estimates (points with coherence >= 0.6 only); from a
model, its exact response on a dense grid (declared delays included).

What is graded depends on the aircraft (:class:`Aircraft`: its class and flight phase, given, read
from the profile's ``[meta]`` ``aircraft_class`` / ``flight_phase``, or guessed from the control
names and said): ADS-33's bandwidth chart only for a rotorcraft in hover and low speed (the charts
built in and the ``--boundaries`` files are those), MIL-STD-1797A's short period for every class in
the flight-phase category (A: rapid manoeuvring and tracking, B: cruise, climb, descent, C: take-off,
approach, landing). A transport in cruise is never graded on the hover chart: its bandwidth and
phase delay are reported, not graded.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import EstimationError
from ...model.linear import LinearModel
from .handling import BUILTIN_BOUNDARIES, TASK_NAMES, Bandwidth, Boundaries, ads33_chart, bandwidth, load_boundaries
from .loes import ShortPeriod, fit_transfer_function, short_period

# flight phase -> (aircraft class, MIL-STD-1797A flight-phase category; None: not a MIL-STD-1797A phase)
PHASES = {"hover": ("rotorcraft", None), "low-speed": ("rotorcraft", None), "forward": ("rotorcraft", None),
          "tracking": ("fixed-wing", "A"), "combat": ("fixed-wing", "A"), "climb": ("fixed-wing", "B"),
          "cruise": ("fixed-wing", "B"), "loiter": ("fixed-wing", "B"), "descent": ("fixed-wing", "B"),
          "takeoff": ("fixed-wing", "C"), "approach": ("fixed-wing", "C"), "landing": ("fixed-wing", "C")}
CLASSES = ("rotorcraft", "fixed-wing")
ROTOR_CONTROLS = ("theta_s", "theta_c", "theta_0", "theta_1s", "theta_1c", "theta_tr", "theta_p")
FIXED_WING_CONTROLS = ("delta_e", "delta_a", "delta_r", "delta_t", "delta_f")
AXES = {"pitch": (("theta_s", "delta_e"), "q", "theta"), "roll": (("theta_c", "delta_a"), "p", "phi")}
LOES_RANGE = (1.0, 10.0)  # rad/s: MIL-STD-1797A's 0.1-10 above the phugoid, which the 2nd-order form lacks


@dataclass(frozen=True)
class Aircraft:
    """Who is graded: ``kind`` (rotorcraft or fixed-wing), flight ``phase`` (a key of :data:`PHASES`,
    or None), MIL-STD-1797A ``category``; ``notes`` say what was guessed or assumed."""

    kind: str
    phase: str | None
    category: str
    notes: tuple[str, ...] = ()

    @property
    def ads33(self) -> bool:
        """Graded on ADS-33's hover and low-speed bandwidth charts: a rotorcraft there."""
        return self.kind == "rotorcraft" and self.phase in ("hover", "low-speed")

    def line(self) -> str:
        grading = ("ADS-33 hover and low-speed bandwidth" if self.ads33 else
                   f"ADS-33 bandwidth charts not applied ({self.kind}" + (f" in {self.phase}" if self.phase else "")
                   + ": they are a rotorcraft's in hover and low speed)")
        return f"{self.kind}, {self.phase or 'flight phase not given'}: {grading}; MIL-STD-1797A category {self.category}"


def aircraft_of(inputs, meta: dict | None = None, kind: str | None = None, phase: str | None = None,
                category: str | None = None) -> Aircraft:
    """The :class:`Aircraft`: ``kind`` and ``phase`` as given, else the profile's ``meta``
    (``aircraft_class``, ``flight_phase``), a phase's class, or the class the control names say
    (guessed, said); ``category`` as given, else the phase's, else A (said)."""
    meta, notes = meta or {}, []
    kind, phase = kind or meta.get("aircraft_class"), phase or meta.get("flight_phase")
    if kind is not None and kind not in CLASSES:
        raise EstimationError(f"aircraft class must be one of {', '.join(CLASSES)}, got '{kind}'")
    if phase is not None and phase not in PHASES:
        raise EstimationError(f"flight phase must be one of {', '.join(PHASES)}, got '{phase}'")
    if phase is not None and kind is not None and PHASES[phase][0] != kind:
        raise EstimationError(f"flight phase '{phase}' is not a {kind}'s (phases of {kind}: "
                              f"{', '.join(k for k, v in PHASES.items() if v[0] == kind)})")
    if kind is None and phase is not None:
        kind = PHASES[phase][0]
    if kind is None:
        rotor = [u for u in inputs if u in ROTOR_CONTROLS]
        fixed = [u for u in inputs if u in FIXED_WING_CONTROLS]
        if bool(rotor) == bool(fixed):
            raise EstimationError(f"aircraft class not given and not told by the controls ({', '.join(inputs)}): "
                                  f"give --aircraft-class ({', '.join(CLASSES)}) or [meta] aircraft_class")
        kind = "rotorcraft" if rotor else "fixed-wing"
        notes.append(f"aircraft class {kind} guessed from the controls ({', '.join(rotor or fixed)}): "
                     "give --aircraft-class or [meta] aircraft_class")
    if kind == "rotorcraft" and phase is None:
        phase = "hover"
        notes.append("rotorcraft flight phase not given: hover and low speed assumed (--phase)")
    if category is None:
        category = (PHASES[phase][1] if phase else None) or "A"
        if not (phase and PHASES[phase][1]):
            notes.append("MIL-STD-1797A category A assumed (give --category or a fixed-wing --phase)")
    return Aircraft(kind, phase, category, tuple(notes))


@dataclass
class AxisHQ:
    axis: str
    input: str
    response: str  # how the attitude response was had
    bandwidth: Bandwidth
    loes: ShortPeriod | None = None
    loes_note: str = ""


@dataclass
class HQReport:
    """Handling-qualities figures per axis, the task category, the source and the ADS-33 boundaries
    graded against (their provenance: ``boundaries.source``, ``boundaries.path``)."""

    source: str
    task: str
    axes: list[AxisHQ] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    boundaries: Boundaries = BUILTIN_BOUNDARIES
    aircraft: Aircraft = Aircraft("rotorcraft", "hover", "A")

    def markdown(self) -> str:
        bounds = self.boundaries
        if bounds.user_supplied:
            about = f"boundaries: {bounds.source} (user-supplied, read from {bounds.path}))."
        else:
            about = "simplified corner boundaries, see docs/frequency.md)." + (
                " **UNVERIFIED boundaries**: the corner values were not checked against ADS-33E-PRF; "
                "a level near a boundary may be wrong." if any(bounds.status(a.axis, self.task) for a in self.axes) else "")
        lines = [f"# Handling qualities: {self.source}", "", f"Aircraft: {self.aircraft.line()}.", "",
                 (f"ADS-33 task category: {TASK_NAMES.get(self.task, self.task)} (hover and low speed; " + about
                  if self.aircraft.ads33 else "ADS-33 level: not graded (see the aircraft above)."), "",
                 "| axis | response | omega_180 [rad/s] | BW phase [rad/s] | BW gain [rad/s] | bandwidth [rad/s] "
                 "| phase delay [s] | ADS-33 level |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for a in self.axes:
            b = a.bandwidth
            lvl = b.level(a.axis, self.task, self.boundaries)
            lines.append(f"| {a.axis} | {a.response} | {_f(b.omega_180)} | {_f(b.omega_bw_phase)} | "
                         f"{_f(b.omega_bw_gain)} | "
                         f"{_f(b.bandwidth) if not np.isfinite(b.bandwidth_below) else f'< {b.bandwidth_below:.3g}'} | "
                         f"{_f(b.phase_delay, 4)} | "
                         f"{self._level(lvl, a.axis)} |")
        for a in self.axes:
            for n in a.bandwidth.notes:
                lines.append(f"- {a.axis}: {n}")
        lines += ["", "## Short-period LOES (pitch rate)", ""]
        for a in self.axes:
            if a.axis != "pitch":
                continue
            if a.loes is None:
                lines.append(f"not fitted: {a.loes_note}")
            else:
                lines += ["```", a.loes.fit.summary(), *a.loes.lines(), "```"]
                if a.loes_note:
                    lines.append(a.loes_note)
        lines += [f"- {n}" for n in self.notes + list(self.aircraft.notes)]
        return "\n".join(lines) + "\n"

    def lines(self) -> list[str]:
        out = [f"handling qualities ({self.aircraft.line()}"
               + (f"; {TASK_NAMES.get(self.task, self.task)})" if self.aircraft.ads33 else ")") + ":"]
        for a in self.axes:
            b = a.bandwidth
            lvl = b.level(a.axis, self.task, self.boundaries)
            bw = _f(b.bandwidth, unit="rad/s") if not np.isfinite(b.bandwidth_below) else \
                f"< {b.bandwidth_below:.3g} rad/s"
            out.append(f"  {a.axis} ({a.response}): bandwidth {bw}, phase delay "
                       f"{_f(b.phase_delay, 4, 's')}: ADS-33 level {self._level(lvl, a.axis)}"
                       + (f" ({'; '.join(b.notes)})" if b.notes else ""))
            if a.loes is not None:
                out += ["  " + s for s in a.loes.lines()] + ([f"  {a.loes_note}"] if a.loes_note else [])
            elif a.axis == "pitch":
                out.append(f"  short-period LOES not fitted: {a.loes_note}")
        return out + [f"  {n}" for n in self.notes] + [f"  note: {n}" for n in self.aircraft.notes]

    def save(self, outdir: str | Path, model: "HQReport | None" = None) -> list[Path]:
        """hq.md and one chart PNG per axis (``hq_<axis>.png``); ``model``: a model's report whose
        points are drawn beside these (flight data against the model)."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        paths = [outdir / "hq.md"]
        paths[0].write_text(self.markdown() + ("\n" + model.markdown() if model else ""))
        others = {a.axis: a for a in (model.axes if model else [])}
        for a in self.axes if self.aircraft.ads33 else ():  # no ADS-33 chart for an aircraft it does not grade
            points = {f"{'flight data' if model else a.axis} ({a.response})": a.bandwidth}
            if a.axis in others:
                points[f"model ({others[a.axis].response})"] = others[a.axis].bandwidth
            fig = ads33_chart(points, a.axis, self.task, self.boundaries)
            FigureCanvasAgg(fig)
            path = outdir / f"hq_{a.axis}.png"
            fig.savefig(path, dpi=90)
            paths.append(path)
        return paths

    def _level(self, lvl: int | None, axis: str) -> str:
        """The ADS-33 level as printed: with its boundaries' status (UNVERIFIED or the user's source)."""
        if not self.aircraft.ads33:
            return "not graded"
        if not lvl:
            return "not determined"
        status = self.boundaries.status(axis, self.task)
        return f"{lvl} ({status})" if status else str(lvl)


def _f(x: float, digits: int = 3, unit: str = "") -> str:
    return (f"{x:.{digits}g}" + (f" {unit}" if unit else "")) if np.isfinite(x) else "not determined"


def axis_inputs(inputs: list[str], pitch: str | None = None, roll: str | None = None) -> dict[str, str]:
    """{axis: input} from explicit choices or the usual names (theta_s / delta_e, theta_c / delta_a)."""
    out = {}
    for axis, chosen in (("pitch", pitch), ("roll", roll)):
        if chosen is not None:
            if chosen not in inputs:
                raise EstimationError(f"--{axis} {chosen}: not an input (inputs: {', '.join(inputs)})")
            out[axis] = chosen
            continue
        found = [u for u in AXES[axis][0] if u in inputs]
        if found:
            out[axis] = found[0]
    if not out:
        raise EstimationError(f"no pitch or roll control among the inputs ({', '.join(inputs)}): name them "
                              "with --pitch / --roll")
    return out


def _attitude(omega, H, coherence, outputs, inputs, axis, u):
    """(attitude response, its coherence or None, description) of ``axis`` to input ``u``."""
    _, rate, attitude = AXES[axis]
    i = inputs.index(u)
    if rate in outputs:
        j = outputs.index(rate)
        return H[:, j, i] / (1j * omega), None if coherence is None else coherence[:, j, i], f"{rate}/{u} / (jw)"
    if attitude in outputs:
        j = outputs.index(attitude)
        return H[:, j, i], None if coherence is None else coherence[:, j, i], f"{attitude}/{u}"
    raise EstimationError(f"{axis}: neither the rate {rate} nor the attitude {attitude} is an output")


def handling_qualities(omega, H, coherence, inputs, outputs, source: str, task: str = "tracking",
                       pitch: str | None = None, roll: str | None = None, category: str | None = None,
                       n_alpha: float | None = None, boundaries: Boundaries | str | Path | None = None,
                       aircraft: Aircraft | None = None) -> HQReport:
    """The report from responses ``H`` (nf, ny, nu) at ``omega`` (rad/s), ``coherence`` (nf, ny, nu) or None;
    ``n_alpha`` (g/rad): normal load factor per angle of attack, for the short period's CAP (none: the
    short-period frequency is not graded); ``boundaries``: the ADS-33 boundaries graded against, or a
    JSON file of them (:func:`.handling.load_boundaries`); None: the built-in (UNVERIFIED) corners;
    ``aircraft`` who is graded (None: :func:`aircraft_of` the inputs, ``category`` applied)."""
    aircraft = aircraft or aircraft_of(list(inputs), category=category)
    if task not in TASK_NAMES:
        raise EstimationError(f"task must be one of {', '.join(TASK_NAMES)}, got '{task}'")
    try:
        if isinstance(boundaries, (str, Path)):
            boundaries = load_boundaries(boundaries)
        report = HQReport(source, task, boundaries=boundaries or BUILTIN_BOUNDARIES, aircraft=aircraft)
        chosen = axis_inputs(list(inputs), pitch, roll)
        for axis in chosen if aircraft.ads33 else ():
            report.boundaries.pair(axis, task)  # a user file lacking the chart needed: said before any work
    except ValueError as exc:
        raise EstimationError(str(exc)) from None
    for axis, u in chosen.items():
        h, coh, how = _attitude(omega, H, coherence, list(outputs), list(inputs), axis, u)
        ax = AxisHQ(axis, u, how, bandwidth(omega, h, coh))
        if axis == "pitch" and AXES["pitch"][1] in outputs:
            j, i = list(outputs).index(AXES["pitch"][1]), list(inputs).index(u)
            try:
                fit = fit_transfer_function(omega, H[:, j, i], None if coherence is None else coherence[:, j, i],
                                            n_num=1, n_den=2, omega_range=LOES_RANGE)
                ax.loes = short_period(fit, aircraft.category, n_alpha)
                if fit.J > 100:
                    ax.loes_note = (f"LOES J {fit.J:.0f} > 100: the pitch-rate response is not short-period-like "
                                    "here (hover; or a mode inside the band the form lacks); its omega, zeta "
                                    "and level do not describe it")
            except ValueError as exc:
                ax.loes_note = str(exc)
        report.axes.append(ax)
    return report


def hq_of_model(model: LinearModel, task: str = "tracking", pitch=None, roll=None, category: str | None = None,
                n_alpha: float | None = None, boundaries=None, aircraft: Aircraft | None = None) -> HQReport:
    """The report from a model's exact responses (0.05-50 rad/s, 400 points; declared delays included);
    ``aircraft`` None: the profile's (its ``[meta]``, else guessed from its controls)."""
    from .response import model_response

    p = model.profile
    omega = np.geomspace(0.05, 50, 400)
    H = model_response(model, omega)
    aircraft = aircraft or aircraft_of(p.input_names, p.meta, category=category)
    return handling_qualities(omega, H, None, p.input_names, list(p.outputs), f"model '{p.name}'", task, pitch,
                              roll, category, n_alpha, boundaries, aircraft)


def hq_of_response(fr, task: str = "tracking", pitch=None, roll=None, category: str | None = None,
                   n_alpha: float | None = None, boundaries=None, aircraft: Aircraft | None = None) -> HQReport:
    """The report from a composite frequency response of runs (coherent points only)."""
    src = f"{len(fr.runs)} run(s): {', '.join(Path(r).name for r in fr.runs[:4])}{' ...' if len(fr.runs) > 4 else ''}"
    coh = np.where(fr.resolved, fr.coherence, 0.0)
    report = handling_qualities(fr.omega, fr.H, coh, fr.inputs, fr.outputs, src, task, pitch, roll, category, n_alpha,
                                boundaries, aircraft)
    report.notes.append(fr.resolution_line())
    return report

"""Identification while the pilot flies: the recursive frequency-domain estimate in the cockpit.

Every frame, the aircraft's measured response (from a simulation of a profile, ``--simulate``, or
an external function, ``--live-response``) and the flown stick go into a
:class:`~identify.estimators.frequency_ee.RecursiveFDEE` (one complex multiply-add per frequency and channel);
one equation group is re-solved per frame, so the whole estimate and its Cramér-Rao bounds are
renewed about once a second without any frame carrying a whole solve. Beside the needles a panel
shows each targeted parameter's Cramér-Rao bound in % of its estimate as a bar against its target,
and "TEST POINT COMPLETE" once all are below. Every frame is appended to ``<out>.live.csv``
(response channels, and the estimate and bounds on the frames where a round completed), flushed as
it is written, like the frame log.

After the flight (:func:`fly_live`) the run file carries the measured response, ML is run on it,
and the live result is put beside ML's in ``<out>.live.md``.
"""
from __future__ import annotations

import importlib
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from identify import LinearModel, Profile, PseudostepError, discretize, load_profile
from identify.estimators.frequency_ee import RecursiveFDEE

from .errors import CueingError

PANEL_WIDTH = 270  # px right of the needles
DEFAULT_TARGET = 20.0  # %: Tischler's guideline for a Cramér-Rao bound worth keeping
DEFAULT_BAND = (0.05, 1.5)  # Hz
ROUND_PERIOD = 1.0  # s between the starts of two re-solve rounds
GOOD, SHORT, NONE = (60, 200, 90), (255, 170, 0), (110, 110, 110)


def live_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.stem + ".live.csv")


# -- the aircraft's response -------------------------------------------------------------------
class SimulatedAircraft:
    """A profile's model flown frame by frame: the input held from one frame to the next (as the
    run file records it), the states measured with white noise of ``noise_fraction`` times each
    state's standard deviation in the response to the commanded signals flown exactly."""

    def __init__(self, model: LinearModel, signals, rate: float, noise_fraction: float = 0.02,
                 seed: int | None = None):
        self.model = model
        self.inputs = [s.input for s in signals]
        p = model.profile
        unknown = [i for i in self.inputs if i not in p.input_names]
        if unknown:
            raise CueingError(f"profile '{p.name}' has no input {', '.join(unknown)}")
        self._cols = [p.input_names.index(i) for i in self.inputs]
        self.noise = noise_fraction * self._response_scale(signals, rate)
        self.rng = np.random.default_rng(seed)
        self.x = np.zeros(model.n_states)
        self._last = None  # (t, u (m,))
        self._phi: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def _u(self, flown) -> np.ndarray:
        u = np.zeros(self.model.n_inputs)
        u[self._cols] = flown
        return u

    def _response_scale(self, signals, rate: float) -> np.ndarray:
        from identify import simulate
        t = np.arange(0, max(s.end_time for s in signals) + 1.0, 1 / rate)
        u = np.zeros((len(t), self.model.n_inputs))
        for s, c in zip(signals, self._cols):
            u[:, c] = s(t)
        return simulate(self.model, u, 1 / rate).x.std(axis=0)

    def describe(self) -> str:
        return f"simulation of '{self.model.profile.name}'"

    def read(self, t: float, flown) -> np.ndarray:
        """Measured states (n,) at time t, the stick ``flown`` (n_axes,) being held from now on."""
        u = self._u(flown)
        if self._last is not None and t > self._last[0]:
            dt = round(t - self._last[0], 9)
            if dt not in self._phi:
                self._phi[dt] = discretize(self.model.A, self.model.B, dt)
            Phi, Gamma = self._phi[dt]
            self.x = Phi @ self.x + Gamma @ self._last[1]
        self._last = (t, u)
        return self.x + self.noise * self.rng.standard_normal(self.x.size)


class ExternalResponse:
    """A function ``f(t, flown) -> states`` (n,), e.g. a flight simulator's measured response."""

    def __init__(self, spec: str):
        spec = spec.removeprefix("external:")
        module, _, name = spec.rpartition(":")
        try:
            self.func = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError, ValueError) as exc:
            raise CueingError(f"--live-response '{spec}': {exc}") from None
        self.spec = spec

    def describe(self) -> str:
        return f"external ({self.spec})"

    def read(self, t: float, flown) -> np.ndarray:
        try:
            return np.asarray(self.func(t, np.asarray(flown)), dtype=float)
        except Exception as exc:  # a simulator's failure ends the run with one line, not a traceback
            raise CueingError(f"--live-response '{self.spec}' at t = {t:.3f} s: {exc}") from None


# -- profile and targets -----------------------------------------------------------------------
def flown_profile(profile: Profile, flown_inputs: list[str]) -> tuple[Profile, list[str]]:
    """The profile with the derivatives of inputs nobody flies fixed at their a priori values
    (their regressors are zero: no data can estimate them); returns it and the names fixed."""
    still = [i for i in profile.input_names if i not in flown_inputs]
    fixed = [name for name in profile.free
             if all(e.matrix == "B" and profile.input_names[e.col] in still
                    for e, _ in profile.parameter_entries(name))]
    if not fixed:
        return profile, []
    return replace(profile, free={k: v for k, v in profile.free.items() if k not in fixed},
                   fixed={**profile.fixed, **{k: profile.free[k] for k in fixed}}), fixed


def primary_derivatives(profile: Profile) -> list[str]:
    """Per moment equation (L, M, N): its largest a priori rate derivative (the damping, ``M_q``)
    and its largest control derivative (the control power, ``M_theta_s``): what a handling-qualities
    test point is flown for. Falls back to every free parameter for a profile without them."""
    rates = {"p", "q", "r"} & set(profile.states)
    picks = []
    for state in sorted(rates):
        eq = profile.state_names.index(state)
        for matrix, wanted in (("A", lambda c: profile.state_names[c] in rates), ("B", lambda c: True)):
            cands = [n for n in profile.free
                     if [(e.matrix, e.row) for e, _ in profile.parameter_entries(n)] == [(matrix, eq)]
                     and wanted(profile.parameter_entries(n)[0][0].col)]
            if cands:
                picks.append(max(cands, key=lambda n: abs(profile.free[n])))
    return picks or list(profile.free)


def parse_targets(spec: str | None, profile: Profile) -> dict[str, float]:
    """``"M_q:10,L_p"`` -> {name: target %} (DEFAULT_TARGET where none given); default: the
    primary damping and control derivatives (:func:`primary_derivatives`)."""
    if not spec:
        return {n: DEFAULT_TARGET for n in primary_derivatives(profile)}
    out = {}
    for item in (s.strip() for s in spec.split(",") if s.strip()):
        name, _, pct = item.partition(":")
        if name not in profile.free:
            raise CueingError(f"--targets: '{name}' is not a free parameter of '{profile.name}' "
                              f"(free: {', '.join(profile.free)})")
        try:
            out[name] = float(pct) if pct else DEFAULT_TARGET
        except ValueError:
            raise CueingError(f"--targets: '{item}': the target after ':' must be a number (%)") from None
        if not out[name] > 0:
            raise CueingError(f"--targets: '{item}': the target must be positive")
    if not out:
        raise CueingError("--targets names no parameter")
    return out


# -- the live session --------------------------------------------------------------------------
@dataclass
class LiveHistory:
    """Estimates re-solved during the flight: times (s), theta and std (rounds, p)."""

    names: list[str]
    t: list[float] = field(default_factory=list)
    theta: list[np.ndarray] = field(default_factory=list)
    std: list[np.ndarray] = field(default_factory=list)


class LiveIdentification:
    """The cockpit side: fed by the runner every frame (:meth:`frame`), draws the panel (:meth:`draw`).

    ``profile``: the a priori model whose free parameters are estimated; ``response``: object with
    ``read(t, flown) -> states``; ``targets`` {parameter: %} or a ``--targets`` text (None: the
    primary derivatives); ``log_path``: the ``.live.csv``.
    After the flight: ``history_``, ``complete_at_`` (s, or None), ``times_`` (s of work per frame).
    """

    def __init__(self, profile: Profile, signals, response, log_path, targets: dict[str, float] | str | None = None,
                 band=DEFAULT_BAND, n_freq: int = 60):
        self.signals = list(signals)
        self.inputs = [s.input for s in self.signals]
        self.profile, self.fixed_unflown = flown_profile(profile, self.inputs)
        self.targets = targets if isinstance(targets, dict) else parse_targets(targets, self.profile)
        missing = [n for n in self.targets if n not in self.profile.free]
        if missing:
            raise CueingError(f"targets {', '.join(missing)} belong to inputs not flown ("
                              f"{', '.join(self.fixed_unflown)} are fixed at their a priori values)")
        self.estimator = RecursiveFDEE(self.profile, band=band, n_freq=n_freq)
        self.response = response
        self.log_path = Path(log_path)
        self.names = self.profile.free_names
        self._input_cols = [self.profile.input_names.index(i) for i in self.inputs]
        self._target_idx = [self.names.index(n) for n in self.targets]
        self.history_ = LiveHistory(self.names)
        self.latest = None
        self.complete_at_: float | None = None
        self.times_: list[float] = []  # wall time of the live work per frame (s)
        self.cpu_times_: list[float] = []  # the same in this thread's CPU time: without other load
        self._round_start = -np.inf
        self._in_round = False
        self._panel = None  # cached rendered panel: redrawn only when the estimate changes
        self._stale = False  # a new estimate awaits drawing
        self._busy = False  # this frame already solved: the redraw waits for the next one
        self._fonts = {}
        self._file = None

    # -- logging ----------------------------------------------------------------------------------
    def open(self) -> None:
        try:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(self.log_path, "w", buffering=1 << 16)
        except OSError as exc:
            raise CueingError(f"{self.log_path}: cannot write the live log ({exc.strerror or exc})") from None
        p = self.profile
        self._file.write(f"# format: pseudostep-live-log/1\n# profile: {p.name}\n"
                         f"# response: {self.response.describe()}\n"
                         f"# band_hz: {self.estimator.omega[0] / 2 / np.pi:g}..{self.estimator.omega[-1] / 2 / np.pi:g}"
                         f" ({self.estimator.omega.size} frequencies)\n"
                         f"# targets: {', '.join(f'{k} {v:g} %' for k, v in self.targets.items())}\n")
        if self.fixed_unflown:
            self._file.write(f"# fixed (input not flown): {', '.join(self.fixed_unflown)}\n")
        cols = ["frame", "time", "t_signal"] + p.state_names + self.inputs
        cols += [c for n in self.names for c in (n, n + "_std")] + ["complete"]
        self._file.write(",".join(cols) + "\n")
        self._n_cols = len(cols)

    def close(self, status: str = "completed") -> None:
        if self._file is not None and not self._file.closed:
            self._file.write(f"# end: {status}\n")
            self._file.close()

    # -- every frame ------------------------------------------------------------------------------
    def frame(self, k: int, t: float, t_signal: float, flown, paused: bool) -> None:
        """One frame: read the response, update the transforms, do this frame's share of a re-solve,
        log the row. Nothing happens during the countdown; a pause (the stick lost) stops the signal,
        not the aircraft, so the record goes on."""
        if self._file is None:
            self.open()
        if t < 0:
            return
        w0, c0 = time.perf_counter(), time.thread_time()
        self._busy = False
        x = self.response.read(t, flown)
        if x.shape != (len(self.profile.states),):
            raise CueingError(f"{self.response.describe()}: gave {x.size} states at t = {t:.3f} s, "
                              f"the profile has {len(self.profile.states)} ({', '.join(self.profile.state_names)})")
        u = np.zeros(len(self.profile.inputs))
        u[self._input_cols] = flown
        self.estimator.update(t, x, u)
        done = self._work(t)
        row = [str(k), f"{t:.9f}", f"{t_signal:.9f}"] + [f"{v:.9g}" for v in x] + [f"{v:.9g}" for v in flown]
        if done is not None:
            row += [f"{v:.9g}" for pair in zip(done.theta, done.std) for v in pair]
            row.append("1" if self.complete_at_ is not None else "0")
        self._file.write(",".join(row) + "\n")
        self._file.flush()
        self.times_.append(time.perf_counter() - w0)
        self.cpu_times_.append(time.thread_time() - c0)

    def _work(self, t: float):
        if not self._in_round and t - self._round_start >= ROUND_PERIOD:
            self._round_start, self._in_round = t, True
        if not self._in_round:
            return None
        est = self.estimator.step()
        self._busy = True
        if est is None:
            return None
        self._in_round = False
        self.latest = est
        self.history_.t.append(t)
        self.history_.theta.append(est.theta)
        self.history_.std.append(est.std)
        rel = est.relative_std[self._target_idx]
        if self.complete_at_ is None and np.all(rel <= np.array(list(self.targets.values()))):
            self.complete_at_ = t
        self._stale = True
        return est

    # -- the panel --------------------------------------------------------------------------------
    def draw(self, surface, rect) -> None:
        """Blit the panel (re-rendered only after a new estimate) into ``rect`` (x, y, w, h)."""
        w0, c0 = time.perf_counter(), time.thread_time()
        # re-rendering the text costs about a millisecond: never on a frame that also solved
        if self._panel is None or (self._stale and not self._busy) or self._panel.get_size() != tuple(rect[2:]):
            self._panel = self._render(rect[2:])
            self._stale = False
        surface.blit(self._panel, rect[:2])
        if self.times_:
            self.times_[-1] += time.perf_counter() - w0
            self.cpu_times_[-1] += time.thread_time() - c0

    def _render(self, size):
        import pygame
        w, h = size
        panel = pygame.Surface((w, h))
        panel.fill((20, 24, 34))
        est = self.latest
        title = "live estimate: waiting" if est is None else f"live estimate at {est.t:5.1f} s"
        self._text(panel, title, (10, 8), 22)
        self._text(panel, "Cramér-Rao bound, % of estimate", (10, 30), 17, (170, 170, 170))
        row_h = max(16, min(30, (h - 120) // max(len(self.targets), 1)))
        bar_x, bar_w = 92, w - 150
        for r, (name, target) in enumerate(self.targets.items()):
            y = 56 + r * row_h
            self._text(panel, name, (10, y), 19)
            pygame.draw.rect(panel, (50, 55, 70), (bar_x, y + 2, bar_w, row_h - 8))
            tick = bar_x + bar_w // 2  # the target sits at mid-bar: the bar spans 0..2x target
            value = np.nan if est is None else est.relative_std[self.names.index(name)]
            if np.isfinite(value):
                fill = int(min(value / (2 * target), 1.0) * bar_w)
                pygame.draw.rect(panel, GOOD if value <= target else SHORT, (bar_x, y + 2, fill, row_h - 8))
                label = f"{value:5.1f}" if value < 1000 else ">999"
            else:
                label = "  -"
            pygame.draw.line(panel, (235, 235, 235), (tick, y - 1), (tick, y + row_h - 5), 2)
            self._text(panel, label, (bar_x + bar_w + 6, y), 19)
        complete = self.complete_at_ is not None
        box = pygame.Rect(10, h - 56, w - 20, 44)
        pygame.draw.rect(panel, GOOD if complete else (60, 60, 70), box, 0 if complete else 2)
        self._text(panel, "TEST POINT COMPLETE" if complete else "collecting ...", box.center, 24,
                   (10, 10, 10) if complete else (200, 200, 200), centre=True)
        return panel

    def _text(self, surface, text, pos, size, color=(235, 235, 235), centre=False):
        import pygame
        if size not in self._fonts:
            if not pygame.font.get_init():
                pygame.font.init()
            self._fonts[size] = pygame.font.Font(None, size)
        img = self._fonts[size].render(text, True, color)
        surface.blit(img, img.get_rect(center=pos) if centre else img.get_rect(topleft=pos))


# -- after the flight --------------------------------------------------------------------------
def read_live_log(path) -> tuple[dict, dict[str, np.ndarray]]:
    """The ``.live.csv`` read back: metadata and columns (blank estimate cells are nan)."""
    path = Path(path)
    meta, header, rows = {}, None, []
    for line in path.read_text().split("\n"):
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            meta[key.strip()] = value.strip()
        elif header is None and line.strip():
            header = line.split(",")
        elif line.strip():
            cells = line.split(",")
            rows.append([float(c) for c in cells] + [np.nan] * (len(header) - len(cells)))
    if header is None or not rows:
        raise CueingError(f"{path}: live log holds no frames")
    data = np.array(rows)
    return meta, {h: data[:, j] for j, h in enumerate(header)}


def add_response(run, live: LiveIdentification):
    """The run file's grid with the measured states the live estimator saw (linear interpolation
    between frames: on a fast clock the frames are the grid)."""
    _, cols = read_live_log(live.log_path)
    t = cols["time"]
    channels = {s: np.interp(run.time, t, cols[s]) for s in live.profile.state_names}
    return run.with_channels(channels, source_of_response=live.response.describe())


def comparison(live: LiveIdentification, ml_result) -> str:
    """Markdown table: the live (recursive FDEE) estimate at the end of the flight beside ML's."""
    est = live.latest
    lines = [f"# Live estimate beside post-flight ML", "",
             f"Live: recursive frequency-domain equation error, last re-solved at {est.t:.1f} s "
             f"({', '.join(f'{k}: {v}' for k, v in est.errors.items()) or 'all equations solved'}); "
             f"test point complete {'at %.1f s' % live.complete_at_ if live.complete_at_ is not None else 'never'}. "
             f"ML: output error on the run file. CR % and I % (insensitivity: the bound were the other "
             f"parameters known) as Tischler & Remple; their guidelines CR % <= 20, I % <= 10.", "",
             "| parameter | target % | live | live std | live CR % | live I % | ML | ML std | (live - ML) / live std |",
             "|---|---|---|---|---|---|---|---|---|"]
    ml = dict(zip(ml_result.names, zip(ml_result.theta, ml_result.std)))
    for i, n in enumerate(live.names):
        v, s = est.theta[i], est.std[i]
        mv, ms = ml.get(n, (np.nan, np.nan))
        tgt = f"{live.targets[n]:g}" if n in live.targets else ""
        lines.append(f"| {n} | {tgt} | {v:.5g} | {s:.3g} | {100 * s / abs(v):.1f} | "
                     f"{est.relative_insensitivity[i]:.1f} | {mv:.5g} | {ms:.3g} | {(v - mv) / s:+.2f} |")
    if live.fixed_unflown:
        lines += ["", f"Fixed at a priori values (their inputs were not flown): {', '.join(live.fixed_unflown)}."]
    return "\n".join(lines) + "\n"


def fly_live(signals, source, out, profile, *, simulate=None, response=None, targets=None,
             noise_fraction: float = 0.02, seed: int | None = None, rate: float = 60.0, ml: bool = True,
             band=DEFAULT_BAND, n_freq: int = 60, **fly_options):
    """Fly with the live estimate; returns (flight, live, ml_result or None).

    ``profile``: the a priori profile estimated live; ``simulate``: profile or LinearModel of the
    aircraft (a simulation), or ``response``: an object with ``read(t, flown)`` (e.g.
    :class:`ExternalResponse`); ``band`` (Hz) and ``n_freq``: the live estimator's frequencies.
    The run file gets the measured response; ML is run on it (``ml``) and ``<out>.live.md``
    compares the two.
    """
    from identify import ML

    from .session import fly

    out = Path(out)
    profile = profile if isinstance(profile, Profile) else load_profile(profile)
    if response is None:
        if simulate is None:
            raise CueingError("--live needs the aircraft's response: --simulate PROFILE or "
                              "--live-response MODULE:FUNCTION")
        aircraft = simulate if isinstance(simulate, LinearModel) else LinearModel(load_profile(simulate))
        response = SimulatedAircraft(aircraft, signals, rate, noise_fraction, seed)
    live = LiveIdentification(profile, signals, response, live_path(out), targets, band=band, n_freq=n_freq)
    try:
        flight = fly(signals, source, out, live=live, rate=rate, seed=seed, **fly_options)
    except BaseException as exc:
        live.close(f"aborted ({exc or type(exc).__name__})")
        raise
    live.close(flight.log.status)
    flight.run = add_response(flight.run, live)
    flight.run.to_csv(out)
    ml_result = None
    if ml and live.latest is not None:
        try:
            ml_result = ML(live.profile).fit(flight.run).result_
        except PseudostepError as exc:  # said in the report, not hidden
            out.with_name(out.stem + ".live.md").write_text(f"ML after the flight failed: {exc}\n")
            return flight, live, None
        out.with_name(out.stem + ".live.md").write_text(comparison(live, ml_result))
    return flight, live, ml_result


def cmd_fly_live(args, signals, options: dict, source):
    """``cueing fly --live PROFILE``: fly with the live estimate, print it beside ML; the flight."""
    opts = dict(options)
    simulate, noise, seed = opts.pop("simulate"), opts.pop("noise_fraction"), opts.pop("seed")
    response = ExternalResponse(args.live_response) if args.live_response else None
    flight, live, ml_result = fly_live(signals, source, args.out, args.live, simulate=simulate, response=response,
                                       targets=args.targets, noise_fraction=noise, seed=seed,
                                       pilot=args.pilot or "", **opts)
    print("\n".join(flight.score.lines()[1:]))
    report = Path(args.out).with_name(Path(args.out).stem + ".live.md")
    print(report.read_text() if report.exists() else "no live estimate (the run ended before the first re-solve)")
    times = np.array(live.times_) * 1e3
    if times.size:
        print(f"live work per frame: median {np.median(times):.2f} ms, 99th percentile {np.percentile(times, 99):.2f} ms")
    print(f"run written to {flight.path} ({flight.log.status}); frame log {flight.log.path}; live log {live.log_path}")
    return flight

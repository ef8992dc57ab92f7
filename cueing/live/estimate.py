"""Identification while the pilot flies: the recursive frequency-domain estimate, without drawing.

Every frame the aircraft's measured response and the flown stick go into a
:class:`~identify.FDEE` streamed by ``partial_fit`` (one complex multiply-add per frequency and channel); one equation
group is re-solved per frame, so the whole estimate and its Cramér-Rao bounds are renewed about
once a second without any frame carrying a whole solve. Every frame is appended to the live log
(:mod:`.log`). :class:`~cueing.live.panel.LivePanel` shows the estimate beside the needles.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from identify import FDEE, Profile
from identify.model.subset import input_parameters

from ..errors import CueingError
from .log import LiveLogWriter
from .targets import flown_profile, parse_targets

DEFAULT_BAND = (0.05, 1.5)  # Hz
ROUND_PERIOD = 1.0  # s between the starts of two re-solve rounds


@dataclass
class LiveHistory:
    """Estimates re-solved during the flight: times (s), theta and std (rounds, p)."""

    names: list[str]
    t: list[float] = field(default_factory=list)
    theta: list[np.ndarray] = field(default_factory=list)
    std: list[np.ndarray] = field(default_factory=list)


class LiveIdentification:
    """The estimate fed every frame (:meth:`update`).

    ``profile``: the a priori model whose free parameters are estimated; ``response``: object with
    ``read(t, flown) -> states`` and ``describe()`` (:mod:`cueing.response`); ``targets``
    {parameter: %} or a ``--targets`` text (None: the primary derivatives); ``log_path``: the
    ``.live.csv``; ``band`` (Hz) and ``n_freq``: the estimator's frequencies.
    During the flight: ``latest`` (the last estimate), ``solved_this_frame``. After it:
    ``history_``, ``complete_at_`` (s, or None), ``times_`` and ``cpu_times_`` (s of work per
    frame, wall and this thread's CPU time, the panel's drawing included via :meth:`charge`).
    """

    def __init__(self, profile: Profile, signals, response, log_path, targets: dict[str, float] | str | None = None,
                 band=DEFAULT_BAND, n_freq: int = 60):
        self.signals = list(signals)
        self.inputs = [s.input for s in self.signals]
        self.profile, self.fixed_unflown = flown_profile(profile, self.inputs)
        # named targets against the whole profile: one on an input the signal does not move is
        # refused with that reason, not as an unknown parameter; the default ones from what is flown
        self.targets = targets if isinstance(targets, dict) else \
            parse_targets(targets, profile if targets else self.profile)
        missing = [n for n in self.targets if n not in self.profile.free]
        if missing:
            acting = input_parameters(profile)
            why = "; ".join(f"{n} acts on {', '.join(u for u, ps in acting.items() if n in ps) or 'no flown input'}"
                            for n in missing)
            raise CueingError(f"--targets {', '.join(missing)}: not excited by this signal, which moves only "
                              f"{', '.join(self.inputs)} ({why}): fly a signal on that input too (a design for "
                              f"several axes) or leave the target out")
        # no samples yet: validates the options now and fixes the frequencies (omega_)
        self.estimator = FDEE(self.profile, band=band, n_freq=n_freq).partial_fit([], [], [])
        self.response = response
        self.log = LiveLogWriter(log_path)
        self.names = self.profile.free_names
        self._input_cols = [self.profile.input_names.index(i) for i in self.inputs]
        self._target_idx = [self.names.index(n) for n in self.targets]
        self._target_pct = np.array(list(self.targets.values()))
        self.history_ = LiveHistory(self.names)
        self.latest = None
        self.solved_this_frame = False  # a re-solve step ran in this frame (the panel waits to redraw)
        self.complete_at_: float | None = None
        self.times_: list[float] = []  # wall time of the live work per frame (s)
        self.cpu_times_: list[float] = []  # the same in this thread's CPU time: without other load
        self._round_start = -np.inf
        self._in_round = False

    @property
    def log_path(self):
        return self.log.path

    # -- logging ----------------------------------------------------------------------------------
    def open(self) -> None:
        """Start the live log: what is estimated, from what, and the columns."""
        hz = self.estimator.omega_ / 2 / np.pi
        meta = {"profile": self.profile.name, "response": self.response.describe(),
                "band_hz": f"{hz[0]:g}..{hz[-1]:g} ({hz.size} frequencies)",
                "targets": ", ".join(f"{k} {v:g} %" for k, v in self.targets.items())}
        if self.fixed_unflown:
            meta["fixed (input not flown)"] = ", ".join(self.fixed_unflown)
        cols = ["frame", "time", "t_signal"] + self.profile.state_names + self.inputs
        cols += [c for n in self.names for c in (n, n + "_std")] + ["complete"]
        self.log.open(meta, cols)

    def close(self, status: str = "completed") -> None:
        self.log.close(status)

    # -- every frame ------------------------------------------------------------------------------
    def update(self, k: int, t: float, t_signal: float, flown, paused: bool) -> None:
        """One frame: read the response, update the transforms, do this frame's share of a re-solve,
        log the row. Nothing happens during the countdown; a pause (the stick lost) stops the signal,
        not the aircraft, so the record goes on."""
        if not self.log.is_open:
            self.open()
        if t < 0:
            return
        w0, c0 = time.perf_counter(), time.thread_time()
        self.solved_this_frame = False
        x = self.response.read(t, flown)
        n = len(self.profile.states)
        if x.shape != (n,):
            raise CueingError(f"{self.response.describe()}: gave {x.size} states at t = {t:.3f} s, "
                              f"the profile has {n} ({', '.join(self.profile.state_names)})")
        u = np.zeros(len(self.profile.inputs))
        u[self._input_cols] = flown
        self.estimator.partial_fit(t, x, u)
        done = self._work(t)
        row = [str(k), f"{t:.9f}", f"{t_signal:.9f}"] + [f"{v:.9g}" for v in x] + [f"{v:.9g}" for v in flown]
        if done is not None:
            row += [f"{v:.9g}" for pair in zip(done.theta, done.std) for v in pair]
            row.append("1" if self.complete_at_ is not None else "0")
        self.log.row(row)
        self.times_.append(time.perf_counter() - w0)
        self.cpu_times_.append(time.thread_time() - c0)

    def charge(self, wall: float, cpu: float) -> None:
        """Add work done for this frame elsewhere (the panel's drawing) to the frame's time."""
        if self.times_:
            self.times_[-1] += wall
            self.cpu_times_[-1] += cpu

    def _work(self, t: float):
        if not self._in_round and t - self._round_start >= ROUND_PERIOD:
            self._round_start, self._in_round = t, True
        if not self._in_round:
            return None
        est = self.estimator.step()
        self.solved_this_frame = True
        if est is None:
            return None
        self._in_round = False
        self.latest = est
        self.history_.t.append(t)
        self.history_.theta.append(est.theta)
        self.history_.std.append(est.std)
        if self.complete_at_ is None and np.all(est.relative_std[self._target_idx] <= self._target_pct):
            self.complete_at_ = t
        return est

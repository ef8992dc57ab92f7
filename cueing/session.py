"""One flown run end to end: fly, turn the frame log into a run file, simulate the aircraft, score."""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from identify import Run

from .clock import FakeClock
from .display import signal_units
from .errors import RunAborted
from .flightlog import FrameLog, frame_log_path, log_to_run
from .response import aircraft_model, simulate_test_point
from .runner import Runner, Screen, runner_options
from .scoring import PracticeScore, score_run


@dataclass
class Flight:
    """A flown run: the frame ``log``, the uniform ``run`` (written to ``path``), its ``score`` and
    the ``runner`` that flew it (render times, screenshots)."""

    log: FrameLog
    run: Run
    path: Path
    score: PracticeScore
    runner: Runner | None = None


def fly(signals, source, out, *, simulate=None, noise_fraction: float = 0.02, seed: int | None = None,
        model=None, fast: bool = False, pilot: str = "", **options) -> Flight:
    """Fly ``signals`` with ``source``; write the run file ``out`` (frame log beside it).

    ``simulate``: profile (name, path or LinearModel) whose response is added; ``model``: model for
    the information-retained score (default: the simulated one), whose profile also gives the
    scale's units; ``fast``: fake clock, no waiting (only for sources that need no human);
    ``options`` go to :class:`Runner`, flat (``lead_in``, ``rate``, ``display`` ...: see
    :func:`~cueing.runner.runner_options`) or as configs (``schedule``, ``screen``, ``panels`` ...).
    """
    out = Path(out)
    sim_model = None if simulate is None else aircraft_model(simulate)
    model = model if model is not None else sim_model
    options = runner_options(**options)
    if fast:
        options["clock"] = FakeClock()
    screen = options.get("screen", Screen())
    if model is not None and screen.units is None:
        options["screen"] = replace(screen, units=signal_units(signals, model.profile))
    runner = Runner(signals, source, frame_log_path(out), meta={"pilot": pilot or "(unnamed)"}, **options)
    signals = runner.signals  # as flown: delayed by the lead-in
    holder = {}

    def end_lines(log):
        holder["flight"] = _finish(log, signals, out, sim_model, noise_fraction, seed, model)
        lines = holder["flight"].score.lines()
        lines[0] = f"Run {'complete' if not log.aborted else log.status} - score"
        return lines

    log = runner.fly(score_lines=end_lines)
    if "flight" not in holder:  # no display: nothing asked for the score yet
        holder["flight"] = _finish(log, signals, out, sim_model, noise_fraction, seed, model)
    flight = holder["flight"]
    flight.runner = runner
    return flight


def _finish(log, signals, out, sim_model, noise_fraction, seed, model) -> Flight:
    if log.aborted and np.sum(log.time >= 0) < 2:
        raise RunAborted(f"run {log.status} before the recording started: no run file written "
                         f"(frame log {log.path})")
    run = log_to_run(log, signals=signals)
    if sim_model is not None:
        run = simulate_test_point(run, sim_model, noise_fraction, seed)
    score = score_run(run, signals, model, log.frame_stats())
    notes = {}
    if score.peak_ratio is not None and score.peak_ratio > 1.05:
        notes["information_note"] = (f"peak response {score.peak_ratio:.3g} x the designed one: raw D-efficiency "
                                     f"{score.d_efficiency:.4g}, information retained at the designed peak response "
                                     f"{score.information_retained:.4g}; the limits assumed the designed input")
    run = run.with_channels({}, score=", ".join(f"{k} {v:.4g}" for k, v in score.to_dict().items()
                                                if isinstance(v, (int, float)) and v is not None), **notes)
    out.parent.mkdir(parents=True, exist_ok=True)
    run.to_csv(out)
    return Flight(log, run, out, score)

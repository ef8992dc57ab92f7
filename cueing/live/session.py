"""A run flown with the live estimate, end to end: fly with the panel, give the run file the
measured response, run ML on it and put the live result beside ML's in ``<out>.live.md``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from identify import Profile, PseudostepError, load_profile

from ..errors import CueingError
from ..response import SimulatedAircraft, aircraft_model
from ..session import fly
from .estimate import DEFAULT_BAND, LiveIdentification
from .log import live_path, read_live_log
from .panel import LivePanel
from .report import comparison


def report_path(out) -> Path:
    out = Path(out)
    return out.with_name(out.stem + ".live.md")


def add_response(run, live: LiveIdentification, model=None):
    """The run file a flight without the live estimate writes, from what the live estimator saw:
    every input of the aircraft's profile (``model``'s, default the live profile; an input not
    flown at its trim value, zero), the measured states (linear interpolation between frames: on a
    fast clock the frames are the grid), their derivatives ``<state>_dot`` (smoothed
    differentiation of the measured states, recorded in the run's processing) and the profile's
    outputs (``C x + D u`` of the measured states)."""
    from identify import LinearModel, add_derivatives

    _, cols = read_live_log(live.log_path)
    t = cols["time"]
    model = model if model is not None else LinearModel(live.profile)
    p = model.profile
    states = {s: np.interp(run.time, t, cols[s]) for s in p.state_names}
    inputs = {u: run.channels.get(u, np.zeros(len(run))) for u in p.input_names}
    x = np.column_stack([states[s] for s in p.state_names])
    u = np.column_stack([inputs[n] for n in p.input_names])
    y = x @ model.C.T + u @ model.D.T
    outputs = {n: y[:, j] for j, n in enumerate(p.outputs) if n not in states}
    out = run.with_channels({**inputs, **states, **outputs}, source_of_response=live.response.describe(),
                            unflown_inputs=", ".join(n for n in p.input_names if n not in run.channels) or "none")
    cutoff = min(6.25, 0.4 / out.dt)  # the project's default, below Nyquist at any frame rate
    return add_derivatives(out, list(p.state_names), cutoff_hz=cutoff)


def fly_live(signals, source, out, profile, *, simulate=None, response=None, targets=None,
             noise_fraction: float = 0.02, seed: int | None = None, rate: float = 60.0, ml: bool = True,
             band=DEFAULT_BAND, n_freq: int = 60, **fly_options):
    """Fly with the live estimate; returns (flight, live, ml_result or None).

    ``profile``: the a priori profile estimated live; ``simulate``: profile or LinearModel of the
    aircraft (a simulation), or ``response``: an object with ``read(t, flown)`` (e.g.
    :class:`~cueing.response.ExternalResponse`); ``band`` (Hz) and ``n_freq``: the live
    estimator's frequencies. The run file gets the measured response; ML is run on it (``ml``) and
    ``<out>.live.md`` compares the two. ``fly_options`` go to :func:`cueing.session.fly`.
    """
    from identify import ML  # output error: loaded when the flight is over

    out = Path(out)
    profile = profile if isinstance(profile, Profile) else load_profile(profile)
    if response is None:
        if simulate is None:
            raise CueingError("--live needs the aircraft's response: --simulate PROFILE or "
                              "--live-response MODULE:FUNCTION")
        response = SimulatedAircraft(aircraft_model(simulate), signals, rate, noise_fraction, seed)
    live = LiveIdentification(profile, signals, response, live_path(out), targets, band=band, n_freq=n_freq)
    try:
        flight = fly(signals, source, out, panels=[LivePanel(live)], rate=rate, seed=seed, **fly_options)
    except BaseException as exc:
        live.close(f"aborted ({exc or type(exc).__name__})")
        raise
    live.close(flight.log.status)
    flight.run = add_response(flight.run, live, getattr(response, "model", None))
    flight.run.to_csv(out)
    if not ml or live.latest is None:
        return flight, live, None
    try:
        ml_result = ML(live.profile).fit(flight.run).result_
    except PseudostepError as exc:  # said in the report, not hidden
        report_path(out).write_text(f"ML after the flight failed: {exc}\n")
        return flight, live, None
    report_path(out).write_text(comparison(live, ml_result))
    return flight, live, ml_result

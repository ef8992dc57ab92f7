"""Data processing before equation-error identification: smoothing, differentiation, CG correction.

Flight-test rates and accelerations carry rotor vibration (for a helicopter, n/rev harmonics far
above the rigid-body band); equation-error methods need state derivatives, so rates must be
differentiated. After the paper (Kaletka & Rix), this module offers

* :func:`smooth` — a zero-phase low-pass (Butterworth run forwards and backwards, ``sosfiltfilt``;
  the paper used 6.25 Hz on data sampled every 0.011 s);
* :func:`differentiate` — a smoothed differentiator: a linear-phase antisymmetric FIR whose response
  is ``j w`` inside the band and rolls off above the cut-off, so its phase is exactly 90 degrees at
  every frequency and it does not amplify the noise the way central differences do;
* :func:`cg_correction` — accelerations measured by an accelerometer offset from the centre of
  gravity, moved to the CG (rigid-body kinematics);
* :func:`add_derivatives` — ``<channel>_dot`` channels from smoothed differentiation.

Every step appends a record to the run's metadata key ``processing`` (a JSON list of
``{"step": ..., options}``); :func:`replay` applies such a list to a raw run again, so a result can be
reproduced from the raw data and its recorded processing.
"""
from __future__ import annotations

import json

import numpy as np

from ..errors import RunError
from .runs import Run

PROCESSING = "processing"


# -- records ----------------------------------------------------------------------------------
def processing_steps(run: Run) -> list[dict]:
    """The processing a run went through, oldest first (empty for raw data)."""
    text = run.meta.get(PROCESSING)
    if not text:
        return []
    try:
        steps = json.loads(text)
    except json.JSONDecodeError:
        raise RunError(f"{run.source}: metadata '{PROCESSING}' is not a JSON list of steps") from None
    if not isinstance(steps, list) or not all(isinstance(s, dict) and "step" in s for s in steps):
        raise RunError(f"{run.source}: metadata '{PROCESSING}' is not a JSON list of steps")
    return steps


def _record(run: Run, channels: dict[str, np.ndarray], step: dict) -> Run:
    """Copy of ``run`` with ``channels`` replaced/added and ``step`` appended to its processing."""
    steps = processing_steps(run) + [step]
    return run.with_channels(channels, **{PROCESSING: json.dumps(steps, separators=(",", ":"))})


def replay(run: Run, steps: list[dict]) -> Run:
    """Apply recorded processing ``steps`` (from :func:`processing_steps`) to ``run`` in order."""
    ops = {"smooth": smooth, "differentiate": add_derivatives, "cg_correction": cg_correction,
           "slice": _slice_step, "trim": remove_trim}
    for step in steps:
        options = {k: v for k, v in step.items() if k not in ("step", "filter", "values")}
        try:
            op = ops[step["step"]]
        except KeyError:
            raise RunError(f"{run.source}: unknown processing step '{step.get('step')}'") from None
        run = op(run, **options)
    return run


def slice_run(run: Run, t_start: float | None = None, t_end: float | None = None) -> Run:
    """``run.slice`` with the cut recorded as a processing step."""
    return _slice_step(run, t_start, t_end)


def _slice_step(run: Run, t_start=None, t_end=None) -> Run:
    out = run.slice(t_start, t_end)
    return _record(out, {}, {"step": "slice", "t_start": t_start, "t_end": t_end})


def parse_trim(text: str) -> tuple[str, float]:
    """``first:1s`` -> ("first", 1.0), ``mean`` -> ("mean", 0), ``none`` -> ("none", 0)."""
    text = str(text).strip().lower()
    if text in ("mean", "none"):
        return text, 0.0
    kind, sep, span = text.partition(":")
    if kind == "first" and sep:
        try:
            seconds = float(span[:-1] if span.endswith("s") else span)
        except ValueError:
            seconds = float("nan")
        if np.isfinite(seconds) and seconds > 0:
            return "first", seconds
    raise RunError(f"trim must be 'first:<seconds>s' (e.g. first:1s), 'mean' or 'none', got {text!r}")


def remove_trim(run: Run, how: str = "first:1s", channels: list[str] | None = None) -> Run:
    """Every channel (or ``channels``) minus its trim value: the mean over the first seconds
    (``first:1s``, the steady flight before the input), the mean of the whole run (``mean``), or
    nothing (``none``). A linear model describes perturbations from trim; the values removed are
    recorded in the processing step, so the result can be traced and replayed."""
    kind, seconds = parse_trim(how)
    names = _channels(run, channels, list(run.channels))
    if kind == "none" or not names:
        return _record(run, {}, {"step": "trim", "how": "none"})
    keep = run.time <= run.time[0] + seconds + 1e-9 if kind == "first" else np.ones(len(run), bool)
    if kind == "first" and keep.sum() < 2:
        raise RunError(f"{run.source}: trim over the first {seconds:g} s holds fewer than two samples "
                       f"(sample interval {run.dt:g} s)")
    trim = {n: float(np.mean(run[n][keep])) for n in names}
    return _record(run, {n: run[n] - v for n, v in trim.items()},
                   {"step": "trim", "how": how, "channels": names, "values": trim})


# -- filters on arrays ------------------------------------------------------------------------
def _check_cutoff(cutoff_hz: float, dt: float, source: str) -> float:
    nyquist = 0.5 / dt
    if not (np.isfinite(cutoff_hz) and 0 < cutoff_hz < nyquist):
        raise RunError(f"{source}: cut-off {cutoff_hz:g} Hz must lie between 0 and the Nyquist "
                       f"frequency {nyquist:g} Hz (sample interval {dt:g} s)")
    return float(cutoff_hz)


def lowpass(x: np.ndarray, dt: float, cutoff_hz: float, order: int = 4, source: str = "<data>") -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x`` (N,) or (N, k) along time (axis 0).

    Run forwards and backwards, so the phase is zero and the magnitude is the Butterworth one
    squared (-6 dB at ``cutoff_hz``).
    """
    _check_cutoff(cutoff_hz, dt, source)
    x = np.asarray(x, dtype=float)
    from scipy.signal import butter, sosfiltfilt  # here: scipy.signal takes 0.4 s to import

    sos = butter(order, cutoff_hz, fs=1.0 / dt, output="sos")
    padlen = min(3 * (2 * len(sos) + 1) * 4, x.shape[0] - 1)  # long pad: less start-up transient
    return sosfiltfilt(sos, x, axis=0, padlen=padlen)


def differentiator_taps(dt: float, cutoff_hz: float, half_length: int | None = None) -> np.ndarray:
    """Antisymmetric FIR taps (2K+1,) of a band-limited differentiator, in 1/s.

    The ideal differentiator limited to ``|w| < wc`` has impulse response
    ``h[k] = (wc k dt cos(wc k dt) - sin(wc k dt)) / (pi k^2 dt^2)``; a Blackman window keeps the
    side lobes (noise leakage) low. ``h[-k] = -h[k]``: the response is purely imaginary, i.e.
    the phase is +90 degrees at every frequency; the gain is ``w`` in band.
    """
    wc = 2 * np.pi * cutoff_hz * dt  # rad/sample
    K = half_length or max(4, int(np.ceil(3.0 / (cutoff_hz * dt))))  # transition ~ cut-off wide
    k = np.arange(1, K + 1)
    h = (wc * k * np.cos(wc * k) - np.sin(wc * k)) / (np.pi * k ** 2)
    window = np.blackman(2 * K + 3)[K + 2:-1]  # right half, excluding the centre and zero end
    h = h * window
    # as taps on x[n+k] the sign flips (h above is for x[n-k]); normalising so that a unit ramp
    # gives exactly 1 (2 sum k h[k] = 1) fixes both the sign and the window's small gain error
    h = h / (2 * np.sum(k * h))
    return np.concatenate([-h[::-1], [0.0], h]) / dt  # taps for x[n-K] .. x[n+K]


def smooth_derivative(x: np.ndarray, dt: float, cutoff_hz: float) -> np.ndarray:
    """Time derivative of ``x`` (N,) or (N, k) by the band-limited differentiator, same shape.

    Ends are padded by point reflection (``2 x0 - x[-k]``), which keeps the slope at the end, so
    the derivative is not pulled towards zero there; within ``K`` samples of either end (the
    filter's half-length, ``3 / cutoff_hz`` s) curvature is lost and the error grows (a few % of
    the signal's derivative for rigid-body motions; see the tests).
    """
    x = np.asarray(x, dtype=float)
    taps = differentiator_taps(dt, cutoff_hz)
    K = (len(taps) - 1) // 2
    flat = x.reshape(len(x), -1)
    if len(x) <= K + 1:
        raise RunError(f"differentiation needs more than {K + 1} samples at {cutoff_hz:g} Hz cut-off, "
                       f"got {len(x)}")
    head = 2 * flat[:1] - flat[K:0:-1]
    tail = 2 * flat[-1:] - flat[-2:-K - 2:-1]
    padded = np.vstack([head, flat, tail])
    # y[n] = sum_k taps[K + k] x[n + k]: a correlation, i.e. convolution with the reversed taps
    from scipy.signal import fftconvolve  # here: scipy.signal takes 0.4 s to import

    out = fftconvolve(padded, taps[::-1, None], mode="valid", axes=0)
    return out.reshape(x.shape)


def central_difference(x: np.ndarray, dt: float) -> np.ndarray:
    """Plain central differences (one-sided at the ends): the baseline smoothing is measured against."""
    return np.gradient(np.asarray(x, dtype=float), dt, axis=0)


# -- steps on runs ----------------------------------------------------------------------------
def _channels(run: Run, channels, default) -> list[str]:
    names = list(default if channels is None else channels)
    run.require(names, "the processing step")
    return names


def smooth(run: Run, cutoff_hz: float = 6.25, channels: list[str] | None = None, order: int = 4) -> Run:
    """Zero-phase low-pass of ``channels`` (default: every channel) at ``cutoff_hz`` Hz.

    For equation error, smooth the inputs with the same filter as the states and derivatives
    (the default): the filter then applies to both sides of ``xdot = A x + B u`` and the
    equations stay consistent; smoothing the responses alone biases LS and IV (measured in the
    BO 105 study: their errors roughly halve when every channel is smoothed alike).
    """
    names = _channels(run, channels, list(run.channels))
    _check_cutoff(cutoff_hz, run.dt, run.source)
    if not names:
        return run
    out = lowpass(run.matrix(names), run.dt, cutoff_hz, order, run.source)
    return _record(run, {n: out[:, j] for j, n in enumerate(names)},
                   {"step": "smooth", "cutoff_hz": float(cutoff_hz), "order": int(order), "channels": names,
                    "filter": "Butterworth, forward-backward (zero phase)"})


def add_derivatives(run: Run, channels: list[str], cutoff_hz: float = 6.25, suffix: str = "_dot") -> Run:
    """Add ``<channel>_dot`` for each of ``channels`` by smoothed differentiation (units/s)."""
    names = _channels(run, channels, [])
    _check_cutoff(cutoff_hz, run.dt, run.source)
    d = smooth_derivative(run.matrix(names), run.dt, cutoff_hz)
    return _record(run, {n + suffix: d[:, j] for j, n in enumerate(names)},
                   {"step": "differentiate", "channels": names, "cutoff_hz": float(cutoff_hz), "suffix": suffix,
                    "filter": "band-limited FIR differentiator, Blackman window (90 deg phase)"})


def cg_correction(run: Run, offset, accels=("a_x", "a_y", "a_z"), rates=("p", "q", "r"),
                  rate_derivatives: tuple | None = None, cutoff_hz: float = 6.25) -> Run:
    """Move accelerometer readings to the centre of gravity.

    ``offset`` (3,) is the accelerometer position relative to the CG in body axes (x forward, y
    right, z down), m. A rigid body's specific force at that point is
    ``a_s = a_cg + w_dot x r + w x (w x r)``, so ``a_cg = a_s - w_dot x r - w x (w x r)``.
    ``accels`` and ``rates`` name the channels per axis; a name that is ``None`` or absent from the
    run counts as zero (a planar or partial set), but at least one acceleration and one rate must be
    present. Angular accelerations come from ``rate_derivatives`` channels if given, else from
    smoothed differentiation of the rates at ``cutoff_hz``. Corrected channels replace the originals.
    """
    r = np.asarray(offset, dtype=float)
    if r.shape != (3,) or not np.all(np.isfinite(r)):
        raise RunError(f"{run.source}: CG offset must be three finite numbers (x, y, z in m), got {offset!r}")
    present = [a for a in accels if a and a in run.channels]
    have_rate = [w for w in rates if w and w in run.channels]
    if not present or not have_rate:
        raise RunError(f"{run.source}: CG correction needs at least one of the acceleration channels "
                       f"{', '.join(a for a in accels if a)} and one of the rates {', '.join(w for w in rates if w)}")
    n = len(run)
    w = np.column_stack([run[x] if x and x in run.channels else np.zeros(n) for x in rates])
    if rate_derivatives is not None:
        wdot = np.column_stack([run[x] if x and x in run.channels else np.zeros(n) for x in rate_derivatives])
    else:
        wdot = smooth_derivative(w, run.dt, _check_cutoff(cutoff_hz, run.dt, run.source))
    extra = np.cross(wdot, r) + np.cross(w, np.cross(w, r))  # (N, 3)
    corrected = {a: run[a] - extra[:, i] for i, a in enumerate(accels) if a and a in run.channels}
    step = {"step": "cg_correction", "offset": r.tolist(), "accels": list(accels), "rates": list(rates),
            "cutoff_hz": float(cutoff_hz)}
    if rate_derivatives is not None:
        step["rate_derivatives"] = list(rate_derivatives)
    return _record(run, corrected, step)

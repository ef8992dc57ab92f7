"""Score any signal set on an a priori model at equal peak response: Fisher information,
D-efficiency, Cramér-Rao bounds, band coverage, the binding limit and robustness over a model set.

Every signal is sampled on one record grid (``record`` s at ``dt`` s, zero-order hold, zero
initial state), so all signals are compared on the same footing; the D-optimal designer uses
the same discrete model, so its figures agree with these to rounding.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identify import LinearModel, output_sensitivities, perturbed_model
from identify.errors import DesignError

from .band import excited_parameters, input_index
from .information import default_noise, log_det, relative_cramer_rao
from .signal import Signal
from .spectrum import half_power_band

PERTURBATION = 0.3  # the issue's "every derivative scaled by 0.7..1.3"


def perturbed_models(model: LinearModel, n: int = 24, spread: float = PERTURBATION,
                     seed: int = 0) -> list[LinearModel]:
    """Models with every free derivative scaled by a factor in 1 -/+ ``spread``: the two uniform
    corners (all x(1-spread), all x(1+spread)) and ``n - 2`` random draws, uniform per derivative."""
    if not 0 <= spread < 1:
        raise DesignError(f"perturbation spread must be in [0, 1), got {spread:g}")
    corners = [model.with_theta(model.theta * f) for f in (1 - spread, 1 + spread)]
    rng = np.random.default_rng(seed)
    return (corners + [perturbed_model(model, spread, rng) for _ in range(n - 2)])[:max(n, 2)]


def record_inputs(model: LinearModel, signals: list[Signal], record: float, dt: float) -> np.ndarray:
    """Inputs (N, m) on the record grid 0..record s, each signal on its own input column."""
    n_samples = int(round(record / dt)) + 1
    t = np.arange(n_samples) * dt
    u = np.zeros((n_samples, model.n_inputs))
    for s in signals:
        j = input_index(model, s.input)
        if s.end_time > record + 1e-9:
            raise DesignError(f"signal '{s.kind}' on {s.input} lasts until {s.end_time:g} s, longer than "
                              f"the {record:g} s record")
        u[:, j] += s(t)
    return u


@dataclass
class Score:
    """Figures of one signal set, every signal scaled to equal peak response (the largest output's
    peak over its limit = 1). ``d_eff`` is relative to the evaluator's reference on the a priori;
    ``worst_d_eff``/``mean_d_eff`` are the worst/geometric-mean over the evaluator's model set of the
    D-efficiency relative to each model's yardstick (the best-width 3211 tuned on that model)."""

    label: str
    log_det: float  # at equal peak response, a priori model
    d_eff: float
    mean_rel_crb: float
    worst_rel_crb: float
    band_covered: float  # fraction of the required band inside the signal's half-power band
    binding: str  # output whose limit binds at equal peak response
    scale: float  # factor on the signal's amplitude that brings it to equal peak response
    amplitude: float  # largest control amplitude at equal peak response (control units)
    worst_d_eff: float
    mean_d_eff: float
    worst_model: str


class Evaluator:
    """Information about ``model``'s parameters excited by ``inputs`` from signals on a record.

    ``params``: the parameter indices scored (default: those the inputs excite at all);
    ``noise_std`` (ny,): assumed measurement noise (default from units, see
    :func:`~signaldesign.information.default_noise`); ``models``: a model set for robustness
    (``model_labels`` names them); ``limits``: peak response allowed per output, ``{output: value}``
    in output units (default: the profile's ``[limits]``; outputs without a limit are free);
    ``bands``: required band (lo, hi) rad/s per input, for the band coverage.
    """

    def __init__(self, model: LinearModel, inputs, record: float = 20.0, dt: float = 0.05, noise_std=None,
                 band=None, models=None, params=None, limits=None, model_labels=None):
        self.model = model
        self.inputs = [inputs] if isinstance(inputs, str) else list(inputs)
        for name in self.inputs:
            input_index(model, name)
        check_record(record, dt)
        self.record, self.dt = float(record), float(dt)
        self.noise_std = default_noise(model.profile) if noise_std is None else np.asarray(noise_std, float)
        if params is None:
            params = sorted(set().union(*(excited_parameters(model, i) for i in self.inputs)))
        self.params = list(params)
        self.names = [model.names[i] for i in self.params]
        self.bands = _bands(band, self.inputs)
        self.models = list(models) if models is not None else []
        self.model_labels = list(model_labels) if model_labels is not None else [
            f"model {i}" for i in range(len(self.models))]
        self.set_limits(model.profile.limits if limits is None else limits, "the profile's [limits]")
        self.reference: list[Signal] | None = None
        self.yardstick_log_dets = None
        self._cache: dict = {}

    @property
    def p(self) -> int:
        return len(self.params)

    # -- limits -----------------------------------------------------------------------------------
    def set_limits(self, limits: dict, source: str) -> "Evaluator":
        """Peak response allowed per output (dict in output units); ``source`` says where from."""
        outputs = self.model.profile.outputs
        for y, v in dict(limits).items():
            if y not in outputs:
                raise DesignError(f"limit for '{y}': not an output (outputs: {', '.join(outputs)})")
            if not (np.isfinite(v) and v > 0):
                raise DesignError(f"limit for '{y}' = {v:g} must be positive")
        self.limits = np.array([float(limits.get(y, np.inf)) for y in outputs])
        self.limits_source = source if np.isfinite(self.limits).any() else None
        return self

    @property
    def has_limits(self) -> bool:
        return self.limits_source is not None

    def ratios(self, signals, model: LinearModel | None = None) -> np.ndarray:
        """Peak |y| over the record / limit per output (ny,); 0 for outputs without a limit."""
        if not self.has_limits:
            raise DesignError("no response limits: give the profile [limits] or use default_limits")
        return self.peaks(signals, model) / self.limits

    def response(self, signals, model: LinearModel | None = None) -> tuple[float, str]:
        """(largest peak/limit over outputs, that output's name)."""
        r = self.ratios(signals, model)
        i = int(np.argmax(r))
        if not r[i] > 0:
            raise DesignError("the signals move no output that has a response limit")
        return float(r[i]), self.model.profile.outputs[i]

    def equal_peak_log_det(self, signals, model: LinearModel | None = None) -> float:
        """log det of the information with the signals scaled to equal peak response on ``model``
        (information grows with amplitude squared, the peak with amplitude: log det - 2p log r)."""
        r, _ = self.response(signals, model)
        return log_det(self.information(signals, model)) - 2 * self.p * np.log(r)

    # -- responses --------------------------------------------------------------------------------
    def unit_responses(self, model: LinearModel):
        """Per input: (sensitivities (N, ny, p_scored) / noise, outputs (N, ny)) to a unit input held
        for the first sample only, cached per model. The discrete model is linear and time-invariant
        from rest, so any input's responses are these convolved with the input samples."""
        key = id(model)
        if key not in self._cache:
            n = int(round(self.record / self.dt)) + 1
            out = {}
            for name in self.inputs:
                u = np.zeros((n, model.n_inputs))
                u[0, input_index(model, name)] = 1.0
                sens = output_sensitivities(model, u, self.dt)
                out[name] = (sens.dy[:, :, self.params] / self.noise_std[None, :, None], sens.y)
            self._cache[key] = (model, out)  # keep the model alive so its id stays unique
        return self._cache[key][1]

    def _responses(self, signals, model: LinearModel | None):
        from scipy.signal import fftconvolve  # here: scipy.signal takes 0.4 s to import
        model = model or self.model
        u = record_inputs(model, _as_list(signals), self.record, self.dt)
        units = self.unit_responses(model)
        n = u.shape[0]
        dy, y = 0.0, 0.0
        for name in {s.input for s in _as_list(signals)}:
            if name not in units:
                raise DesignError(f"signal on '{name}' but the evaluator scores {', '.join(self.inputs)}")
            col = u[:, input_index(model, name)]
            S, Y = units[name]
            dy = dy + fftconvolve(col[:, None, None], S, axes=0)[:n]
            y = y + fftconvolve(col[:, None], Y, axes=0)[:n]
        return dy, y

    def information(self, signals, model: LinearModel | None = None) -> np.ndarray:
        """Fisher information (p, p) over the scored parameters."""
        dy, _ = self._responses(signals, model)
        return np.einsum("kyi,kyj->ij", dy, dy)

    def peaks(self, signals, model: LinearModel | None = None) -> np.ndarray:
        """max |y| over the record per output (ny,), output units."""
        return np.abs(self._responses(signals, model)[1]).max(axis=0)

    def robust_log_dets(self, signals) -> np.ndarray:
        """log det at equal peak response on every model of the set (n_models,); each model
        scales the signals to its own peak (amplitude build-up in flight meets the real response)."""
        return np.array([self.equal_peak_log_det(signals, m) for m in self.models])

    def set_reference(self, signals) -> "Evaluator":
        """Signals that D-efficiencies on the a priori are relative to (the best-width 3211)."""
        self.reference = _as_list(signals)
        self._ref = self.equal_peak_log_det(self.reference)
        return self

    def set_yardsticks(self, log_dets) -> "Evaluator":
        """Per model of the set, the equal-peak log det the robust columns are relative to."""
        self.yardstick_log_dets = np.asarray(log_dets, float)
        return self

    def score(self, signals, label: str | None = None) -> Score:
        signals = _as_list(signals)
        if self.reference is None:
            self.set_reference(signals)
        r, binding = self.response(signals)
        M = self.information(signals) / r ** 2
        ld = log_det(M)
        crb = relative_cramer_rao(M, self.model.theta[self.params]) if np.isfinite(ld) else np.full(self.p, np.inf)
        covered = [band_coverage(s, self.bands[s.input]) for s in signals if s.input in self.bands]
        worst = mean = float("nan")
        worst_model = "-"
        if self.models and self.yardstick_log_dets is not None:
            with np.errstate(invalid="ignore"):  # a singular model gives -inf, shown as 0
                rel = (self.robust_log_dets(signals) - self.yardstick_log_dets) / self.p
            i = int(np.argmin(rel))
            worst, mean, worst_model = float(np.exp(rel[i])), float(np.exp(rel.mean())), self.model_labels[i]
        with np.errstate(invalid="ignore"):  # a singular reference gives nan, shown as such
            d_eff = float(np.exp((ld - self._ref) / self.p))
        return Score(label or " + ".join(f"{s.kind} on {s.input}" for s in signals), ld, d_eff, float(np.mean(crb)), float(np.max(crb)),
                     float(np.mean(covered)) if covered else float("nan"), binding, 1.0 / r,
                     max(abs(s.amplitude) * float(np.abs(s.levels).max()) for s in signals) / r,
                     worst, mean, worst_model)


def check_record(record: float, dt: float) -> None:
    """One DesignError line for a record or time step that cannot be sampled."""
    if not (np.isfinite(dt) and dt > 0):
        raise DesignError(f"time step (--dt) must be positive, got {dt:g} s")
    if not (np.isfinite(record) and record >= 2 * dt):
        raise DesignError(f"record {record:g} s is not a usable record at a {dt:g} s time step")


def _bands(band, inputs) -> dict:
    if band is None:
        return {}
    if isinstance(band, dict):
        return dict(band)
    return {inputs[0]: tuple(band)}


def band_coverage(signal: Signal, band) -> float:
    """Fraction of the required band (lo, hi) rad/s, measured on a log-frequency axis (the band
    spans decades), that lies inside the signal's half-power band (the paper's Fig. 2 view)."""
    lo, hi = map(float, band)
    s_lo, s_hi, _ = half_power_band(signal)
    a, b = max(lo, s_lo), min(hi, s_hi)
    return float(max(0.0, np.log(b / a)) / np.log(hi / lo)) if b > a and hi > lo else 0.0


def _as_list(signals) -> list[Signal]:
    return [signals] if isinstance(signals, Signal) else list(signals)


def tune_width(factory, widths, evaluator: Evaluator, model: LinearModel | None = None):
    """The signal(s) ``factory(width)`` with the most information at equal peak response on
    ``model`` (the a priori by default; raw log det when there are no limits) over ``widths``
    (numbers, or tuples of one width per axis); returns (signals, width, log det)."""
    best = None
    for w in widths:
        w = tuple(float(x) for x in w) if isinstance(w, tuple) else float(w)
        s = factory(w)
        ld = (evaluator.equal_peak_log_det(s, model) if evaluator.has_limits
              else log_det(evaluator.information(s, model)))
        if best is None or ld > best[0]:
            best = (ld, s, w)
    if best is None:
        raise DesignError("no width to tune over")
    return best[1], best[2], best[0]


def format_scores(scores: list[Score], reference_label: str = "reference") -> str:
    """Plain-text comparison table, every signal at equal peak response."""
    w = max([34] + [len(s.label) for s in scores])
    head = (f"{'signal (each at equal peak response)':<{w}} {'log det M':>10} {'D-eff':>6} {'mean CRB':>9} "
            f"{'worst CRB':>9} {'band':>5} {'binds':>7} {'amplitude':>9} {'worst D-eff':>11} {'mean D-eff':>10}  worst model")
    rows = [head, "-" * len(head)]
    for s in scores:
        rows.append(f"{s.label:<{w}} {s.log_det:10.2f} {s.d_eff:6.3f} {100 * s.mean_rel_crb:8.2f}% "
                    f"{100 * s.worst_rel_crb:8.2f}% {100 * s.band_covered:4.0f}% {s.binding:>7} {s.amplitude:9.4f} "
                    f"{s.worst_d_eff:11.3f} {s.mean_d_eff:10.3f}  {s.worst_model}")
    rows.append(f"each signal scaled so that its largest peak/limit is 1; D-eff = (det M / det M_ref)^(1/p) "
                f"relative to {reference_label} on the a priori; CRB = Cramér-Rao std / |theta|; band = "
                f"fraction of the required band inside the half-power band; binds = the output at its "
                f"limit; amplitude = control amplitude at equal peak; worst/mean D-eff over the model set, each model relative to the best-width "
                f"3211 tuned on that model")
    return "\n".join(rows)

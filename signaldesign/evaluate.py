"""Score any signal set on an a priori model: Fisher information, D-efficiency, Cramér-Rao bounds,
in-band power, peak response and robustness over perturbed models.

Every signal is sampled on one record grid (``record`` s at ``dt`` s, zero-order hold, zero
initial state), so all signals are compared on the same footing; the D-optimal designer uses
the same discrete model, so its figures agree with these to rounding.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import fftconvolve

from identify import LinearModel, output_sensitivities, perturbed_model
from identify.errors import DesignError

from .band import excited_parameters, input_index
from .information import default_noise, log_det, relative_cramer_rao
from .signal import Signal
from .spectrum import in_band_fraction

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
    """Figures of one signal set; ``d_eff``/``worst_d_eff`` are relative to the evaluator's reference."""

    label: str
    log_det: float
    d_eff: float
    mean_rel_crb: float
    worst_rel_crb: float
    in_band: float
    peak: float  # largest over outputs of max|y| relative to the reference's
    worst_d_eff: float
    mean_d_eff: float


class Evaluator:
    """Information about ``model``'s parameters excited by ``inputs`` from signals on a record.

    ``params``: the parameter indices scored (default: those the inputs excite at all);
    ``noise_std`` (ny,): assumed measurement noise (default from units, see
    :func:`~signaldesign.information.default_noise`); ``models``: perturbed models for robustness.
    """

    def __init__(self, model: LinearModel, inputs, record: float = 20.0, dt: float = 0.05, noise_std=None,
                 band=None, models=None, params=None):
        self.model = model
        self.inputs = [inputs] if isinstance(inputs, str) else list(inputs)
        for name in self.inputs:
            input_index(model, name)
        if not (record > 0 and dt > 0 and record >= 2 * dt):
            raise DesignError(f"record {record:g} s and time step {dt:g} s are not a usable record")
        self.record, self.dt = float(record), float(dt)
        self.noise_std = default_noise(model.profile) if noise_std is None else np.asarray(noise_std, float)
        if params is None:
            params = sorted(set().union(*(excited_parameters(model, i) for i in self.inputs)))
        self.params = list(params)
        self.names = [model.names[i] for i in self.params]
        self.band = band
        self.models = list(models) if models is not None else []
        self.reference: list[Signal] | None = None
        self._ref_logdets = None
        self._cache: dict = {}

    @property
    def p(self) -> int:
        return len(self.params)

    def _unit_responses(self, model: LinearModel):
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
        model = model or self.model
        u = record_inputs(model, _as_list(signals), self.record, self.dt)
        units = self._unit_responses(model)
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
        """log det of the information on every perturbed model (n_models,)."""
        return np.array([log_det(self.information(signals, m)) for m in self.models])

    def set_reference(self, signals) -> "Evaluator":
        """Signals that D-efficiencies and peak responses are relative to (e.g. the best 3211)."""
        self.reference = _as_list(signals)
        self._ref = (log_det(self.information(self.reference)), self.peaks(self.reference))
        self._ref_logdets = self.robust_log_dets(self.reference) if self.models else None
        return self

    def score(self, signals, label: str | None = None) -> Score:
        signals = _as_list(signals)
        if self.reference is None:
            self.set_reference(signals)
        ld_ref, peak_ref = self._ref
        M = self.information(signals)
        ld = log_det(M)
        crb = relative_cramer_rao(M, self.model.theta[self.params]) if np.isfinite(ld) else np.full(self.p, np.inf)
        peaks = self.peaks(signals)
        ok = peak_ref > 0
        peak = float(np.max(peaks[ok] / peak_ref[ok])) if ok.any() else float("nan")
        fractions = [in_band_fraction(s, self.band) for s in signals] if self.band is not None else [np.nan]
        worst = mean = float("nan")
        if self.models:
            with np.errstate(invalid="ignore"):  # a reference singular on some model gives nan, shown
                rel = (self.robust_log_dets(signals) - self._ref_logdets) / self.p
            worst, mean = float(np.exp(rel.min())), float(np.exp(rel.mean()))
        return Score(label or " + ".join(f"{s.kind} on {s.input}" for s in signals), ld,
                     float(np.exp((ld - ld_ref) / self.p)), float(np.mean(crb)), float(np.max(crb)),
                     float(np.mean(fractions)), peak, worst, mean)


def _as_list(signals) -> list[Signal]:
    return [signals] if isinstance(signals, Signal) else list(signals)


def tune_width(factory, widths, evaluator: Evaluator):
    """The signal(s) ``factory(width)`` with the largest log det over ``widths`` (numbers, or tuples
    of one width per axis); returns (signals, width)."""
    best = None
    for w in widths:
        w = tuple(float(x) for x in w) if isinstance(w, tuple) else float(w)
        s = factory(w)
        ld = log_det(evaluator.information(s))
        if best is None or ld > best[0]:
            best = (ld, s, w)
    if best is None:
        raise DesignError("no width to tune over")
    return best[1], best[2]


def format_scores(scores: list[Score], reference_label: str = "reference") -> str:
    """Plain-text comparison table."""
    w = max([34] + [len(s.label) for s in scores])
    head = (f"{'signal':<{w}} {'log det M':>10} {'D-eff':>6} {'mean CRB':>9} {'worst CRB':>9} "
            f"{'in-band':>7} {'peak':>6} {'worst D-eff':>11} {'mean D-eff':>10}")
    rows = [head, "-" * len(head)]
    for s in scores:
        rows.append(f"{s.label:<{w}} {s.log_det:10.2f} {s.d_eff:6.3f} {100 * s.mean_rel_crb:8.2f}% "
                    f"{100 * s.worst_rel_crb:8.2f}% {100 * s.in_band:6.1f}% {s.peak:6.2f} "
                    f"{s.worst_d_eff:11.3f} {s.mean_d_eff:10.3f}")
    rows.append(f"D-eff = (det M / det M_ref)^(1/p), peak = max|y| / reference's, both relative to "
                f"{reference_label}; CRB = Cramér-Rao std / |theta|; worst/mean D-eff over perturbed models")
    return "\n".join(rows)

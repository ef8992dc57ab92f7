"""The flight-path reconstruction estimator: output error on the rigid-body kinematics.

Unknowns ``beta = [theta (the sensor errors in the model), x0 of every segment (7 each)]``: as the
engine's multiple shooting does for unstable models, each run is integrated in segments of
``SEGMENT`` s, each from its own estimated initial state, so the accelerometers' and gyros' noise,
integrated, cannot build up into a random walk over the whole run (which would make the residuals
strongly coloured, the bounds of the biases too confident and the score tests too eager). The
kinematics are nonlinear, so their sensitivities are not those of the linear output-error engine
(:mod:`identify.estimators.output_error`, whose linear time-invariant recursions do not apply to
a trajectory-dependent linearisation): they are central finite differences of the integrated
kinematics, all perturbations of a run integrated as one batch. The normal equations, the
Levenberg-Marquardt steps on them and the Cramér-Rao covariance are the engine's own
(:class:`~identify.estimators.information.BlockInformation`: the parameters shared by every run,
each run's initial state its own block), as is ML's noise-covariance relaxation (the noise
variance of each output re-estimated from the residuals after every step).

Sensor errors enter one at a time (forward selection): at the current fit, every error not yet in
the model is scored with refine's Lagrange-multiplier test (:class:`identify.refine.diagnostics.ScoreBase`:
the residual's energy along the candidate's sensitivity, orthogonal to the model's and the initial
states' columns, here divided by its variance under the residuals' own covariance: the integrated
accelerometer and gyro noise makes them coloured); the largest is added if it exceeds the Šidák threshold for the family-wise level
``alpha`` over the candidates tested, and the model refitted; the selection stops when none does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..estimators.information import BlockInformation
from . import kinematics as K
from .sensors import ANGULAR, SensorError, by_name, catalogue

# finite-difference steps: small against the sensors' resolution, large against rounding
_STEP = {"a_x": 1e-3, "a_y": 1e-3, "a_z": 1e-3, "p": 1e-5, "q": 1e-5, "r": 1e-5}
_X0_STEP = np.array([1e-3, 1e-3, 1e-3, 1e-5, 1e-5, 1e-5, 1e-3])
# s: each run is integrated in segments this long, each from its own estimated initial state. With the
# synthetic flight's gyro noise (benchmarks/compat.py, 10 seeds) the b_q bounds are honest at 3 s
# (RMS of error / std 1.01) and optimistic at 5 s (1.34) and 8 s (1.61): the integrated gyro noise
# colours the residuals more the longer a segment
SEGMENT = 3.0
MAX_LAG_SHARE = 0.25  # the residual autocovariance is used up to this share of a segment (Bartlett taper)
STEP_TOL_SE = 1e-2  # converged: the next Gauss-Newton step moves no unknown by 1/100 of its std error
R_CHANGE_TOL = 1e-4
MIN_SAMPLES = 50


@dataclass
class _RunData:
    source: str
    time: np.ndarray
    dt: float
    inputs: np.ndarray  # (N, 6) measured
    z: np.ndarray  # (N, ny) measured outputs


@dataclass
class _Response:
    y: list[np.ndarray]  # per segment (N, ny)
    e: list[np.ndarray]
    J: list[np.ndarray] | None = None  # per segment (N, ny, p + 7)
    extra: list[np.ndarray] | None = None  # per segment (N, ny, q): candidates not in the model


class _Problem:
    """Modelled outputs and their sensitivities for a set of sensor errors ``errors``."""

    def __init__(self, data: list[_RunData], outputs: list[str], errors: list[SensorError]):
        self.data, self.outputs, self.errors = data, outputs, errors
        self.col = [K.OUTPUTS.index(y) for y in outputs]
        self.p, self.S = len(errors), len(data)

    @property
    def n_beta(self) -> int:
        return self.p + 7 * self.S

    def split(self, beta):
        return beta[:self.p], beta[self.p:].reshape(self.S, 7)

    def _output_model(self, ykin: np.ndarray, t: np.ndarray, theta: dict) -> np.ndarray:
        """``K y_kin(t - tau) + b`` per output, ``ykin`` (B, N, ny)."""
        y = ykin.copy()
        for j, name in enumerate(self.outputs):
            tau, dk, b = (theta.get(f"{k}_{name}", 0.0) for k in ("tau", "K", "b"))
            if tau:
                y[:, :, j] = np.stack([np.interp(t - tau, t, row) for row in y[:, :, j]])
            y[:, :, j] = (1 + dk) * y[:, :, j] + b
        return y

    def evaluate(self, beta: np.ndarray, jacobian: bool = True, extra: list[SensorError] = ()) -> _Response:
        """Outputs, residuals and (with ``jacobian``) sensitivities of every segment: all segments
        and all finite-difference perturbations integrated as one batch (one time loop)."""
        theta_vec, x0 = self.split(beta)
        theta = {e.name: v for e, v in zip(self.errors, theta_vec)}
        bias = np.array([theta.get(f"b_{c}", 0.0) for c in K.INPUTS])
        perturb = []  # (kind, index, step): batch members beyond the first, +step then -step
        if jacobian:
            perturb = [("in", K.INPUTS.index(e.channel), _STEP[e.channel]) for e in (*self.errors, *extra)
                       if e.on_input]
            perturb += [("x0", i, _X0_STEP[i]) for i in range(7)]
        B, S = 1 + 2 * len(perturb), self.S
        L = max(len(d.time) for d in self.data)
        inputs = np.stack([np.pad(d.inputs, ((0, L - len(d.time)), (0, 0)), mode="edge") for d in self.data])
        biases = np.repeat(bias[None], B, axis=0)  # (B, 6)
        starts = np.repeat(x0[None], B, axis=0)  # (B, S, 7)
        for m, (kind, i, h) in enumerate(perturb):
            for sgn, row in ((1, 1 + 2 * m), (-1, 2 + 2 * m)):
                if kind == "in":
                    biases[row, i] += sgn * h
                else:
                    starts[row, :, i] += sgn * h
        drive = (inputs[None] - biases[:, None, None, :]).reshape(B * S, L, 6)
        states = K.integrate(starts.reshape(B * S, 7), drive, self.data[0].dt).reshape(B, S, L, 7)
        ykin = K.outputs(states)[..., self.col]
        ys, es, Js, Xs = [], [], [], []
        for s, d in enumerate(self.data):
            y = self._output_model(ykin[:, s, :len(d.time)], d.time, theta)
            if not np.all(np.isfinite(y[0])):
                raise EstimationError(f"{d.source}: the reconstructed trajectory diverges")
            ys.append(y[0])
            es.append(d.z - y[0])
            if not jacobian:
                continue
            diff = {(kind, i): (y[1 + 2 * m] - y[2 + 2 * m]) / (2 * h) for m, (kind, i, h) in enumerate(perturb)}

            def column(e: SensorError):
                if e.on_input:
                    return diff[("in", K.INPUTS.index(e.channel))]  # the batch perturbed b itself
                j = self.outputs.index(e.channel)
                out = np.zeros_like(y[0])
                gain = 1 + theta.get(f"K_{e.channel}", 0.0)
                shifted = (y[0][:, j] - theta.get(f"b_{e.channel}", 0.0)) / gain
                if e.kind == "bias":
                    out[:, j] = 1.0
                elif e.kind == "scale":
                    out[:, j] = shifted
                else:  # d/dtau of K y(t - tau) = -K y'(t - tau)
                    out[:, j] = -gain * np.gradient(shifted, d.dt)
                return out

            J = np.zeros((len(d.time), len(self.outputs), self.p + 7))
            for i, e in enumerate(self.errors):
                J[:, :, i] = column(e)
            for i in range(7):
                J[:, :, self.p + i] = diff[("x0", i)]
            Js.append(J)
            Xs.append(np.stack([column(e) for e in extra], axis=2) if extra else np.zeros(J.shape[:2] + (0,)))
        return _Response(ys, es, Js if jacobian else None, Xs if jacobian else None)

    def information(self, ev: _Response, R: np.ndarray) -> tuple[BlockInformation, np.ndarray]:
        """``M = J^T R^-1 J`` in the engine's block form and ``g = J^T R^-1 e``."""
        k = self.p + 7
        w = 1 / np.sqrt(R)
        local = np.zeros((self.S, k, k))
        index = np.zeros((self.S, k), int)
        g = np.zeros(self.n_beta)
        for r, (J, e) in enumerate(zip(ev.J, ev.e)):
            Jw = (J * w[None, :, None]).reshape(-1, k)
            local[r] = Jw.T @ Jw
            index[r] = np.r_[np.arange(self.p), self.p + 7 * r + np.arange(7)]
            np.add.at(g, index[r], Jw.T @ (e * w).ravel())
        return BlockInformation(local, index, self.n_beta, index[:, self.p:]), g


def _coloured_kernel(e: np.ndarray, max_lag: int) -> np.ndarray:
    """Per output (ny, 2L+1) the Bartlett-tapered autocovariance of the weighted residual ``e``
    (N, ny) at lags -L..L: the residual covariance as a Toeplitz kernel. The integrated noise of
    the accelerometers and gyros makes the residuals of a kinematic fit coloured (a random walk
    on the integrated states): white-noise bounds and scores would be too confident."""
    N = len(e)
    L = min(max_lag, N - 1)
    lags = np.arange(L + 1)
    gamma = np.array([np.einsum("ny,ny->y", e[lag:], e[:N - lag]) / N for lag in lags])  # (L+1, ny)
    taper = 1 - lags / (L + 1)
    half = gamma * taper[:, None]
    return np.concatenate([half[:0:-1], half]).T  # lags -L..L


def _toeplitz_apply(kernel: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``T_y X`` per output: ``X`` (N, ny, k), ``kernel`` (ny, 2L+1)."""
    from scipy.signal import fftconvolve

    L = (kernel.shape[1] - 1) // 2
    out = np.empty_like(X)
    for j in range(X.shape[1]):
        full = fftconvolve(X[:, j, :], kernel[j][:, None], mode="full", axes=0)
        out[:, j, :] = full[L:L + len(X)]
    return out


def _cost(ev: _Response, R: np.ndarray) -> float:
    return 0.5 * float(sum(np.sum(e ** 2 / R) for e in ev.e))


def _relaxed(ev: _Response) -> np.ndarray:
    e = np.vstack(ev.e)
    return np.maximum(np.mean(e ** 2, axis=0), 1e-30)


@dataclass
class _Fit:
    beta: np.ndarray
    ev: _Response
    R: np.ndarray
    M: BlockInformation
    iterations: int
    converged: bool
    stop: str


def _solve(prob: _Problem, beta: np.ndarray, max_iter: int) -> _Fit:
    """Levenberg-Marquardt with noise-covariance relaxation, from ``beta``."""
    ev = prob.evaluate(beta)
    R = _relaxed(ev)
    M, g = prob.information(ev, R)
    lam, it, stop, converged = 1e-3, 0, "max_iter", False
    r_change = np.inf
    while it < max_iter:
        step0 = M.solve(g, 0.0)
        in_se = math.sqrt(max(float(g @ step0), 0.0))
        if in_se < STEP_TOL_SE and r_change < R_CHANGE_TOL:
            converged, stop = True, f"gradient: the next step is {in_se:.1e} standard errors"
            break
        cost = _cost(ev, R)
        while lam < 1e8:
            trial = beta + M.solve(g, lam)
            try:
                t_ev = prob.evaluate(trial, jacobian=False)
                c = _cost(t_ev, R)
            except EstimationError:
                c = np.inf
            if c < cost:
                break
            lam *= 10
        else:
            converged = in_se < 10 * STEP_TOL_SE
            stop = f"no step lowers the cost (next step {in_se:.1e} standard errors)"
            break
        it += 1
        beta, lam = trial, max(lam / 10, 1e-9)
        ev = prob.evaluate(beta)
        R_new = _relaxed(ev)
        r_change = float(np.max(np.abs(R_new / R - 1)))
        R = R_new
        M, g = prob.information(ev, R)
    return _Fit(beta, ev, R, M, it, converged, stop)


@dataclass
class CompatResult:
    """Estimated sensor errors: ``errors`` (names), ``value`` (as reported: scale factors as K),
    ``std`` (Cramér-Rao corrected for coloured residuals, Morelli & Klein), ``steps`` of the selection, per-output residual RMS
    ``rms_before`` (no sensor error modelled) and ``rms_after``, ``noise_std`` per output,
    per-run initial states and the convergence of the final fit."""

    errors: list[SensorError]
    value: np.ndarray
    std: np.ndarray
    covariance: np.ndarray
    outputs: list[str]
    steps: list[dict]
    rms_before: dict[str, float]
    rms_after: dict[str, float]
    noise_std: dict[str, float]
    x0: list[dict]
    converged: bool
    stop: str
    iterations: int
    runs: list[str]
    alpha: float
    info: dict = field(default_factory=dict)
    residuals_before: list[np.ndarray] = field(default_factory=list, repr=False)
    residuals_after: list[np.ndarray] = field(default_factory=list, repr=False)
    time: list[np.ndarray] = field(default_factory=list, repr=False)

    def parameters(self) -> dict[str, dict]:
        out = {}
        for e, v, s in zip(self.errors, self.value, self.std):
            entry = {"value": float(v), "std": float(s), "unit": e.unit}
            if e.channel in ANGULAR and e.kind == "bias":
                entry.update(value_deg=float(np.degrees(v)), std_deg=float(np.degrees(s)))
            out[e.name] = entry
        return out

    def summary(self) -> str:
        lines = [f"flight-path reconstruction of {len(self.runs)} run(s): outputs {', '.join(self.outputs)}",
                 f"sensor errors selected by score tests (family-wise level {self.alpha:g}):"]
        for s in self.steps:
            lines.append(f"  step {s['step']}: {s['error']} (score {s['statistic']:.4g} > {s['threshold']:.4g})")
        if not self.steps:
            lines.append("  none: the measurements agree with the kinematics within their noise")
        lines.append(f"{'sensor error':<16}{'estimate':>13}{'std error':>12}  unit")
        for name, p in self.parameters().items():
            text = f"{name:<16}{p['value']:13.6g}{p['std']:12.4g}  {p['unit']}"
            if "value_deg" in p:
                text += f"  ({p['value_deg']:.4g} ± {p['std_deg']:.2g} deg{'/s' if p['unit'] == 'rad/s' else ''})"
            lines.append(text)
        lines.append(f"convergence: {'converged' if self.converged else 'NOT CONVERGED'} after "
                     f"{self.iterations} iterations ({self.stop})")
        lines.append(f"{'output':<10}{'RMS before':>14}{'RMS after':>14}")
        lines += [f"{y:<10}{self.rms_before[y]:14.4g}{self.rms_after[y]:14.4g}" for y in self.outputs]
        return "\n".join(lines)

    def corrected(self, runs: list[Run]) -> list[Run]:
        """``runs`` with the estimated errors removed from their channels: inputs minus their
        biases; outputs ``(measured(t + tau) - b) / K``; samples a skew would take beyond the
        record's end are cut (said in the run's metadata)."""
        theta = {e.name: v for e, v in zip(self.errors, self.value)}
        out = []
        for run in runs:
            t = run.time
            ch = dict(run.channels)
            for e in self.errors:
                if e.kind == "bias" and e.on_input:
                    ch[e.channel] = ch[e.channel] - theta[e.name]
            shift = 0.0
            for y in self.outputs:
                tau, k, b = theta.get(f"tau_{y}", 0.0), theta.get(f"K_{y}", 1.0), theta.get(f"b_{y}", 0.0)
                if tau or k != 1.0 or b:
                    ch[y] = (np.interp(t + tau, t, ch[y]) - b) / k
                    shift = max(shift, abs(tau))
            keep = np.ones(len(t), bool)
            taus = [theta.get(f"tau_{y}", 0.0) for y in self.outputs]
            if any(taus):
                keep &= (t + max(max(taus), 0.0) <= t[-1] + 1e-12) & (t + min(min(taus), 0.0) >= t[0] - 1e-12)
            note = ", ".join(f"{e.name} = {v:.6g} {e.unit}" for e, v in zip(self.errors, self.value))
            meta = dict(run.meta, compat_corrected=note or "no sensor error found")
            if not keep.all():
                meta["compat_cut"] = f"{int((~keep).sum())} end sample(s) cut: the time skew moves them beyond the record"
            out.append(Run(t[keep], {k: v[keep] for k, v in ch.items()}, meta, run.source))
        return out

    def to_dict(self) -> dict:
        return {"runs": self.runs, "outputs": self.outputs, "alpha": self.alpha,
                "sensor_errors": self.parameters(), "steps": self.steps,
                "correlation": _correlation(self.covariance).tolist(),
                "residual_rms": {"before": self.rms_before, "after": self.rms_after},
                "noise_std": self.noise_std, "initial_states": self.x0,
                "converged": self.converged, "stop": self.stop, "iterations": self.iterations, **self.info}


def _correlation(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num(cov / np.outer(d, d))


class Compat:
    """Flight-path reconstruction (scikit-learn style: ``Compat(...).fit(runs).result_``).

    Runs need the inputs :data:`~identify.compat.kinematics.INPUTS` (``a_x, a_y, a_z`` specific
    force in m/s^2, ``p, q, r`` in rad/s) and any of the outputs
    :data:`~identify.compat.kinematics.OUTPUTS` (``V`` m/s, ``alpha``, ``beta``, ``phi``,
    ``theta``, ``psi`` rad, ``h`` m): those present are compared. ``errors``: sensor errors to
    estimate without selection (names such as ``b_q``, ``K_alpha``, ``tau_alpha``); None (default)
    selects them with score tests at family-wise level ``alpha`` from ``candidates`` (default the
    whole :func:`~identify.compat.sensors.catalogue`), at most ``max_steps``.
    """

    def __init__(self, errors=None, *, alpha: float = 0.01, candidates=None, max_steps: int = 12,
                 max_iter: int = 30, segment: float = SEGMENT, progress=None):
        self.errors, self.alpha, self.candidates, self.segment = errors, alpha, candidates, segment
        self.max_steps, self.max_iter, self.progress = max_steps, max_iter, progress
        self.result_: CompatResult | None = None

    def _data(self, runs: list[Run]) -> tuple[list[_RunData], list[str]]:
        runs = [runs] if isinstance(runs, Run) else list(runs)
        if not runs:
            raise EstimationError("compat: no runs given")
        for run in runs:
            run.require(list(K.INPUTS), "flight-path reconstruction (accelerations and rates drive the kinematics)")
            if len(run) < MIN_SAMPLES:
                raise EstimationError(f"{run.source}: only {len(run)} samples; at least {MIN_SAMPLES} needed")
        outputs = [y for y in K.OUTPUTS if all(y in r.channels for r in runs)]
        if not {"V", "alpha"} & set(outputs) or not outputs:
            raise EstimationError(f"compat: the runs hold none of the outputs {', '.join(K.OUTPUTS)} in common")
        if len({round(r.dt, 9) for r in runs}) > 1:
            raise EstimationError("compat: the runs have different sample intervals: resample them to one")
        data = []
        for r in runs:
            z = np.column_stack([np.unwrap(r[y]) if y == "psi" else r[y] for y in outputs])
            n_seg = max(1, int(round(r.duration / self.segment))) if math.isfinite(self.segment) else 1
            for k, rows in enumerate(np.array_split(np.arange(len(r)), n_seg)):
                where = r.source if n_seg == 1 else f"{r.source} [{r.time[rows[0]]:g}..{r.time[rows[-1]]:g} s]"
                data.append(_RunData(where, r.time[rows] - r.time[rows[0]], r.dt, r.matrix(list(K.INPUTS))[rows],
                                     z[rows]))
        return data, outputs

    def fit(self, runs) -> "Compat":
        if not (0 < self.alpha < 1):
            raise EstimationError(f"compat: alpha must lie in (0, 1), got {self.alpha}")
        runs = [runs] if isinstance(runs, Run) else list(runs)
        data, outputs = self._data(runs)
        pool = catalogue(K.INPUTS, outputs)
        if self.candidates is not None:
            pool = [by_name(n, K.INPUTS, outputs) for n in self.candidates]
        chosen = [by_name(n, K.INPUTS, outputs) for n in (self.errors or [])]
        x0 = np.concatenate([K.initial_state(dict(zip(outputs, d.z[0]))) for d in data])
        before = _solve(_Problem(data, outputs, []), x0, self.max_iter)
        if self.errors is not None:
            prob = _Problem(data, outputs, chosen)
            fit = _solve(prob, np.r_[np.zeros(len(chosen)), before.beta], self.max_iter) if chosen else before
            steps = []
        else:
            # the residuals' colour comes from the richest model the white-noise scores select (its
            # residuals are the noise, not unmodelled sensor errors); the selection is then made
            # again with the scores that colour gives
            fits = {}  # by the errors in the model, in order: the second pass refits none the first made
            prob, fit, _ = self._select(data, outputs, pool, before, None, fits)
            kernels = [_coloured_kernel(e, int(MAX_LAG_SHARE * len(e))) for e in fit.ev.e]
            prob, fit, steps = self._select(data, outputs, pool, before, kernels, fits)
        self.result_ = self._result(runs, prob, before, fit, steps)
        return self

    def _select(self, data, outputs, pool, before: _Fit, kernels, fits: dict):
        """Forward selection from no sensor error: ``(problem, fit, steps)``; ``kernels`` the
        residual covariance per run (None: white)."""
        from scipy import stats

        prob, fit, steps = _Problem(data, outputs, []), before, []
        while len(steps) < self.max_steps:
            left = [e for e in pool if e not in prob.errors]
            if not left:
                break
            best, stat, threshold = self._score(prob, fit, left, kernels)
            if self.progress:
                self.progress(f"compat ({'white' if kernels is None else 'coloured'} scores): best candidate "
                              f"{best.name}: score {stat:.4g} (threshold {threshold:.4g})")
            if not stat > threshold:
                break
            steps.append({"step": len(steps) + 1, "error": best.name, "statistic": stat, "threshold": threshold,
                          "p_value": float(stats.chi2.sf(stat, 1)), "candidates": len(left)})
            key = tuple(e.name for e in (*prob.errors, best))
            if key not in fits:
                theta, xs = prob.split(fit.beta)
                new = _Problem(data, outputs, [*prob.errors, best])
                fits[key] = new, _solve(new, np.r_[theta, 0.0, xs.ravel()], self.max_iter)
            prob, fit = fits[key]
        return prob, fit, steps

    def _score(self, prob: _Problem, fit: _Fit, left: list[SensorError], kernels):
        """The candidate with the largest score statistic, it and the Šidák threshold; ``kernels``
        the residual autocovariance per run (unweighted, (ny, 2L+1)), None for white residuals."""
        from ..refine.diagnostics import ScoreBase, sidak_threshold

        ev = prob.evaluate(fit.beta, extra=left)
        sigma = np.sqrt(fit.R)
        k = prob.p + 7
        base = np.zeros((sum(e.size for e in ev.e), prob.p + 7 * prob.S))
        row = 0
        for r, J in enumerate(ev.J):  # parameters shared by every run, initial states per run
            m = J.shape[0] * J.shape[1]
            flat = J.reshape(m, k)
            base[row:row + m, :prob.p] = flat[:, :prob.p]
            base[row:row + m, prob.p + 7 * r:prob.p + 7 * r + 7] = flat[:, prob.p:]
            row += m
        sb = ScoreBase.build(ev.e, base, sigma)
        # refine's score, g^2 / (c' c) for the candidate column c orthogonal to the model's, with
        # the residual's own covariance in the denominator, g^2 / (c' T c): the same statistic for
        # white residuals, chi-square(1) also for the coloured ones a kinematic fit leaves
        w = 1 / sigma
        Jc = np.concatenate([(X * w[None, :, None]).reshape(-1, X.shape[2]) for X in ev.extra])
        perp = Jc - sb.Q @ (sb.Q.T @ Jc)
        e_perp = sb.e - sb.Q @ (sb.Q.T @ sb.e)
        g = perp.T @ e_perp
        var = np.zeros(len(left))
        row = 0
        for r, e in enumerate(ev.e):
            m = e.size
            P = perp[row:row + m].reshape(e.shape[0], e.shape[1], -1)
            var += np.einsum("nyk,nyk->k", P, P if kernels is None else
                             _toeplitz_apply(kernels[r] * (w ** 2)[:, None], P))
            row += m
        scores = np.where(var > 0, g ** 2 / np.maximum(var, 1e-300), 0.0)
        i = int(np.argmax(scores))
        return left[i], float(scores[i]), sidak_threshold(self.alpha, len(left), 1)

    @staticmethod
    def _coloured_covariance(prob: _Problem, fit: _Fit) -> np.ndarray:
        """``M^-1 B M^-1`` (Morelli & Klein) for the sensor errors: ``B = J' R^-1/2 T R^-1/2 J``
        with ``T`` the residuals' own (tapered) covariance, M the information matrix."""
        k, w = prob.p + 7, 1 / np.sqrt(fit.R)
        J = np.zeros((prob.n_beta, prob.n_beta))
        B = np.zeros_like(J)
        for r, (Jr, e) in enumerate(zip(fit.ev.J, fit.ev.e)):
            Jw = Jr * w[None, :, None]
            idx = np.r_[np.arange(prob.p), prob.p + 7 * r + np.arange(7)]
            kernel = _coloured_kernel(e * w, int(MAX_LAG_SHARE * len(e)))
            J[np.ix_(idx, idx)] += np.einsum("nyk,nyl->kl", Jw, Jw)
            B[np.ix_(idx, idx)] += np.einsum("nyk,nyl->kl", Jw, _toeplitz_apply(kernel, Jw))
        active = np.diag(J) > 0
        Minv = np.zeros_like(J)
        Minv[np.ix_(active, active)] = np.linalg.pinv(J[np.ix_(active, active)], hermitian=True)
        return (Minv @ B @ Minv)[:prob.p, :prob.p]

    def _result(self, runs, prob: _Problem, before: _Fit, fit: _Fit, steps) -> CompatResult:
        P = prob.p
        cov, ill = np.zeros((0, 0)), False
        if P:
            cov = self._coloured_covariance(prob, fit)
            ill = fit.M.covariance()[1]
        d = np.diag(cov)
        std = np.where(d > 0, np.sqrt(np.where(d > 0, d, 0.0)), np.nan)
        theta, xs = prob.split(fit.beta)
        value = np.array([e.display(v) for e, v in zip(prob.errors, theta)])

        def rms(ev):
            e = np.vstack(ev.e)
            return {y: float(np.sqrt(np.mean(e[:, j] ** 2))) for j, y in enumerate(prob.outputs)}

        return CompatResult(
            errors=list(prob.errors), value=value, std=std, covariance=cov, outputs=prob.outputs, steps=steps,
            rms_before=rms(before.ev), rms_after=rms(fit.ev),
            noise_std={y: float(np.sqrt(v)) for y, v in zip(prob.outputs, fit.R)},
            x0=[dict(zip(K.STATES, map(float, x))) for x in xs], converged=fit.converged, stop=fit.stop,
            iterations=fit.iterations, runs=[r.source for r in runs], alpha=self.alpha,
            info={"ill_conditioned": bool(ill), "method": "output error (ML, relaxed noise covariance) on the "
                  "rigid-body kinematics; finite-difference sensitivities; Levenberg-Marquardt on the "
                  "engine's block information matrix"},
            residuals_before=before.ev.e, residuals_after=fit.ev.e, time=[d.time for d in prob.data])

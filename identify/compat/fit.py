"""The flight-path reconstruction estimator: the output-error engine on the rigid-body kinematics.

:class:`KinematicProblem` puts the kinematics on the engine's seam
(:mod:`identify.estimators.output_error`): unknowns ``beta = [theta (the sensor errors in the
model), x0 of every segment (7 each)]``; each run is integrated in segments of ``SEGMENT`` s,
each from its own estimated initial state (the engine's multiple shooting), so the
accelerometers' and gyros' noise, integrated, cannot build up into a random walk over the whole
run. The kinematics are nonlinear: the problem supplies the prediction and its sensitivities
(central finite differences of the integration, all perturbations and segments as one batch; the
output model's columns exact), the engine does the rest: ML's Levenberg-Marquardt with
noise-covariance relaxation (:class:`identify.estimators.ml.OutputErrorSolver`, on the one solver of
:mod:`identify.estimators.lm`), the block information
matrix and the coloured-residual bounds (:class:`~identify.estimators.coloured_bounds.ColouredBounds`).

The bounds add to the engine's sandwich (the outputs' own, possibly coloured, noise) the noise of
the measured inputs integrated through the kinematics (errors in the variables,
:func:`_input_noise_information`): it moves theta and alpha alike (and h with alpha), a coupling
of the outputs that the per-output Toeplitz of the coloured bounds cannot hold.

Sensor errors enter one at a time (forward selection): at the current fit, every error not yet in
the model is scored with refine's Lagrange-multiplier test (:class:`identify.refine.diagnostics.ScoreBase`:
the residual's energy along the candidate's sensitivity, orthogonal to the model's and the initial
states' columns, here divided by its variance under the noise autocorrelation the engine's coloured
bounds estimate); the largest is added if it exceeds the Šidák threshold for the family-wise level
``alpha`` over the candidates tested, and the model refitted; the selection stops when none does.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError, SimulationError
from ..estimators.colour import toeplitz_apply
from ..estimators.ml import R_CHANGE_TOL, OutputErrorSolver
from ..estimators.output_error import Layout, OutputError, Response
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
STEP_TOL = 1e-10  # relative parameter step: never the convergence test (sensor errors start at 0); the engine's
                  # test in standard errors is
MIN_SAMPLES = 50


@dataclass
class _RunData:
    """One segment of a run: ``run`` its index, ``time`` from the segment's start."""

    source: str
    run: int
    time: np.ndarray
    dt: float
    inputs: np.ndarray  # (N, 6) measured
    z: np.ndarray  # (N, ny) measured outputs


@dataclass
class _Settings:
    """What the engine's solver reads from its estimator (:class:`identify.estimators.ml.ML`)."""

    max_iter: int
    tol: float = STEP_TOL
    noise_cov_: None = None  # relaxation
    relax_from_: None = None  # from the a priori residuals
    tol_se: float = R_CHANGE_TOL
    progress: None = None
    verbose: bool = False


class KinematicProblem(OutputError):
    """Flight-path reconstruction on the output-error engine's seam (:mod:`identify.estimators.output_error`).

    Unknowns ``beta = [theta (the sensor errors ``errors``), x0 of every segment (7 each)]``; no
    zero shifts of the engine's kind (output biases are sensor errors, shared by the runs). The
    prediction integrates the kinematics of every segment and its sensitivities are central finite
    differences, all segments and perturbations in one batch (one time loop); the engine does the
    rest. ``__init__`` sets the attributes the engine reads, not a linear model's (no ``super()``).
    """

    def __init__(self, data: list[_RunData], outputs: list[str], errors: list[SensorError]):
        self.data, self.outputs, self.errors = data, outputs, errors
        self.col = [K.OUTPUTS.index(y) for y in outputs]
        S = len(data)
        self.p, self.n, self.ny, self.m, self.dt = len(errors), 7, len(outputs), 6, data[0].dt
        self.layout = Layout(np.array([d.run for d in data]), np.zeros(S, int), np.array([len(d.time) for d in data]))
        L = self.layout.L
        self.n_runs = int(self.layout.run.max()) + 1
        self.Z, self.mask = np.zeros((L, self.ny, S)), np.zeros((L, S))
        for s, d in enumerate(data):
            self.Z[:len(d.time), :, s], self.mask[:len(d.time), s] = d.z, 1.0
        self.estimate_x0, self.estimate_bias = True, False
        self.local_index = np.hstack([np.tile(np.arange(self.p), (S, 1)),
                                      self.p + np.arange(7 * S).reshape(S, 7), -np.ones((S, self.ny), int)])
        self.n_beta = self.p + 7 * S

    def names(self) -> list[str]:
        return [e.name for e in self.errors] + [f"x0[{s}].{x}" for s in range(len(self.data)) for x in K.STATES]

    def segment_groups(self) -> list[tuple[int, int]]:
        return [(0, len(self.data))]  # the sensitivities are held whole

    def split(self, beta):
        return beta[:self.p], beta[self.p:].reshape(-1, 7)

    def _output_model(self, ykin: np.ndarray, t: np.ndarray, theta: dict) -> np.ndarray:
        """``K y_kin(t - tau) + b`` per output, ``ykin`` (B, N, ny)."""
        y = ykin.copy()
        for j, name in enumerate(self.outputs):
            tau, dk, b = (theta.get(f"{k}_{name}", 0.0) for k in ("tau", "K", "b"))
            if tau:
                y[:, :, j] = _shifted(y[:, :, j], t, tau)
            y[:, :, j] = (1 + dk) * y[:, :, j] + b
        return y

    def evaluate(self, beta: np.ndarray, jacobian: bool = True, extra: list[SensorError] = ()) -> Response:
        """Outputs, residuals and (with ``jacobian``) sensitivities of every segment, as the
        engine's :class:`~identify.estimators.output_error.Response` (``dy_x0`` per segment);
        ``extra`` candidates not in the model get their sensitivities in ``ev.extra`` (per segment
        (N_s, ny, q)) for the score tests."""
        theta_vec, x0 = self.split(beta)
        theta = {e.name: v for e, v in zip(self.errors, theta_vec)}
        bias = np.array([theta.get(f"b_{c}", 0.0) for c in K.INPUTS])
        perturb = []  # (kind, index, step): batch members beyond the first, +step then -step
        if jacobian:
            perturb = [("in", K.INPUTS.index(e.channel), _STEP[e.channel]) for e in (*self.errors, *extra)
                       if e.on_input]
            perturb += [("x0", i, _X0_STEP[i]) for i in range(7)]
        B, S, L = 1 + 2 * len(perturb), len(self.data), self.layout.L
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
        with np.errstate(over="ignore", invalid="ignore"):  # divergence is reported below
            states = K.integrate(starts.reshape(B * S, 7), drive, self.dt).reshape(B, S, L, 7)
            ykin = K.outputs(states)[..., self.col]
        y_all = np.zeros((L, self.ny, S))
        dy_x0, dy_theta, extras = np.zeros((L, self.ny, 7, S)), np.zeros((L, self.ny, self.p, S)), []
        for s, d in enumerate(self.data):
            N = len(d.time)
            y = self._output_model(ykin[:, s, :N], d.time, theta)
            if not np.all(np.isfinite(y[0])):
                raise SimulationError(f"{d.source}: the reconstructed trajectory diverges")
            y_all[:N, :, s] = y[0]
            if not jacobian:
                continue
            diff = {(kind, i): (y[1 + 2 * m] - y[2 + 2 * m]) / (2 * h) for m, (kind, i, h) in enumerate(perturb)}
            for i, e in enumerate(self.errors):
                dy_theta[:N, :, i, s] = self._column(e, diff, y[0], ykin[0, s, :N], d.time, theta)
            for i in range(7):
                dy_x0[:N, :, i, s] = diff[("x0", i)]
            columns = [self._column(e, diff, y[0], ykin[0, s, :N], d.time, theta) for e in extra]
            extras.append(np.stack(columns, axis=2) if columns else np.zeros((N, self.ny, 0)))
        ev = Response(beta.copy(), np.where(self.mask[:, None, :] > 0, self.Z - y_all, 0.0), y_all)
        if jacobian:
            ev.dy_x0, ev.held, ev.extra = dy_x0, dy_theta, extras
            # for the input-noise term of the bounds (:func:`_input_noise_information`): the
            # trajectory, the inputs driving it and the state transition from each segment's start
            x0_rows = [m for m, (kind, _, _) in enumerate(perturb) if kind == "x0"]
            ev.states, ev.drive = states[0], drive[:S]
            ev.dx_x0 = np.stack([(states[1 + 2 * m] - states[2 + 2 * m]) / (2 * perturb[m][2]) for m in x0_rows],
                                axis=-1)  # (S, L, 7 states, 7 initial states)
        return ev

    def _column(self, e: SensorError, diff: dict, y: np.ndarray, ykin: np.ndarray, t: np.ndarray,
                theta: dict) -> np.ndarray:
        """Sensitivity (N, ny) of the outputs of one segment (modelled ``y``, kinematic ``ykin``
        at the times ``t`` from its start) to sensor error ``e``."""
        if e.on_input:
            return diff[("in", K.INPUTS.index(e.channel))]  # the batch perturbed b itself
        j = self.outputs.index(e.channel)
        out = np.zeros_like(y)
        gain = 1 + theta.get(f"K_{e.channel}", 0.0)
        if e.kind == "bias":
            out[:, j] = 1.0
        elif e.kind == "scale":
            out[:, j] = (y[:, j] - theta.get(f"b_{e.channel}", 0.0)) / gain
        else:
            out[:, j] = gain * _skew_sensitivity(ykin[:, j], t, theta.get(e.name, 0.0))
        return out

    def segments(self, arr: np.ndarray) -> list[np.ndarray]:
        """(L, ny, S) back to one (N_s, ny) array per segment."""
        return [arr[:n, :, s] for s, n in enumerate(self.layout.length)]


@dataclass
class _Fit:
    prob: KinematicProblem
    beta: np.ndarray
    ev: Response
    Wh: np.ndarray
    M: object  # the engine's BlockInformation at the estimate
    iterations: int
    converged: bool
    stop: str

    @property
    def R(self) -> np.ndarray:
        return 1 / np.diag(self.Wh) ** 2

    def coloured(self):
        """The engine's coloured-residual covariance (Morelli & Klein, residuals corrected for the
        fit's projection): ``(BlockCovariance, rho)``, rho (L, ny) the whitened noise autocorrelation."""
        cov, rho, _ = self.prob.coloured_information(self.ev, self.Wh, self.M)
        return cov, rho


def _solve(prob: KinematicProblem, beta: np.ndarray, max_iter: int) -> _Fit:
    """ML's Levenberg-Marquardt with noise-covariance relaxation (the engine's solver), from ``beta``."""
    ev = prob.evaluate(beta)
    sv = _EngineSolver(_Settings(max_iter), prob, ev, [d.z for d in prob.data])
    sv.run()
    return _Fit(prob, sv.beta, sv.ev, sv.Wh, sv.M, sv.iterations, sv.converged, sv.stop)


class _EngineSolver(OutputErrorSolver):
    name = "compat"
    requires_parameters = False  # the first fit holds no sensor error: initial states alone


def _shifted(y: np.ndarray, t: np.ndarray, tau: float, axis: int = -1) -> np.ndarray:
    """``y(t - tau)`` along ``axis`` (samples at ``t``) by a cubic spline through the samples,
    extrapolated by its end pieces for the few samples a skew reaches beyond the record. Smooth in
    ``tau`` throughout: linear interpolation, or values held at the ends, make the cost piecewise
    quadratic with a kink at every whole sample, and an estimate on a kink stalled the solver (no
    step lowers the cost although a one-sided slope says one should); a skew is a continuous-time
    delay anyway."""
    from scipy.interpolate import CubicSpline

    return CubicSpline(t, y, axis=axis)(t - tau)


def _skew_sensitivity(y: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """``d/dtau`` of :func:`_shifted` (``y`` (N,)): minus the spline's slope at ``t - tau``. Exact:
    a central difference of the shifted output (a smoothed slope) moved the Gauss-Newton fixed
    point off the cost's minimum by 0.1 standard error."""
    from scipy.interpolate import CubicSpline

    return -CubicSpline(t, y)(t - tau, 1)


def _input_matrix(states: np.ndarray, inputs: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """``df/da`` (N, 7, 6) of the kinematics along a trajectory (states (N, 7), inputs (N, 6))."""
    out = np.empty((len(states), 7, 6))
    for i in range(6):
        step = np.zeros(6)
        step[i] = h
        out[:, :, i] = (K.derivatives(states.T, (inputs + step).T)
                        - K.derivatives(states.T, (inputs - step).T)).T / (2 * h)
    return out


def input_noise_variance(prob: KinematicProblem) -> np.ndarray:
    """Variance (6,) of the accelerometers' and gyros' white noise, from their fifth differences
    (var = 252 sigma^2 for white noise, in which the motion, even turbulence's with its
    random-walk-like increments, counts about 12 times less than in third differences), robustly
    (median absolute value / 0.6745: the steps of a control input's response do not count)."""
    d5 = np.vstack([np.diff(d.inputs, 5, axis=0) for d in prob.data])
    return (np.median(np.abs(d5), axis=0) / 0.6745) ** 2 / 252


def _input_noise_information(prob: KinematicProblem, ev: Response, Wh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``J^T W G Q G^T W J`` as local blocks (S, k, k): what the noise of the measured inputs
    (variances ``q`` (6,)), integrated through the kinematics, adds to the residuals' covariance
    (errors in the variables: the inputs are measured, not known). ``G`` is the response of the
    outputs to a noise sample w_k of the inputs at sample k, ``dy/dx0(t) Phi(k)^-1 B_k dt`` for
    t > k (Phi(k) the state transition from the segment's start, B_k = df/da there), so
    ``G_k^T W J = dt B_k^T Phi(k)^-T sum_{t>k} (dy/dx0)^T W J`` (and half the term t = k, from the
    interpolation of the inputs between samples): a reverse cumulative sum per
    segment, no (N x N) matrix. The outputs it couples (an integrated q noise moves theta and
    alpha alike) are what the per-output Toeplitz of the coloured bounds cannot describe."""
    Jloc = prob.local_jacobian(ev, Wh)  # (S, L, ny, k)
    p, k = prob.p, Jloc.shape[-1]
    local = np.zeros((len(Jloc), k, k))
    for s, N in enumerate(prob.layout.length):
        J = Jloc[s, :N]
        A = np.einsum("tyi,tyk->tik", J[:, :, p:p + 7], J)  # (N, 7, k)
        # RK4 with the inputs linear between samples: a sample drives the interval before it
        # (half, reaching x(k)) and the one after it (half, from x(k+1)); the ends drive one each
        after = np.zeros_like(A)
        after[:-1] = np.cumsum(A[::-1], axis=0)[::-1][1:]  # sum over t > k
        after[1:] += 0.5 * A[1:]
        after[0] *= 0.5
        X = np.linalg.solve(ev.dx_x0[s, :N].transpose(0, 2, 1), after)  # Phi(k)^-T (N, 7, k)
        v = prob.dt * np.einsum("tji,tjk->tik", _input_matrix(ev.states[s, :N], ev.drive[s, :N]), X)
        local[s] = np.einsum("tik,i,til->kl", v, q, v)
    return local


def _spectrum(rho: np.ndarray, n_fft: int) -> np.ndarray:
    """Spectrum (F, ny) of the even autocorrelation ``rho`` (L, ny, lag 0 first) over ``n_fft``
    points, for :func:`identify.estimators.colour.toeplitz_apply`."""
    L = len(rho)
    seq = np.zeros((n_fft, rho.shape[1]))
    seq[:L] = rho
    seq[n_fft - L + 1:] = rho[1:][::-1]
    return np.fft.rfft(seq, axis=0).real


@dataclass
class CompatResult:
    """Estimated sensor errors: ``errors`` (names), ``value`` (as reported: scale factors as K),
    ``std`` (the outputs' coloured noise, Morelli & Klein, and the inputs' integrated noise),
    ``steps`` of the selection, per-output residual RMS ``rms_before`` (no sensor error modelled)
    and ``rms_after``, ``noise_std`` per output,
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
                    ch[y] = (_shifted(ch[y], t, -tau) - b) / k
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
    whole :func:`~identify.compat.sensors.catalogue`), at most ``max_steps``. ``input_noise``:
    standard deviations of the inertial sensors' white noise by channel (SI, e.g. from the data
    sheet) for the bounds; channels not given are estimated from the data (:func:`input_noise_variance`,
    which counts high-frequency motion such as rough turbulence in ``a_z`` as noise: conservative).
    """

    def __init__(self, errors=None, *, alpha: float = 0.01, candidates=None, max_steps: int = 12,
                 max_iter: int = 30, segment: float = SEGMENT, input_noise: dict | None = None, progress=None):
        self.errors, self.alpha, self.candidates, self.segment = errors, alpha, candidates, segment
        self.max_steps, self.max_iter, self.progress = max_steps, max_iter, progress
        self.input_noise = input_noise
        self.result_: CompatResult | None = None
        self.problem_ = self.beta_ = self.weighting_ = None  # the final fit on the engine: problem, unknowns, Wh

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
        for i, r in enumerate(runs):
            z = np.column_stack([np.unwrap(r[y]) if y == "psi" else r[y] for y in outputs])
            n_seg = max(1, int(round(r.duration / self.segment))) if math.isfinite(self.segment) else 1
            for k, rows in enumerate(np.array_split(np.arange(len(r)), n_seg)):
                where = r.source if n_seg == 1 else f"{r.source} [{r.time[rows[0]]:g}..{r.time[rows[-1]]:g} s]"
                data.append(_RunData(where, i, r.time[rows] - r.time[rows[0]], r.dt,
                                     r.matrix(list(K.INPUTS))[rows], z[rows]))
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
        before = _solve(KinematicProblem(data, outputs, []), x0, self.max_iter)
        if self.errors is not None:
            fit = _solve(KinematicProblem(data, outputs, chosen), np.r_[np.zeros(len(chosen)), before.beta],
                         self.max_iter) if chosen else before
            steps = []
        else:
            # the residuals' colour comes from the richest model the white-noise scores select (its
            # residuals are the noise, not unmodelled sensor errors); the selection is then made
            # again with the scores that colour gives
            fits = {}  # by the errors in the model, in order: the second pass refits none the first made
            fit, _ = self._select(data, outputs, pool, before, None, fits)
            _, rho = fit.coloured()
            fit, steps = self._select(data, outputs, pool, before, rho, fits)
        self.result_ = self._result(runs, before, fit, steps)
        self.problem_, self.beta_, self.weighting_ = fit.prob, fit.beta, fit.Wh
        return self

    def _select(self, data, outputs, pool, before: _Fit, rho, fits: dict):
        """Forward selection from no sensor error: ``(fit, steps)``; ``rho`` the whitened noise
        autocorrelation per output (L, ny) (None: white)."""
        from scipy import stats

        fit, steps = before, []
        while len(steps) < self.max_steps:
            left = [e for e in pool if e not in fit.prob.errors]
            if not left:
                break
            best, stat, threshold = self._score(fit, left, rho)
            if self.progress:
                self.progress(f"compat ({'white' if rho is None else 'coloured'} scores): best candidate "
                              f"{best.name}: score {stat:.4g} (threshold {threshold:.4g})")
            if not stat > threshold:
                break
            steps.append({"step": len(steps) + 1, "error": best.name, "statistic": stat, "threshold": threshold,
                          "p_value": float(stats.chi2.sf(stat, 1)), "candidates": len(left)})
            key = tuple(e.name for e in (*fit.prob.errors, best))
            if key not in fits:
                theta, xs = fit.prob.split(fit.beta)
                fits[key] = _solve(KinematicProblem(data, outputs, [*fit.prob.errors, best]),
                                   np.r_[theta, 0.0, xs.ravel()], self.max_iter)
            fit = fits[key]
        return fit, steps

    def _score(self, fit: _Fit, left: list[SensorError], rho):
        """The candidate with the largest score statistic, it and the Šidák threshold; ``rho`` the
        whitened noise autocorrelation (L, ny) from the engine's coloured bounds, None for white."""
        from ..refine.diagnostics import ScoreBase, sidak_threshold

        prob = fit.prob
        ev = prob.evaluate(fit.beta, extra=left)
        sigma = 1 / np.diag(fit.Wh)
        e = prob.segments(ev.e)
        base = np.zeros((sum(x.size for x in e), prob.n_beta))
        row = 0
        for s, n_s in enumerate(prob.layout.length):  # sensor errors shared, initial states per segment
            m = n_s * prob.ny
            base[row:row + m, :prob.p] = ev.held[:n_s, :, :, s].reshape(m, prob.p)
            base[row:row + m, prob.p + 7 * s:prob.p + 7 * s + 7] = ev.dy_x0[:n_s, :, :, s].reshape(m, 7)
            row += m
        sb = ScoreBase.build(e, base, sigma)
        # refine's score, g^2 / (c' c) for the candidate column c orthogonal to the model's, with
        # the noise's own covariance in the denominator, g^2 / (c' T c): the same statistic for
        # white residuals, chi-square(1) also for the coloured ones a kinematic fit leaves
        w = 1 / sigma
        Jc = np.concatenate([(X * w[None, :, None]).reshape(-1, X.shape[2]) for X in ev.extra])
        perp = Jc - sb.Q @ (sb.Q.T @ Jc)
        e_perp = sb.e - sb.Q @ (sb.Q.T @ sb.e)
        g = perp.T @ e_perp
        var = np.zeros(len(left))
        n_fft = 2 * prob.layout.L
        spectrum = None if rho is None else _spectrum(rho, n_fft)
        row = 0
        for x in e:
            P = perp[row:row + x.size].reshape(x.shape[0], x.shape[1], -1)
            var += np.einsum("nyk,nyk->k", P, P if rho is None else toeplitz_apply(spectrum, P, n_fft))
            row += x.size
        scores = np.where(var > 0, g ** 2 / np.maximum(var, 1e-300), 0.0)
        i = int(np.argmax(scores))
        return left[i], float(scores[i]), sidak_threshold(self.alpha, len(left), 1)

    def _result(self, runs, before: _Fit, fit: _Fit, steps) -> CompatResult:
        prob = fit.prob
        P = prob.p
        cov, ill, white, coloured, inputs = np.zeros((0, 0)), False, np.zeros(0), np.zeros(0), np.zeros(0)
        given = dict(self.input_noise or {})
        unknown = set(given) - set(K.INPUTS)
        if unknown:
            raise EstimationError(f"compat: input_noise: {', '.join(sorted(unknown))} not an inertial sensor "
                                  f"(known: {', '.join(K.INPUTS)})")
        q = np.where([c in given for c in K.INPUTS], [float(given.get(c, 0.0)) ** 2 for c in K.INPUTS],
                     input_noise_variance(prob))
        if P:
            cov_c = fit.coloured()[0].gg[:P, :P]
            cov_i = fit.M.sandwich(_input_noise_information(prob, fit.ev, fit.Wh, q)).gg[:P, :P]
            cov = cov_c + cov_i  # the outputs' own (coloured) noise and the inputs' noise integrated
            cov_white, ill = fit.M.covariance()
            white, coloured, inputs = (np.sqrt(np.clip(np.diag(c)[:P], 0, None))
                                       for c in (cov_white.gg[:P, :P], cov_c, cov_i))
        d = np.diag(cov)
        std = np.where(d > 0, np.sqrt(np.where(d > 0, d, 0.0)), np.nan)
        theta, xs = prob.split(fit.beta)
        value = np.array([e.display(v) for e, v in zip(prob.errors, theta)])
        names = [e.name for e in prob.errors]

        def rms(f: _Fit):
            e = np.vstack(prob.segments(f.ev.e))
            return {y: float(np.sqrt(np.mean(e[:, j] ** 2))) for j, y in enumerate(prob.outputs)}

        return CompatResult(
            errors=list(prob.errors), value=value, std=std, covariance=cov, outputs=prob.outputs, steps=steps,
            rms_before=rms(before), rms_after=rms(fit),
            noise_std={y: float(np.sqrt(v)) for y, v in zip(prob.outputs, fit.R)},
            x0=[dict(zip(K.STATES, map(float, x))) for x in xs], converged=fit.converged, stop=fit.stop,
            iterations=fit.iterations, runs=[r.source for r in runs], alpha=self.alpha,
            info={"ill_conditioned": bool(ill), "method": "the output-error engine (ML, relaxed noise covariance, "
                  "multiple shooting, Levenberg-Marquardt) on the rigid-body kinematics; finite-difference "
                  "sensitivities; coloured-residual bounds (Morelli & Klein)",
                  "std_white": dict(zip(names, map(float, white))),
                  "std_coloured": dict(zip(names, map(float, coloured))),
                  "std_input_noise": dict(zip(names, map(float, inputs))),
                  "input_noise_std": dict(zip(K.INPUTS, map(float, np.sqrt(q)))),
                  "input_noise_source": {c: "given" if c in given else "estimated"
                                         for c in K.INPUTS}},
            residuals_before=prob.segments(before.ev.e), residuals_after=prob.segments(fit.ev.e),
            time=[d.time for d in prob.data])

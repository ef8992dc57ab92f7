"""A model on runs as a prediction: residuals with every nuisance fitted, and their columns.

The output-error prediction every estimator offers refine by default
(:meth:`identify.estimators.base.Estimator.prediction`), and the fitting of profiles whose
pseudo-inputs are built from the model's states (``identify estimate`` and refine alike).

The model is simulated by the segmented output-error engine
(:class:`identify.estimators.output_error.OutputError`, the one that ML uses) over the same
multiple-shooting segments; each segment's initial state and (by default) each run's output zero
shifts are then the least-squares fit to the measured outputs, weighted by each output's noise as
ML weights them, exact because the outputs are linear in them. With ``jacobian`` the output
sensitivities to the free parameters and to the nuisance come along: the columns of the score tests.

A pseudo-input built from the model's *states* (a nonlinear term such as q|q| or q theta_s) is
never taken from the measured channels here (:func:`predict`): those carry the gust response, and
feeding measured outputs back as an input turns output error into partly equation error, which
"predicts" turbulent data better although the truth is linear. It is computed from the model's own
states instead, each segment simulated sample by sample by the nonlinear recursion
``x_{k+1} = Phi x_k + Gamma [u_k; f(x_k, u_k)]``, alternating with the least-squares fit of the
initial states and zero shifts until the term settles: a true prediction from the inputs and each
segment's initial state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..data.runs import Run
from ..errors import EstimationError
from ..model import pseudo_inputs as pi
from ..model.linear import LinearModel
from ..model.profile import Profile
from ..model.simulate import discretize
from .output_error import OutputError, cut
from .result import IdentificationResult

PREDICT_ITER, PREDICT_TOL = 20, 1e-6  # fixed-point iterations of a state-built term; relative change
REFITS = 8  # at most, for a model with a state-built term: fits until the estimates settle


@dataclass
class ModelFit:
    """A profile's model on runs: ``residuals``/``modelled`` (N_r, ny) per run, ``x0`` (S_r, n)
    and ``bias`` (ny,) per run; with ``jacobian``: ``dy`` (N_r, ny, p) output sensitivities to the
    free parameters and ``nuisance`` (N_r, ny, n S_r [+ ny]) to the segment initial states and
    the zero shifts, per run (the columns of the score test)."""

    residuals: list[np.ndarray]
    modelled: list[np.ndarray]
    x0: list[np.ndarray]
    bias: list[np.ndarray]
    dy: list[np.ndarray] | None = None
    nuisance: list[np.ndarray] | None = None
    runs: list[Run] | None = None  # the runs as simulated (state-built pseudo-inputs from the model)
    noise: dict | None = None  # noise parameters the prediction fitted (a filter's F and R), else None


def _problem(profile: Profile, runs: list[Run], segment: float, zero_shifts: bool, inputs=None) -> OutputError:
    u = [r.matrix(profile.input_names) for r in runs] if inputs is None else inputs
    z = [r.matrix(list(profile.outputs)) for r in runs]
    return OutputError(profile, u, z, runs[0].dt, segment, estimate_x0=True, estimate_bias=zero_shifts)


def _nuisance_columns(prob: OutputError, theta: np.ndarray) -> list[np.ndarray]:
    """d y / d (segment initial states, zero shifts) per run, (N_r, ny, n S_r [+ ny])."""
    lay, n, ny = prob.layout, prob.n, prob.ny
    resp = prob.initial_state_response(theta)
    out = []
    for r in range(prob.n_runs):
        segs = np.flatnonzero(lay.run == r)
        N = int(lay.length[segs].sum())
        cols = np.zeros((N, ny, n * len(segs) + (ny if prob.estimate_bias else 0)))
        for i, s in enumerate(segs):
            a, length = int(lay.start[s]), int(lay.length[s])
            cols[a:a + length, :, i * n:(i + 1) * n] = resp[:length]
        if prob.estimate_bias:
            cols[:, :, n * len(segs):] = np.eye(ny)
        out.append(cols)
    return out


def evaluate(profile: Profile, runs: list[Run], zero_shifts: bool = True, segment: float = math.inf,
             jacobian: bool = False) -> ModelFit:
    """Simulate the profile's model (a priori values = the estimates) over runs, each cut into
    segments of at most ``segment`` s (``inf``: whole runs) as ML cuts them; every segment's
    initial state and (``zero_shifts``) each run's output biases are the weighted least-squares
    fit to the measured outputs, exact because the outputs are linear in them."""
    prob = _problem(profile, runs, segment, zero_shifts)
    theta = LinearModel(profile).theta
    beta = np.concatenate([theta, np.zeros(prob.n_beta - prob.p)])
    forced = prob.per_run(prob.evaluate(beta, jacobian=False).y)
    nuis = _nuisance_columns(prob, theta)
    res, mod, x0s, biases = [], [], [], []
    n, ny = prob.n, prob.ny
    for run, y, nu in zip(runs, forced, nuis):
        z = run.matrix(list(profile.outputs))
        # weighted as ML weights them: outputs in different units and noise levels must not let
        # the largest numbers (m/s) set the initial states at the expense of the rest (rad);
        # weights from the channels' spread first, then relaxed once to the residuals' RMS
        w = 1.0 / np.maximum(z.std(axis=0), 1e-12)
        for _ in range(2):
            X = (nu * w[None, :, None]).reshape(-1, nu.shape[2])
            coef, *_ = np.linalg.lstsq(X, ((z - y) * w).ravel(), rcond=None)
            fitted = y + (nu.reshape(-1, nu.shape[2]) @ coef).reshape(z.shape)
            w = 1.0 / np.maximum(np.sqrt(np.mean((z - fitted) ** 2, axis=0)), 1e-12 * np.max(1 / w))
        res.append(z - fitted)
        mod.append(fitted)
        n_seg = (nu.shape[2] - (ny if zero_shifts else 0)) // n
        x0s.append(coef[:n * n_seg].reshape(n_seg, n))
        biases.append(coef[n * n_seg:] if zero_shifts else np.zeros(ny))
    ev = ModelFit(res, mod, x0s, biases)
    if jacobian:
        full = np.concatenate([theta, np.concatenate([x.ravel() for x in x0s])]
                              + ([np.concatenate(biases)] if zero_shifts else []))
        jac = prob.evaluate(full, jacobian=True).dy_theta  # (L, ny, p, S) at the fitted x0
        L, _, p, S = jac.shape
        ev.dy = [d.reshape(len(d), ny, p) for d in prob.per_run(jac.reshape(L, ny * p, S))]
        ev.nuisance = nuis
    return ev


def state_terms(p: Profile) -> dict[str, dict]:
    """``{name: description}`` of the pseudo-inputs of ``p`` built from its states (a product with a
    state factor): they are computed from the model's simulated states, never from measurements."""
    return {n: spec for n, spec in pi.specs(p).items() if set(spec.get("product", ())) & set(p.states)}


def simulated_terms(p: Profile, runs: list[Run], ev: ModelFit, terms: dict[str, dict],
                    segment: float = math.inf) -> list[Run]:
    """``runs`` with each pseudo-input of ``terms`` computed from the model's own states: every
    segment simulated sample by sample from its fitted initial state ``ev.x0`` with the terms fed
    back, ``x_{k+1} = Phi x_k + Gamma [u_k; f(x_k, u_k)]`` (the engine's zero-order hold), so the
    channels returned are exactly those of that simulation."""
    model = LinearModel(p)
    dt = runs[0].dt
    Phi, Gamma = discretize(model.A, model.B, dt)
    lay = cut([len(r) for r in runs], dt, segment)
    col = {n: p.input_names.index(n) for n in terms}
    state = {s: i for i, s in enumerate(p.state_names)}
    # terms whose every coefficient is zero (a candidate at its null value: the score test's
    # columns) do not act on the states: the linear simulation gives them all at once
    fed_back = bool(np.any(Gamma[:, list(col.values())] != 0))
    out = []
    for r, run in enumerate(runs):
        u = run.matrix(p.input_names)
        chans = {f: run[f] for spec in terms.values() for f in spec["product"] if f not in state}
        with np.errstate(over="ignore", invalid="ignore"):  # divergence is reported by the caller
            for i, s in enumerate(np.flatnonzero(lay.run == r)):
                x = np.array(ev.x0[r][i], float)
                k0, k1 = lay.start[s], lay.start[s] + lay.length[s]
                if not fed_back:
                    forcing, X = u[k0:k1] @ Gamma.T, np.empty((k1 - k0, len(x)))
                    for k in range(k1 - k0):
                        X[k], x = x, Phi @ x + forcing[k]
                    for n, spec in terms.items():
                        u[k0:k1, col[n]] = _term([X[:, state[f]] if f in state else chans[f][k0:k1]
                                                  for f in spec["product"]], spec)
                    continue
                for k in range(k0, k1):
                    for n, spec in terms.items():
                        u[k, col[n]] = _term([x[state[f]] if f in state else chans[f][k] for f in spec["product"]],
                                             spec)
                    x = Phi @ x + Gamma @ u[k]
        out.append(run.with_channels({n: u[:, col[n]] for n in terms}))
    return out


def _term(factors: list, spec: dict):
    """A state-built pseudo-input from its factors' values (numbers or arrays): their product, the
    ones ``spec["abs"]`` marks taken as magnitudes."""
    return math.prod(abs(v) if a else v for v, a in zip(factors, spec.get("abs", [False] * len(factors))))


def predict(profile: Profile, runs: list[Run], zero_shifts: bool = True, segment: float = math.inf,
            start: list[Run] | None = None) -> ModelFit:
    """:func:`evaluate` as a true prediction: the pseudo-inputs built from states (:func:`state_terms`)
    computed from the model's own simulated states (:func:`simulated_terms`), alternating with the
    least-squares fit of the initial states and zero shifts until the terms settle; ``ModelFit.runs``
    holds the runs with those channels. Raises :class:`EstimationError` if they do not (a term
    that makes the model diverge). ``start``: runs holding the terms to start from (a nearby model's)."""
    terms = state_terms(profile)
    current = runs if not terms else start if start is not None else \
        [r.with_channels({n: np.zeros(len(r)) for n in terms}) for r in runs]
    ev = evaluate(profile, current, zero_shifts, segment)
    changes = [0.0]
    for _ in range(PREDICT_ITER if terms else 0):
        new = simulated_terms(profile, runs, ev, terms, segment)
        changes.append(max(np.max(np.abs(a[n] - b[n])) / max(np.max(np.abs(a[n])), 1e-300)
                           for a, b in zip(new, current) for n in terms))
        if not np.isfinite(changes[-1]):
            break
        current = new
        ev = evaluate(profile, current, zero_shifts, segment)
        if changes[-1] < PREDICT_TOL:
            break
    if terms and not changes[-1] < PREDICT_TOL:
        raise EstimationError(f"profile '{profile.name}': the simulation with the nonlinear term(s) "
                              f"{', '.join(terms)} from the model's own states does not settle (change "
                              f"{changes[-1]:.3g} after {len(changes) - 1} iterations, tolerance {PREDICT_TOL:g}): "
                              + _unsettled(changes[1:]))
    ev.runs = current
    return ev


def _unsettled(changes: list[float]) -> str:
    """Why the fixed-point iteration of a state-built term stopped: the term makes the model
    diverge (the change grows or is not finite), or it still converges, too slowly (its feedback
    is nearly unstable: a lightly damped slow mode; seen on u^2 in the Navion's X equation, change
    3e-6 after 20 iterations, which the message used to call divergence)."""
    last = changes[-3:]
    if np.all(np.isfinite(last)) and all(b < a for a, b in zip(last, last[1:])) and len(last) > 1:
        return (f"it still converges, too slowly (change {changes[0]:.3g} at the first iteration): "
                "the term's feedback is nearly unstable")
    return "the term makes the model diverge"


def settle(refit, profile: Profile, max_fits: int = REFITS):
    """The fixed point of ``refit`` (a profile -> (fitted profile, result)) for a model whose
    state-built terms come from the simulated states of the model being fitted: each fit holds the
    terms of its starting values, so fit again from the estimate until no estimate moves by more
    than a tenth of its standard error (a thousandth of its value without bounds); a secant step
    on the last two fits (a contraction of rate lambda, ``F(theta) = (lambda - 1)(theta - theta*)``)
    jumps to the extrapolated fixed point. Raises :class:`EstimationError` if it does not settle."""
    pairs = []
    for _ in range(max_fits):
        fitted, result = refit(profile)
        move = result.theta - result.apriori
        std = np.asarray(result.std, float)
        tol = np.where(np.isfinite(std) & (std > 0), 0.1 * std, 1e-3 * np.abs(result.theta) + 1e-12)
        if np.all(np.abs(move) <= tol):
            return fitted, result
        pairs.append((np.asarray(result.apriori, float), move))
        nxt = result.theta
        if len(pairs) > 1:
            (a, Fa), (b, Fb) = pairs[-2:]
            slope = float((Fb - Fa) @ (b - a) / max((b - a) @ (b - a), 1e-300))  # lambda - 1
            if -2.0 < slope < -0.05:
                nxt = b - Fb / slope
        profile = fitted.with_values(dict(zip(result.names, map(float, nxt))))
    raise EstimationError(f"the estimates of '{profile.name}' with its nonlinear term(s) from the model's own "
                          f"states did not settle in {max_fits} fits (largest move {np.max(np.abs(move) / tol):.3g} "
                          f"tenths of a standard error)")


def fit_state_terms(estimator, profile: Profile, runs: list[Run], zero_shifts: bool = True,
                    segment: float = math.inf):
    """``(fitted profile, result)`` of ``estimator(profile).fit(runs)`` for a profile with state-built
    terms, fitted as refine fits them: the terms from the simulated states of the model being
    fitted (:func:`predict`), re-fitted until the estimates settle (:func:`settle`). Measured
    states would put their noise into the terms (an errors-in-variables bias)."""
    def fit(prof: Profile):
        result = estimator(prof).fit(predict(prof, runs, zero_shifts, segment).runs).result_
        return result.identified_profile(prof.name), result

    fitted, result = settle(fit, profile)
    return fitted, feedback_bounds(result, fitted, runs, zero_shifts, segment)


def feedback_bounds(result: IdentificationResult, fitted: Profile, runs: list[Run], zero_shifts: bool = True,
                    segment: float = math.inf, base: ModelFit | None = None) -> IdentificationResult:
    """``result`` (a settled fit of ``fitted``, whose state-built terms were held at their values)
    with its covariance widened for the terms' feedback. Each fit sees the terms as inputs, but they
    move with the estimates through the simulated states: the estimate is the fixed point
    ``theta = g(theta)`` of the fit ``g``, an instrumental-variable estimate, whose covariance by the
    delta method is ``K^-1 C K^-T`` with ``C`` the fit's own (coloured-residual) covariance and
    ``K = I - dg/dtheta = (J_h^T W J_h)^-1 J_h^T W J_t``: ``J_h`` the sensitivities with the terms
    held, ``J_t`` with them following the states (both with the nuisance refitted, by forward
    differences), ``W`` the outputs' inverse noise variances. ``base``: ``predict(fitted, runs, ...)``
    if the caller has it already."""
    base = base or predict(fitted, runs, zero_shifts, segment)
    w = 1.0 / np.maximum(np.sqrt(np.mean(np.vstack(base.residuals) ** 2, axis=0)), 1e-300)

    def stacked(ev: ModelFit) -> np.ndarray:
        return np.concatenate([(e * w).ravel() for e in ev.residuals])

    r0 = stacked(base)
    theta = np.array([fitted.free[n] for n in result.names])  # where base was simulated
    std = np.where(np.isfinite(result.std), result.std, 0.0)
    step = 1e-4 * np.maximum(np.abs(theta), std) + 1e-9
    held, moving = [], []
    for name, value, h in zip(result.names, theta, step):
        p = fitted.with_values({name: float(value + h)})
        held.append((r0 - stacked(evaluate(p, base.runs, zero_shifts, segment))) / h)
        moving.append((r0 - stacked(predict(p, runs, zero_shifts, segment, start=base.runs))) / h)
    J_h, J_t = np.column_stack(held), np.column_stack(moving)
    K = np.linalg.lstsq(J_h.T @ J_h, J_h.T @ J_t, rcond=None)[0]
    if not np.all(np.isfinite(K)) or np.linalg.cond(K) > 1e12:
        cov = np.full((len(theta), len(theta)), np.inf)
    else:
        K_inv = np.linalg.inv(K)
        C = result.covariance if result.covariance is not None else np.diag(result.std ** 2)
        cov = K_inv @ C @ K_inv.T
    how = result.info.get("standard_errors", "Cramér-Rao (white residuals)")
    return replace(result, covariance=cov, std=np.sqrt(np.abs(np.diag(cov))),
                   info={**result.info, "standard_errors": f"{how}, widened for the feedback of the state-built "
                                                           f"term(s) {', '.join(state_terms(fitted))} (delta method)"})


def input_response(p: Profile, runs: list[Run], segment: float, input_name: str, transform) -> list[np.ndarray]:
    """Per run (N_r, ny): the model's response to ``transform(u, dt)`` of one input (the others
    zero), each segment from rest (its initial state is a nuisance parameter anyway)."""
    j = p.input_names.index(input_name)
    inputs = []
    for run in runs:
        u = np.zeros((len(run), len(p.inputs)))
        u[:, j] = transform(run[input_name], run.dt)
        inputs.append(u)
    prob = _problem(p, runs, segment, False, inputs)
    beta = np.concatenate([LinearModel(p).theta, np.zeros(prob.n_beta - prob.p)])
    return prob.per_run(prob.evaluate(beta, jacobian=False).y)


def block_design(shared: list[np.ndarray], per_run: list[np.ndarray]) -> np.ndarray:
    """Stack per-run sensitivities into one design matrix.

    ``shared``: per run (N_r, ny, p) columns common to all runs (parameters); ``per_run``: per run
    (N_r, ny, k_r) nuisance columns (initial state, zero shifts) that get their own block. Rows are
    run-major, then sample, then output (as ``residual.ravel()``). Returns (M, p + sum k_r).
    """
    p = shared[0].shape[2]
    k_tot = sum(c.shape[2] for c in per_run)
    rows = sum(c.shape[0] * c.shape[1] for c in shared)
    J = np.zeros((rows, p + k_tot))
    r0, c0 = 0, p
    for s, c in zip(shared, per_run):
        m = s.shape[0] * s.shape[1]
        J[r0:r0 + m, :p] = s.reshape(m, p)
        J[r0:r0 + m, c0:c0 + c.shape[2]] = c.reshape(m, c.shape[2])
        r0, c0 = r0 + m, c0 + c.shape[2]
    return J


__all__ = ["ModelFit", "evaluate", "predict", "settle", "fit_state_terms", "feedback_bounds", "state_terms",
           "simulated_terms", "input_response", "block_design"]

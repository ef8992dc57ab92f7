"""A model on runs, as refine sees it: residuals with every nuisance fitted, and their columns.

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
from ..estimators.output_error import OutputError, cut
from ..estimators.result import IdentificationResult
from ..model import pseudo_inputs as pi
from ..model.linear import LinearModel
from ..model.profile import Profile
from ..model.simulate import discretize
from . import diagnostics as dg

MIN_SAMPLES = 50  # per run: fewer leave the residual tests without power
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
    out = []
    for r, run in enumerate(runs):
        u = run.matrix(p.input_names)
        chans = {f: run[f] for spec in terms.values() for f in spec["product"] if f not in state}
        with np.errstate(over="ignore", invalid="ignore"):  # divergence is reported by the caller
            for i, s in enumerate(np.flatnonzero(lay.run == r)):
                x = np.array(ev.x0[r][i], float)
                for k in range(lay.start[s], lay.start[s] + lay.length[s]):
                    for n, spec in terms.items():
                        u[k, col[n]] = math.prod(
                            (abs(v) if a else v) for v, a in
                            zip((x[state[f]] if f in state else chans[f][k] for f in spec["product"]),
                                spec.get("abs", [False] * len(spec["product"]))))
                    x = Phi @ x + Gamma @ u[k]
        out.append(run.with_channels({n: u[:, col[n]] for n in terms}))
    return out


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
    change = 0.0
    for _ in range(PREDICT_ITER if terms else 0):
        new = simulated_terms(profile, runs, ev, terms, segment)
        change = max(np.max(np.abs(a[n] - b[n])) / max(np.max(np.abs(a[n])), 1e-300)
                     for a, b in zip(new, current) for n in terms)
        if not np.isfinite(change):
            break
        current = new
        ev = evaluate(profile, current, zero_shifts, segment)
        if change < PREDICT_TOL:
            break
    if terms and not change < PREDICT_TOL:
        raise EstimationError(f"profile '{profile.name}': the simulation with the nonlinear term(s) "
                              f"{', '.join(terms)} from the model's own states does not settle (change "
                              f"{change:.3g} after {PREDICT_ITER} iterations): the term makes the model diverge")
    ev.runs = current
    return ev


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
        cov = K_inv @ result._cov() @ K_inv.T
    how = result.info.get("standard_errors", "Cramér-Rao (white residuals)")
    return replace(result, covariance=cov, std=np.sqrt(np.abs(np.diag(cov))),
                   info={**result.info, "standard_errors": f"{how}, widened for the feedback of the state-built "
                                                           f"term(s) {', '.join(state_terms(fitted))} (delta method)"})


def unexplained(residuals: list[np.ndarray], shared: list[np.ndarray], nuisance: list[np.ndarray],
                sigma: np.ndarray) -> list[np.ndarray]:
    """Residuals (N_r, ny) per run minus their least-squares fit on the columns ``shared``
    (N_r, ny, k, common to all runs) and ``nuisance`` (N_r, ny, k_r, per run), weighted 1/sigma."""
    w = np.tile(1.0 / sigma, sum(len(e) for e in residuals))
    C = dg.block_design(shared, nuisance) * w[:, None]
    C /= np.maximum(np.linalg.norm(C, axis=0), 1e-300)
    e = np.concatenate([r.ravel() for r in residuals]) * w
    G = C.T @ C
    coef = np.linalg.solve(G + 1e-10 * np.trace(G) / len(G) * np.eye(len(G)), C.T @ e)
    clean = (e - C @ coef) / w
    parts = np.split(clean, np.cumsum([r.size for r in residuals])[:-1])
    return [c.reshape(r.shape) for c, r in zip(parts, residuals)]


def errors(evaluation: ModelFit, outputs, scale: np.ndarray) -> dict:
    """RMS error per output and the normalised ``overall`` (see the module docstring)."""
    E = np.vstack(evaluation.residuals)
    rms = np.sqrt(np.mean(E ** 2, axis=0))
    out = {y: float(r) for y, r in zip(outputs, rms)}
    out["overall"] = float(np.sqrt(np.mean((rms / scale) ** 2)))
    return out


def neg_log_likelihood(residuals: list[np.ndarray]) -> float:
    """Concentrated Gaussian negative log-likelihood with a diagonal noise covariance estimated
    from the residuals: (N/2) sum_y log(mean e_y^2)."""
    E = np.vstack(residuals)
    return 0.5 * E.shape[0] * float(np.sum(np.log(np.maximum(np.mean(E ** 2, axis=0), 1e-300))))


def split_validation(runs: list[Run]) -> tuple[list[Run], list[Run]]:
    """Validation runs into a *choosing* and a *judging* part: alternate runs when there are
    several; one run is cut in two halves in time (first half chooses) when each half keeps
    ``MIN_SAMPLES``, else it only judges."""
    if len(runs) >= 2:
        return runs[0::2], runs[1::2]
    if len(runs) == 1 and len(runs[0]) >= 2 * MIN_SAMPLES:
        r = runs[0]
        mid = r.time[len(r) // 2]
        first, second = r.slice(None, mid - 0.5 * r.dt), r.slice(mid, None)
        return ([replace(first, source=f"{r.source} [first half]")],
                [replace(second, source=f"{r.source} [second half]")])
    return [], list(runs)


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


def check_identifiable(p: Profile, runs: list[Run], zero_shifts: bool, segment: float) -> None:
        """The fitted model's parameters must be identifiable beside the nuisance: rank test of the
        weighted sensitivity matrix, naming the parameters in its null space."""
        ev = evaluate(p, runs, zero_shifts, segment, jacobian=True)
        J = dg.block_design(ev.dy, ev.nuisance)
        sigma = np.sqrt(np.mean(np.vstack(ev.residuals) ** 2, axis=0))
        Jw = J * np.tile(1 / np.where(sigma > 0, sigma, 1.0), len(J) // len(sigma))[:, None]
        names = p.free_names
        npar = len(names)
        # parameters beside the nuisance (initial states, zero shifts): project those out first, so
        # that an unobservable state's initial value is not mistaken for an unidentifiable parameter
        U, sn, _ = np.linalg.svd(Jw[:, npar:], full_matrices=False)
        Q = U[:, sn > 1e-10 * max(sn.max(initial=0.0), 1e-300)]
        Jp = Jw[:, :npar] - Q @ (Q.T @ Jw[:, :npar])
        Jp = Jp / np.maximum(np.linalg.norm(Jw[:, :npar], axis=0), 1e-300)
        _, s, Vt = np.linalg.svd(Jp, full_matrices=False)
        if s[-1] < 1e-7 * max(s[0], 1e-300) or s[0] == 0:
            null = Vt[s < 1e-7 * max(s[0], 1e-300)] if s[0] > 0 else Vt
            worst = [names[i] for i in np.flatnonzero(np.max(np.abs(null), axis=0) > 0.1)]
            raise EstimationError(f"profile '{p.name}': free parameters not identifiable from these runs "
                                  f"(no information separates {', '.join(worst)}); "
                                  f"fix some or add excitation")


__all__ = ["ModelFit", "evaluate", "predict", "settle", "fit_state_terms", "feedback_bounds", "state_terms",
           "simulated_terms", "errors", "neg_log_likelihood", "unexplained", "split_validation",
           "input_response", "check_identifiable", "MIN_SAMPLES"]

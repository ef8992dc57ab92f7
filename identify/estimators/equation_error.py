"""Equation-error estimators: least squares (LS) and iterated instrumental variables (IV).

The model is linear in its parameters, so each state equation is a linear regression::

    xdot_i - (A0 x + B0 u)_i = sum_j theta_j (dA[j] x + dB[j] u)_i + b_{r,i}

with regressors built from the profile's constant tensors ``dA``/``dB`` (so ties and any profile
work), and ``b_{r,i}`` a zero shift per run ``r`` and equation ``i`` (sensor biases, trim). Equations
are solved separately (the paper's "each equation independently") except where a tied parameter
spans several equations: those are stacked jointly. Several runs stack into one regression sharing
the derivatives.

State derivatives come, per state, from a ``<state>_dot`` channel; else from an output in
``output_defs`` with exactly one state-derivative term (``a_x = u_dot + g theta`` gives ``u_dot``);
else from smoothed differentiation of the measured state (:mod:`identify.data.preprocess`). Equation
error needs every state measured.

Standard errors: ``(X^T X)^-1 X^T R X (X^T X)^-1`` with ``R`` the Toeplitz matrix of the residual
autocorrelation (Morelli & Klein's correction for coloured residuals, which equation-error residuals
always are after smoothing); computed with FFTs, O(p N log N), per run and equation (residuals
of different runs, and of different equations in a jointly solved group, are taken as
uncorrelated). The white-residual bound ``sigma^2 (X^T X)^-1`` is kept in ``info["std_white"]``.

IV replaces the regressors' states by instruments: states simulated from the a priori model (or
the LS estimate), then from each new estimate, until the parameters stop changing. Instruments are
correlated with the true states but not with the measurement noise, which removes LS's
errors-in-variables bias. For an unstable model (the S 61 in hover) a simulation over a whole run
drifts away from the data, and instruments that no longer resemble the states make ``Z^T X``
ill-conditioned; so by default (``reinit="auto"``) the simulation restarts from the measured state
every half doubling time of the fastest unstable mode of the starting model (1 to 5 s, as ML's
multiple shooting cuts its segments), which bounds the drift while keeping the instruments
noise-free between restarts. Should a later estimate be so much more unstable that even this
diverges, the interval is halved for the rest of the iteration (never lengthened, so the
iteration cannot cycle between two instrument sets).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..data.preprocess import processing_steps, smooth_derivative
from ..data.runs import Run
from ..errors import ConvergenceWarning, EstimationError, SimulationError
from ..model.linear import LinearModel
from ..model.profile import DOT, Profile
from ..model.simulate import discretize
from .base import Estimator
from .colour import autocorr_apply as _autocorr_apply
from .output_error import MIN_SEGMENT, auto_segment, restarts, simulate_segments
from .prior import posterior, prior_term
from .result import IdentificationResult, fit_metrics

DEFAULT_DIFF_CUTOFF_HZ = 6.25
_RANK_RTOL = 1e-10


# -- state derivatives ------------------------------------------------------------------------
def state_derivatives(run: Run, profile: Profile, cutoff_hz: float | None = None) -> tuple[np.ndarray, dict]:
    """State derivatives (N, n) of a run and, per state, where each came from.

    Order of preference: a ``<state>_dot`` channel; an output defined with exactly one
    state-derivative term whose other terms are measured; smoothed differentiation of the state
    at ``cutoff_hz`` (default 6.25 Hz, capped at 0.4 x the sample rate).
    """
    states, n = profile.state_names, len(run)
    xdot, sources = np.empty((n, len(states))), {}
    for j, s in enumerate(states):
        name = s + DOT
        if name in run.channels:
            xdot[:, j], sources[s] = run[name], f"channel {name}"
            continue
        derived = _from_output(run, profile, name)
        if derived is not None:
            xdot[:, j], sources[s] = derived
            continue
        wanted = cutoff_hz or DEFAULT_DIFF_CUTOFF_HZ
        fc = min(wanted, 0.4 / run.dt)  # the differentiator's band must stay below Nyquist
        xdot[:, j] = smooth_derivative(run[s], run.dt, fc)
        capped = f" (asked {wanted:g} Hz, capped below Nyquist)" if fc < wanted else ""
        sources[s] = f"smoothed differentiation of {s} at {fc:g} Hz{capped}"
    return xdot, sources


def _from_output(run: Run, profile: Profile, name: str):
    for y, terms in profile.output_defs.items():
        dots = [t for t in terms if t.endswith(DOT) and t[: -len(DOT)] in profile.states]
        if dots != [name] or not terms[name] or y not in run.channels \
                or not all(t in run.channels for t in terms if t != name):
            continue
        rest = sum((c * run[t] for t, c in terms.items() if t != name), np.zeros(len(run)))
        return (run[y] - rest) / terms[name], f"output {y}"
    return None


# -- regression structure ---------------------------------------------------------------------
@dataclass
class Group:
    """Equations (state indices) solved jointly and the parameters (indices) they involve."""

    equations: list[int]
    params: list[int]


def equation_groups(model: LinearModel) -> list[Group]:
    """Split the state equations into independent regressions (joined only by tied parameters)."""
    touches = (np.abs(model.dA).sum(axis=2) + np.abs(model.dB).sum(axis=2)) > 0  # (p, n)
    n = model.n_states
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for row in touches:
        eqs = np.flatnonzero(row)
        for e in eqs[1:]:
            parent[find(e)] = find(eqs[0])
    groups: dict[int, list[int]] = {}
    for e in range(n):
        if touches[:, e].any():
            groups.setdefault(find(e), []).append(e)
    return [Group(eqs, sorted(np.flatnonzero(touches[:, eqs].any(axis=1)).tolist())) for eqs in groups.values()]


def regressors(model: LinearModel, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Regressors (N, n, p): column j of equation i is ``(dA[j] x + dB[j] u)_i``."""
    return np.einsum("pij,kj->kip", model.dA, x) + np.einsum("pij,kj->kip", model.dB, u)


def fixed_part(model: LinearModel, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Known part (N, n) of the state derivatives: ``A0 x + B0 u`` (gravity, kinematics)."""
    return x @ model.A0.T + u @ model.B0.T


@dataclass
class MeasuredRun:
    """One run prepared for equation error: measured states and inputs, and (time domain only)
    the state derivatives with, per state, where each came from."""

    run: Run
    x: np.ndarray  # (N, n) measured states
    u: np.ndarray  # (N, m) inputs
    xdot: np.ndarray | None = None  # (N, n)
    sources: dict | None = None


def _design(group: Group, regs: list[np.ndarray]):
    """Blocks (one per run and equation) of the group's regression, with bias columns.

    ``regs`` gives, per run, the regressors (N, n, p) from :func:`regressors` (of the measured
    states for X, of the simulated states for the instruments Z). Returns a list of (N, q)
    matrices; column order: parameters, then one zero shift per (run, equation).
    """
    ne, nr, npar = len(group.equations), len(regs), len(group.params)
    q = npar + nr * ne
    blocks = []
    for r, full in enumerate(regs):
        reg = full[:, group.equations][:, :, group.params]  # (N, ne, npar)
        for k in range(ne):
            block = np.zeros((len(full), q))
            block[:, :npar] = reg[:, k]
            block[:, npar + r * ne + k] = 1.0
            blocks.append(block)
    return blocks


def _targets(model: LinearModel, group: Group, data: list[MeasuredRun]) -> list[np.ndarray]:
    out = []
    for d in data:
        y = d.xdot - fixed_part(model, d.x, d.u)
        out += [y[:, e] for e in group.equations]
    return out


def _column_names(model: LinearModel, group: Group, data: list[MeasuredRun]) -> list[str]:
    p = model.profile
    eqs = [p.equation(p.state_names[e]) for e in group.equations]
    return ([model.names[j] for j in group.params]
            + [f"zero shift of equation {eq} in run {r + 1}" for r in range(len(data)) for eq in eqs])


def check_rank(X: np.ndarray, names: list[str]) -> np.ndarray:
    """Column scales of X; raise naming the parameters that the data cannot separate."""
    scale = np.linalg.norm(X, axis=0)
    dead = [names[i] for i in np.flatnonzero(scale == 0)]
    if dead:
        raise EstimationError(f"not identifiable from these runs (regressor is zero): {', '.join(dead)}")
    _, s, vt = np.linalg.svd(X / scale, full_matrices=False)
    if s[-1] < _RANK_RTOL * s[0]:
        null = np.abs(vt[-1])
        involved = [names[i] for i in np.flatnonzero(null > 0.2 * null.max())]
        raise EstimationError(f"not identifiable from these runs (regressors nearly collinear): "
                              f"{', '.join(involved)}")
    return scale


def _solve(X_blocks, y_blocks, Z_blocks, names, prior=None):
    """Estimate, residual blocks, coloured-residual and white covariances of one group (and, with
    a ``prior``, the mixed estimate's parts, see :func:`_mixed`)."""
    if prior is not None:
        return _mixed(X_blocks, y_blocks, Z_blocks, names, *prior)
    X, y = np.vstack(X_blocks), np.concatenate(y_blocks)
    Z = X if Z_blocks is None else np.vstack(Z_blocks)
    scale = check_rank(X, names)
    Xs, Zs = X / scale, Z / scale
    H = Zs.T @ Xs
    if Z_blocks is None:
        theta_s = np.linalg.lstsq(Xs, y, rcond=None)[0]
    else:
        check_rank(Zs, names)
        theta_s = np.linalg.solve(H, Zs.T @ y)
    theta = theta_s / scale
    residuals = [yb - Xb @ theta for Xb, yb in zip(X_blocks, y_blocks)]
    Hinv = np.linalg.inv(H)
    q, ntot = X.shape[1], X.shape[0]
    dof = max(ntot - q, 1) / ntot
    M_white = sum((v @ v / len(v) / dof) * (Zb / scale).T @ (Zb / scale)
                  for v, Zb in zip(residuals, Z_blocks or X_blocks))
    M_col = sum((Zb / scale).T @ _autocorr_apply(v / np.sqrt(dof), Zb / scale)
                for v, Zb in zip(residuals, Z_blocks or X_blocks))
    cov_white = Hinv @ M_white @ Hinv.T / np.outer(scale, scale)
    cov_col = Hinv @ M_col @ Hinv.T / np.outer(scale, scale)
    return theta, residuals, cov_col, cov_white, None


MIXED_PASSES = 3  # residual variance and mixed estimate solved in turn (the variance settles at once)


def _mixed(X_blocks, y_blocks, Z_blocks, names, mean, prec):
    """Theil and Goldberger's mixed estimation (Morelli & Klein): the prior ``theta_j ~ N(mean_j,
    1 / prec_j)`` (prec 0: none; the zero-shift columns have none) as extra regression rows
    weighted against the equation's residual variance s^2 (re-estimated from the mixed fit's
    residuals): ``(Z^T X / s^2 + P^-1) theta = Z^T y / s^2 + P^-1 mean`` (Z = X for LS). A
    regressor the data cannot separate is accepted when the prior holds it. Returns as
    :func:`_solve` with, last, ``(A, D_coloured, D_white)``: ``A`` the inverse of the left side,
    ``D`` the data's part of the covariance (:mod:`identify.estimators.prior`)."""
    X, y = np.vstack(X_blocks), np.concatenate(y_blocks)
    Z = X if Z_blocks is None else np.vstack(Z_blocks)
    has = prec > 0
    resid = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    q, ntot = X.shape[1], X.shape[0]
    s2 = max(float(resid @ resid) / max(ntot - q, 1), 1e-300)
    check_rank(np.vstack([X, np.diag(np.sqrt(prec * s2))[has]]), names)
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    Xs, Zs = X / scale, Z / scale
    prec_s, mean_s = prec / scale ** 2, np.nan_to_num(mean) * scale
    H = Zs.T @ Xs
    for _ in range(MIXED_PASSES):
        Hp = H / s2 + np.diag(prec_s)
        theta_s = np.linalg.solve(Hp, Zs.T @ y / s2 + prec_s * mean_s)
        v = y - Xs @ theta_s
        s2 = max(float(v @ v) / max(ntot - q, 1), 1e-300)
    Hp = H / s2 + np.diag(prec_s)
    theta = theta_s / scale
    residuals = [yb - Xb @ theta for Xb, yb in zip(X_blocks, y_blocks)]
    A = np.linalg.inv(Hp)
    dof = max(ntot - q, 1) / ntot
    Zb_s = [Zb / scale for Zb in (Z_blocks or X_blocks)]
    B_white = sum((v @ v / len(v) / dof) * Zb.T @ Zb for v, Zb in zip(residuals, Zb_s)) / s2 ** 2
    B_col = sum(Zb.T @ _autocorr_apply(v / np.sqrt(dof), Zb) for v, Zb in zip(residuals, Zb_s)) / s2 ** 2
    unscale = 1 / np.outer(scale, scale)
    D_white, D_col = A @ B_white @ A.T * unscale, A @ B_col @ A.T * unscale
    prior_part = (A * prec_s) @ A.T * unscale
    # A in the parameters' units: theta = A_u (Z^T y / s^2 + P^-1 mean) with A_u = A / outer(scale)
    return theta, residuals, D_col + prior_part, D_white + prior_part, (A * unscale, D_col, D_white)


# -- simulation for instruments and modelled outputs ------------------------------------------
def simulate_states(model: LinearModel, u: np.ndarray, dt: float, x_meas: np.ndarray, bias: np.ndarray,
                    segment: float | None) -> np.ndarray:
    """States (N, n) simulated with constant forcing ``bias`` (n,), restarted from the measured
    states ``x_meas`` (N, n) every ``segment`` s (``None``: once, at the start)."""
    n, N = model.n_states, len(u)
    Phi, Gamma = discretize(model.A, np.hstack([model.B, np.eye(n)]), dt)
    forcing = np.hstack([u, np.broadcast_to(bias, (N, n))]) @ Gamma.T
    layout = restarts(N, dt, segment)
    with np.errstate(over="ignore", invalid="ignore"):  # divergence is reported below
        x = simulate_segments(Phi, forcing, x_meas[layout.start], layout)
    if not np.all(np.isfinite(x)) or np.abs(x).max() > 1e6 * max(1.0, np.abs(x_meas).max()):
        raise SimulationError(f"simulation of '{model.profile.name}' diverged over a run")
    return x


def _segment(model: LinearModel, reinit, duration: float) -> float | None:
    """Restart interval (s) of simulations over runs up to ``duration`` s; None: no restarts."""
    if reinit is None:
        return None
    if reinit == "auto":
        seg = auto_segment(model, duration)
        return None if not np.isfinite(seg) else seg
    return float(reinit)


# -- estimators -------------------------------------------------------------------------------
class EquationError(Estimator):
    """Shared machinery of LS and IV."""

    weighs_prior = True  # mixed estimation (the profile's [prior] in the regressions)

    def __init__(self, profile, *, bias: bool = True, diff_cutoff_hz: float | None = None,
                 coloured: bool = True, reinit="auto"):
        super().__init__(profile)
        self.bias, self.diff_cutoff_hz, self.coloured, self.reinit = bias, diff_cutoff_hz, coloured, reinit

    def _validate(self) -> None:
        super()._validate()
        if self.diff_cutoff_hz is not None and not self.diff_cutoff_hz > 0:
            raise EstimationError(f"differentiator cut-off must be positive, got {self.diff_cutoff_hz} Hz")
        reinit = self.reinit
        if not (reinit in (None, "auto") or (isinstance(reinit, (int, float)) and reinit > 0)):
            raise EstimationError(f"reinit must be 'auto', None or a positive time in s, got {reinit!r}")
        self.model_ = LinearModel(self.profile_)

    def check_runs(self, runs: Run | list[Run], channels: list[str] | None = None) -> list[Run]:
        runs = [runs] if isinstance(runs, Run) else list(runs)
        for run in runs:  # before the profile's channel check: say why the states are needed
            run.require(self.profile_.state_names, "equation error (every state must be measured)")
        return super().check_runs(runs, channels)

    # data -----------------------------------------------------------------------------------
    def _measured(self, run: Run) -> MeasuredRun:
        """A run's measured states and inputs, every value finite (no derivatives yet)."""
        p = self.profile_
        for name in p.state_names + p.input_names:
            bad = np.flatnonzero(~np.isfinite(run[name]))
            if bad.size:
                raise EstimationError(f"{run.source}: channel '{name}': non-finite value at t = "
                                      f"{run.time[bad[0]]:g} s")
        return MeasuredRun(run, run.matrix(p.state_names), run.matrix(p.input_names))

    def _prepare(self, runs: list[Run]) -> list[MeasuredRun]:
        """The measured runs with their state derivatives (what the time-domain regression needs)."""
        p = self.profile_
        out = []
        for run in runs:
            d = self._measured(run)
            d.xdot, d.sources = state_derivatives(run, p, self.diff_cutoff_hz)
            bad = np.argwhere(~np.isfinite(d.xdot))
            if bad.size:
                k, s = bad[0][0], p.state_names[bad[0][1]]
                raise EstimationError(f"{run.source}: derivative of '{s}' ({d.sources[s]}): "
                                      f"non-finite value at t = {run.time[k]:g} s")
            out.append(d)
        return out

    def _groups(self) -> list[Group]:
        m = self.model_
        groups = equation_groups(m)
        covered = {j for g in groups for j in g.params}
        outside = [m.names[j] for j in range(len(m.names)) if j not in covered]
        if outside:
            raise EstimationError(f"parameter(s) {', '.join(outside)} act only on the output equation; "
                                  f"equation error cannot estimate them (use ML)")
        return groups

    # one regression pass --------------------------------------------------------------------
    def _estimate(self, data: list[MeasuredRun], instruments: list[np.ndarray] | None):
        m = self.model_
        p, n = len(m.names), m.n_states
        theta, cov_col, cov_white = np.zeros(p), np.zeros((p, p)), np.zeros((p, p))
        biases = np.zeros((len(data), n))
        residual_std = {}
        term = prior_term(self.profile_, m.names)
        mixed = None if term is None else (np.zeros((p, p)), np.zeros((p, p)), np.zeros((p, p)))
        regs_x = [regressors(m, d.x, d.u) for d in data]
        regs_z = None if instruments is None else [regressors(m, x, d.u) for x, d in zip(instruments, data)]
        for g in self._groups():
            X = _design(g, regs_x)
            y = _targets(m, g, data)
            Z = None if regs_z is None else _design(g, regs_z)
            names = _column_names(m, g, data)
            if not self.bias:
                npar = len(g.params)
                X = [b[:, :npar] for b in X]
                Z = None if Z is None else [b[:, :npar] for b in Z]
                names = names[:npar]
            k = len(g.params)
            idx = np.array(g.params)
            group_prior = None
            if term is not None and term.has[idx].any():  # zero-shift columns: no prior
                extra = len(names) - k
                group_prior = (np.concatenate([term.mean[idx], np.zeros(extra)]),
                               np.concatenate([term.precision[idx], np.zeros(extra)]))
            est, res, cc, cw, parts = _solve(X, y, Z, names, group_prior)
            theta[idx] = est[:k]
            cov_col[np.ix_(idx, idx)] = cc[:k, :k]
            cov_white[np.ix_(idx, idx)] = cw[:k, :k]
            if mixed is not None:  # the group's A and D (no prior in it: the data alone, W = I)
                block = parts or (cw, cc, cw)
                for full, part in zip(mixed, block):
                    full[np.ix_(idx, idx)] = part[:k, :k]
            if self.bias:
                biases[:, g.equations] = est[k:].reshape(len(data), len(g.equations))
            ne = len(g.equations)
            for i, e in enumerate(g.equations):
                v = np.concatenate([res[r * ne + i] for r in range(len(data))])
                residual_std[self.profile_.state_names[e]] = float(np.std(v))
        self.mixed_ = None if term is None else (term, *mixed)
        return theta, cov_col, cov_white, biases, residual_std

    # simulation ---------------------------------------------------------------------------------
    def _simulate(self, model: LinearModel, data: list[MeasuredRun], biases: np.ndarray, segment):
        return [simulate_states(model, d.u, d.run.dt, d.x, b, segment) for d, b in zip(data, biases)]

    def _modelled(self, model: LinearModel, data: list[MeasuredRun], biases: np.ndarray):
        """Output-error simulation of the identified model from each run's measured initial state;
        restarted as for the instruments only if a plain simulation diverges or drifts away."""
        C, D, Cd = model.C, model.D, model.Cd
        measured = [d.run.matrix(list(self.profile_.outputs)) for d in data]

        def outputs(xs):
            return [x @ C.T + d.u @ D.T + b @ Cd.T for x, d, b in zip(xs, data, biases)]

        how = "plain simulation from the measured initial state"
        try:
            ys = outputs(self._simulate(model, data, biases, None))
            drift = any(np.sqrt(np.mean((y - z) ** 2, axis=0)).max() > 3 * max(np.std(z, axis=0).max(), 1e-12)
                        for y, z in zip(ys, measured))
        except SimulationError:
            ys, drift = None, True
        if drift:
            longest = max(d.run.duration for d in data)
            segment = _segment(model, "auto" if self.reinit is None else self.reinit, longest) or MIN_SEGMENT
            ys = outputs(self._simulate(model, data, biases, segment))
            how = (f"simulations restarted from the measured states every {segment:.3g} s (a plain "
                   f"simulation drifts away), so the RMS errors are of {segment:.3g} s predictions")
        return measured, ys, how

    def _result(self, data, theta, cov_col, cov_white, biases, info) -> IdentificationResult:
        model = self.model_.with_theta(theta)
        cov = cov_col if self.coloured else cov_white
        measured, modelled, how = self._modelled(model, data, biases)
        p = self.profile_
        info = dict(info)
        info.update({
            "std_white": np.sqrt(np.diag(cov_white)),
            "std_coloured": np.sqrt(np.diag(cov_col)),
            "standard_errors": "coloured-residual correction (Morelli & Klein)" if self.coloured
            else "white residuals",
            "derivatives": [d.sources for d in data] if data[0].sources is not None else info.get("derivatives"),
            "zero_shifts": [{p.equation(s): float(b[j]) for j, s in enumerate(p.state_names)} for b in biases]
            if self.bias else None,
            "initial_states": [dict(zip(p.state_names, d.x[0].tolist())) for d in data],
            "modelled": how,
            "processing": [processing_steps(d.run) for d in data],
        })
        if getattr(self, "mixed_", None) is not None:  # mixed estimation: the prior's record
            term, A, D_col, D_white = self.mixed_
            info["prior"] = posterior(term, theta, A, D_col if self.coloured else D_white)[1]
        return IdentificationResult(
            method=self.method, profile=p, theta=theta, std=np.sqrt(np.diag(cov)), covariance=cov,
            fit=fit_metrics(list(p.outputs), measured, modelled), info=info,
            runs=[d.run.source for d in data], time=[d.run.time for d in data],
            measured=measured, modelled=modelled)


class LS(EquationError):
    """Equation-error least squares over one or several runs.

    Options: ``bias`` (a zero shift per run and equation, default True); ``diff_cutoff_hz`` for
    states differentiated numerically; ``coloured`` (standard errors corrected for coloured
    residuals, default True); ``reinit`` (how ``result_.modelled`` is simulated if the plain
    simulation drifts; see the module notes). ``result_.info`` holds per-run zero shifts, the
    derivative sources, residual standard deviations per equation and white-residual errors.
    """

    method = "ls"

    def _fit(self, runs: list[Run]) -> IdentificationResult:
        data = self._prepare(runs)
        theta, cc, cw, biases, rstd = self._estimate(data, None)
        return self._result(data, theta, cc, cw, biases, {"residual_std": rstd})


class IV(EquationError):
    """Iterated instrumental variables.

    The instruments are the states simulated (per run, from the measured initial state, with the
    current zero shifts) from the starting model — ``start="ls"`` (default, as in the paper) or
    ``"apriori"`` — then from each new estimate, until the largest parameter change relative to
    ``max(|theta|, 1e-3)`` falls below ``tol`` or ``max_iter`` is reached. ``progress(iteration,
    change, theta)`` is called after every iteration (progress display). Other options as for LS.
    """

    method = "iv"
    progress_quantity = "max rel. change"

    def __init__(self, profile, *, start: str = "ls", max_iter: int = 30, tol: float = 1e-9,
                 progress=None, **options):
        super().__init__(profile, **options)
        self.start, self.max_iter, self.tol, self.progress = start, max_iter, tol, progress

    def _validate(self) -> None:
        super()._validate()
        if self.start not in ("ls", "apriori"):
            raise EstimationError(f"IV start must be 'ls' or 'apriori', got {self.start!r}")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise EstimationError(f"IV max_iter must be a positive integer, got {self.max_iter!r}")

    def _fit(self, runs: list[Run]) -> IdentificationResult:
        data = self._prepare(runs)
        theta, cc, cw, biases, rstd = self._estimate(data, None)
        if self.start == "apriori":
            theta, biases = self.model_.theta.copy(), np.zeros_like(biases)
        history, converged = [], False
        # restart interval fixed from the starting model: letting it follow each estimate can make
        # the iteration cycle between two instrument sets instead of converging
        longest = max(d.run.duration for d in data)
        segment = _segment(self.model_.with_theta(theta), self.reinit, longest)
        dt = min(d.run.dt for d in data)
        for it in range(1, self.max_iter + 1):
            model = self.model_.with_theta(theta)
            while True:
                try:
                    Z = self._simulate(model, data, biases, segment)
                    break
                except SimulationError:
                    segment = 0.5 * (longest if segment is None else segment)
                    if segment < 5 * dt:
                        raise EstimationError(f"IV: the instrument simulation diverged at iteration {it} "
                                              f"even when restarted every {2 * segment:.3g} s") from None
            new, cc, cw, biases, rstd = self._estimate(data, Z)
            change = float(np.max(np.abs(new - theta) / np.maximum(np.abs(new), 1e-3)))
            theta = new
            history.append(change)
            if self.progress is not None:
                self.progress(it, change, theta.copy())
            if change < self.tol:
                converged = True
                break
        stop = (f"parameter change {history[-1]:.2g} < tol {self.tol:g}" if converged else
                f"max_iter: {self.max_iter} iterations, last parameter change {history[-1]:.2g} (tol {self.tol:g})")
        if not converged:
            warnings.warn(f"IV did not converge: {stop}; the estimates are not final (raise max_iter)",
                          ConvergenceWarning, stacklevel=3)
        info = {"iterations": len(history), "converged": converged, "stop": stop, "change_history": history,
                "start": self.start, "instrument_segment_s": segment, "residual_std": rstd}
        return self._result(data, theta, cc, cw, biases, info)

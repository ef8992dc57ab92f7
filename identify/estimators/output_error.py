"""The segmented output-error engine: runs cut into segments, all simulated at once.

Used by ML (:class:`OutputError`: residuals and their exact Jacobian, plain or multiple
shooting) and by IV (:func:`simulate_segments`: instrument states restarted from the measured
ones every few seconds).

Output error compares measured outputs ``z`` with the outputs ``y`` of the model simulated from
the inputs. Each run is cut into *segments*; every segment is simulated from its own initial state
and every run carries its own output zero shifts (biases)::

    x_s[k+1] = Phi x_s[k] + Gamma u_s[k],   x_s[0] = x0_s
    y_s[k]   = C x_s[k] + D u_s[k] + b_run(s)

One segment per run is the *plain* output-error form. Several short segments per run is
*multiple shooting*: an unstable model is integrated only over a few seconds at a time, so it
cannot diverge and the cost stays nearly quadratic; the segment initial states are nuisance
parameters estimated with the derivatives.

The unknowns are stacked in one vector ``beta = [theta (p), x0 per segment (n each), bias per run
(ny each)]``. All segments are padded to a common length and simulated *together* (segments are
a trailing axis), as are the parameter sensitivities: one time recursion per iteration, however
many parameters and segments. The normal equations are accumulated segment by segment from the
small local Jacobian ``[dy/dtheta, dy/dx0_s, dy/db]``, so the big, mostly empty global Jacobian
is never formed.

The seam for nonlinear models: everything after the simulation (cost, normal equations,
:class:`~identify.estimators.information.BlockInformation`, the coloured-residual bounds, ML's
solver) reads only the layout attributes set in ``__init__`` (``p, n, ny, layout, Z, mask,
n_runs, local_index, n_beta, estimate_x0, estimate_bias``) and the :class:`Response` of
:meth:`OutputError.evaluate`. A subclass that sets those and supplies ``evaluate`` (prediction and
sensitivities of every segment; ``dy_x0`` per segment, (L, ny, n, S), when a nonlinear model's
initial-state response differs from segment to segment) and ``names`` plugs a nonlinear problem
into the engine: :class:`identify.compat.fit.KinematicProblem` (flight-path reconstruction).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError
from ..model.linear import LinearModel
from ..model.profile import Profile
from ..model.sensitivity import discretize_with_derivatives
from ..model.simulate import DIVERGENCE_LIMIT, discretize, propagate
from .coloured_bounds import COLOUR_MAX_ITER, COLOUR_TOL, ColouredBounds
from .information import BlockInformation

MIN_SEGMENT = 1.0  # s: shorter segments leave too little response to pin down their own x0
MAX_SEGMENT = 5.0  # s: longer segments of an unstable model grow too nonlinear in theta
OUTPUT_LIMIT = 1e3  # a modelled output this many times the largest measured one has diverged
BLOCK_FLOATS = 2_000_000  # time blocks of the sensitivity work hold about this many floats (16 MB)
SENS_GROUP_FLOATS = 8_000_000  # parameter sensitivities held at once, groups of segments (64 MB)


def auto_segment(model: LinearModel, duration: float) -> float:
    """Segment length in s for a model and the longest run (``math.inf``: the plain form).

    A stable model, or one whose fastest divergence doubles the response no more than once over
    the run, is simulated over the whole run. Otherwise segments last half the fastest unstable
    mode's time to double (clipped to 1..5 s): over a segment the a priori model's error grows
    by at most about 40 %.
    """
    t_double = min((m.time_to_half_or_double for m in model.modes() if not m.stable), default=math.inf)
    if duration <= t_double:
        return math.inf
    return float(np.clip(t_double / 2, MIN_SEGMENT, MAX_SEGMENT))


@dataclass
class Layout:
    """Segments of the runs: ``run`` (S,) run index, ``start`` (S,) first sample in the run,
    ``length`` (S,) samples; ``L`` the longest segment (the padded length)."""

    run: np.ndarray
    start: np.ndarray
    length: np.ndarray

    @property
    def L(self) -> int:
        return int(self.length.max())

    @property
    def n_segments(self) -> int:
        return len(self.run)


def cut(run_lengths: list[int], dt: float, segment: float) -> Layout:
    """Cut runs of ``run_lengths`` samples into near-equal segments of at most ``segment`` s."""
    run, start, length = [], [], []
    for r, N in enumerate(run_lengths):
        pieces = 1 if not math.isfinite(segment) else max(1, int(math.ceil((N - 1) * dt / segment - 1e-9)))
        edges = np.linspace(0, N, pieces + 1).round().astype(int)
        for a, b in zip(edges[:-1], edges[1:]):
            run.append(r), start.append(a), length.append(b - a)
    return Layout(np.array(run), np.array(start), np.array(length))


def restarts(n_samples: int, dt: float, segment: float | None) -> Layout:
    """One run cut every ``segment`` s (whole samples) from its first sample on, for a simulation
    restarted from known states (``None`` or ``inf``: one segment)."""
    step = n_samples if segment is None or not math.isfinite(segment) else max(1, int(round(segment / dt)))
    start = np.arange(0, n_samples, step)
    return Layout(np.zeros(len(start), int), start, np.minimum(step, n_samples - start))


def pad(layout: Layout, series: list[np.ndarray]) -> np.ndarray:
    """The segments of per-run series (N_r, k) side by side, zero-padded: (L, k, S)."""
    out = np.zeros((layout.L, series[0].shape[1], layout.n_segments))
    for s, (r, a, n_s) in enumerate(zip(layout.run, layout.start, layout.length)):
        out[:n_s, :, s] = series[r][a:a + n_s]
    return out


def simulate_segments(Phi: np.ndarray, forcing: np.ndarray, x_start: np.ndarray, layout: Layout) -> np.ndarray:
    """States (N, n) of one run simulated segment by segment, all segments in one recursion:
    ``x[k+1] = Phi x[k] + forcing[k]`` (forcing (N, n)), segment s starting from ``x_start[s]``
    ((S, n)) at its first sample."""
    x = propagate(Phi, pad(layout, [forcing]), np.asarray(x_start, dtype=float).T)
    return np.concatenate([x[:n_s, :, s] for s, n_s in enumerate(layout.length)])


@dataclass
class Response:
    """Model response at one ``beta``: ``e`` (L, ny, S) residual z - y (0 on padding), ``y`` (L, ny, S);
    with the Jacobian: ``dy_x0`` (L, ny, n) (shared by all segments; (L, ny, n, S) per segment for
    a nonlinear model) and the parameter
    sensitivities ``dy_theta`` (L, ny, p, S), held (``held``) or, for many segments, recomputed a
    group of segments at a time by ``compute(segments)`` (:meth:`theta_sensitivities`) so that
    they never exist whole (an hour in 3 s segments: 460 MB)."""

    beta: np.ndarray
    e: np.ndarray
    y: np.ndarray
    dy_x0: np.ndarray | None = None
    held: np.ndarray | None = None
    compute: object = None

    @property
    def dy_theta(self) -> np.ndarray | None:
        """All parameter sensitivities (L, ny, p, S) (computed whole if not held)."""
        return self.theta_sensitivities(slice(None)) if self.held is not None or self.compute else None

    def theta_sensitivities(self, segments: slice) -> np.ndarray:
        """Parameter sensitivities of the ``segments`` (L, ny, p, s)."""
        return self.held[..., segments] if self.held is not None else self.compute(segments)


class OutputError:
    """The output-error problem of a profile over runs cut into segments.

    ``u``: list of (N_r, m) inputs; ``z``: list of (N_r, ny) measured outputs; ``dt`` s;
    ``segment`` s (``math.inf``: one segment per run). ``estimate_x0``/``estimate_bias`` choose
    whether segment initial states / run zero shifts are unknowns (else held at their start values).
    """

    prior = None  # a PriorTerm where set; a subclass that builds its own state (compat's kinematics) has none

    def __init__(self, profile: Profile, u: list[np.ndarray], z: list[np.ndarray], dt: float,
                 segment: float, estimate_x0: bool = True, estimate_bias: bool = True):
        self.profile, self.dt = profile, float(dt)
        self.model0 = LinearModel(profile)
        self.n, self.m, self.ny, self.p = (self.model0.n_states, self.model0.n_inputs,
                                           self.model0.n_outputs, len(self.model0.names))
        self.layout = lay = cut([len(zr) for zr in z], dt, segment)
        S = lay.n_segments
        self.U, self.Z = pad(lay, u), pad(lay, z)
        self.mask = pad(lay, [np.ones((len(zr), 1)) for zr in z])[:, 0, :]
        self.n_runs = len(z)
        peak = np.max([np.abs(zr).max(axis=0) for zr in z], axis=0)
        self.y_limit = np.where(peak > 0, OUTPUT_LIMIT * peak, np.inf)
        # global index of each local column [theta | x0 of the segment | bias of its run]; -1: held
        p, n, ny = self.p, self.n, self.ny
        x0_idx = p + np.arange(S * n).reshape(S, n) if estimate_x0 else -np.ones((S, n), int)
        nb0 = p + (S * n if estimate_x0 else 0)
        b_idx = nb0 + np.arange(self.n_runs * ny).reshape(self.n_runs, ny) if estimate_bias \
            else -np.ones((self.n_runs, ny), int)
        self.local_index = np.hstack([np.tile(np.arange(p), (S, 1)), x0_idx, b_idx[lay.run]])
        self.n_beta = nb0 + (self.n_runs * ny if estimate_bias else 0)
        self.estimate_x0, self.estimate_bias = estimate_x0, estimate_bias
        self.x0_held = np.zeros((n, S))  # used when x0 is not estimated
        self.b_held = np.zeros((ny, self.n_runs))
        self.prior = None  # a PriorTerm (identify.estimators.prior): its residuals join the cost

    # -- the unknown vector ----------------------------------------------------------------------
    def unpack(self, beta: np.ndarray):
        """``theta`` (p,), ``x0`` (n, S), ``bias`` (ny, R) from ``beta``."""
        p, n, ny, S = self.p, self.n, self.ny, self.layout.n_segments
        theta = beta[:p]
        k = p
        if self.estimate_x0:
            x0, k = beta[k:k + S * n].reshape(S, n).T, k + S * n
        else:
            x0 = self.x0_held
        b = beta[k:k + self.n_runs * ny].reshape(self.n_runs, ny).T if self.estimate_bias else self.b_held
        return theta, x0, b

    def initial_beta(self, theta: np.ndarray) -> np.ndarray:
        """``theta`` with each segment's initial state taken from the measured outputs that are
        plain states (others 0) and zero biases; also sets the held values."""
        p = self.profile
        x0 = np.zeros((self.n, self.layout.n_segments))
        for j, y in enumerate(p.outputs):
            if y in p.states and p.output_terms(y) == {y: 1.0}:
                x0[p.state_names.index(y)] = self.Z[0, j, :]
        self.x0_held = x0
        parts = [np.asarray(theta, float)]
        if self.estimate_x0:
            parts.append(x0.T.ravel())
        if self.estimate_bias:
            parts.append(np.zeros(self.n_runs * self.ny))
        return np.concatenate(parts)

    def names(self) -> list[str]:
        """Name of every element of beta (parameters, ``x0[s].state``, ``bias[r].output``)."""
        out = list(self.model0.names)
        if self.estimate_x0:
            out += [f"x0[{s}].{x}" for s in range(self.layout.n_segments) for x in self.profile.state_names]
        if self.estimate_bias:
            out += [f"bias[{r}].{y}" for r in range(self.n_runs) for y in self.profile.outputs]
        return out

    # -- simulation ------------------------------------------------------------------------------
    def evaluate(self, beta: np.ndarray, jacobian: bool = True) -> Response:
        """Residuals at ``beta`` and, with ``jacobian``, the exact output sensitivities."""
        theta, x0, b = self.unpack(beta)
        model = self.model0.with_theta(theta)
        L, S, n = self.layout.L, self.layout.n_segments, self.n
        if jacobian:
            Phi, Gamma, dPhi, dGamma = discretize_with_derivatives(model, self.dt)
        else:
            Phi, Gamma = discretize(model.A, model.B, self.dt)
        with np.errstate(over="ignore", invalid="ignore"):  # divergence is reported below
            x = propagate(Phi, Gamma @ self.U, x0)  # (L, n, S); matmul broadcasts over time
            C, D = model.C, model.D
            y = C @ x + D @ self.U + b[:, self.layout.run][None]
        self._check(x, y)
        e = np.where(self.mask[:, None, :] > 0, self.Z - y, 0.0)  # padding may hold inf
        ev = Response(beta, e, y)
        if jacobian:
            ev.dy_x0 = self._state_response(C, Phi)

            def compute(segments):
                return self._sensitivities(model, Phi, dPhi, dGamma, x[..., segments], self.U[..., segments])

            if self.segment_groups() == [(0, S)]:
                ev.held = compute(slice(None))
            else:
                ev.compute = compute
        return ev

    def segment_groups(self) -> list[tuple[int, int]]:
        """Groups of segments ``(a, b)`` whose parameter sensitivities hold about SENS_GROUP_FLOATS."""
        lay = self.layout
        size = max(1, SENS_GROUP_FLOATS // (lay.L * self.ny * self.p))
        return [(a, min(lay.n_segments, a + size)) for a in range(0, lay.n_segments, size)]

    def blocks(self, columns: int):
        """Time blocks ``(k0, k1)`` over the padded length, each holding about BLOCK_FLOATS floats
        of a (block, n, columns) array: long records never hold the sensitivity work whole."""
        L = self.layout.L
        size = max(8, BLOCK_FLOATS // max(self.n * columns, 1))
        return [(k0, min(L, k0 + size)) for k0 in range(0, L, size)]

    def _sensitivities(self, model: LinearModel, Phi, dPhi, dGamma, x, U) -> np.ndarray:
        """Parameter sensitivities (L, ny, p, S) of the segments whose states are ``x`` (L, n, S)
        and inputs ``U`` (L, m, S): the recursion ``S[k+1] = Phi S[k] + dPhi_i x[k] + dGamma_i u[k]``
        run block by block in time (the state carried across), so its forcing and states exist one
        block at a time."""
        L, S, n, p, ny = self.layout.L, x.shape[2], self.n, self.p, self.ny
        C = model.C
        dy_theta = np.empty((L, ny, p, S))
        sens = np.zeros((n, p * S))
        for k0, k1 in self.blocks(p * S):
            xb, ub = x[k0:k1], U[k0:k1]
            # forcing of the sensitivities, dPhi_i x + dGamma_i u, for all i at once: (l, n, p, S)
            forcing = ((dPhi.reshape(p * n, n) @ xb + dGamma.reshape(p * n, self.m) @ ub)
                       .reshape(k1 - k0, p, n, S).transpose(0, 2, 1, 3).reshape(k1 - k0, n, p * S))
            block = propagate(Phi, forcing, sens)
            direct = model.dC.reshape(p * ny, n) @ xb + model.dD.reshape(p * ny, self.m) @ ub
            dy_theta[k0:k1] = ((C @ block).reshape(k1 - k0, ny, p, S)
                               + direct.reshape(k1 - k0, p, ny, S).transpose(0, 2, 1, 3))
            sens = Phi @ block[-1] + forcing[-1]
        return dy_theta

    def initial_state_response(self, theta: np.ndarray) -> np.ndarray:
        """``dy/dx0 = C Phi^k`` (L, ny, n), the same for every segment (without the parameter
        sensitivities that :meth:`evaluate` computes with it)."""
        model = self.model0.with_theta(theta)
        Phi, _ = discretize(model.A, model.B, self.dt)
        return self._state_response(model.C, Phi)

    def _state_response(self, C: np.ndarray, Phi: np.ndarray) -> np.ndarray:
        """``C Phi^k`` (L, ny, n), a time block at a time."""
        out, power = np.empty((self.layout.L, self.ny, self.n)), np.eye(self.n)
        for k0, k1 in self.blocks(self.n):
            powers = propagate(Phi, np.zeros((k1 - k0, self.n, self.n)), power)
            out[k0:k1] = C @ powers
            power = Phi @ powers[-1]
        return out

    def _check(self, x: np.ndarray, y: np.ndarray) -> None:
        """SimulationError naming state or output, run and time where the simulation diverges:
        a state beyond DIVERGENCE_LIMIT or an output beyond OUTPUT_LIMIT times its measured peak."""
        valid = self.mask[:, None, :] > 0
        bad_x = (~np.isfinite(x) | (np.abs(x) > DIVERGENCE_LIMIT)) & valid
        bad_y = (np.abs(y) > self.y_limit[None, :, None]) & valid
        checks = ((bad_x, "state", self.profile.state_names, f"exceeds {DIVERGENCE_LIMIT:g}"),
                  (bad_y, "output", self.profile.outputs, f"exceeds {OUTPUT_LIMIT:g} times its measured peak"))
        for bad, kind, names, what in checks:
            if bad.any():
                k, j, s = np.argwhere(bad)[0]
                lay = self.layout
                t = (lay.start[s] + k) * self.dt
                raise SimulationError(f"simulation diverged: {kind} '{names[j]}' {what} in run {lay.run[s] + 1} "
                                      f"at t = {t:.3f} s from the run's start")

    # -- cost and normal equations ---------------------------------------------------------------
    def whitened(self, ev: Response, Wh: np.ndarray) -> np.ndarray:
        """Whitened residuals ``Wh e`` as one flat vector over all valid samples."""
        return (Wh @ ev.e).transpose(2, 0, 1)[self.mask.T > 0].ravel()

    def cost(self, ev: Response, Wh: np.ndarray) -> float:
        """0.5 sum e^T R^-1 e (R^-1 = Wh^T Wh), plus the prior's 0.5 sum ((theta - mu) / s)^2."""
        prior = 0.0 if self.prior is None else self.prior.cost(ev.beta[:self.p])
        return 0.5 * float(np.sum((Wh @ ev.e) ** 2)) + prior

    def residual_vector(self, beta: np.ndarray, Wh: np.ndarray) -> np.ndarray:
        """Whitened residuals at ``beta`` (what a general least-squares solver minimises)."""
        return self.whitened(self.evaluate(beta, jacobian=False), Wh)

    def local_jacobian(self, ev: Response, Wh: np.ndarray, k0: int = 0, k1: int | None = None,
                        segment: int | slice | None = None, dy_theta: np.ndarray | None = None) -> np.ndarray:
        """Whitened local Jacobian ``Wh [dy/dtheta, dy/dx0_s, dy/db]`` of every segment (or of
        ``segment``, an index or a slice of them) over the samples k0..k1 (default all),
        (S, k1 - k0, ny, p + n + ny), 0 on padding; ``dy_theta`` the segments' parameter
        sensitivities (L, ny, p, S) if already at hand."""
        _, ny, S = ev.e.shape
        k1 = ev.e.shape[0] if k1 is None else k1
        segs = segment if isinstance(segment, slice) else \
            slice(None) if segment is None else slice(segment, segment + 1)
        S = len(range(S)[segs])
        if dy_theta is None:
            dy_theta = ev.theta_sensitivities(segs)
        p, n, l = self.p, self.n, k1 - k0
        Jloc = np.empty((S, l, ny, p + n + ny))
        Jloc[..., :p] = ((Wh @ dy_theta[k0:k1].reshape(l, ny, p * S)).reshape(l, ny, p, S)
                         .transpose(3, 0, 1, 2))
        if ev.dy_x0.ndim == 4:  # a nonlinear model: each segment its own initial-state response
            Jloc[..., p:p + n] = (Wh @ ev.dy_x0[k0:k1, :, :, segs].reshape(l, ny, -1)).reshape(
                l, ny, n, S).transpose(3, 0, 1, 2)
        else:
            Jloc[..., p:p + n] = (Wh @ ev.dy_x0[k0:k1])[None]
        Jloc[..., p + n:] = Wh
        Jloc[self.mask[k0:k1, segs].T == 0] = 0.0  # not a product: padding may hold inf
        return Jloc

    def normal_equations(self, ev: Response, Wh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Information matrix ``M = J^T R^-1 J`` (n_beta, n_beta) and ``g = J^T R^-1 e`` (n_beta,),
        J = dy/dbeta, dense (small problems; :meth:`information` keeps M's block structure)."""
        M, g = self.information(ev, Wh)
        return M.dense(), g

    def information(self, ev: Response, Wh: np.ndarray, active: np.ndarray | None = None):
        """``M = J^T R^-1 J`` as a :class:`~identify.estimators.information.BlockInformation`
        (globals, each segment's initial states, their couplings; ``active`` the unknowns solved
        for, default those with any sensitivity) and ``g = J^T R^-1 e`` (n_beta,)."""
        Ml, gl = self.local_information(ev, Wh)
        g = np.zeros(self.n_beta)
        for s in range(len(gl)):
            keep = self.local_index[s] >= 0
            np.add.at(g, self.local_index[s][keep], gl[s][keep])
        return BlockInformation(Ml, self.local_index, self.n_beta, self.x_index, active), g

    @property
    def x_index(self) -> np.ndarray:
        """Places in beta of each segment's initial states (S, n); (S, 0) when they are held."""
        S = self.layout.n_segments
        return self.local_index[:, self.p:self.p + self.n] if self.estimate_x0 else np.zeros((S, 0), int)

    def local_information(self, ev: Response, Wh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per segment ``J_s^T R^-1 J_s`` (S, k, k) and ``J_s^T R^-1 e_s`` (S, k) over its local
        unknowns (k = p + n + ny), accumulated a time block at a time."""
        _, ny, S = ev.e.shape
        k = self.p + self.n + ny
        Ml, gl = np.zeros((S, k, k)), np.zeros((S, k))
        for a, b in self.segment_groups():  # a group of segments at a time, block by block in time:
            segs = slice(a, b)               # bounded memory for long records
            dy = ev.theta_sensitivities(segs)
            for k0, k1 in self.blocks((b - a) * k):
                Jloc = self.local_jacobian(ev, Wh, k0, k1, segs, dy).reshape(b - a, (k1 - k0) * ny, k)
                ew = (Wh @ ev.e[k0:k1, :, segs]).transpose(2, 0, 1).reshape(b - a, (k1 - k0) * ny, 1)
                Jt = Jloc.transpose(0, 2, 1)
                Ml[segs] += Jt @ Jloc
                gl[segs] += (Jt @ ew)[..., 0]
        if self.prior is not None:  # the prior's residuals: theta's rows, in the first segment's block
            p = self.p
            Ml[0, np.arange(p), np.arange(p)] += self.prior.precision
            gl[0, :p] += self.prior.gradient(ev.beta[:p])
        return Ml, gl

    def coloured_information(self, ev: Response, Wh: np.ndarray, info: BlockInformation,
                             max_iter: int = COLOUR_MAX_ITER, tol: float = COLOUR_TOL):
        """Morelli & Klein's sandwich for coloured residuals, ``cov B cov``, with
        ``B = sum over whitened outputs y and segments s of J_ys^T T_y J_ys`` and ``cov = M^-1``
        (``info``, the information at the estimate).

        ``J_ys`` is the whitened sensitivity of output y in segment s (rows of ``Wh J``, ``J`` =
        dy/dbeta) and ``T_y`` the Toeplitz matrix of the autocorrelation ``rho_y`` of output y's
        whitened measurement noise in the run of segment s, pooled over that run's segments (lag
        products stay within a segment: segments are taken as independent of each other, as are
        the outputs; each run has its own: runs flown on different axes differ in residual size).

        ``rho_y`` comes from the residuals ``e = (I - H) w`` (H = J M^-1 J^T, whitened), not the
        noise ``w``: the fit removes from them exactly the components along the sensitivities, so
        their plain autocorrelation ``r_y`` makes ``B`` too small (for white noise with many unknowns
        per sample, such as short multiple-shooting segments, by 30-40 % in the tests). Its expected
        value is ``E r_y(k) = rho_y(k) - [2 tr(S_k H T) - tr(S_k H T H)]_y / N`` (S_k the lag-k
        shift; ``H T H = J (cov B cov) J^T``), so ``rho`` is solved from the linear fixed point
        ``rho = r + [2 xcorr(J cov, T J) - xcorr(J cov B cov, J)] / N`` starting from white noise
        (the first pass is the exact correction for white noise). Its slow modes are the low
        frequencies that the segments' initial states absorb (plain passes contract them by only
        ~0.65 each), so the passes are preconditioned by the circulant approximation of the map
        (:func:`_preconditioner`) and combined by Anderson acceleration (:func:`_anderson_weights`),
        until no parameter's standard error changes by more than ``tol`` (relative) or after
        ``max_iter`` passes. All of it by FFT convolutions over time, all columns of a segment at
        once; the covariances are formed block by block (:class:`BlockInformation`), never
        (n_beta, n_beta).

        Returns the covariance (a :class:`~identify.estimators.information.BlockCovariance`),
        ``rho`` (L, ny) (lag 0 first) and the number of passes.

        Computed by :class:`~identify.estimators.coloured_bounds.ColouredBounds`.
        """
        return ColouredBounds(self, ev, Wh, info).solve(max_iter, tol)

    # -- per-run views -----------------------------------------------------------------------------
    def per_run(self, arr: np.ndarray) -> list[np.ndarray]:
        """Segment-stacked (L, ny, S) array back to one (N_r, ny) array per run."""
        lay = self.layout
        out = [[] for _ in range(self.n_runs)]
        for s in range(lay.n_segments):
            out[lay.run[s]].append(arr[:lay.length[s], :, s])
        return [np.vstack(parts) for parts in out]

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
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft

from ..errors import SimulationError
from ..model.linear import LinearModel
from ..model.profile import Profile
from ..model.sensitivity import discretize_with_derivatives
from ..model.simulate import DIVERGENCE_LIMIT, discretize, propagate
from .colour import power
from .information import BlockInformation

MIN_SEGMENT = 1.0  # s: shorter segments leave too little response to pin down their own x0
MAX_SEGMENT = 5.0  # s: longer segments of an unstable model grow too nonlinear in theta
COLOUR_MAX_ITER = 30  # passes of the coloured-noise autocorrelation correction (see coloured_information)
COLOUR_TOL = 1e-2  # ... until no parameter standard error changes by more than this (relative)
OUTPUT_LIMIT = 1e3  # a modelled output this many times the largest measured one has diverged
BLOCK_FLOATS = 2_000_000  # time blocks of the sensitivity work hold about this many floats (16 MB)
COLOUR_CHUNK_FLOATS = 3_000_000  # Jacobian columns per FFT in the coloured correction: ~24 MB of spectra
SENS_GROUP_FLOATS = 8_000_000  # parameter sensitivities held at once, groups of segments (64 MB)
COLOUR_CACHE = 8_000_000  # spectra kept between passes up to this many floats (64 MB)


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
    with the Jacobian: ``dy_x0`` (L, ny, n) (shared by all segments) and the parameter
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

            if self._segment_groups() == [(0, S)]:
                ev.held = compute(slice(None))
            else:
                ev.compute = compute
        return ev

    def _segment_groups(self) -> list[tuple[int, int]]:
        """Groups of segments ``(a, b)`` whose parameter sensitivities hold about SENS_GROUP_FLOATS."""
        lay = self.layout
        size = max(1, SENS_GROUP_FLOATS // (lay.L * self.ny * self.p))
        return [(a, min(lay.n_segments, a + size)) for a in range(0, lay.n_segments, size)]

    def _blocks(self, columns: int):
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
        for k0, k1 in self._blocks(p * S):
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
        for k0, k1 in self._blocks(self.n):
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
        """0.5 sum e^T R^-1 e (R^-1 = Wh^T Wh)."""
        return 0.5 * float(np.sum((Wh @ ev.e) ** 2))

    def residual_vector(self, beta: np.ndarray, Wh: np.ndarray) -> np.ndarray:
        """Whitened residuals at ``beta`` (what a general least-squares solver minimises)."""
        return self.whitened(self.evaluate(beta, jacobian=False), Wh)

    def _local_jacobian(self, ev: Response, Wh: np.ndarray, k0: int = 0, k1: int | None = None,
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
        Jloc[..., p:p + n] = (Wh @ ev.dy_x0[k0:k1])[None]
        Jloc[..., p + n:] = Wh
        Jloc[self.mask[k0:k1, segs].T == 0] = 0.0  # not a product: padding may hold inf
        return Jloc

    def _scatter(self, Ml: np.ndarray, gl: np.ndarray | None = None):
        """Sum per-segment local blocks ``Ml`` (S, k, k) (and ``gl`` (S, k)) into the global ones."""
        M, g = np.zeros((self.n_beta, self.n_beta)), np.zeros(self.n_beta)
        for s in range(len(Ml)):
            idx = self.local_index[s]
            keep = idx >= 0
            i = idx[keep]
            M[np.ix_(i, i)] += Ml[s][np.ix_(keep, keep)]
            if gl is not None:
                g[i] += gl[s][keep]
        return M, g

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
        for a, b in self._segment_groups():  # a group of segments at a time, block by block in time:
            segs = slice(a, b)               # bounded memory for long records
            dy = ev.theta_sensitivities(segs)
            for k0, k1 in self._blocks((b - a) * k):
                Jloc = self._local_jacobian(ev, Wh, k0, k1, segs, dy).reshape(b - a, (k1 - k0) * ny, k)
                ew = (Wh @ ev.e[k0:k1, :, segs]).transpose(2, 0, 1).reshape(b - a, (k1 - k0) * ny, 1)
                Jt = Jloc.transpose(0, 2, 1)
                Ml[segs] += Jt @ Jloc
                gl[segs] += (Jt @ ew)[..., 0]
        return Ml, gl

    def coloured_information(self, ev: Response, Wh: np.ndarray, info: BlockInformation,
                             max_iter: int = COLOUR_MAX_ITER, tol: float = COLOUR_TOL):
        """Morelli & Klein's sandwich for coloured residuals, ``cov B cov``, with
        ``B = sum over whitened outputs y and segments s of J_ys^T T_y J_ys`` and ``cov = M^-1``
        (``info``, the information at the estimate).

        ``J_ys`` is the whitened sensitivity of output y in segment s (rows of ``Wh J``, ``J`` =
        dy/dbeta) and ``T_y`` the Toeplitz matrix of the autocorrelation ``rho_y`` of output y's
        whitened measurement noise, pooled over all segments of all runs (lag products stay within a
        segment: segments are taken as independent of each other, as are the outputs).

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

        Memory: the columns of each segment's Jacobian go through the FFTs a chunk at a time
        (COLOUR_CHUNK_FLOATS); their spectra are kept between passes only while they are small
        (COLOUR_CACHE), else recomputed, so an hour at 100 Hz stays within a few hundred MB.
        """
        L, ny, S = ev.e.shape
        n_fft = scipy.fft.next_fast_len(2 * L - 1, real=True)
        F = n_fft // 2 + 1
        count = max(float(self.mask.sum()), 1.0)
        r = np.fft.irfft(power(Wh @ ev.e, n_fft).sum(axis=2) / count, n_fft, axis=0)  # (n_fft, ny)
        k_loc = self.p + self.n + ny
        cov, _ = info.covariance()
        cov_local = info.local(cov)  # (S, k, k)
        # columns of each segment's Jacobian are taken a chunk at a time, so that the spectra of a
        # long record (n_fft ~ 2 N) never exist for all columns at once; spectra are kept between
        # passes while they fit in COLOUR_CACHE floats (short segments: always)
        width = max(1, min(k_loc, COLOUR_CHUNK_FLOATS // (2 * F * ny)))  # complex: 2 floats
        cache_ok = S * F * ny * k_loc * 4 <= COLOUR_CACHE  # two complex spectra per column
        Jloc = self._local_jacobian(ev, Wh) if cache_ok else None  # (S, L, ny, k), 0 on padding
        short = L * ny * k_loc <= COLOUR_CHUNK_FLOATS  # a segment's Jacobian may be held whole

        def segments():
            """``(s, keep, J)`` for every segment in turn; many short segments have their
            Jacobians rebuilt a group at a time (one sensitivity recursion for the group), a
            long one a time block at a time."""
            if held is not None:
                yield from held
                return
            for a, b in [(0, S)] if Jloc is not None or not short else self._segment_groups():
                group = Jloc if Jloc is not None else self._local_jacobian(ev, Wh, segment=slice(a, b)) \
                    if short else None
                for s in range(a, b):
                    keep = self.local_index[s] >= 0
                    whole = None if group is None else group[s - a, :self.layout.length[s]][..., keep]
                    yield s, keep, _SegmentJacobian(self, ev, Wh, s, keep, whole)
        held = None
        held = list(segments()) if Jloc is not None else None  # small: built once for all passes

        cache = {}

        def spectra(s, c, J, cov_ii):
            """Spectra (w, ny, F) of the columns c of J and of (J cov)[:, c], time last (scipy's
            FFT along a contiguous last axis is 2x numpy's along a strided first one). The FFT is
            linear: with all columns at once the latter is a small product, not another FFT."""
            key = (s, c.start, c.stop)  # slices are not hashable before Python 3.12
            if key in cache:
                return cache[key]
            FJ = scipy.fft.rfft(J.columns(c), n_fft, axis=-1)
            FG = _over_columns(cov_ii, FJ) if c == slice(None) else \
                scipy.fft.rfft(J.times(cov_ii[:, c]), n_fft, axis=-1)
            if cache_ok:
                cache[key] = FJ, FG
            return FJ, FG

        def chunks(q):
            return [slice(None)] if width >= q else [slice(a, min(q, a + width)) for a in range(0, q, width)]

        def first_half(rho, white):
            """``B(rho)`` (local blocks) and the 2 xcorr(J cov, T J) part of the correction. For
            white ``rho`` (the first pass) ``T J = rho(0) J`` needs no FFT."""
            spectrum = np.clip(np.fft.rfft(rho, axis=0).real, 0.0, None).T  # a covariance: PSD, (ny, F)
            rho0 = rho[0][:, None]
            Bl = np.zeros((S, k_loc, k_loc))
            corr = np.zeros((ny, F))
            shared = {}

            def toeplitz_times(FJ, J, c, cols):
                """``T J`` (time last) and its spectrum for the columns c of J (``cols`` of FJ)."""
                if white:
                    return rho0 * J.columns(c)[cols], rho0 * FJ[cols]
                TJ = scipy.fft.irfft(spectrum * FJ[cols], n_fft, axis=-1)[..., :J.length]
                return TJ, scipy.fft.rfft(TJ, n_fft, axis=-1)

            for s, keep, J in segments():
                cov_ii = cov_local[s][np.ix_(keep, keep)]
                block = np.zeros((J.q, J.q))
                # the initial-state and zero-shift columns of segments of one length are the same
                # (C Phi^k and Wh): their T J is computed once per length (short segments only)
                for c in chunks(J.q):
                    FJ, FG = spectra(s, c, J, cov_ii)
                    n_own = int(keep[:self.p].sum()) if held is not None and c == slice(None) else len(FJ)
                    parts = [(slice(0, n_own), toeplitz_times(FJ, J, c, slice(0, n_own)))]
                    if n_own < len(FJ):
                        key = (J.length, keep.tobytes())
                        if key not in shared:
                            shared[key] = toeplitz_times(FJ, J, c, slice(n_own, None))
                        parts.append((slice(n_own, None), shared[key]))
                    for cols, (TJ, FTJ) in parts:
                        block[:, c][:, cols] = J.gram(TJ)
                        corr += 2 * _real_inner(FG[cols], FTJ)
                    del FJ, FG, parts
                Bl[s][np.ix_(keep, keep)] = block
            return 0.5 * (Bl + Bl.transpose(0, 2, 1)), corr

        def second_half(cov_c, corr):
            """``g(rho)``: the correction ``corr`` less xcorr(J cov B cov, J), cov_c = cov B cov."""
            cov_c = info.local(cov_c)
            for s, keep, J in segments():
                cc = cov_c[s][np.ix_(keep, keep)]
                for c in chunks(J.q):
                    FJ = spectra(s, c, J, cov_local[s][np.ix_(keep, keep)])[0]
                    FC = _over_columns(cc, FJ) if c == slice(None) else \
                        scipy.fft.rfft(J.times(cc[:, c]), n_fft, axis=-1)
                    corr -= _real_inner(FC, FJ)
                    del FJ, FC
            return r + np.fft.irfft(corr.T / count, n_fft, axis=0)

        xs, hs, fs, Bs = [], [], [], []
        rho = np.zeros_like(r)
        rho[0] = r[0]  # start: white noise of the residuals' variance
        std_old, gain = None, None
        for passes in range(1, max_iter + 1):
            B_k, corr = first_half(rho, white=passes == 1)
            g_k = second_half(info.sandwich(B_k), corr)
            if gain is None:
                gain = _preconditioner(g_k - r, r[0])
            # the preconditioned map h(rho) = rho + P (g(rho) - rho) has the same fixed point
            step = np.fft.irfft(gain * np.fft.rfft(g_k - rho, axis=0), n_fft, axis=0)
            xs.append(rho), hs.append(rho + step), fs.append(step), Bs.append(B_k)
            # B is linear in rho: the Anderson combination's B is the same combination of the passes'
            alpha = _anderson_weights(fs)
            cov_c = info.sandwich(sum(a * b for a, b in zip(alpha, Bs)))
            rho_bar = sum(a * x for a, x in zip(alpha, xs))
            std = np.sqrt(np.clip(np.diag(cov_c.gg)[:self.p], 0, None))  # the parameters (nuisances follow)
            if std_old is not None and np.all(np.abs(std - std_old) <= tol * std_old):
                break
            std_old = std
            rho = sum(a * h for a, h in zip(alpha, hs))
        return cov_c, rho_bar[:L], passes

    # -- per-run views -----------------------------------------------------------------------------
    def per_run(self, arr: np.ndarray) -> list[np.ndarray]:
        """Segment-stacked (L, ny, S) array back to one (N_r, ny) array per run."""
        lay = self.layout
        out = [[] for _ in range(self.n_runs)]
        for s in range(lay.n_segments):
            out[lay.run[s]].append(arr[:lay.length[s], :, s])
        return [np.vstack(parts) for parts in out]


def _over_columns(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``sum_q A[q, r] X[q]`` (r, ny, F) for complex spectra X (q, ny, F), as one real matrix
    product on their (re, im) pairs (4x fewer operations than a complex one)."""
    q, ny, F = X.shape
    return (A.T @ X.view(float).reshape(q, -1)).view(complex).reshape(A.shape[1], ny, F)


def _real_inner(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``Re sum_q conj(A) B`` (ny, F) of complex spectra (q, ny, F), on their (re, im) pairs."""
    _, ny, F = A.shape
    return np.einsum("qyf,qyf->yf", A.view(float), B.view(float)).reshape(ny, F, 2).sum(axis=-1)


def _preconditioner(correction: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """``1 / (1 - K(f))`` (F, ny), K the share of the noise spectrum the fit removes at each
    frequency, read from the first pass's ``correction`` (n_fft, ny) at white noise of ``variance``
    (ny,): the map ``rho -> r + A rho`` as a circulant (long segments) is ``S -> S_r + K S``."""
    K = np.fft.rfft(correction, axis=0).real / np.maximum(variance, 1e-300)
    return 1 / np.maximum(1 - K, 0.1)


def _anderson_weights(residuals: list[np.ndarray]) -> np.ndarray:
    """Weights ``alpha`` (k,), summing to 1, that minimise ``|sum alpha_i residuals_i|`` (2-norm)."""
    F = np.stack([f.ravel() for f in residuals], axis=1)
    if F.shape[1] == 1:
        return np.ones(1)
    # alpha = e_k - D gamma with D the differences of successive residuals: unconstrained least squares
    D = F[:, 1:] - F[:, :-1]
    gamma = np.linalg.lstsq(D, F[:, -1], rcond=None)[0]
    alpha = np.zeros(F.shape[1])
    alpha[-1] = 1.0
    alpha[1:] -= gamma
    alpha[:-1] += gamma
    return alpha


class _SegmentJacobian:
    """The whitened local Jacobian (l, ny, q) of one segment (its estimated columns ``keep``),
    either held ``whole`` or rebuilt from the stored sensitivities a time block at a time, so
    that a long record's Jacobian never exists whole: its products are all it offers."""

    def __init__(self, prob: OutputError, ev: Response, Wh: np.ndarray, segment: int, keep: np.ndarray,
                 whole: np.ndarray | None = None):
        self.prob, self.ev, self.Wh, self.segment, self.keep, self.whole = prob, ev, Wh, segment, keep, whole
        self.length, self.q, self.ny = int(prob.layout.length[segment]), int(keep.sum()), ev.e.shape[1]
        # columns first, time last (q, ny, l): the FFTs run along a contiguous axis and the
        # products over columns are single matrix products
        self.whole_t = None if whole is None else np.ascontiguousarray(whole.transpose(2, 1, 0))

    def columns(self, c: slice) -> np.ndarray:
        """Columns c of J (w, ny, l)."""
        if self.whole_t is not None:
            return self.whole_t[c]
        return np.ascontiguousarray(self.apply(np.eye(self.q)[:, c]).transpose(2, 1, 0))

    def times(self, C: np.ndarray) -> np.ndarray:
        """``J C`` (w, ny, l) for C (q, w)."""
        if self.whole_t is not None:
            return (C.T @ self.whole_t.reshape(self.q, -1)).reshape(C.shape[1], self.ny, self.length)
        return np.ascontiguousarray(self.apply(C).transpose(2, 1, 0))

    def _blocks(self):
        if self.whole is not None:
            yield 0, self.length, self.whole
            return
        for k0, k1 in self.prob._blocks(len(self.keep)):
            if k0 >= self.length:
                break
            k1 = min(k1, self.length)
            yield k0, k1, self.prob._local_jacobian(self.ev, self.Wh, k0, k1, self.segment)[0][..., self.keep]

    def apply(self, C: np.ndarray) -> np.ndarray:
        """``J C`` (l, ny, w) for C (q, w)."""
        out = np.empty((self.length, self.ny, C.shape[1]))
        for k0, k1, J in self._blocks():
            out[k0:k1] = J @ C
        return out

    def gram(self, T: np.ndarray) -> np.ndarray:
        """``J^T T`` (q, w) summed over time and outputs, T (w, ny, l)."""
        w = T.shape[0]
        if self.whole_t is not None:
            return self.whole_t.reshape(self.q, -1) @ T.reshape(w, -1).T
        acc = np.zeros((self.q, w))
        for k0, k1, J in self._blocks():
            acc += J.reshape(-1, self.q).T @ np.ascontiguousarray(T[..., k0:k1].transpose(2, 1, 0)).reshape(-1, w)
        return acc

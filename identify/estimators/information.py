"""The information matrix of (multiple-shooting) output error, solved by block elimination.

The unknowns ``beta`` split into *globals* (the derivatives theta and the runs' zero shifts) and
the initial states of every segment. A segment's initial states influence only that segment, so
the information matrix ``M = J^T R^-1 J`` is an *arrow*: a dense globals block ``M_gg`` (G, G),
one small block ``M_xx,s`` (n, n) per segment and the couplings ``M_gx,s`` (G, n); there is
nothing between two segments' initial states. An hour at 100 Hz cut into 3 s segments has
thousands of segments, and the dense (n_beta, n_beta) matrix (GBs, O(n_beta^3) to factor) is
never formed: the segments' states are eliminated (Schur complement)::

    (M_gg - sum_s M_gx,s M_xx,s^-1 M_xg,s) d_g = r_g - sum_s M_gx,s M_xx,s^-1 r_x,s
    d_x,s = M_xx,s^-1 (r_x,s - M_xg,s d_g)

and of the covariance ``M^-1`` only the blocks anyone reads are formed: globals (G, G), each
segment's states (n, n) and their coupling to the globals (G, n) (:class:`BlockCovariance`).
Everything is done on the matrix scaled to unit diagonal (conditioning, and Marquardt's damping
``M + lam diag(M)`` is then ``Ms + lam I``); unknowns that nothing excites (zero diagonal) are held.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

ILL_CONDITIONED = 1e14  # condition number of a scaled block beyond which its inverse is a pseudo-inverse


@dataclass
class BlockCovariance:
    """The blocks of a covariance of ``beta`` that are ever read: ``gg`` (G, G) of the globals,
    ``gx`` (S, G, n) globals x each segment's initial states and ``xx`` (S, n, n); ``g_index``
    (G,) and ``x_index`` (S, n) their places in beta (n_beta unknowns); 0 for held unknowns."""

    gg: np.ndarray
    gx: np.ndarray
    xx: np.ndarray
    g_index: np.ndarray
    x_index: np.ndarray
    n_beta: int

    def diag(self) -> np.ndarray:
        out = np.zeros(self.n_beta)
        out[self.g_index] = np.diag(self.gg)
        if self.x_index.size:
            out[self.x_index] = np.diagonal(self.xx, axis1=1, axis2=2)
        return out

    def dense(self) -> np.ndarray:
        """The full (n_beta, n_beta) matrix (small problems and tests only: the states of two
        segments are filled in from the globals, cov_xs,xt = cov_xs,g cov_gg^-1 cov_g,xt)."""
        out = np.zeros((self.n_beta, self.n_beta))
        g = self.g_index
        out[np.ix_(g, g)] = self.gg
        if self.x_index.size:
            pinv = np.linalg.pinv(self.gg, hermitian=True)
            for s, xs in enumerate(self.x_index):
                out[np.ix_(g, xs)] = self.gx[s]
                out[np.ix_(xs, g)] = self.gx[s].T
                for t, xt in enumerate(self.x_index):
                    out[np.ix_(xs, xt)] = self.xx[s] if s == t else self.gx[s].T @ pinv @ self.gx[t]
        return out


class BlockInformation:
    """The arrow-structured information matrix of :class:`~identify.estimators.output_error.OutputError`.

    ``local`` (S, k, k): each segment's local information over its local unknowns ``[theta (p),
    x0 of the segment (n), zero shifts of its run (ny)]``, ``local_index`` (S, k) their places
    in beta (-1: held), ``n_beta`` unknowns, ``x_index`` (S, n) the places of each segment's
    initial states (empty when they are not estimated); ``active`` (n_beta,) the unknowns solved
    for (others held: zero step, zero covariance).
    """

    def __init__(self, local: np.ndarray, local_index: np.ndarray, n_beta: int, x_index: np.ndarray,
                 active: np.ndarray | None = None):
        S = len(local)
        self.local_index, self.n_beta = local_index, n_beta
        self.x_index = x_index if x_index.size else np.zeros((S, 0), int)
        is_x = np.zeros(n_beta, bool)
        is_x[self.x_index.ravel()] = True
        self.g_index = np.flatnonzero(~is_x)
        G, n = len(self.g_index), self.x_index.shape[1]
        self.G, self.n = G, n
        g_pos = np.full(n_beta, -1)
        g_pos[self.g_index] = np.arange(G)
        # local -> (globals or the segment's own states) positions
        self.lg = np.where(local_index >= 0, g_pos[np.maximum(local_index, 0)], -1)  # (S, k)
        x_pos = np.full(n_beta, -1)  # a state's place within its own segment's block
        x_pos[self.x_index] = np.arange(n)
        self.lx = np.where(local_index >= 0, x_pos[np.maximum(local_index, 0)], -1)  # (S, k)
        self.gg, self.gx, self.xx = np.zeros((G, G)), np.zeros((S, G, n)), np.zeros((S, n, n))
        self._add(local, self.gg, self.gx, self.xx)
        d = self.diag()
        self.active = d > 1e-300 + 1e-26 * d.max() if active is None else active
        # scale to unit diagonal; held unknowns: unit diagonal, no coupling
        self.d = np.where(self.active, np.sqrt(np.where(self.active, d, 1.0)), 1.0)
        self.dg, self.dx = self.d[self.g_index], self.d[self.x_index] if n else np.zeros((S, 0))
        self.sgg = self._scaled_g(self.gg)
        self.sgx = self.gx / self.dg[None, :, None] / self.dx[:, None, :]
        self.sxx = self.xx / self.dx[:, :, None] / self.dx[:, None, :]
        ag, ax = self.active[self.g_index], self.active[self.x_index] if n else np.zeros((S, 0), bool)
        self.sgx *= ag[None, :, None] & ax[:, None, :]
        self.sxx *= ax[:, :, None] & ax[:, None, :]
        self.sxx[:, np.arange(n), np.arange(n)] = 1.0
        self.ag, self.ax = ag, ax
        self._parts = None

    def _scaled_g(self, gg):
        ag = self.active[self.g_index]
        out = gg / np.outer(self.dg, self.dg) * np.outer(ag, ag)
        np.fill_diagonal(out, 1.0)
        return out

    def _add(self, local, gg, gx, xx):
        """Sum the per-segment local blocks (S, k, k) into the arrow blocks (all segments at once)."""
        S, k = self.lg.shape
        s = np.broadcast_to(np.arange(S)[:, None, None], (S, k, k))
        gi, gj = np.broadcast_to(self.lg[:, :, None], (S, k, k)), np.broadcast_to(self.lg[:, None, :], (S, k, k))
        xi, xj = np.broadcast_to(self.lx[:, :, None], (S, k, k)), np.broadcast_to(self.lx[:, None, :], (S, k, k))
        sel = (gi >= 0) & (gj >= 0)
        np.add.at(gg, (gi[sel], gj[sel]), local[sel])
        if self.n:
            sel = (gi >= 0) & (xj >= 0)
            np.add.at(gx, (s[sel], gi[sel], xj[sel]), local[sel])
            sel = (xi >= 0) & (xj >= 0)
            xx[s[sel], xi[sel], xj[sel]] += local[sel]  # one segment's own states: no repeats

    # -- products and solves -----------------------------------------------------------------
    def diag(self) -> np.ndarray:
        out = np.zeros(self.n_beta)
        out[self.g_index] = np.diag(self.gg)
        if self.n:
            out[self.x_index] = np.diagonal(self.xx, axis1=1, axis2=2)
        return out

    def matvec(self, v: np.ndarray) -> np.ndarray:
        """``M v`` (n_beta,)."""
        out = np.zeros(self.n_beta)
        vg = v[self.g_index]
        out[self.g_index] = self.gg @ vg
        if self.n:
            vx = v[self.x_index]  # (S, n)
            out[self.g_index] += np.einsum("sgn,sn->g", self.gx, vx)
            out[self.x_index] = np.einsum("sgn,g->sn", self.gx, vg) + np.einsum("snm,sm->sn", self.xx, vx)
        return out

    def dense(self) -> np.ndarray:
        """The full (n_beta, n_beta) matrix (tests and small problems)."""
        out = np.zeros((self.n_beta, self.n_beta))
        g = self.g_index
        out[np.ix_(g, g)] = self.gg
        for s, xs in enumerate(self.x_index if self.n else []):
            out[np.ix_(g, xs)] = self.gx[s]
            out[np.ix_(xs, g)] = self.gx[s].T
            out[np.ix_(xs, xs)] = self.xx[s]
        return out

    def local(self, cov: BlockCovariance) -> np.ndarray:
        """The blocks of ``cov`` (a :class:`BlockCovariance` of this problem) over each segment's
        local unknowns, (S, k, k) in the local order (0 for held ones)."""
        S, G, n = len(self.lg), self.G, self.n
        full = np.empty((S, G + n, G + n))
        full[:, :G, :G] = cov.gg
        if n:
            full[:, :G, G:] = cov.gx
            full[:, G:, :G] = cov.gx.transpose(0, 2, 1)
            full[:, G:, G:] = cov.xx
        pos = np.where(self.lg >= 0, self.lg, np.where(self.lx >= 0, G + self.lx, 0))
        out = full[np.arange(S)[:, None, None], pos[:, :, None], pos[:, None, :]]
        held = (self.lg < 0) & (self.lx < 0)
        out[held[:, :, None] | held[:, None, :]] = 0.0
        return out

    def solve(self, rhs: np.ndarray, lam: float = 0.0, solve_for: np.ndarray | None = None) -> np.ndarray:
        """``(M + lam diag(M)) step = rhs`` on the active unknowns (and of those only
        ``solve_for`` (n_beta,) bool, if given; the others held: step 0)."""
        act = self.active if solve_for is None else self.active & solve_for
        b = np.where(act, rhs / self.d, 0.0)
        ag = act[self.g_index]
        Agg = self.sgg * np.outer(ag, ag)
        np.fill_diagonal(Agg, np.where(ag, 1.0 + lam, 1.0))
        bg = b[self.g_index]
        if self.n:
            ax = act[self.x_index]
            Axx = self.sxx * (ax[:, :, None] & ax[:, None, :])
            Axx[:, np.arange(self.n), np.arange(self.n)] = np.where(ax, 1.0 + lam, 1.0)
            Mxg = (self.sgx * (ag[None, :, None] & ax[:, None, :])).transpose(0, 2, 1)
            # K = Axx^-1 [M_xg | r_x] for every segment at once
            K = _solve_batched(Axx, np.concatenate([Mxg, b[self.x_index][:, :, None]], axis=2))
            Agg = Agg - np.einsum("sng,snh->gh", Mxg, K[:, :, :-1])
            bg = bg - np.einsum("sng,sn->g", Mxg, K[:, :, -1])
        sg = _solve(Agg, bg)
        step = np.zeros(self.n_beta)
        step[self.g_index] = sg
        if self.n:
            step[self.x_index] = K[:, :, -1] - np.einsum("snh,h->sn", K[:, :, :-1], sg)
        return np.where(act, step / self.d, 0.0)

    def covariance(self) -> tuple[BlockCovariance, bool]:
        """``M^-1`` on the active unknowns (0 elsewhere) as its blocks, and whether it is ill-conditioned."""
        E, K, C, ill = self._inverse_parts()
        gx = -np.einsum("gh,snh->sgn", C, K) if self.n else np.zeros((len(K), self.G, 0))
        xx = E + np.einsum("sng,gh,smh->snm", K, C, K) if self.n else E
        return self._unscaled(C, gx, xx), ill

    def sandwich(self, local_B: np.ndarray) -> BlockCovariance:
        """``M^-1 B M^-1`` for ``B`` the sum of per-segment local blocks ``local_B`` (S, k, k) in
        the local order (the coloured-residual covariance; B has M's arrow structure)."""
        E, K, C, _ = self._inverse_parts()
        S, G, n = len(local_B), self.G, self.n
        # B scaled like M, as arrow blocks
        Bgg, Bgx, Bxx = np.zeros((G, G)), np.zeros((S, G, n)), np.zeros((S, n, n))
        self._add(local_B, Bgg, Bgx, Bxx)
        Bgg = Bgg / np.outer(self.dg, self.dg) * np.outer(self.ag, self.ag)
        if not n:
            CWC = C @ Bgg @ C
            return self._unscaled(CWC, np.zeros((S, G, 0)), np.zeros((S, 0, 0)))
        Bgx = Bgx / self.dg[None, :, None] / self.dx[:, None, :] * (self.ag[None, :, None] & self.ax[:, None, :])
        Bxx = Bxx / self.dx[:, :, None] / self.dx[:, None, :] * (self.ax[:, :, None] & self.ax[:, None, :])
        # M^-1 = E + V C V^T with V = [I; -K_1; ...; -K_S] (rows: globals, then each segment's
        # states) and E the segments' blocks Axx^-1; B V per segment: (BV)_g = Bgg - sum Bgx K,
        # (BV)_x,s = Bxg,s - Bxx,s K_s
        BVx = Bgx.transpose(0, 2, 1) - Bxx @ K  # (S, n, G)
        W = Bgg - np.einsum("sgn,snh->gh", Bgx, K) - np.einsum("sng,snh->gh", K, BVx)  # V^T B V
        Z = E @ BVx  # (E B V) on each segment's states (S, n, G)
        CWC = C @ W @ C
        gx = np.einsum("gh,snh->sgn", C, Z) - np.einsum("gh,snh->sgn", CWC, K)
        KC = K @ C  # (S, n, G)
        xx = E @ Bxx @ E - Z @ KC.transpose(0, 2, 1) - KC @ Z.transpose(0, 2, 1) + KC @ W @ KC.transpose(0, 2, 1)
        return self._unscaled(CWC, gx, xx)

    def _inverse_parts(self):
        """Scaled ``E`` (S, n, n) = Mxx^-1, ``K`` (S, n, G) = Mxx^-1 Mxg, ``C`` = Schur complement^-1,
        ill (computed once)."""
        if self._parts is None:
            self._parts = self._compute_inverse_parts()
        return self._parts

    def _compute_inverse_parts(self):
        ill = False
        if self.n:
            E, ill_x = _inverse_batched(self.sxx)
            K = E @ self.sgx.transpose(0, 2, 1)
            schur = self.sgg - np.einsum("sgn,snh->gh", self.sgx, K)
        else:
            E, K, schur, ill_x = np.zeros((len(self.sgx), 0, 0)), np.zeros((len(self.sgx), 0, self.G)), self.sgg, False
        C, ill_g = _inverse(schur)
        return E, K, C, bool(ill_x or ill_g)

    def _unscaled(self, gg, gx, xx) -> BlockCovariance:
        """Back from the unit-diagonal scaling; held unknowns get 0."""
        ag, dg = self.ag, self.dg
        gg = gg / np.outer(dg, dg) * np.outer(ag, ag)
        if self.n:
            gx = gx / dg[None, :, None] / self.dx[:, None, :] * (ag[None, :, None] & self.ax[:, None, :])
            xx = xx / self.dx[:, :, None] / self.dx[:, None, :] * (self.ax[:, :, None] & self.ax[:, None, :])
        return BlockCovariance(gg, gx, xx, self.g_index, self.x_index, self.n_beta)


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _solve_batched(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(A, hermitian=True) @ b


def _inverse(A: np.ndarray) -> tuple[np.ndarray, bool]:
    if not A.size:  # no globals: initial states alone (compat's first fit)
        return A.copy(), False
    ill = bool(np.linalg.cond(A) > ILL_CONDITIONED)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return (np.linalg.pinv(A, rcond=1e-15, hermitian=True) if ill else np.linalg.inv(A)), ill


def _inverse_batched(A: np.ndarray) -> tuple[np.ndarray, bool]:
    ill = bool(np.any(np.linalg.cond(A) > ILL_CONDITIONED))
    return (np.linalg.pinv(A, rcond=1e-15, hermitian=True) if ill else np.linalg.inv(A)), ill

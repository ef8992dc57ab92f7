"""The Fisher information of a step sequence as a quadratic form in its levels, and the design
criterion built on it: information per unit of peak response, on one model or over a model set.

Output sensitivities are linear in the input, so for K steps of width h the noise-weighted
sensitivity history is ``sum_k l_k shift_k(S_pulse)`` where ``S_pulse`` is the response to one
unit pulse of width h. The Fisher information is a quadratic form in the levels::

    M(l) = sum_{k,j} l_k l_j G_kj,     G_kj = sum_t shift_k(S)^T shift_j(S)    (p x p)

and the outputs are linear in them, ``y(t) = Y(t) l``. Information grows with amplitude squared
and the peak response with amplitude, so at equal peak response (the largest output's peak over
its limit, r(l), brought to 1) a sequence carries ``log det M(l) - 2 p log r(l)``: the criterion.
A search changes a few levels at a time; the objective keeps ``V_k = sum_j G_kj l_j`` and y so that a
proposal costs a few small products and one p x p log determinant per model.
"""
from __future__ import annotations

import copy

import numpy as np

from identify import LinearModel

from .evaluate import DesignError, Evaluator
from .signal import Signal


class StepBasis:
    """Pulse basis of K steps of ``width`` s per axis on a record, on every model of ``models``
    (default: the evaluator's a priori only; the a priori should come first).

    ``G`` (n_models, Ktot, Ktot, p, p); ``Y`` (n_models, N, ny, Ktot) output response per unit level.
    The record runs 0..``record`` s sampled every ``dt`` (``width`` a multiple of ``dt``).
    """

    def __init__(self, evaluator: Evaluator, width: float, n_steps: int, delay: float = 0.0,
                 models: list[LinearModel] | None = None):
        ev = self.evaluator = evaluator
        self.width, self.n_steps, self.delay = float(width), int(n_steps), float(delay)
        self.inputs = ev.inputs
        self.sub = int(round(width / ev.dt))
        if self.sub < 1 or abs(self.sub * ev.dt - width) > 1e-9 * max(1.0, width):
            raise DesignError(f"step width {width:g} s is not a multiple of the {ev.dt:g} s time step")
        self.offset = int(round(delay / ev.dt))
        if delay + n_steps * width > ev.record + 1e-9:
            raise DesignError(f"a {n_steps * width:g} s sequence does not fit in the {ev.record:g} s record")
        self.models = list(models) if models else [ev.model]
        self.n = int(round(ev.record / ev.dt)) + 1
        self.Ktot = len(self.inputs) * self.n_steps
        pulses = [self._pulses(m) for m in self.models]
        p = ev.p
        self.G = np.zeros((len(self.models), self.Ktot, self.Ktot, p, p))  # filled in place: no stacked copy
        for G, pl in zip(self.G, pulses):
            self._gram([P[0] for P in pl], G)
        self.Y = np.stack([self._outputs([P[1] for P in pl]) for pl in pulses])

    def _pulses(self, model: LinearModel):
        """Per axis: weighted sensitivities (N, ny, p) and outputs (N, ny) for a unit pulse lasting
        one step from t = 0, as running sums of the evaluator's cached unit-sample responses."""
        units = self.evaluator.unit_responses(model)
        out = []
        for name in self.inputs:
            pulse = []
            for R in units[name]:
                c = np.cumsum(R, axis=0)
                c[self.sub:] -= c[:-self.sub].copy()
                pulse.append(c)
            out.append(pulse)
        return out

    def _gram(self, pulses, G: np.ndarray) -> None:
        """Fill G (Kt, Kt, p, p). For steps k <= j (shift difference d = j - k) and pulse responses
        S_a, S_b: ``G = sum_{tau < L_k} S_a(tau + d h)^T S_b(tau)`` with ``L_k = N - offset - (k + d) h``:
        the L_k of one (axis pair, d) diagonal are h samples apart, so the sums are a head (tau below
        the smallest L) plus running sums of h-sample blocks, each block one matrix product."""
        n, K, h, o = self.n, self.n_steps, self.sub, self.offset
        axes = len(self.inputs)
        for a in range(axes):
            for b in range(axes):
                for d in range(K):
                    span = n - o - d * h  # tau + d h must stay inside the record
                    k = np.arange(K - d)
                    k = k[span - k * h > 0]
                    if not k.size:
                        continue
                    A, B = pulses[a][d * h:d * h + span], pulses[b][:span]
                    ny, p = A.shape[1], A.shape[2]
                    head = span - (k.size - 1) * h  # the smallest L: tau in [0, head) is in every sum
                    sums = np.empty((k.size, p, p))
                    sums[0] = A[:head].reshape(-1, p).T @ B[:head].reshape(-1, p)
                    if k.size > 1:
                        Ab = A[head:span].reshape(k.size - 1, h * ny, p)
                        Bb = B[head:span].reshape(k.size - 1, h * ny, p)
                        sums[1:] = np.matmul(Ab.transpose(0, 2, 1), Bb)
                    csum = np.cumsum(sums, axis=0)[::-1]  # csum[k]: the sum over tau < L_k
                    G[a * K + k, b * K + k + d] = csum
                    G[b * K + k + d, a * K + k] = csum.transpose(0, 2, 1)

    def _outputs(self, pulses) -> np.ndarray:
        """(N, ny, Kt) output response per unit level of each step."""
        n, K = self.n, self.n_steps
        out = np.zeros((n, pulses[0].shape[1], len(self.inputs) * K))
        for a, Y in enumerate(pulses):
            for k in range(K):
                s = self.offset + k * self.sub
                if s < n:
                    out[s:, :, a * K + k] = Y[:n - s]
        return out

    def information(self, levels, model: int = 0) -> np.ndarray:
        """M(l) (p, p) for levels (Ktot,) on model number ``model`` (0 is the a priori)."""
        return np.einsum("k,j,kjab->ab", levels, levels, self.G[model])

    def peaks(self, levels, model: int = 0) -> np.ndarray:
        """max |y| over the record per output (ny,), for unit amplitude."""
        return np.abs(self.Y[model] @ levels).max(axis=0)

    def signals(self, levels, amplitudes, kind: str = "pseudo-stochastic", params: dict | None = None) -> list[Signal]:
        K = self.n_steps
        amps = np.broadcast_to(np.asarray(amplitudes, float), (len(self.inputs),))
        return [Signal(kind, name, self.width, np.asarray(levels[a * K:(a + 1) * K]), float(amps[a]),
                       self.delay, dict(params or {}, width=self.width))
                for a, name in enumerate(self.inputs)]


class Objective:
    """Design criterion on a basis, for levels (Ktot,) at unit amplitude.

    Free amplitude (``amplitude`` None): per model m, ``log det M_m(l) - 2 p log r_m(l)`` with
    ``r_m`` the largest output peak over its limit on model m (the information at equal peak
    response; the amplitude is an outcome, 1 / r_0). Fixed amplitude A: ``log det M_m(l) + 2 p log A``
    while ``A r_0(l) <= 1``; beyond, a large offset (any sequence within the limits scores higher) and
    a graded penalty that leads the search back (the designer rejects an infeasible result). Criterion ``nominal`` scores model 0 (the a priori),
    ``mean`` the mean over models with ``weights`` (the expected log det under that prior), ``worst`` the minimum over models of the
    score minus ``offsets`` (n_models,) (a relative D-efficiency, e.g. against each model's
    correctly tuned 3211).
    """

    PENALTY = 10.0  # per unit of 2 p log(A r_0) beyond the limit
    FLOOR_PENALTY = 20.0  # per unit of a priori log det below the nominal floor
    INFEASIBLE = 1e4  # offset of any sequence beyond a limit at a fixed amplitude

    def __init__(self, basis: StepBasis, criterion: str = "mean", inv_limits=None, amplitude: float | None = None,
                 offsets=None, weights=None, worst_weight: float = 1.0, softness: float = 0.0,
                 nominal_floor: float | None = None, stride: int = 1, prior_information=None):
        if criterion not in ("nominal", "worst", "mean", "robust"):
            raise DesignError(f"unknown criterion '{criterion}' (robust, mean, worst, nominal)")
        self.worst_weight, self.softness = float(worst_weight), float(softness)
        self.nominal_floor = nominal_floor
        self.basis, self.criterion, self.amplitude = basis, criterion, amplitude
        self.n_models = 1 if criterion == "nominal" else len(basis.models)
        self.G = basis.G[:self.n_models]
        self.Y = basis.Y[:self.n_models]
        # 1 / limit per output (ny,); 0 for an output without a limit
        self.inv_limits = 1.0 / basis.evaluator.limits if inv_limits is None else np.asarray(inv_limits, float)
        self._sample(stride)
        self.offsets = np.zeros(self.n_models) if offsets is None else np.asarray(offsets, float)[:self.n_models]
        w = np.ones(self.n_models) if weights is None else np.asarray(weights, float)[:self.n_models]
        self.weights = w / w.sum()
        self.p = basis.evaluator.p
        # a priori weighting: the prior's information (p, p) added to the flight's at the amplitude
        # flown, so the design maximises what the flight adds to what is known (identify.model.prior)
        self.prior_information = None if prior_information is None else np.asarray(prior_information, float)
        self.evaluations = 0
        self._base = self._last = None

    def _sample(self, stride: int) -> None:
        """Outputs per step over their limits, every ``stride``-th sample, flattened and contiguous:
        ``Yk`` (m, K, X) with X = samples x limited outputs, so a proposal reads the few rows it
        changes and the largest peak/limit is one reduction. A search reads every other sample
        (half the cost); on a fast aircraft (Navion) those peaks are ~2 % low, so the designer
        polishes its result with every sample."""
        self.stride = int(stride)
        keep = self.inv_limits > 0
        if not keep.any():  # no output limited: every peak ratio is 0
            keep = np.arange(self.inv_limits.size) == 0
        Y = self.Y[:, ::self.stride][:, :, keep, :] * self.inv_limits[keep][None, None, :, None]  # (m, T, ny', K)
        self.Yk = np.ascontiguousarray(np.moveaxis(Y, 3, 1).reshape(Y.shape[0], Y.shape[3], -1))
        self._base = self._last = None

    def exact(self) -> "Objective":
        """A copy that reads the peaks on every sample."""
        other = copy.copy(self)
        other._sample(1)
        other.evaluations = 0
        return other

    # -- state kept for low-rank updates ------------------------------------------------------------
    def _state(self, levels):
        """(levels, V (m, K, p, p), M (m, p, p), y (m, N, ny)) from scratch."""
        V = np.einsum("mkjab,j->mkab", self.G, levels)
        M = np.einsum("k,mkab->mab", levels, V)
        y = np.matmul(levels, self.Yk)
        return levels.copy(), V, M, y

    def reset(self, levels=None) -> None:
        """Forget (or set) the committed candidate that proposals are updated from."""
        self._base = None if levels is None else self._state(np.asarray(levels, float))

    def commit(self) -> None:
        """Make the last scored candidate the base of the next low-rank updates."""
        if self._last is None:
            return
        levels, idx, d, M, y, V = self._last
        if idx is not None and idx.size:
            # V_k += sum_j G_kj d_j = (sum_j d_j G_jk)^T: rows of G are contiguous; V is updated in
            # place (the base owns it: built by _state, changed only here)
            sl = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == idx.size else idx
            m = self._base[1].shape[0]
            # one matrix product over the changed steps (a contiguous run is a view, not a copy)
            dV = np.matmul(d, self.G[:, sl].reshape(m, idx.size, -1)).reshape(self._base[1].shape)
            V = self._base[1]
            V += dV.transpose(0, 1, 3, 2)
        elif idx is not None:
            V = self._base[1]
        self._base = (levels, V, M, y)

    def _candidate(self, levels):
        """(M, y) of ``levels`` from the committed base when few steps differ, else from scratch."""
        if self._base is not None:
            l0, V, M0, y0 = self._base
            idx = np.flatnonzero(levels != l0)
            if idx.size == 0:
                self._last = (levels.copy(), idx, idx.astype(float), M0, y0, None)
                return M0, y0
            if idx.size <= max(2, levels.size // 3):
                d = (levels - l0)[idx]
                # proposals change one contiguous run of steps: slices are views, not copies
                sl = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == idx.size else idx
                Gii = self.G[:, sl, sl] if isinstance(sl, slice) else self.G[:, idx[:, None], idx[None, :]]
                m, p = M0.shape[0], M0.shape[1]
                # contractions over the changed steps as (batched) matrix products: p x p flattened
                Vi = np.matmul(d, V[:, sl].reshape(m, idx.size, p * p)).reshape(m, p, p)
                dGd = np.matmul(d, np.matmul(d, Gii.reshape(m, idx.size, idx.size, p * p))).reshape(m, p, p)
                M = M0 + Vi + Vi.transpose(0, 2, 1) + dGd
                y = y0 + np.matmul(d, self.Yk[:, sl])
                self._last = (levels.copy(), idx, d, M, y, None)
                return M, y
        _, V, M, y = self._state(levels)
        self._last = (levels.copy(), None, None, M, y, V)
        return M, y

    # -- scoring ------------------------------------------------------------------------------------
    def ratios(self, y) -> np.ndarray:
        """Largest peak over limit per model (m,) from outputs over limits y (m, X)."""
        return np.abs(y).max(axis=1)

    def _value(self, M, r) -> float:
        return self.combine(self.per_model(M, r))

    def per_model(self, M, r) -> np.ndarray:
        """Each model's term (m,) from its information M (m, p, p) and peak ratio r (m,), offsets
        subtracted; -inf for a singular information."""
        if self.prior_information is not None:
            return self._with_prior(M, r)
        sign, ld = np.linalg.slogdet(M)
        ld = np.where(sign > 0, ld, -np.inf)
        if self.amplitude is None:
            with np.errstate(divide="ignore"):
                per_model = ld - 2 * self.p * np.log(r)
        else:
            over = max(0.0, float(np.log(self.amplitude * r[0]))) if r[0] > 0 else 0.0
            per_model = ld + 2 * self.p * (np.log(self.amplitude) - self.PENALTY * over)
            if over > 0:  # below every flyable sequence within the limits, graded toward them
                per_model = per_model - self.INFEASIBLE
        return np.where(np.isfinite(per_model), per_model, -np.inf) - self.offsets

    def _with_prior(self, M, r) -> np.ndarray:
        """Each model's ``log det(M a^2 + P^-1)`` at the amplitude ``a`` flown (free: 1 / r, the
        largest peak at its limit; fixed: beyond the limits, as :meth:`per_model` penalises)."""
        r = np.asarray(r, float)
        with np.errstate(divide="ignore"):
            a2 = 1 / r ** 2 if self.amplitude is None else np.full(r.shape, float(self.amplitude) ** 2)
        a2 = np.where(np.isfinite(a2), a2, 0.0)
        sign, ld = np.linalg.slogdet(M * a2[:, None, None] + self.prior_information[None])
        ld = np.where((sign > 0) & (r > 0), ld, -np.inf)
        if self.amplitude is not None and r[0] > 0:
            over = max(0.0, float(np.log(self.amplitude * r[0])))
            ld = ld - 2 * self.p * self.PENALTY * over - (self.INFEASIBLE if over > 0 else 0.0)
        return ld - self.offsets

    def combine(self, per_model, floor: bool = True) -> float:
        """The criterion from the models' terms (every combination is non-decreasing in each term;
        ``floor`` False leaves out the nominal floor's penalty)."""
        per_model = np.asarray(per_model, float)
        if self.criterion == "nominal":
            return float(per_model[0])
        if self.criterion == "worst":
            return float(per_model.min())
        if self.criterion == "robust":
            return self._robust(per_model, floor)
        return float(per_model @ self.weights) if np.all(np.isfinite(per_model)) else -np.inf

    def _robust(self, rel, floor: bool = True) -> float:
        """weights . rel + worst_weight * soft minimum of rel (log-sum-exp at ``softness`` log-det
        units; the plain minimum at 0)."""
        if not np.all(np.isfinite(rel)):
            return -np.inf
        lo = float(rel.min())
        if self.softness > 0:
            lo -= self.softness * float(np.log(np.exp(-(rel - lo) / self.softness).sum()))
        value = float(rel @ self.weights) + self.worst_weight * lo
        if floor and self.nominal_floor is not None:  # below the floor on the a priori: steeply worse
            value -= self.FLOOR_PENALTY * max(0.0, self.nominal_floor - float(rel[0]))
        return value

    def __call__(self, levels) -> float:
        levels = np.asarray(levels, dtype=float)
        self.evaluations += 1
        M, y = self._candidate(levels)
        return self._value(M, self.ratios(y))

    def terms(self, levels) -> np.ndarray:
        """Each model's term (m,) of ``levels``, offsets subtracted (scored from scratch)."""
        M, y = self._state(np.asarray(levels, float))[2:]
        return self.per_model(M, self.ratios(y))

    def batch(self, L: np.ndarray, chunk: int = 2048) -> np.ndarray:
        """Objective of many candidates L (C, Ktot)."""
        self.evaluations += len(L)
        out = np.empty(len(L))
        for i in range(0, len(L), chunk):
            Li = L[i:i + chunk]
            M = np.einsum("ck,cj,mkjab->cmab", Li, Li, self.G, optimize=True)
            y = np.einsum("mkx,ck->cmx", self.Yk, Li, optimize=True)
            for c in range(len(Li)):
                out[i + c] = self._value(M[c], self.ratios(y[c]))
        return out

    def feasible_amplitude(self, levels) -> tuple[float, float]:
        """(amplitude flown, r_0 at unit amplitude) for a final sequence."""
        r0 = float(((np.abs(self.Y[0] @ np.asarray(levels, float)).max(axis=0)) * self.inv_limits).max())
        return (self.amplitude if self.amplitude is not None else 1.0 / r0), r0


class PerInputObjective(Objective):
    """The criterion of a multi-axis run at equal per-input peak response: each input flown as
    large as its own response, alone, allows (its largest output peak / limit at 1, as in a run of
    its own), so the inputs' responses add in the run. Per model m and axis a the scale is
    ``s_a = 1 / r_ma(l_a)`` and the information ``sum_ab s_a s_b M_ab(l)``, with ``M_ab`` the
    block of the quadratic form between axes a and b. Free amplitude only (a fixed amplitude is
    already one per input). The low-rank update keeps the blocks and, per axis b, ``V^b_k = sum_{j
    in b} G_kj l_j``: a proposal changes one axis c, so it moves the blocks of row and column c and
    c's scale; with the information split by axis once per committed base (:meth:`_split`), a
    proposal costs about the single-axis update (1.4-1.6x faster than updating every block, four
    inputs)."""

    def __init__(self, basis: StepBasis, criterion: str = "mean", **kw):
        if kw.get("amplitude") is not None:
            raise DesignError("per-input peak response needs a free amplitude (a fixed one is the same on every input)")
        super().__init__(basis, criterion, **kw)
        self.axes, self.K = len(basis.inputs), basis.n_steps
        self._rest = None  # the committed base's split by axis (_split)

    def _axis_y(self, levels):
        """Outputs over limits per axis (m, axes, X)."""
        K = self.K
        return np.stack([np.matmul(levels[a * K:(a + 1) * K], self.Yk[:, a * K:(a + 1) * K])
                         for a in range(self.axes)], axis=1)

    def _state(self, levels):
        """(levels, V (m, axes, Ktot, p, p) per axis of j, blocks (m, axes, axes, p, p), y)."""
        K = self.K
        V = np.stack([np.einsum("mkjab,j->mkab", self.G[:, :, b * K:(b + 1) * K], levels[b * K:(b + 1) * K])
                      for b in range(self.axes)], axis=1)
        B = np.stack([np.einsum("k,mbkxy->mbxy", levels[a * K:(a + 1) * K], V[:, :, a * K:(a + 1) * K])
                      for a in range(self.axes)], axis=1)
        return levels.copy(), V, B, self._axis_y(levels)

    def reset(self, levels=None) -> None:
        super().reset(levels)
        self._rest = None

    def commit(self) -> None:
        if self._last is None:
            return
        levels, idx, d, B, y, fresh = self._last
        if fresh is not None:
            V = fresh
        else:
            V = self._base[1]
            if idx.size:
                c = int(idx[0]) // self.K
                m = V.shape[0]
                sl = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == idx.size else idx
                dV = np.matmul(d, self.G[:, sl].reshape(m, idx.size, -1)).reshape(V[:, c].shape)
                V[:, c] += dV.transpose(0, 1, 3, 2)
        if callable(B):  # a low-rank candidate keeps its blocks and outputs as a recipe until committed
            B, y = B()
        self._base, self._rest = (levels, V, B, y), None

    def _split(self):
        """Of the committed base: the scales s (m, axes), the information M (m, p, p) and per axis c
        the information without axis c, ``sum_{a,b != c} s_a s_b B_ab``, and axis c's row
        ``R_c = sum_{b != c} s_b B_cb``, each (m, axes, p, p) and summed directly (no differences of
        large terms): a proposal on axis c changes only its row, its block and its scale."""
        if self._rest is None:
            B, y = self._base[2], self._base[3]
            s = self.scales(y)
            ss = s[:, :, None] * s[:, None, :]
            rest, R = np.empty((2, B.shape[0], self.axes) + B.shape[-2:])
            for c in range(self.axes):
                w = ss.copy()
                w[:, c, :] = w[:, :, c] = 0
                rest[:, c] = np.einsum("mab,mabxy->mxy", w, B)
                sb = s.copy()
                sb[:, c] = 0
                R[:, c] = np.einsum("mb,mbxy->mxy", sb, B[:, c])
            self._rest = (s, _scaled(s, B), rest, R)
        return self._rest

    def _candidate(self, levels):
        """The scaled information M (m, p, p) of ``levels``; from the committed base by a low-rank
        update of axis c's row, block and scale when the changed steps are few and on one axis."""
        if self._base is not None:
            l0, V, B0, y0 = self._base
            idx = np.flatnonzero(levels != l0)
            if idx.size == 0:
                self._last = (levels.copy(), idx, idx.astype(float), B0, y0, None)
                return self._split()[1]
            c = int(idx[0]) // self.K
            if int(idx[-1]) // self.K == c and idx.size <= max(2, self.K // 3):
                d = (levels - l0)[idx]
                m, p = B0.shape[0], B0.shape[-1]
                # proposals change one contiguous run of steps: slices are views, not copies
                sl = slice(idx[0], idx[-1] + 1) if idx[-1] - idx[0] + 1 == idx.size else idx
                # row c of the blocks: d . V^b over the changed steps, for every axis b
                Vi = np.matmul(d, V[:, :, sl].reshape(m, self.axes, idx.size, p * p)).reshape(m, self.axes, p, p)
                Gii = self.G[:, sl, sl] if isinstance(sl, slice) else self.G[:, idx[:, None], idx[None, :]]
                dGd = np.matmul(d, np.matmul(d, Gii.reshape(m, idx.size, idx.size, p * p))).reshape(m, p, p)
                yc = y0[:, c] + np.matmul(d, self.Yk[:, sl])
                s, _, rest, R = self._split()
                sc = _reciprocal(np.abs(yc).max(axis=1))
                sb = s.copy()
                sb[:, c] = 0
                row = R[:, c] + np.einsum("mb,mbxy->mxy", sb, Vi)  # the other axes' scales are unchanged
                block = B0[:, c, c] + _sym(Vi[:, c]) + dGd
                M = rest[:, c] + sc[:, None, None] * _sym(row) + (sc ** 2)[:, None, None] * block

                def blocks(B0=B0, y0=y0, Vi=Vi, dGd=dGd, yc=yc, c=c):
                    B = B0.copy()
                    B[:, c] += Vi
                    B[:, :, c] += Vi.transpose(0, 1, 3, 2)
                    B[:, c, c] += dGd
                    y = y0.copy()
                    y[:, c] = yc
                    return B, y

                self._last = (levels.copy(), idx, d, blocks, None, None)
                return M
        _, V, B, y = self._state(levels)
        self._last = (levels.copy(), None, None, B, y, V)
        return _scaled(self.scales(y), B)

    def scales(self, y) -> np.ndarray:
        """1 / each axis' own largest peak over limit (m, axes); 0 for an axis at rest."""
        return _reciprocal(np.abs(y).max(axis=2))

    def terms(self, levels) -> np.ndarray:
        B, y = self._state(np.asarray(levels, float))[2:]
        return self.per_model(_scaled(self.scales(y), B), np.ones(B.shape[0]))

    def __call__(self, levels) -> float:
        levels = np.asarray(levels, dtype=float)
        self.evaluations += 1
        M = self._candidate(levels)
        return self.combine(self.per_model(M, np.ones(M.shape[0])))

    def batch(self, L: np.ndarray, chunk: int = 2048) -> np.ndarray:
        saved = self._base
        out = np.empty(len(L))
        for i, levels in enumerate(np.asarray(L, float)):
            self._base = None
            out[i] = self(levels)
        self._base = saved
        return out

    def feasible_amplitude(self, levels):
        """(amplitude flown per axis (axes,), the largest axis' r_0 at unit amplitude)."""
        levels, K = np.asarray(levels, float), self.K
        r = np.array([(np.abs(self.Y[0][:, :, a * K:(a + 1) * K] @ levels[a * K:(a + 1) * K]).max(axis=0)
                       * self.inv_limits).max() for a in range(self.axes)])
        return _reciprocal(r), float(r.min())


def _reciprocal(r) -> np.ndarray:
    """1 / r, and 0 where r is 0 (an axis at rest has no scale)."""
    return np.where(r > 0, 1.0 / np.where(r > 0, r, 1.0), 0.0)


def _scaled(s, B) -> np.ndarray:
    """The information ``sum_ab s_a s_b B_ab`` (m, p, p) from per-axis scales s (m, axes) and blocks B."""
    return np.einsum("ma,mb,mabxy->mxy", s, s, B)


def _sym(X) -> np.ndarray:
    """X + X^T over the last two axes."""
    return X + np.swapaxes(X, -1, -2)

"""D-optimal three-level pseudo-stochastic step sequences (levels -1/0/+1 times an amplitude).

Output sensitivities are linear in the input, so for K steps of width h the sensitivity history
is ``sum_k l_k shift_k(S_pulse)`` where ``S_pulse`` is the response to one unit pulse of width h.
The Fisher information is then a quadratic form in the levels::

    M(l) = sum_{k,j} l_k l_j G_kj,     G_kj = sum_t shift_k(S)^T W shift_j(S)    (p x p)

with the K x K blocks ``G`` computed once per model and width (one Gram product). A candidate
costs two small matrix-vector products and a p x p log determinant, so exhaustive search runs
over every flyable sequence where there are few, and simulated annealing where there are many.
Several control axes are designed together by stacking their pulse bases (cross terms ``G_kj``
between axes carry the coupling).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from identify import LinearModel

from .band import input_index
from .evaluate import DesignError, Evaluator
from .signal import Signal

LEVELS = (-1, 0, 1)


# -- flyability -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Flyability:
    """Constraints a pilot can fly: every hold (including neutral holds between pulses) lasts at
    least ``min_pulse`` steps; at most ``max_changes`` level changes (counting leaving and returning
    to 0); no jump over two levels (+1 to -1) unless ``max_jump`` is 2. The sequence starts from and
    returns to 0 (trim) outside its K steps, so those edges count as changes and jumps."""

    min_pulse: int = 1
    max_changes: int | None = None
    max_jump: int = 1

    def violations(self, levels) -> list[str]:
        """Human-readable reasons the sequence is not flyable (empty when it is)."""
        levels = np.asarray(levels)
        out = []
        if not np.all(np.isin(levels, LEVELS)):
            out.append("levels must be -1, 0 or +1")
            return out
        if not np.any(levels):
            out.append("the sequence never leaves 0")
            return out
        padded = np.concatenate([[0], levels, [0]])
        steps = np.diff(padded)
        if np.abs(steps).max() > self.max_jump:
            out.append(f"a jump over {np.abs(steps).max()} levels (max {self.max_jump})")
        changes = int(np.count_nonzero(steps))
        if self.max_changes is not None and changes > self.max_changes:
            out.append(f"{changes} level changes (max {self.max_changes})")
        for start, length, level in _runs(levels):
            at_edge = start == 0 or start + length == levels.size
            if length < self.min_pulse and not (level == 0 and at_edge):
                out.append(f"a hold of {length} step(s) at {level:+d} from step {start} (min {self.min_pulse})")
                break
        return out

    def feasible(self, levels) -> bool:
        """Same verdict as :meth:`violations`, in plain Python: the annealer calls it per proposal."""
        prev, run, changes, leading = 0, 0, 0, True
        for v in levels:
            if v == prev:
                run += 1
                continue
            if v not in (-1, 0, 1) or abs(v - prev) > self.max_jump:
                return False
            if not leading and run < self.min_pulse:
                return False
            changes, run, prev, leading = changes + 1, 1, v, False
        if leading:
            return False
        if prev != 0:
            if run < self.min_pulse:
                return False
            changes += 1
        return self.max_changes is None or changes <= self.max_changes


def _runs(levels):
    """(start, length, level) of each run of equal levels."""
    levels = np.asarray(levels)
    edges = np.flatnonzero(np.diff(levels)) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [levels.size]])
    return [(int(s), int(e - s), int(levels[s])) for s, e in zip(starts, ends)]


def enumerate_sequences(n_steps: int, fly: Flyability, limit: int | None = None,
                        canonical: bool = True) -> np.ndarray:
    """Every flyable sequence of ``n_steps`` levels, shape (C, n_steps), by depth-first search that
    prunes a branch as soon as it breaks a constraint. ``canonical`` keeps one of each +/- pair
    (the information is even in the levels). Stops with DesignError past ``limit`` sequences."""
    out: list[tuple] = []
    seq = [0] * n_steps
    max_changes = fly.max_changes if fly.max_changes is not None else n_steps + 1

    def close_ok(level, run):
        # the last hold must be long enough and the return to 0 a legal jump and change
        return abs(level) <= fly.max_jump and (level == 0 or run >= fly.min_pulse)

    def dfs(k, level, run, changes, leading, signed):
        if k == n_steps:
            final_changes = changes + (level != 0)
            if not leading and close_ok(level, run) and final_changes <= max_changes:
                out.append(tuple(seq))
                if limit is not None and len(out) > limit:
                    raise _TooMany
            return
        for new in LEVELS:
            if canonical and not signed and new == -1:
                continue  # first non-zero level is +1
            if new == level:
                seq[k] = new
                dfs(k + 1, level, run + 1, changes, leading and new == 0, signed)
                continue
            if abs(new - level) > fly.max_jump or changes + 1 > max_changes:
                continue
            if not leading and run < fly.min_pulse:
                continue  # the hold being left is too short (leading zeros merge with trim)
            seq[k] = new
            dfs(k + 1, new, 1, changes + 1, leading and new == 0, signed or new != 0)

    try:
        dfs(0, 0, 0, 0, True, False)
    except _TooMany:
        raise DesignError(f"more than {limit} flyable sequences of {n_steps} steps: too many to search "
                          f"exhaustively") from None
    return np.array(out, dtype=float).reshape(len(out), n_steps)


class _TooMany(Exception):
    pass


def count_sequences(n_steps: int, fly: Flyability, limit: int | None = None) -> int | None:
    """Number of canonical flyable sequences (as :func:`enumerate_sequences` would list), counted
    by dynamic programming over (step, level, hold length capped at min_pulse, changes, leading);
    None when it exceeds ``limit``."""
    from functools import lru_cache

    max_changes = fly.max_changes if fly.max_changes is not None else n_steps + 1

    @lru_cache(maxsize=None)
    def count(k, level, run, changes, leading):
        if k == n_steps:
            final = changes + (level != 0)
            ok = not leading and (level == 0 or run >= fly.min_pulse) and final <= max_changes
            return int(ok)
        total = 0
        for new in LEVELS:
            if leading and new == -1:
                continue
            if new == level:
                total += count(k + 1, level, min(run + 1, fly.min_pulse), changes, leading and new == 0)
            elif (abs(new - level) <= fly.max_jump and changes + 1 <= max_changes
                  and (leading or run >= fly.min_pulse)):
                total += count(k + 1, new, min(1, fly.min_pulse), changes + 1, leading and new == 0)
        return total

    n = count(0, 0, 0, 0, True)
    return None if limit is not None and n > limit else n


# -- the quadratic information form ---------------------------------------------------------------
class StepBasis:
    """Pulse basis of K steps of ``width`` s per axis on a record; information and peaks as
    functions of the levels.

    ``G`` (Ktot, Ktot, p, p) per model; ``Y`` (N, ny, Ktot) output response per unit level.
    The record runs 0..``record`` s sampled every ``dt`` (``width`` a multiple of ``dt``).
    """

    def __init__(self, evaluator: Evaluator, width: float, n_steps: int, amplitudes, delay: float = 0.0,
                 models: list[LinearModel] | None = None):
        ev = self.evaluator = evaluator
        self.width, self.n_steps, self.delay = float(width), int(n_steps), float(delay)
        self.inputs = ev.inputs
        self.amplitudes = np.broadcast_to(np.asarray(amplitudes, float), (len(self.inputs),)).copy()
        self.sub = int(round(width / ev.dt))
        if self.sub < 1 or abs(self.sub * ev.dt - width) > 1e-9 * max(1.0, width):
            raise DesignError(f"step width {width:g} s is not a multiple of the {ev.dt:g} s time step")
        self.offset = int(round(delay / ev.dt))
        if delay + n_steps * width > ev.record + 1e-9:
            raise DesignError(f"a {n_steps * width:g} s sequence does not fit in the {ev.record:g} s record")
        self.models = [ev.model] + list(models or [])
        self.n = int(round(ev.record / ev.dt)) + 1
        self.G = np.stack([self._gram(m) for m in self.models])  # (n_models, Kt, Kt, p, p)
        self.Ktot = len(self.inputs) * self.n_steps
        p = ev.p
        # (n_models, Kt, Kt*p*p): M = l @ (l @ G2) as two matrix-vector products
        self.G2 = self.G.reshape(len(self.models), self.Ktot, self.Ktot * p * p)
        self.Y = self._outputs(ev.model)

    def _pulses(self, model: LinearModel):
        """Per axis: weighted sensitivities (N, ny, p) and outputs (N, ny) for one pulse of the axis
        amplitude lasting one step width from t = 0, as running sums of the evaluator's cached
        unit-sample responses (the model is linear and time-invariant: no new simulation per width)."""
        units = self.evaluator._unit_responses(model)
        out = []
        for a, name in enumerate(self.inputs):
            S, Y = units[name]
            pulse = []
            for R in (S, Y):
                c = np.cumsum(R, axis=0)
                c[self.sub:] -= c[:-self.sub].copy()
                pulse.append(self.amplitudes[a] * c)
            out.append(pulse)
        return out

    def _gram(self, model: LinearModel) -> np.ndarray:
        """G (Kt, Kt, p, p). For steps k <= j (shift difference d = j - k) and pulse responses
        S_a, S_b: ``G = sum_{tau < L_j} S_a(tau + d h)^T S_b(tau)`` with ``L_j = N - offset - j h``:
        one running sum over tau per (axis pair, d) gives every block of that diagonal."""
        pulses = [P[0] for P in self._pulses(model)]
        n, K, h, o = self.n, self.n_steps, self.sub, self.offset
        axes, p = len(self.inputs), self.evaluator.p
        G = np.zeros((axes * K, axes * K, p, p))
        for a in range(axes):
            for b in range(axes):
                for d in range(K):
                    span = n - o - d * h  # tau + d h must stay inside the record
                    if span <= 0:
                        continue
                    prod = np.einsum("tyi,tyj->tij", pulses[a][d * h:d * h + span], pulses[b][:span])
                    csum = np.cumsum(prod, axis=0)
                    for k in range(K - d):
                        j = k + d
                        L = n - o - j * h
                        if L > 0:
                            G[a * K + k, b * K + j] = csum[L - 1]
                            G[b * K + j, a * K + k] = csum[L - 1].T
        return G

    def _outputs(self, model: LinearModel) -> np.ndarray:
        """(N, ny, Kt) output response per unit level of each step."""
        pulses = [P[1] for P in self._pulses(model)]
        n, K = self.n, self.n_steps
        out = np.zeros((n, pulses[0].shape[1], len(self.inputs) * K))
        for a, Y in enumerate(pulses):
            for k in range(K):
                s = self.offset + k * self.sub
                if s < n:
                    out[s:, :, a * K + k] = Y[:n - s]
        return out

    def information(self, levels, model: int = 0) -> np.ndarray:
        """M(l) (p, p) for levels (Ktot,) on model number ``model`` (0 is the nominal)."""
        p = self.evaluator.p
        v = (levels @ self.G2[model]).reshape(self.Ktot, p * p)
        return (levels @ v).reshape(p, p)

    def log_dets(self, levels) -> np.ndarray:
        """log det M(l) on every model (n_models,); -inf where singular."""
        p = self.evaluator.p
        v = np.einsum("k,mkq->mq", levels, self.G2).reshape(len(self.models), self.Ktot, p * p)
        M = np.einsum("k,mkq->mq", levels, v).reshape(-1, p, p)
        sign, val = np.linalg.slogdet(M)
        return np.where(sign > 0, val, -np.inf)

    def batch_log_det(self, L: np.ndarray, model: int = 0, chunk: int = 4096) -> np.ndarray:
        """log det M on model number ``model`` for many candidates L (C, Ktot) at once."""
        p = self.evaluator.p
        out = np.empty(len(L))
        for i in range(0, len(L), chunk):
            Li = L[i:i + chunk]
            T = (Li @ self.G2[model]).reshape(len(Li), self.Ktot, p * p)
            M = np.einsum("ck,ckq->cq", Li, T).reshape(-1, p, p)
            sign, val = np.linalg.slogdet(M)
            out[i:i + chunk] = np.where(sign > 0, val, -np.inf)
        return out

    def peaks(self, levels) -> np.ndarray:
        """max |y| over the record per output (ny,)."""
        return np.abs(self.Y @ levels).max(axis=0)

    def signals(self, levels, kind: str = "pseudo-stochastic", params: dict | None = None) -> list[Signal]:
        K = self.n_steps
        return [Signal(kind, name, self.width, np.asarray(levels[a * K:(a + 1) * K]), float(self.amplitudes[a]),
                       self.delay, dict(params or {}, width=self.width))
                for a, name in enumerate(self.inputs)]


# -- search ---------------------------------------------------------------------------------------
@dataclass
class SearchResult:
    """Best levels (Ktot,), its objective, how it was found and how many candidates were scored."""

    levels: np.ndarray
    objective: float
    method: str
    evaluations: int
    seconds: float = 0.0
    trace: list = field(default_factory=list)


class Objective:
    """Criterion on a basis: ``nominal`` log det, or ``worst``/``mean`` over the basis' models of
    log det minus ``offsets`` (n_models,) (e.g. the reference signal's log dets, making it a
    relative D-efficiency); candidates whose peak response exceeds ``max_peak`` (ny,) score -inf."""

    def __init__(self, basis: StepBasis, criterion: str = "nominal", offsets=None, max_peak=None):
        if criterion not in ("nominal", "worst", "mean"):
            raise DesignError(f"unknown criterion '{criterion}' (nominal, worst, mean)")
        if criterion != "nominal" and len(basis.models) < 2:
            raise DesignError(f"criterion '{criterion}' needs perturbed models")
        self.basis, self.criterion = basis, criterion
        n_models = len(basis.models)
        self.offsets = np.zeros(n_models) if offsets is None else np.asarray(offsets, float)[:n_models]
        self.max_peak = None if max_peak is None else np.asarray(max_peak, float)
        self.evaluations = 0
        self._base = self._last = None

    def _models(self) -> int:
        return 1 if self.criterion == "nominal" else len(self.basis.models)

    def _full(self, levels: np.ndarray) -> np.ndarray:
        """M(l) (n_models, p, p) from scratch: two matrix-vector products per model."""
        b, p = self.basis, self.basis.evaluator.p
        v = np.einsum("k,mkq->mq", levels, b.G2[:self._models()]).reshape(-1, b.Ktot, p * p)
        return np.einsum("k,mkq->mq", levels, v).reshape(-1, p, p)

    def _incremental(self, levels: np.ndarray):
        """M(l) as the committed M plus a low-rank change when few steps differ, else None.
        With d = l - l0 on the changed steps I: dM = sum_{k in I} d_k (V_k + V_k^T)
        + sum_{k, j in I} d_k d_j G_kj, where V_k = sum_j l0_j G_kj."""
        if self._base is None:
            return None
        l0, M0 = self._base
        idx = np.flatnonzero(levels != l0)
        if idx.size == 0:
            return M0
        if idx.size > max(2, self.basis.Ktot // 4):
            return None
        G = self.basis.G[:self._models(), idx]  # (m, r, K, p, p)
        d = (levels - l0)[idx]
        V = np.einsum("mrkab,k->mrab", G, l0)
        dM = np.einsum("r,mrab->mab", d, V)
        dM = dM + dM.transpose(0, 2, 1) + np.einsum("r,s,mrsab->mab", d, d, G[:, :, idx])
        return M0 + dM

    def reset(self, levels=None) -> None:
        """Forget (or set) the committed candidate that proposals are updated from."""
        self._base = None
        if levels is not None:
            levels = np.asarray(levels, float)
            self._base = (levels.copy(), self._full(levels))

    def commit(self) -> None:
        """Make the last scored candidate the base of the next low-rank updates."""
        if self._last is not None:
            self._base = self._last

    def __call__(self, levels) -> float:
        levels = np.asarray(levels, dtype=float)
        self.evaluations += 1
        self._last = None
        if self.max_peak is not None and np.any(self.basis.peaks(levels) > self.max_peak):
            return -np.inf
        M = self._incremental(levels)
        if M is None:
            M = self._full(levels)
        self._last = (levels.copy(), M)
        sign, val = np.linalg.slogdet(M)
        rel = np.where(sign > 0, val, -np.inf) - self.offsets[:len(M)]
        if self.criterion == "nominal":
            return float(rel[0])
        return float(rel.min() if self.criterion == "worst" else rel.mean())

    def batch(self, L: np.ndarray) -> np.ndarray:
        """Objective of many candidates L (C, Ktot)."""
        self.evaluations += len(L)
        lds = np.stack([self.basis.batch_log_det(L, m) for m in range(len(self.basis.models))
                        if self.criterion != "nominal" or m == 0]) - self.offsets[:, None]
        values = lds[0] if self.criterion == "nominal" else (lds.min(axis=0) if self.criterion == "worst"
                                                              else lds.mean(axis=0))
        if self.max_peak is not None:
            for i in range(0, len(L), 512):
                peaks = np.abs(np.einsum("tyk,ck->cty", self.basis.Y, L[i:i + 512])).max(axis=1)
                values[i:i + 512][np.any(peaks > self.max_peak, axis=1)] = -np.inf
        return values


def exhaustive(objective: Objective, fly: Flyability, limit: int = 200_000) -> SearchResult:
    """Score every flyable sequence (per axis; several axes as their product) and keep the best."""
    t0 = time.perf_counter()
    basis = objective.basis
    axes = len(basis.inputs)
    one = enumerate_sequences(basis.n_steps, fly, limit)
    if axes == 1:
        L = one
    else:
        full = enumerate_sequences(basis.n_steps, fly, limit, canonical=False)
        total = len(one) * len(full) ** (axes - 1)
        if total > limit:
            raise DesignError(f"{total} flyable multi-axis sequences: too many to search exhaustively")
        grids = [one] + [full] * (axes - 1)
        idx = np.stack(np.meshgrid(*[np.arange(len(g)) for g in grids], indexing="ij"), -1).reshape(-1, axes)
        L = np.concatenate([g[idx[:, a]] for a, g in enumerate(grids)], axis=1)
    values = objective.batch(L)
    i = int(np.argmax(values))
    return SearchResult(L[i].copy(), float(values[i]), "exhaustive", len(L), time.perf_counter() - t0)


def _random_feasible(n_steps: int, fly: Flyability, rng: np.random.Generator, tries: int = 2000) -> np.ndarray:
    """A random flyable sequence built hold by hold."""
    for _ in range(tries):
        seq, level, k = [], 0, 0
        while k < n_steps:
            choices = [v for v in LEVELS if v != level and abs(v - level) <= fly.max_jump]
            level = int(rng.choice(choices)) if k else int(rng.choice([-1, 1]))
            hold = int(rng.integers(fly.min_pulse, 3 * fly.min_pulse + 2))
            seq += [level] * hold
            k += hold
        seq = np.array(seq[:n_steps], float)
        if fly.feasible(seq):
            return seq
        # repair: the tail (truncated hold or too-many changes) often fails; trim it to 0
        for cut in range(n_steps - 1, 0, -1):
            trial = seq.copy()
            trial[cut:] = 0
            if fly.feasible(trial):
                return trial
    raise DesignError(f"no flyable {n_steps}-step sequence found: constraints (min pulse "
                      f"{fly.min_pulse} steps, max {fly.max_changes} changes) leave none")


def _propose(levels: list, n_steps: int, axes: int, fly: Flyability, rng) -> list:
    """A random neighbour (plain lists: this runs thousands of times per design)."""
    new = list(levels)
    a = int(rng.integers(axes))
    lo = a * n_steps
    move = rng.random()
    if move < 0.4:  # a block of up to 2 min_pulse steps to another level
        length = int(rng.integers(1, 2 * fly.min_pulse + 1))
        start = lo + int(rng.integers(0, n_steps))
        value = LEVELS[int(rng.integers(3))]
        for k in range(start, min(start + length, lo + n_steps)):
            new[k] = value
    elif move < 0.8:  # move a switch by one step
        changes = [k for k in range(lo + 1, lo + n_steps) if new[k] != new[k - 1]]
        if changes:
            c = changes[int(rng.integers(len(changes)))]
            if rng.random() < 0.5:
                new[c] = new[c - 1]
            else:
                new[c - 1] = new[c]
    elif move < 0.9:  # flip the sign of one hold
        k = lo + int(rng.integers(n_steps))
        v = new[k]
        i = k
        while i >= lo and new[i] == v:
            new[i] = -v
            i -= 1
        i = k + 1
        while i < lo + n_steps and new[i] == v:
            new[i] = -v
            i += 1
    else:  # shift the whole axis by one step
        seg = new[lo:lo + n_steps]
        seg = seg[1:] + seg[:1] if rng.random() < 0.5 else seg[-1:] + seg[:-1]
        new[lo:lo + n_steps] = seg
    return new


def anneal(objective: Objective, fly: Flyability, n_iter: int = 6000, restarts: int = 3, seed: int = 0,
           start=None, progress=None) -> SearchResult:
    """Simulated annealing over flyable sequences: infeasible proposals are rejected, the
    temperature falls geometrically from the scale of the objective's typical changes."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    basis = objective.basis
    K, axes = basis.n_steps, len(basis.inputs)

    def feasible(levels):
        return all(fly.feasible(levels[a * K:(a + 1) * K]) for a in range(axes))

    def score(levels):
        return objective(np.array(levels, dtype=float))

    objective.reset()
    best = None
    for r in range(restarts):
        if start is not None and r == 0:
            cur = [float(v) for v in start]
        else:
            cur = [float(v) for _ in range(axes) for v in _random_feasible(K, fly, rng)]
        f_cur = score(cur)
        objective.commit()
        # temperature scale from a few random feasible neighbours
        deltas = []
        for _ in range(60):
            cand = _propose(cur, K, axes, fly, rng)
            if feasible(cand):
                f = score(cand)
                if np.isfinite(f) and np.isfinite(f_cur):
                    deltas.append(abs(f - f_cur))
        T0 = max(float(np.median(deltas)) if deltas else 1.0, 1e-3)
        T_end = T0 * 1e-3
        r_best = (f_cur, list(cur))
        for i in range(n_iter):
            T = T0 * (T_end / T0) ** (i / max(n_iter - 1, 1))
            cand = _propose(cur, K, axes, fly, rng)
            if cand == cur or not feasible(cand):
                continue
            f = score(cand)
            if f >= f_cur or (np.isfinite(f) and (not np.isfinite(f_cur) or rng.random() < np.exp((f - f_cur) / T))):
                cur, f_cur = cand, f
                objective.commit()
                if f_cur > r_best[0]:
                    r_best = (f_cur, list(cur))
        # finish with a greedy pass over every single-step change
        objective.reset(r_best[1])
        cur, f_cur = _polish(objective, r_best[1], r_best[0], K, axes, fly.min_pulse, feasible)
        if best is None or f_cur > best[0]:
            best = (f_cur, np.array(cur, dtype=float))
        if progress is not None:
            progress(r + 1, restarts)
    objective.reset()  # report the optimum scored from scratch, free of update round-off
    value = objective(best[1])
    return SearchResult(best[1], float(value), "annealing", objective.evaluations, time.perf_counter() - t0)


def _polish(score: Objective, levels, value, n_steps, axes, min_pulse, feasible):
    """Greedy local search: set any block of 1..2 min_pulse steps of one axis to any level, and
    shift any switch by one step, while that improves the objective."""
    improved = True
    while improved:
        improved = False
        for a in range(axes):
            lo, hi = a * n_steps, (a + 1) * n_steps
            for start in range(lo, hi):
                for length in range(1, 2 * min_pulse + 1):
                    for v in LEVELS:
                        stop = min(start + length, hi)
                        if all(levels[k] == v for k in range(start, stop)):
                            continue
                        cand = list(levels)
                        cand[start:stop] = [float(v)] * (stop - start)
                        if feasible(cand):
                            f = score(cand)
                            if f > value + 1e-12:
                                levels, value, improved = cand, f, True
                                score.commit()
    return levels, value


# -- the designer ---------------------------------------------------------------------------------
@dataclass
class WidthTrial:
    """One step width tried: ``width`` s, ``n_steps``, the search's result."""

    width: float
    n_steps: int
    result: SearchResult


class SequenceDesign:
    """Optimised three-level pseudo-stochastic sequence(s), one per input axis.

    ``fit(model)`` tries constant step widths (multiples of ``dt`` between ``min_width`` and
    ``max_width`` s, each with K = round(duration / width) steps), searches each exhaustively when
    it has at most ``exhaustive_limit`` flyable sequences and by simulated annealing otherwise, and
    keeps the best. Attributes after fit: ``signals_`` (list of Signal), ``result_`` (SearchResult),
    ``width_`` (s), ``trials_`` (WidthTrial per width), ``evaluator_``, ``basis_``, ``seconds_`` (wall)
    and ``cpu_seconds_``.

    Criteria: ``nominal`` maximises log det M on the a priori model; ``worst``/``mean`` maximise the
    worst/mean over the a priori and ``perturbations`` models with every derivative scaled within
    1 -/+ ``spread`` of log det M relative to the ``reference`` signals (a relative D-efficiency).
    Every width is first screened on the a priori model with a third of the annealing budget;
    the ``refine_widths`` best are then searched with the full budget and the chosen criterion,
    started from their screening optima (one model per candidate is cheap, 25 are not). ``max_peak`` caps
    every output's peak response at that multiple of the reference's.
    """

    def __init__(self, inputs="theta_s", duration: float = 7.0, record: float = 20.0, amplitude=1.0,
                 dt: float = 0.05, min_width: float = 0.3, max_width: float = 1.0, widths=None,
                 min_pulse: float | None = None, max_changes: int | None = None,
                 allow_double_jumps: bool = False, criterion: str = "nominal", perturbations: int = 0,
                 spread: float = 0.3, reference=None, max_peak: float | None = None,
                 exhaustive_limit: int = 6000, n_iter: int = 5000, restarts: int = 3, seed: int = 0,
                 noise_std=None, delay: float = 0.0, refine_widths: int = 2, progress=None):
        self.inputs = [inputs] if isinstance(inputs, str) else list(inputs)
        self.duration, self.record, self.amplitude, self.dt = duration, record, amplitude, dt
        self.min_width, self.max_width, self.widths = min_width, max_width, widths
        self.min_pulse, self.max_changes, self.allow_double_jumps = min_pulse, max_changes, allow_double_jumps
        self.criterion, self.perturbations, self.spread = criterion, perturbations, spread
        self.reference, self.max_peak = reference, max_peak
        self.exhaustive_limit, self.n_iter, self.restarts, self.seed = exhaustive_limit, n_iter, restarts, seed
        self.noise_std, self.delay, self.progress = noise_std, delay, progress
        self.refine_widths = refine_widths

    def candidate_widths(self) -> list[tuple[float, int]]:
        """(width, K) pairs: widths on the dt grid, K = round(duration / width), one width per K."""
        if not (self.duration > 0):
            raise DesignError(f"duration must be positive, got {self.duration:g} s")
        if self.widths is not None:
            widths = [float(w) for w in self.widths]
        else:
            lo = max(int(np.ceil(self.min_width / self.dt - 1e-9)), 1)
            hi = int(np.floor(self.max_width / self.dt + 1e-9))
            widths = [round(i * self.dt, 10) for i in range(lo, hi + 1)]
        pairs = {}
        for w in widths:
            K = int(round(self.duration / w))
            if K >= 1 and w <= self.duration + 1e-9 and abs(K * w - self.duration) <= 0.5 * w + 1e-9:
                # per K keep the width whose K steps come closest to the duration
                if K not in pairs or abs(K * w - self.duration) < abs(K * pairs[K] - self.duration):
                    pairs[K] = w
        if not pairs:
            shortest = min(widths) if widths else self.min_width
            raise DesignError(f"duration {self.duration:g} s is shorter than one pulse ({shortest:g} s)")
        return sorted((w, K) for K, w in pairs.items())

    def flyability(self, width: float) -> Flyability:
        min_steps = 1 if self.min_pulse is None else max(1, int(np.ceil(self.min_pulse / width - 1e-9)))
        return Flyability(min_steps, self.max_changes, 2 if self.allow_double_jumps else 1)

    def fit(self, model: LinearModel) -> "SequenceDesign":
        t0, c0 = time.perf_counter(), time.process_time()
        if self.criterion not in ("nominal", "worst", "mean"):
            raise DesignError(f"unknown criterion '{self.criterion}' (nominal, worst, mean)")
        if self.criterion != "nominal" and self.perturbations < 1:
            raise DesignError(f"criterion '{self.criterion}' needs perturbed models (perturbations >= 1)")
        if self.max_changes is not None and self.max_changes < 2:
            raise DesignError(f"max changes {self.max_changes}: a sequence needs at least 2 (leave 0, return)")
        if self.min_pulse is not None and self.min_pulse > self.duration:
            raise DesignError(f"minimum pulse width {self.min_pulse:g} s exceeds the duration {self.duration:g} s")
        pairs = self.candidate_widths()
        if self.delay + self.duration > self.record:
            raise DesignError(f"a {self.duration:g} s signal does not fit in the {self.record:g} s record")
        from .evaluate import perturbed_models
        # a seed of its own: the designer's perturbed models are not the ones a comparison scores on
        models = perturbed_models(model, self.perturbations, self.spread, self.seed + 1) if self.perturbations else []
        ev = Evaluator(model, self.inputs, self.record, self.dt, self.noise_std, models=models)
        offsets = max_peak = None
        if self.reference is not None:
            ev.set_reference(self.reference)
            offsets = np.concatenate([[ev._ref[0]], ev._ref_logdets if models else []])
            if self.max_peak is not None:
                max_peak = self.max_peak * ev._ref[1]
        elif self.max_peak is not None:
            raise DesignError("a peak-response limit needs reference signals to be relative to")
        # stage 1 screens every width on the a priori model (one model per candidate is cheap);
        # stage 2 searches the best few widths with the full budget and the chosen criterion,
        # started from their screening optima
        self.trials_, stage1 = [], []
        n_total = len(pairs) + self.refine_widths
        for i, (width, K) in enumerate(pairs):
            basis = StepBasis(ev, width, K, self.amplitude, self.delay)
            objective = Objective(basis, "nominal", None if offsets is None else offsets[:1], max_peak)
            result = self._search(objective, self.flyability(width), self.seed + i,
                                  n_iter=max(self.n_iter // 3, 200), restarts=1)
            if result is not None:
                self.trials_.append(WidthTrial(width, K, result))
                stage1.append((result, basis))
            if self.progress is not None:
                self.progress(i + 1, n_total)
        ranked = sorted(stage1, key=lambda rb: -rb[0].objective)[:self.refine_widths]
        best = None
        for j, (res, basis) in enumerate(ranked):
            if self.criterion != "nominal":
                basis = StepBasis(ev, basis.width, basis.n_steps, self.amplitude, self.delay, models)
            objective = Objective(basis, self.criterion, offsets, max_peak)
            if res.method == "exhaustive" and self.criterion == "nominal":
                result = res  # already the optimum at this width
            else:
                # a robust candidate costs a log det per model: one restart fewer (the first
                # starts from the nominal optimum)
                restarts = self.restarts if self.criterion == "nominal" else max(1, self.restarts - 1)
                result = self._search(objective, self.flyability(basis.width), self.seed + 100 + j,
                                      start=res.levels, n_iter=self.n_iter, restarts=restarts)
            if result is not None and (best is None or result.objective > best[0].objective):
                best = (result, basis)
            if self.progress is not None:
                self.progress(len(pairs) + j + 1, n_total)
        if self.progress is not None and len(ranked) < self.refine_widths:
            self.progress(n_total, n_total)
        if best is None or not np.isfinite(best[0].objective):
            raise DesignError("no flyable sequence satisfies the constraints (min pulse, max changes, peak)")
        self.result_, self.basis_ = best
        self.width_ = self.basis_.width
        self.evaluator_ = ev
        params = {"criterion": self.criterion, "method": self.result_.method, "duration": self.duration,
                  "record": self.record, "units": {i: model.profile.inputs[i] for i in self.inputs}}
        self.signals_ = self.basis_.signals(self.result_.levels, params=params)
        self.seconds_ = time.perf_counter() - t0
        self.cpu_seconds_ = time.process_time() - c0  # this process only: the machine may be shared
        return self

    def _search(self, objective: Objective, fly: Flyability, seed: int, start=None, n_iter: int = 5000,
                restarts: int = 3) -> SearchResult | None:
        """Exhaustive when the (single-axis) sequence space is small, annealing otherwise."""
        K = objective.basis.n_steps
        # a robust candidate costs one log det per model: a smaller space counts as small
        limit = self.exhaustive_limit // max(len(objective.basis.models), 1)
        n = count_sequences(K, fly, limit) if len(self.inputs) == 1 else None
        if n == 0:
            return None
        if n is not None:
            return exhaustive(objective, fly, limit)
        return anneal(objective, fly, n_iter, restarts, seed, start)

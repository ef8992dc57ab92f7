"""Searches over flyable sequences: exhaustive where the space is small, simulated annealing with
restarts and a local search (:func:`polish`: blocks set, holds flipped and shifted, until no move
improves) otherwise.

The objective (see :mod:`signaldesign.quadform`) scores a candidate from the last accepted one by a
low-rank update, so proposals change a few levels at a time: a block set to a level, a switch
moved, a hold's sign flipped. Annealing restarts and iterated-local-search ("kick") chains are
independent tasks with their own seeds, run in worker processes by :mod:`signaldesign.workers`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .evaluate import DesignError
from .flyable import LEVELS, Flyability, enumerate_sequences
from .quadform import Objective
from .workers import run_tasks


@dataclass
class SearchResult:
    """Best levels (Ktot,), its objective, how it was found and how many candidates were scored."""

    levels: np.ndarray
    objective: float
    method: str
    evaluations: int
    seconds: float = 0.0
    trace: list = field(default_factory=list)


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
    """A random neighbour that changes few levels (plain lists: this runs thousands of times)."""
    new = list(levels)
    a = int(rng.integers(axes))
    lo = a * n_steps
    move = rng.random()
    if move < 0.35:  # a block of up to 2 min_pulse steps to another level
        length = int(rng.integers(1, 2 * fly.min_pulse + 1))
        start = lo + int(rng.integers(0, n_steps))
        value = LEVELS[int(rng.integers(3))]
        for k in range(start, min(start + length, lo + n_steps)):
            new[k] = value
    elif move < 0.8:  # move a switch by up to min_pulse steps
        changes = [k for k in range(lo + 1, lo + n_steps) if new[k] != new[k - 1]]
        if changes:
            c = changes[int(rng.integers(len(changes)))]
            step = int(rng.integers(1, fly.min_pulse + 1))
            if rng.random() < 0.5:  # later: the earlier hold extends
                for k in range(c, min(c + step, lo + n_steps)):
                    new[k] = new[c - 1]
            else:  # earlier: the later hold extends
                for k in range(max(c - step, lo), c):
                    new[k] = new[c]
    else:  # flip the sign of one hold
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
    return new


def anneal(objective: Objective, fly: Flyability, n_iter: int = 4000, restarts: int = 4, seed: int = 0,
           starts=(), progress=None, kicks: int = 0, jobs: int = 1, chains: int | None = None) -> SearchResult:
    """Simulated annealing over flyable sequences from ``starts`` (level vectors, e.g. the tuned
    3211 on the grid) and then random flyable sequences, ``restarts`` runs in all, each finished by
    a greedy polish. Infeasible proposals are rejected; the temperature falls geometrically from
    the scale of the objective's typical changes. Then ``kicks`` rounds of iterated local search
    (a few random moves, polished; kept when better) shared among ``chains`` chains (default one
    per restart), chain c starting from the c-th best distinct restart (the landscape is rugged:
    the best restart is not always the basin with the best optimum nearby). Every restart and
    chain has its own seed (from ``seed``), so ``jobs`` (worker processes,
    :mod:`signaldesign.workers`) changes only the time. ``trace`` holds each restart's final
    objective."""
    t0 = time.perf_counter()
    K, axes = objective.basis.n_steps, len(objective.basis.inputs)
    starts = [np.asarray(s, float) for s in starts if _feasible(s, K, axes, fly)]
    chains = min(restarts if chains is None else chains, kicks) if kicks > 0 else 0
    seeds = np.random.SeedSequence(seed).spawn(restarts + chains)
    args = [(starts[r] if r < len(starts) else None, n_iter, seeds[r]) for r in range(restarts)]
    found = run_tasks(_restart, args, objective, fly, jobs, progress)
    trace = [f for f, _, _ in found]
    evaluations = sum(e for _, _, e in found)
    ranked = _distinct(sorted(found, key=lambda r: -r[0]))
    best = ranked[0][:2]
    if chains:
        args = [(ranked[c % len(ranked)][1], kicks // chains + (c < kicks % chains), seeds[restarts + c])
                for c in range(chains)]
        for f, levels, e in run_tasks(_kick_chain, args, objective, fly, jobs):
            evaluations += e
            if f > best[0]:
                best = (f, levels)
    objective.reset()  # report the optimum scored from scratch, free of update round-off
    levels = np.array(best[1], dtype=float)
    value = objective(levels)
    return SearchResult(levels, float(value), "annealing", evaluations + 1, time.perf_counter() - t0, trace)


def _distinct(ranked):
    """The (value, levels, evaluations) results without repeated level vectors, order kept."""
    out, seen = [], set()
    for r in ranked:
        key = tuple(r[1])
        if key not in seen:
            seen.add(key)
            out.append(r)
    return out


def _restart(objective: Objective, fly: Flyability, start, n_iter: int, seed) -> tuple[float, list, int]:
    """One annealing run (from ``start``, else a random flyable sequence) ended by a polish:
    (objective, levels, candidates scored)."""
    rng = np.random.default_rng(seed)
    e0 = objective.evaluations
    K, axes = objective.basis.n_steps, len(objective.basis.inputs)

    def feasible(levels):
        return _feasible(levels, K, axes, fly)

    if start is not None:
        cur = [float(v) for v in start]
    else:
        cur = [float(v) for _ in range(axes) for v in _random_feasible(K, fly, rng)]
    objective.reset(cur)
    f_cur = objective(np.array(cur))
    objective.commit()
    deltas = []  # temperature scale from a few random feasible neighbours
    for _ in range(60):
        cand = _propose(cur, K, axes, fly, rng)
        if feasible(cand):
            f = objective(np.array(cand))
            if np.isfinite(f) and np.isfinite(f_cur):
                deltas.append(abs(f - f_cur))
    # hot enough that a typical worsening is accepted 80 % of the time at first: with peak
    # responses in the criterion the landscape is rugged (an optimum can sit among neighbours
    # far below it), and a walk at the median change never leaves its basin
    T0 = max(float(np.mean(deltas)) / -np.log(0.8) if deltas else 1.0, 1e-3)
    T_end = T0 * 1e-3
    r_best = (f_cur, list(cur))
    for i in range(n_iter):
        T = T0 * (T_end / T0) ** (i / max(n_iter - 1, 1))
        for _ in range(50):  # every iteration scores a flyable neighbour (rejecting is cheap)
            cand = _propose(cur, K, axes, fly, rng)
            if cand != cur and feasible(cand):
                break
        else:
            continue
        f = objective(np.array(cand))
        if f >= f_cur or (np.isfinite(f) and (not np.isfinite(f_cur) or rng.random() < np.exp((f - f_cur) / T))):
            cur, f_cur = cand, f
            objective.commit()
            if f_cur > r_best[0]:
                r_best = (f_cur, list(cur))
    objective.reset(r_best[1])
    cur, f_cur = _polish(objective, r_best[1], r_best[0], K, axes, fly.min_pulse, feasible)
    return float(f_cur), cur, objective.evaluations - e0


def _kick_chain(objective: Objective, fly: Flyability, levels, rounds: int, seed) -> tuple[float, list, int]:
    """Iterated local search: perturb the best by 2..4 random flyable moves, polish, keep if better;
    ``rounds`` times. (Polishing only near the kick was 3x cheaper but rarely beat the best: the
    Navion's robust figure fell below target on 2 of 4 seeds.)"""
    rng = np.random.default_rng(seed)
    e0 = objective.evaluations
    K, axes = objective.basis.n_steps, len(objective.basis.inputs)

    def feasible(c):
        return _feasible(c, K, axes, fly)

    levels = [float(v) for v in levels]
    objective.reset(levels)
    f_best = objective(np.array(levels))
    for _ in range(rounds):
        cand = list(levels)
        for _ in range(int(rng.integers(2, 5))):
            for _ in range(50):
                nxt = _propose(cand, K, axes, fly, rng)
                if feasible(nxt):
                    cand = nxt
                    break
        if cand == levels:
            continue
        objective.reset(cand)
        f = objective(np.array(cand))
        objective.commit()
        cand, f = _polish(objective, cand, f, K, axes, fly.min_pulse, feasible)
        if f > f_best:
            f_best, levels = f, cand
    return float(f_best), levels, objective.evaluations - e0


def _feasible(levels, K, axes, fly) -> bool:
    return all(fly.feasible(levels[a * K:(a + 1) * K]) for a in range(axes))


def polish(objective: Objective, fly: Flyability, levels) -> tuple[np.ndarray, float]:
    """Local search from ``levels`` to a local optimum of ``objective`` (see :func:`_polish`)."""
    K, axes = objective.basis.n_steps, len(objective.basis.inputs)
    levels = [float(v) for v in levels]
    objective.reset(levels)
    value = objective(np.array(levels))
    objective.commit()
    levels, value = _polish(objective, levels, value, K, axes, fly.min_pulse, lambda c: _feasible(c, K, axes, fly))
    objective.reset()
    return np.array(levels), objective(np.array(levels))


def _polish(score: Objective, levels, value, n_steps, axes, min_pulse, feasible):
    """Local search until no move improves the objective (first improvement): set any block of
    1..2 min_pulse steps of one axis to any level (which also moves any switch), flip the sign of
    any hold, and shift any hold by 1..min_pulse steps either way. After an improvement the scan
    resumes where it was (not from the first move), so a pass costs one sweep of the neighbourhood."""
    moves = list(_neighbours(levels, n_steps, axes, min_pulse))
    i, since = 0, 0
    while since < len(moves):
        cand = moves[i % len(moves)]
        i, since = i + 1, since + 1
        if feasible(cand):
            f = score(cand)
            if f > value + 1e-12:
                levels, value, since = cand, f, 0
                score.commit()
                moves = list(_neighbours(levels, n_steps, axes, min_pulse))
                i = i % len(moves) if moves else 0
    return levels, value


def _neighbours(levels, n_steps, axes, min_pulse):
    """The polish's moves from ``levels``."""
    for a in range(axes):
        lo, hi = a * n_steps, (a + 1) * n_steps
        for start in range(lo, hi):
            for length in range(1, 2 * min_pulse + 1):
                stop = min(start + length, hi)
                for v in LEVELS:
                    if any(levels[k] != v for k in range(start, stop)):
                        cand = list(levels)
                        cand[start:stop] = [float(v)] * (stop - start)
                        yield cand
        runs, k = [], lo
        while k < hi:
            e = k
            while e < hi and levels[e] == levels[k]:
                e += 1
            runs.append((k, e))
            k = e
        for s, e in runs:
            if levels[s] == 0:
                continue
            cand = list(levels)
            cand[s:e] = [-levels[s]] * (e - s)
            yield cand
            for shift in range(1, min_pulse + 1):
                for d in (shift, -shift):
                    if not (lo <= s + d and e + d <= hi):
                        continue
                    cand = list(levels)
                    cand[s:e] = [0.0] * (e - s)
                    cand[s + d:e + d] = [levels[s]] * (e - s)
                    yield cand

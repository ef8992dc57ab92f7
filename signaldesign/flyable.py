"""Flyable three-level sequences: the pilot's constraints, and every sequence that meets them.

Levels are -1, 0, +1 on a grid of equal steps; a hold lasts at least ``min_pulse`` steps, the
sequence makes at most ``max_changes`` level changes and (by default) never jumps +1 to -1 in one
step. The sequence starts from and returns to trim (0) outside its steps.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .evaluate import DesignError

LEVELS = (-1, 0, 1)


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


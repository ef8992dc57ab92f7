"""Where the filter-error likelihood can have two optima: the noise's starts and the restart.

Where F compensation puts a start of R below its floor the likelihood can have two optima (the
model's misfit taken by the measurement noise, or by the process noise with q and theta tracked
tightly), and neither the gain-held start of R nor the floor found the better on every seed: FEM
also runs from the process-noise side, F from the states' whole measured rms (F_WIDE instead of
F_START) with R on its floor, and keeps the higher likelihood (docs/filter_error.md, "Two
optima"). Both starts begin at the a priori derivatives; on refine's blind lag_de (seed 3) both
ended on the worse optimum (-log L 1987 above), and the process-noise side's start from the better
fit's derivatives reached the better one: FEM restarts there once more. A start whose filter has
no steady state fails alone: reported, the others stand.
"""
from __future__ import annotations

import numpy as np

from ...errors import EstimationError
from .base import F_START
from .solver import FilterSolver

F_WIDE = 1.0
R_STARTS = {"gain_held": ("gain_held", 1.0), "wide_f": ("floor", F_WIDE / F_START)}  # name: (R's start, F's factor)
START_NAMES = {"gain_held": "R = (I - C K) S_hat", "wide_f": f"F x{F_WIDE / F_START:.3g} with R on its floor",
               "restart": "the best fit's derivatives, F and R as wide_f"}
RESTART = ("floor", F_WIDE / F_START)  # (R's start, F's factor), as wide_f; None: no restart (benchmarks measure both)
SAME_OPTIMUM = 1.0  # -log L within this of the best: the same optimum (a likelihood ratio far from significant)


def fit_from_starts(fem, prob, beta, active, **options) -> FilterSolver:
    """The fit from the start (:class:`FilterSolver`); where F compensation put a start of R below
    its floor (``floor_bound``), or the start failed, from every start of R_STARTS too, the highest
    likelihood of the converged fits kept: the likelihood can have two optima there, and each single
    start missed the better one on some seeds; then once more from the better fit's derivatives
    (``RESTART``), since both starts from the a priori derivatives can miss it too. A start that
    fails (no steady state, a numerical failure) is recorded, the others stand; all failed: one
    :class:`EstimationError` naming why. The record in ``solver.starts`` (the starts' -log L, the
    one kept, the failures, ``line``: one line for the summary); no warning per fit."""
    tried, failed = {}, {}
    _try(fem, "gain_held", ("gain_held", 1.0), beta, prob, active, tried, failed, **options)
    first = tried.get("gain_held")
    if first is not None and not first.floor_bound:
        return first
    for name, start in R_STARTS.items():
        if name not in tried and name not in failed:
            _try(fem, name, start, beta, prob, active, tried, failed, **options)
    if not tried:
        raise EstimationError("; ".join(dict.fromkeys(failed.values())))
    b = beta.copy()
    b[:prob.p] = tried[_kept(tried)].beta[:prob.p]
    # the a priori derivatives' starts missed it too (refine_blind lag_de seed 3); from the same
    # derivatives (held: a nuisance-only prediction) the restart would repeat the wide_f start
    if RESTART is not None and not np.array_equal(b[:prob.p], beta[:prob.p]):
        _try(fem, "restart", RESTART, b, prob, active, tried, failed, **options)
    kept = _kept(tried)
    best = tried[kept]
    floor_bound = list(first.floor_bound) if first is not None else []
    costs = ", ".join(f"{k} {v.history[-1]:.6g}" for k, v in tried.items())
    why = (f"the F-compensated start of R fell below its floor on {', '.join(floor_bound)} (the likelihood can "
           f"have two optima)" if floor_bound else "the first start failed")
    line = (f"{why}: fitted from {len(tried) + len(failed)} starts (-log L {costs}), kept {kept} "
            f"({START_NAMES[kept]})" + "".join(f"; {k} failed: {v}" for k, v in failed.items()))
    best.starts = {"floor_bound": floor_bound, "kept": kept, "cost": {k: float(v.history[-1]) for k, v in tried.items()},
                   "converged": {k: bool(v.converged) for k, v in tried.items()}, "failed": failed, "line": line}
    return best


def _try(fem, name, start, beta, prob, active, tried, failed, **options) -> None:
    """The fit from ``beta`` with ``start`` = (R's start, F's factor), into ``tried[name]``, or
    why it failed into ``failed[name]`` (a start whose filter has no steady state, a numerical
    failure on the way: the others stand)."""
    r_start, f_factor = start
    b = beta.copy()
    b[prob.index["f"]] *= f_factor
    try:
        tried[name] = FilterSolver(fem, prob, b, active, r_start=r_start, **options)
        tried[name].run()
    except EstimationError as e:
        tried.pop(name, None)
        failed[name] = str(e)
    except (np.linalg.LinAlgError, ValueError, FloatingPointError) as e:
        tried.pop(name, None)
        failed[name] = f"FEM: a numerical failure in the filter ({e})"


def _kept(tried: dict) -> str:
    """The first start at the best optimum among the converged fits (all, where none converged;
    ties: the earlier start, the default first)."""
    pool = {k: v for k, v in tried.items() if v.converged} or tried
    low = min(v.history[-1] for v in pool.values())
    return next(k for k, v in pool.items() if v.history[-1] <= low + SAME_OPTIMUM)

"""What strongly coloured output-error residuals point to, its causes ranked.

Output error's coloured-residual bounds far wider than its white ones say the residuals are not
measurement noise. The causes, in the order a user should act on them:

1. a model error refine finds (an input delay, a missing derivative or control term): the
   residuals then follow the inputs: ``identify refine``;
2. turbulence, or a pilot or SAS closing the loop: the residuals do not follow the inputs (open
   loop), or refine found nothing: the filter-error method (``--method fem``).

"Follow the inputs": per output, the share of the residuals' variance a short FIR of every input
explains (lags 0..``FIR_SECONDS``; both first-differenced, so that a slow residual does not pass
for a fast misfit), against the same share with each run's inputs shifted
circularly by ``NULL_SHIFTS`` offsets (the inputs' and the residuals' own colour kept, their
alignment broken: a permutation test valid for coloured residuals). An output follows the inputs
when its share exceeds every shifted one (level 1/(NULL_SHIFTS + 1) = 0.01 per output) and
``FOLLOW_SHARE``.
"""
from __future__ import annotations

import numpy as np

COLOURED_ADVICE = 2.0  # coloured-residual bounds this many times the white ones: the residuals are not noise
FIR_SECONDS = 1.0  # the FIR's length (s): a delay's or a missing term's misfit lies within it
FIR_TAPS = 25  # at most (lags spaced over FIR_SECONDS)
NULL_SHIFTS = 99  # circular shifts of the inputs: the null distribution of the explained share (level 0.01)
FOLLOW_SHARE = 0.01  # and at least this share of the variance of an output's residual increments


def _fir(u: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """(N, m * len(lags)) of the inputs (N, m) delayed by ``lags`` samples (zero before the record)."""
    N, m = u.shape
    cols = np.zeros((N, m * len(lags)))
    for i, k in enumerate(lags):
        cols[k:, i * m:(i + 1) * m] = u[:N - k]
    return cols


def _shares(residuals: list[np.ndarray], inputs: list[np.ndarray], lags: np.ndarray, shift: float) -> np.ndarray:
    """Per output, the share of the residuals' variance the FIR explains (each run's inputs rolled
    by ``shift`` of its length)."""
    # first differences of both (prewhitening): a slow residual (a phugoid in gusts) spans few
    # independent shifts, and any alignment with it would pass for input-driven
    X = np.vstack([_fir(np.diff(np.roll(u, int(shift * len(u)), axis=0), axis=0), lags) for u in inputs])
    E = np.vstack([np.diff(e, axis=0) for e in residuals])
    coef, *_ = np.linalg.lstsq(X, E, rcond=None)
    total = np.sum(E ** 2, axis=0)
    return np.where(total > 0, np.sum((X @ coef) ** 2, axis=0) / np.maximum(total, 1e-300), 0.0)


def follows_inputs(residuals: list[np.ndarray], inputs: list[np.ndarray], dt: float, outputs: list[str]) -> dict:
    """``{output: share}`` of the outputs whose residuals follow the inputs (module notes)."""
    n = min(len(e) for e in residuals)
    step = max(1, int(round(FIR_SECONDS / dt / FIR_TAPS)))
    lags = np.arange(0, min(int(FIR_SECONDS / dt), n // 4) + 1, step)
    moving = [u for u in inputs if u.size and np.any(np.ptp(u, axis=0) > 0)]
    if not moving or len(moving) != len(inputs) or n < 8 * len(lags):
        return {}
    real = _shares(residuals, inputs, lags, 0.0)
    null = np.max([_shares(residuals, inputs, lags, s) for s in np.linspace(0.1, 0.9, NULL_SHIFTS)], axis=0)
    return {y: float(r) for y, r, q in zip(outputs, real, null) if r > q and r >= FOLLOW_SHARE}


def colour_advice(std_white: np.ndarray, std_col: np.ndarray | None, followed) -> str | None:
    """The note when the residuals are strongly coloured (median coloured/white bound >=
    COLOURED_ADVICE; on the benchmarks' turbulent cases 4.5-7, in calm air 0.94-0.98), its causes
    ranked: residuals that follow the inputs (``followed()``, called only then: :func:`follows_inputs`)
    send the user to refine first; otherwise turbulence or feedback, and the filter-error method."""
    if std_col is None:
        return None
    ok = np.isfinite(std_white) & np.isfinite(std_col) & (std_white > 0)
    ratio = float(np.median(std_col[ok] / std_white[ok])) if ok.any() else float("nan")
    if not ratio >= COLOURED_ADVICE:
        return None
    followed = followed()
    head = f"the residuals are strongly coloured (coloured-residual bounds {ratio:.1f}x the white ones)"
    if followed:
        listed = ", ".join(f"{y} {100 * s:.0f} %" for y, s in followed.items())
        return (f"{head} and follow the inputs (share of their increments an FIR of the inputs explains: {listed}, beyond any shifted input's): "
                f"a model error first (an input delay, a missing derivative): run `identify refine`; if it finds "
                f"nothing, turbulence or a pilot/SAS in the loop (--method fem)")
    return (f"{head} and do not follow the inputs: turbulence, or a pilot or SAS in the loop? Output error's "
            f"estimates may then be biased beyond their bounds; the filter-error method (--method fem) models "
            f"the process noise")

"""Backward elimination in output error: fix at zero, one at a time, what the data do not support.

A parameter is *unsupported* when its estimate is within ``level`` (2) standard errors of zero
(the estimator's own bounds: ML's are corrected for coloured residuals). The least supported
is fixed at zero and the model re-fitted; the removal stands unless it raises the held-out
prediction error (the overall error: the RMS over outputs of each output's RMS error divided by
the output's standard deviation, as refine reports it) by more than ``tolerance`` (1 %) of itself.
Why a tolerance and not a likelihood-ratio test on the held-out data: the re-fit moves every
other parameter and each held-out segment's initial state too, and on the 8-state hover case
removing a parameter at 0.2 std moved the held-out Gaussian likelihood by +-100 (20 times a
chi-square limit corrected for the residuals' colour) while its overall error moved by 0.1 %; a
re-fit alone moved it by up to 1.6 %. A refused parameter stays (and is not tried again); then
the next least supported is tried, until every free parameter is supported or was refused.

The held-out data are those of the :class:`~identify.refine.fitting.Fitting` handed in: its
``choosing`` part (refine's, or the part ``identify structure`` holds out), else the fitting runs
themselves (then only the |estimate| rule decides: the fit error always rises). It runs inside
``identify structure`` and as ``identify refine --prune``'s last step.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ProfileError, PseudostepError
from ..model.subset import fix
from .regression import Decision


class Prune:
    """Backward elimination by output error (see the module docstring). ``level``: |estimate| /
    std below which a parameter is unsupported (2); ``tolerance``: the relative rise of the
    held-out error a removal may cause (0.01); ``keep``: parameters never tried."""

    def __init__(self, level: float = 2.0, tolerance: float = 0.01, keep=()):
        self.level, self.tolerance, self.keep = level, tolerance, tuple(keep)

    def run(self, fitting, profile, result, say=None):
        """Prune ``profile`` (fitted, ``result`` its fit) on ``fitting``'s data: the pruned profile,
        its result and the :class:`~identify.structure.regression.Decision` s (dropped or kept)."""
        say = say or (lambda msg: None)
        data = "choosing" if fitting.data.get("choosing") else "fit"
        refused, decisions = set(self.keep), []
        scale = output_scale(fitting.data["fit"], profile.outputs)
        while True:
            t = _t_values(result)
            weak = sorted((abs(v), n) for n, v in t.items() if n not in refused and not abs(v) >= self.level)
            if not weak or len(profile.free) <= 1:
                return profile, result, decisions
            tval, name = weak[0]
            try:
                trial = fix(profile.with_values({name: 0.0}), [name])
                new_p, new_r = fitting.refit(trial, trial)
                before, after = fitting.residuals(profile, data), fitting.residuals(new_p, data)
            except (ProfileError, PseudostepError) as exc:
                refused.add(name)
                decisions.append(self._decision(name, tval, math.nan, math.nan, "kept",
                                                f"re-fit without it failed: {exc}"))
                say(f"  prune {name}: kept (the re-fit without it failed: {exc})")
                continue
            j0, j1 = overall_error(before, scale), overall_error(after, scale)
            limit = j0 * (1 + self.tolerance) if data == "choosing" else math.inf
            if j1 > limit:
                refused.add(name)
                decisions.append(self._decision(name, tval, j0, j1, "kept",
                                                f"the {data} error rises {j1 / j0 - 1:+.2%} (more than {self.tolerance:.1%})"))
                say(f"  prune {name} (|t| = {tval:.2f}): kept, the {data} error rises {j1 / j0 - 1:+.2%}")
                continue
            decisions.append(self._decision(name, tval, j0, j1, "dropped",
                                            f"|estimate| < {self.level:g} std; the {data} error changes {j1 / j0 - 1:+.2%}"))
            say(f"  prune {name} (|t| = {tval:.2f}): fixed at zero")
            profile, result = new_p, new_r

    def _decision(self, name, tval, j0, j1, action, note) -> Decision:
        return Decision("output error", action, name, "", float(tval), self.level,
                        f"|estimate|/std below {self.level:g}, then the held-out error", j0, j1, True, note)


def _t_values(result) -> dict[str, float]:
    """|estimate| / std per free parameter (a NaN bound, not determined: t = 0, unsupported)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.isfinite(result.std) & (result.std > 0), result.theta / result.std, 0.0)
    return dict(zip(result.names, map(float, t)))


def output_scale(runs, outputs) -> np.ndarray:
    """Each output's standard deviation over ``runs`` (the unit of the overall error)."""
    return np.array([np.std(np.concatenate([r[y] for r in runs])) or 1.0 for y in outputs])


def overall_error(residuals: list[np.ndarray], scale: np.ndarray) -> float:
    """RMS over outputs of each output's RMS error divided by its ``scale`` (refine's ``overall``)."""
    rms = np.sqrt(np.mean(np.vstack(residuals) ** 2, axis=0))
    return float(np.sqrt(np.mean((rms / scale) ** 2)))


__all__ = ["Prune", "output_scale", "overall_error"]

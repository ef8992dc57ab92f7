"""The frequency-response estimate's own deterministic error, seen through a model's simulated runs.

A composite response from short records is not the aircraft's response even without noise: each
segment holds the transient of the input before it and the taper smears H over the window's
resolution (:mod:`.response` corrects the leakage to first order only). On 20-s runs of the
unstable S 61 hover model the noise-free estimate lies 5 % of |H| off the truth at the median of the
fitted points (11 % at the low end of q/theta_s), and fitting it gave L_theta_c +1.4 %, L_p -2.3 %
with no noise at all. That error is a deterministic function of the aircraft and the inputs flown,
so a model's simulated runs with the same inputs (its initial state and zero shifts fitted, as
VERIFY does) put through the *same* estimate (:func:`.response.replay`: frequencies, windows,
leakage correction and composite weights) show it: ``ratio = H_replayed / H_model``. Fitting the
data divided by the ratio of the current estimate, and repeating, converges to the model whose
simulated runs give the data's estimate (an indirect-inference fit): at the truth the ratio is the
data's own error, so the fixed point is unbiased to first order in the parameter error.
"""
from __future__ import annotations

import numpy as np

from ...model.linear import LinearModel
from .response import replay
from .statespace import response_and_jacobian


def estimate_error(fr, runs, predictions, fit, used: np.ndarray) -> tuple[np.ndarray, str]:
    """``ratio`` (nf, ny, nu) = what ``fr``'s estimate makes of the fitted model's response over its
    exact response (1 where either is unknown), and a line stating its size on the ``used`` points
    (nf, ny, nu) bool, the ones fitted."""
    p = fit.profile
    sims = [r.with_channels({y: pr.modelled[:, k] for k, y in enumerate(p.outputs)})
            for r, pr in zip(runs, predictions)]
    yi = [p.outputs.index(y) for y in fr.outputs]
    ui = [p.input_names.index(u) for u in fr.inputs]
    tau = np.array([fit.tau.get(u, 0.0) for u in fr.inputs])
    exact = response_and_jacobian(LinearModel(p, fit.theta), fr.omega, yi, ui, tau)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = replay(fr, sims) / exact
    known = np.isfinite(ratio) & (np.abs(ratio) > 0)
    ratio = np.where(known, ratio, 1.0)
    unknown = int((used & ~known).sum())
    used = used & known
    size = 100 * np.abs(ratio[used] - 1)
    line = ("response estimate's own error (the fitted model's simulated runs through the same estimate, "
            f"against its exact response): {np.median(size):.2g} % median, {np.max(size):.2g} % max over "
            f"{used.sum()} fitted points; the fit and its J are against the data corrected for it"
            if size.size else "response estimate's own error: not determined on any fitted point")
    if unknown:
        line += f"; {unknown} fitted point(s) without a replay left uncorrected"
    return ratio, line

"""The filter-error method on a profile with declared turbulence: the seam to the gust model.

:func:`identify.model.turbulence.augment` builds the model with gust states; the filter-error
method fits it as any other (its corners are free parameters of A, the gusts' F its process
noise), and :func:`fit` hands the result back on the user's profile: the profile's derivatives with
their bounds, the fitted corners and intensities with theirs in ``info["turbulence"]``, the
process-noise model in one line (``info["process_noise_model"]``), and a profile whose
``[turbulence]`` starts the next fit (refine's nested fits) at the fitted values.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from ...model.turbulence import GustModel, augment, without
from ..result import IdentificationResult


def fit(fem, runs) -> IdentificationResult:
    """The FEM fit of ``fem.profile_`` (which declares ``[turbulence]``) on ``runs``. Corners to
    estimate: first a fit with them held at their starts, then from its derivatives the fit with
    them free (from the a priori derivatives at once, the gusts took the a
    priori model's misfit as white noise: corners ran to 165 rad/s and the filter diverged, S 61
    hover with a stability augmentation, benchmarks/filter_error.py)."""
    p = fem.profile_
    default = getattr(fem, "default_turbulence_", False)
    gm, calm = augment(p, runs), []
    if gm.corners:
        t = {k: v for k, v in p.turbulence.items() if k != "corner_start"}
        held = augment(replace(p, turbulence={**t, "corner": {s: gm.held_start(s) for s in gm.corners}}), runs)
        first, _ = _fit_augmented(fem, held, runs, diffuse=False)  # the derivatives' start alone
        # a gust whose F went to 0 there is not in the data: its corner is not determined, and
        # freed it ran beyond the Nyquist frequency and the fit stalled (calm air, the default's
        # gusts on u and w of the Navion), so it is left out
        calm = [s for s, g in gm.gusts.items() if s in gm.corners and first.info["process_noise"][g]["F"] == 0.0]
        p = without(p, calm)
        if not p.turbulence:
            return _calm_air(fem, p, runs, calm, default)
        # the gusts' F and R start afresh: from the first fit's F the start of R fell below its
        # floor (FEM's three starts, five times the time, the same optimum)
        start = replace(p, free=dict(zip(p.free, map(float, first.theta[:gm.n_derivatives]))))
        gm = replace(augment(start, runs), profile=p)
    res, inner = _fit_augmented(fem, gm, runs)
    return on_profile(gm, res, inner, default=default, calm=calm)


def _calm_air(fem, p, runs, calm: list, default: bool) -> IdentificationResult:
    """No gust found (every one's F went to 0): the fit without process noise (output error), said."""
    inner = fem.clone(p, process_noise={}).fit(runs)
    res = inner.result_
    fem.problem_, fem.beta_ = inner.problem_, inner.beta_
    line = res.info["process_noise_model"] + CALM_NOTE.format(", ".join(calm)) + (DEFAULT_NOTE if default else "")
    res.info.update(process_noise_model=line, turbulence={"model": line, "gusts": {}, "not_found": calm,
                                                          "airspeed": None, "declared": not default})
    return res


def augmented_estimator(fem, runs, gm: GustModel | None = None, **changes):
    """An unfitted FEM with ``fem``'s options (and ``changes``) on the augmented profile (``gm``'s,
    default built from ``fem.profile_`` and ``runs``), the gust states' process noise with the
    option's."""
    gm = gm or augment(fem.profile_, runs)
    return fem.clone(gm.augmented, process_noise={**gm.noise_states(), **(fem.process_noise or {})},
                     **{"diffuse": gm.diffuse, "stationary_start": tuple(gm.gusts.values()) if gm.diffuse else (),
                        "positive": tuple(gm.corners.values()), **changes})


def _fit_augmented(fem, gm: GustModel, runs, **changes):
    """FEM (with ``fem``'s options and ``changes``) on the augmented profile: its result and the fitted FEM."""
    inner = augmented_estimator(fem, runs, gm, **changes).fit(runs)
    res = inner.result_
    fem.problem_, fem.beta_, fem.gusts_ = inner.problem_, inner.beta_, gm
    return res, inner


DEFAULT_NOTE = ("; the default (neither [turbulence] nor [process_noise] declared; white process noise instead: "
                "[process_noise] or --process-noise)")


CALM_NOTE = "; no gust found on {} (its F went to 0 with the corner held at its start): left out"


def on_profile(gm: GustModel, res: IdentificationResult, inner, default: bool = False,
               calm: list = ()) -> IdentificationResult:
    """The augmented fit ``res`` (by the FEM ``inner``) on the user's profile (``default``: the gust
    states are FEM's default, not declared; ``calm``: the velocities whose gust was left out: both
    said in the process-noise line and recorded)."""
    k = gm.n_derivatives
    prob = inner.problem_
    f = {s: v["F"] for s, v in res.info["process_noise"].items()}
    rows = {name: i for i, name in enumerate(gm.augmented.free_names)}
    rows.update({s: int(j) for s, j in zip(prob.noise_states, prob.index["f"])})
    cov = inner.covariance_all_
    for name, row in list(rows.items()):  # held (not excited) or on the boundary: no bound
        if not (np.isfinite(cov[row, row]) and cov[row, row] > 0):
            del rows[name]
    line = gm.describe() + (CALM_NOTE.format(", ".join(calm)) if calm else "") + (DEFAULT_NOTE if default else "")
    gusts = gm.report(res.theta, f, cov, rows)
    info = {**res.info, "process_noise_model": line, "turbulence": {
        "model": line, "gusts": gusts, "not_found": list(calm), "airspeed": gm.airspeed, "declared": not default}}
    nyquist = math.pi / prob.dt
    odd = {f"corner of {s}": (f"{g['corner']:.4g} rad/s, {'beyond the Nyquist frequency' if g['corner'] > 0 else 'not positive'}"
                              f": the gust is not determined (white at this sampling, or taking a misfit of the "
                              f"model); its corner and intensity are not meaningful")
           for s, g in gusts.items() if g["corner_estimated"] and not 0 < g["corner"] < nyquist}
    if odd:
        info["not_determined"] = {**res.info.get("not_determined", {}), **odd}
        warnings.warn("FEM: " + "; ".join(f"{k}: {v}" for k, v in odd.items()), stacklevel=4)
    own = {s: v for s, v in f.items() if s in gm.profile.process_noise}
    profile = replace(gm.profile, turbulence=gm.fitted_table(res.theta, f),
                      process_noise=own or gm.profile.process_noise)
    return IdentificationResult(res.method, profile, res.theta[:k].copy(), res.std[:k].copy(), res.fit, info,
                                res.runs, None if res.covariance is None else res.covariance[:k, :k].copy(),
                                res.time, res.measured, res.modelled, simulated=res.simulated)

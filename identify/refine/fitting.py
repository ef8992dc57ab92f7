"""What candidates (and the loop) ask while scoring and fitting: :class:`Fitting`.

One object per refinement holds the estimator instance, the data sets, the nuisance and segments
every fit shares, and the cache of predictions: a candidate is handed this, never the loop, and
asks it for ``refit``, ``residuals``, ``prediction`` and ``input_response``. How a model predicts
the data (output error, one-step-ahead innovations) is the estimator's
(:meth:`identify.estimators.base.Estimator.prediction`); the fitting object only caches and counts.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np

from ..data.runs import Run
from ..errors import ConvergenceWarning, PseudostepError
from ..estimators.prediction import ModelFit, block_design, feedback_bounds, settle, state_terms
from ..estimators.result import IdentificationResult
from ..model.pseudo_inputs import prepare
from ..model.profile import Profile


class Fitting:
    """Fits and predictions of profiles on refine's data sets.

    ``estimator``: the estimator instance (cloned per fit, :meth:`Estimator.nested`); ``data``:
    ``{"fit": runs, "choosing": runs, "validation": runs}``; ``zero_shifts``, ``segment`` (s) the
    nuisance and segments of every fit and prediction; ``tau_max`` (s) the largest delay a
    candidate searches; ``held`` the parameters held because the estimator cannot determine them;
    ``say`` a progress callable. Records ``unconverged`` (one note per fit that
    did not converge) and counts ``evaluations`` (predictions computed, each (model, data set) once).
    """

    def __init__(self, estimator, data: dict[str, list[Run]], declared: Profile, *, zero_shifts: bool = True,
                 segment: float = math.inf, tau_max: float = 0.5, held: tuple = (), say=None):
        self.estimator, self.data, self.declared = estimator, data, declared
        self.held = tuple(held)  # parameters the estimator cannot determine, held (still dynamics)
        self.zero_shifts, self.segment, self.tau_max = zero_shifts, segment, tau_max
        self.say = say or (lambda msg: None)
        self.cache: dict = {}
        self.fitted_noise: dict = {}  # profile text -> the noise its fit estimated (a filter's F and R)
        self.evaluations = 0
        self.unconverged: list[str] = []

    def forget(self, kind: str) -> None:
        """Drop the cached entries of one ``kind`` (the first element of their key)."""
        for key in [k for k in self.cache if k[0] == kind]:
            del self.cache[key]

    @property
    def dt(self) -> float:
        return self.data["fit"][0].dt

    def prediction(self, p: Profile, data: str = "fit") -> ModelFit:
        """The profile's prediction of one data set (``fit``, ``choosing``, ``validation``) with the
        shared segments and nuisance; each (model, data set) pair computed once.

        Held-out data are predicted by the model fitted on the fitting runs, its noise parameters
        included (``ModelFit.noise``, a filter's F and R, hence its gain): re-fitted on the held-out
        data, a filter without an effect raises its process noise there until it tracks what the
        effect explains, and the held-out check then measures the effect against a model partly
        fitted to the data that judge it. Only each run's own nuisance (initial state, zero shifts)
        is fitted on held-out runs.

        On the fitting runs a fitted profile's noise parameters start from its fit's
        (``fitted_noise``): the prediction is then the fit's own optimum, not another local one of
        the noise's likelihood (a filter whose F and R re-fitted from scratch ended 6000 below its
        fit at the same derivatives and made every likelihood ratio meaningless)."""
        key = (p.to_toml(), data)
        if key not in self.cache:
            noise = self.prediction(p, "fit").noise if data != "fit" else None
            start = self.fitted_noise.get(key[0]) if data == "fit" else None
            self.evaluations += 1
            self.cache[key] = self.estimator.prediction(p, prepare(p, self.data[data]), zero_shifts=self.zero_shifts,
                                                        segment=self.segment, **({"noise": noise} if noise else {}),
                                                        **({"noise_start": start} if start else {}))
        return self.cache[key]

    def residuals(self, p: Profile, data: str = "fit"):
        return self.prediction(p, data).residuals

    def sensitivities(self, ext_p: Profile, runs: list[Run], null: ModelFit) -> ModelFit:
        """The prediction of ``runs`` (holding every candidate's channels) by the extended profile
        ``ext_p`` at its null values, with its sensitivities: the score tests' columns."""
        self.evaluations += 1
        return self.estimator.sensitivities(ext_p, runs, null, zero_shifts=self.zero_shifts, segment=self.segment)

    def input_response(self, p: Profile, input_name: str, transform) -> list:
        """Per fit run (N_r, ny): the response to ``transform(u, dt)`` of one input (the others zero)."""
        start = self.prediction(p).noise  # the gain of the fit's (or the prediction's) noise
        return self.estimator.input_response(p, prepare(p, self.data["fit"]), segment=self.segment,
                                             input_name=input_name, transform=transform,
                                             **({"noise_start": start} if start else {}))

    def estimate(self, profile: Profile, runs: list[Run], bounds: bool = True,
                 advice: bool = False, start: IdentificationResult | None = None) -> IdentificationResult:
        """Fit ``profile`` with the shared nuisance and segments; ``bounds=False`` when only the
        estimate and its likelihood are used (the fits inside a delay search); ``advice`` the
        estimator's note on what coloured residuals point to (the declared model's fit only);
        ``start`` a neighbouring model's fit (a search's) whose noise estimate starts this one's."""
        estimator = self.estimator.nested(profile, zero_shifts=self.zero_shifts, segment=self.segment, bounds=bounds,
                                          advice=advice, **({"start": start} if start is not None else {}))
        with warnings.catch_warnings():
            # recorded below, once per fit, instead of interleaved with the progress lines
            warnings.simplefilter("ignore", ConvergenceWarning)
            result = estimator.fit(runs).result_
        if not result.converged:
            free = ", ".join(n for n in result.names if n not in self.declared.free) or "declared model"
            note = f"fit with {free} did not converge ({result.info.get('stop', 'no reason given')})"
            self.unconverged.append(note)
            self.say(f"  warning: {note}")
        return result

    def refit(self, ext_p: Profile, p: Profile, bounds: bool = True, advice: bool = False,
              start: IdentificationResult | None = None) -> tuple[Profile, IdentificationResult]:
        """Fit of an extended profile: the fitted profile (named as ``p``) and the result (``advice``,
        ``start``: :meth:`estimate`).
        State-built terms come from the predicted states of the model being fitted (:func:`settle`),
        or from the estimator's own state estimates inside its fit (``builds_state_terms``)."""
        builds = self.estimator.builds_state_terms

        def fit(prof: Profile):
            simulated = state_terms(prof) and not builds
            runs = self.prediction(prof).runs if simulated else prepare(prof, self.data["fit"])
            result = self.estimate(prof, runs, bounds=bounds, advice=advice, start=start)
            fitted = _keep_meta(result.identified_profile(p.name), ext_p)
            noise = self.estimator.fitted_noise(result)
            if noise is not None:
                self.fitted_noise[fitted.to_toml()] = noise
            return fitted, result

        if not state_terms(ext_p) or builds:
            return fit(ext_p)
        fitted, result = settle(fit, ext_p)
        if bounds:
            # the loop evaluates the fitted model anyway: its cached prediction is the bounds' base
            result = feedback_bounds(result, fitted, prepare(fitted, self.data["fit"]), self.zero_shifts,
                                     self.segment, base=self.prediction(fitted))
        return fitted, result

    def refit_in_metric(self, start: Profile, noise, max_iter: int = 20) -> tuple[Profile, float, dict]:
        """Gauss-Newton fit of ``start``'s free parameters that minimises the noise model's cost
        (``noise.cost`` of the residuals, the score test's metric), started at ``start``'s values
        (refine's warm start: the current estimates, the new parameters at their null value); the
        nuisance fitted by the estimator's prediction at every point. A check of a re-fit that
        ended below the nested null in that metric, not an estimator: it tells whether the metric
        itself has a better point there. ``(profile, cost, {name: {"value", "std"}})``, the stds
        from the whitened design in that metric."""
        names, prof = start.free_names, start
        theta = np.array([start.free[n] for n in names], float)
        cost, std = noise.cost(self.residuals(prof)), np.full(len(names), np.nan)
        for _ in range(max_iter):
            ev = self.prediction(prof)
            evj = self.sensitivities(prof, ev.runs, ev)
            J = block_design([noise.whiten(d) for d in evj.dy], [noise.whiten(nu) for nu in evj.nuisance])
            e = np.concatenate([noise.whiten(r).ravel() for r in ev.residuals])
            step, cov = _gauss_newton(J, e, len(names))
            std = np.sqrt(np.clip(np.diag(cov), 0, None))
            for _ in range(12):  # halve the step until the metric's cost falls
                trial = replace(prof, free=dict(zip(names, map(float, theta + step))))
                try:
                    c = noise.cost(self.residuals(trial))
                except PseudostepError:
                    c = math.inf
                if c < cost:
                    break
                step = step / 2
            else:
                break
            done = cost - c < 1e-6 * abs(cost) + 1e-9
            theta, cost, prof = theta + step, c, trial
            if done:
                break
        return prof, cost, {n: {"value": float(v), "std": float(s)} for n, v, s in zip(names, theta, std)}


def _gauss_newton(J: np.ndarray, e: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares step of the first ``p`` columns of ``J`` (the rest nuisance) on ``e``
    and its covariance (unit-variance ``e``)."""
    Q, R = np.linalg.qr(J)
    keep = np.abs(np.diag(R)) > 1e-10 * np.max(np.abs(np.diag(R)), initial=1e-300)
    full = np.zeros(J.shape[1])
    full[keep] = np.linalg.lstsq(J[:, keep], e, rcond=None)[0]
    info = J[:, keep].T @ J[:, keep]
    cov = np.full((J.shape[1], J.shape[1]), np.nan)
    cov[np.ix_(keep, keep)] = np.linalg.pinv(info)
    return full[:p], cov[:p, :p]


def _keep_meta(p: Profile, template: Profile) -> Profile:
    """Identified profile with the template's meta (delays, pseudo-inputs, periodic frequencies)."""
    return replace(p, meta={**dict(p.meta), **dict(template.meta)})


__all__ = ["Fitting"]

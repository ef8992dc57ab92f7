"""``FR``: the profile's state-space model fitted to the runs' frequency responses (``--method fr``).

CIFER's FRESPID -> COMPOSITE -> DERIVID as one estimator like the others: the composite frequency
responses of every input/output pair (:mod:`.response`) and the state-space fit to them by
Tischler's cost J over the resolved, coherent points (:mod:`.statespace`: Cramér-Rao and
insensitivity %, optional delays per input, optional pruning of what fails CIFER's gates).

What a frequency response cannot see, the initial state and trim offsets of each run, is fitted
afterwards for the time histories of the result (:func:`.verify.predict`, as in VERIFY), so that
``result_.modelled``, the plots and the fit table show the identified model's prediction of the
runs; :func:`.verify.verify` does the same on held-out runs.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...data.runs import Run
from ...errors import EstimationError
from ...model.linear import LinearModel
from ...model.subset import fix
from ..base import Estimator
from ..result import IdentificationResult, fit_metrics
from .bootstrap import N_DRAWS, bootstrap_covariance
from .estimate_error import estimate_error
from .response import MIN_COHERENCE, frequency_response
from .statespace import ResponseData, fit_frequency_responses
from .verify import output_weights, predict


class FR(Estimator):
    """Frequency-response fit of a profile's free parameters.

    Options: ``delays`` inputs that get an equivalent time delay (s, in ``[0, tau_max]``), added to
    the profile's declared ``meta.delays``; ``prune`` fix, one at a time, the parameters that fail
    CIFER's gates (insensitivity <= 10 %, Cramér-Rao <= 20 %) at their a priori values and re-fit;
    ``f_range`` (Hz) and ``n_freq`` the frequency grid of the responses (default from the runs);
    ``min_coherence`` of the points fitted; ``n_draws`` surrogate runs behind the standard errors
    (:mod:`.bootstrap`: the runs' own residual noise through the whole estimate and fit; 0: Tischler's
    bound from J alone, which takes correlated points as independent and is too small);
    ``bias_passes`` re-fits against the responses corrected for the estimate's own deterministic
    error (:func:`.estimate_error.estimate_error`; 0: none).
    """

    method = "fr"

    def __init__(self, profile, *, delays: tuple[str, ...] = (), tau_max: float = 0.3, prune: bool = False,
                 f_range: tuple[float, float] | None = None, n_freq: int = 80,
                 min_coherence: float = MIN_COHERENCE, n_draws: int = N_DRAWS, bias_passes: int = 2):
        super().__init__(profile)
        self.delays, self.tau_max, self.prune = delays, tau_max, prune
        self.f_range, self.n_freq, self.min_coherence = f_range, n_freq, min_coherence
        self.n_draws, self.bias_passes = n_draws, bias_passes

    def _validate(self) -> None:
        super()._validate()
        unknown = [u for u in self.delays if u not in self.profile_.input_names]
        if unknown:
            raise EstimationError(f"delays: {', '.join(unknown)} not an input of '{self.profile_.name}' "
                                  f"(inputs: {', '.join(self.profile_.input_names)})")
        if not self.tau_max > 0:
            raise EstimationError(f"tau_max must be positive, got {self.tau_max!r}")
        if self.n_draws != 0 and not self.n_draws >= 3:
            raise EstimationError(f"n_draws must be 0 or at least 3, got {self.n_draws!r}")
        if not 0 < self.min_coherence < 1:
            raise EstimationError(f"min_coherence must lie in (0, 1), got {self.min_coherence!r}")

    def nested(self, profile, *, bounds: bool = True, **_):
        """Refine's nested fits compare likelihoods of one structure: no pruning inside them (the
        structure is pruned once, before them: :meth:`determinable`); no bootstrap where only the
        estimate and its likelihood are used (``bounds=False``)."""
        return self.clone(profile, prune=False, n_draws=self.n_draws if bounds else 0)

    def determinable(self, profile, runs: list[Run]):
        """``profile`` with the parameters that fail CIFER's gates on these runs held at their a priori
        values, and their reasons: one pruned fit (no bootstrap, no correction passes: the gates are
        read from J's bound, as the pruning does). Refine fits and extends that structure; unpruned,
        its fits wander off along the undetermined directions (S 61 4-DOF: X_q -1487, Y_q -4581, not
        converged)."""
        fit = self.clone(profile, prune=True, n_draws=0, bias_passes=0).fit(runs).result_
        reasons = {d["parameter"]: d["reason"] for d in fit.info["pruned"]}
        return (fix(profile, list(reasons)) if reasons else profile), reasons

    def _fit(self, runs: list[Run]) -> IdentificationResult:
        p = self.profile_
        fr = frequency_response(runs, p.input_names, list(p.outputs), f_range=self.f_range, n_freq=self.n_freq)
        delays = tuple(u for u in self.delays if u not in fr.unmoved)
        data = ResponseData.from_response(fr)
        try:
            fit = fit_frequency_responses(p, data, delays=delays, tau_max=self.tau_max,
                                          min_coherence=self.min_coherence, prune=self.prune)
            fit, ratio, bias_line = self._debiased(fit, fr, data, runs, delays)
            standard_errors = "Cramér-Rao from the J fit (Gauss-Newton, residual variance; points taken as independent)"
            gain, bound = None, fit.std  # J's bound: points taken as independent
            if self.n_draws:
                fit, standard_errors, gain = self._bootstrap(fit, fr, ratio, runs, delays)
        except np.linalg.LinAlgError as exc:  # not the input's fault: said as what it is
            raise EstimationError(f"FR: numerical failure, not an input error: {exc} (a model with non-finite "
                                  "responses or predictions: the fit diverged along directions these runs do not "
                                  "determine; --prune holds them, or fly runs that move every input)") from None
        except ValueError as exc:
            raise EstimationError(f"FR: {exc}") from None
        model, predictions = self._predicted(fit, runs)
        if bias_line:
            fit.notes.append(bias_line)
        profile = model.profile
        scale, unit_notes = output_weights(model)
        resolution = fr.resolution_line(LinearModel(p))  # against the a priori modes: the ones planned for
        lines = [resolution] + fit.cost_lines() + fit.notes + [f"standard errors: {standard_errors}"]
        if fr.unmoved:
            lines.append(f"inputs no run moves (their pairs and delays left out): {', '.join(fr.unmoved)}")
        if fit.tau:
            lines.append("fitted delays: " + ", ".join(f"{u} {t:.4g} ± {fit.tau_std[u]:.2g} s"
                                                       for u, t in fit.tau.items()))
        info = {"frequency_domain": True, "converged": fit.converged, "iterations": fit.iterations,
                "stop": "least-squares tolerance" if fit.converged else "evaluation limit",
                "J": fit.J, "J_mean": fit.J_mean, "n_points": fit.n_points, "left_out": fit.left_out,
                "pruned": [{"parameter": n, "reason": r, "J_mean_after": j} for n, r, j in fit.pruned],
                "delays_fitted": fit.tau, "delays_std": fit.tau_std, "resolution": resolution,
                "windows_s": list(map(float, fr.windows)), "unmoved_inputs": fr.unmoved,
                "standard_errors": standard_errors, "n_draws": self.n_draws, "bias_passes": self.bias_passes,
                "ratio_gain": gain, "criterion": criterion(fit, bound if self.n_draws else None, delays),
                "report_lines": lines, "initial_states": [pr.x0.tolist() for pr in predictions],
                "zero_shifts": [pr.zero_shifts.tolist() for pr in predictions], "notes": unit_notes}
        result = IdentificationResult(
            self.method, profile, fit.theta, fit.std,
            fit_metrics(list(p.outputs), [pr.measured for pr in predictions], [pr.modelled for pr in predictions]),
            info, [r.source for r in runs], fit.covariance,
            [pr.time for pr in predictions], [pr.measured for pr in predictions], [pr.modelled for pr in predictions])
        result.info["accuracy"] = result.accuracy()
        return result

    def _debiased(self, fit, fr, data, runs, delays):
        """``fit`` re-fitted ``bias_passes`` times against the data freed of the response estimate's own
        error as the current model shows it (:mod:`.estimate_error`), the last ratio and its line."""
        ratio, line = np.ones_like(fr.H), ""
        for _ in range(self.bias_passes):
            _, predictions = self._predicted(fit, runs)
            ratio, line = estimate_error(fr, runs, predictions, fit, data.usable(self.min_coherence))
            refit = fit_frequency_responses(fit.profile, replace(data, H=data.H / ratio), theta0=fit.theta,
                                            delays=delays, tau_max=self.tau_max, min_coherence=self.min_coherence)
            fit = replace(refit, pruned=fit.pruned, left_out=fit.left_out,
                          notes=list(dict.fromkeys(fit.notes + refit.notes)))
        return fit, ratio, line

    def _predicted(self, fit, runs):
        """The identified model (fitted delays added to the declared ones) and its prediction of the runs."""
        p = self.profile_
        declared = {k: float(v) for k, v in dict(p.meta.get("delays", {})).items()}
        profile = fit.profile
        if fit.tau:
            meta = dict(profile.meta)
            meta["delays"] = {**declared, **{u: declared.get(u, 0.0) + t for u, t in fit.tau.items()}}
            profile = replace(profile, meta=meta)
        model = LinearModel(profile, fit.theta)
        scale, _ = output_weights(model)
        return model, [predict(model, r, scale) for r in runs]

    def _bootstrap(self, fit, fr, ratio, runs, delays):
        """``fit`` with the standard errors of :mod:`.bootstrap`, the line that says how they were had, and
        the factors (per parameter) by which the correction ratio's dependence on the estimate scaled them."""
        p = self.profile_
        _, predictions = self._predicted(fit, runs)

        def refit(draws):
            frb = frequency_response(draws, p.input_names, list(p.outputs), omega=fr.omega, windows=fr.windows)
            d = ResponseData.from_response(frb)
            f = fit_frequency_responses(fit.profile, replace(d, H=d.H / ratio), theta0=fit.theta,
                                        delays=delays, tau_max=self.tau_max, min_coherence=self.min_coherence,
                                        max_nfev=20)
            return np.concatenate([f.theta, [f.tau[u] for u in delays]])

        n = len(fit.theta)
        cov, failed = bootstrap_covariance(refit, n + len(delays), runs, predictions, list(p.outputs), p.input_names,
                                           self.n_draws)
        factor = None
        how = (f"residual bootstrap, {self.n_draws - failed} surrogate sets of runs (the prediction residual's part "
               f"not coherent with the inputs, phases randomised) through the response estimate and the fit; about "
               f"{100 / np.sqrt(2 * max(self.n_draws - failed - 1, 1)):.0f} % relative precision")
        if failed:
            how += f"; {failed} surrogate(s) not fitted or diverged, left out"
        sd = np.sqrt(np.diag(cov))
        if np.all(np.isfinite(sd)) and self.bias_passes:
            gain = self._fixed_point_gain(fit, fr, ratio, runs, delays, sd)
            if gain is not None:
                cov = gain @ cov @ gain.T
                factor = np.sqrt(np.diag(cov)) / sd
                how += ("; scaled for the correction ratio's own dependence on the estimate (held fixed in the "
                        f"surrogates; linearised fixed point: standard errors x {factor.min():.3g}-{factor.max():.3g})")
            else:
                how += "; the correction ratio's dependence on the estimate not determined (left out)"
        sd = np.sqrt(np.diag(cov))
        if not np.all(np.isfinite(sd)):
            how += "; not determined (too few surrogates fitted): NaN"
        return (replace(fit, std=sd[:n], covariance=cov[:n, :n],
                        tau_std={u: float(sd[n + k]) for k, u in enumerate(delays)}), how,
                None if factor is None else factor.tolist())

    def _fixed_point_gain(self, fit, fr, ratio, runs, delays, step):
        """``(I - S)^-1``: how the corrected estimate moves per unit move of a fit against a fixed ratio.

        The estimate is (to the passes' precision) a fixed point ``x = F(data, ratio(x))``; the
        surrogates refit with the ratio held, so they give ``dF/d data`` alone. ``S = dF/d x`` through
        the ratio, by finite differences of one standard error (``step``) per parameter: the ratio of
        the perturbed model's simulated runs through the same estimate, the data refitted against it.
        On the S 61 benchmark it enlarges the bound on ``L_p`` by 13 % on average; the paired check there
        (the whole procedure per surrogate against the fixed ratio) measured 7 % (benchmarks/frequency_fit.py).
        None when a perturbed model's prediction or refit fails."""
        n = len(fit.theta)
        data = ResponseData.from_response(fr)
        used = data.usable(self.min_coherence)

        def with_x(x):
            return replace(fit, theta=np.asarray(x[:n], float), tau={u: float(x[n + k]) for k, u in enumerate(delays)})

        def refit(r):
            f = fit_frequency_responses(fit.profile, replace(data, H=data.H / r), theta0=fit.theta, delays=delays,
                                        tau_max=self.tau_max, min_coherence=self.min_coherence, max_nfev=20)
            return np.concatenate([f.theta, [f.tau[u] for u in delays]])

        x0 = np.concatenate([fit.theta, [fit.tau[u] for u in delays]])
        try:
            base = refit(ratio)
            S = np.empty((len(x0), len(x0)))
            for k in range(len(x0)):
                x = x0.copy()
                x[k] += step[k] if k < n else min(step[k], self.tau_max - x[k]) or -step[k]
                _, predictions = self._predicted(with_x(x), runs)
                r, _ = estimate_error(fr, runs, predictions, with_x(x), used)
                S[:, k] = (refit(r) - base) / (x[k] - x0[k])
            gain = np.linalg.inv(np.eye(len(x0)) - S)
        except (ValueError, EstimationError, np.linalg.LinAlgError):
            return None
        return gain if np.all(np.isfinite(gain)) else None


def criterion(fit, bound: np.ndarray | None, delays) -> dict:
    """What the fit minimised, for nested comparisons
    (:meth:`~identify.estimators.result.IdentificationResult.compare_lr_test`): J's sum of squares,
    its residual variance per point, and per parameter the factor by which the standard error's
    variance exceeds J's bound ``bound`` (the bootstrap's over the bound that takes the points as
    independent: neighbouring points of a composite response are correlated and J's coherence
    weights are not their inverse variances; median 24 for X_q on the pitch case). Without a
    bootstrap (``bound`` None, ``n_draws=0``) the factor is unknown (NaN) and so is a likelihood
    ratio: J's drop over its dispersion alone, the points taken as independent, averaged 14-22 for
    a null effect (benchmarks/refine_fr.py)."""
    n_points = 2 * sum(fit.n_points.values())  # magnitude and phase of each point
    dispersion = fit.J_mean / max(n_points - len(fit.theta) - len(delays), 1)
    inflation = np.full(len(fit.theta), np.nan)
    if bound is not None:
        with np.errstate(divide="ignore", invalid="ignore"):
            inflation = (np.asarray(fit.std) / np.asarray(bound)) ** 2
    return {"kind": "frequency-response J", "cost": float(fit.J_mean), "points": n_points,
            "dispersion": float(dispersion), "inflation": dict(zip(fit.names, map(float, inflation)))}


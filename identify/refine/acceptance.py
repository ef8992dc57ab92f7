"""Whether a fitted candidate is kept: the checks after its score test, each giving a reason
('' when it passes).

* :func:`undetermined`: an estimate, bound or statistic that is not a finite number is no evidence
  (a NaN standard error once read as an infinite Wald statistic);
* :func:`failed_refit`: a re-fit that diverged or ended below the nested null is a failed fit,
  not a verdict;
* :func:`held_out_refusal`: the *choosing* data's prediction error in the test's noise-model
  metric, a one-sided test along the fitted change;
* :class:`ErrorChange` and :func:`error_refusal`: the error the user sees, the plain RMS error of
  the report's before/after table (simulation under output error, one-step prediction under filter
  error) on the held-out data: on the *judging* data it must fall, beyond its noise in the plain
  error's metric or in the noise model's; no error the report shows may rise beyond its noise.

Why both metrics. The noise-model metric is the efficient one (a generalised least-squares
metric: it discounts turbulence the model cannot predict) and it chooses; but a candidate it
favours can still raise the error the user reads (real lateral data: ``L_da_absda`` lowered the
whitened cost by 0.33 of 2443 while the validation simulation error rose from 0.0715 to 0.0818).
The plain error is what the report promises: it must fall, and rise nowhere beyond its noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..errors import PseudostepError
from .candidates import parameters_of
from .noise import NoiseModel

HELD_OUT_Z = float(stats.norm.isf(0.05))  # one-sided 5 %: the choosing data's test in the noise-model metric
IMPROVE_LEVEL = 0.05  # level of "lower beyond its noise" on the judging data (both metrics together)
WORSE_LEVEL = 0.05  # family level (Šidák over outputs and held-out data) of "worse beyond its noise"


def undetermined(params: dict, statistics: dict) -> str:
    """Why the fitted ``params`` ({name: {"value", "std"}}) or the ``statistics`` ({label: value})
    are not determined ('' if they are): a value, a bound or a statistic that is NaN or infinite,
    or a bound of zero, measures nothing and is never read as significance."""
    bad = [f"{n} = {v['value']:.4g} ± {v.get('std', math.nan):.3g}" for n, v in params.items()
           if not (math.isfinite(v["value"]) and math.isfinite(v.get("std", math.nan)) and v["std"] > 0)]
    bad += [f"{label} {value:.4g}" for label, value in statistics.items() if not math.isfinite(value)]
    return ("not determinable from these data (" + "; ".join(bad) + "): an undetermined bound is no "
            "significance") if bad else ""


def failed_refit(result, lr: float, null_cost: float, threshold: float, own: bool = False) -> str:
    """Why a re-fit is a failed fit, not a verdict ('' if it is not): it diverged, or its likelihood
    is below the nested null's by more than the test's threshold (the extended model contains the
    null, so a re-fit that found its optimum cannot be worse: it went astray; seen once as a
    likelihood ratio of -5.9e6), or the ratio is not finite."""
    stop = str(result.info.get("stop", ""))
    if not result.converged and stop.startswith(("diverged", "stalled")):
        return f"re-fit failed ({stop}): no likelihood ratio"
    if not math.isfinite(lr) and own:
        return (f"the {result.method.upper()} estimator's likelihood ratio is not determined (its criterion's "
                f"points are correlated and the factor that says how much is unknown, e.g. without its bootstrap)")
    if not math.isfinite(lr):
        return "re-fit failed (its likelihood is not finite): no likelihood ratio"
    if lr < -max(threshold, 1e-9 * abs(null_cost)):
        return (f"re-fit failed: its likelihood is below the nested null's (ratio {lr:.3g}), so it did not "
                f"find its optimum; no likelihood ratio")
    return ""


def held_out_refusal(held: dict, change: dict, data: str, label: str) -> str:
    """Refusal unless the model with the effect predicts held-out ``data`` better in the test's
    noise-model metric, and better by more than a null effect would in 5 % of cases ('' if it
    passes).

    The held-out data fit nothing: the effect's parameters come from the fitting runs, so the
    prediction change ``d`` there is a fixed direction, whatever the number of parameters. With
    the whitened null residual ``e`` (unit white noise under the null) the cost change is
    ``D = 2 <e, d> - |d|^2``: a null effect makes it ``N(-s^2, 4 s^2)``, ``s^2 = |d|^2`` (the
    cost of the change alone, ``change[data]``). The check asks ``<e, d> / s > z_0.95``, the
    one-sided 5 % test that the held-out data move the way the effect says, i.e.
    ``D > 2 z s - s^2``, and ``D > 0``. Its level is 5 % for any ``s`` and any parameter count."""
    if data not in held:
        return ""
    before, after = held[data]
    s = math.sqrt(max(change.get(data, 0.0), 0.0))
    need = max(0.0, 2.0 * HELD_OUT_Z * s - s * s)
    if before - after > need:
        return ""
    return (f"did not lower the prediction error on the {label} data by more than {need:.3g} (noise-model cost "
            f"{before:.6g} -> {after:.6g}; the one-sided 5 % bar 2 z s - s^2 of a change of size s^2 = {s * s:.3g})")


def second_attempt(fitting, method: str, cand, p, noise, null_cost: float, threshold: float, first: tuple,
                   held_data: list[str]):
    """A re-fit that ended below the nested null in the test's metric (``first`` = its
    ``(profile, result, parameters, lr, reason)``) gets a second look, said on screen and
    recorded (``Step.attempts``): a fit in the test's metric itself from the warm start (the
    current estimates, the new parameters at their null value,
    :meth:`~identify.refine.fitting.Fitting.refit_in_metric`); where that finds a better
    likelihood than the null, the estimator is restarted from that point. Its fit is kept if it
    no longer ends below the null; else the refusal says that the estimator's optimum and the
    test's metric disagree (seen: output error on strongly coloured residuals, whose white
    likelihood has its optimum elsewhere), not that the fit lost its way.
    Returns ``(profile, result, parameters, lr, reason, attempts)``."""
    new_p, result, params, lr, failed = first
    attempts = [{"fit": f"{method}, warm start", "parameters": params, "lr_statistic": float(lr)}]
    start = cand.profile(p)
    # a searched structure (a delay: its tau in meta, not free; a lag's other state): no null start to re-fit
    if set(start.free) != set(new_p.free) or not set(cand.params) <= set(start.free):
        return new_p, result, params, lr, failed, attempts
    fitting.say(f"  the {method} re-fit ends below the nested null in the test's metric (ratio {lr:.3g}): "
                "re-fitting in that metric, then restarting the estimator from there")
    check_p, check_cost, check_params = fitting.refit_in_metric(start, noise)
    check_lr = null_cost - check_cost
    attempts.append({"fit": "the test's metric, warm start", "parameters": _only(check_params, cand.params),
                     "lr_statistic": float(check_lr)})
    if not check_lr > 0:
        return new_p, result, params, lr, failed, attempts
    try:
        again_p, again = fitting.refit(check_p, p)
        [fitting.prediction(again_p, d) for d in held_data]  # as every option: not divergent there
    except PseudostepError as exc:
        attempts.append({"fit": f"{method}, restarted from the test's metric's fit", "error": str(exc)})
        return new_p, result, params, lr, failed, attempts
    again_params = parameters_of(again, cand.params)
    again_lr = null_cost - noise.cost(fitting.residuals(again_p))
    attempts.append({"fit": f"{method}, restarted from the test's metric's fit", "parameters": again_params,
                     "lr_statistic": float(again_lr)})
    again_failed = failed_refit(again, again_lr, null_cost, threshold)
    fitting.say(f"  restarted {method} re-fit: ratio {again_lr:.3g}" + (" (kept)" if not again_failed else ""))
    if not again_failed:
        return again_p, again, again_params, again_lr, "", attempts
    shown = ", ".join(f"{k} = {v['value']:.3g}" for k, v in attempts[1]["parameters"].items())
    mine = ", ".join(f"{k} = {v['value']:.3g}" for k, v in params.items())
    reason = (f"the {method} re-fit ({mine}) ends below the nested null in the test's noise-model metric "
              f"(ratio {lr:.3g}; restarted from the metric's own fit, {again_lr:.3g}), where a fit in that "
              f"metric finds {shown} (ratio {check_lr:.3g}): the {method} estimator's likelihood and the "
              f"test's metric disagree about this effect; not added")
    return new_p, result, params, float("nan"), reason, attempts



def _only(params: dict, names) -> dict:
    return {k: v for k, v in params.items() if k in names}


@dataclass
class ErrorChange:
    """The change an effect makes to the plain squared error of one held-out data set, in the
    report's units: ``gain`` = ``sum_y sum_t (e0^2 - e1^2) / scale_y^2`` (positive: the error
    fell; ``before`` the same sum for the model without it), ``sd`` its standard deviation under
    the residual noise; per output the same without the scale (``outputs``: y -> (gain, sd))."""

    before: float
    gain: float
    sd: float
    outputs: dict = field(default_factory=dict)

    @property
    def z(self) -> float:
        return self.gain / self.sd if self.sd > 0 else (0.0 if self.gain == 0 else math.copysign(math.inf, self.gain))

    def to_dict(self) -> dict:
        return {"before": self.before, "gain": self.gain, "sd": self.sd, "z": self.z,
                "outputs": {y: {"gain": g, "sd": s} for y, (g, s) in self.outputs.items()}}


def error_change(before: list[np.ndarray], after: list[np.ndarray], outputs, scale: np.ndarray,
                 noise: NoiseModel) -> ErrorChange:
    """:class:`ErrorChange` of held-out residuals ``before`` and ``after`` (per run (N_r, ny)).

    A paired test on the same samples: with ``d = e0 - e1`` the change of the prediction (fixed:
    the effect's parameters come from the fitting runs), ``e0^2 - e1^2 = 2 e0 d - d^2``, so the
    gain's noise is that of ``2 <e0, d / scale^2>``: ``Var = 4 kappa^2 Var(<e, g>)`` for the
    residual noise ``e`` (``noise``, a vector autoregression fitted to the fitting runs' residuals
    of the model with the effect, :meth:`NoiseModel.variance_along`: the residual's
    autocorrelation across samples and outputs, as the samples are not independent), ``kappa^2``
    the held-out data's own noise level in that model's units when larger (a noisier validation
    flight), from the whitened ``after`` residuals."""
    w2 = 1.0 / scale ** 2
    ny = len(outputs)
    whitened = [noise.whiten(e) for e in after]
    count = sum(w.size for w in whitened)
    kappa2 = max(1.0, sum(float(np.sum(w ** 2)) for w in whitened) / count) if count else 1.0
    # one weighting per output (its own change, unscaled) and the overall one (scaled): one pass
    g = [np.concatenate([(b - a)[:, :, None] * np.eye(ny)[None], ((b - a) * w2)[:, :, None]], axis=2)
         for b, a in zip(before, after)]
    sd = 2.0 * np.sqrt(kappa2 * np.maximum(noise.variance_along(g), 0.0))
    gains = sum(np.sum(b ** 2 - a ** 2, axis=0) for b, a in zip(before, after))
    per = {y: (float(gains[j]), float(sd[j])) for j, y in enumerate(outputs)}
    return ErrorChange(float(sum(np.sum(b ** 2 * w2) for b in before)), float(gains @ w2), float(sd[-1]), per)


def error_refusal(changes: dict, labels: dict, judge: str | None = None, held: dict | None = None,
                  spread: dict | None = None) -> str:
    """Why an effect is refused by the held-out data sets ({data: :class:`ErrorChange`}; '' if it
    is not).

    No error the report shows may rise beyond its noise (one-sided, Šidák over them at
    ``WORSE_LEVEL``): the overall error of every held-out data set and each output's on the
    ``judge`` data (the validation columns of the report's table; the choosing data's outputs are
    not shown, and with several effects missing one of them added alone can move an output there
    that the next one puts right: a true delay on theta_0 of four missing). On the ``judge`` data the
    overall plain error (the report's validation error) must fall, and the fall must be beyond its
    noise in one of two metrics, each one-sided at half of ``IMPROVE_LEVEL`` (so 5 % together):
    the plain error's, overall or for an output (Šidák over them: a real effect of one output's
    equation can leave the overall error, dominated by another missing effect, unchanged), or the
    noise-model cost's (``held``: before and after; ``spread``: the change's own cost ``s^2``, so
    the fall's spread is ``2 s``), where turbulence the model cannot predict swamps the plain error
    but not the effect (a true 0.08 s delay on a hovering S 61 with a pilot in gusts: the judging
    data's simulation error 0.6 % lower, 0.2 of its noise; the noise-model cost 460 lower, 11 of its
    spread). The former judging check, ``D > 2 z s - s^2``, passed any positive ``D`` once the
    change was large (``s > 3.29``): 0.33 of a cost of 2443 confirmed an effect that raised the
    validation simulation error by 14 %."""
    shown = {data: [("overall", c.gain, c.sd)] + ([(y, g, s) for y, (g, s) in c.outputs.items()] if data == judge
                                                  else []) for data, c in changes.items()}
    z_worse = float(stats.norm.isf(1.0 - (1.0 - WORSE_LEVEL) ** (1.0 / max(sum(map(len, shown.values())), 1))))
    for data, numbers in shown.items():
        for name, gain, sd in numbers:
            if sd > 0 and -gain > z_worse * sd:
                return (f"makes the {labels[data]} data's {name} error worse beyond its noise (squared error "
                        f"+{-gain:.4g}, {-gain / sd:.3g} standard deviations of a paired test; the bar "
                        f"{z_worse:.3g})")
    if judge not in changes:
        return ""
    c = changes[judge]
    rel = math.sqrt(max(c.before - c.gain, 0.0) / c.before) - 1.0 if c.before > 0 else 0.0
    if not c.gain > 0:
        return f"does not lower the {labels[judge]} data's error (the report's validation error: {100 * rel:+.3g} %)"
    level = IMPROVE_LEVEL / 2
    z_plain = float(stats.norm.isf(1.0 - (1.0 - level) ** (1.0 / (1 + len(c.outputs)))))
    if c.gain > z_plain * c.sd or any(g > z_plain * s for g, s in c.outputs.values()):
        return ""
    z_noise = float(stats.norm.isf(level))
    fall, s2 = held[judge][0] - held[judge][1], max(spread[judge], 0.0)
    if s2 > 0 and fall > z_noise * 2.0 * math.sqrt(s2):
        return ""
    return (f"lowers the {labels[judge]} data's error ({100 * rel:+.3g} %) but not beyond its noise: {c.z:.3g} "
            f"standard deviations of a paired test of the plain error (the bar {z_plain:.3g}, overall or any output), "
            f"{fall / (2 * math.sqrt(s2)) if s2 > 0 else 0.0:.3g} of the noise-model cost (the bar {z_noise:.3g})")


__all__ = ["undetermined", "failed_refit", "second_attempt", "held_out_refusal", "ErrorChange", "error_change",
           "error_refusal", "HELD_OUT_Z", "IMPROVE_LEVEL", "WORSE_LEVEL"]

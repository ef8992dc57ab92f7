"""Fit and check: one estimator on prepared runs, the checks a result carries, the files written.

A profile's state-built terms (a refined profile's ``q|q|``) are taken from the model's simulated
states where the estimator simulates (output error), as refine fitted them: measured states would
put their noise into the terms (an errors-in-variables bias), and the estimates refine reported
would not be reproduced. The checks go into the result's ``info`` before it is returned:
``frequency_cost_J`` (J of the identified and the a priori model against the runs' frequency
responses) and, with held-out runs, ``verify`` (VERIFY: the identified model's prediction of runs
that took no part).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Estimation:
    """``result`` the complete :class:`~identify.estimators.result.IdentificationResult`; ``runs``
    the prepared runs fitted; ``cost_text`` the frequency-domain cost lines; ``verification``
    VERIFY's (None without held-out runs)."""

    result: object
    runs: list
    cost_text: str
    verification: object = None
    notes: list[str] = field(default_factory=list)

    def text(self) -> str:
        """The summary, the frequency-response fit's report, J and VERIFY, as printed."""
        parts = [self.result.summary()]
        if "report_lines" in self.result.info:  # the frequency-response fit's J, pruning and delays
            parts.append("\n".join(self.result.info["report_lines"]))
        parts.append(self.cost_text)
        if self.verification is not None:
            parts.append("\n".join(self.verification.lines()))
        return "\n\n".join(parts)

    def save(self, out: str | Path, plots: bool = False) -> list[str]:
        """``result.json``, ``summary.txt`` (what :meth:`text` says), ``identified_profile.toml``,
        ``time_histories.npz``; ``plots``: the time histories and residuals drawn; VERIFY's plot
        with held-out runs. Returns the names written."""
        result = self.result
        out = result.save(out)
        (out / "summary.txt").write_text(self.text() + "\n")
        written = ["result.json", "summary.txt", "identified_profile.toml"] + (["time_histories.npz"] if result.time else [])
        if plots:  # on request: drawing them costs three times the fit itself (benchmarks/ml_speed.py)
            from ..estimators.plots import save_plots
            written += [p.name for p in save_plots(result, out, self.runs)]
        if self.verification is not None:
            from ..estimators.frequency.verify import plot_verification
            from ..model.profile import output_units
            written.append(plot_verification(self.verification, out / "verify.png", output_units(result.profile)).name)
        return written


def estimate(estimator, runs: list, held: list | None = None) -> Estimation:
    """``estimator`` fitted to the prepared ``runs``, checked (J; VERIFY on ``held``)."""
    from ..estimators.frequency.response import cost_report
    from ..model.linear import LinearModel

    result = fit(estimator, runs)
    text, result.info["frequency_cost_J"] = cost_report(runs, {"identified": result.model,
                                                              "a priori": LinearModel(profile_of(estimator))})
    verification = None
    if held:
        from ..estimators.frequency.verify import verify
        verification = verify(result.model, held)
        result.info["verify"] = verification.to_dict()
    return Estimation(result, runs, text, verification)


def fit(estimator, runs: list):
    """The estimator's result on ``runs``; a profile's state-built terms from the model's simulated
    states where the estimator simulates (see the module notes), re-fitted until they settle."""
    from ..estimators.prediction import fit_state_terms, state_terms
    from ..model.linear import LinearModel

    profile = profile_of(estimator)
    terms = state_terms(profile)
    if not (terms and estimator.simulates_state_terms):
        return estimator.fit(runs).result_
    # the estimator's own segments, fixed so that the terms are predicted over the same ones
    segment = estimator.prediction_segment(LinearModel(profile), max(r.duration for r in runs))
    print(f"note: {', '.join(terms)} built from the model's simulated states (re-fitted until "
          f"the estimates settle)", file=sys.stderr)
    return fit_state_terms(lambda p: estimator.nested(p, segment=segment), profile, runs, segment=segment)[1]


def profile_of(estimator):
    """The estimator's a priori profile, loaded (it may hold a path or a bundled name)."""
    from ..model.profile import Profile, load_profile

    return estimator.profile if isinstance(estimator.profile, Profile) else load_profile(estimator.profile)

"""Write a refinement's evidence: ``refine.json``, ``final_profile.toml``, ``report.md`` and plots.

``refine.json`` holds ``steps`` (each with ``effect``, ``target``, ``parameters`` {name: {value,
std}}, ``statistic``, ``threshold``, ``dof``, ``p_value``, ``lr_statistic``, ``error_before``,
``error_after``), the ``rejected`` candidates with the reason, ``pruned`` (``--prune``: the
backward elimination's decisions, :class:`identify.structure.prune.Prune`), top-level ``error_before`` /
``error_after`` ({"fit": {output: rms, ..., "overall"}, "validation": ...}), the residual
``diagnostics`` before and after, ``frequency_cost_J`` (Tischler's frequency-domain fit cost of
the declared model's fit and of the refined model against the fit runs' frequency responses, per
input-output pair and the mean: :func:`identify.estimators.frequency.response.cost_report`), ``final_profile`` (the
refined model as profile TOML text) and ``provenance`` (the fit and held-out runs' files, hashes, reading
and processing: :func:`identify.data.provenance.provenance`), whoever calls :func:`write`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..data.provenance import provenance, provenance_lines
from ..estimators.result import jsonable
from ..estimators.frequency.response import cost_report, format_cost
from ..model.profile import output_units
from .diagnostics import spectral_peak
from .loop import Refine


def to_dict(r: Refine) -> dict:
    """Everything ``refine.json`` holds (plain JSON types)."""
    return jsonable({
        "profile": r.declared_.name,
        "method": r.estimator_.method,
        "estimator": {"class": type(r.estimator_).__name__,
                      **{k: v for k, v in r.estimator_.get_params().items() if k != "profile" and not callable(v)}},
        "runs": [run.source for run in r.runs_],
        "validation_runs": [run.source for run in r.validation_runs_],
        "data": r.data_,
        "notes": r.notes_,
        "undetermined_scores": r.undetermined_scores_,
        "alpha": r.alpha,
        "coloured_tests": r.coloured,
        "noise_model_orders": r.noise_orders_,
        "noise_model_white": r.noise_white_,
        "tries": r.tries_,
        "pruned": [vars(d) for d in getattr(r, "pruned_", [])],
        "evaluations": r.evaluations_,
        "catalogue": list(r.kinds_),
        "unconverged_fits": r.unconverged_,
        "undeterminable": dict(getattr(r, "undeterminable_", {})),
        "estimator_advice": r.initial_result_.info.get("estimator_advice"),
        "segment_s": r.segment_ if np.isfinite(r.segment_) else None,
        "nothing_found": r.nothing_found,
        "stopped": r.stopped_,
        "steps": [s.to_dict() for s in r.steps_],
        "rejected": [s.to_dict() for s in r.rejected_],
        "error_before": r.error_before_,
        "error_after": r.error_after_,
        "diagnostics": r.diagnostics_,
        "frequency_cost_J": cost_report(r.runs_, {"before": r.initial_result_.model, "after": r.result_.model})[1],
        "last_scores": [t.to_dict() for t in sorted(r.last_scores_, key=lambda t: t.log_p)[:10]],
        "poorly_identified": _poorly_identified(r),
        "final_parameters": {n: {"value": float(v), "std": float(s)}
                             for n, v, s in zip(r.result_.names, r.result_.theta, r.result_.std)},
        "final_profile": r.profile_.to_toml(),
        "provenance": provenance(list(r.runs_) + list(r.validation_runs_)),
    })


def _poorly_identified(r: Refine) -> list[dict]:
    """Parameters of the final model whose standard error exceeds half their value (or that no
    input excites: std inf), as the final result gives them."""
    out = []
    for n, v, s in zip(r.result_.names, r.result_.theta, r.result_.std):
        if not np.isfinite(s) or (v != 0 and s > 0.5 * abs(v)):
            out.append({"name": n, "value": float(v), "std": float(s)})
    return out


def _value_std(p: dict) -> str:
    """```name` = value ± std`` of a parameter as ``to_dict`` gives it; a standard error that is
    not determined (None in JSON: e.g. the final fit did not converge) said so, not a crash."""
    std = p["std"]
    told = f"{std:.2g}" if std is not None and np.isfinite(std) else "(standard error not determined)"
    return f"`{p['name']}` = {p['value']:.4g} ± {told}"


def write(r: Refine, outdir: str | Path, plots: bool = True) -> Path:
    """Write ``refine.json``, ``final_profile.toml``, ``report.md`` (and PNG plots) into ``outdir``."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    data = to_dict(r)
    (outdir / "refine.json").write_text(json.dumps(data, indent=2))
    r.profile_.save(outdir / "final_profile.toml")
    figures = _plots(r, outdir) if plots else []
    (outdir / "report.md").write_text(markdown(r, data, figures))
    return outdir


def _fmt_err(err: dict) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in err.items())


def _error_table(before: dict, after: dict, outputs) -> list[str]:
    rows = ["| output | fit before | fit after | validation before | validation after |",
            "| --- | ---: | ---: | ---: | ---: |"]
    for y in list(outputs) + ["overall"]:
        vb = before.get("validation", {}).get(y)
        va = after.get("validation", {}).get(y)
        cell = lambda v: "–" if v is None else f"{v:.4g}"  # noqa: E731
        rows.append(f"| {y} | {cell(before['fit'].get(y))} | {cell(after['fit'].get(y))} | "
                    f"{cell(vb)} | {cell(va)} |")
    return rows


def _names(runs: list[str]) -> str:
    return ", ".join(runs) or "none"


def markdown(r: Refine, data: dict, figures: list[str]) -> str:
    """The human report: verdict, data roles, errors before/after, each try's evidence,
    diagnostics, plots."""
    outputs = list(r.declared_.outputs)
    d = data["data"]
    lines = [f"# Model refinement: {r.declared_.name}", ""]
    orders = ", ".join(f"{o}" + ("" if w else " (its cap: innovations still not white, the tests outside their "
                                        "validity)")
                       for o, w in zip(r.noise_orders_, r.noise_white_))
    lines += ["## Data and tests", "",
              f"- **fit** (estimation, score and likelihood-ratio tests): {_names(d['fit'])}",
              f"- **choosing** (every try's held-out check, the choice between a delay and a lag): "
              f"{_names(d['choosing'])}",
              f"- **judging** (only confirms a candidate the rest has chosen, once; the `validation` "
              f"errors below): {_names(d['validation'])}",
              f"- method {data['method']}; candidates of {', '.join(r.kinds_)}; family-wise false-alarm "
              f"level alpha = {r.alpha} per step (Šidák over all candidates tested)",
              "- tests " + ("valid for coloured residuals: score and likelihood-ratio statistics in the metric "
                            "of a vector autoregressive noise model of the residuals (orders per step: "
                            f"{orders or '-'})" if r.coloured else
                            "for white residuals (`coloured=False`)"),
              f"- {r.tries_} candidate(s) tried: {len(r.steps_)} accepted, {len(r.rejected_)} rejected; "
              f"stopped: {r.stopped_}"]
    lines += [f"- **note**: {note}" for note in r.notes_]
    lines += [f"- **warning**: {len(r.unconverged_)} fit(s) did not converge: " + "; ".join(r.unconverged_)
              ] if r.unconverged_ else []
    lines += ["- held at a priori values (the estimator cannot determine them from the fit runs): "
              + "; ".join(f"`{n}` ({why})" for n, why in r.undeterminable_.items())
              ] if getattr(r, "undeterminable_", None) else []
    lines.append("")
    if r.nothing_found:
        lines.append("**Nothing found**: no candidate effect is significant and confirmed; the residuals are "
                     "consistent with the noise model at this level. `steps` is empty.")
    else:
        lines.append(f"**{len(r.steps_)} effect(s) added**: " + "; ".join(
            f"{s.effect} on {s.target}" for s in r.steps_) + ".")
    poor = data["poorly_identified"]
    if poor:
        lines += ["", "**Poorly identified** in the final model (standard error above half the value): " +
                  ", ".join(_value_std(p) for p in poor) +
                  ". An input that excites them: `python -m signaldesign band` / `design`."]
    lines += ["", "## Error before and after", "",
              "RMS error per output; `overall` is the RMS over outputs of RMS / std of the measured output; "
              "validation = the judging data.", ""]
    lines += _error_table(r.error_before_, r.error_after_, outputs)
    cost = data["frequency_cost_J"]
    lines += ["", "Frequency-domain fit cost J on the fit runs, before (the declared model's fit) and after:", "",
              "```", cost["not_computed"] if "not_computed" in cost else
              "\n".join(format_cost(c, f"model {label} refinement") for label, c in cost.items()), "```"]
    for i, s in enumerate(r.steps_, start=1):
        lines += ["", f"## Step {i}: {s.effect} on {s.target}", ""] + _evidence(s)
    if r.rejected_:
        lines += ["", "## Rejected candidates", ""]
        for s in r.rejected_:
            lines += [f"### {s.effect} on {s.target}: {s.reason}", ""] + _evidence(s) + [""]
    if getattr(r, "pruned_", None):
        lines += ["", "## Backward elimination (--prune)", "",
                  "| parameter | decision | abs(estimate)/std | held-out error before | after | why |",
                  "| --- | --- | --- | --- | --- | --- |"]
        lines += [f"| {d.term} | {'fixed at 0' if d.action == 'dropped' else 'kept'} | {d.statistic:.3g} | "
                  f"{d.before:.4g} | {d.after:.4g} | {d.note} |" for d in r.pruned_]
    lines += ["", "## Residual diagnostics", "",
              "| output | Ljung-Box p before | after | trend t before | after | peak Hz / p before | after |",
              "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    b, a = r.diagnostics_["before"], r.diagnostics_["after"]
    for y in outputs:
        lines.append(f"| {y} | {b[y]['ljung_box_p']:.3g} | {a[y]['ljung_box_p']:.3g} | {b[y]['t_trend']:.3g} | "
                     f"{a[y]['t_trend']:.3g} | {b[y]['peak_hz']:.3g} / {b[y]['peak_p']:.2g} | "
                     f"{a[y]['peak_hz']:.3g} / {a[y]['peak_p']:.2g} |")
    if figures:
        lines += ["", "## Plots", ""] + [f"![{f}]({f})" for f in figures]
    # the final fit starts from the previous step's estimates; the column shows the declared a priori
    # values (an effect refine added has none)
    declared = {**r.declared_.fixed, **r.declared_.free}
    lines += ["", "## Final identification", "", r.result_.markdown(start=declared, start_label="a priori (declared)")]
    lines += ["", "## Final model", "", "Written to `final_profile.toml`:", "", "```toml",
              r.profile_.to_toml().rstrip(), "```", ""]
    lines += ["## Data provenance", "", "```", *provenance_lines(data["provenance"]), "```", ""]
    return "\n".join(lines)


def _evidence(s) -> list[str]:
    """One try's evidence as Markdown list items."""
    lines = [f"- score statistic {s.statistic:.4g} > threshold {s.threshold:.4g} "
             f"(chi-square, {s.dof} dof, p = {s.p_value:.3g}, {s.tested} candidates tested; noise model: "
             f"{'of the residuals' if s.metric == 'residual' else 'of the residuals without this candidate'}, "
             f"order {s.noise_order})"]
    if s.why:
        lines.append(f"- physical reason: {s.why}")
    lines.append(f"- likelihood ratio of the re-fit {s.lr_statistic:.4g}"
                 + (f" (the estimator's own criterion: {s.lr_criterion})" if s.lr_criterion else "")
                 + "; Wald statistic of the estimate "
                 f"(coloured-residual bounds) {s.wald:.4g}")
    for name, v in s.parameters.items():
        lines.append(f"- `{name}` = {v['value']:.6g} ± {v['std']:.3g}" + (
            f" (± {v['std_profile']:.3g} from the profile's curvature alone, the other parameters' errors "
            f"left out)" if "std_profile" in v and v["std_profile"] != v["std"] else ""))
    for data, (b, a) in s.held_out.items():
        lines.append(f"- prediction error on the {'judging' if data == 'validation' else 'choosing'} data "
                     f"(noise-model cost) {b:.6g} -> {a:.6g}")
    for data, c in s.error_change.items():
        lines.append(f"- plain squared error on the {'judging' if data == 'validation' else 'choosing'} data "
                     f"(the report's error, normalised) lowered by {c['gain']:.4g} ± {c['sd']:.3g} ({c['z']:.3g} "
                     f"standard deviations of the paired test)")
    if not s.noise_white:
        lines.append("- the test's noise model reached its order cap (innovations not white): the tests are outside "
                     "their validity, the held-out data decided")
    lines.append(f"- error before: fit {_fmt_err(s.error_before['fit'])}")
    lines.append(f"- error after: fit {_fmt_err(s.error_after['fit'])}")
    if "validation" in s.error_before:
        lines.append(f"- judging data RMS (overall) before {s.error_before['validation']['overall']:.4g}, after "
                     f"{s.error_after['validation']['overall']:.4g}")
    if s.runner_up:
        lines.append("- next candidates: " + ", ".join(
            f"{c['effect']} on {c['target']} ({c['statistic']:.3g} / {c['threshold']:.3g})" for c in s.runner_up))
    return lines


def _plots(r: Refine, outdir: Path) -> list[str]:
    outputs = list(r.declared_.outputs)
    units = output_units(r.declared_)
    ev = r.final_evaluation_
    before, after = ev["before"].residuals, ev["fit"].residuals
    _before_after(ev["time"][0], before[0], after[0], [f"{y} [{units[y] or '-'}]" for y in outputs], "time [s]",
                  "residuals (first fit run)", outdir / "residuals.png", log=False)
    dt = r.runs_[0].dt
    sb, sa = spectral_peak(before, dt), spectral_peak(after, dt)
    # one-sided power spectral density (scipy's periodogram): output unit squared per Hz
    _before_after(sb["freqs"][1:], sb["psd"][1:], sa["psd"][1:], [f"{y} [({units[y] or '-'})²/Hz]" for y in outputs],
                  "frequency [Hz]", "residual power spectral density (periodogram, fit runs averaged)",
                  outdir / "residual_spectra.png", log=True)
    return ["residuals.png", "residual_spectra.png"]


def _before_after(x, before, after, outputs, xlabel: str, title: str, path: Path, log: bool) -> None:
    """One panel per output, before and after refinement; ``before``/``after`` (N, ny); drawn on
    an Agg canvas (no pyplot state)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ny = len(outputs)
    fig = Figure(figsize=(8, 1.6 * ny + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(ny, 1, sharex=True, squeeze=False)
    for j, y in enumerate(outputs):
        ax = axes[j, 0]
        draw = ax.loglog if log else ax.plot  # spectra: log frequency and log power
        draw(x, before[:, j], lw=0.7, label="before")
        draw(x, after[:, j], lw=0.7, label="after")
        ax.set_ylabel(y, fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel(xlabel)
    fig.suptitle(title)
    fig.savefig(path, dpi=90)

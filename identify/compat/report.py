"""What ``identify compat`` writes: corrected runs, ``compat.json`` and ``report.md``.

The corrected runs are CSV run files (SI units, every channel of the input run, the estimated
sensor errors removed, the corrections in their metadata), ready for ``identify estimate`` and
``identify refine``. ``compat.json`` holds the estimates with their bounds, the selection's steps
(score, threshold), the residual RMS before and after and the data's provenance; ``report.md``
says the same for a reader, with a plot of the residuals before and after when asked for.
"""
from __future__ import annotations

import json
from pathlib import Path


from ..data.provenance import provenance, provenance_lines
from ..data.runs import Run
from ..estimators.result import dumps
from .fit import CompatResult


def corrected_names(runs: list[Run]) -> list[str]:
    """``corrected_<file stem>.csv`` per run (``_<k>`` added where a file gave several runs)."""
    stems = [Path(r.source.split(" [")[0]).stem or "run" for r in runs]
    return [f"corrected_{s}" + (f"_{stems[:i].count(s) + 1}" if stems.count(s) > 1 else "") + ".csv"
            for i, s in enumerate(stems)]


def write(result: CompatResult, runs: list[Run], outdir, plots: bool = False) -> list[str]:
    """Write everything into ``outdir``; returns the names written."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    names = corrected_names(runs)
    for run, name in zip(result.corrected(runs), names):
        run.to_csv(out / name)
    data = dict(result.to_dict(), corrected_runs=names, provenance=provenance(runs))
    (out / "compat.json").write_text(dumps(data))
    figures = [_plot(result, out / "residuals_before_after.png")] if plots else []
    (out / "report.md").write_text(markdown(result, names, figures, data["provenance"]))
    return ["compat.json", "report.md", *names, *figures]


def markdown(result: CompatResult, names: list[str], figures: list[str], prov: dict) -> str:
    lines = ["# Flight-path reconstruction", "",
             f"Runs: {', '.join(f'`{r}`' for r in result.runs)}. Outputs compared with the kinematics: "
             f"{', '.join(result.outputs)}.", "",
             f"Sensor errors were added one at a time by score tests (family-wise level {result.alpha:g}, "
             "Šidák over the candidates left at each step; the residuals' own covariance in the score).", "",
             "| step | sensor error | score | threshold |", "| ---: | --- | ---: | ---: |"]
    lines += [f"| {s['step']} | `{s['error']}` | {s['statistic']:.4g} | {s['threshold']:.4g} |" for s in result.steps]
    if not result.steps:
        lines.append("| - | none: the measurements agree with the kinematics within their noise | | |")
    lines += ["", "## Estimated sensor errors", "",
              "Standard errors: the outputs' noise, corrected for coloured residuals (Morelli & Klein), and "
              "the inertial sensors' noise integrated through the kinematics (errors in the variables; noise std "
              + ", ".join(f"{c} {v:.3g} ({result.info.get('input_noise_source', {}).get(c, '')})"
                          for c, v in result.info.get("input_noise_std", {}).items()) + ").", "",
              "| sensor error | estimate | std error | unit | in degrees |", "| --- | ---: | ---: | --- | ---: |"]
    for name, p in result.parameters().items():
        deg = f"{p['value_deg']:.4g} ± {p['std_deg']:.2g}" if "value_deg" in p else ""
        lines.append(f"| `{name}` | {p['value']:.6g} | {p['std']:.3g} | {p['unit']} | {deg} |")
    lines += ["", f"Convergence: {'converged' if result.converged else '**NOT CONVERGED**'} after "
              f"{result.iterations} iterations ({result.stop}).", "",
              "## Residuals before and after", "",
              "Before: the kinematics with no sensor error (initial states fitted); after: with the errors above.", "",
              "| output | RMS before | RMS after |", "| --- | ---: | ---: |"]
    lines += [f"| {y} | {result.rms_before[y]:.4g} | {result.rms_after[y]:.4g} |" for y in result.outputs]
    lines += [""] + [f"![residuals before and after]({f})" for f in figures]
    lines += ["", "## Corrected runs", "", ", ".join(f"`{n}`" for n in names)
              + ": every channel in SI units, the errors above removed (inputs minus their biases, outputs "
              "`(measured(t + tau) - b) / K`), ready for `identify estimate` and `identify refine`.", "",
              "## Data provenance", "", "```", *provenance_lines(prov), "```", ""]
    return "\n".join(lines)


def _plot(result: CompatResult, path: Path) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ny = len(result.outputs)
    fig = Figure(figsize=(8.0, 1.0 + 1.2 * ny))
    FigureCanvasAgg(fig)
    axes = fig.subplots(ny, 1, sharex=True, squeeze=False)[:, 0]
    offset = 0.0
    for t, before, after in zip(result.time, result.residuals_before, result.residuals_after):
        for j, ax in enumerate(axes):
            ax.plot(offset + t, before[:, j], color="0.6", linewidth=0.7)
            ax.plot(offset + t, after[:, j], color="C0", linewidth=0.7)
        offset += t[-1] + (t[1] - t[0] if len(t) > 1 else 0.0)
    for ax, y in zip(axes, result.outputs):
        ax.set_ylabel(f"{y} [{'m/s' if y == 'V' else 'm' if y == 'h' else 'rad'}]", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title("residuals before (grey) and after (blue) the sensor errors, segments in turn", fontsize=9)
    axes[-1].set_xlabel("time [s]")
    fig.subplots_adjust(left=0.1, right=0.98, top=0.95, bottom=0.06)
    fig.savefig(path, dpi=90)
    return path.name


def load(path) -> dict:
    """``compat.json`` back as a dict."""
    return json.loads(Path(path).read_text())


__all__ = ["write", "markdown", "corrected_names", "load"]

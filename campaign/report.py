"""The campaign report: ``<out>/report.md`` with the trend figure ``<out>/trends.png``.

Failures come first (points that failed, then fits that did not converge, each with its
reason), then the points that break a trend, the poorly identified estimates, the trend figure,
the stitched model's verification when ``campaign stitch`` has run, and where the tables are.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .prior import report_lines as prior_lines
from .table import rows, write_table
from .trends import BREAK_SIGMA, POOR_REL_STD, campaign_trends, plot_trends


def write_report(campaign, out) -> Path:
    out = Path(out)
    table = rows(campaign, out)
    tables = write_table(campaign, out)
    cond = campaign.trend_condition
    status = {}
    for row in table:
        status.setdefault(row["point"], (row["status"], row.get("reason", "")))
    counts = {s: sum(v[0] == s for v in status.values()) for s in ("ok", "not converged", "failed", "missing")}
    lines = [f"# Campaign report: {campaign.name}", "",
             f"{len(campaign.points)} test points from `{campaign.source}`; method `{campaign.method}`"
             f"{', refined' if campaign.refine else ''}; trends over `{cond}`.", "",
             "| identified | not converged | failed | not yet run |", "| ---: | ---: | ---: | ---: |",
             f"| {counts['ok']} | {counts['not converged']} | {counts['failed']} | {counts['missing']} |", ""]
    lines += _failures(status)
    trends = campaign_trends(table, cond)
    if trends:
        plot_trends(trends, cond, out / "trends.png", title=f"{campaign.name}: estimates over {cond}")
        lines += _breaks(trends, cond) + _poor(trends)
        lines += ["## Trends", "",
                  f"Each derivative against `{cond}` with ±1 std error bars; the line is the smooth trend "
                  f"(weighted polynomial, degree by BIC) with its ±2 std band; red circles: points more than "
                  f"{BREAK_SIGMA:g} std from the trend fitted without them; grey and shaded: poorly identified "
                  f"(relative std > {POOR_REL_STD:g} % or not converged).", "", "![trends](trends.png)", ""]
    if campaign.refine:
        lines += _refined(out, campaign)
    lines += _stitch(out / "stitch" / "stitch.json", cond)
    lines += prior_lines(out)
    lines += _runs(out / "runs.jsonl")
    lines += ["## Tables", "", f"- `{tables['csv'].name}`: one row per (point, parameter)"]
    lines.append(f"- `{tables['parquet'].name}`: the same, typed" if tables["parquet"] else f"- {tables['note']}")
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _failures(status: dict) -> list[str]:
    bad = [(p, s, r) for p, (s, r) in status.items() if s in ("failed", "not converged", "missing")]
    if not bad:
        return ["## Failures", "", "None: every point was identified and converged.", ""]
    order = {"failed": 0, "not converged": 1, "missing": 2}
    lines = ["## Failures", "", "| point | status | reason |", "| --- | --- | --- |"]
    lines += [f"| {p} | {s} | {r.replace('|', '/')} |" for p, s, r in sorted(bad, key=lambda b: order[b[1]])]
    return lines + [""]


def _breaks(trends, cond) -> list[str]:
    rows_ = [(t.parameter, n, x, z) for t in trends for n, x, z, b in zip(t.points, t.x, t.z, t.breaks) if b]
    lines = ["## Points that break a trend", ""]
    if not rows_:
        return lines + [f"None: every estimate lies within {BREAK_SIGMA:g} std of its trend.", ""]
    lines += [f"| parameter | point | {cond} | std from trend |", "| --- | --- | ---: | ---: |"]
    lines += [f"| `{p}` | {n} | {x:g} | {z:+.1f} |" for p, n, x, z in rows_]
    points = sorted({n for _, n, _, _ in rows_})
    return lines + ["", f"Points breaking at least one trend: {', '.join(points)}. A point breaking several trends "
                        f"at once suggests an effect its model does not declare (try `refine = true`).", ""]


def _poor(trends) -> list[str]:
    lines = ["## Poorly identified estimates and scatter", "",
             "| parameter | poorly identified | of | scatter / std |", "| --- | ---: | ---: | ---: |"]
    lines += [f"| `{t.parameter}` | {int(t.poor.sum())} | {len(t.points)} | {t.scale:.2f} |" for t in trends]
    return lines + ["", "Scatter / std: how much more the estimates scatter about their trend than their standard "
                        "errors say (robust; at least 1). Above 1 the Cramér-Rao bounds are optimistic (turbulence, "
                        "coloured residuals) and the 3-std test uses the observed scatter.", ""]


def _refined(out, campaign) -> list[str]:
    from .table import records

    lines = ["## Refinement", "", "| point | effects added | stopped |", "| --- | --- | --- |"]
    for point, rec in records(campaign, out):
        steps = (rec or {}).get("refine_steps") or []
        added = ", ".join(f"{s['effect']} on {s['target']}" for s in steps if "effect" in s) or "none"
        stopped = next((s["stopped"] for s in steps if "stopped" in s), "")
        lines.append(f"| {point.name} | {added} | {stopped.replace('|', '/')} |")
    return lines + ["", "Rejected candidates and their reasons are in each point's record (`points/<key>.json`).", ""]


def _stitch(path: Path, cond) -> list[str]:
    if not path.exists():
        return []
    s = json.loads(path.read_text())
    lines = ["## Stitched model", "",
             f"`stitch/stitched_profile.toml`: {s['points']} points over {cond} {s['range'][0]:g}..{s['range'][1]:g}"
             f" (`identify model stitch/stitched_profile.toml --at {cond}=VALUE`).", ""]
    checks = [c for c in s.get("verification", []) if "ratio" in c]
    if checks:
        lines += ["Held-out points (not part of the stitch): prediction error of the stitched model against "
                  "the point's own model, on all the point's runs (and on its held-out runs alone):", "",
                  f"| point | set | {cond} | own model | stitched | ratio | within 10 % | ratio on held-out runs |",
                  "| --- | --- | ---: | ---: | ---: | ---: | --- | ---: |"]
        lines += [f"| {c['point']} | {c.get('set', 'held out')} | {c[cond]:g} | {c['own_error']:.4f} | {c['stitched_error']:.4f} | "
                  f"{c['ratio']:.3f} | {'yes' if c['within_10pct'] else 'NO'} | "
                  f"{c.get('validation_ratio', float('nan')):.3f} |" for c in checks]
    errors = [c for c in s.get("verification", []) if "error" in c]
    lines += [f"- {c['point']}: not verified ({c['error']})" for c in errors]
    return lines + [""]


def _runs(path: Path) -> list[str]:
    if not path.exists():
        return []
    last = json.loads(path.read_text().splitlines()[-1])
    return ["## Last run", "",
            f"{last['command']}: {last['computed']} computed, {last['already_done']} already stored, "
            f"{last['failed']} failed; executor {last['executor']} ({last['workers']} workers), "
            f"{last['seconds']:.1f} s (+ {last.get('startup_s', 0):.1f} s to start), coordinator peak memory {last['peak_rss_mb']:.0f} MB.", ""]

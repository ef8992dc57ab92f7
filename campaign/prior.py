"""``prior = "stitch"``: every test point identified again with the other points' stitched model as
its prior (leave-one-out), after the plain pass.

For each point, the stitch (:func:`campaign.stitch.stitch`) of every *other* identified point is
taken at the point's condition: its values are the prior's centres and its interpolated standard
errors (the trend's std there) the prior's stds (:mod:`identify.model.prior`). A point outside
the others' range (an end of the envelope: a stitch is not extrapolated), or a campaign with too
few other points, has no prior: it is identified as before and the reason recorded. The records
go to ``<out>/points_prior/``; ``<out>/prior_stitch.json`` lists per point where the prior decided
an estimate (data share under one half) and any prior-data conflict, and the report says so.
"""
from __future__ import annotations

import json
from pathlib import Path

from identify.errors import PseudostepError
from identify.model.prior import with_prior
from identify.model.profile import parse_profile
from identify.model.schedule import at_condition

from .runner import run_tasks, task_of
from .point import identify_point
from .store import point_key
from .stitch import stitch
from .table import records, rows

FOLDER, SUMMARY = "points_prior", "prior_stitch.json"


def stitch_prior(campaign, point, recs, table) -> tuple[dict, str]:
    """The prior ``{name: {"value", "std"}}`` the other points' stitch gives ``point``, or ``{}``
    and the reason it has none."""
    cond = campaign.trend_condition
    value = point.condition.get(cond)
    if not isinstance(value, (int, float)):
        return {}, f"no numeric '{cond}'"
    try:
        stitched, _ = stitch(campaign, recs, table, exclude=[point.name])
        here = at_condition(stitched, float(value))
    except PseudostepError as exc:
        return {}, f"no leave-one-out stitch: {exc}"
    std = here.meta.get("std", {})
    prior = {n: {"value": float(here.free[n]), "std": float(s)} for n, s in std.items()
             if n in here.free and s is not None and s > 0}
    return prior, "" if prior else "the stitch holds no standard errors"


def run_with_stitch_prior(campaign, out, executor, **kw) -> dict:
    """The second pass (see the module notes): returns the runner's statistics."""
    recs, table = records(campaign, out), rows(campaign, out)
    priors = {p.name: stitch_prior(campaign, p, recs, table) for p in campaign.points}

    def make_task(camp, point):
        task = task_of(camp, point)
        prior, _ = priors[point.name]
        if prior:
            profile = parse_profile(task["profile"], source=task["profile_source"])
            known = {n: v for n, v in prior.items() if n in profile.free}
            task["profile"] = with_prior(profile, known).to_toml()
            task["key"] = point_key(task)
        return task

    stats = run_tasks(campaign, out, executor, make_task, identify_point, folder=FOLDER,
                      label="identifying with the stitch's prior", **kw)
    write_summary(campaign, out, priors, make_task)
    return stats


def write_summary(campaign, out, priors: dict, make_task) -> Path:
    from .store import Store

    store, summary = Store(out, FOLDER), {}
    for point in campaign.points:
        prior, why = priors[point.name]
        entry = {"prior_parameters": len(prior), "no_prior": why or None}
        try:
            rec = store.get(make_task(campaign, point)["key"])
        except PseudostepError as exc:
            rec, entry["error"] = None, str(exc)
        if rec is not None:
            entry["status"] = rec["status"]
            entry.update(rec.get("prior") or {})
        summary[point.name] = entry
    path = Path(out) / SUMMARY
    path.write_text(json.dumps(summary, indent=1))
    return path


def report_lines(out) -> list[str]:
    """The report's section: per point the parameters the prior decided and any conflict."""
    path = Path(out) / SUMMARY
    if not path.exists():
        return []
    summary = json.loads(path.read_text())
    lines = ["## A priori weighting: the other points' stitch as each point's prior", "",
             "Each point identified again with the leave-one-out stitched model at its condition as prior "
             "(records in `points_prior/`). *Decided by the prior*: the data's share of the information under "
             "one half.", "", "| point | prior on | decided by the prior | prior-data conflict |",
             "| --- | ---: | --- | --- |"]
    for name, e in summary.items():
        if e.get("no_prior"):
            lines.append(f"| {name} | none | - | {e['no_prior'].replace('|', '/')} |")
            continue
        c = e.get("conflict") or {}
        conflict = f"**on {', '.join(c['drivers'])}**" if c.get("detected") else "none"
        decided = ", ".join(e.get("decided_by_prior") or []) or "none"
        lines.append(f"| {name} | {e['prior_parameters']} | {decided} | {conflict} |")
    return lines + [""]


def screen_lines(out) -> list[str]:
    """What the second pass found, on screen: points with a prior, where it decided, conflicts."""
    summary = json.loads((Path(out) / SUMMARY).read_text())
    with_prior = [n for n, e in summary.items() if not e.get("no_prior")]
    lines = [f"with the other points' stitch as prior: {len(with_prior)} of {len(summary)} points "
             f"(records in {FOLDER}/, summary in {SUMMARY})"]
    for name, e in summary.items():
        if e.get("no_prior"):
            lines.append(f"  {name}: no prior ({e['no_prior']})")
        if e.get("decided_by_prior"):
            lines.append(f"  {name}: decided by the prior: {', '.join(e['decided_by_prior'])}")
        if (e.get("conflict") or {}).get("detected"):
            lines.append(f"  {name}: PRIOR-DATA CONFLICT on {', '.join(e['conflict']['drivers'])}")
    return lines

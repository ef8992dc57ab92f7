"""``campaign stitch``: one model of the envelope from the test points' models (model stitching).

Every free parameter becomes a smooth function of the condition: the trend of
:mod:`campaign.trends` (weighted polynomial, points that break it and points that did not
converge left out), tabulated at evenly spaced breakpoints over the stitched points' range with
its standard deviation there. Fixed parameters that differ between the points' a priori models
(the kinematic ``Z_q = V``) and trim values (``trim_<channel>`` columns) are tabulated the same way,
unweighted. The result is a *scheduled profile* (:mod:`identify.model.schedule`): an ordinary
profile at the middle of the range whose ``[meta.schedule]`` holds the tables, so that
``identify model stitched.toml --at airspeed=47`` prints the model at any condition inside it.

:func:`verify` judges a stitched model on test points that took no part in it: at each, the
stitched model's prediction error on all the point's runs against the error of the point's own
identified model (fitted to most of them) on the same runs; the held-out runs alone are reported too.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from identify.errors import CampaignError
from identify.model.profile import parse_profile

from .trends import best_fit, campaign_trends

BREAKPOINTS = 25
TOLERANCE = 1.10  # the stitched model's error may exceed the point's own model's by 10 %


def stitch(campaign, records: list[tuple], table: list[dict], exclude=(), breakpoints: int = BREAKPOINTS):
    """The stitched profile from the points' ``records`` (``(point, record)``) and the tidy
    ``table``, leaving out the points named in ``exclude``; returns ``(profile, summary)``."""
    cond = campaign.trend_condition
    held = set(exclude)
    breaking = breaking_points([row for row in table if row["point"] not in held], cond)
    exclude = held | set(breaking)
    ok = [(p, r) for p, r in records if r and r["status"] == "ok" and p.name not in exclude
          and isinstance(p.condition.get(cond), (int, float))]
    if len(ok) < 2:
        raise CampaignError(f"stitch needs at least 2 identified points with a numeric '{cond}' (have {len(ok)})")
    profiles = [parse_profile(r["identified_profile"], source=p.name) for p, r in ok]
    base = profiles[len(profiles) // 2]
    x = np.array([p.condition[cond] for p, _ in ok], float)
    at = np.linspace(x.min(), x.max(), breakpoints)
    used = [row for row in table if row["point"] not in exclude]
    values, std = {}, {}
    for t in campaign_trends(used, cond):
        if t.fit is None or t.parameter not in base.free:
            continue
        mean, sd = t.fit(at)
        values[t.parameter], std[t.parameter] = mean.tolist(), sd.tolist()
    missing = sorted(set(base.free) - set(values))
    if missing:
        raise CampaignError(f"stitch: no trend for {', '.join(missing)} (too few points)")
    for name in base.fixed:  # known values that move with the condition (kinematic terms)
        col = np.array([p.fixed.get(name, math.nan) for p in profiles])
        if np.ptp(col) > 0:
            values[name] = best_fit(x, col, None)(at)[0].tolist()
    trim = {}
    for channel in sorted({k for p, _ in ok for k in p.trim}):
        pts = [(p.condition[cond], p.trim[channel]) for p, _ in ok if channel in p.trim]
        if len(pts) >= 2:
            tx, ty = map(np.array, zip(*pts))
            trim[channel] = best_fit(tx, ty, None)(at)[0].tolist()
    schedule = {"condition": cond, "at": at.tolist(), "values": values, "std": std}
    if trim:
        schedule["trim"] = trim
    mid = len(at) // 2
    profile = base.with_values({k: v[mid] for k, v in values.items()},
                               name=f"{campaign.name}: stitched over {cond} {at[0]:g}..{at[-1]:g}")
    meta = {**base.meta, "schedule": schedule, "stitched_from": [p.name for p, _ in ok],
            "condition": {cond: float(at[mid])}}
    from dataclasses import replace
    profile = replace(profile, meta=meta, source="<stitched profile>", description=f"Stitched from {len(ok)} test points; "
                      f"values at {cond} = {at[mid]:g}; tables in [meta.schedule]")
    summary = {"condition": cond, "points": len(ok), "range": [float(at[0]), float(at[-1])],
               "held_out": sorted(held), "breaking_trends_left_out": breaking,
               "not_stitched": [p.name for p, r in records if p.name not in exclude and (not r or r["status"] != "ok")]}
    return profile, summary


def breaking_points(table: list[dict], cond: str) -> dict[str, list[str]]:
    """{point: [parameters]} of the points that break any parameter's trend: their models are
    suspect as a whole (an effect they do not declare biases several estimates, not all of them
    beyond 3 std), so the stitch leaves them out entirely and held-out checks never pick them."""
    out: dict[str, list[str]] = {}
    for t in campaign_trends(table, cond):
        for name, b in zip(t.points, t.breaks):
            if b:
                out.setdefault(name, []).append(t.parameter)
    return out


def verify(stitched, campaign, records: list[tuple], names, label: str = "held out") -> list[dict]:
    """Per point in ``names``: the stitched model at the point's condition against the point's
    own identified model, both judged on all the point's runs (fitted and held-out: the own model
    has the advantage of having been fitted to most of them) and, apart, on its held-out runs."""
    from identify.data.io import load_channel_map, read_run_files
    from identify.errors import PseudostepError
    from identify.model.pseudo_inputs import prepare
    from identify.model.schedule import at_condition, schedule_of

    from .point import prediction_error

    cond = schedule_of(stitched)["condition"]
    by_name = {p.name: (p, r) for p, r in records}
    out = []
    for name in names:
        point, rec = by_name[name]
        if not rec or rec["status"] != "ok":
            out.append({"point": name, "set": label, "error": "the point has no identified model"})
            continue
        own = parse_profile(rec["identified_profile"], source=name)
        cmap = load_channel_map(Path(point.root) / point.channel_map) if point.channel_map else None
        if not isinstance(point.condition.get(cond), (int, float)):
            out.append({"point": name, "set": label, "error": f"no numeric '{cond}' column"})
            continue
        try:
            here = at_condition(stitched, float(point.condition[cond]))
        except PseudostepError as exc:  # outside the schedule
            out.append({"point": name, "set": label, "error": str(exc)})
            continue
        check = {"point": name, "set": label, cond: point.condition[cond]}
        fit, held = point.files("runs"), point.files("validate")  # as the manifest has them now
        for prefix, files in (("", fit + held), ("validation_", held)):
            if files:
                runs = read_run_files(files, cmap, own)
                check[f"{prefix}own_error"] = prediction_error(own, prepare(own, runs))
                check[f"{prefix}stitched_error"] = prediction_error(here, prepare(here, runs))
                check[f"{prefix}ratio"] = check[f"{prefix}stitched_error"] / check[f"{prefix}own_error"]
        check["within_10pct"] = bool(check["ratio"] <= TOLERANCE)
        out.append(check)
    return out


def held_out_points(campaign, records, table: list[dict], count: int) -> list[str]:
    """``count`` interior points spread evenly over the condition (never the ends: a stitch is
    not extrapolated), chosen among the identified points that break no trend."""
    cond = campaign.trend_condition
    breaking = breaking_points(table, cond)
    ok = sorted((p.condition[cond], p.name) for p, r in records if r and r["status"] == "ok"
                and isinstance(p.condition.get(cond), (int, float)) and p.name not in breaking)
    if len(ok) < count + 2:
        raise CampaignError(f"cannot hold out {count} of {len(ok)} identified points (ends stay in)")
    picks = np.linspace(0, len(ok) - 1, count + 2)[1:-1]
    return [ok[int(round(i))][1] for i in picks]


def write(out: Path, profile, summary: dict, checks: list[dict]) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    path = profile.save(out / "stitched_profile.toml")
    (out / "stitch.json").write_text(json.dumps({**summary, "verification": checks}, indent=1))
    return {"profile": path, "json": out / "stitch.json"}

"""``campaign identify``: every test point's task, run on an executor, each record stored at once.

The coordinator (this process) only builds tasks (file paths and the profile's text, a few kB
each), hashes their inputs (:func:`campaign.store.point_key`), skips the points whose record
exists, hands the rest to the executor and writes each record the moment it arrives. It holds
no run data and no results beyond the one being written, so its memory does not depend on the
number of points.
"""
from __future__ import annotations

import json
import resource
import sys
import time
from collections.abc import Callable
from pathlib import Path

from identify.errors import CampaignError, PseudostepError

from .manifest import Campaign, Point
from .point import failure_record, identify_point, make_estimator
from .store import Store, point_key


def point_profile(point: Point):
    """The point's a priori profile; a scheduled one evaluated at the point's condition."""
    from identify.model.profile import load_profile
    from identify.model.schedule import at_condition, schedule_of

    profile = load_profile(point.profile_path())
    schedule = schedule_of(profile)
    if schedule is not None:
        cond = schedule["condition"]
        if not isinstance(point.condition.get(cond), (int, float)):
            raise CampaignError(f"point {point.name}: the scheduled profile needs a numeric '{cond}' column")
        profile = at_condition(profile, float(point.condition[cond]))
    return profile


def task_of(campaign: Campaign, point: Point) -> dict:
    """The task of one point (plain data a worker process can receive); its ``key`` the hash of
    its inputs. A point whose inputs cannot even be assembled raises :class:`PseudostepError`."""
    from identify.errors import read_text

    profile = point_profile(point)
    task = {"name": point.name, "runs": [str(p) for p in point.files("runs")],
            "validate": [str(p) for p in point.files("validate")],
            "profile": profile.to_toml(), "profile_source": profile.source,
            "channel_map": read_text(Path(point.root) / point.channel_map, CampaignError, "channel map")
            if point.channel_map else None,
            "method": campaign.method, "refine": campaign.refine, "options": dict(campaign.options)}
    task["key"] = point_key(task)
    return task


def input_failure(point: Point, campaign: Campaign, exc: PseudostepError) -> tuple[str, dict]:
    """A point whose inputs are missing or malformed: a failure record keyed by the point's name
    and the error (recomputed next time, since the files may have been fixed)."""
    import hashlib

    key = "input-" + hashlib.sha256(f"{point.name}\n{exc}".encode()).hexdigest()[:18]
    task = {"name": point.name, "key": key, "method": campaign.method, "refine": campaign.refine,
            "runs": point.runs, "validate": point.validate}
    return key, failure_record(task, str(exc))


def point_keys(campaign: Campaign, make_task: Callable | None = None) -> dict[str, str]:
    """{point name: key} for every point (the store's file names)."""
    make_task = make_task or task_of
    keys = {}
    for point in campaign.points:
        try:
            keys[point.name] = make_task(campaign, point)["key"]
        except PseudostepError as exc:
            keys[point.name] = input_failure(point, campaign, exc)[0]
    return keys


def run_campaign(campaign: Campaign, out: str | Path, executor, **kw) -> dict:
    """Identify every point not yet in the store (:func:`run_tasks` with :func:`identify_point`);
    the estimator options are checked first (a wrong one would fail every point)."""
    make_estimator(campaign.method, None, campaign.options)
    return run_tasks(campaign, out, executor, task_of, identify_point, **kw)


def run_tasks(campaign: Campaign, out: str | Path, executor, make_task: Callable, job: Callable, *,
              folder: str = "points", label: str = "identifying", retry_failed: bool = False,
              progress: bool = True, on_result: Callable | None = None) -> dict:
    """Run ``job`` on every point's task (``make_task(campaign, point)``) not yet in the store
    ``<out>/<folder>``, each record stored as it arrives; return (and append to
    ``<out>/runs.jsonl``) the statistics: points, already done, computed, failed, wall time,
    the coordinator's peak memory; ``seconds`` excludes the executor's start (``startup_s``)."""
    store = Store(out, folder)
    t0 = time.perf_counter()
    executor.start()  # workers up and their libraries loaded: timed apart from the points' work
    started = time.perf_counter()
    stats = {"command": label, "points": len(campaign.points), "already_done": 0, "computed": 0, "failed": 0,
             "shared": 0, "executor": executor.name, "workers": getattr(executor, "workers", None)}
    seen: set[str] = set()

    def todo():
        for point in campaign.points:
            try:
                task = make_task(campaign, point)
            except PseudostepError as exc:
                key, record = input_failure(point, campaign, exc)
                store.put(key, record)
                stats["failed"] += 1
                bar.write(f"FAILED {point.name}: {exc}", file=sys.stderr)
                bar.update(1)
                continue
            if task["key"] in seen:
                stats["shared"] += 1
                bar.update(1)
                continue  # two points with identical inputs share one record
            seen.add(task["key"])
            old = store.get(task["key"])
            if old is not None and (old["status"] != "failed" or not retry_failed):
                stats["already_done"] += 1
                bar.update(1)
                continue
            yield task

    bar = _bar(len(campaign.points), progress, label)
    try:
        for task, record in executor.map(job, todo()):
            store.put(task["key"], record)
            stats["computed"] += 1
            if record["status"] != "ok":
                stats["failed"] += record["status"] == "failed"
                bar.write(f"{record['status'].upper()} {task['name']}: {record['reason']}", file=sys.stderr)
            bar.update(1)
            if on_result is not None:
                on_result(task, record)
    finally:
        bar.close()
    stats["seconds"] = time.perf_counter() - started
    stats["startup_s"] = started - t0
    stats["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    with open(Path(out) / "runs.jsonl", "a") as f:
        f.write(json.dumps(stats) + "\n")
    return stats


def _bar(total: int, enabled: bool, label: str):
    from tqdm import tqdm

    return tqdm(total=total, unit="point", desc=label, disable=not enabled, file=sys.stderr,
                dynamic_ncols=True, leave=True)

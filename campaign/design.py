"""``campaign design``: the designed input of every test point, before the flights.

Each point's a priori model (its profile, a scheduled one at the point's condition) gets the
robust default design of :mod:`signaldesign` (:class:`~signaldesign.design.SequenceDesign`,
criterion ``robust``), one run per control axis as flight tests are flown. The designs run on the
campaign's executor like the identifications (one search process per job: ``jobs=1`` inside a
worker) and are stored the same way (keyed by the hash of the profile and the options, resumed);
each point's signals are also written to ``<out>/designs/<point>.signals.json``, the file
``signaldesign``, ``cueing`` and ``signaldesign make --csv`` read.
"""
from __future__ import annotations

from pathlib import Path

from .point import guarded
from .runner import point_keys, point_profile, run_tasks
from .store import Store, point_key

DEFAULTS = {"duration": 7.0, "record": 20.0}


def design_task(options: dict):
    """A ``make_task`` for :func:`campaign.runner.run_tasks` with these SequenceDesign options."""
    def make(campaign, point) -> dict:
        profile = point_profile(point)
        task = {"name": point.name, "kind": "design", "profile": profile.to_toml(),
                "profile_source": profile.source, "options": {**DEFAULTS, **options}}
        task["key"] = point_key(task)
        return task
    return make


def design_point(task: dict) -> dict:
    """One point's designs (one per input axis); failures recorded, never raised."""
    return guarded(_design, task, {"point": task["name"], "key": task["key"]})


def _design(task: dict) -> dict:
    from identify.model.linear import LinearModel
    from identify.model.profile import parse_profile
    from signaldesign.design import SequenceDesign

    model = LinearModel(parse_profile(task["profile"], source=task["profile_source"]))
    signals, records = [], []
    for axis in model.profile.input_names:  # one run per control axis, as flight tests are flown
        d = SequenceDesign(axis, jobs=1, **task["options"]).fit(model)
        signals += [s.to_dict() for s in d.signals_]
        records.append(d.record)
    return {"status": "ok", "reason": "", "signals": signals, "inputs": model.profile.input_names,
            "records_s": records, "flight_time_s": float(sum(records))}


def run_design(campaign, out, executor, options: dict, progress: bool = True) -> dict:
    """Design every point; write each point's signal file; return the statistics with the
    campaign's total flight time (every point's records, one per axis)."""
    from signaldesign.signal import Signal, save_signals

    out = Path(out)
    folder = out / "designs"

    def written(task, record):
        if record["status"] == "ok":
            save_signals([Signal.from_dict(s) for s in record["signals"]], folder / f"{task['name']}.signals.json")

    stats = run_tasks(campaign, out, executor, design_task(options), design_point, folder="designs",
                      label="designing", progress=progress, on_result=written)
    store, keys = Store(out, "designs"), point_keys(campaign, design_task(options))
    total, done = 0.0, 0
    for point in campaign.points:
        rec = store.get(keys[point.name])
        if rec and rec["status"] == "ok":
            total += rec["flight_time_s"]
            done += 1
            if not (folder / f"{point.name}.signals.json").exists():  # designed by an earlier, killed run
                written({"name": point.name}, rec)
    stats.update(designed=done, flight_time_s=total)
    return stats

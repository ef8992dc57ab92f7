"""The work of one test point, as a worker runs it: read the runs, identify, judge, return a record.

:func:`identify_point` takes a task (plain data: file paths, the profile's TOML text, the method
and options) and returns a JSON-ready record; it never raises. A point that cannot be identified
(an unreadable file, a missing channel, an estimator that gives up) comes back as a record with
``status = "failed"`` and the reason; a fit that stopped before convergence keeps its estimates
with ``status = "not converged"``. BLAS runs on one thread inside the job, wherever it runs
(serial, a local worker or a Dask worker), so that every executor computes bit-identical results.
"""
from __future__ import annotations

import json
import math
import time
import warnings

def failure_record(task: dict, reason: str) -> dict:
    """The record of a task that produced no result (its inputs, a worker that died): the task's
    labels, ``status = "failed"`` and the reason; no estimates."""
    record = {"point": task["name"], "key": task["key"], "status": "failed", "reason": reason,
              "warnings": [], "seconds": None}
    for k in ("method", "refine"):
        if k in task:
            record[k] = task[k]
    for k in ("runs", "validate"):
        if k in task:
            record[k] = [str(p) for p in task[k]]
    return record


def identify_point(task: dict) -> dict:
    """The record of one test point (see the module docstring); ``seconds`` is the job's wall time."""
    labels = {"point": task["name"], "key": task["key"], "method": task["method"], "refine": task["refine"],
              "runs": [str(p) for p in task["runs"]], "validate": [str(p) for p in task["validate"]]}
    return guarded(_identify, task, labels)


def guarded(work, task: dict, record: dict) -> dict:
    """``record`` updated with ``work(task)``, run on one BLAS thread; never raises: an exception
    becomes ``status = "failed"`` with its reason; every warning and the wall time recorded."""
    from threadpoolctl import threadpool_limits

    started = time.perf_counter()
    with threadpool_limits(1), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            record.update(work(task))
        except Exception as exc:  # recorded, never raised: the campaign goes on
            from identify.errors import PseudostepError
            reason = str(exc) if isinstance(exc, PseudostepError) else f"{type(exc).__name__}: {exc}"
            record.update(status="failed", reason=reason.splitlines()[0] if reason else type(exc).__name__)
    record["warnings"] = sorted({str(w.message).splitlines()[0] for w in caught})
    record["seconds"] = time.perf_counter() - started
    return _jsonable(record)


def make_estimator(method: str, profile, options: dict):
    """The estimator instance of ``method`` with the manifest's ``[options]`` (identify's
    registry); an option the method does not take is one error line (checked by the coordinator
    before any work)."""
    from identify.estimators.registry import build

    return build(method, profile, names={k: f"[options] {k}" for k in options}, **options)


def _identify(task: dict) -> dict:
    from identify.model.profile import parse_profile
    from identify.model.pseudo_inputs import prepare
    from identify.pipeline import Job, Reading

    profile = parse_profile(task["profile"], source=task["profile_source"])
    job = Job(task["runs"], profile, task["method"], dict(task["options"]), Reading(task["channel_map"]))
    names = {k: f"[options] {k}" for k in task["options"]}  # an option's name in a one-line error
    steps = []
    if task["refine"]:
        refiner = job.refine(task["validate"], names=names).refiner
        result, final = refiner.result_, refiner.profile_
        runs, held = refiner.runs_, refiner.validation_runs_
        steps = [{"effect": s.effect, "target": s.target, "statistic": s.statistic} for s in refiner.steps_]
        steps += [{"rejected": f"{s.effect} on {s.target}", "reason": s.reason} for s in refiner.rejected_]
        steps.append({"stopped": refiner.stopped_})
    else:
        est = job.estimate(names=names)
        result, final, runs = est.result, est.result.identified_profile(), est.runs
        held = job.reading.prepared(task["validate"], profile, window=False) if task["validate"] else []
    out = {"status": "ok" if result.converged else "not converged",
           "reason": "" if result.converged else f"did not converge ({result.info.get('stop', 'no reason given')})",
           "converged": result.converged,
           "parameters": {n: {"value": float(v), "std": float(s), "apriori": float(a)}
                          for n, v, s, a in zip(result.names, result.theta, result.std, result.apriori)},
           "identified_profile": final.to_toml(), "refine_steps": steps,
           "fit_error": prediction_error(final, prepare(final, runs)),
           "result": _result_json(result)}
    out["validation_error"] = prediction_error(final, prepare(final, held)) if held else None
    prior = result.info.get("prior")
    if prior:  # a priori weighting: where the prior decided, and any conflict
        out["prior"] = {"decided_by_prior": prior["decided_by_prior"], "conflict": prior["conflict"],
                        "data_share": {n: v["data_share"] for n, v in prior["parameters"].items()}}
    return out


def _result_json(result) -> dict:
    """What result.json holds for the same job on the command line, but the fit's wall time (the
    record's ``seconds`` times the job): a record depends on its inputs only."""
    out = result.to_dict()
    out["info"].get("provenance", {}).pop("wall_time_s", None)
    return out


def prediction_error(profile, runs) -> float:
    """The model's error predicting the runs from their inputs: every output simulated over each
    whole run (initial state and output zero shifts fitted by least squares, as refine judges a
    model), RMS error per output divided by that output's spread in the data, then the RMS over
    outputs (dimensionless; 0 is perfect, ~1 no better than the mean)."""
    import numpy as np

    from identify.estimators.prediction import predict

    residuals = np.vstack(predict(profile, runs).residuals)
    measured = np.vstack([r.matrix(list(profile.outputs)) for r in runs])
    spread = np.where(measured.std(axis=0) > 0, measured.std(axis=0), 1.0)
    return float(np.sqrt(np.mean((np.sqrt(np.mean(residuals ** 2, axis=0)) / spread) ** 2)))


def _jsonable(obj):
    """Strict-JSON form: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, (str, bytes)):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return json.loads(json.dumps(obj)) if not isinstance(obj, (str, int, float, bool, type(None))) else obj

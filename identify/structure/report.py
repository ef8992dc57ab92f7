"""Write a structure search: ``structure.json`` (every decision) and ``final_profile.toml``.

``structure.json`` holds ``table`` (one row per declared parameter and per candidate that entered:
``fate`` kept, dropped, added or "added, then dropped", the final value and std, the stage and
statistic of the last decision on it with its threshold and the error before and after),
``decisions`` (every move in order: the orthogonal-function ranking is in ``ranking`` per equation
group), ``dropped``/``added``/``kept``, ``errors`` (held-out overall errors of the declared, the
equation-error and the final model), the data used, the options and ``equation_error_seconds``.
"""
from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from ..estimators.result import dumps, jsonable
from .search import StructureSearch


def to_dict(s: StructureSearch) -> dict:
    return jsonable({
        "profile": s.declared_.name,
        "method": s.estimator_.method,
        "options": {"alpha": s.alpha, "f_in": s.f_in, "f_out": s.f_out, "candidates": s.candidates,
                    "nonlinear": list(s.nonlinear or ()), "knots": s.knots_, "level": s.level,
                    "tolerance": s.tolerance, "confirm": s.confirm},
        "data": s.data_,
        "held": s.held_,
        "equation_error_seconds": s.equation_error_seconds_,
        "pool": [t.name for t in s.pool_],
        "kept": s.kept_, "dropped": s.dropped_, "added": s.added_,
        "table": s.table(),
        "decisions": [asdict(d) for d in s.decisions_],
        "ranking": {sel.problem.label: sel.ranking for sel in s.selections_},
        "press": {sel.problem.label: sel.fit.press for sel in s.selections_},
        "errors": s.errors_,
        "equation_error_held_out": getattr(s, "equation_error_held_out_", {}),
        "output_error_skipped": s.skipped_,
        "unconverged": getattr(s, "unconverged_", []),
        "final_profile": s.profile_.to_toml(),
    })


def write(s: StructureSearch, out) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "structure.json").write_text(dumps(to_dict(s)))
    s.profile_.save(out / "final_profile.toml")
    return out


__all__ = ["to_dict", "write"]

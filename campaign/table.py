"""The campaign's results as one tidy table: a row per (test point, parameter).

Columns: ``point``, every condition column, ``trim_<channel>`` columns, ``parameter``, ``value``,
``std``, ``apriori``, ``rel_std_pct``, ``converged``, ``status``, ``fit_error``,
``validation_error``, ``reason``, ``key`` (the store's record). A point that failed has one row
with an empty ``parameter`` and its reason; a point not yet identified has ``status = missing``.

Written as CSV (always: no dependency, opens anywhere) and as Parquet when ``pyarrow`` is
installed (``pip install pyarrow``: typed columns, fast to load for a large campaign). Why not an
xarray dataset: the table is long and ragged (points with different parameter sets after refine,
failed points without any) and xarray would bring pandas with it; a tidy table is what pandas,
R and spreadsheets read directly. pyarrow (tens of MB) is therefore optional, not a dependency;
without it the CSV is written and the Parquet file's absence is said on screen and in the report.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

from .manifest import Campaign
from .runner import point_keys
from .store import Store

FIELDS = ("parameter", "value", "std", "apriori", "rel_std_pct", "converged", "status", "fit_error",
          "validation_error", "reason", "key")


def records(campaign: Campaign, out: str | Path) -> list[tuple]:
    """``(point, record or None)`` in manifest order (None: not identified yet)."""
    store, keys = Store(out), point_keys(campaign)
    return [(p, store.get(keys[p.name])) for p in campaign.points]


def rows(campaign: Campaign, out: str | Path) -> list[dict]:
    conds = campaign.condition_columns
    trims = sorted({k for p in campaign.points for k in p.trim})
    table = []
    for point, rec in records(campaign, out):
        head = {"point": point.name, **{c: point.condition.get(c, "") for c in conds},
                **{f"trim_{t}": point.trim.get(t, "") for t in trims}}
        if rec is None:
            table.append({**head, "status": "missing", "reason": "not identified yet"})
            continue
        common = {"converged": rec.get("converged", ""), "status": rec["status"], "reason": rec.get("reason", ""),
                  "fit_error": rec.get("fit_error"), "validation_error": rec.get("validation_error"),
                  "key": rec["key"]}
        params = rec.get("parameters") or {}
        if not params:
            table.append({**head, **common})
        for name, p in params.items():
            value, std = p["value"], p["std"]
            rel = 100 * std / abs(value) if std is not None and value else math.inf
            table.append({**head, "parameter": name, "value": value, "std": _num(std), "apriori": p["apriori"],
                          "rel_std_pct": rel, **common})
    return table


def columns(campaign: Campaign) -> list[str]:
    trims = sorted({k for p in campaign.points for k in p.trim})
    return ["point"] + campaign.condition_columns + [f"trim_{t}" for t in trims] + list(FIELDS)


def write_table(campaign: Campaign, out: str | Path) -> dict:
    """Write ``results.csv`` (and ``results.parquet`` with pyarrow); returns {"csv", "parquet",
    "note"} (``parquet`` None and ``note`` saying why when it was not written)."""
    out = Path(out)
    table, cols = rows(campaign, out), columns(campaign)
    csv_path = out / "results.csv"
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, cols, extrasaction="ignore")
        w.writeheader()
        for row in table:
            w.writerow({k: _cell(row.get(k, "")) for k in cols})
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return {"csv": csv_path, "parquet": None,
                "note": "results.parquet not written: pyarrow is not installed (pip install pyarrow)"}
    data = {k: [_arrow(row.get(k)) for row in table] for k in cols}
    pq.write_table(pa.table(data), out / "results.parquet")
    return {"csv": csv_path, "parquet": out / "results.parquet", "note": ""}


def _num(x):
    return math.inf if x is None else x  # a null std in a record is an infinite one (not excited)


def _cell(v):
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if math.isinf(v) else repr(v))
    return "" if v is None else v


def _arrow(v):
    return None if v == "" else v

"""Where a result's numbers came from: files and their hashes, how they were read and processed.

:func:`provenance` gathers, per run, what the readers and the processing steps recorded in the
run's metadata (:mod:`identify.data.ingest`, :mod:`identify.data.preprocess`): the file and its
SHA-256, its format, the channel map, unit conversions, derived channels, resampling, time gaps,
dropped or interpolated samples, trim removal, the processing steps, warnings and notes; plus
the tool's version. Estimators put it into ``result.info["provenance"]`` (so ``result.json``
holds it), and reports print :func:`provenance_lines`.
"""
from __future__ import annotations

import json
import platform

from .runs import Run

# run metadata keys that say how the numbers were obtained, in the order a reader wants them
KEYS = ("sha256", "upstream_sha256", "compat_corrected", "compat_cut", "source_format", "matrix", "struct_element", "header", "time_from", "time_origin", "time_rebuilt", "channel_map",
        "units_declared", "converted_to_si", "derived", "resampled", "time_jitter", "time_gaps", "segment",
        "missing_outside_window", "missing_markers", "rate_change_outside_window", "dropped_samples", "interpolated_samples", "slice", "warnings", "notes")


def tool_version() -> str:
    """``pseudostep <version>`` from ``identify/_version.py``, the one place it is written (the
    installed metadata can lag behind an editable source tree)."""
    from .._version import __version__

    return f"pseudostep {__version__}"


def provenance(runs: list[Run]) -> dict:
    """``{"tool", "python", "runs": [{"source", ...KEYS present, "processing"}]}``."""
    out = []
    for run in runs:
        entry = {"source": run.source, "samples": len(run), "dt": run.dt}
        entry.update({k: run.meta[k] for k in KEYS if k in run.meta})
        if "channel_map" in entry:
            try:
                entry["channel_map"] = json.loads(entry["channel_map"])
            except json.JSONDecodeError:
                pass
        if run.meta.get("processing"):
            from .preprocess import processing_steps

            entry["processing"] = processing_steps(run)
        out.append(entry)
    return {"tool": tool_version(), "python": platform.python_version(), "runs": out}


def provenance_lines(prov: dict) -> list[str]:
    """Plain lines for reports: one block per run."""
    lines = [f"data provenance ({prov['tool']}):"]
    for r in prov["runs"]:
        lines.append(f"  {r['source']}: {r['samples']} samples at {r['dt']:.6g} s"
                     + (f", sha256 {r['sha256'][:16]}..." if "sha256" in r else ""))
        for key in KEYS[1:]:
            if key in r:
                value = r[key] if isinstance(r[key], str) else json.dumps(r[key], separators=(",", ":"))
                lines.append(f"    {key.replace('_', ' ')}: {value}")
        for step in r.get("processing", []):
            lines.append(f"    processing: {json.dumps(step, separators=(',', ':'))}")
    return lines

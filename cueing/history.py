"""Practice history per pilot (JSON lines) and the learning curve."""
from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

import numpy as np

from identify.errors import read_text

from .errors import CueingError

ENV = "PSEUDOSTEP_HISTORY"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
SCORES = ("rms", "timing_mean", "timing_std", "lag", "level_error_pos", "level_error_neg", "spectral_fidelity",
          "d_efficiency", "peak_ratio", "information_retained")
OVER_100 = ("info %: information retained at the designed peak response (raw D-efficiency / peak ratio^2); "
            "over 100: the flown shape carries more information per unit of peak response than the design")


def _info(record: dict) -> float:
    """Information retained at the designed peak response (older records: the raw D-efficiency)."""
    value = record.get("information_retained")
    return _num(record.get("d_efficiency") if value is None or "peak_ratio" not in record else value)


def history_dir(directory=None) -> Path:
    """``directory``, else ``$PSEUDOSTEP_HISTORY``, else ``~/.pseudostep/practice``."""
    return Path(directory or os.environ.get(ENV) or Path.home() / ".pseudostep" / "practice")


def history_path(pilot: str, directory=None) -> Path:
    if not _NAME.match(pilot or ""):
        raise CueingError(f"pilot name '{pilot}': use letters, digits, '-', '_' or '.' only")
    return history_dir(directory) / f"{pilot}.jsonl"


def append_attempt(pilot: str, record: dict, directory=None) -> Path:
    """Append one scored attempt (``record``: score dict plus signal, source, run) to the history."""
    path = history_path(pilot, directory)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"when": time.strftime("%Y-%m-%dT%H:%M:%S"), **record}
    with open(path, "a") as f:
        f.write(json.dumps(record, default=_jsonable) + "\n")
    return path


def load_history(pilot: str, directory=None) -> list[dict]:
    path = history_path(pilot, directory)
    if not path.is_file():
        raise CueingError(f"no practice history for pilot '{pilot}' ({path} does not exist)")
    text = read_text(path, CueingError, "practice history")
    records = []
    for n, line in enumerate(text.splitlines(), start=1):
        if line.strip():
            try:
                records.append(_checked(json.loads(line), path, n))
            except json.JSONDecodeError:
                raise CueingError(f"{path}: line {n}: not a JSON record") from None
    if not records:
        raise CueingError(f"{path}: holds no attempts")
    return records


def _checked(record, path: Path, n: int) -> dict:
    """A history record: a JSON object whose scores are numbers (null or NaN where undefined)."""
    if not isinstance(record, dict) or "rms" not in record:
        raise CueingError(f"{path}: line {n}: not a practice record (a JSON object with the scores)")
    for key in SCORES:
        value = record.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise CueingError(f"{path}: line {n}: '{key}' is not a number")
    return record


def format_history(records: list[dict]) -> str:
    """One row per attempt; timing is the mean switch timing ('missed' when no switch was followed),
    lag the cross-correlation delay; info over 100 % is explained below the table."""
    rows = [f"{'#':>3}  {'when':19}  {'RMS %':>6}  {'timing ms':>9}  {'lag ms':>6}  {'level+ %':>8}  {'level- %':>8}  "
            f"{'fidelity':>8}  {'info %':>6}  signal"]
    for i, r in enumerate(records, start=1):
        d, timing = _info(r), _num(r.get("timing_mean"))
        rows.append(f"{i:3d}  {str(r.get('when', '')):19}  {100 * _num(r['rms']):6.1f}  "
                    f"{f'{1000 * timing:+9.0f}' if np.isfinite(timing) else 'missed':>9}  "
                    f"{_ms(r.get('lag')):>6}  {100 * _num(r.get('level_error_pos')):+8.1f}  "
                    f"{100 * _num(r.get('level_error_neg')):+8.1f}  {_num(r.get('spectral_fidelity')):8.3f}  "
                    f"{f'{100 * d:6.1f}' if np.isfinite(d) else '':>6}  {r.get('signal', '')}")
    if any(_info(r) > 1 for r in records):
        rows.append(OVER_100)
    return "\n".join(rows)


def plot_learning_curve(pilot: str, records: list[dict], path) -> Path:
    """Learning curve PNG: RMS error, switch timing and lag, and information retained per attempt."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = np.arange(1, len(records) + 1)
    fig = Figure(figsize=(7, 7))  # on its own Agg canvas: no pyplot state, no display
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    axes[0].plot(n, [100 * _num(r["rms"]) for r in records], "o-")
    axes[0].set_ylabel("RMS error [% amp.]")
    axes[1].plot(n, [1000 * abs(_num(r.get("timing_mean"))) for r in records], "o-", label="switch timing |mean|")
    axes[1].plot(n, [1000 * _num(r.get("timing_std")) for r in records], "s--", label="switch timing std")
    axes[1].plot(n, [1000 * _num(r.get("lag")) for r in records], "^:", label="lag (cross-correlation)")
    missed = [i for i, r in zip(n, records) if not np.isfinite(_num(r.get("timing_mean")))]
    if missed:
        axes[1].set_title(f"no switch followed within the window in attempt(s) {', '.join(map(str, missed))}",
                          fontsize=8)
    axes[1].set_ylabel("timing [ms]")
    axes[1].legend(fontsize=8)
    d = [_info(r) for r in records]
    axes[2].plot(n, [100 * v for v in d], "o-", label="at the designed peak response")
    axes[2].axhline(100, color="0.5", ls=":", lw=1)
    axes[2].legend(fontsize=8)
    axes[2].set_ylabel("information [%]")
    axes[2].set_xlabel("attempt")
    axes[0].set_title(f"practice history: {pilot}")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=80)
    return path


def _num(v) -> float:
    return np.nan if v is None else float(v)


def _ms(v) -> str:
    return f"{1000 * _num(v):+6.0f}" if np.isfinite(_num(v)) else "-"


def _jsonable(v):
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")

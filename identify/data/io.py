"""The one door through which every command reads runs: CSV run files and MATLAB ``.mat`` files.

``identify estimate``, ``identify refine`` and the cueing replay source all read through
:func:`read_run_file`; a ``.mat`` file is read through a channel map (:func:`load_channel_map`).
"""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import RunError
from .matfile import read_mat
from .runs import Run, read_run


def load_channel_map(spec: str | Path) -> dict:
    """A channel map from a JSON file or JSON text.

    Form: ``{"channels": {channel: variable or column}, "time": variable or column,
    "matrix": name, "dt": seconds}``; a flat ``{channel: variable or column}`` is read as
    ``{"channels": ...}``.
    """
    text = str(spec)
    path = Path(text)
    source = text
    if not text.lstrip().startswith("{"):
        try:
            text = path.read_text()
        except OSError as exc:
            raise RunError(f"{spec}: cannot read channel map ({exc.strerror or exc})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise RunError(f"{source}: channel map is not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise RunError(f"{source}: channel map must be a JSON object")
    if "channels" not in data:
        data = {"channels": data}
    unknown = set(data) - {"channels", "time", "matrix", "dt"}
    if unknown:
        raise RunError(f"{source}: channel map has unknown key(s) {', '.join(sorted(unknown))}")
    if not isinstance(data["channels"], dict) or not data["channels"]:
        raise RunError(f"{source}: channel map 'channels' must be a non-empty object")
    return data


def read_run_file(path: str | Path, channel_map: dict | None = None) -> Run:
    """A run from a CSV run file or, with ``.mat`` suffix, a MATLAB file read through
    ``channel_map`` (see :func:`load_channel_map`; without one every vector variable is read)."""
    path = Path(path)
    if path.suffix.lower() != ".mat":
        return read_run(path)
    cmap = channel_map or {}
    return read_mat(path, cmap.get("channels"), time=cmap.get("time"), matrix=cmap.get("matrix"),
                    dt=cmap.get("dt"))


def read_run_files(paths, channel_map: dict | None = None) -> list[Run]:
    """Runs from several files (CSV or ``.mat``), in order."""
    return [read_run_file(p, channel_map) for p in paths]

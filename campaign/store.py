"""The campaign's store: one JSON record per test point, written the moment the point finishes.

A record's file name is the hash of everything its result depends on (:func:`point_key`): the
contents of its run files (not their names or dates), the a priori profile as evaluated at the
point, the channel map, the method, refine and estimator options, and the versions of pseudostep
and of the record format. A campaign run again therefore recomputes exactly the points whose
inputs changed; an interrupted one resumes where it stopped. Writes are atomic (a temporary file
in the same folder, flushed to disk, then renamed), so a kill at any instant leaves either the
whole record or none, never a torn one.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

RECORD_VERSION = 2  # 2: the result (as result.json holds it) in every record
CHUNK = 1 << 20
LABELS = ("name", "key", "profile_source")  # not inputs: renaming a point recomputes nothing
FILES = ("runs", "validate")


def pseudostep_version() -> str:
    from identify import __version__  # identify/_version.py: the one place it is written

    return __version__


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's contents, read in chunks (constant memory for any size)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(CHUNK), b""):
            h.update(block)
    return h.hexdigest()


def point_key(task: dict) -> str:
    """The hash of a task's inputs (24 hex digits): every entry but its labels (``name``, ``key``,
    ``profile_source``), run files (``runs``, ``validate``) by their contents, with the versions."""
    inputs = {k: v for k, v in task.items() if k not in LABELS}
    for k in FILES:
        if k in inputs:
            inputs[k] = [file_digest(p) for p in inputs[k]]
    inputs.update(record=RECORD_VERSION, pseudostep=pseudostep_version())
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:24]


class Store:
    """Records under ``<out>/<folder>/<key>.json`` (``points``: identification, ``designs``)."""

    def __init__(self, out: str | Path, folder: str = "points"):
        self.folder = Path(out) / folder
        self.folder.mkdir(parents=True, exist_ok=True)
        for stale in self.folder.glob(".*.tmp"):  # a write a kill interrupted: never a record
            stale.unlink(missing_ok=True)

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.json"

    def get(self, key: str) -> dict | None:
        path = self.path(key)
        if not path.exists():
            return None
        return json.loads(path.read_text())

    def has(self, key: str) -> bool:
        return self.path(key).exists()

    def put(self, key: str, record: dict) -> Path:
        """Write ``record`` atomically: the rename happens only after the bytes are on disk."""
        path = self.path(key)
        tmp = self.folder / f".{key}.{os.getpid()}.tmp"
        with open(tmp, "w") as f:
            f.write(json.dumps(record, indent=1, allow_nan=False, sort_keys=True))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        return path

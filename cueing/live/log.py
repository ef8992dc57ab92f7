"""The live log ``<out>.live.csv``: one row per frame (the response channels, and the estimate and
its bounds on the frames where a re-solve round completed), flushed as it is written like the
frame log, and read back after the flight."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import CueingError

FORMAT = "pseudostep-live-log/1"


def live_path(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.stem + ".live.csv")


class LiveLogWriter:
    """Writes the live log at ``path``: :meth:`open` with the header lines, :meth:`row` per frame,
    :meth:`close` with the run's status."""

    def __init__(self, path):
        self.path = Path(path)
        self.file = None

    def open(self, meta: dict[str, str], columns: list[str]) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.file = open(self.path, "w", buffering=1 << 16)
        except OSError as exc:
            raise CueingError(f"{self.path}: cannot write the live log ({exc.strerror or exc})") from None
        self.file.write(f"# format: {FORMAT}\n" + "".join(f"# {k}: {v}\n" for k, v in meta.items()))
        self.file.write(",".join(columns) + "\n")

    @property
    def is_open(self) -> bool:
        return self.file is not None

    def row(self, cells: list[str]) -> None:
        self.file.write(",".join(cells) + "\n")
        self.file.flush()

    def close(self, status: str = "completed") -> None:
        if self.file is not None and not self.file.closed:
            self.file.write(f"# end: {status}\n")
            self.file.close()


def read_live_log(path) -> tuple[dict, dict[str, np.ndarray]]:
    """The ``.live.csv`` read back: metadata and columns (blank estimate cells are nan)."""
    path = Path(path)
    meta, header, rows = {}, None, []
    for line in path.read_text().split("\n"):
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            meta[key.strip()] = value.strip()
        elif header is None and line.strip():
            header = line.split(",")
        elif line.strip():
            cells = line.split(",")
            rows.append([float(c) for c in cells] + [np.nan] * (len(header) - len(cells)))
    if header is None or not rows:
        raise CueingError(f"{path}: live log holds no frames")
    data = np.array(rows)
    return meta, {h: data[:, j] for j, h in enumerate(header)}

"""How runs are read and prepared: the one reader (:mod:`identify.data.io`), then the same steps
for every command. Notes go to stderr, as the reader's own; what was done is recorded in each
run's metadata (the result's provenance)."""
from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from ..errors import EstimationError


@dataclass(frozen=True)
class Reading:
    """``channel_map`` a map (dict), a JSON file or JSON text (see
    :func:`identify.data.io.load_channel_map`); ``nan`` the NaN policy inside the window
    ``t_start .. t_end`` (s); ``smooth`` a zero-phase low-pass (Hz) of every channel alike;
    ``trim`` ``first:1s``, ``mean`` or ``none`` (None: the data are used as they are)."""

    channel_map: dict | str | Path | None = None
    nan: str = "refuse"
    t_start: float | None = None
    t_end: float | None = None
    smooth: float | None = None
    trim: str | None = None

    def map(self) -> dict | None:
        from ..data.io import load_channel_map

        if self.channel_map is None or isinstance(self.channel_map, dict):
            return self.channel_map
        return load_channel_map(self.channel_map)

    def recorded(self, paths, profile=None, window: bool = True) -> list:
        """Every run of the files (CSV or .mat; a file split by time gaps gives several) in SI
        units, smoothed, cut to the window and trimmed as asked, but as recorded otherwise: no
        declared delay applied (the frequency responses, handling qualities and LOES judge the
        aircraft from the stick, its delays included). ``window``: the window applies (the
        analysed runs), else the whole files are read (held-out runs)."""
        return self._processed(self._read(paths, profile, window), profile, window, bool(paths))

    def prepared(self, paths, profile, window: bool = True) -> list:
        """:meth:`recorded`, the runs as ``profile`` needs them: a refined profile's delays applied
        and its pseudo-inputs built from the channels as read (before smoothing and trim)."""
        from ..model.pseudo_inputs import prepare

        return self._processed(prepare(profile, self._read(paths, profile, window)), profile, window, bool(paths))

    def _read(self, paths, profile, window: bool) -> list:
        from ..data.ingest import ReadOptions
        from ..data.io import read_run_files

        options = ReadOptions(self.nan, *((self.t_start, self.t_end) if window else (None, None)))
        return read_run_files(paths, self.map(), profile, options)

    def _processed(self, runs, profile, window: bool, required: bool) -> list:
        from ..data.preprocess import slice_run, smooth

        out = []
        for r in runs:
            if self.smooth is not None:  # every channel alike, inputs included: keeps the equations consistent
                r = smooth(r, self.smooth)
            if window and (self.t_start is not None or self.t_end is not None):
                if ("segment" in r.meta or "dropped_samples" in r.meta) and not self._overlaps(r):
                    print(f"note: {r.source} lies outside --t-start/--t-end: not used", file=sys.stderr)
                    continue
                r = slice_run(r, self.t_start, self.t_end)
            out.append(self._trimmed(r, profile))
        if required and not out:
            raise EstimationError("no run has samples between --t-start and --t-end")
        return out

    def _trimmed(self, run, profile):
        """``run`` minus its trim values, the profile's pseudo-inputs (a constant, the time, ...)
        left as they are; said once per run."""
        from ..data.preprocess import remove_trim
        from ..model.pseudo_inputs import specs

        if self.trim is None:
            return run
        if self.trim == "none":
            return remove_trim(run, "none")  # recorded: the data were taken as perturbations already
        pseudo = set(specs(profile)) if profile is not None else set()
        out = remove_trim(run, self.trim, [n for n in run.channels if n not in pseudo])
        print(f"note: {run.source}: trim removed ({self.trim}) from "
              f"{len(run.channels) - len(pseudo & set(run.channels))} channel(s)", file=sys.stderr)
        return out

    def _overlaps(self, run) -> bool:
        """Whether a run has two or more samples in the window (a gap's segment may have none)."""
        lo = -float("inf") if self.t_start is None else self.t_start
        hi = float("inf") if self.t_end is None else self.t_end
        return int(((run.time >= lo) & (run.time <= hi)).sum()) >= 2

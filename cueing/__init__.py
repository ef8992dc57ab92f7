"""cueing: the pilot's two-needle display, input sources, flight logs, practice scoring and the
live estimate while flying.

Uses :mod:`signaldesign` (signals) and :mod:`identify` (runs, models); :mod:`campaign` (whole
pipelines) sits above it.
"""
import os as _os

from identify._version import __version__  # noqa: F401 (one version for the whole project)

_os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # no pygame banner on stdout

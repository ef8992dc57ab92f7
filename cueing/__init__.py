"""cueing: the pilot's two-needle display, input sources, flight logs and practice scoring.

The top layer: uses :mod:`signaldesign` (signals) and :mod:`identify` (runs, models).
"""
import os as _os

from identify._version import __version__  # noqa: F401 (one version for the whole project)

_os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # no pygame banner on stdout

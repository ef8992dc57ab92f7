"""cueing: the pilot's two-needle display, input sources, flight logs and practice scoring.

The top layer: uses :mod:`signaldesign` (signals) and :mod:`identify` (runs, models).
"""
import os as _os

_os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # no pygame banner on stdout

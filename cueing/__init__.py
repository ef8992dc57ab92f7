"""cueing: the pilot's two-needle display, input sources, flight logs and practice scoring.

The top layer: uses :mod:`signaldesign` (signals) and :mod:`identify` (runs, models).
"""

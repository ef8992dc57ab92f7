"""Identification while the pilot flies: the recursive frequency-domain estimate in the cockpit.

``targets`` (what a test point is flown for) < ``log`` (the ``.live.csv``) < ``estimate`` (the
estimate, no drawing) < ``panel`` (its pygame panel beside the needles) and ``report`` (beside
post-flight ML) < ``session`` (:func:`fly_live`: fly, measured response into the run file, ML,
``<out>.live.md``). The aircraft's response comes from :mod:`cueing.response`.
"""
from .estimate import LiveIdentification
from .log import live_path, read_live_log
from .panel import LivePanel
from .session import fly_live
from .targets import parse_targets

__all__ = ["LiveIdentification", "LivePanel", "fly_live", "live_path", "parse_targets", "read_live_log"]

"""Identification while the pilot flies: the recursive frequency-domain estimate in the cockpit.

``targets`` (what a test point is flown for) < ``log`` (the ``.live.csv``) < ``estimate`` (the
estimate; no pygame) < ``panel`` (its pygame panel beside the needles) and ``report`` (beside
post-flight ML) < ``session`` (:func:`fly_live`: fly, measured response into the run file, ML,
``<out>.live.md``). The aircraft's response comes from :mod:`cueing.response`.

Names are imported on first use, so the estimate loads without the cockpit (pygame).
"""
from __future__ import annotations

import importlib

# public name -> submodule that defines it
_LAZY = {"LiveIdentification": "estimate", "live_path": "log", "read_live_log": "log", "LivePanel": "panel",
         "fly_live": "session", "parse_targets": "targets"}

__all__ = list(_LAZY)


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'cueing.live' has no attribute {name!r}")
    return getattr(importlib.import_module(f".{module}", __name__), name)

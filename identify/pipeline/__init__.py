"""The pipeline of one identification, the same for every caller.

read -> prepare (NaN policy, window, smoothing, trim, the profile's delays and pseudo-inputs)
-> fit -> checks (frequency-domain cost J, VERIFY on held-out runs, identifiability) -> a
complete result with its data's provenance -> write. ``python -m identify`` (parsing and
printing only), ``campaign identify`` and Python callers all go through :class:`Job`::

    from identify import Job
    est = Job(["run_lon.csv"], "profile.toml", method="ml", trim="first:1s").estimate()
    print(est.text())
    est.save("out")

:class:`Reading` is how runs are read and prepared, for the commands that do not fit a model
(``freq``, ``hq``, ``loes``, ``compat``, ``show``) too.
"""
from __future__ import annotations

from .job import Job
from .reading import Reading

__all__ = ["Job", "Reading"]

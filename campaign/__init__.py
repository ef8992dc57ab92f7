"""campaign: the package that runs whole pipelines and test campaigns.

The top layer: uses :mod:`cueing` (flying), :mod:`signaldesign` (input design) and
:mod:`identify` (estimation, refinement); nothing below imports it. ``python -m campaign demo``
runs the whole pipeline on the bundled default profile (:mod:`campaign.demo`); ``design``,
``identify``, ``stitch`` and ``report`` run a test campaign from a manifest (:mod:`campaign.manifest`,
docs/campaign.md) on a local process pool or Dask (:mod:`campaign.executors`).
"""

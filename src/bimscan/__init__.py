"""bimscan: labelled synthetic laser scans from BIM (IFC) models, tripod and mobile, at dataset scale.

An IFC model becomes labelled point clouds as a surveyor would scan the building: tripod stations
of a virtual terrestrial laser scanner (TLS) or a handheld or backpack scanner walked through it
(multi-beam lidars, SLAM-like drift), on the site as it stands (construction stage, clutter).
bimscan plans the survey (the fewest stations that cover the chosen elements at the asked
density), builds whole datasets of scenes x configurations, validates them, and trains a
segmentation network on them that it scores on real scans and adapts to a user's own unlabelled
scans. It brings a site scan back onto its model: aligned without a starting guess, each element
judged built, not built, hidden or out of tolerance, against the work schedule.

The pipeline, stage by stage (one subpackage each): ``ifc`` (parse; generated buildings) ->
``semantics`` (labels) -> ``site`` (the site as scanned) -> ``scan`` (scanner and lidar models,
sensor effects, ray engines) -> ``survey`` (stations, walks, multi-station and mobile runs; its
``planning``: survey planning) -> ``process`` (filters, checks, subsampling) -> ``io`` (LAS/LAZ,
E57, PLY, NumPy, OBJ, HELIOS++) -> ``dataset`` (local or on a Ray cluster) -> ``stats`` and
``render`` -> ``learn`` (training, evaluation, prediction, adaptation); ``compare`` (a site
scan against its model: alignment, progress); ``cli``, ``pipeline`` and ``sim2real`` compose them.
"""

from __future__ import annotations

import functools


@functools.cache
def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bimscan")
    except PackageNotFoundError:  # running from a source tree without installation
        return "0.0.0+source"


def __getattr__(name: str) -> str:
    # ``__version__`` is looked up when first asked for: importlib.metadata takes a tenth of a second,
    # and the command line's start-up, before its signal handlers are in place, stays that much shorter
    if name == "__version__":
        return _version()
    raise AttributeError(f"module 'bimscan' has no attribute {name!r}")


__all__ = ["__version__"]

"""bimscan: labelled synthetic terrestrial laser scans from BIM (IFC) models.

The pipeline, stage by stage (one subpackage each): ``ifc`` (parse) -> ``semantics`` (labels)
-> ``scan`` (virtual scanner, ray engine, noise) -> ``survey`` (stations, multi-station runs)
-> ``process`` (filters, checks) -> ``io`` (LAS/LAZ, PLY, NumPy, OBJ, HELIOS++) -> ``dataset``
-> ``stats`` -> ``learn``; ``cli`` and ``pipeline`` compose them.
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

"""bimscan: labelled synthetic terrestrial laser scans from BIM (IFC) models.

The pipeline, stage by stage (one subpackage each): ``ifc`` (parse) -> ``semantics`` (labels)
-> ``scan`` (virtual scanner, ray engine, noise) -> ``survey`` (stations, multi-station runs)
-> ``process`` (filters, checks) -> ``io`` (LAS/LAZ, PLY, NumPy, OBJ, HELIOS++) -> ``dataset``
-> ``stats`` -> ``learn``; ``cli`` and ``pipeline`` compose them.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("bimscan")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+source"

__all__ = ["__version__"]

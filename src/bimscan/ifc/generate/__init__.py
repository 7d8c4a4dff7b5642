"""Procedural IFC4 buildings (the embedded demo data): a seeded plan (``layout``) drawn from a
style table (``styles``), authored as IFC (``building``). ``make_building`` is the entry point."""

from bimscan.ifc.generate.building import (
    GeneratedBuilding,
    build_building_model,
    check_building_options,
    make_building,
)
from bimscan.ifc.generate.styles import DEFAULT_STYLE, STYLES

__all__ = [
    "DEFAULT_STYLE", "STYLES", "GeneratedBuilding", "build_building_model", "check_building_options", "make_building",
]

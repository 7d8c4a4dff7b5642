"""Procedural IFC4 buildings (the embedded demo data): a seeded plan (``layout``), authored as IFC
(``building``). ``make_building`` is the entry point."""

from bimscan.ifc.generate.building import (
    GeneratedBuilding,
    build_building_model,
    check_building_options,
    make_building,
)

__all__ = ["GeneratedBuilding", "build_building_model", "check_building_options", "make_building"]

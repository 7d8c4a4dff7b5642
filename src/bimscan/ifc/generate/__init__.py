"""Procedural IFC4 buildings (the embedded demo data): a seeded plan (``floor_plan``) drawn from a
style table (``styles``), authored as IFC (``building``). ``make_building`` is the entry point.

The authoring names load on first use: importing the style table (plain data, as the command
line does for its help) does not import IfcOpenShell.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bimscan.ifc.generate.styles import DEFAULT_STYLE, STYLES

if TYPE_CHECKING:
    from bimscan.ifc.generate.building import (
        GeneratedBuilding,
        build_building_model,
        check_building_options,
        make_building,
    )

_AUTHORING = ("GeneratedBuilding", "build_building_model", "check_building_options", "make_building")

__all__ = [
    "DEFAULT_STYLE", "STYLES", "GeneratedBuilding", "build_building_model", "check_building_options", "make_building",
]


def __getattr__(name: str) -> Any:
    if name in _AUTHORING:
        from bimscan.ifc.generate import building

        return getattr(building, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

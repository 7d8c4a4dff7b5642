"""IFC schema facts from IfcOpenShell: class inheritance and the set of known class names."""

from __future__ import annotations

from functools import cache

import ifcopenshell.ifcopenshell_wrapper as wrapper

SUPPORTED_SCHEMAS = ("IFC2X3", "IFC4", "IFC4X3_ADD2")


@cache
def class_ancestry(schema: str, ifc_class: str) -> tuple[str, ...]:
    """The class and its supertypes, nearest first: IfcWallStandardCase -> (IfcWallStandardCase, IfcWall, ...)."""
    try:
        declaration = wrapper.schema_by_name(schema).declaration_by_name(ifc_class)
    except (RuntimeError, IndexError):
        return (ifc_class,)
    chain = []
    while declaration is not None:
        chain.append(declaration.name())
        declaration = declaration.supertype()
    return tuple(chain)


@cache
def known_classes() -> frozenset[str]:
    """Every entity name of every supported schema (for checking label-scheme rules)."""
    names: set[str] = set()
    for schema in SUPPORTED_SCHEMAS:
        names.update(d.name() for d in wrapper.schema_by_name(schema).entities())
    return frozenset(names)

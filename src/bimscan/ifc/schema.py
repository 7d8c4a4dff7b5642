"""IFC schema facts from IfcOpenShell: class inheritance and the set of known class names."""

from __future__ import annotations

import difflib
from functools import cache

import ifcopenshell.ifcopenshell_wrapper as wrapper

SUPPORTED_SCHEMAS = ("IFC2X3", "IFC4", "IFC4X3_ADD2")
PRODUCT_ROOT = "IfcProduct"  # what stands in a scene: every component's class descends from it


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


@cache
def product_classes() -> dict[str, str]:
    """The classes of things a model places in space, ``IfcProduct`` and its subclasses in every
    supported schema: lower-case name -> the schemas' spelling (``"ifcdoor"`` -> ``"IfcDoor"``)."""
    names: dict[str, str] = {}
    for schema in SUPPORTED_SCHEMAS:
        for declaration in wrapper.schema_by_name(schema).entities():
            name = declaration.name()
            if PRODUCT_ROOT in class_ancestry(schema, name):
                names[name.lower()] = name
    return names


def nearest_product_class(name: str) -> str | None:
    """The product class (``product_classes``) spelt most like ``name``, or None when none is close."""
    close = difflib.get_close_matches(name.lower(), product_classes(), n=1, cutoff=0.6)
    return product_classes()[close[0]] if close else None

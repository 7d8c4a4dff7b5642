"""bimscan's own class vocabulary for what a site adds to a model (no IFC model holds these objects).

Every added object is a component whose ``ifc_class`` column holds one of ``SITE_CLASSES``:
``Clutter.<Kind>`` (furniture and site materials), ``Fixture.<Kind>`` (luminaires and air
terminals under the ceiling), ``Temporary.<Kind>`` (temporary works and equipment), ``Person.<Pose>`` or
``Terrain.Ground`` (the ground around the building, ``site.ground``). A class's ancestry is itself, its group (``Clutter``, ``Fixture``,
``Temporary``, ``Person``) and then the IFC class the object would be in a model
(``IfcFurniture``, ``IfcLightFixture``, ``IfcAirTerminal`` or ``IfcBuildingElementProxy``, with
their supertypes), so a label-scheme rule can name the exact
class, the group, or the IFC class::

    [[rules]]
    ifc_class = "Clutter.Chair"    # only chairs
    [[rules]]
    ifc_class = "Temporary"        # every temporary work

``site_class_names()`` is what rule checking accepts besides IFC classes (a misspelt name is
still an error).
"""

from __future__ import annotations

from dataclasses import dataclass

GROUPS = ("Clutter", "Fixture", "Temporary", "Person", "Terrain")


@dataclass(frozen=True)
class SiteClass:
    """One added object class: its group and the IFC classes it would be in a model, first known first
    (IFC2X3 has no IfcFurniture, IfcLightFixture or IfcAirTerminal: its furniture is
    IfcFurnishingElement, its light fixtures and air terminals IfcFlowTerminal)."""

    name: str
    group: str
    ifc_classes: tuple[str, ...]


_FURNITURE = ("IfcFurniture", "IfcFurnishingElement")
_PROXY = ("IfcBuildingElementProxy",)
_LIGHT = ("IfcLightFixture", "IfcFlowTerminal")
_AIR = ("IfcAirTerminal", "IfcFlowTerminal")

SITE_CLASSES: dict[str, SiteClass] = {
    c.name: c for c in (
        SiteClass("Clutter.Desk", "Clutter", _FURNITURE),
        SiteClass("Clutter.Chair", "Clutter", _FURNITURE),
        SiteClass("Clutter.Sofa", "Clutter", _FURNITURE),
        SiteClass("Clutter.Shelf", "Clutter", _FURNITURE),
        SiteClass("Clutter.Cabinet", "Clutter", _FURNITURE),
        SiteClass("Clutter.Whiteboard", "Clutter", _FURNITURE),
        SiteClass("Fixture.Luminaire", "Fixture", _LIGHT),
        SiteClass("Fixture.AirTerminal", "Fixture", _AIR),
        SiteClass("Clutter.MaterialStack", "Clutter", _PROXY),
        SiteClass("Clutter.Pallet", "Clutter", _PROXY),
        SiteClass("Clutter.Box", "Clutter", _PROXY),
        SiteClass("Clutter.Bucket", "Clutter", _PROXY),
        SiteClass("Clutter.CableDrum", "Clutter", _PROXY),
        SiteClass("Clutter.WasteBin", "Clutter", _PROXY),
        SiteClass("Temporary.Ladder", "Temporary", _PROXY),
        SiteClass("Temporary.Trestle", "Temporary", _PROXY),
        SiteClass("Temporary.ScaffoldTower", "Temporary", _PROXY),
        SiteClass("Temporary.Prop", "Temporary", _PROXY),
        SiteClass("Temporary.Container", "Temporary", _PROXY),
        SiteClass("Person.Standing", "Person", _PROXY),
        SiteClass("Person.Walking", "Person", _PROXY),
        SiteClass("Terrain.Ground", "Terrain", _PROXY),
    )
}


def site_class_names() -> frozenset[str]:
    """Every class name of bimscan's own vocabulary: the classes and their groups."""
    return frozenset(SITE_CLASSES) | frozenset(GROUPS)


def site_class_ancestry(name: str, ifc_ancestry: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    """The class, its group, then the first of its IFC classes that the model's schema knows, with
    that class's supertypes. ``ifc_ancestry``: IFC class -> its chain in the scene's schema (a
    chain of one means the schema does not know the class)."""
    cls = SITE_CLASSES[name]
    for ifc_class in cls.ifc_classes:
        chain = ifc_ancestry.get(ifc_class, (ifc_class,))
        if len(chain) > 1:
            return (name, cls.group) + chain
    return (name, cls.group)

"""Surface facts of each component from the IFC model: style colour, transparency, material names.

What a viewer shows is what the scanner's camera and laser see: the colour and transparency of a
component come from the surface styles (``IfcSurfaceStyle`` holding an
``IfcSurfaceStyleShading`` or ``IfcSurfaceStyleRendering``: ``SurfaceColour`` and
``Transparency``) of its body's representation items (``IfcStyledItem``, through mapped items and
boolean results), and, where the items carry none, of its materials
(``IfcMaterialDefinitionRepresentation``). Material names (``IfcMaterial``, layer, profile and
constituent sets, inherited from the element's type) are kept as written; the scanner maps them
to near-infrared reflectance through its own, overridable table (``bimscan.scan.surfaces``).

A component with several styles takes the colour of its most used opaque style and the highest
transparency among its styles: a window whose glazing is a transparent item is transparent (its
frame is a small part of its area).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator

import numpy as np

from bimscan.types import ComponentSurfaces

# Representations that are not the element's body (as in ifc/load.py) and hold no surface style.
_NOT_BODY = {"axis", "footprint", "box", "annotation", "reference", "profile", "clearance", "lighting", "cog",
             "survey", "plan"}
_MAX_DEPTH = 32  # mapped items nest; deeper chains are malformed
OPAQUE_BELOW = 0.5  # styles with less transparency count as opaque when choosing a colour


def read_surfaces(elements: Iterable) -> ComponentSurfaces:
    """The surface facts of ``elements`` (IfcOpenShell entities, in component order)."""
    cache: dict[int, tuple[str, tuple[float, float, float] | None, float] | None] = {}
    colors, transparency, styles, materials = [], [], [], []
    for element in elements:
        found = [s for s in (_surface_style(st, cache) for st in _item_styles(element)) if s is not None]
        names = _material_names(element)
        if not found:
            found = [s for s in (_surface_style(st, cache) for st in _material_styles(element)) if s is not None]
        color, alpha, name = _summarise(found)
        colors.append(color)
        transparency.append(alpha)
        styles.append(name)
        materials.append("; ".join(names))
    n = len(colors)
    return ComponentSurfaces(
        color=np.array(colors, dtype=np.float32).reshape(n, 3),
        transparency=np.array(transparency, dtype=np.float32),
        style=np.array(styles, dtype=str) if n else np.zeros(0, dtype="<U1"),
        material=np.array(materials, dtype=str) if n else np.zeros(0, dtype="<U1"),
    )


def _summarise(found: list[tuple[str, tuple[float, float, float] | None, float]]
               ) -> tuple[tuple[float, float, float], float, str]:
    """(colour, transparency, style name) of one component from its styles (one entry per styled item)."""
    nan = (float("nan"),) * 3
    if not found:
        return nan, 0.0, ""
    alpha = max(s[2] for s in found)
    opaque = [s for s in found if s[2] < OPAQUE_BELOW and s[1] is not None] or [s for s in found if s[1] is not None]
    if not opaque:
        return nan, alpha, found[0][0]
    counts = Counter((s[0], s[1]) for s in opaque)
    (name, color), _ = max(counts.items(), key=lambda kv: (kv[1], -opaque.index(next(s for s in opaque if (s[0], s[1]) == kv[0]))))
    return color, alpha, name  # type: ignore[return-value]


def _body_items(element) -> Iterator:
    representation = getattr(element, "Representation", None)
    if representation is None:
        return
    for rep in representation.Representations or ():
        if (rep.RepresentationIdentifier or "").lower() in _NOT_BODY:
            continue
        yield from rep.Items or ()


def _leaves(item, depth: int = 0) -> Iterator:
    """The item and what it is made of: mapped representations, boolean first operands."""
    if item is None or depth > _MAX_DEPTH:
        return
    yield item
    if item.is_a("IfcMappedItem"):
        source = item.MappingSource
        mapped = getattr(source, "MappedRepresentation", None) if source is not None else None
        for sub in (getattr(mapped, "Items", None) or ()):
            yield from _leaves(sub, depth + 1)
    elif item.is_a("IfcBooleanResult"):
        yield from _leaves(item.FirstOperand, depth + 1)


def _styles_of_styled_item(styled) -> Iterator:
    for style in styled.Styles or ():
        if style.is_a("IfcPresentationStyleAssignment"):  # IFC2X3 wraps styles in an assignment
            yield from style.Styles or ()
        else:
            yield style


def _item_styles(element) -> Iterator:
    """Presentation styles attached to the element's body items (one per styled item)."""
    for item in _body_items(element):
        for leaf in _leaves(item):
            for styled in getattr(leaf, "StyledByItem", None) or ():
                yield from _styles_of_styled_item(styled)


def _materials(element) -> list:
    import ifcopenshell.util.element as util

    try:
        return [m for m in util.get_materials(element) if m is not None and m.is_a("IfcMaterial")]
    except (AttributeError, TypeError, RuntimeError):  # malformed material associations: no materials
        return []


def _material_names(element) -> list[str]:
    names: list[str] = []
    for material in _materials(element):
        name = " ".join(str(material.Name or "").split())
        if name and name not in names:
            names.append(name)
    return names


def _material_styles(element) -> Iterator:
    for material in _materials(element):
        for definition in getattr(material, "HasRepresentation", None) or ():
            for rep in definition.Representations or ():
                for styled in rep.Items or ():
                    if styled.is_a("IfcStyledItem"):
                        yield from _styles_of_styled_item(styled)


def _surface_style(style, cache: dict) -> tuple[str, tuple[float, float, float] | None, float] | None:
    """(name, colour or None, transparency) of an IfcSurfaceStyle; None for other styles."""
    if style is None or not style.is_a("IfcSurfaceStyle"):
        return None
    key = style.id()
    if key not in cache:
        color, alpha = None, 0.0
        for element in style.Styles or ():
            if element.is_a("IfcSurfaceStyleShading"):  # Rendering is a subtype
                rgb = element.SurfaceColour
                if rgb is not None and rgb.is_a("IfcColourRgb"):
                    color = tuple(min(1.0, max(0.0, float(v or 0.0))) for v in (rgb.Red, rgb.Green, rgb.Blue))
                value = getattr(element, "Transparency", None)
                if value is not None:
                    alpha = min(1.0, max(0.0, float(value)))
        cache[key] = (str(style.Name or ""), color, alpha)
    return cache[key]

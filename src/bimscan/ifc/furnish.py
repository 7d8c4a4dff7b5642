"""Writing a site into an IFC copy: clutter as IfcFurniture / IfcBuildingElementProxy, the
elements a construction stage leaves out removed, so other tools see the scene bimscan scans.

``write_furnished(source, out, objects, removed)`` copies ``source`` with every ``FurnishObject``
added as an element of its IFC class (``ObjectType`` = bimscan's class, e.g. ``Clutter.Chair``),
its triangles as the body (IFC4/IFC4X3: IfcTriangulatedFaceSet; IFC2X3: IfcFacetedBrep), placed at
its lowest corner and contained in its storey (by name; else the lowest storey), and with the
elements whose GlobalIds are in ``removed`` deleted. Coordinates are converted to the project's
length unit. Partly opened ceilings stay whole in the copy (only their panels are cut in the scan).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import atomic_output, mark_ifc_written_by
from bimscan.ifc.output import check_ifc_output
from bimscan.ifc.schedule import open_model


@dataclass(frozen=True)
class FurnishObject:
    """One object to add: its GlobalId, IFC classes to use (first the schema knows), bimscan's
    class, name, storey name, and its closed mesh (vertices (V, 3) float64 world metres, faces
    (F, 3) int32)."""

    global_id: str
    ifc_classes: tuple[str, ...]
    object_type: str
    name: str
    storey: str
    vertices: np.ndarray
    faces: np.ndarray


def check_furnished_output(out: str | Path, *, source: str | Path | None = None, overwrite: bool = False) -> Path:
    """``out`` as a Path, or an OutputError now for a furnished copy that cannot be written there
    (``bimscan.ifc.output.check_ifc_output``: not ``.ifc``, the model ``source`` itself, a missing
    folder, something there without ``overwrite`` or that bimscan may not replace)."""
    return check_ifc_output(out, overwrite=overwrite, source=source, like="furnished.ifc",
                            role="the model being furnished")


def write_furnished(source: str | Path, out: str | Path, objects: Sequence[FurnishObject],
                    removed: Iterable[str] = (), *, overwrite: bool = False) -> int:
    """Write the furnished copy of ``source`` to ``out`` (atomically; an existing ``out`` only with
    ``overwrite``, and only an IFC bimscan wrote); returns the elements added. The copy's header adds
    the author "bimscan furnish" to the model's own."""
    import ifcopenshell.api
    import ifcopenshell.api.geometry  # noqa: F401  (registers the geometry api)
    import ifcopenshell.util.representation
    import ifcopenshell.util.unit

    source, out = Path(source), check_furnished_output(out, source=source, overwrite=overwrite)
    model = open_model(source)
    mark_ifc_written_by(model, "furnish")
    run = ifcopenshell.api.run
    scale = ifcopenshell.util.unit.calculate_unit_scale(model)  # project units -> metres
    gone = set(removed)
    for element in list(model.by_type("IfcElement")):
        if element.GlobalId in gone:
            run("root.remove_product", model, product=element)
    body = ifcopenshell.util.representation.get_context(model, "Model", "Body", "MODEL_VIEW")
    if body is None:
        parent = ifcopenshell.util.representation.get_context(model, "Model") or run(
            "context.add_context", model, context_type="Model")
        body = run("context.add_context", model, context_type="Model", context_identifier="Body",
                   target_view="MODEL_VIEW", parent=parent)
    storeys = {s.Name or "": s for s in model.by_type("IfcBuildingStorey")}
    lowest = min(storeys.values(), key=_elevation, default=None)
    schema = model.schema
    added = 0
    for obj in objects:
        ifc_class = next((c for c in obj.ifc_classes if _known(schema, c)), "IfcBuildingElementProxy")
        element = run("root.create_entity", model, ifc_class=ifc_class, name=obj.name)
        element.GlobalId = obj.global_id
        element.ObjectType = obj.object_type
        origin = obj.vertices.min(axis=0)
        local = (obj.vertices - origin) / scale
        representation = model.createIfcShapeRepresentation(
            body, "Body", "Tessellation" if schema != "IFC2X3" else "Brep", [_solid(model, local, obj.faces)])
        run("geometry.assign_representation", model, product=element, representation=representation)
        matrix = np.eye(4)
        matrix[:3, 3] = origin  # the api takes metres (SI) and converts to the project's unit
        run("geometry.edit_object_placement", model, product=element, matrix=matrix, is_si=True)
        container = storeys.get(obj.storey) or lowest
        if container is not None:
            run("spatial.assign_container", model, relating_structure=container, products=[element])
        added += 1
    try:
        with atomic_output(out) as temp:
            model.write(str(temp))
    except OSError as exc:
        raise OutputError(f"could not write {out}: {exc.strerror or exc}; check the folder and free space") from exc
    return added


def _known(schema: str, ifc_class: str) -> bool:
    from bimscan.ifc.schema import class_ancestry

    return len(class_ancestry(schema, ifc_class)) > 1


def _elevation(storey) -> float:
    return float(getattr(storey, "Elevation", None) or 0.0)


def _solid(model, vertices: np.ndarray, faces: np.ndarray):  # -> entity_instance
    points = [tuple(float(c) for c in v) for v in vertices]
    if model.schema == "IFC2X3":
        cartesian = [model.createIfcCartesianPoint(p) for p in points]
        loops = [model.createIfcFace([model.createIfcFaceOuterBound(model.createIfcPolyLoop(
            [cartesian[i] for i in face]), True)]) for face in faces.tolist()]
        return model.createIfcFacetedBrep(model.createIfcClosedShell(loops))
    point_list = model.createIfcCartesianPointList3D(points)
    return model.createIfcTriangulatedFaceSet(point_list, None, True, [tuple(int(i) + 1 for i in f) for f in faces])

"""Stage 1: parse an IFC model into one scannable mesh plus a component table.

``load_ifc`` reads IFC2X3, IFC4 and IFC4X3 through IfcOpenShell's geometry iterator on all
cores, in world coordinates, metres, Z up, openings cut from their hosts. Every building element
with 3D geometry becomes one component (dense id, GlobalId, IFC class, PredefinedType, name,
storey). Labels are applied afterwards, by a scheme (``bimscan.semantics.label_model``). Room volumes (IfcSpace) are kept aside for station planning; openings, virtual
elements, annotations and grids are not scannable. Elements whose geometry fails are reported
(GlobalId, class, reason) and skipped. Parsed geometry is cached by file content hash.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bimscan.errors import EmptyModelError, IfcError, InputFileError
from bimscan.files import file_sha256
from bimscan.ifc import cache as geometry_cache
from bimscan.ifc.materials import read_surfaces
from bimscan.ifc.schema import SUPPORTED_SCHEMAS, class_ancestry
from bimscan.progress import progress_bar
from bimscan.types import ComponentTable, FailedElement, ParsedModel, SceneMesh, Space, Storey

# Bumped whenever what _parse_model produces changes, so stale cache entries are never used.
LOADER_VERSION = 2  # 2: component surface styles and materials (ifc/materials.py)

# Representation identifiers that are never the element's solid body.
_NON_BODY_IDENTIFIERS = {
    "axis", "footprint", "box", "annotation", "reference", "profile", "clearance", "lighting", "cog",
    "survey", "plan",
}
# IfcElement subtypes that are not physical surfaces a laser can hit.
_NOT_SCANNABLE = ("IfcFeatureElement", "IfcVirtualElement")


def load_ifc(path: str | Path, *, use_cache: bool = True, threads: int | None = None) -> ParsedModel:
    """Parse an IFC file into a ParsedModel (no labels yet).

    path: an IFC-SPF file (.ifc) or a zip of one (.ifczip).
    use_cache: reuse geometry parsed before (keyed by file content hash and loader version;
    folder ``$BIMSCAN_CACHE_DIR`` or ``~/.cache/bimscan``). threads: geometry threads (all cores).
    Raises InputFileError (missing/unreadable), IfcError (not IFC, truncated, garbled,
    unsupported schema), EmptyModelError (no element with geometry).
    """
    path = Path(path)
    if path.is_file() and zipfile.is_zipfile(path):
        return _load_ifczip(path, use_cache=use_cache, threads=threads)
    _check_ifc_file(path)
    digest = file_sha256(path)
    key = f"{digest}-v{LOADER_VERSION}"
    parsed = geometry_cache.load_parsed(key) if use_cache else None
    if parsed is None:
        parsed = _parse_model(path, threads=threads or os.cpu_count() or 1)
        if use_cache:
            geometry_cache.store_parsed(key, parsed)
    return replace(parsed, source=str(path), file_sha256=digest)


def _load_ifczip(path: Path, *, use_cache: bool, threads: int | None) -> ParsedModel:
    """An .ifczip (a zip archive holding one IFC-SPF file): extract it to a temporary folder."""
    with zipfile.ZipFile(path) as archive:
        members = [m for m in archive.namelist() if m.lower().endswith(".ifc") and not m.endswith("/")]
        if len(members) != 1:
            raise IfcError(f"{path}: a zip archive with {len(members)} .ifc files; an .ifczip must hold exactly one")
        with tempfile.TemporaryDirectory(prefix="bimscan-ifczip-") as folder:
            extracted = Path(folder) / Path(members[0]).name
            with archive.open(members[0]) as source, extracted.open("wb") as target:
                shutil.copyfileobj(source, target, 8 << 20)
            model = load_ifc(extracted, use_cache=use_cache, threads=threads)
    return replace(model, source=str(path))


def _check_ifc_file(path: Path) -> None:
    """Clear errors for a missing, empty, non-IFC or truncated file before IfcOpenShell sees it."""
    if not path.exists():
        raise InputFileError(f"{path}: no such file; check the path")
    if not path.is_file():
        raise InputFileError(f"{path}: is a folder, not an IFC file")
    try:
        with path.open("rb") as handle:
            head = handle.read(4096)
            handle.seek(max(0, path.stat().st_size - 4096))
            tail = handle.read()
    except OSError as exc:
        raise InputFileError(f"{path}: cannot be read ({exc.strerror}); check its permissions") from exc
    if not head.strip():
        raise IfcError(f"{path}: the file is empty; export the model again")
    if not head.lstrip(b"\xef\xbb\xbf \t\r\n").upper().startswith(b"ISO-10303-21"):
        raise IfcError(f"{path}: not an IFC file (no ISO-10303-21 STEP header); pass an IFC-SPF (.ifc) export")
    if b"END-ISO-10303-21" not in tail.upper():
        raise IfcError(f"{path}: the IFC file is truncated (no END-ISO-10303-21; at its end); copy or export it again")


def _parse_model(path: Path, *, threads: int) -> ParsedModel:
    import ifcopenshell
    import ifcopenshell.util.unit

    # IfcOpenShell logs every failed element itself; we collect and report them instead.
    logging.getLogger("ifcopenshell").setLevel(logging.CRITICAL)
    log = ifcopenshell.ifcopenshell_wrapper.logger()
    log.output_format(ifcopenshell.ifcopenshell_wrapper.logger.FMT_INMEMORY)
    try:
        model = ifcopenshell.open(str(path), logger=log)
    except Exception as exc:  # IfcOpenShell raises its own Error type with parser messages
        raise IfcError(f"{path}: the IFC file could not be parsed ({exc}); check the export or repair the file") from exc
    # The parser recovers from syntax errors by skipping text, which silently loses elements:
    # a garbled file is refused rather than half-loaded. (Dangling references and missing
    # attributes, common in real exports, are not syntax errors and pass.)
    syntax_errors = [m for m in (str(x) for x in log.log_messages()) if "[SYN" in m]
    if syntax_errors:
        first = re.sub(r"^<log_message '|'>$", "", syntax_errors[0])
        raise IfcError(
            f"{path}: the IFC file is garbled ({len(syntax_errors)} syntax error(s), first: {first}); "
            "export or copy it again"
        )
    schema = model.schema_identifier
    if schema not in SUPPORTED_SCHEMAS:
        raise IfcError(f"{path}: schema {schema} is not supported; export as one of {', '.join(SUPPORTED_SCHEMAS)}")

    elements = sorted(_scannable_elements(model), key=lambda e: e.id())
    if not elements:
        raise EmptyModelError(f"{path}: the model has no building elements with 3D geometry; nothing to scan")
    shapes, failed = _triangulate(model, elements, threads=threads, what="elements")

    components = [e for e in elements if e.id() in shapes]
    if not components:
        raise EmptyModelError(
            f"{path}: no element produced geometry ({len(failed)} failed, e.g. {failed[0].ifc_class} "
            f"{failed[0].global_id}: {failed[0].reason}); check the model in an IFC viewer"
        )
    vertices, faces, face_component = [], [], []
    offset = 0
    for cid, element in enumerate(components):
        v, f = shapes[element.id()]
        vertices.append(v)
        faces.append(f + offset)
        face_component.append(np.full(len(f), cid, dtype=np.int32))
        offset += len(v)
    mesh = SceneMesh(
        vertices=np.ascontiguousarray(np.concatenate(vertices), dtype=np.float64),
        faces=np.ascontiguousarray(np.concatenate(faces), dtype=np.int32),
        face_component=np.concatenate(face_component),
    )
    unit_scale = ifcopenshell.util.unit.calculate_unit_scale(model)
    storeys = _storeys(model, unit_scale)
    table = _component_table(components, schema)
    spaces = _spaces(model, threads=threads)
    surfaces = read_surfaces(components)
    return ParsedModel(source=str(path), file_sha256="", schema=schema, mesh=mesh, components=table, storeys=storeys, spaces=spaces, failed=tuple(failed), surfaces=surfaces)


def _scannable_elements(model):  # -> list[entity_instance]
    out = []
    for element in model.by_type("IfcElement"):
        if any(element.is_a(t) for t in _NOT_SCANNABLE):
            continue
        if _has_body(element):
            out.append(element)
    return out


def _has_body(element) -> bool:
    representation = getattr(element, "Representation", None)
    if representation is None:
        return False
    for rep in representation.Representations or ():
        context = rep.ContextOfItems
        context_type = getattr(context, "ContextType", None) or getattr(getattr(context, "ParentContext", None), "ContextType", None)
        if context_type not in (None, "Model"):
            continue
        if (rep.RepresentationIdentifier or "").lower() in _NON_BODY_IDENTIFIERS:
            continue
        if (rep.RepresentationType or "") in ("Curve2D", "GeometricCurveSet", "Annotation2D", "Point", "PointCloud"):
            continue
        return True
    return False


def _triangulate(model, elements, *, threads: int, what: str):
    """Triangles of each element in world coordinates (metres); failures with a reason."""
    import ifcopenshell.geom

    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    shapes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    iterator = ifcopenshell.geom.iterator(settings, model, max(1, threads), include=elements)
    with progress_bar(total=len(elements), desc=f"triangulating {what}", unit="it") as bar:
        if iterator.initialize():
            while True:
                shape = iterator.get()
                v, f = _shape_arrays(shape.geometry)
                if len(f):
                    shapes[shape.id] = (v, f)
                bar.update(1)
                if not iterator.next():
                    break
    failed = []
    for element in elements:
        if element.id() in shapes:
            continue
        # The iterator drops failures silently; triangulate alone to learn why (or recover).
        try:
            shape = ifcopenshell.geom.create_shape(settings, element)
            v, f = _shape_arrays(shape.geometry)
            if len(f):
                shapes[element.id()] = (v, f)
                continue
            reason = "geometry produced no triangles"
        except Exception as exc:  # IfcOpenShell raises RuntimeError or its own errors per element
            reason = _short_reason(exc)
        failed.append(FailedElement(global_id=str(element.GlobalId), ifc_class=element.is_a(), reason=reason))
    return shapes, failed


def _short_reason(exc: Exception) -> str:
    """IfcOpenShell's message without the product dump (GlobalId and class are reported apart)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    text = re.sub(r"Product: #\d+=[^,]*\([^)]*\),\s*", "", text)
    return text if len(text) <= 300 else text[:297] + "..."


def _shape_arrays(geometry) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.frombuffer(geometry.verts_buffer, dtype=np.float64).reshape(-1, 3)
    faces = np.frombuffer(geometry.faces_buffer, dtype=np.int32).reshape(-1, 3)
    if len(faces) and (faces.max() >= len(vertices) or not np.isfinite(vertices).all()):
        return vertices[:0], faces[:0]
    return vertices.copy(), faces.copy()


def _storey_of(element) -> str:
    import ifcopenshell.util.element as util

    seen = 0
    current = element
    while current is not None and seen < 16:
        if current.is_a("IfcBuildingStorey"):
            return current.Name or ""
        parent = util.get_container(current) or util.get_aggregate(current) or _host_of_filling(current)
        current = parent
        seen += 1
    return ""


def _host_of_filling(element):
    """The wall a door or window sits in (through its opening), if any."""
    for fills in getattr(element, "FillsVoids", None) or ():
        opening = fills.RelatingOpeningElement
        for voids in getattr(opening, "VoidsElements", None) or ():
            return voids.RelatingBuildingElement
    return None


def _component_table(components, schema: str) -> ComponentTable:
    import ifcopenshell.util.element as util

    rows = []
    for element in components:
        parent = util.get_aggregate(element)
        rows.append((
            str(element.GlobalId), element.is_a(), str(util.get_predefined_type(element) or ""),
            str(element.Name or ""), _storey_of(element), parent.is_a() if parent is not None else "",
        ))
    columns = list(zip(*rows))
    ancestry = {cls: class_ancestry(schema, cls) for cls in sorted(set(columns[1]) | set(columns[5]) - {""})}
    return ComponentTable(
        global_id=np.array(columns[0], dtype=str),
        ifc_class=np.array(columns[1], dtype=str),
        predefined_type=np.array(columns[2], dtype=str),
        name=np.array(columns[3], dtype=str),
        storey=np.array(columns[4], dtype=str),
        parent_class=np.array(columns[5], dtype=str),
        label=np.zeros(len(rows), dtype=np.uint8),
        class_ancestry=ancestry,
    )


def _storeys(model, unit_scale: float) -> tuple[Storey, ...]:
    import ifcopenshell.util.placement as placement

    storeys = []
    for storey in model.by_type("IfcBuildingStorey"):
        if storey.ObjectPlacement is not None:
            z = float(placement.get_local_placement(storey.ObjectPlacement)[2][3]) * unit_scale
        else:
            z = float(storey.Elevation or 0.0) * unit_scale
        storeys.append(Storey(name=storey.Name or "", elevation_m=round(z, 6)))
    return tuple(sorted(storeys, key=lambda s: (s.elevation_m, s.name)))


def _spaces(model, *, threads: int) -> tuple[Space, ...]:
    spaces = sorted((s for s in model.by_type("IfcSpace") if _has_body(s)), key=lambda s: s.id())
    if not spaces:
        return ()
    shapes, _ = _triangulate(model, spaces, threads=threads, what="spaces")
    out = []
    for space in spaces:
        if space.id() not in shapes:
            continue  # a room without usable geometry only costs the station planner a hint
        v, f = shapes[space.id()]
        name = " ".join(filter(None, (space.Name, getattr(space, "LongName", None)))) or str(space.GlobalId)
        out.append(Space(global_id=str(space.GlobalId), name=name, storey=_storey_of(space), vertices=v, faces=f))
    return tuple(out)

"""On-disk cache of parsed IFC geometry, so the six scans of one scene parse it once.

Entries are keyed by the file's SHA-256 plus the loader version; each is one uncompressed
``.npz`` (arrays) and one ``.json`` (everything else), written atomically. The folder is
``$BIMSCAN_CACHE_DIR`` or ``~/.cache/bimscan``; deleting it is always safe.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from bimscan.files import atomic_output, write_atomic
from bimscan.ifc.report import FailedElement, IfcIssue, IfcLoadReport, IfcRepair
from bimscan.types import ComponentSurfaces, ComponentTable, ParsedModel, SceneMesh, Space, Storey

_TABLE_COLUMNS = ("global_id", "ifc_class", "predefined_type", "name", "storey", "parent_class")


def cache_dir() -> Path:
    """Where parsed geometry is kept."""
    root = os.environ.get("BIMSCAN_CACHE_DIR")
    return Path(root) if root else Path.home() / ".cache" / "bimscan"


def load_parsed(key: str) -> ParsedModel | None:
    """The cached parse for ``key``, or None when absent or unreadable (then it is re-parsed)."""
    folder = cache_dir() / "ifc"
    arrays_path, meta_path = folder / f"{key}.npz", folder / f"{key}.json"
    if not (arrays_path.is_file() and meta_path.is_file()):
        return None
    try:
        meta = json.loads(meta_path.read_text("utf-8"))
        with np.load(arrays_path, allow_pickle=False) as arrays:
            mesh = SceneMesh(vertices=arrays["vertices"], faces=arrays["faces"], face_component=arrays["face_component"],
                             face_transparency=arrays["face_transparency"] if "face_transparency" in arrays else None)
            table = ComponentTable(
                **{c: arrays[f"component_{c}"] for c in _TABLE_COLUMNS},
                label=np.zeros(len(arrays["component_global_id"]), dtype=np.uint8),
                class_ancestry={k: tuple(v) for k, v in meta["class_ancestry"].items()},
                step_id=arrays["component_step_id"],
            )
            v_split = np.cumsum(meta["space_vertex_counts"])[:-1]
            f_split = np.cumsum(meta["space_face_counts"])[:-1]
            space_vertices = np.split(arrays["space_vertices"], v_split) if meta["spaces"] else []
            space_faces = np.split(arrays["space_faces"], f_split) if meta["spaces"] else []
            surfaces = None
            if "surface_color" in arrays:
                surfaces = ComponentSurfaces(color=arrays["surface_color"], transparency=arrays["surface_transparency"],
                                             style=arrays["surface_style"], material=arrays["surface_material"])
        spaces = tuple(
            Space(vertices=np.ascontiguousarray(v), faces=np.ascontiguousarray(f), **s)
            for s, v, f in zip(meta["spaces"], space_vertices, space_faces)
        )
        return ParsedModel(
            source="", file_sha256="", schema=meta["schema"], mesh=mesh, components=table,
            storeys=tuple(Storey(**s) for s in meta["storeys"]), spaces=spaces,
            failed=tuple(FailedElement(**f) for f in meta["failed"]), surfaces=surfaces,
            report=_report_from(meta["report"]),
        )
    except (OSError, ValueError, KeyError, TypeError):
        return None  # a damaged entry is simply parsed again


def store_parsed(key: str, parsed: ParsedModel) -> None:
    """Write a cache entry atomically; a cache that cannot be written is skipped silently."""
    folder = cache_dir() / "ifc"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        spaces = parsed.spaces
        arrays = {
            "vertices": parsed.mesh.vertices, "faces": parsed.mesh.faces, "face_component": parsed.mesh.face_component,
            **{f"component_{c}": getattr(parsed.components, c) for c in _TABLE_COLUMNS},
            "component_step_id": (parsed.components.step_id if parsed.components.step_id is not None
                                  else np.zeros(len(parsed.components), dtype=np.int64)),
            "space_vertices": np.concatenate([s.vertices for s in spaces]) if spaces else np.empty((0, 3)),
            "space_faces": np.concatenate([s.faces for s in spaces]) if spaces else np.empty((0, 3), np.int32),
        }
        if parsed.mesh.face_transparency is not None:
            arrays["face_transparency"] = parsed.mesh.face_transparency
        if parsed.surfaces is not None:
            arrays |= {f"surface_{c}": getattr(parsed.surfaces, c) for c in ("color", "transparency", "style", "material")}
        meta = {
            "schema": parsed.schema,
            "class_ancestry": dict(parsed.components.class_ancestry),
            "storeys": [{"name": s.name, "elevation_m": s.elevation_m} for s in parsed.storeys],
            "failed": [dataclasses.asdict(f) for f in parsed.failed],
            "report": dataclasses.asdict(parsed.report),
            "spaces": [{"global_id": s.global_id, "name": s.name, "storey": s.storey} for s in spaces],
            "space_vertex_counts": [len(s.vertices) for s in spaces],
            "space_face_counts": [len(s.faces) for s in spaces],
        }
        with atomic_output(folder / f"{key}.npz") as temp, temp.open("wb") as handle:
            np.savez(handle, **arrays)
        write_atomic(folder / f"{key}.json", json.dumps(meta).encode())
    except OSError:
        return


def _report_from(document: dict) -> IfcLoadReport:
    return IfcLoadReport(
        declared_elements=int(document["declared_elements"]), length_unit_m=float(document["length_unit_m"]),
        length_unit_source=str(document["length_unit_source"]),
        repairs=tuple(IfcRepair(kind=r["kind"], per_class=dict(r["per_class"]), lines=tuple(r["lines"]))
                      for r in document["repairs"]),
        issues=tuple(IfcIssue(kind=i["kind"], count=int(i["count"]), lines=tuple(i["lines"]), example=str(i["example"]))
                     for i in document["issues"]),
    )

"""The bimscan cloud header as JSON, and label checks shared by the readers.

Every writer stores the same JSON document beside the points (a LAS EVLR, a PLY sidecar, the
NumPy folder's ``meta.json``), so a cloud explains itself whatever its format::

    {"bimscan_cloud": 1, "columns": [...], "n_points": N, "origin_m": [x, y, z],
     "scheme": {...}, "components": {column: [...], ...} | null, "stations": [...],
     "metadata": {...}}

``components`` is stored by column (one list per ``ComponentTable`` field), which keeps large
tables compact. Dumps are canonical (sorted keys, fixed separators) so equal headers give equal
bytes.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from bimscan.files import dump_json as canonical_json
from bimscan.errors import InputFileError, OutputError
from bimscan.types import (
    CloudHeader,
    ComponentTable,
    LabelClass,
    LabelRule,
    LabelScheme,
    PointCloud,
    Station,
    UNLABELLED,
)

HEADER_VERSION = 1
HEADER_KEY = "bimscan_cloud"
_TABLE_COLUMNS = ("global_id", "ifc_class", "predefined_type", "name", "storey", "parent_class")


def dump_json(document: Mapping[str, Any], *, indent: int | None = None) -> bytes:
    """Canonical JSON bytes of a header document (compact unless ``indent``); OutputError if not JSON-able."""
    try:
        return canonical_json(document, indent=indent)
    except (TypeError, ValueError) as exc:
        raise OutputError(
            f"cloud header is not JSON-able ({exc}); keep CloudHeader.metadata to dicts, lists, "
            "strings, finite numbers and booleans"
        ) from exc


def present_columns(chunk: PointCloud) -> tuple[str, ...]:
    """Names of the columns a chunk carries (``xyz`` always), in ``PointCloud.COLUMNS`` order."""
    return tuple(c for c in PointCloud.COLUMNS if getattr(chunk, c) is not None)


def header_to_document(header: CloudHeader, *, columns: tuple[str, ...], n_points: int) -> dict[str, Any]:
    """The JSON document stored with a cloud (see the module docstring)."""
    scheme = header.scheme
    document: dict[str, Any] = {
        HEADER_KEY: HEADER_VERSION,
        "columns": list(columns),
        "n_points": int(n_points),
        "origin_m": [float(v) for v in header.origin],
        "scheme": {
            "name": scheme.name,
            "default_label": scheme.default_label,
            "classes": [{"id": int(c.id), "name": c.name, "color": c.color} for c in scheme.classes],
            "rules": [
                {
                    "ifc_class": r.ifc_class, "label": r.label,
                    "predefined_types": list(r.predefined_types), "parent_class": r.parent_class,
                }
                for r in scheme.rules
            ],
        },
        "components": None,
        "stations": [
            {
                "id": int(s.id), "position": [float(v) for v in s.position],
                "heading_deg": float(s.heading_deg),
                "floor_z": None if s.floor_z is None else float(s.floor_z),
                "storey": s.storey, "room": s.room,
            }
            for s in header.stations
        ],
        "metadata": dict(header.metadata),
    }
    table = header.components
    if table is not None:
        components: dict[str, Any] = {c: [str(v) for v in getattr(table, c)] for c in _TABLE_COLUMNS}
        components["label"] = [int(v) for v in table.label]
        components["class_ancestry"] = {k: list(v) for k, v in table.class_ancestry.items()}
        document["components"] = components
    return document


def header_from_document(document: Mapping[str, Any], *, where: str) -> CloudHeader:
    """Rebuild a ``CloudHeader`` from its JSON document; ``where`` names the file for errors."""
    try:
        scheme_doc = document["scheme"]
        scheme = LabelScheme(
            name=str(scheme_doc["name"]),
            classes=tuple(
                LabelClass(id=int(c["id"]), name=str(c["name"]), color=str(c["color"]))
                for c in scheme_doc["classes"]
            ),
            rules=tuple(
                LabelRule(
                    ifc_class=str(r["ifc_class"]), label=str(r["label"]),
                    predefined_types=tuple(str(p) for p in r.get("predefined_types", ())),
                    parent_class=r.get("parent_class"),
                )
                for r in scheme_doc.get("rules", ())
            ),
            default_label=str(scheme_doc["default_label"]),
        )
        table_doc = document.get("components")
        table = None
        if table_doc is not None:
            table = ComponentTable(
                **{c: np.array(table_doc[c], dtype=str) for c in _TABLE_COLUMNS},
                label=np.array(table_doc["label"], dtype=np.uint8),
                class_ancestry={k: tuple(v) for k, v in table_doc.get("class_ancestry", {}).items()},
            )
        stations = tuple(Station.from_dict(s) for s in document.get("stations", ()))
        origin = tuple(float(v) for v in document.get("origin_m", (0.0, 0.0, 0.0)))
        return CloudHeader(
            scheme=scheme, components=table, stations=stations,
            origin=origin,  # type: ignore[arg-type]
            metadata=dict(document.get("metadata", {})),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputFileError(
            f"{where}: the stored bimscan header is damaged ({type(exc).__name__}: {exc}); "
            "write the cloud again with bimscan"
        ) from exc


def parse_document(raw: bytes, *, where: str) -> dict[str, Any] | None:
    """The bimscan header document in ``raw`` JSON bytes, or None when it is not one."""
    try:
        document = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFileError(f"{where}: the stored bimscan header is not valid JSON ({exc}); write the cloud again") from exc
    if not isinstance(document, dict) or HEADER_KEY not in document:
        return None
    if document[HEADER_KEY] != HEADER_VERSION:
        raise InputFileError(
            f"{where}: bimscan cloud header version {document[HEADER_KEY]!r} is not supported "
            f"(this bimscan reads version {HEADER_VERSION}); upgrade bimscan"
        )
    return document




def as_labels(values: np.ndarray, *, field: str, where: str) -> np.ndarray:
    """``values`` as (N,) uint8 class ids; anything but integers in 0..255 is an InputFileError.

    Float columns (CloudCompare stores scalar fields as float) are accepted when every value is
    a whole number in range. -1, the "ignore" label of Pointcept folders, becomes 255
    (``UNLABELLED``), which losses and metrics skip.
    """
    values = np.asarray(values)
    if values.dtype.kind in "if" and len(values) and (values == -1).any():
        values = np.where(values == -1, UNLABELLED, values)
    if len(values) == 0:
        return np.zeros(0, dtype=np.uint8)
    if values.dtype.kind not in "iuf" and values.dtype.kind != "b":
        raise InputFileError(f"{where}: labels in {field!r} have dtype {values.dtype}, not integers; name another label field")
    if values.dtype.kind == "f":
        bad = ~np.isfinite(values) | (values != np.round(values)) | (values < 0) | (values > 255)
    elif values.dtype.kind in "iu":
        bad = (values < 0) | (values > 255)
    else:
        bad = np.zeros(len(values), dtype=bool)
    if bad.any():
        example = values[np.flatnonzero(bad)[0]].item()
        raise InputFileError(
            f"{where}: labels in {field!r} must be integers in 0..255, found {example!r} "
            f"({int(bad.sum())} such values); name another label field"
        )
    return values.astype(np.uint8)

"""A dataset folder on disk: the manifest, unit folders, their metadata and checksums.

Layout of a built dataset (``OUT_DIR``)::

    manifest.json                   every unit and its status (the shape below; training reads it)
    dataset.json                    the resolved spec and the software that built it
    scenes/<scene>.ifc              generated demo buildings (IFC scenes stay where they are)
    scenes/<scene>.stations.json    the stations planned once per scene, reused by every configuration
    units/<scene>__<config>/        one data unit
        cloud.laz | cloud.las | cloud.ply (+ .ply.json) | cloud/ (NumPy folder)
        unit.json                   reproducible metadata: inputs, counts, extents, histogram, checksums
        timings.json                how long it took (kept apart: it differs from run to run)

``manifest.json``::

    {"format": "bimscan-dataset", "version": 1,
     "units": [{"id": str, "scene": str, "config": str, "status": "done" | "failed" | "pending",
                "error": str | null, "points": int, "files": {"laz": "units/<id>/cloud.laz", ...}}]}

JSON files are canonical (sorted keys, fixed indentation) and written atomically, so equal
content gives equal bytes and a reader never sees half a file. A unit folder is staged under a
hidden name in ``units/`` and renamed into place when complete: a unit folder that exists is
whole, and its checksums tell whether its files are still the ones written.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bimscan.errors import DatasetError, InputFileError
from bimscan.files import dump_json, file_sha256, temp_path, write_atomic

MANIFEST_NAME = "manifest.json"
DATASET_NAME = "dataset.json"
UNITS_DIR = "units"
SCENES_DIR = "scenes"
UNIT_NAME = "unit.json"
TIMINGS_NAME = "timings.json"
MANIFEST_FORMAT = "bimscan-dataset"
MANIFEST_VERSION = 1
UNIT_FORMAT = "bimscan-unit"
UNIT_VERSION = 1
STATUSES = ("done", "failed", "pending")


def write_json(path: Path, document: Mapping[str, Any]) -> None:
    """Write ``document`` to ``path`` as canonical JSON, atomically."""
    write_atomic(path, dump_json(document))


def read_json(path: Path) -> dict[str, Any]:
    """A JSON object from ``path``; DatasetError when it is missing, garbled or not an object."""
    try:
        document = json.loads(path.read_bytes())
    except FileNotFoundError as exc:
        raise DatasetError(f"{path}: missing; run the build again to rewrite it") from exc
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: not readable JSON ({exc}); run the build again to rewrite it") from exc
    if not isinstance(document, dict):
        raise DatasetError(f"{path}: expected a JSON object, got {type(document).__name__}")
    return document


def fingerprint(inputs: Mapping[str, Any]) -> str:
    """SHA-256 of the canonical JSON of a unit's inputs: equal inputs, equal fingerprint."""
    return hashlib.sha256(dump_json(inputs)).hexdigest()


def manifest_entry(*, unit: str, scene: str, config: str, status: str, error: str | None = None, points: int = 0,
                   files: Mapping[str, str] | None = None) -> dict[str, Any]:
    """One manifest row (``files`` relative to the dataset folder)."""
    if status not in STATUSES:
        raise ValueError(f"unit status {status!r} is not one of {STATUSES}")
    return {"id": unit, "scene": scene, "config": config, "status": status, "error": error, "points": int(points),
            "files": dict(files or {})}


def write_manifest(out_dir: Path, entries: list[dict[str, Any]]) -> None:
    """Write ``manifest.json`` atomically."""
    write_json(out_dir / MANIFEST_NAME, {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "units": entries})


def read_manifest(dataset_dir: str | Path) -> dict[str, Any]:
    """The manifest of a dataset folder, checked for its format and shape.

    Raises InputFileError when the folder or its manifest is missing, DatasetError when the
    manifest is not a bimscan dataset manifest.
    """
    folder = Path(dataset_dir)
    path = folder / MANIFEST_NAME
    if not folder.is_dir():
        raise InputFileError(f"{folder}: no such dataset folder; pass the OUT_DIR of 'bimscan build'")
    if not path.is_file():
        raise InputFileError(f"{folder}: no {MANIFEST_NAME}; pass the OUT_DIR of 'bimscan build'")
    document = read_json(path)
    if document.get("format") != MANIFEST_FORMAT or document.get("version") != MANIFEST_VERSION:
        raise DatasetError(f"{path}: not a {MANIFEST_FORMAT} manifest of version {MANIFEST_VERSION} (format "
                           f"{document.get('format')!r}, version {document.get('version')!r})")
    units = document.get("units")
    if not isinstance(units, list):
        raise DatasetError(f"{path}: 'units' must be a list")
    for entry in units:
        if not isinstance(entry, dict) or not {"id", "scene", "config", "status", "points", "files"} <= set(entry) \
                or entry["status"] not in STATUSES:
            raise DatasetError(f"{path}: malformed unit entry {entry!r}; rebuild the dataset")
    return document


def unit_dir(out_dir: Path, unit: str) -> Path:
    return out_dir / UNITS_DIR / unit


def verify_unit(folder: Path, *, expected_fingerprint: str) -> str | None:
    """Why the unit folder is not a finished unit of these inputs, or None when it is.

    Checks that ``unit.json`` is there and readable, was written for the same inputs (its
    fingerprint), and that every file it lists still has the SHA-256 recorded at build time.
    """
    meta_path = folder / UNIT_NAME
    if not meta_path.is_file():
        return "no unit.json"
    try:
        meta = read_json(meta_path)
    except DatasetError as exc:
        return str(exc)
    if meta.get("format") != UNIT_FORMAT or meta.get("version") != UNIT_VERSION:
        return f"unit.json has format {meta.get('format')!r} version {meta.get('version')!r}"
    if meta.get("fingerprint") != expected_fingerprint:
        return "built from other inputs (spec, scene file or software changed)"
    checksums = meta.get("checksums")
    files = meta.get("files")
    if not isinstance(checksums, dict) or not checksums or not isinstance(files, dict) or not files:
        return "unit.json lists no files"
    for name in files.values():
        if not (folder / name).exists():
            return f"{name} is missing"
    for name, digest in sorted(checksums.items()):
        path = folder / name
        if not path.is_file():
            return f"{name} is missing"
        if file_sha256(path) != digest:
            return f"{name} does not match its checksum"
    return None


def staging_dir(out_dir: Path, unit: str) -> Path:
    """A fresh hidden folder in ``units/`` to build ``unit`` in (renamed into place by replace_path)."""
    folder = temp_path(out_dir / UNITS_DIR / unit)
    folder.mkdir(parents=True)
    return folder


def remove_leftovers(out_dir: Path) -> int:
    """Delete staging folders and half-renamed files a killed build left in the dataset; returns how many."""
    removed = 0
    for folder in (out_dir / UNITS_DIR, out_dir / SCENES_DIR, out_dir):
        if not folder.is_dir():
            continue
        for entry in folder.iterdir():
            if entry.name.startswith(".") and entry.name.endswith((".tmp", ".old")):
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)
                removed += 1
    return removed

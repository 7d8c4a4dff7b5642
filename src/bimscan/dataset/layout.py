"""A dataset folder on disk: its layout, typed records of its JSON files, which unit file to read.

This module is the one owner of the folder's layout; the builder, the statistics, the learner
and the CLI ask it (``DatasetFolder``, ``Manifest``, ``UnitRecord``) instead of reading paths and
dicts of their own. Layout of a built dataset (``OUT_DIR``)::

    manifest.json                   every unit and its status (``Manifest``)
    dataset.json                    the resolved spec and the software that built it
    scenes/<scene>.ifc              generated buildings (IFC scenes stay where they are)
    scenes/<scene>.generated.json   the options, software and checksum a generated building was made with
    scenes/<scene>.stations.json    the stations planned once per scene, reused by every configuration
    scenes/<scene>.<site>.stations.json   the same for a scene dressed as a site (stage, clutter)
    scenes/<scene>.<site>.site.npz  that dressed scene (mesh, component table, what was placed),
                                    dressed once by the scene task and read by every unit
    units/<scene>__<config>/        one data unit
        cloud.laz | cloud.las | cloud.ply (+ .ply.json) | cloud/ (NumPy folder)
        unit.json                   reproducible metadata (``UnitRecord``)
        timings.json                how long it took (kept apart: it differs from run to run)
    .bimscan.json                   what bimscan wrote in the folder (``bimscan.files`` output folders)
    .lock                           held by the build running in the folder

The dataset folder is an output folder (``bimscan.files.prepare_output_folder``): a build writes
into a new or empty folder or one bimscan made (a folder with a bimscan ``manifest.json`` made
before folders had records counts too), replaces there only what its record lists, and leaves
anything else in it alone; a user's ``manifest.json`` is refused before any work.

JSON files are canonical (sorted keys, fixed indentation) and written atomically, so equal
content gives equal bytes and a reader never sees half a file. A unit folder is staged under a
hidden name in ``units/`` and renamed into place when complete: a unit folder that exists is
whole, and its checksums tell whether its files are still the ones written. A unit rebuilt over
an old one replaces it only when the old folder holds nothing but what its ``unit.json`` lists
(``FOLDER_OUTPUTS["unit"]``): files added to a unit folder by hand are never removed.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.errors import DatasetError, InputFileError
from bimscan.files import (
    FOLDER_OUTPUTS,
    FolderOutput,
    atomic_output,
    check_replaceable,
    dump_json,
    file_sha256,
    json_marker,
    prepare_output_folder,
    read_marker,
    remove_dead_temps,
    temp_path,
    write_atomic,
)
from bimscan.io import CLOUD_FORMATS, WRITABLE_FORMATS
from bimscan.types import BimScene, ComponentSurfaces, ComponentTable, SceneMesh, SiteState, Station

MANIFEST_NAME = "manifest.json"
DATASET_NAME = "dataset.json"
UNITS_DIR = "units"
SCENES_DIR = "scenes"
UNIT_NAME = "unit.json"
TIMINGS_NAME = "timings.json"
TRAJECTORY_NAME = "trajectory.csv"  # a mobile unit's walk (survey.trajectory)
LOCK_NAME = ".lock"
MANIFEST_FORMAT = "bimscan-dataset"
MANIFEST_VERSION = 1
UNIT_FORMAT = "bimscan-unit"
UNIT_VERSION = 4
STATIONS_FORMAT = "bimscan-stations"
STATIONS_VERSION = 1
SITE_FORMAT = "bimscan-site-scene"
SITE_VERSION = 5  # 4: each triangle's style transparency; 5: lay-in openings cut only the pieces they reach into
_SURFACE_COLUMNS = ("color", "transparency", "style", "material")
_SITE_COLUMNS = ("global_id", "ifc_class", "predefined_type", "name", "storey", "parent_class", "label")
STATUSES = ("done", "failed", "pending")
UNIT_SEPARATOR = "__"

# format name (bimscan.io's WRITABLE_FORMATS) -> the unit's cloud file name ("cloud": a NumPy folder)
FORMAT_FILES: dict[str, str] = {name: "cloud" + CLOUD_FORMATS[name][0] for name in WRITABLE_FORMATS}
# Which of a unit's files a reader takes: the fastest to decode first. All hold the same points
# (the NumPy folder as float32 around the cloud's origin, LAS/LAZ and E57 in 0.1 mm steps, PLY as doubles).
READ_ORDER = ("npy", "ply", "las", "laz", "e57")


def foreign_unit_entries(folder: Path) -> list[str] | None:
    """None unless ``folder`` is marked as a data unit (its ``unit.json`` has the unit format); then
    the files in it (by path inside it) that its record neither is nor lists, links included."""
    record = read_marker(folder / UNIT_NAME)
    if not json_marker(record, "format", UNIT_FORMAT):
        return None
    checksums = json.loads(record or b"{}").get("checksums")
    listed = set(checksums if isinstance(checksums, dict) else ()) | {UNIT_NAME, TIMINGS_NAME}
    foreign = []
    for root, dirs, files in os.walk(folder):  # links to folders are listed in dirs, not entered
        for name in files + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
            relative = Path(root, name).relative_to(folder).as_posix()
            if relative not in listed or os.path.islink(os.path.join(root, name)):
                foreign.append(relative)
    return sorted(foreign)


FOLDER_OUTPUTS["unit"] = FolderOutput(what="a bimscan data unit", foreign=foreign_unit_entries)


# What a build writes at the top of a dataset folder (``bimscan.files.prepare_output_folder`` names).
DATASET_OUTPUTS = (MANIFEST_NAME, DATASET_NAME, LOCK_NAME, f"{UNITS_DIR}/", f"{SCENES_DIR}/")


def is_earlier_dataset(folder: Path) -> bool:
    """Whether ``folder`` is a dataset folder made before output folders had records: its
    ``manifest.json`` is a bimscan dataset manifest."""
    return json_marker(read_marker(folder / MANIFEST_NAME), "format", MANIFEST_FORMAT)


def unit_id(scene: str, config: str) -> str:
    """The id (and folder name) of the unit of ``scene`` scanned with ``config``."""
    return f"{scene}{UNIT_SEPARATOR}{config}"


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


@dataclass(frozen=True)
class ManifestEntry:
    """One unit in ``manifest.json``: its status, point count and files (relative to the dataset)."""

    id: str
    scene: str
    config: str
    status: str
    error: str | None = None
    points: int = 0
    files: Mapping[str, str] = field(default_factory=dict)  # format key -> path relative to the dataset

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"unit status {self.status!r} is not one of {STATUSES}")

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "scene": self.scene, "config": self.config, "status": self.status,
                "error": self.error, "points": int(self.points), "files": dict(self.files)}

    @staticmethod
    def from_json(document: Any, *, where: str) -> ManifestEntry:
        try:
            files = document["files"]
            if not isinstance(files, dict) or not all(isinstance(v, str) for v in files.values()):
                raise TypeError("files must map format keys to paths")
            return ManifestEntry(id=str(document["id"]), scene=str(document["scene"]),
                                 config=str(document["config"]), status=document["status"],
                                 error=document.get("error"), points=int(document["points"]), files=dict(files))
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: malformed unit entry {document!r} ({exc}); rebuild the dataset") from exc

    def cloud_file(self, dataset_dir: str | Path) -> Path:
        """The unit's cloud to read (``READ_ORDER``); InputFileError when none is listed or it is gone."""
        key = next((k for k in READ_ORDER if k in self.files), None)
        if key is None:
            raise InputFileError(f"{Path(dataset_dir) / MANIFEST_NAME}: unit {self.id!r} lists no cloud among "
                                 f"{', '.join(READ_ORDER)}; rebuild the unit")
        path = Path(dataset_dir) / self.files[key]
        if not path.exists():
            raise InputFileError(f"{Path(dataset_dir) / MANIFEST_NAME}: unit {self.id!r} cloud {path} is missing; "
                                 "rebuild the unit")
        return path


def unit_folder_cloud(folder: str | Path) -> Path | None:
    """The cloud to read of a unit folder (``units/<scene>__<config>/``, by ``READ_ORDER``), None
    when ``folder`` is not one (no ``unit.json``, or no cloud beside it)."""
    folder = Path(folder)
    if not (folder / UNIT_NAME).is_file():
        return None
    files = (folder / FORMAT_FILES[name] for name in READ_ORDER if name in FORMAT_FILES)
    return next((path for path in files if path.exists()), None)


@dataclass(frozen=True)
class Manifest:
    """``manifest.json``: every unit of the dataset, in spec order."""

    units: tuple[ManifestEntry, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "units": [u.to_json() for u in self.units]}

    @staticmethod
    def from_json(document: dict[str, Any], *, where: str) -> Manifest:
        if document.get("format") != MANIFEST_FORMAT or document.get("version") != MANIFEST_VERSION:
            raise DatasetError(f"{where}: not a {MANIFEST_FORMAT} manifest of version {MANIFEST_VERSION} (format "
                               f"{document.get('format')!r}, version {document.get('version')!r})")
        units = document.get("units")
        if not isinstance(units, list):
            raise DatasetError(f"{where}: 'units' must be a list")
        return Manifest(units=tuple(ManifestEntry.from_json(u, where=where) for u in units))

    def done(self) -> list[ManifestEntry]:
        """The finished units."""
        return [u for u in self.units if u.status == "done"]


@dataclass(frozen=True)
class UnitRecord:
    """``unit.json``: everything a unit's bytes came from and what they hold (reproducible).

    inputs: what the fingerprint hashes (recipe, scene, scheme, formats, ...). stations: where
    the scanner stood. extents: {"min", "max", "size"} metres. class_histogram: class name ->
    points. station_counts: station id (text) -> points. files: format key -> name in the unit
    folder; checksums: file name -> SHA-256 of every file written. site: what dressing the scene
    as a site did (``types.SiteState.to_json``: components not built, objects placed per class);
    empty for the model as it is. ifc: what loading the IFC file repaired, assumed, found wrong
    (``report``, ``bimscan.ifc.summary.report_document``) and which declared elements produced
    no geometry (``failed``, with their cause).
    """

    id: str
    scene: str
    config: str
    fingerprint: str
    inputs: Mapping[str, Any]
    ifc_schema: str
    stations: tuple[Station, ...]
    device_warnings: tuple[str, ...]
    points: int
    points_scanned: int
    dropped_invalid: int
    dropped_by_voxel: int
    extents: Mapping[str, list[float]]
    class_histogram: Mapping[str, int]
    station_counts: Mapping[str, int]
    files: Mapping[str, str]
    checksums: Mapping[str, str]
    bytes: int
    site: Mapping[str, Any] = field(default_factory=dict)
    ifc: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        document = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        document["stations"] = [dataclasses.asdict(s) for s in self.stations]
        document["device_warnings"] = list(self.device_warnings)
        return {"format": UNIT_FORMAT, "version": UNIT_VERSION, **document}

    @staticmethod
    def from_json(document: dict[str, Any], *, where: str) -> UnitRecord:
        if document.get("format") != UNIT_FORMAT or document.get("version") != UNIT_VERSION:
            raise DatasetError(f"{where}: unit.json has format {document.get('format')!r} version "
                               f"{document.get('version')!r}, not {UNIT_FORMAT} {UNIT_VERSION}; rebuild the unit")
        try:
            values = {f.name: document[f.name] for f in dataclasses.fields(UnitRecord)}
            values["stations"] = tuple(Station.from_dict(s) for s in values["stations"])
            values["device_warnings"] = tuple(str(w) for w in values["device_warnings"])
            for name in ("points", "points_scanned", "dropped_invalid", "dropped_by_voxel", "bytes"):
                values[name] = int(values[name])
            for name in ("files", "checksums", "class_histogram", "station_counts", "extents", "inputs", "site", "ifc"):
                if not isinstance(values[name], dict):
                    raise TypeError(f"{name} must be an object")
            return UnitRecord(**values)
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{where}: unit.json is incomplete ({exc}); rebuild the unit") from exc

    def scheme_classes(self) -> list[dict[str, Any]]:
        """The label scheme's classes the unit was labelled with (id, name, color)."""
        return list(self.inputs["scheme"]["classes"])


def write_unit_record(unit_folder: Path, record: UnitRecord) -> None:
    """Write ``record`` as the ``unit.json`` of ``unit_folder`` (canonical, atomic)."""
    write_json(unit_folder / UNIT_NAME, record.to_json())


class DatasetFolder:
    """Paths and records of one dataset folder (it need not exist yet)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST_NAME

    @property
    def info_path(self) -> Path:
        return self.root / DATASET_NAME

    @property
    def units_dir(self) -> Path:
        return self.root / UNITS_DIR

    @property
    def scenes_dir(self) -> Path:
        return self.root / SCENES_DIR

    def unit_dir(self, unit: str) -> Path:
        return self.units_dir / unit

    def unit_record_path(self, unit: str) -> Path:
        return self.unit_dir(unit) / UNIT_NAME

    def generated_scene_path(self, scene: str) -> Path:
        return self.scenes_dir / f"{scene}.ifc"

    def generated_record_path(self, scene: str) -> Path:
        """What a generated scene was made from (options, software, checksum)."""
        return self.scenes_dir / f"{scene}.generated.json"

    def stations_path(self, scene: str, site_tag: str = "") -> Path:
        """Where the stations of a scene (dressed as the site ``site_tag`` names; "" for the model as
        it is) are stored."""
        return self.scenes_dir / (f"{scene}.{site_tag}.stations.json" if site_tag else f"{scene}.stations.json")

    def site_scene_path(self, scene: str, site_tag: str) -> Path:
        """Where the scene task keeps a scene dressed as the site ``site_tag`` names."""
        return self.scenes_dir / f"{scene}.{site_tag}.site.npz"

    def unit_files(self, unit: str, files: Mapping[str, str]) -> dict[str, str]:
        """A unit's files (format -> name in its folder) as manifest paths (relative to the dataset)."""
        return {fmt: f"{UNITS_DIR}/{unit}/{name}" for fmt, name in files.items()}

    def is_dataset(self) -> bool:
        return self.manifest_path.is_file()

    def prepare(self) -> None:
        """Check the folder can take a build, before any work, and make it (``DATASET_OUTPUTS``):
        OutputError for a user's folder or a user's file at one of the build's names."""
        prepare_output_folder(self.root, names=DATASET_OUTPUTS, made_by=is_earlier_dataset)

    def check_unit_folder(self, unit: str) -> None:
        """OutputError when something a build may not replace is where ``unit`` goes: a file, a
        link, a folder that is not a bimscan data unit, or a unit with files added to it."""
        path = self.unit_dir(unit)
        if os.path.lexists(path):
            check_replaceable(path, kind="unit")

    def read_manifest(self) -> Manifest:
        """The manifest, checked for its format and shape.

        Raises InputFileError when the folder or its manifest is missing, DatasetError when the
        manifest is not a bimscan dataset manifest.
        """
        if not self.root.is_dir():
            raise InputFileError(f"{self.root}: no such dataset folder; pass the OUT_DIR of 'bimscan build'")
        if not self.manifest_path.is_file():
            raise InputFileError(f"{self.root}: no {MANIFEST_NAME}; pass the OUT_DIR of 'bimscan build'")
        return Manifest.from_json(read_json(self.manifest_path), where=str(self.manifest_path))

    def write_manifest(self, manifest: Manifest) -> None:
        write_json(self.manifest_path, manifest.to_json())

    def read_unit(self, unit: str) -> UnitRecord:
        path = self.unit_record_path(unit)
        return UnitRecord.from_json(read_json(path), where=str(path))

    def read_stations(self, scene: str, site_tag: str = "") -> tuple[Station, ...]:
        """The stations a scene task stored."""
        path = self.stations_path(scene, site_tag)
        document = read_json(path)
        try:
            return tuple(Station.from_dict(s) for s in document["stations"])
        except (KeyError, TypeError, ValueError) as exc:
            raise DatasetError(f"{path}: damaged station file ({exc}); delete it and run the build again") from exc

    def staging_dir(self, unit: str) -> Path:
        """A fresh hidden folder in ``units/`` to build ``unit`` in (renamed into place when whole)."""
        folder = temp_path(self.unit_dir(unit))
        folder.mkdir(parents=True)
        return folder

    def remove_dead_temps(self) -> int:
        """Delete the staging folders and half-written files whose writer process has ended (those of
        the workers a stopped build has just ended), keeping those of live processes; returns how many."""
        return sum(remove_dead_temps(folder) for folder in (self.units_dir, self.scenes_dir, self.root))

    def remove_leftovers(self) -> int:
        """Delete staging folders and half-renamed files a killed build left; returns how many."""
        removed = 0
        for folder in (self.units_dir, self.scenes_dir, self.root):
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


def write_site_scene(path: Path, scene: BimScene, key: str) -> None:
    """Store a dressed scene's mesh, component table and site state (a NumPy ``.npz`` with fixed
    member dates, so equal scenes give equal bytes), written atomically; ``key`` says what it was
    dressed from (the stations key of its scene task)."""
    if scene.site is None:
        raise ValueError("only a scene dressed as a site is stored")
    meta = {"format": SITE_FORMAT, "version": SITE_VERSION, "key": key,
            "class_ancestry": dict(scene.components.class_ancestry),
            "unmapped_classes": dict(scene.unmapped_classes),
            "site": {"settings": dict(scene.site.settings), **scene.site.to_json(),
                     "free_floor_m2": scene.site.free_floor_m2}}
    arrays = {"vertices": scene.mesh.vertices, "faces": scene.mesh.faces, "face_component": scene.mesh.face_component,
              **{f"component_{c}": getattr(scene.components, c) for c in _SITE_COLUMNS},
              "meta": np.frombuffer(dump_json(meta), dtype=np.uint8)}
    if scene.mesh.face_transparency is not None:
        arrays["face_transparency"] = scene.mesh.face_transparency
    if scene.surfaces is not None:
        arrays |= {f"surface_{c}": getattr(scene.surfaces, c) for c in _SURFACE_COLUMNS}
    with atomic_output(path) as temp, zipfile.ZipFile(temp, "w", zipfile.ZIP_STORED) as archive:
        for name, array in arrays.items():
            member = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            with archive.open(member, "w", force_zip64=True) as handle:
                np.lib.format.write_array(handle, np.ascontiguousarray(array), allow_pickle=False)


def read_site_scene(path: Path, base: BimScene, key: str) -> BimScene | None:
    """The dressed scene stored at ``path`` on top of ``base`` (the scene as parsed and labelled),
    or None when it is missing, damaged or was dressed from something else (another ``key``)."""
    try:
        with np.load(path, allow_pickle=False) as arrays:
            meta = json.loads(arrays["meta"].tobytes())
            if meta.get("format") != SITE_FORMAT or meta.get("version") != SITE_VERSION or meta.get("key") != key:
                return None
            mesh = SceneMesh(vertices=arrays["vertices"], faces=arrays["faces"], face_component=arrays["face_component"],
                             face_transparency=arrays["face_transparency"] if "face_transparency" in arrays.files else None)
            table = ComponentTable(**{c: arrays[f"component_{c}"] for c in _SITE_COLUMNS},
                                   class_ancestry={k: tuple(v) for k, v in meta["class_ancestry"].items()})
            surfaces = (ComponentSurfaces(**{c: arrays[f"surface_{c}"] for c in _SURFACE_COLUMNS})
                        if "surface_color" in arrays.files else None)
        site = meta["site"]
        state = SiteState(settings=site["settings"], removed=site["removed"], placed=site["placed"],
                          rooms=int(site["rooms"]), free_floor_m2=float(site["free_floor_m2"]))
        return dataclasses.replace(base, mesh=mesh, components=table, unmapped_classes=meta["unmapped_classes"],
                                   site=state, surfaces=surfaces)
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile):
        return None  # dressed again by the unit


def verify_unit(folder: Path, *, expected_fingerprint: str) -> str | None:
    """Why the unit folder is not a finished unit of these inputs, or None when it is.

    Checks that ``unit.json`` is there and readable, was written for the same inputs (its
    fingerprint), and that every file it lists still has the SHA-256 recorded at build time.
    """
    path = folder / UNIT_NAME
    if not path.is_file():
        return "no unit.json"
    try:
        record = UnitRecord.from_json(read_json(path), where=str(path))
    except DatasetError as exc:
        return str(exc)
    if record.fingerprint != expected_fingerprint:
        return "built from other inputs (spec, scene file or software changed)"
    if not record.checksums or not record.files:
        return "unit.json lists no files"
    for name in record.files.values():
        if not (folder / name).exists():
            return f"{name} is missing"
    for name, digest in sorted(record.checksums.items()):
        file = folder / name
        if not file.is_file():
            return f"{name} is missing"
        if file_sha256(file) != digest:
            return f"{name} does not match its checksum"
    return None

"""E57 (ASTM E2807) clouds through libE57Format, as the ``pye57`` wheel ships it.

Layout of a bimscan E57 file (``scan.e57``):

- One ``/data3D`` entry per station (in stream order; a station whose points come back after
  another station's gets a further entry with the same pose, so the file keeps the stream's
  order; bimscan's surveys never do that). Each entry has a deterministic ``guid``, ``name``
  (``station <id>``), ``bimscan:stationId`` and a ``pose``: ``translation`` = the station's
  beam origin (world metres) and ``rotation`` = the unit quaternion (w, x, y, z) of its heading
  about +Z, so ``world = R @ local + translation``.
- Per point: ``cartesianX/Y/Z`` (metres in the station's frame: the scanner's own frame, its
  azimuth 0 along the station heading), ``sphericalRange/Azimuth/Elevation`` (metres and
  radians, of the same point), both scaled integers as scanner exports store them: 0.1 mm
  steps (as bimscan's LAS; +-214 km around the station) and 1e-7 rad steps (0.06 mm at 600 m),
  which libE57Format packs about twice as fast as doubles and in half the bytes;
  ``intensity`` (integer 0..65535,
  ``intensityLimits`` 0..65535), ``timeStamp`` (double, seconds since the start of the survey,
  as bimscan's ``time`` column; the entries have no ``acquisitionStart``), ``returnIndex`` 0 of
  ``returnCount`` 1 (E57 counts returns from 0; a return number 0, as LAS files that leave it
  unset have, is written as the first return, and a count below its return number as that
  number, as bimscan's LAS does), and ``rowIndex``/``columnIndex``: the scan
  grid of the rotating-mirror scanner, column = mirror line (one vertical profile per head
  step), row = pulse within the line (0 at the lowest elevation), with ``indexBounds``, so
  software that expects structured scans treats each entry as one. The grid is recovered
  exactly from ``time``: pulse = (time - station start) * pulse rate, with the station's clock
  starting at ``k * station duration`` for the k-th station of the header and the pulse pattern
  of ``metadata["settings"]`` and ``metadata["scanner"]`` (``bimscan.scan.pattern``); clouds
  without those (or without ``time``) are written without the grid.
- Extension fields in the namespace ``bimscan`` = ``urn:bimscan:e57:1`` (E57 extensions,
  which other readers skip): per point ``bimscan:label`` (integer 0..255, the class id) and
  ``bimscan:component`` (integer -1..C-1, the BIM component id); at the root
  ``bimscan:cloudHeader``: the full header document as JSON (label scheme and class table,
  component table, stations, origin, metadata; see ``bimscan.io._header``).
- A mobile scan's per-point ``ring``, ``channel`` and ``sensor_xyz`` (beam origins) have no E57
  field: such clouds are refused (``check_e57_columns``, also before any work by
  ``bimscan.io.check_cloud_output``) rather than written without them.
- Clouds without a ``station`` column are one entry posed at ``CloudHeader.origin``
  (``cartesian = xyz - origin``, no spherical fields, which need a sensor position); so are
  stations the header has no pose for when the header has no stations at all. A station id
  missing from a header that has stations is refused.
- Reproducible bytes: GUIDs are UUIDv5 of the header document; ``creationDateTime`` is
  ``SOURCE_DATE_EPOCH`` as GPS time when that is set and left out otherwise; points go to
  libE57Format in fixed blocks of ``E57_BLOCK_POINTS`` rows (its packets depend on the rows per
  write call), so the bytes do not depend on how the caller chunked the stream.

Reading takes any E57: poses are applied (world coordinates), spherical-only scans are
converted, points flagged invalid are dropped, ``station`` is ``bimscan:stationId`` or else the
scan's index in ``/data3D``, ``intensity`` is scaled from ``intensityLimits`` (or the field's
own bounds, else 0..1) to 0..65535, ``time`` is ``timeStamp`` as stored, and labels come from
``label_field`` (any numeric point field, e.g. ``bimscan:label`` or a foreign extension) or,
in bimscan's own files, ``bimscan:label``.

libE57Format's errors (through pye57) carry a multi-line debug report after their first line;
bimscan's messages quote the first line only.
"""

from __future__ import annotations

import datetime as dt
import math
import re
import shutil
import uuid
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bimscan import __version__
from bimscan.errors import ConfigError, InputFileError, OutputError
from bimscan.io._header import as_labels, dump_json, header_from_document, header_to_document, parse_document
from bimscan.io._labelled import CopyCheck, ExtraField, check_label_count, field_values_dtype
from bimscan.io._writer import StagedOutput, StreamingCloudWriter, WrittenCloud, check_input_path, source_date_epoch
from bimscan.types import CloudHeader, PointCloud

try:  # pye57's package __init__ also imports its high-level reader (and pyquaternion): skip it
    from pye57 import libe57
except ImportError as _exc:  # pragma: no cover - pye57 is a dependency; a broken install says so
    raise ImportError("bimscan's E57 support needs the pye57 package: pip install pye57") from _exc

E57_BLOCK_POINTS = 1 << 15  # rows per libE57Format write call: fixed, so bytes do not depend on chunking
READ_BLOCK_POINTS = 1 << 20  # rows per libE57Format read call
NAMESPACE_PREFIX = "bimscan"
NAMESPACE_URI = "urn:bimscan:e57:1"
HEADER_NODE = "bimscan:cloudHeader"
LABEL_FIELD = "bimscan:label"
COMPONENT_FIELD = "bimscan:component"
STATION_NODE = "bimscan:stationId"
INTENSITY_MAX = 65535
_GUID_NAMESPACE = uuid.UUID("0c6e5f9a-3b1d-5e27-8f4a-6d2c9b1e7a53")
_GPS_EPOCH = dt.datetime(1980, 1, 6, tzinfo=dt.UTC)
# UTC leap seconds since the GPS epoch (IERS Bulletin C): GPS time runs ahead of UTC by one
# more second from each of these days on (18 s since 2017).
_LEAP_DAYS = tuple(dt.datetime(y, m, 1, tzinfo=dt.UTC) for y, m in (
    (1981, 7), (1982, 7), (1983, 7), (1985, 7), (1988, 1), (1990, 1), (1991, 1), (1992, 7), (1993, 7),
    (1994, 7), (1996, 1), (1997, 7), (1999, 1), (2006, 1), (2009, 1), (2012, 7), (2015, 7), (2017, 1)))


def _reason(exc: Exception) -> str:
    """The first line of a libE57Format error (the rest is its debug report)."""
    return str(exc).strip().split("\n", 1)[0]


def _free_bytes(folder: Path) -> int:
    """Bytes available to this user in ``folder``'s file system."""
    return shutil.disk_usage(folder).free


def _write_error(exc: Exception, path: Path) -> OutputError:
    """The one-line OutputError for a libE57Format failure while writing ``path``.

    libE57Format reports a failed write without its errno; a file system with (almost) no space
    left is the usual cause and is named as such. Only its file errors (open, write, seek, ...)
    send the user to the folder; any other (a value outside a field's declared limits, ...) is
    named as it is.
    """
    if _free_bytes(path.parent) < (1 << 20):
        return OutputError(f"disk full while writing {path}; free space and run again")
    reason = _reason(exc)
    if re.search(r"\(Error\w*(Open|Write|Read|Seek|Close|File)\w*\)", reason):
        return OutputError(f"could not write {path} (libE57Format: {reason}); check the folder, its permissions and "
                           "free space, and run again")
    return OutputError(f"could not write {path}: libE57Format refused the points ({reason})")


# A mobile scan's per-point columns, which E57 (one pose per scan) has no field for, in words.
MOBILE_COLUMNS: dict[str, str] = {"sensor_xyz": "beam origins", "ring": "rings", "channel": "lidar channels"}


def check_e57_columns(path: str | Path, columns: tuple[str, ...]) -> None:
    """Raise OutputError when a cloud with ``columns`` cannot be written to E57 without losing some."""
    mobile = [words for column, words in MOBILE_COLUMNS.items() if column in columns]
    if mobile:
        raise OutputError(f"{path}: E57 stores one pose per scan and has no field for a mobile scan's "
                          f"{', '.join(mobile)}; write a mobile scan to .las, .laz, .ply or a folder")


# -- small helpers ----------------------------------------------------------------------------------

def gps_seconds(unix_seconds: int) -> float:
    """GPS time (seconds since 1980-01-06, leap seconds included) of a Unix time."""
    moment = dt.datetime.fromtimestamp(unix_seconds, tz=dt.UTC)
    leaps = sum(moment >= day for day in _LEAP_DAYS)
    return (moment - _GPS_EPOCH).total_seconds() + leaps


def heading_quaternion(heading_deg: float) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation by ``heading_deg`` about +Z."""
    half = math.radians(heading_deg) / 2.0
    return (math.cos(half), 0.0, 0.0, math.sin(half))


def quaternion_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    """The (3, 3) float64 rotation matrix of the quaternion (w, x, y, z), normalised first."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / math.sqrt(sum(v * v for v in q))
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def _guid(text: str) -> str:
    return "{" + str(uuid.uuid5(_GUID_NAMESPACE, text)) + "}"


@dataclass(frozen=True)
class E57Scan:
    """One ``/data3D`` entry: its name, bimscan station id (None in foreign files), point count
    and pose: translation (3,) metres and rotation quaternion (w, x, y, z)."""

    index: int
    name: str
    station_id: int | None
    n_points: int
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]


@dataclass(frozen=True)
class _Grid:
    """What turns a point's time into its scan-grid cell (see the module docstring)."""

    pattern: Any  # bimscan.scan.pattern.PulsePattern
    start: dict[int, float]  # station id -> the station's clock start, seconds
    row_max: int
    column_max: int


def _scan_grid(header: CloudHeader) -> _Grid | None:
    """The scan grid of a bimscan survey's cloud, or None when the header does not describe one."""
    # The pulse schedule belongs to the scanner stage; E57's grid indices are derived from it.
    from bimscan.scan.device import ScannerModel, ScanSettings
    from bimscan.scan.pattern import PulsePattern
    from bimscan.toml_files import build_dataclass

    settings_doc, scanner_doc = header.metadata.get("settings"), header.metadata.get("scanner")
    if not isinstance(settings_doc, Mapping) or not isinstance(scanner_doc, Mapping) or not header.stations:
        return None
    try:
        settings = build_dataclass(ScanSettings, settings_doc, where="metadata settings")
        scanner = build_dataclass(ScannerModel, scanner_doc, where="metadata scanner")
    except ConfigError:
        return None
    pattern = PulsePattern.of(settings, scanner)
    if pattern.n_lines == 0:
        return None
    start, stop = pattern.line_pulses(0, pattern.n_lines)
    duration = settings.duration_s()
    return _Grid(pattern=pattern, start={s.id: k * duration for k, s in enumerate(header.stations)},
                 row_max=max(int((stop - start).max()) - 1, 0), column_max=pattern.n_lines - 1)


# -- writing ----------------------------------------------------------------------------------------

COORDINATE_STEP_M = 1e-4  # cartesian and range steps: bimscan's LAS resolution
ANGLE_STEP_RAD = 1e-7
_INT32_MAX = int(np.iinfo(np.int32).max)
# Scaled integer fields: name -> (scale, raw minimum, raw maximum)
_SCALED_FIELDS: dict[str, tuple[float, int, int]] = {
    **{name: (COORDINATE_STEP_M, -_INT32_MAX, _INT32_MAX) for name in ("cartesianX", "cartesianY", "cartesianZ")},
    "sphericalRange": (COORDINATE_STEP_M, 0, _INT32_MAX),
    "sphericalAzimuth": (ANGLE_STEP_RAD, -math.ceil(math.pi / ANGLE_STEP_RAD), math.ceil(math.pi / ANGLE_STEP_RAD)),
    "sphericalElevation": (ANGLE_STEP_RAD, -math.ceil(math.pi / 2 / ANGLE_STEP_RAD),
                           math.ceil(math.pi / 2 / ANGLE_STEP_RAD)),
}

# Point fields: name -> NumPy dtype of the block buffer. pye57 maps buffers by their struct
# format: uint8 'B', uint16 'H', int64 'q' (np.longlong), float64 'd'. (Its 'l' means int32,
# which NumPy's int64 reports on Linux: never hand it np.int64.)
_FIELD_DTYPES: dict[str, type] = {
    "cartesianX": np.float64, "cartesianY": np.float64, "cartesianZ": np.float64,
    "sphericalRange": np.float64, "sphericalAzimuth": np.float64, "sphericalElevation": np.float64,
    "intensity": np.uint16, "timeStamp": np.float64, "returnIndex": np.uint8, "returnCount": np.uint8,
    "rowIndex": np.longlong, "columnIndex": np.longlong, LABEL_FIELD: np.uint8, COMPONENT_FIELD: np.longlong,
    "colorRed": np.uint8, "colorGreen": np.uint8, "colorBlue": np.uint8,
}
COLOR_FIELDS = ("colorRed", "colorGreen", "colorBlue")


class _OpenScan:
    """The ``/data3D`` entry being written: its writer and the bounds of what it holds."""

    def __init__(self, node: Any, writer: Any, station: int | None) -> None:
        self.node = node
        self.writer = writer
        self.station = station
        self.n_points = 0
        self.return_high = 0
        self.low = np.full(3, np.inf)
        self.high = np.full(3, -np.inf)
        self.spherical_low = np.full(3, np.inf)  # range, azimuth, elevation
        self.spherical_high = np.full(3, -np.inf)
        self.grid_low = np.full(2, np.iinfo(np.int64).max)  # row, column
        self.grid_high = np.full(2, -1)


class E57CloudWriter(StreamingCloudWriter):
    """Streams ``PointCloud`` chunks into an E57 file, one ``/data3D`` entry per station."""

    def __init__(self, path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                 fields: tuple[ExtraField, ...] = ()) -> None:
        if fields:
            raise ValueError(f"{path}: the E57 writer stores no extra fields (see e57_carriable)")
        super().__init__(path, header=header, overwrite=overwrite, checksum=checksum)
        self._image: Any = None
        self._fields: tuple[str, ...] = ()
        self._buffers: dict[str, np.ndarray] = {}  # one block of every point field, handed to libE57Format
        self._scratch = np.zeros(0)  # (E57_BLOCK_POINTS,) f8 work space
        self._native_buffers: Any = None
        self._fill = 0
        self._scan: _OpenScan | None = None
        self._n_scans = 0
        self._poses = {s.id: s for s in header.stations}
        self._posed = False
        self._grid: _Grid | None = None
        self._root_guid = ""
        self._returns = False

    # -- layout ---------------------------------------------------------------------------------
    def _begin(self, columns: tuple[str, ...]) -> None:
        check_e57_columns(self.path, columns)
        temp = self._stage_file(self.path)
        self._posed = "station" in columns and bool(self.header.stations)
        self._grid = _scan_grid(self.header) if self._posed and "time" in columns else None
        fields = ["cartesianX", "cartesianY", "cartesianZ"]
        if self._posed:
            fields += ["sphericalRange", "sphericalAzimuth", "sphericalElevation"]
        if "intensity" in columns:
            fields.append("intensity")
        if "time" in columns:
            fields.append("timeStamp")
        fields += ["returnIndex", "returnCount"]
        if "rgb" in columns:
            fields += list(COLOR_FIELDS)
        if self._grid is not None:
            fields += ["rowIndex", "columnIndex"]
        if "label" in columns:
            fields.append(LABEL_FIELD)
        if "component" in columns:
            fields.append(COMPONENT_FIELD)
        self._fields = tuple(fields)
        self._returns = "return_number" in columns
        self._buffers = {name: np.zeros(E57_BLOCK_POINTS, dtype=_FIELD_DTYPES[name]) for name in self._fields}
        self._scratch = np.zeros(E57_BLOCK_POINTS)
        if "returnCount" in self._buffers:
            self._buffers["returnCount"][:] = 1
        self._root_guid = _guid(dump_json(header_to_document(self.header, columns=columns, n_points=0)).decode("utf-8"))
        try:
            self._image = libe57.ImageFile(str(temp), "w")
            self._write_root()
            self._native_buffers = libe57.VectorSourceDestBuffer()
            for name in self._fields:
                self._native_buffers.append(
                    libe57.SourceDestBuffer(self._image, name, self._buffers[name], E57_BLOCK_POINTS, True, True))
        except libe57.E57Exception as exc:
            raise _write_error(exc, self.path) from exc

    def _write_root(self) -> None:
        image, root = self._image, self._image.root()
        image.extensionsAdd("", libe57.E57_V1_0_URI)
        image.extensionsAdd(NAMESPACE_PREFIX, NAMESPACE_URI)
        root.set("formatName", libe57.StringNode(image, "ASTM E57 3D Imaging Data File"))
        root.set("guid", libe57.StringNode(image, self._root_guid))
        root.set("versionMajor", libe57.IntegerNode(image, libe57.E57_FORMAT_MAJOR))
        root.set("versionMinor", libe57.IntegerNode(image, libe57.E57_FORMAT_MINOR))
        root.set("e57LibraryVersion", libe57.StringNode(image, f"bimscan {__version__} ({libe57.E57_LIBRARY_ID})"))
        root.set("coordinateMetadata", libe57.StringNode(image, ""))  # local metres: no CRS is known
        epoch = source_date_epoch()
        if epoch is not None:
            created = libe57.StructureNode(image)
            created.set("dateTimeValue", libe57.FloatNode(image, gps_seconds(epoch)))
            created.set("isAtomicClockReferenced", libe57.IntegerNode(image, 0, 0, 1))
            root.set("creationDateTime", created)
        root.set("data3D", libe57.VectorNode(image, True))
        root.set("images2D", libe57.VectorNode(image, True))

    def _pose(self, station: int | None) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """(translation, quaternion) of a station's entry; the origin for unposed entries."""
        if not self._posed or station is None:
            return tuple(float(v) for v in self.header.origin), (1.0, 0.0, 0.0, 0.0)  # type: ignore[return-value]
        pose = self._poses.get(station)
        if pose is None:
            raise OutputError(
                f"{self.path}: points of station {station} but the header has no station {station} "
                f"(it has {', '.join(str(s) for s in sorted(self._poses))}); pass every station in CloudHeader.stations")
        return tuple(float(v) for v in pose.position), heading_quaternion(pose.heading_deg)  # type: ignore[return-value]

    def _prototype(self) -> Any:
        image = self._image
        prototype = libe57.StructureNode(image)
        bounds: dict[str, tuple[int, int]] = {
            "intensity": (0, INTENSITY_MAX), LABEL_FIELD: (0, 255),
            "colorRed": (0, 255), "colorGreen": (0, 255), "colorBlue": (0, 255),
            # E57 counts returns from 0; scans without the beam footprint have one return per pulse
            "returnIndex": (0, 254) if self._returns else (0, 0), "returnCount": (1, 255) if self._returns else (1, 1),
            COMPONENT_FIELD: (-1, len(self.header.components) - 1 if self.header.components is not None
                              else int(np.iinfo(np.int32).max)),
        }
        if self._grid is not None:
            bounds["rowIndex"] = (0, self._grid.row_max)
            bounds["columnIndex"] = (0, self._grid.column_max)
        for name in self._fields:
            if name in bounds:
                low, high = bounds[name]
                prototype.set(name, libe57.IntegerNode(image, low, low, max(high, low)))
            elif name in _SCALED_FIELDS:
                scale, low, high = _SCALED_FIELDS[name]
                prototype.set(name, libe57.ScaledIntegerNode(image, 0, low, high, scale, 0.0))
            else:
                prototype.set(name, libe57.FloatNode(image, 0.0, libe57.E57_DOUBLE))
        return prototype

    # -- data3D entries -------------------------------------------------------------------------
    def _open_scan(self, station: int | None) -> None:
        image = self._image
        translation, rotation = self._pose(station)
        node = libe57.StructureNode(image)
        image.root()["data3D"].append(node)
        node.set("guid", libe57.StringNode(image, _guid(f"{self._root_guid}/data3D/{self._n_scans}")))
        pose_station = self._poses.get(station) if station is not None else None
        name = f"station {station}" if station is not None else "scan"
        if pose_station is not None and pose_station.room:
            name += f" ({pose_station.room})"
        node.set("name", libe57.StringNode(image, name))
        node.set("description", libe57.StringNode(image, f"bimscan {__version__} virtual terrestrial laser scan"))
        scanner = self.header.metadata.get("scanner")
        if isinstance(scanner, Mapping) and scanner.get("description"):
            node.set("sensorModel", libe57.StringNode(image, str(scanner["description"])))
        if station is not None:
            node.set(STATION_NODE, libe57.IntegerNode(image, int(station), 0, 65535))
        pose = libe57.StructureNode(image)
        quaternion = libe57.StructureNode(image)
        for key, value in zip("wxyz", rotation, strict=True):
            quaternion.set(key, libe57.FloatNode(image, value))
        offset = libe57.StructureNode(image)
        for key, value in zip("xyz", translation, strict=True):
            offset.set(key, libe57.FloatNode(image, value))
        pose.set("rotation", quaternion)
        pose.set("translation", offset)
        node.set("pose", pose)
        points = libe57.CompressedVectorNode(image, self._prototype(), libe57.VectorNode(image, True))
        node.set("points", points)
        writer = points.writer(self._native_buffers)
        self._scan = _OpenScan(node, writer, station)
        self._n_scans += 1

    def _close_scan(self) -> None:
        scan = self._scan
        if scan is None:
            return
        self._flush()
        scan.writer.close()
        self._scan = None
        image, node = self._image, scan.node
        if scan.n_points == 0:
            return
        cartesian = libe57.StructureNode(image)
        for axis, name in enumerate("xyz"):
            cartesian.set(f"{name}Minimum", libe57.FloatNode(image, float(scan.low[axis])))
            cartesian.set(f"{name}Maximum", libe57.FloatNode(image, float(scan.high[axis])))
        node.set("cartesianBounds", cartesian)
        if "sphericalRange" in self._buffers:
            spherical = libe57.StructureNode(image)
            for key, value in (("rangeMinimum", scan.spherical_low[0]), ("rangeMaximum", scan.spherical_high[0]),
                               ("azimuthStart", scan.spherical_low[1]), ("azimuthEnd", scan.spherical_high[1]),
                               ("elevationMinimum", scan.spherical_low[2]),
                               ("elevationMaximum", scan.spherical_high[2])):
                spherical.set(key, libe57.FloatNode(image, float(value)))
            node.set("sphericalBounds", spherical)
        index = libe57.StructureNode(image)
        if "rowIndex" in self._buffers:
            index.set("rowMinimum", libe57.IntegerNode(image, int(scan.grid_low[0])))
            index.set("rowMaximum", libe57.IntegerNode(image, int(scan.grid_high[0])))
            index.set("columnMinimum", libe57.IntegerNode(image, int(scan.grid_low[1])))
            index.set("columnMaximum", libe57.IntegerNode(image, int(scan.grid_high[1])))
        index.set("returnMinimum", libe57.IntegerNode(image, 0))
        index.set("returnMaximum", libe57.IntegerNode(image, int(scan.return_high)))
        node.set("indexBounds", index)
        if "colorRed" in self._buffers:
            limits = libe57.StructureNode(image)
            for name in ("Red", "Green", "Blue"):
                limits.set(f"color{name}Minimum", libe57.IntegerNode(image, 0))
                limits.set(f"color{name}Maximum", libe57.IntegerNode(image, 255))
            node.set("colorLimits", limits)
        if "intensity" in self._buffers:
            limits = libe57.StructureNode(image)
            limits.set("intensityMinimum", libe57.IntegerNode(image, 0))
            limits.set("intensityMaximum", libe57.IntegerNode(image, INTENSITY_MAX))
            node.set("intensityLimits", limits)

    def _flush(self) -> None:
        if self._fill and self._scan is not None:
            self._scan.writer.write(self._fill)
        self._fill = 0

    # -- points ---------------------------------------------------------------------------------
    def _append(self, chunk: PointCloud, values: np.ndarray | None) -> None:
        try:
            if chunk.station is None:
                if self._scan is None:
                    self._open_scan(None)
                self._feed(chunk)
                return
            cuts = np.flatnonzero(np.diff(chunk.station)) + 1
            for start, stop in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(chunk)]]), strict=True):
                station = int(chunk.station[start])
                if self._scan is None or self._scan.station != station:
                    self._close_scan()
                    self._open_scan(station)
                whole = (start, stop) == (0, len(chunk))
                self._feed(chunk if whole else chunk.take(slice(int(start), int(stop))))
        except libe57.E57Exception as exc:
            raise _write_error(exc, self.path) from exc

    def _feed(self, part: PointCloud) -> None:
        """Encode the rows of one station into the block buffers, writing every full block."""
        done = 0
        while done < len(part):
            take = min(len(part) - done, E57_BLOCK_POINTS - self._fill)
            rows = part if take == len(part) else part.take(slice(done, done + take))
            self._encode(rows, slice(self._fill, self._fill + take))
            self._fill += take
            done += take
            if self._fill == E57_BLOCK_POINTS:
                self._flush()

    def _encode(self, rows: PointCloud, into: slice) -> None:
        scan = self._scan
        assert scan is not None
        translation, rotation = self._pose(scan.station)
        local = rows.xyz - np.asarray(translation)
        if rotation != (1.0, 0.0, 0.0, 0.0):
            local = local @ quaternion_matrix(rotation)  # R^T applied to row vectors
        buffers = self._buffers
        x, y, z = (buffers[name][into] for name in ("cartesianX", "cartesianY", "cartesianZ"))
        for axis, column in enumerate((x, y, z)):
            column[...] = local[:, axis]
        if len(rows):  # bounds from the contiguous buffers; NaN and inf show up in them too
            low, high = [c.min() for c in (x, y, z)], [c.max() for c in (x, y, z)]
            reach = _INT32_MAX * COORDINATE_STEP_M
            if not (np.isfinite(low).all() and np.isfinite(high).all()):
                raise OutputError(f"{self.path}: non-finite coordinates in station {scan.station}; drop them first")
            if min(low) < -reach or max(high) > reach:
                raise OutputError(
                    f"{self.path}: points {max(-min(low), max(high)):.6g} m from the pose of "
                    f"{'station ' + str(scan.station) if scan.station is not None else 'the origin'} do not fit E57's "
                    "0.1 mm integer steps (+-214 km); give stations (or CloudHeader.origin) near the points")
            np.minimum(scan.low, low, out=scan.low)
            np.maximum(scan.high, high, out=scan.high)
        if "sphericalRange" in buffers:
            horizontal = np.hypot(x, y, out=self._scratch[: len(rows)])
            spherical = (np.hypot(horizontal, z, out=buffers["sphericalRange"][into]),
                         np.arctan2(y, x, out=buffers["sphericalAzimuth"][into]),
                         np.arctan2(z, horizontal, out=buffers["sphericalElevation"][into]))
            if len(rows):
                np.minimum(scan.spherical_low, [c.min() for c in spherical], out=scan.spherical_low)
                np.maximum(scan.spherical_high, [c.max() for c in spherical], out=scan.spherical_high)
        if "intensity" in buffers:
            buffers["intensity"][into] = rows.intensity
        if "timeStamp" in buffers:
            buffers["timeStamp"][into] = rows.time
        if self._returns:
            # LAS files that leave return numbers unset hold 0 (LAS 1.4 counts from 1): the first return
            number = np.maximum(rows.return_number, 1)
            np.subtract(number, 1, out=buffers["returnIndex"][into])
            np.maximum(rows.number_of_returns, number, out=buffers["returnCount"][into])
            if len(rows):
                scan.return_high = max(scan.return_high, int(number.max()) - 1)
        if "colorRed" in buffers:
            for channel, name in enumerate(COLOR_FIELDS):
                buffers[name][into] = rows.rgb[:, channel]
        if "rowIndex" in buffers:
            row, column = self._grid_cells(rows.time, scan.station)  # type: ignore[arg-type]
            buffers["rowIndex"][into] = row
            buffers["columnIndex"][into] = column
            if len(row):
                np.minimum(scan.grid_low, (row.min(), column.min()), out=scan.grid_low)
                np.maximum(scan.grid_high, (row.max(), column.max()), out=scan.grid_high)
        if LABEL_FIELD in buffers:
            buffers[LABEL_FIELD][into] = rows.label
        if COMPONENT_FIELD in buffers:
            component = rows.component
            high = len(self.header.components) - 1 if self.header.components is not None else np.iinfo(np.int32).max
            if len(component) and (component.min() < -1 or component.max() > high):
                bad = int(component[(component < -1) | (component > high)][0])
                raise OutputError(f"{self.path}: component id {bad} is outside the header's component table "
                                  f"(-1..{high}); pass the table the ids refer to")
            buffers[COMPONENT_FIELD][into] = component
        scan.n_points += len(rows)

    def _grid_cells(self, time: np.ndarray, station: int) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) int64 of points of ``station`` from their time (see the module docstring)."""
        grid = self._grid
        assert grid is not None
        pattern = grid.pattern
        exact = (time - grid.start[station]) * pattern.pulse_freq_hz
        pulse = np.rint(exact)
        if len(pulse) and (np.abs(exact - pulse).max() > 1e-3 or pulse.min() < 0 or pulse.max() >= pattern.total_pulses):
            raise OutputError(
                f"{self.path}: the times of station {station} are not pulse times of the scan settings in the "
                "header metadata; write the survey's own times, or drop metadata['settings'] to write without the scan grid")
        pulse = pulse.astype(np.int64)
        line, _ = pattern.phase(pulse)
        first, last = int(line.min()), int(line.max())
        starts, stops = pattern.line_pulses(first, last + 1)
        row = pulse - starts[line - first]
        if len(row) and ((row < 0).any() or (pulse >= stops[line - first]).any()):  # pragma: no cover - pattern bug
            raise OutputError(f"{self.path}: pulses of station {station} fall outside their mirror line's window")
        return row, line

    def _finish(self) -> None:
        assert self.columns is not None
        try:
            self._close_scan()
            document = header_to_document(self.header, columns=self.columns, n_points=self.n_points)
            self._image.root().set(HEADER_NODE, libe57.StringNode(self._image, dump_json(document).decode("utf-8")))
            image, self._image = self._image, None
            image.close()
        except libe57.E57Exception as exc:
            raise _write_error(exc, self.path) from exc

    def _release(self) -> None:
        image, self._image = self._image, None
        scan, self._scan = self._scan, None
        try:
            if scan is not None and scan.writer.isOpen():
                scan.writer.close()
            if image is not None and image.isOpen():
                image.cancel()  # discards the unfinished file (abort removes it too)
        except libe57.E57Exception:
            pass  # the output is being discarded; a failing close changes nothing
        self._native_buffers = None
        self._buffers = {}
        self._scratch = np.zeros(0)
        super()._release()


def open_e57_writer(path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                    fields: tuple[ExtraField, ...] = ()) -> E57CloudWriter:
    """An E57 writer (registered as ``WRITERS["e57"]``); it takes no extra ``fields``."""
    return E57CloudWriter(path, header=header, overwrite=overwrite, checksum=checksum, fields=fields)


def e57_carriable(fields: tuple[ExtraField, ...]) -> tuple[tuple[ExtraField, ...], tuple[str, ...]]:
    """The E57 writer carries no other format's fields (an E57 field outside the standard needs a
    namespace of its own): all of ``fields``, in words."""
    return (), tuple(repr(field.name) for field in fields)


# -- reading ----------------------------------------------------------------------------------------

_SIGNATURE = b"ASTM-E57"


def _open(path: Path) -> Any:
    with path.open("rb") as handle:  # a plain message for files that are not E57 at all
        signature = handle.read(len(_SIGNATURE))
    if signature != _SIGNATURE:
        raise InputFileError(f"{path}: not an E57 file (no ASTM-E57 signature); check the file")
    try:
        return libe57.ImageFile(str(path), "r")
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: not a readable E57 file ({_reason(exc)}); check the file") from exc


def _has_namespace(image: Any) -> bool:
    """True when the file declares bimscan's extension prefix with bimscan's URI."""
    return any(image.extensionsPrefix(i) == NAMESPACE_PREFIX and image.extensionsUri(i) == NAMESPACE_URI
               for i in range(image.extensionsCount()))


def _stored_document(image: Any, path: Path) -> dict[str, Any] | None:
    root = image.root()
    if not _has_namespace(image) or not root.isDefined(HEADER_NODE):
        return None
    return parse_document(root[HEADER_NODE].value().encode("utf-8"), where=str(path))


def _number(node: Any) -> float:
    """The value of an Integer, ScaledInteger or Float node."""
    return float(node.scaledValue() if isinstance(node, libe57.ScaledIntegerNode) else node.value())


def _field_bounds(node: Any) -> tuple[float, float] | None:
    """The declared (minimum, maximum) of a numeric prototype field, None when unbounded (floats)."""
    if isinstance(node, libe57.IntegerNode):
        return float(node.minimum()), float(node.maximum())
    if isinstance(node, libe57.ScaledIntegerNode):
        return float(node.scaledMinimum()), float(node.scaledMaximum())
    return None


def _scan_pose(scan: Any) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    translation, rotation = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
    if scan.isDefined("pose"):
        pose = scan["pose"]
        if pose.isDefined("translation"):
            node = pose["translation"]
            translation = [_number(node[k]) if node.isDefined(k) else 0.0 for k in "xyz"]
        if pose.isDefined("rotation"):
            node = pose["rotation"]
            rotation = [_number(node[k]) if node.isDefined(k) else 0.0 for k in "wxyz"]
    return tuple(translation), tuple(rotation)  # type: ignore[return-value]


def _scans(image: Any) -> list[Any]:
    root = image.root()
    if not root.isDefined("data3D"):
        return []
    data3d = root["data3D"]
    return [libe57.StructureNode(data3d.get(i)) for i in range(data3d.childCount())]


def read_e57_scans(path: str | Path) -> list[E57Scan]:
    """The ``/data3D`` entries of an E57 file: names, station ids, point counts and poses."""
    path = check_input_path(path)
    image = _open(path)
    try:
        result = []
        for index, scan in enumerate(_scans(image)):
            translation, rotation = _scan_pose(scan)
            station = int(scan[STATION_NODE].value()) if _has_namespace(image) and scan.isDefined(STATION_NODE) else None
            result.append(E57Scan(
                index=index, name=scan["name"].value() if scan.isDefined("name") else "", station_id=station,
                n_points=int(libe57.CompressedVectorNode(scan.get("points")).childCount()),
                translation=translation, rotation=rotation))
        return result
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: the E57 structure is damaged ({_reason(exc)}); check the file") from exc
    finally:
        image.close()


def count_e57_points(path: str | Path) -> int:
    """Point records an E57 file holds (every scan's ``points`` vector, by its header)."""
    return sum(scan.n_points for scan in read_e57_scans(path))


def read_e57_header(path: str | Path) -> CloudHeader | None:
    """The ``CloudHeader`` bimscan stored in an E57 file, or None for a foreign file."""
    path = check_input_path(path)
    image = _open(path)
    try:
        document = _stored_document(image, path)
    finally:
        image.close()
    return None if document is None else header_from_document(document, where=str(path))


@dataclass
class _Plan:
    """What to read from every scan of a file, decided once so every chunk has the same columns."""

    columns: set[str]
    label_source: str | None
    bimscan: bool


def _prototype_names(scan: Any) -> set[str]:
    prototype = libe57.StructureNode(libe57.CompressedVectorNode(scan.get("points")).prototype())
    return {prototype.get(i).elementName() for i in range(prototype.childCount())}


def _plan(image: Any, scans: list[Any], document: dict[str, Any] | None, label_field: str | None, path: Path) -> _Plan:
    names = [_prototype_names(scan) for scan in scans]
    for index, present in enumerate(names):
        if not ({"cartesianX", "cartesianY", "cartesianZ"} <= present
                or {"sphericalRange", "sphericalAzimuth", "sphericalElevation"} <= present):
            raise InputFileError(f"{path}: scan {index} has neither cartesian nor spherical coordinates; check the file")
    if label_field is not None:
        missing = [i for i, present in enumerate(names) if label_field not in present]
        if missing:
            fields = ", ".join(sorted(names[missing[0]]))
            raise InputFileError(f"{path}: scan {missing[0]} has no point field {label_field!r} to read labels "
                                 f"from; it has {fields}")
    if document is not None:
        columns = set(document["columns"])
        label_source = label_field or (LABEL_FIELD if "label" in columns else None)
    else:
        every = set.intersection(*names) if names else set()
        columns = {"xyz", "station"} | ({"intensity"} if "intensity" in every else set()) \
            | ({"time"} if "timeStamp" in every else set()) \
            | ({"return_number", "number_of_returns"} if {"returnIndex", "returnCount"} <= every else set()) \
            | ({"rgb"} if set(COLOR_FIELDS) <= every else set())
        label_source = label_field
    if label_source is not None:
        columns.add("label")
    else:
        columns.discard("label")
    return _Plan(columns=columns, label_source=label_source, bimscan=document is not None)


def _read_scan(image: Any, scan: Any, index: int, plan: _Plan, path: Path, block: int) -> Iterator[PointCloud]:
    """The points of one ``/data3D`` entry in world coordinates, block by block."""
    points = libe57.CompressedVectorNode(scan.get("points"))
    total = int(points.childCount())
    prototype = libe57.StructureNode(points.prototype())
    present = _prototype_names(scan)
    cartesian = {"cartesianX", "cartesianY", "cartesianZ"} <= present
    coordinates = ("cartesianX", "cartesianY", "cartesianZ") if cartesian else \
        ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
    invalid = "cartesianInvalidState" if cartesian else "sphericalInvalidState"
    wanted: dict[str, type] = {name: np.float64 for name in coordinates}
    if invalid in present:
        wanted[invalid] = np.longlong
    if "intensity" in plan.columns:
        wanted["intensity"] = np.float64
    if "time" in plan.columns:
        wanted["timeStamp"] = np.float64
    if plan.label_source is not None:
        wanted[plan.label_source] = np.float64
    if "component" in plan.columns and COMPONENT_FIELD in present:
        wanted[COMPONENT_FIELD] = np.longlong
    if "return_number" in plan.columns:
        wanted["returnIndex"] = np.longlong
        wanted["returnCount"] = np.longlong
    if "rgb" in plan.columns:
        wanted.update({name: np.float64 for name in COLOR_FIELDS})
    color_low, color_high = 0.0, 255.0
    if "rgb" in plan.columns and scan.isDefined("colorLimits"):  # other tools store 0..65535 or 0..1
        limits = scan["colorLimits"]
        color_low, color_high = _number(limits["colorRedMinimum"]), _number(limits["colorRedMaximum"])
    station = np.uint16(index)
    if plan.bimscan and scan.isDefined(STATION_NODE):
        station = np.uint16(scan[STATION_NODE].value())
    translation, rotation = _scan_pose(scan)
    matrix = quaternion_matrix(rotation)
    identity = rotation == (1.0, 0.0, 0.0, 0.0)
    low, high = 0.0, float(INTENSITY_MAX)
    if "intensity" in wanted:
        if scan.isDefined("intensityLimits"):
            limits = scan["intensityLimits"]
            low, high = _number(limits["intensityMinimum"]), _number(limits["intensityMaximum"])
        else:
            low, high = _field_bounds(prototype["intensity"]) or (0.0, 1.0)  # float intensities: 0..1
    capacity = max(1, min(block, total))
    buffers = {name: np.zeros(capacity, dtype=dtype) for name, dtype in wanted.items()}
    native = libe57.VectorSourceDestBuffer()
    for name in wanted:
        native.append(libe57.SourceDestBuffer(image, name, buffers[name], capacity, True, True))
    reader = points.reader(native)
    try:
        while True:
            n = reader.read()
            if n == 0:
                break
            keep = slice(0, n) if invalid not in buffers else np.flatnonzero(buffers[invalid][:n] == 0)
            first, second, third = (buffers[name][keep] for name in coordinates)
            if not cartesian:  # range, azimuth, elevation
                first, second, third = (first * np.cos(third) * np.cos(second), first * np.cos(third) * np.sin(second),
                                        first * np.sin(third))
            local = np.stack([first, second, third], axis=1).astype(np.float64)
            xyz = (local if identity else local @ matrix.T) + np.asarray(translation)
            count = len(xyz)
            intensity = None
            if "intensity" in wanted:
                values = buffers["intensity"][keep]
                if (low, high) != (0.0, float(INTENSITY_MAX)):
                    values = (values - low) * (INTENSITY_MAX / (high - low)) if high > low else np.zeros_like(values)
                intensity = np.clip(np.rint(values), 0, INTENSITY_MAX).astype(np.uint16)
            label = None
            if plan.label_source is not None:
                label = as_labels(buffers[plan.label_source][keep], field=plan.label_source, where=str(path))
            component = None
            if "component" in plan.columns:
                component = (buffers[COMPONENT_FIELD][keep].astype(np.int32) if COMPONENT_FIELD in buffers
                             else np.full(count, -1, dtype=np.int32))
            returns = {}
            if "return_number" in plan.columns:
                returns = {"return_number": np.clip(buffers["returnIndex"][keep] + 1, 1, 255).astype(np.uint8),
                           "number_of_returns": np.clip(buffers["returnCount"][keep], 1, 255).astype(np.uint8)}
            rgb = None
            if "rgb" in plan.columns:
                scale = 255.0 / (color_high - color_low) if color_high > color_low else 0.0
                rgb = np.stack([np.clip(np.rint((buffers[name][keep] - color_low) * scale), 0, 255)
                                for name in COLOR_FIELDS], axis=1).astype(np.uint8)
            yield PointCloud(
                xyz=xyz, label=label, component=component, rgb=rgb, **returns,
                station=np.full(count, station, dtype=np.uint16) if "station" in plan.columns else None,
                intensity=intensity,
                time=buffers["timeStamp"][keep].astype(np.float64) if "timeStamp" in wanted else None,
            )
    finally:
        reader.close()


def _rechunk(pieces: Iterator[PointCloud], chunk_points: int) -> Iterator[PointCloud]:
    """Re-cut a stream of pieces into chunks of exactly ``chunk_points`` rows (the last one shorter)."""
    pending: list[PointCloud] = []
    held = 0
    for piece in pieces:
        while len(piece):
            take = min(len(piece), chunk_points - held)
            pending.append(piece if take == len(piece) else piece.take(slice(0, take)))
            piece = piece.take(slice(take, None)) if take < len(piece) else piece.take(slice(0, 0))
            held += take
            if held == chunk_points:
                yield pending[0] if len(pending) == 1 else PointCloud.concatenate(pending)
                pending, held = [], 0
    if held:
        yield pending[0] if len(pending) == 1 else PointCloud.concatenate(pending)


def _empty(columns: set[str]) -> PointCloud:
    dtypes = {"label": np.uint8, "component": np.int32, "station": np.uint16, "intensity": np.uint16, "time": np.float64,
              "return_number": np.uint8, "number_of_returns": np.uint8}
    empty = {c: np.zeros(0, dtype=d) for c, d in dtypes.items() if c in columns}
    if "rgb" in columns:
        empty["rgb"] = np.zeros((0, 3), dtype=np.uint8)
    return PointCloud(xyz=np.zeros((0, 3)), **empty)


def iter_e57_chunks(
    path: str | Path, *, chunk_points: int = 2_000_000, label_field: str | None = None, labels: bool = True,
) -> Iterator[PointCloud]:
    """Stream an E57 file as world-coordinate ``PointCloud`` chunks of ``chunk_points`` rows.

    Scans follow each other in ``/data3D`` order; chunks run across scan boundaries. Files
    bimscan wrote give back the columns that were written; foreign files give xyz, station (the
    scan's index), intensity and time where every scan has them, and labels from
    ``label_field`` (a point field, e.g. an extension ``prefix:name``) only. ``labels`` False:
    label None (not read).
    """
    path = check_input_path(path)
    if chunk_points < 1:
        raise ValueError(f"chunk_points must be positive, got {chunk_points}")
    image = _open(path)
    try:
        scans = _scans(image)
        plan = _plan(image, scans, _stored_document(image, path), label_field, path)
        if not labels:
            plan = _Plan(columns=plan.columns - {"label"}, label_source=None, bimscan=plan.bimscan)
        block = min(chunk_points, READ_BLOCK_POINTS)

        def pieces() -> Iterator[PointCloud]:
            for index, scan in enumerate(scans):
                yield from _read_scan(image, scan, index, plan, path, block)

        produced = False
        for chunk in _rechunk(pieces(), chunk_points):
            produced = True
            yield chunk
        if not produced:  # one empty chunk still tells which columns exist
            yield _empty(plan.columns)
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: the E57 point data is damaged ({_reason(exc)}); check the file") from exc
    finally:
        image.close()



# -- labelled copies ------------------------------------------------------------------------------
#
# A labelled copy keeps an E57 file's whole tree as libE57Format reads it: every element of the
# root (guid, coordinateMetadata, images2D with their blobs, other tools' extensions, ...), every
# /data3D scan with its name, guid, pose, bounds, limits and sensor records, and every point
# field of every record with its type, bounds and scale (integers and scaled integers copied as
# raw integers, so nothing is re-quantised; points flagged invalid stay, labelled 255). The class
# goes to ``bimscan:label`` (integer 0..255, replaced where the scan had one, else added as its
# last field) and bimscan's header document to ``bimscan:cloudHeader``. The file is written anew,
# so its bytes are libE57Format's layout of the same tree.

_LEAF_DTYPES: dict[type, type] = {libe57.IntegerNode: np.longlong, libe57.ScaledIntegerNode: np.longlong,
                                  libe57.FloatNode: np.float64}
_CONTAINERS = (libe57.StructureNode, libe57.VectorNode)


def _typed(node: Any) -> Any:
    """``node`` (a generic Node of a tree, or one already typed) as its own node class."""
    if not isinstance(node, libe57.Node):
        return node
    kind = node.type()
    return {
        libe57.E57_STRUCTURE: libe57.StructureNode, libe57.E57_VECTOR: libe57.VectorNode,
        libe57.E57_COMPRESSED_VECTOR: libe57.CompressedVectorNode, libe57.E57_INTEGER: libe57.IntegerNode,
        libe57.E57_SCALED_INTEGER: libe57.ScaledIntegerNode, libe57.E57_FLOAT: libe57.FloatNode,
        libe57.E57_STRING: libe57.StringNode, libe57.E57_BLOB: libe57.BlobNode,
    }[kind](node)


def _children(node: Any) -> list[Any]:
    return [_typed(node.get(i)) for i in range(node.childCount())]


def _leaf(node: Any, image: Any) -> Any:
    """A new, unattached copy in ``image`` of a value node (integer, scaled integer, float, string)."""
    if isinstance(node, libe57.IntegerNode):
        return libe57.IntegerNode(image, node.value(), node.minimum(), node.maximum())
    if isinstance(node, libe57.ScaledIntegerNode):
        return libe57.ScaledIntegerNode(image, node.rawValue(), node.minimum(), node.maximum(), node.scale(),
                                        node.offset())
    if isinstance(node, libe57.FloatNode):
        return libe57.FloatNode(image, node.value(), node.precision(), node.minimum(), node.maximum())
    return libe57.StringNode(image, node.value())


def _detached(node: Any, image: Any) -> Any:
    """A new, unattached copy in ``image`` of a tree without blobs or compressed vectors (a
    prototype, a codecs vector)."""
    if isinstance(node, libe57.StructureNode):
        copy = libe57.StructureNode(image)
        for child in _children(node):
            copy.set(child.elementName(), _detached(child, image))
        return copy
    if isinstance(node, libe57.VectorNode):
        copy = libe57.VectorNode(image, node.allowHeteroChildren())
        for child in _children(node):
            copy.append(_detached(child, image))
        return copy
    return _leaf(node, image)


def _attach(parent: Any, name: str, node: Any) -> Any:
    if isinstance(parent, libe57.VectorNode):
        parent.append(node)
    else:
        parent.set(name, node)
    return node


def _copy_tree(source: Any, parent: Any, image: Any, points: Any) -> None:
    """Copy the children of ``source`` (a structure or vector) under ``parent`` (attached, in
    ``image``), in order (see ``_copy_single``)."""
    for child in _children(source):
        _copy_single(child, parent, image, points)


def _prototype_leaves(prototype: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """(path name, node) of every value field of a prototype, nested structures included."""
    leaves = []
    for child in _children(prototype):
        path = prefix + child.elementName()
        if isinstance(child, _CONTAINERS):
            leaves += _prototype_leaves(child, path + "/")
        else:
            leaves.append((path, child))
    return leaves


def _points_prototype(scan: Any) -> Any:
    return libe57.StructureNode(libe57.CompressedVectorNode(scan.get("points")).prototype())


def _text_fields(scans: list[Any]) -> list[str]:
    return sorted({name for scan in scans for name, node in _prototype_leaves(_points_prototype(scan))
                   if isinstance(node, libe57.StringNode)})


def check_e57_copy(path: Path, target_format: str, top_class: int) -> CopyCheck:
    """What a labelled copy of the E57 ``path`` cannot keep: point fields that hold text, which
    libE57Format's buffers through pye57 do not carry."""
    path = check_input_path(path)
    image = _open(path)
    try:
        text = _text_fields(_scans(image))
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: the E57 structure is damaged ({_reason(exc)}); check the file") from exc
    finally:
        image.close()
    return CopyCheck(lost=tuple(f"point field {name!r} (text)" for name in text))


_READ_FIELDS = frozenset({"cartesianX", "cartesianY", "cartesianZ", "sphericalRange", "sphericalAzimuth",
                          "sphericalElevation", "cartesianInvalidState", "sphericalInvalidState", "intensity",
                          "timeStamp", "returnIndex", "returnCount", *COLOR_FIELDS, LABEL_FIELD, COMPONENT_FIELD})
_INTEGER_TYPES = ("i1", "u1", "i2", "u2", "i4", "u4", "i8")


def _field_kind(node: Any) -> str | None:
    """The NumPy dtype a point field's values are carried in, None for text."""
    if isinstance(node, libe57.IntegerNode):
        low, high = node.minimum(), node.maximum()
        return next((f"<{t}" if t[1] != "1" else t for t in _INTEGER_TYPES
                     if np.iinfo(t).min <= low and high <= np.iinfo(t).max), "<i8")
    if isinstance(node, libe57.ScaledIntegerNode):
        return "<f8"
    if isinstance(node, libe57.FloatNode):
        return "<f4" if node.precision() == libe57.E57_SINGLE else "<f8"
    return None


def _e57_fields(scans: list[Any]) -> tuple[list[ExtraField], list[str]]:
    """The point fields beyond what the reader takes that every scan has in one type (as fields),
    and the others (in some scans only, or text), by name."""
    kinds: dict[str, set[str | None]] = {}
    for scan in scans:
        for name, node in _prototype_leaves(_points_prototype(scan)):
            if name not in _READ_FIELDS:
                kinds.setdefault(name, set()).add(_field_kind(node))
    fields, other = [], []
    for name in sorted(kinds):
        present = sum(name in {n for n, _ in _prototype_leaves(_points_prototype(scan))} for scan in scans)
        (kind,) = kinds[name] if len(kinds[name]) == 1 else (None,)
        if kind is None or present < len(scans):
            other.append(name)
        else:
            fields.append(ExtraField(name, kind))
    return fields, other


def e57_fields(path: Path) -> tuple[ExtraField, ...]:
    """The point fields of the E57 ``path`` the reader does not take (the scan grid, other tools'
    extensions, ...) that every scan has, for copies into other formats."""
    path = check_input_path(path)
    image = _open(path)
    try:
        return tuple(_e57_fields(_scans(image))[0])
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: the E57 structure is damaged ({_reason(exc)}); check the file") from exc
    finally:
        image.close()


def iter_e57_fields(path: Path, fields: tuple[ExtraField, ...]) -> Iterator[np.ndarray]:
    """The values of ``fields`` of every valid point (the points the reader gives, in its order),
    blocks of ``field_values_dtype`` records; scaled integers as their scaled values. Nothing
    without ``fields``."""
    path = check_input_path(path)
    if not fields:
        return
    image = _open(path)
    try:
        for scan in _scans(image):
            vector = libe57.CompressedVectorNode(scan.get("points"))
            names = {name for name, _ in _prototype_leaves(_points_prototype(scan))}
            invalid = "cartesianInvalidState" if {"cartesianX", "cartesianY", "cartesianZ"} <= names \
                else "sphericalInvalidState"
            capacity = max(1, min(READ_BLOCK_POINTS, int(vector.childCount())))
            buffers = {f.name: np.zeros(capacity, np.float64 if f.dtype[-2] == "f" else np.longlong) for f in fields}
            if invalid in names:
                buffers[invalid] = np.zeros(capacity, np.longlong)
            native = libe57.VectorSourceDestBuffer()
            for name, buffer in buffers.items():
                native.append(libe57.SourceDestBuffer(image, name, buffer, capacity, True, True))
            reader = vector.reader(native)
            try:
                while n := reader.read():
                    keep = np.arange(n) if invalid not in buffers else np.flatnonzero(buffers[invalid][:n] == 0)
                    values = np.empty(len(keep), dtype=field_values_dtype(fields))
                    for field in fields:
                        values[field.name] = buffers[field.name][keep]
                    yield values
            finally:
                reader.close()
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: the E57 point data is damaged ({_reason(exc)}); check the file") from exc
    finally:
        image.close()


def e57_held(path: Path) -> tuple[str, ...]:
    """What the E57 ``path`` holds beyond a ``PointCloud``'s columns and its ``e57_fields``, in
    words: other point fields, the scans' poses and names, images, points flagged invalid (which
    the reader drops), its coordinate system and other elements of its root."""
    path = check_input_path(path)
    image = _open(path)
    try:
        scans = _scans(image)
        document = _stored_document(image, path)
        held = []
        other = _e57_fields(scans)[1]
        if other:
            held.append(("point field " if len(other) == 1 else "point fields ") + ", ".join(other)
                        + " (text, or not in every scan)")
        if document is None and scans:
            held.append(f"the poses and names of its {len(scans)} scan{'s' if len(scans) != 1 else ''} (the points are "
                        "carried in world coordinates)")
        invalid = {"cartesianInvalidState", "sphericalInvalidState"}
        if any(invalid & {name for name, _ in _prototype_leaves(_points_prototype(scan))} for scan in scans):
            held.append("the points flagged invalid")
        root = image.root()
        if root.isDefined("images2D") and root["images2D"].childCount():
            count = root["images2D"].childCount()
            held.append(f"{count} image{'s' if count != 1 else ''} (images2D)")
        if root.isDefined("coordinateMetadata") and root["coordinateMetadata"].value():
            held.append("the coordinate reference system (coordinateMetadata)")
        standard = {"formatName", "guid", "versionMajor", "versionMinor", "e57LibraryVersion", "coordinateMetadata",
                    "creationDateTime", "data3D", "images2D", HEADER_NODE}
        elements = [child.elementName() for child in _children(root) if child.elementName() not in standard]
        if elements:
            held.append("root elements " + ", ".join(elements))
        return tuple(held)
    except libe57.E57Exception as exc:
        raise InputFileError(f"{path}: the E57 structure is damaged ({_reason(exc)}); check the file") from exc
    finally:
        image.close()


def copy_e57_labelled(
    source: Path, target: Path, labels: np.ndarray, *, header: CloudHeader, overwrite: bool = False,
    checksum: bool = True,
) -> WrittenCloud:
    """Copy the E57 ``source`` to ``target`` with ``labels`` (N,) uint8 in ``bimscan:label`` (see
    the section comment; N counts the points the reader gives, the valid ones); registered as
    ``LABELLED_COPIERS["e57"]``. ``header``: bimscan's document in ``bimscan:cloudHeader``."""
    source = check_input_path(source)
    image = _open(source)
    try:
        scans = _scans(image)
        document_in = _stored_document(image, source)
        plan = _plan(image, scans, document_in, None, source)
        kept = {*plan.columns, "label"} | ({"component"} if document_in is not None
                                           and "component" in document_in.get("columns", ()) else set())
        columns = tuple(c for c in PointCloud.COLUMNS if c in kept)
        with StagedOutput(target, overwrite=overwrite, checksum=checksum) as staged:
            temp = staged.file(target)
            copy = libe57.ImageFile(str(temp), "w")
            try:
                labelled = _copy_image(image, copy, labels, source, target)
                check_label_count(labels, labelled, source)
                document = header_to_document(header, columns=columns, n_points=labelled)
                copy.root().set(HEADER_NODE, libe57.StringNode(copy, dump_json(document).decode("utf-8")))
                copy.close()
            except libe57.E57Exception as exc:
                raise _write_error(exc, target) from exc
            finally:
                if copy.isOpen():
                    copy.cancel()
            return staged.commit(n_points=labelled)
    finally:
        image.close()


def _copy_image(image: Any, copy: Any, labels: np.ndarray, source: Path, target: Path) -> int:
    """Copy the tree of ``image`` into the new ``copy`` (bimscan's header document left out), the
    labels into every scan's points; returns how many labels went to valid points."""
    extensions = {image.extensionsPrefix(i): image.extensionsUri(i) for i in range(image.extensionsCount())}
    if extensions.get(NAMESPACE_PREFIX, NAMESPACE_URI) != NAMESPACE_URI:
        raise OutputError(f"{source}: its E57 prefix {NAMESPACE_PREFIX!r} names another namespace "
                          f"({extensions[NAMESPACE_PREFIX]}); bimscan cannot add its label field to it")
    extensions[NAMESPACE_PREFIX] = NAMESPACE_URI
    for prefix, uri in extensions.items():
        copy.extensionsAdd(prefix, uri)
    labelled = 0

    def points(vector: Any, parent: Any, name: str) -> None:
        nonlocal labelled
        scan = name == "points" and parent.pathName().startswith("/data3D/")
        labelled += _copy_points(image, copy, vector, parent, name, labels[labelled:] if scan else None, source)

    root = image.root()
    for child in _children(root):
        if child.elementName() == HEADER_NODE:
            continue
        _copy_single(child, copy.root(), copy, points)
    return labelled


def _copy_single(child: Any, parent: Any, image: Any, points: Any) -> None:
    """Copy ``child`` under ``parent`` (attached, in ``image``): containers attached before their
    children (blobs and compressed vectors are written in place), blobs streamed, compressed
    vectors through ``points(vector, parent_copy, name)``."""
    name = child.elementName()
    if isinstance(child, libe57.StructureNode):
        _copy_tree(child, _attach(parent, name, libe57.StructureNode(image)), image, points)
    elif isinstance(child, libe57.VectorNode):
        _copy_tree(child, _attach(parent, name, libe57.VectorNode(image, child.allowHeteroChildren())), image, points)
    elif isinstance(child, libe57.BlobNode):
        size = int(child.byteCount())
        blob = _attach(parent, name, libe57.BlobNode(image, size))
        buffer = np.zeros(max(1, min(size, 8 << 20)), dtype=np.uint8)
        for start in range(0, size, len(buffer)):
            count = min(len(buffer), size - start)
            child.read(buffer, start, count)
            blob.write(buffer, start, count)
    elif isinstance(child, libe57.CompressedVectorNode):
        points(child, parent, name)
    else:
        _attach(parent, name, _leaf(child, image))


def _copy_points(image: Any, copy: Any, vector: Any, parent: Any, name: str, labels: np.ndarray | None,
                 source: Path) -> int:
    """Copy the compressed vector ``vector`` of ``image`` as ``name`` of ``parent`` in ``copy``,
    every record as stored; with ``labels`` (a scan's points) the valid records get the next
    labels in ``bimscan:label`` and the invalid ones 255. Returns the labels used."""
    prototype = libe57.StructureNode(vector.prototype())
    new_prototype = libe57.StructureNode(copy)
    for child in _children(prototype):
        field = child.elementName()
        if field == LABEL_FIELD and labels is not None:
            continue  # written anew below, last
        if not isinstance(child, libe57.StringNode) and not (isinstance(child, _CONTAINERS) and any(
                isinstance(node, libe57.StringNode) for _, node in _prototype_leaves(child))):
            new_prototype.set(field, _detached(child, copy))
    if labels is not None:
        new_prototype.set(LABEL_FIELD, libe57.IntegerNode(copy, 0, 0, 255))
    leaves = [(path, node) for path, node in _prototype_leaves(new_prototype) if path != LABEL_FIELD or labels is None]
    target = libe57.CompressedVectorNode(copy, new_prototype, _detached(_typed(vector.codecs()), copy))
    _attach(parent, name, target)
    total = int(vector.childCount())
    capacity = max(1, min(READ_BLOCK_POINTS, total))
    buffers = {path: np.zeros(capacity, dtype=_LEAF_DTYPES[type(node)]) for path, node in leaves}
    reading, writing = libe57.VectorSourceDestBuffer(), libe57.VectorSourceDestBuffer()
    for path, buffer in buffers.items():  # integers as stored: scaled integers unscaled
        reading.append(libe57.SourceDestBuffer(image, path, buffer, capacity, True, False))
        writing.append(libe57.SourceDestBuffer(copy, path, buffer, capacity, True, False))
    label = np.zeros(capacity, dtype=np.uint8)
    if labels is not None:
        writing.append(libe57.SourceDestBuffer(copy, LABEL_FIELD, label, capacity, True, False))
    names = set(buffers)
    invalid = "cartesianInvalidState" if {"cartesianX", "cartesianY", "cartesianZ"} <= names else "sphericalInvalidState"
    reader, writer = vector.reader(reading), target.writer(writing)
    used = 0
    try:
        while True:
            try:
                n = reader.read()
            except libe57.E57Exception as exc:
                raise InputFileError(f"{source}: the E57 point data is damaged ({_reason(exc)}); check the file") from exc
            if n == 0:
                break
            if labels is not None:
                valid = np.ones(n, dtype=bool) if invalid not in buffers else buffers[invalid][:n] == 0
                count = int(valid.sum())
                if used + count > len(labels):
                    raise ValueError(f"{source}: more valid points than the {len(labels)} labels; pass one per point")
                label[:n] = 255
                label[:n][valid] = labels[used:used + count]
                used += count
            writer.write(n)
    finally:
        reader.close()
        writer.close()
    return used

__all__ = [
    "COMPONENT_FIELD", "check_e57_copy", "copy_e57_labelled", "e57_carriable", "e57_fields", "e57_held",
    "iter_e57_fields", "E57CloudWriter", "E57Scan", "E57_BLOCK_POINTS", "HEADER_NODE", "LABEL_FIELD", "MOBILE_COLUMNS",
    "NAMESPACE_PREFIX", "NAMESPACE_URI", "STATION_NODE", "check_e57_columns", "gps_seconds", "heading_quaternion", "iter_e57_chunks",
    "count_e57_points", "open_e57_writer", "quaternion_matrix", "read_e57_header", "read_e57_scans",
]

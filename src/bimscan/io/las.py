"""LAS 1.4 / LAZ clouds through laspy (LAZ compressed by lazrs, in parallel when available).

Layout of a bimscan LAS/LAZ file:

- Point format 6, or 7 (format 6 plus RGB) when the cloud has colour. Coordinates are int32
  steps of ``LAS_SCALE_M`` = 0.0001 m (0.1 mm) around the header offset, which is
  ``CloudHeader.origin``: a file reaches about +-214 km from its origin. Points farther out are
  refused (``OutputError``) rather than wrapped.
- ``label`` -> ``classification``; ``intensity`` -> ``intensity``; ``time`` -> ``gps_time``
  (seconds since the start of the survey, not GPS time); ``station`` -> ``point_source_id``
  and the extra dimension ``station`` (uint16); ``component`` -> extra dimension ``component``
  (int32); ``return_number`` / ``number_of_returns`` -> the LAS fields of the same names (at
  most 15, the format's limit; without the columns every point is return 1 of 1); ``rgb`` ->
  ``red``/``green``/``blue`` scaled to 16 bits (x 257, so 255 -> 65535). Of the columns a cloud
  lacks, the extra dimensions are left out and the standard fields stay zero; all read back as
  None (the header document lists the columns that were written). Foreign files give their
  return numbers, and their colour when the point format has it.
- VLR ``LASF_Spec``/0, the LAS 1.4 classification lookup: 256 x (uint8 class, char[15] name),
  the scheme's class names cut to 15 ASCII bytes, so CloudCompare and friends show them.
- EVLR ``bimscan``/1: the full header document as JSON (scheme, component table, stations,
  origin, metadata; see ``bimscan.io._header``).
- Reproducible header: creation date from ``SOURCE_DATE_EPOCH`` (else 1970-01-01), project GUID
  derived from the header document, fixed system identifier and generating software. Chunks are
  re-blocked into ``BLOCK_POINTS`` rows (a multiple of the LAZ chunk of ``LAZ_CHUNK_POINTS``)
  before laspy sees them, so the bytes do not depend on how the caller chunked the stream (lazrs
  happens to buffer partial LAZ chunks itself; the re-blocking does not rely on it) and the
  writer holds one block, about 40 MB, whatever the point count.
- Ctrl-C and SIGTERM: lazrs writes through the ``WatchedFile`` wrapper, whose Python ``write`` is
  where a pending signal's handler runs when the signal arrives while lazrs compresses (a mobile
  scan spends about half its time there); lazrs turned the handler's exception into
  ``IoError: Failed to call write``. Signals are held while lazrs runs
  (``bimscan.processes.signals_held``) and handled as soon as it returns.
"""

from __future__ import annotations

import datetime as dt
import io
import struct
import unicodedata
import uuid
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import laspy
import numba as nb
import numpy as np
from laspy.errors import LaspyException
from laspy.point.record import PackedPointRecord
from laspy.vlrs.known import ClassificationLookupVlr, LasZipVlr
from laspy.vlrs.vlrlist import VLRList

from bimscan import __version__
from bimscan.errors import InputFileError, OutputError
from bimscan.io._header import (
    as_labels,
    dump_json,
    header_from_document,
    header_to_document,
    parse_document,
)
from bimscan.io._labelled import CopyCheck, ExtraField, check_label_count, field_values_dtype
from bimscan.io._writer import (
    BLOCK_POINTS,
    StagedOutput,
    StreamingCloudWriter,
    WatchedFile,
    WrittenCloud,
    check_input_path,
    source_date_epoch,
)
from bimscan.processes import signals_held
from bimscan.types import CloudHeader, LabelScheme, PointCloud

LAS_SCALE_M = 1e-4  # 0.1 mm coordinate step
MAX_RETURNS = 15  # return numbers of point formats 6-10 are 4 bits
RGB_SCALE = 257  # 8-bit colour to LAS's 16 bits: 255 -> 65535, and back exactly by // 257
LAZ_CHUNK_POINTS = 50_000  # lazrs' default LAZ chunk; BLOCK_POINTS must stay a multiple of it
# lazrs' parallel compressor first: it compresses a block's LAZ chunks on every core and writes the
# bytes of the single-threaded one (the same chunks, each compressed alone), which is the fallback
LAZ_BACKENDS = (laspy.LazBackend.LazrsParallel, laspy.LazBackend.Lazrs)
BIMSCAN_USER_ID = "bimscan"
BIMSCAN_RECORD_ID = 1
SYSTEM_IDENTIFIER = "bimscan virtual TLS"
_INT32 = (float(np.iinfo(np.int32).min), float(np.iinfo(np.int32).max))
_GUID_NAMESPACE = uuid.UUID("6f3c1d2e-8a4b-5c7d-9e0f-b1a2c3d4e5f6")

if BLOCK_POINTS % LAZ_CHUNK_POINTS:  # pragma: no cover - a guard for whoever edits the constants
    raise ImportError("BLOCK_POINTS must be a multiple of LAZ_CHUNK_POINTS")


def _creation_date() -> dt.date:
    epoch = source_date_epoch()
    return dt.date(1970, 1, 1) if epoch is None else dt.datetime.fromtimestamp(epoch, tz=dt.UTC).date()


def lookup_name(name: str) -> str:
    """A class name as the classification lookup VLR stores it: ASCII, at most 15 bytes."""
    ascii_name = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode("ascii")
    return ascii_name[:15]


def _classification_lookup(scheme: LabelScheme) -> ClassificationLookupVlr:
    vlr = ClassificationLookupVlr()
    names = {c.id: lookup_name(c.name) for c in scheme.classes if 0 <= c.id <= 255}
    for class_id in range(256):  # the LAS 1.4 record is always 256 entries long
        vlr[class_id] = names.get(class_id, "")
    return vlr


SENSOR_DIMENSIONS = ("sensor_x", "sensor_y", "sensor_z")  # a mobile scan's beam origins, 0.1 mm steps


def _las_header(header: CloudHeader, columns: tuple[str, ...], fields: tuple[ExtraField, ...] = ()) -> laspy.LasHeader:
    las_header = laspy.LasHeader(version="1.4", point_format=7 if "rgb" in columns else 6)
    extra = []
    if "component" in columns:
        extra.append(laspy.ExtraBytesParams(name="component", type=np.int32, description="BIM component id"))
    if "station" in columns:
        extra.append(laspy.ExtraBytesParams(name="station", type=np.uint16, description="scan station id"))
    if "ring" in columns:
        extra.append(laspy.ExtraBytesParams(name="ring", type=np.uint8, description="lidar ring (beam by elevation)"))
    if "sensor_xyz" in columns:
        for axis, name in enumerate(SENSOR_DIMENSIONS):
            extra.append(laspy.ExtraBytesParams(name=name, type=np.int32, description=f"beam origin {'xyz'[axis]}",
                                                scales=np.array([LAS_SCALE_M]),
                                                offsets=np.array([header.origin[axis]], dtype=np.float64)))
    for field in fields:  # another format's per-point fields, after bimscan's own
        extra.append(laspy.ExtraBytesParams(name=field.name, type=np.dtype(field.dtype),
                                            description=field.description.encode("ascii", "replace")[:31].decode()))
    if extra:
        las_header.add_extra_dims(extra)
    las_header.offsets = np.asarray(header.origin, dtype=np.float64)
    las_header.scales = np.full(3, LAS_SCALE_M)
    las_header.creation_date = _creation_date()
    las_header.system_identifier = SYSTEM_IDENTIFIER
    las_header.generating_software = f"bimscan {__version__}"[:31]
    digest = dump_json(header_to_document(header, columns=columns, n_points=0))
    las_header.uuid = uuid.uuid5(_GUID_NAMESPACE, digest.decode("utf-8"))
    las_header.vlrs.append(_classification_lookup(header.scheme))
    return las_header


@nb.njit(cache=True, nogil=True)
def quantise_xyz(xyz: np.ndarray, origin: np.ndarray, scale: float, x: np.ndarray, y: np.ndarray, z: np.ndarray,
                 low: np.ndarray, high: np.ndarray) -> int:
    """Coordinates (N, 3) float64 metres -> int32 steps of ``scale`` around ``origin`` (3,), written to
    ``x``, ``y``, ``z`` (N,) (the record block's fields), in one pass: ``rint((v - origin) / scale)``,
    the operations ``np.subtract``, ``np.divide`` and ``np.rint`` do, so the same steps. ``low`` and
    ``high`` (3,) float64 take the running bounds in steps. Returns -1, or ``3 * row + axis`` of the
    first coordinate whose step is not finite or does not fit an int32 (nothing is written from it on)."""
    lowest, highest = -2147483648.0, 2147483647.0
    out = (x, y, z)
    for i in range(xyz.shape[0]):
        for axis in range(3):
            step = np.rint((xyz[i, axis] - origin[axis]) / scale)
            if not (step >= lowest and step <= highest):  # also NaN
                return 3 * i + axis
            out[axis][i] = np.int32(step)
            if step < low[axis]:
                low[axis] = step
            if step > high[axis]:
                high[axis] = step
    return -1


class LasCloudWriter(StreamingCloudWriter):
    """Streams ``PointCloud`` chunks into a LAS 1.4 (``compress=False``) or LAZ file."""

    def __init__(
        self, path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True, compress: bool,
        fields: tuple[ExtraField, ...] = (),
    ) -> None:
        super().__init__(path, header=header, overwrite=overwrite, checksum=checksum, fields=fields)
        self.compress = compress
        self._file: WatchedFile | None = None
        self._writer: laspy.LasWriter | None = None
        self._point_format: laspy.PointFormat | None = None
        self._block: np.ndarray | None = None  # (BLOCK_POINTS,) packed point records being filled
        self._scratch: np.ndarray | None = None  # (BLOCK_POINTS,) f8 work space for quantising beam origins
        self._fill = 0
        self._low = np.full(3, np.inf)  # bounds in coordinate steps, for the LAS header
        self._high = np.full(3, -np.inf)
        self._by_return = np.zeros(16, dtype=np.int64)  # points per return number, for the LAS header

    def _begin(self, columns: tuple[str, ...]) -> None:
        las_header = _las_header(self.header, columns, self.fields)
        self._file = self._open_file(self.path)
        backend = LAZ_BACKENDS if self.compress else None
        self._writer = laspy.LasWriter(
            self._file, las_header, do_compress=self.compress, laz_backend=backend, closefd=False
        )
        self._point_format = self._writer.header.point_format
        self._block = np.zeros(BLOCK_POINTS, dtype=self._point_format.dtype())
        # zeros, touched only where rows are encoded (a small unit never faults most of its pages in)

    def _encode(self, chunk: PointCloud, out: np.ndarray, values: np.ndarray | None = None) -> None:
        """Quantise and pack ``chunk`` (and ``values`` of the extra fields) into ``out`` (rows of the
        point record block)."""
        for field in self.fields:
            out[field.name] = values[field.name]  # type: ignore[index]
        origin = self.header.origin
        if len(chunk):
            xyz = np.ascontiguousarray(chunk.xyz, dtype=np.float64)
            bad = quantise_xyz(xyz, np.asarray(origin, dtype=np.float64), LAS_SCALE_M, out["X"], out["Y"], out["Z"],
                               self._low, self._high)
            if bad >= 0:
                axis, row = bad % 3, bad // 3
                raise OutputError(
                    f"{self.path}: {'xyz'[axis]} = {xyz[row, axis]} m does not fit LAS 0.1 mm steps around the "
                    f"origin {origin[axis]} m (+-214 km); use finite coordinates and set CloudHeader.origin near the data"
                )
        if chunk.label is not None:
            out["classification"] = chunk.label
        if chunk.intensity is not None:
            out["intensity"] = chunk.intensity
        if chunk.time is not None:
            out["gps_time"] = chunk.time
        if chunk.component is not None:
            out["component"] = chunk.component
        if chunk.station is not None:
            out["station"] = chunk.station
            out["point_source_id"] = chunk.station
        if chunk.return_number is not None and chunk.number_of_returns is not None:
            number = np.clip(chunk.return_number, 1, MAX_RETURNS)
            out["bit_fields"] = number | (np.clip(chunk.number_of_returns, number, MAX_RETURNS) << 4)
            self._by_return += np.bincount(number, minlength=16)
        else:
            out["bit_fields"] = 0b0001_0001  # return 1 of 1 (LAS 1.4 forbids return number 0)
            self._by_return[1] += len(chunk)
        if chunk.rgb is not None:
            for channel, name in enumerate(("red", "green", "blue")):
                out[name] = chunk.rgb[:, channel].astype(np.uint16) * RGB_SCALE
        if chunk.ring is not None:
            out["ring"] = chunk.ring
        if chunk.channel is not None:  # LAS 1.4 scanner_channel: bits 4-5 of the classification flags byte
            out["classification_flags"] = (out["classification_flags"] & 0b1100_1111) | (chunk.channel.astype(np.uint8) << 4)
        if chunk.sensor_xyz is not None:
            if self._scratch is None:
                self._scratch = np.empty(BLOCK_POINTS, dtype=np.float64)
            steps = self._scratch[: len(chunk)]
            for axis, name in enumerate(SENSOR_DIMENSIONS):
                np.subtract(chunk.sensor_xyz[:, axis], origin[axis], out=steps)
                np.divide(steps, LAS_SCALE_M, out=steps)
                out[name] = np.rint(steps)

    def _append(self, chunk: PointCloud, values: np.ndarray | None) -> None:
        assert self._block is not None
        start = 0
        while start < len(chunk):
            take = min(len(chunk) - start, BLOCK_POINTS - self._fill)
            part = chunk if take == len(chunk) else chunk.take(slice(start, start + take))
            with self.clock.step("encode"):
                self._encode(part, self._block[self._fill : self._fill + take],
                             None if values is None else values[start:start + take])
            self._fill += take
            start += take
            if self._fill == BLOCK_POINTS:
                self._flush()

    def _flush(self) -> None:
        if self._fill and self._writer is not None and self._block is not None:
            # Straight to laspy's point writer: LasWriter.write_points would recompute the bounds
            # (known from _encode) and the return counts (all 1) with a sort of every block.
            record = PackedPointRecord(self._block[: self._fill], self._point_format)
            try:
                # lazrs would turn a Ctrl-C inside its write callback into an IoError: signals wait
                with signals_held(), self.clock.step("compress" if self.compress else "store"):
                    self._writer.point_writer.write_points(record)
            except (LaspyException, RuntimeError) as exc:  # lazrs raises LazrsError(RuntimeError)
                raise OutputError(f"could not write {self.path} ({exc}); check the disk and run again") from exc
        self._fill = 0

    def _finish(self) -> None:
        assert self._writer is not None and self.columns is not None
        self._flush()
        las_header = self._writer.header
        las_header.point_count = self.n_points
        las_header.number_of_points_by_return[:] = self._by_return[1:1 + len(las_header.number_of_points_by_return)]
        if self.n_points:
            las_header.mins = self._low * las_header.scales + las_header.offsets
            las_header.maxs = self._high * las_header.scales + las_header.offsets
        document = header_to_document(self.header, columns=self.columns, n_points=self.n_points)
        evlr = laspy.VLR(BIMSCAN_USER_ID, BIMSCAN_RECORD_ID, "bimscan cloud header (JSON)", dump_json(document))
        try:
            with signals_held():  # lazrs writes its last chunk and chunk table here
                self._writer.write_evlrs(VLRList([evlr]))
                self._writer.close()
        except (LaspyException, RuntimeError) as exc:
            raise OutputError(f"could not finish {self.path} ({exc}); check the disk and run again") from exc
        self._writer = None

    def _release(self) -> None:
        self._block = None
        self._scratch = None
        self._writer = None
        super()._release()


def open_las_writer(path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                    fields: tuple[ExtraField, ...] = ()) -> LasCloudWriter:
    """An uncompressed LAS 1.4 writer (registered as ``WRITERS["las"]``); ``fields``: extra dimensions."""
    return LasCloudWriter(path, header=header, overwrite=overwrite, checksum=checksum, compress=False, fields=fields)


def open_laz_writer(path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                    fields: tuple[ExtraField, ...] = ()) -> LasCloudWriter:
    """A LAZ writer (registered as ``WRITERS["laz"]``); ``fields``: extra dimensions."""
    return LasCloudWriter(path, header=header, overwrite=overwrite, checksum=checksum, compress=True, fields=fields)


_EXTRA_BYTES_TYPES = frozenset({"u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8"})


def las_carriable(fields: tuple[ExtraField, ...]) -> tuple[tuple[ExtraField, ...], tuple[str, ...]]:
    """The ``fields`` a LAS/LAZ writer stores as extra dimensions, and the others in words: names
    the format or bimscan already uses, names longer than 32 ASCII bytes, non-numeric values."""
    taken = {n.lower() for n in laspy.PointFormat(7).dimension_names} | {
        "component", "station", "ring", *SENSOR_DIMENSIONS}
    carried, lost = [], []
    for field in fields:
        kind = np.dtype(field.dtype)
        if field.name.lower() in taken:
            lost.append(f"{field.name!r} (a name LAS or bimscan uses)")
        elif not field.name.isascii() or len(field.name) > 32:
            lost.append(f"{field.name!r} (LAS names extra dimensions in at most 32 ASCII bytes)")
        elif kind.str.lstrip("<>|=") not in _EXTRA_BYTES_TYPES:
            lost.append(f"{field.name!r} ({kind})")
        else:
            carried.append(field)
            taken.add(field.name.lower())
    return tuple(carried), tuple(lost)


# -- reading ------------------------------------------------------------------------------------

def _open(path: Path) -> laspy.LasReader:
    try:
        return laspy.open(path)
    except (LaspyException, OSError, ValueError, EOFError) as exc:
        raise InputFileError(f"{path}: not a readable LAS/LAZ file ({exc}); check the file") from exc


def _stored_document(las_header: laspy.LasHeader, path: Path) -> dict[str, Any] | None:
    # an EVLR in bimscan's files; a VLR in labelled copies of LAS 1.0-1.3 files, which have no EVLRs
    for record in [*(las_header.evlrs or ()), *las_header.vlrs]:
        if record.user_id == BIMSCAN_USER_ID and record.record_id == BIMSCAN_RECORD_ID:
            return parse_document(record.record_data_bytes(), where=str(path))
    return None


def check_header(las_header: laspy.LasHeader, path: Path) -> None:
    """InputFileError (one line) for a header that cannot describe real points: a scale that is
    not a positive finite number, a non-finite offset, or point counts that disagree with each
    other or with the size of an uncompressed file."""
    for axis, (scale, offset) in enumerate(zip(las_header.scales, las_header.offsets)):
        if not (np.isfinite(scale) and scale > 0) or not np.isfinite(offset):
            raise InputFileError(
                f"{path}: the LAS header's {'xyz'[axis]} scale {float(scale)!r} / offset {float(offset)!r} cannot "
                "give coordinates (the scale must be a positive number, both finite); the file is damaged: export it again")
    count = int(las_header.point_count)
    if las_header.version.minor >= 4:  # LAS 1.4 keeps a 32-bit legacy count (byte 107) beside the 64-bit one
        with path.open("rb") as handle:
            handle.seek(107)
            legacy = int.from_bytes(handle.read(4), "little")
        if legacy and count < 2**32 and legacy != count:
            raise InputFileError(f"{path}: the LAS header gives two point counts ({legacy:,} and {count:,}); the file is "
                                 "damaged: export it again")
    if las_header.are_points_compressed:
        return  # the LAZ chunk table is checked by the decompressor
    record = int(las_header.point_format.size)
    start = int(las_header.offset_to_point_data)
    evlr = int(las_header.start_of_first_evlr or 0)
    end = evlr if evlr > start else path.stat().st_size
    held, extra = divmod(end - start, record) if record else (count, 0)
    # Fewer records than the count: cut short. More, filling the data exactly: the count is wrong.
    # (Other trailing bytes are tolerated: some writers pad.)
    if held < count or (held != count and (extra == 0 or evlr > start)):
        raise InputFileError(f"{path}: the LAS header says {count:,} points, the file holds {max(held, 0):,}; the file "
                             "is damaged or cut short: copy or export it again")


def read_las_header(path: str | Path) -> CloudHeader | None:
    """The ``CloudHeader`` bimscan stored in a LAS/LAZ file, or None for a foreign file."""
    path = check_input_path(path)
    with _open(path) as reader:
        document = _stored_document(reader.header, path)
    return None if document is None else header_from_document(document, where=str(path))


_EVLR_HEADER = struct.Struct("<H16sHQ32s")  # reserved, user id, record id, record length, description


def count_las_points(path: str | Path) -> int:
    """Points a LAS/LAZ file holds by its header.

    InputFileError when the file is shorter than its header says: the uncompressed point records,
    or the extended VLRs that LAS 1.4 stores after the points (bimscan's metadata is one: a
    truncated LAZ, whose compressed points cannot be sized, is caught by that).
    """
    path = check_input_path(path)
    with _open(path) as reader:
        header = reader.header
        count = int(header.point_count)
        end = header.offset_to_point_data
        if not header.are_points_compressed:
            end += count * header.point_format.size
        n_evlrs = int(getattr(header, "number_of_evlrs", 0) or 0)
        start_of_evlrs = int(getattr(header, "start_of_first_evlr", 0) or 0)
    size = path.stat().st_size
    if n_evlrs and start_of_evlrs:
        end = max(end, start_of_evlrs)
        with path.open("rb") as handle:
            for _ in range(n_evlrs):
                handle.seek(end)
                raw = handle.read(_EVLR_HEADER.size)
                if len(raw) < _EVLR_HEADER.size:
                    end = size + 1
                    break
                end += _EVLR_HEADER.size + _EVLR_HEADER.unpack(raw)[3]
    if size < end:
        raise InputFileError(f"{path}: the file ends at byte {size} but its header describes {end} bytes "
                             f"({count} points); the file is truncated")
    return count


def _rgb8(raw: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colour of LAS records: 16-bit colour by its high byte, which gives bimscan's own
    colour (x 257: (257 v) >> 8 = v) back exactly; files that wrote 8-bit values into the 16-bit
    fields (none above 255) as they are."""
    rgb = np.stack([np.asarray(raw[name], dtype=np.uint16) for name in ("red", "green", "blue")], axis=1)
    return (rgb >> 8).astype(np.uint8) if len(rgb) and rgb.max() > 255 else rgb.astype(np.uint8)


def _stations(values: np.ndarray, field: str, path: Path) -> np.ndarray:
    """(N,) uint16 station ids from a dimension's values; InputFileError for values that are no ids."""
    if values.dtype.kind in "fc" and len(values) and not np.array_equal(values, np.round(values)):
        raise InputFileError(f"{path}: dimension {field!r} holds fractions, not station ids; name another field")
    if len(values) and (values.min() < 0 or values.max() > np.iinfo(np.uint16).max):
        raise InputFileError(f"{path}: dimension {field!r} holds {values.min()}..{values.max()}, not station ids "
                             "(0..65535); name another field")
    return values.astype(np.uint16)


def iter_las_chunks(
    path: str | Path, *, chunk_points: int = 2_000_000, label_field: str | None = None, labels: bool = True,
    station_field: str | None = None, runs: Sequence[tuple[int, int]] | None = None,
) -> Iterator[PointCloud]:
    """Stream a LAS/LAZ file as ``PointCloud`` chunks of at most ``chunk_points`` rows (with ``runs``:
    one chunk per (first point, count) run, read by seeking to it: a sparse look at a large file,
    a LAZ file decompressing only the chunks the runs fall in).

    Labels come from ``label_field`` (any dimension, e.g. an extra dimension ``"gt"``), else from
    ``classification``. Files bimscan wrote give back the columns that were written; foreign
    files give xyz, label, intensity and time (``gps_time`` when the point format has it).
    ``labels`` False: label None (not decoded). ``station_field``: the dimension that holds each
    point's station (``point_source_id``, where registration software puts the scan position of a
    merged cloud), read as the ``station`` column.
    """
    path = check_input_path(path)
    if chunk_points < 1:
        raise ValueError(f"chunk_points must be positive, got {chunk_points}")
    with _open(path) as reader:
        las_header = reader.header
        check_header(las_header, path)
        document = _stored_document(las_header, path)
        names = list(las_header.point_format.dimension_names)
        if label_field is not None and label_field not in names:
            raise InputFileError(
                f"{path}: no dimension {label_field!r} to read labels from; the file has {', '.join(names)}"
            )
        if station_field is not None and station_field not in names:
            raise InputFileError(
                f"{path}: no dimension {station_field!r} to read stations from; the file has {', '.join(names)}")
        if document is not None:
            columns = set(document["columns"])
        else:
            columns = {"xyz", "label", "intensity", "return_number", "number_of_returns"}
            columns |= ({"time"} if "gps_time" in names else set()) | ({"rgb"} if "red" in names else set())
        if label_field is not None:
            columns.add("label")
        if not labels:
            columns.discard("label")
        if station_field is not None:
            columns.add("station")
        label_source = label_field or "classification"
        station_source = station_field or "station"
        scales, offsets = las_header.scales, las_header.offsets

        def to_cloud(points: laspy.ScaleAwarePointRecord) -> PointCloud:
            raw = points.array
            xyz = np.empty((len(raw), 3), dtype=np.float64)
            for axis, name in enumerate("XYZ"):
                xyz[:, axis] = raw[name] * scales[axis] + offsets[axis]
            return PointCloud(
                xyz=xyz,
                label=as_labels(np.asarray(points[label_source]), field=label_source, where=str(path))
                if "label" in columns else None,
                component=np.asarray(raw["component"], dtype=np.int32)
                if "component" in columns and "component" in names else None,
                station=_stations(np.asarray(points[station_source]), station_source, path)
                if "station" in columns and station_source in names else None,
                intensity=np.asarray(raw["intensity"], dtype=np.uint16) if "intensity" in columns else None,
                time=np.asarray(raw["gps_time"], dtype=np.float64)
                if "time" in columns and "gps_time" in names else None,
                return_number=np.asarray(points.return_number, dtype=np.uint8) if "return_number" in columns else None,
                number_of_returns=np.asarray(points.number_of_returns, dtype=np.uint8)
                if "number_of_returns" in columns else None,
                rgb=_rgb8(raw) if "rgb" in columns and "red" in names else None,
                ring=np.asarray(raw["ring"], dtype=np.uint8) if "ring" in columns and "ring" in names else None,
                channel=np.asarray(points.scanner_channel, dtype=np.uint8) if "channel" in columns else None,
                sensor_xyz=np.column_stack([np.asarray(points[name], dtype=np.float64) for name in SENSOR_DIMENSIONS])
                if "sensor_xyz" in columns and SENSOR_DIMENSIONS[0] in names else None,
            )

        try:
            if las_header.point_count == 0:  # one empty chunk still tells which columns exist
                yield to_cloud(reader.read_points(0))
                return
            if runs is not None:
                for first, count in runs:
                    reader.seek(first)
                    yield to_cloud(reader.read_points(count))
                return
            for points in reader.chunk_iterator(chunk_points):
                yield to_cloud(points)
        except (LaspyException, EOFError, ValueError, RuntimeError) as exc:
            # laspy raises its own errors and ValueError on short buffers; lazrs raises RuntimeError
            raise InputFileError(f"{path}: the point data is damaged ({exc}); check the file") from exc



# -- labelled copies ------------------------------------------------------------------------------
#
# A labelled copy keeps a LAS/LAZ file as it was stored: the public header block byte for byte
# (version, point format, scales, offsets, bounds, counts, GUID, system identifier, dates, bytes
# other software added), every VLR and EVLR as stored (CRS as WKT or GeoTIFF keys, extra-bytes
# descriptions, ...), the bytes between the VLRs and the points, and every point record with its
# integer X/Y/Z, extra bytes and unregistered bytes. Only the class changes: the classification
# bits of each record, the classification lookup VLR (the new class names) and bimscan's header
# document (an EVLR; a VLR in LAS 1.0-1.3, which have no EVLRs), each replaced where it was or
# added at the end. LAS <-> LAZ toggles the compression (lazrs; its LASzip VLR added or dropped).

_VLR_HEADER = struct.Struct("<H16sHH32s")  # reserved, user id, record id, record length, description
LOOKUP_ID = ("LASF_Spec", 0)  # the classification lookup
EXTRA_BYTES_ID = ("LASF_Spec", 4)
LASZIP_ID = ("laszip encoded", 22204)
DOCUMENT_ID = (BIMSCAN_USER_ID, BIMSCAN_RECORD_ID)
PROJECTION_USER_ID = "LASF_Projection"
LEGACY_CLASS_MAX = 31  # point formats 0-5 keep the class in 5 bits
# The LAS 1.4 point format with the fields of a legacy one and a whole byte of class (scan angles
# in 0.006 deg steps instead of whole degrees).
UPGRADED_FORMATS = {0: 6, 1: 6, 2: 7, 3: 7, 4: 9, 5: 10}
SCAN_ANGLE_STEP_DEG = 0.006
_HEADER_14 = 375  # bytes of the LAS 1.4 public header block
_HEADER_13 = 235
_LEGACY_HEADER = 227
COPY_BLOCK_POINTS = BLOCK_POINTS  # records per step: bounds a copy's memory (a multiple of the LAZ chunk)
_INTERNAL_WAVEFORM = 0b10  # global encoding bit 1: waveform data packets inside the file


@dataclass(frozen=True)
class LasRecord:
    """A VLR or EVLR as stored: its ids and all its bytes (header and data)."""

    user_id: str
    record_id: int
    raw: bytes
    offset: int  # where it starts in its file


@dataclass(frozen=True)
class LasLayout:
    """The parts of a LAS/LAZ file as stored, for copies that keep them byte for byte.

    header: the public header block (``header_size`` bytes, with bytes other software appended);
    vlr_tail: the bytes between the last VLR and the point data; point_format: the id without the
    compression bits; evlr_start / waveform_start: 0 when the file has none.
    """

    header: bytes
    version: tuple[int, int]
    point_format: int
    compressed: bool
    record_length: int
    point_count: int
    offset_to_point_data: int
    vlrs: tuple[LasRecord, ...]
    vlr_tail: bytes
    evlrs: tuple[LasRecord, ...]
    evlr_start: int
    waveform_start: int
    global_encoding: int
    scales: tuple[float, float, float]
    file_size: int

    @property
    def points_end(self) -> int | None:
        """Where the point records end (None for compressed points, whose size the header does not give)."""
        return None if self.compressed else self.offset_to_point_data + self.point_count * self.record_length

    @property
    def base_size(self) -> int:
        """Bytes of a record of the point format itself (the rest of ``record_length``: extra bytes)."""
        return int(laspy.PointFormat(self.point_format).size)


def _id_text(raw: bytes) -> str:
    return raw.split(b"\0", 1)[0].decode("ascii", "replace")


def read_las_layout(path: Path) -> LasLayout:
    """The stored parts of a LAS/LAZ file (see ``LasLayout``); InputFileError when they do not add up."""
    size = path.stat().st_size

    def damaged(what: str) -> InputFileError:
        return InputFileError(f"{path}: {what}; the file is damaged: export it again")

    with path.open("rb") as handle:
        head = handle.read(_HEADER_14)
        if len(head) < _LEGACY_HEADER or head[:4] != b"LASF":
            raise InputFileError(f"{path}: not a LAS/LAZ file (no LASF signature); check the file")
        version = (head[24], head[25])
        header_size, offset, n_vlrs = struct.unpack_from("<HII", head, 94)
        point_format, record_length = struct.unpack_from("<BH", head, 104)
        count = struct.unpack_from("<I", head, 107)[0]
        scales = struct.unpack_from("<3d", head, 131)
        waveform = evlr_start = n_evlrs = 0
        if version[1] >= 3 and header_size >= _HEADER_13:
            waveform = struct.unpack_from("<Q", head, 227)[0]
        if version[1] >= 4 and header_size >= _HEADER_14:
            evlr_start, n_evlrs, count = struct.unpack_from("<QIQ", head, 235)
        if header_size < _LEGACY_HEADER or offset < header_size:
            raise damaged(f"the LAS header gives a header size of {header_size} bytes and points at byte {offset}")
        handle.seek(0)
        header = handle.read(header_size)
        vlrs = []
        for _ in range(n_vlrs):
            start = handle.tell()
            raw = handle.read(_VLR_HEADER.size)
            if len(raw) < _VLR_HEADER.size:
                raise damaged(f"the file ends inside its VLR {len(vlrs) + 1} of {n_vlrs}")
            _, user, record, length, _ = _VLR_HEADER.unpack(raw)
            data = handle.read(length)
            if len(data) < length or handle.tell() > offset:
                raise damaged(f"VLR {len(vlrs) + 1} of {n_vlrs} runs past the start of the point data")
            vlrs.append(LasRecord(_id_text(user), record, raw + data, start))
        vlr_tail = handle.read(offset - handle.tell())
        evlrs = []
        if n_evlrs and evlr_start:
            handle.seek(evlr_start)
            for _ in range(n_evlrs):
                start = handle.tell()
                raw = handle.read(_EVLR_HEADER.size)
                if len(raw) < _EVLR_HEADER.size:
                    raise damaged(f"the file ends inside its EVLR {len(evlrs) + 1} of {n_evlrs}")
                _, user, record, length, _ = _EVLR_HEADER.unpack(raw)
                if start + _EVLR_HEADER.size + length > size:
                    raise damaged(f"EVLR {len(evlrs) + 1} of {n_evlrs} runs past the end of the file")
                data = handle.read(length)
                evlrs.append(LasRecord(_id_text(user), record, raw + data, start))
    return LasLayout(
        header=header, version=version, point_format=point_format & 0x3F, compressed=bool(point_format & 0x80),
        record_length=record_length, point_count=int(count), offset_to_point_data=offset, vlrs=tuple(vlrs),
        vlr_tail=vlr_tail, evlrs=tuple(evlrs), evlr_start=int(evlr_start) if evlrs else 0, waveform_start=int(waveform),
        global_encoding=struct.unpack_from("<H", head, 6)[0], scales=scales, file_size=size,
    )


def _record_bytes(record: laspy.VLR | Any, *, extended: bool) -> bytes:
    buffer = io.BytesIO()
    VLRList([record]).write_to(buffer, as_extended=extended)
    return buffer.getvalue()


def _upgrade(layout: LasLayout, top_class: int) -> int | None:
    """The point format a copy must take to hold class ids up to ``top_class``, None to keep its own."""
    return UPGRADED_FORMATS[layout.point_format] if layout.point_format in UPGRADED_FORMATS and \
        top_class > LEGACY_CLASS_MAX else None


def check_las_copy(path: Path, target_format: str, top_class: int) -> CopyCheck:
    """What a labelled copy of the LAS/LAZ ``path`` into ``target_format`` ("las"/"laz") cannot keep."""
    path = check_input_path(path)
    with _open(path) as reader:
        check_header(reader.header, path)
    layout = read_las_layout(path)
    lost: list[str] = []
    changed: list[str] = []
    if layout.compressed and layout.waveform_start and layout.global_encoding & _INTERNAL_WAVEFORM:
        lost.append("the waveform data packets stored after its compressed points")
    upgraded = _upgrade(layout, top_class)
    if upgraded is not None:
        version = ".".join(str(v) for v in layout.version)
        changed.append(f"point format {layout.point_format} (LAS {version}) becomes {upgraded} (LAS 1.4), whose "
                       f"classification holds the class ids up to {top_class} (format {layout.point_format}: 0-31); "
                       "scan angles go from whole degrees to 0.006 deg steps")
    return CopyCheck(lost=tuple(lost), changed=tuple(changed))


_BIMSCAN_DIMENSIONS = {"component": "component", "station": "station", "ring": "ring",
                       **{name: "sensor_xyz" for name in SENSOR_DIMENSIONS}}  # extra dimension -> its column
_READ_DIMENSIONS = frozenset({"X", "Y", "Z", "intensity", "return_number", "number_of_returns", "classification",
                              "gps_time", "red", "green", "blue"})  # what the reader takes of another tool's file


def _las_field_sources(path: Path) -> list[tuple[ExtraField, str, int | None]]:
    """(field, dimension, element of an array dimension or None) for every per-point field of the
    LAS/LAZ ``path`` the reader does not take: extra dimensions (scaled ones as their scaled
    float64 values), and in other tools' files the LAS fields bimscan does not read (user data,
    scan angle, point source id, the flag bits, ...); bimscan's own files leave those at zero or
    carry them as columns."""
    with _open(path) as reader:
        las_header = reader.header
        document = _stored_document(las_header, path)
    point_format = las_header.point_format
    carried = set() if document is None else set(document.get("columns", ()))
    sample = laspy.ScaleAwarePointRecord.zeros(1, header=las_header)
    sources: list[tuple[ExtraField, str, int | None]] = []
    if document is None:
        for name in point_format.standard_dimension_names:
            if name not in _READ_DIMENSIONS:
                sources.append((ExtraField(name, np.asarray(sample[name]).dtype.str), name, None))
    for dimension in point_format.extra_dimensions:
        name = dimension.name
        if name == "ExtraBytes" or _BIMSCAN_DIMENSIONS.get(name) in carried:
            continue  # unregistered bytes (no type to give them) or one of bimscan's columns
        kind = np.asarray(sample[name]).dtype.str
        if dimension.num_elements == 1:
            sources.append((ExtraField(name, kind, dimension.description), name, None))
        else:
            sources += [(ExtraField(f"{name}_{i}", kind, dimension.description), name, i)
                        for i in range(dimension.num_elements)]
    return sources


def las_fields(path: Path) -> tuple[ExtraField, ...]:
    """The per-point fields of the LAS/LAZ ``path`` beyond a ``PointCloud``'s columns (see
    ``_las_field_sources``)."""
    return tuple(field for field, _, _ in _las_field_sources(check_input_path(path)))


def iter_las_fields(path: Path, fields: tuple[ExtraField, ...]) -> Iterator[np.ndarray]:
    """The values of ``fields`` (of ``las_fields``) of every point, blocks of ``field_values_dtype`` records."""
    path = check_input_path(path)
    where = {field.name: (dimension, element) for field, dimension, element in _las_field_sources(path)}
    with _open(path) as reader:
        try:
            for points in reader.chunk_iterator(COPY_BLOCK_POINTS):
                values = np.empty(len(points), dtype=field_values_dtype(fields))
                for field in fields:
                    dimension, element = where[field.name]
                    data = np.asarray(points[dimension])
                    values[field.name] = data if element is None else data[:, element]
                yield values
        except (LaspyException, EOFError, ValueError, RuntimeError) as exc:
            raise InputFileError(f"{path}: the point data is damaged ({exc}); check the file") from exc


def las_held(path: Path) -> tuple[str, ...]:
    """What the LAS/LAZ ``path`` holds beyond a ``PointCloud``'s columns and its ``las_fields``,
    in words: its CRS, other VLRs and EVLRs, unregistered extra bytes."""
    path = check_input_path(path)
    with _open(path) as reader:
        point_format = reader.header.point_format
    layout = read_las_layout(path)
    held: list[str] = []
    records = [*layout.vlrs, *layout.evlrs]
    crs = [r for r in records if r.user_id == PROJECTION_USER_ID]
    if crs:
        kinds = sorted({"WKT" if r.record_id in (2111, 2112) else "GeoTIFF keys" for r in crs})
        held.append(f"the CRS ({' and '.join(kinds)})")
    ours = {LOOKUP_ID, EXTRA_BYTES_ID, LASZIP_ID, DOCUMENT_ID}
    others = [f"{r.user_id}/{r.record_id}" for r in records
              if r.user_id != PROJECTION_USER_ID and (r.user_id, r.record_id) not in ours]
    if others:
        held.append(f"{'VLR/EVLR' if len(others) == 1 else 'VLRs/EVLRs'} {', '.join(others)}")
    if "ExtraBytes" in point_format.extra_dimension_names:
        held.append("extra bytes no VLR describes")
    return tuple(held)


def _foreign_columns(point_format: laspy.PointFormat) -> tuple[str, ...]:
    """The columns ``iter_las_chunks`` gives of another tool's file, in ``PointCloud.COLUMNS`` order."""
    names = set(point_format.dimension_names)
    present = {"xyz", "label", "intensity", "return_number", "number_of_returns"}
    present |= ({"time"} if "gps_time" in names else set()) | ({"rgb"} if "red" in names else set())
    return tuple(c for c in PointCloud.COLUMNS if c in present)


def copy_las_labelled(
    source: Path, target: Path, labels: np.ndarray, *, header: CloudHeader, overwrite: bool = False,
    checksum: bool = True,
) -> WrittenCloud:
    """Copy the LAS/LAZ ``source`` to ``target`` (.las or .laz) with ``labels`` (N,) uint8 in
    ``classification`` (see the section comment); registered as ``LABELLED_COPIERS["las"/"laz"]``.

    ``header``: what the copy stores in bimscan's header document (its origin becomes the file's
    offsets, which its coordinates are stored around). The class ids ``header.scheme`` holds decide
    the point format: formats 0-5 hold 0-31 and become their LAS 1.4 equivalent (6, 7, 9, 10) for more.
    """
    source = check_input_path(source)
    compress = target.suffix.lower() == ".laz"
    with _open(source) as reader:
        las_header = reader.header
        check_header(las_header, source)
        layout = read_las_layout(source)
        check_label_count(labels, layout.point_count, source)
        document_in = _stored_document(las_header, source)
        top_class = max((c.id for c in header.scheme.classes), default=0)
        upgraded = _upgrade(layout, top_class)
        out_format = layout.point_format if upgraded is None else upgraded
        version = layout.version if upgraded is None else (1, 4)
        base_in = layout.base_size
        base_out = int(laspy.PointFormat(out_format).size)
        record_out = layout.record_length - base_in + base_out
        if document_in is not None:
            columns = tuple(c for c in PointCloud.COLUMNS if c in {*document_in["columns"], "label"})
        else:
            columns = _foreign_columns(las_header.point_format)
        offsets = tuple(float(v) for v in las_header.offsets)
        document = dump_json(header_to_document(replace(header, origin=offsets), columns=columns,  # type: ignore[arg-type]
                                                n_points=layout.point_count))
        document_record = laspy.VLR(BIMSCAN_USER_ID, BIMSCAN_RECORD_ID, "bimscan cloud header (JSON)", document)
        in_vlr = version < (1, 4)
        if in_vlr and len(document) > 0xFFFF:
            raise OutputError(f"{target}: bimscan's header ({len(document):,} bytes) does not fit a LAS "
                              f"{version[0]}.{version[1]} VLR (64 KiB); label a LAS 1.4 copy of the file")
        # VLRs: the input's, with the lookup and bimscan's document replaced where they were
        lookup = _record_bytes(_classification_lookup(header.scheme), extended=False)
        vlrs: list[bytes] = []
        placed = {LOOKUP_ID: False, DOCUMENT_ID: not in_vlr}
        for record in layout.vlrs:
            key = (record.user_id, record.record_id)
            if key == LASZIP_ID:
                continue  # the compression's own record: dropped, or written anew below
            if key in placed:
                if not placed[key]:
                    vlrs.append(lookup if key == LOOKUP_ID else _record_bytes(document_record, extended=False))
                    placed[key] = True
                continue
            vlrs.append(record.raw)
        if not placed[LOOKUP_ID]:
            vlrs.append(lookup)
        if not placed[DOCUMENT_ID]:
            vlrs.append(_record_bytes(document_record, extended=False))
        laz_vlr = None
        if compress:
            import lazrs

            laz_vlr = lazrs.LazVlr.new_for_compression(out_format, record_out - base_out)
            vlrs.append(_record_bytes(LasZipVlr(laz_vlr.record_data()), extended=False))
        head = bytearray(layout.header)
        if upgraded is not None:
            head = _header_14(layout)
        vlr_bytes = b"".join(vlrs)
        struct.pack_into("<HII", head, 94, len(head), len(head) + len(vlr_bytes) + len(layout.vlr_tail), len(vlrs))
        struct.pack_into("<BH", head, 104, out_format | (0x80 if compress else 0), record_out)
        by_return = np.zeros(16, dtype=np.int64)

        with StagedOutput(target, overwrite=overwrite, checksum=checksum) as staged:
            out = staged.open(staged.file(target))
            out.write(bytes(head))
            out.write(vlr_bytes)
            out.write(layout.vlr_tail)
            compressor = None
            if laz_vlr is not None:
                import lazrs

                with signals_held():  # lazrs writes the chunk table's offset here
                    compressor = lazrs.ParLasZipCompressor(out, laz_vlr)
            done = 0
            try:
                for points in reader.chunk_iterator(COPY_BLOCK_POINTS):
                    rows = np.array(points.array, copy=True).view(np.uint8).reshape(-1, layout.record_length)
                    label = np.asarray(labels[done:done + len(rows)], dtype=np.uint8)
                    if upgraded is not None:
                        rows = _upgraded_rows(rows, layout, out_format, label, by_return)
                    elif layout.point_format < 6:
                        if len(label) and int(label.max()) > LEGACY_CLASS_MAX:
                            raise ValueError(f"class id {int(label.max())} above the scheme's {top_class}")
                        rows[:, 15] = (rows[:, 15] & 0b1110_0000) | label  # bits 5-7: synthetic, key point, withheld
                    else:
                        rows[:, 16] = label
                    if compressor is not None:
                        with signals_held(), staged.clock.step("compress"):
                            compressor.compress_many(rows.reshape(-1))
                    else:
                        out.write(memoryview(rows).cast("B"))
                    done += len(rows)
                if compressor is not None:
                    with signals_held():  # the last chunk and the chunk table
                        compressor.done()
            except (LaspyException, EOFError, RuntimeError) as exc:
                if out.error is not None:
                    raise
                raise InputFileError(f"{source}: the point data is damaged ({exc}); check the file") from exc
            if done != layout.point_count:
                raise InputFileError(f"{source}: the LAS header says {layout.point_count:,} points, the file holds "
                                     f"{done:,}; the file is damaged or cut short: copy or export it again")
            _copy_tail(source, layout, out, head, version, document_record, upgraded is not None, by_return)
            return staged.commit(n_points=layout.point_count)


def _header_14(layout: LasLayout) -> bytearray:
    """The public header block of a LAS 1.4 copy of an older file: its fields as they were, the
    fields 1.3 and 1.4 add (counts 64-bit, legacy counts 0 as formats 6-10 ask), then the bytes
    other software appended to the old block."""
    old = layout.header
    standard = _HEADER_13 if layout.version[1] == 3 else _LEGACY_HEADER if layout.version[1] < 4 else _HEADER_14
    head = bytearray(old[:_LEGACY_HEADER])
    head[25] = 4
    waveform = struct.unpack_from("<Q", old, 227)[0] if standard >= _HEADER_13 else 0
    head += struct.pack("<QQIQ15Q", waveform, 0, 0, layout.point_count, *([0] * 15))
    struct.pack_into("<I5I", head, 107, 0, 0, 0, 0, 0, 0)
    head += old[standard:]
    return head


def _upgraded_rows(rows: np.ndarray, layout: LasLayout, out_format: int, label: np.ndarray,
                   by_return: np.ndarray) -> np.ndarray:
    """Records (M, record length) uint8 of a legacy point format as records of ``out_format``:
    every field by name, scan angle rank to 0.006 deg steps, the class a whole byte, extra bytes as
    they were. Counts the points per return number into ``by_return`` (16,)."""
    base_in = layout.base_size
    old_format, new_format = laspy.PointFormat(layout.point_format), laspy.PointFormat(out_format)
    old = PackedPointRecord(np.ascontiguousarray(rows[:, :base_in]).view(old_format.dtype()).reshape(-1), old_format)
    new = PackedPointRecord.zeros(len(rows), new_format)
    new.copy_fields_from(old)
    new["scan_angle"] = np.rint(np.asarray(old["scan_angle_rank"], dtype=np.float64) / SCAN_ANGLE_STEP_DEG).astype(np.int16)
    new["classification"] = label
    by_return += np.bincount(np.asarray(new.return_number, dtype=np.int64), minlength=16)[:16]
    out = np.empty((len(rows), int(new_format.size) + rows.shape[1] - base_in), dtype=np.uint8)
    out[:, : new_format.size] = new.array.view(np.uint8).reshape(len(rows), -1)
    out[:, new_format.size:] = rows[:, base_in:]
    return out


def _copy_tail(source: Path, layout: LasLayout, out: WatchedFile, head: bytearray, version: tuple[int, int],
               document: laspy.VLR, upgraded: bool, by_return: np.ndarray) -> None:
    """Write what follows the points (bytes other software stored there, such as waveform data, and
    the EVLRs with bimscan's document replaced or added), then the finished header block."""
    tail_start = out.tell()
    end = layout.points_end
    tail_end = (layout.evlr_start if layout.evlrs and layout.evlr_start >= (end or 0) else layout.file_size)
    if end is not None and tail_end > end:
        with source.open("rb") as handle:
            handle.seek(end)
            remaining = tail_end - end
            while remaining:
                block = handle.read(min(remaining, 8 << 20))
                if not block:
                    break
                out.write(block)
                remaining -= len(block)
    moved: dict[int, int] = {}  # old offset of an EVLR -> new
    if version >= (1, 4):
        evlrs: list[tuple[int, bytes]] = []
        placed = False
        for record in layout.evlrs:
            if (record.user_id, record.record_id) == DOCUMENT_ID:
                if not placed:
                    evlrs.append((-1, _record_bytes(document, extended=True)))
                    placed = True
                continue
            evlrs.append((record.offset, record.raw))
        if not placed:
            evlrs.append((-1, _record_bytes(document, extended=True)))
        first = out.tell()
        for offset, raw in evlrs:
            moved[offset] = out.tell()
            out.write(raw)
        struct.pack_into("<QI", head, 235, first, len(evlrs))
        if upgraded:
            struct.pack_into("<15Q", head, 255, *(int(v) for v in by_return[1:16]))
    if version[1] >= 3 and layout.waveform_start:
        waveform = layout.waveform_start
        if waveform in moved:
            waveform = moved[waveform]
        elif end is not None and end <= waveform < tail_end:
            waveform = tail_start + waveform - end
        struct.pack_into("<Q", head, 227, waveform)
    out.seek(0)
    out.write(bytes(head))

__all__ = [
    "LAS_SCALE_M", "LasLayout", "check_las_copy", "copy_las_labelled", "iter_las_fields", "las_carriable", "las_fields",
    "las_held", "read_las_layout", "LAZ_CHUNK_POINTS", "LasCloudWriter", "check_header", "count_las_points", "iter_las_chunks",
    "lookup_name",
    "open_las_writer", "open_laz_writer", "read_las_header",
]

"""NumPy folder clouds in the Pointcept scene layout, written incrementally.

Layout of a bimscan NumPy folder (``scan/``):

===========================  ==========  =============================================================
file                         dtype       content
===========================  ==========  =============================================================
``coord.npy``                (N, 3) f4   xyz - origin, metres (float32 keeps ~1e-5 m within 100 m)
``origin.npy``               (3,) f8     the origin (``CloudHeader.origin``), metres
``segment.npy``              (N,) i4     label (semantic class id)
``instance.npy``             (N,) i4     component id (-1: none)
``station.npy``              (N,) u2     station id
``intensity.npy``            (N,) u2     intensity
``time.npy``                 (N,) f8     seconds since the start of the survey
``return_number.npy``        (N,) u1     which echo of its pulse (1-based)
``number_of_returns.npy``    (N,) u1     echoes of its pulse
``color.npy``                (N, 3) u1   RGB colour (Pointcept's name)
``ring.npy``                 (N,) u1     lidar ring (mobile scans: the beam's rank by elevation)
``channel.npy``              (N,) u1     which lidar of the platform (mobile scans)
``sensor.npy``               (N, 3) f8   beam origin at the pulse's time, metres (mobile scans)
``meta.json``                            the header document (``bimscan.io._header``), origin included
===========================  ==========  =============================================================

Files of columns the cloud lacks are not written. ``meta.json`` marks the folder as bimscan's: with
``overwrite`` a folder is replaced only when it has that marker and holds nothing but the files
above (``FOLDER_OUTPUTS["npy"]``); a folder of someone else's (a stray ``coord.npy`` included) is
refused. Each ``.npy`` is streamed: its header is
written first with a fixed size (``NPY_HEADER_BYTES``) and rewritten at close with the final
shape, padded with spaces as the format allows, so ``np.load`` reads it (memory-mapped too).
The folder is built under a temporary name and renamed into place at close.
"""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.errors import InputFileError
from bimscan.files import FOLDER_OUTPUTS, FolderOutput, folder_entries, json_marker, read_marker
from bimscan.io._header import (
    HEADER_KEY,
    as_labels,
    dump_json,
    header_from_document,
    header_to_document,
    parse_document,
)
from bimscan.io._labelled import CopyCheck, ExtraField, check_label_count, field_values_dtype
from bimscan.io._writer import StagedOutput, StreamingCloudWriter, WatchedFile, WrittenCloud, check_input_path
from bimscan.types import CloudHeader, PointCloud

# column -> (file stem, dtype, row shape)
NPDIR_FILES: dict[str, tuple[str, str, tuple[int, ...]]] = {
    "xyz": ("coord", "<f4", (3,)),
    "label": ("segment", "<i4", ()),
    "component": ("instance", "<i4", ()),
    "station": ("station", "<u2", ()),
    "intensity": ("intensity", "<u2", ()),
    "time": ("time", "<f8", ()),
    "return_number": ("return_number", "u1", ()),
    "number_of_returns": ("number_of_returns", "u1", ()),
    "rgb": ("color", "u1", (3,)),
    "ring": ("ring", "u1", ()),
    "channel": ("channel", "u1", ()),
    "sensor_xyz": ("sensor", "<f8", (3,)),
}
META_NAME = "meta.json"
ORIGIN_NAME = "origin.npy"
BLOCK_ROWS = 1 << 22  # labels a copy converts at a time
NPY_HEADER_BYTES = 128  # magic + version + length + dict padded; fits a 20-digit row count
_NPY_MAGIC = b"\x93NUMPY\x01\x00"
NPDIR_NAMES = frozenset({f"{stem}.npy" for stem, _, _ in NPDIR_FILES.values()} | {ORIGIN_NAME, META_NAME})


COPIED_KEY = "copied_entries"  # meta.json of a labelled copy: the entries it copied from its input


def foreign_npdir_entries(folder: Path) -> list[str] | None:
    """None unless ``folder`` is marked as a bimscan NumPy cloud (its ``meta.json`` is a cloud header
    document); then the entries bimscan does not write in one (sub-folders as ``name/``): neither
    its own files nor those a labelled copy wrote there (listed in ``meta.json``)."""
    marker = read_marker(folder / META_NAME)
    if not json_marker(marker, HEADER_KEY):
        return None
    copied = json.loads(marker or b"{}").get(COPIED_KEY, [])
    written = NPDIR_NAMES | {str(name) for name in copied} if isinstance(copied, list) else NPDIR_NAMES
    return [name for name in folder_entries(folder) if name not in written]


FOLDER_OUTPUTS["npy"] = FolderOutput(what="a bimscan NumPy cloud", foreign=foreign_npdir_entries)


def npy_header(dtype: str, shape: tuple[int, ...]) -> bytes:
    """A version 1.0 ``.npy`` header of exactly ``NPY_HEADER_BYTES`` bytes."""
    text = f"{{'descr': '{dtype}', 'fortran_order': False, 'shape': {shape!r}, }}"
    size = NPY_HEADER_BYTES - len(_NPY_MAGIC) - 2
    if len(text) + 1 > size:  # pragma: no cover - shapes here are at most 2-D with 20 digits
        raise ValueError(f"npy header {text!r} does not fit {NPY_HEADER_BYTES} bytes")
    body = text.ljust(size - 1) + "\n"
    return _NPY_MAGIC + size.to_bytes(2, "little") + body.encode("latin1")


class NpdirCloudWriter(StreamingCloudWriter):
    """Streams ``PointCloud`` chunks into a Pointcept-style NumPy folder."""

    FOLDER_KIND = "npy"

    def __init__(self, path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                 fields: tuple[ExtraField, ...] = ()) -> None:
        super().__init__(path, header=header, overwrite=overwrite, checksum=checksum, fields=fields)
        self._files: dict[str, WatchedFile] = {}
        self._field_files: dict[str, WatchedFile] = {}
        self._origin = np.asarray(header.origin, dtype=np.float64)

    def _begin(self, columns: tuple[str, ...]) -> None:
        self._folder = self._stage_dir(self.path)
        for column in columns:
            stem, dtype, row_shape = NPDIR_FILES[column]
            handle = self._watch(self._folder / f"{stem}.npy")
            handle.write(npy_header(dtype, (0, *row_shape)))
            self._files[column] = handle
        for field in self.fields:  # another format's per-point fields: one array each, named as they were
            handle = self._watch(self._folder / f"{field.name}.npy")
            handle.write(npy_header(np.dtype(field.dtype).str, (0,)))
            self._field_files[field.name] = handle

    def _append(self, chunk: PointCloud, values: np.ndarray | None) -> None:
        for name, handle in self._field_files.items():
            handle.write(memoryview(np.ascontiguousarray(values[name])).cast("B"))  # type: ignore[index]
        for column, handle in self._files.items():
            _, dtype, _ = NPDIR_FILES[column]
            if column == "xyz":  # float32 around the origin, without a float64 temporary
                values = np.empty(chunk.xyz.shape, dtype=dtype)
                np.subtract(chunk.xyz, self._origin, out=values, casting="same_kind")
            else:
                values = np.ascontiguousarray(getattr(chunk, column), dtype=dtype)
            handle.write(memoryview(values).cast("B"))

    def _finish(self) -> None:
        assert self.columns is not None
        for column, handle in self._files.items():
            _, dtype, row_shape = NPDIR_FILES[column]
            handle.seek(0)
            handle.write(npy_header(dtype, (self.n_points, *row_shape)))
        for field in self.fields:
            handle = self._field_files[field.name]
            handle.seek(0)
            handle.write(npy_header(np.dtype(field.dtype).str, (self.n_points,)))
        np.save(self._watch(self._folder / ORIGIN_NAME), self._origin)
        document = header_to_document(self.header, columns=self.columns, n_points=self.n_points)
        if self.fields:
            document[COPIED_KEY] = sorted(f"{field.name}.npy" for field in self.fields)
        self._watch(self._folder / META_NAME).write(dump_json(document, indent=1))

    def _release(self) -> None:
        self._files = {}
        self._field_files = {}
        super()._release()


def open_npdir_writer(path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                      fields: tuple[ExtraField, ...] = ()) -> NpdirCloudWriter:
    """A NumPy folder writer (registered as ``WRITERS["npy"]``); ``fields``: one ``<name>.npy`` each."""
    return NpdirCloudWriter(path, header=header, overwrite=overwrite, checksum=checksum, fields=fields)


_FILE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


def npdir_carriable(fields: tuple[ExtraField, ...]) -> tuple[tuple[ExtraField, ...], tuple[str, ...]]:
    """The ``fields`` a NumPy folder writer stores as ``<name>.npy``, and the others in words:
    names of bimscan's own files, names that are no plain file name."""
    taken = {name.lower() for name in NPDIR_NAMES}
    carried, lost = [], []
    for field in fields:
        if f"{field.name}.npy".lower() in taken:
            lost.append(f"{field.name!r} (a name bimscan's NumPy folder uses)")
        elif not _FILE_NAME.fullmatch(field.name):
            lost.append(f"{field.name!r} (not a plain file name)")
        else:
            carried.append(field)
            taken.add(f"{field.name}.npy".lower())
    return tuple(carried), tuple(lost)


# -- reading ------------------------------------------------------------------------------------

def _stored_document(folder: Path) -> dict[str, Any] | None:
    meta = folder / META_NAME
    if not meta.is_file():
        return None
    return parse_document(meta.read_bytes(), where=str(meta))


def read_npdir_header(path: str | Path) -> CloudHeader | None:
    """The ``CloudHeader`` bimscan stored in a NumPy folder's ``meta.json``, or None."""
    folder = check_input_path(path)
    document = _stored_document(folder)
    return None if document is None else header_from_document(document, where=str(folder / META_NAME))


def _load(path: Path) -> np.ndarray:
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{path}: not a readable .npy file ({exc}); check the file") from exc


def count_npdir_points(path: str | Path) -> int:
    """Rows of a NumPy folder's ``coord.npy`` (its header; a short file is refused by NumPy)."""
    folder = check_input_path(path)
    coord = _load(folder / "coord.npy")
    return int(coord.shape[0])


def iter_npdir_chunks(
    path: str | Path, *, chunk_points: int = 2_000_000, label_field: str | None = None, labels: bool = True,
) -> Iterator[PointCloud]:
    """Stream a NumPy folder as ``PointCloud`` chunks of at most ``chunk_points`` rows.

    ``label_field`` names the ``.npy`` file holding labels (e.g. ``"segment20"``); by default
    ``segment.npy``. Foreign Pointcept folders without ``origin.npy`` have their origin at 0.
    ``labels`` False: label None (not read).
    """
    folder = check_input_path(path)
    if not folder.is_dir():
        raise InputFileError(f"{folder}: not a folder; a NumPy cloud is a folder holding coord.npy")
    if chunk_points < 1:
        raise ValueError(f"chunk_points must be positive, got {chunk_points}")
    if not (folder / "coord.npy").is_file():
        raise InputFileError(f"{folder}: no coord.npy; not a Pointcept-style NumPy cloud folder")
    coord = _load(folder / "coord.npy")
    if coord.ndim != 2 or coord.shape[1] < 3:
        raise InputFileError(f"{folder / 'coord.npy'}: shape {coord.shape}, expected (N, 3)")
    origin = np.zeros(3)
    if (folder / ORIGIN_NAME).is_file():
        origin = np.asarray(_load(folder / ORIGIN_NAME), dtype=np.float64)
        if origin.shape != (3,):
            raise InputFileError(f"{folder / ORIGIN_NAME}: shape {origin.shape}, expected (3,); the folder is damaged")
    stems = {"label": label_field or "segment", "component": "instance", "station": "station",
             "intensity": "intensity", "time": "time", "return_number": "return_number",
             "number_of_returns": "number_of_returns", "rgb": "color", "ring": "ring", "channel": "channel",
             "sensor_xyz": "sensor"}
    if label_field is not None and not (folder / f"{label_field}.npy").is_file():
        present = sorted(p.stem for p in folder.glob("*.npy"))
        raise InputFileError(f"{folder}: no {label_field}.npy to read labels from; the folder has {', '.join(present)}")
    if not labels:
        del stems["label"]
    arrays = {}
    for column, stem in stems.items():
        file = folder / f"{stem}.npy"
        if file.is_file():
            array = _load(file)
            if array.shape[0] != coord.shape[0]:
                raise InputFileError(f"{file}: {array.shape[0]} rows but coord.npy has {coord.shape[0]}; the folder is inconsistent")
            if column in ("rgb", "sensor_xyz"):
                if array.ndim != 2 or array.shape[1] < 3:
                    raise InputFileError(f"{file}: shape {array.shape}, expected (N, 3) colours; the folder is damaged")
                arrays[column] = array
            else:
                arrays[column] = array.reshape(len(array), -1)[:, 0] if array.ndim > 1 else array
    where = str(folder)
    for start in range(0, max(len(coord), 1), chunk_points):
        stop = min(start + chunk_points, len(coord))
        xyz = np.asarray(coord[start:stop, :3], dtype=np.float64) + origin
        columns: dict[str, np.ndarray] = {}
        for column, array in arrays.items():
            values = np.asarray(array[start:stop])
            if column == "label":
                columns[column] = as_labels(values, field=f"{stems['label']}.npy", where=where)
            elif column == "component":
                columns[column] = values.astype(np.int32)
            elif column in ("station", "intensity"):
                columns[column] = values.astype(np.uint16)
            elif column in ("return_number", "number_of_returns", "ring", "channel"):
                columns[column] = values.astype(np.uint8)
            elif column == "sensor_xyz":
                columns[column] = np.asarray(values[:, :3], dtype=np.float64)
            elif column == "rgb":
                # Pointcept stores colour as uint8 or as floats 0..255 (or 0..1 from some converters)
                rgb = np.asarray(values[:, :3])
                if rgb.dtype.kind == "f":
                    rgb = np.clip(np.rint(rgb * 255.0 if len(rgb) and rgb.max() <= 1.0 else rgb), 0, 255)
                columns[column] = rgb.astype(np.uint8)
            else:
                columns[column] = values.astype(np.float64)
        yield PointCloud(xyz=xyz, **columns)



# -- labelled copies ------------------------------------------------------------------------------
#
# A labelled copy of a NumPy folder holds every entry of its input as it was (every array, any
# other file, sub-folders, links as links), with ``segment.npy`` written anew (in the input's
# dtype and shape when it had one that holds the class ids, else bimscan's int32) and bimscan's
# ``meta.json`` (kept as it is when it is another tool's), which lists the entries it copied, so a
# later run may replace the folder as bimscan's own.

LABEL_STEM = NPDIR_FILES["label"][0]


def _label_layout(folder: Path, top_class: int) -> tuple[str, tuple[int, ...]] | None:
    """The (dtype, row shape) of the input's ``segment.npy`` when a copy can keep it (an integer or
    float array of (N,) or (N, 1) that holds ``top_class``), None otherwise (bimscan's int32 (N,))."""
    file = folder / f"{LABEL_STEM}.npy"
    if not file.is_file():
        return None
    array = _load(file)
    kind = array.dtype
    if array.ndim not in (1, 2) or (array.ndim == 2 and array.shape[1] != 1) or kind.kind not in "iuf":
        return None
    if kind.kind in "iu" and np.iinfo(kind).max < top_class:
        return None
    return kind.str, tuple(array.shape[1:])


def check_npdir_copy(path: Path, target_format: str, top_class: int) -> CopyCheck:
    """What a labelled copy of the NumPy folder ``path`` does not keep as it was: a ``segment.npy``
    whose dtype or shape cannot hold the class ids becomes bimscan's int32."""
    folder = check_input_path(path)
    file = folder / f"{LABEL_STEM}.npy"
    if file.is_file() and _label_layout(folder, top_class) is None:
        array = _load(file)
        return CopyCheck(changed=(f"{file.name} ({array.dtype}, shape {array.shape}) becomes int32 (N,): it cannot "
                                  f"hold the class ids up to {top_class}",))
    return CopyCheck()


_READ_NAMES = frozenset({f"{stem}.npy" for stem, _, _ in NPDIR_FILES.values()} | {ORIGIN_NAME, META_NAME})


def _field_arrays(folder: Path) -> tuple[list[tuple[ExtraField, str, int | None]], list[str]]:
    """(field, file name, column or None) of every array of ``folder`` the reader does not take that
    holds one number (N,) or a row (N, k) per point (a column ``<stem>_<i>`` each), and the names
    of its other entries (files, folders, arrays of other shapes)."""
    rows = count_npdir_points(folder)
    fields: list[tuple[ExtraField, str, int | None]] = []
    other: list[str] = []
    for name in folder_entries(folder):
        if name in _READ_NAMES:
            continue
        array = _load(folder / name) if name.endswith(".npy") and (folder / name).is_file() else None
        if array is None or array.dtype.kind not in "biuf" or array.ndim not in (1, 2) or array.shape[0] != rows:
            other.append(name)
            continue
        stem, kind = name[: -len(".npy")], array.dtype.newbyteorder("<").str
        if array.ndim == 1:
            fields.append((ExtraField(stem, kind), name, None))
        else:
            fields += [(ExtraField(f"{stem}_{i}", kind), name, i) for i in range(array.shape[1])]
    return fields, other


def npdir_fields(path: Path) -> tuple[ExtraField, ...]:
    """The per-point arrays of the NumPy folder ``path`` the reader does not take (see ``_field_arrays``)."""
    return tuple(field for field, _, _ in _field_arrays(check_input_path(path))[0])


def iter_npdir_fields(path: Path, fields: tuple[ExtraField, ...]) -> Iterator[np.ndarray]:
    """The values of ``fields`` (of ``npdir_fields``) of every point, blocks of records."""
    folder = check_input_path(path)
    sources = {field.name: (name, column) for field, name, column in _field_arrays(folder)[0]}
    arrays = {name: _load(folder / name) for name, _ in sources.values()}
    rows = count_npdir_points(folder)
    for start in range(0, max(rows, 1), BLOCK_ROWS):
        stop = min(start + BLOCK_ROWS, rows)
        values = np.empty(stop - start, dtype=field_values_dtype(fields))
        for field in fields:
            name, column = sources[field.name]
            block = arrays[name][start:stop]
            values[field.name] = block if column is None else block[:, column]
        yield values


def npdir_held(path: Path) -> tuple[str, ...]:
    """The entries of the NumPy folder ``path`` that are neither read nor ``npdir_fields``, in words."""
    other = _field_arrays(check_input_path(path))[1]
    if not other:
        return ()
    return (("entry " if len(other) == 1 else "entries ") + ", ".join(other),)


def copy_npdir_labelled(
    source: Path, target: Path, labels: np.ndarray, *, header: CloudHeader, overwrite: bool = False,
    checksum: bool = True,
) -> WrittenCloud:
    """Copy the NumPy folder ``source`` to ``target`` with ``labels`` (N,) uint8 in ``segment.npy``
    (see the section comment); registered as ``LABELLED_COPIERS["npy"]``."""
    folder = check_input_path(source)
    n_points = count_npdir_points(folder)
    check_label_count(labels, n_points, folder)
    top_class = max((c.id for c in header.scheme.classes), default=0)
    layout = _label_layout(folder, top_class)
    dtype, row_shape = layout if layout is not None else ("<i4", ())
    meta = read_marker(folder / META_NAME)
    ours = meta is None or json_marker(meta, HEADER_KEY)  # absent, or bimscan's: written anew
    entries = [name for name in folder_entries(folder) if name != f"{LABEL_STEM}.npy"
               and not (ours and name == META_NAME)]
    with StagedOutput(target, overwrite=overwrite, checksum=checksum, kind="npy") as staged:
        temp = staged.folder(target, kind="npy")
        for name in entries:
            entry = folder / name.rstrip("/")
            if name.endswith("/"):
                shutil.copytree(entry, temp / name.rstrip("/"), symlinks=True)
            else:
                shutil.copy2(entry, temp / name, follow_symlinks=False)
        out = staged.open(temp / f"{LABEL_STEM}.npy")
        out.write(npy_header(dtype, (n_points, *row_shape)))
        for start in range(0, n_points, BLOCK_ROWS):
            block = np.asarray(labels[start:start + BLOCK_ROWS]).astype(dtype)
            out.write(memoryview(np.ascontiguousarray(block)).cast("B"))
        if ours:
            origin = np.zeros(3)
            if (folder / ORIGIN_NAME).is_file():
                origin = np.asarray(_load(folder / ORIGIN_NAME), dtype=np.float64)
            columns = tuple(c for c in PointCloud.COLUMNS if c == "label" or c == "xyz"
                            or (folder / f"{NPDIR_FILES[c][0]}.npy").is_file())
            document = header_to_document(replace(header, origin=tuple(float(v) for v in origin)),  # type: ignore[arg-type]
                                          columns=columns, n_points=n_points)
            document[COPIED_KEY] = sorted(name for name in entries if name not in NPDIR_NAMES)
            staged.open(temp / META_NAME).write(dump_json(document, indent=1))
        return staged.commit(n_points=n_points)

__all__ = [
    "NPDIR_FILES", "check_npdir_copy", "copy_npdir_labelled", "iter_npdir_fields", "npdir_carriable", "npdir_fields",
    "npdir_held", "NPDIR_NAMES", "NpdirCloudWriter", "count_npdir_points", "foreign_npdir_entries", "iter_npdir_chunks",
    "npy_header", "open_npdir_writer", "read_npdir_header",
]

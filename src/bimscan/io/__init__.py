"""Cloud and mesh files: streamed, atomic, reproducible writers and readers.

Clouds: LAS 1.4 / LAZ (``las``), binary PLY (``ply``), E57 with one scan per station
(``e57``) and Pointcept-style NumPy folders (``npdir``), chosen by the path's suffix (no suffix, or a trailing ``/``: a NumPy folder). Every
writer takes ``PointCloud`` chunks as they come, keeps its memory bounded whatever the point
count, writes under a temporary name renamed at close, stores the ``CloudHeader`` (label scheme,
component table, stations, metadata) with the points, and gives the same bytes for the same
points however they were chunked. Meshes: ``export_obj`` (OBJ with one group per component,
one OBJ per component, an index CSV, optionally a HELIOS++ scene) and ``read_obj``.

::

    with open_cloud_writer("scan.laz", header=header) as writer:
        for chunk in chunks:
            writer.write(chunk)
    written = writer.close()          # path, n_points, files, sha256
    cloud = read_cloud("scan.laz")
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError, OutputError
from bimscan.io._writer import CloudWriter, WrittenCloud, check_input_path, check_output_path
from bimscan.io.e57 import count_e57_points, iter_e57_chunks, open_e57_writer, read_e57_header
from bimscan.io.las import count_las_points, iter_las_chunks, open_las_writer, open_laz_writer, read_las_header
from bimscan.io.npdir import count_npdir_points, iter_npdir_chunks, open_npdir_writer, read_npdir_header
from bimscan.io.obj import ObjExport, export_obj, read_obj
from bimscan.io.ply import count_ply_points, iter_ply_chunks, open_ply_writer, read_ply_header
from bimscan.types import CloudHeader, PointCloud

# Format key: the lower-case suffix; "" is a NumPy folder.
WRITERS: dict[str, Callable[..., CloudWriter]] = {
    ".las": open_las_writer,
    ".laz": open_laz_writer,
    ".ply": open_ply_writer,
    ".e57": open_e57_writer,
    "": open_npdir_writer,
}
CHUNK_READERS: dict[str, Callable[..., Iterator[PointCloud]]] = {
    ".las": iter_las_chunks,
    ".laz": iter_las_chunks,
    ".ply": iter_ply_chunks,
    ".e57": iter_e57_chunks,
    "": iter_npdir_chunks,
}
HEADER_READERS: dict[str, Callable[[str | Path], CloudHeader | None]] = {
    ".las": read_las_header,
    ".laz": read_las_header,
    ".ply": read_ply_header,
    ".e57": read_e57_header,
    "": read_npdir_header,
}
POINT_COUNTERS: dict[str, Callable[[str | Path], int]] = {
    ".las": count_las_points,
    ".laz": count_las_points,
    ".ply": count_ply_points,
    ".e57": count_e57_points,
    "": count_npdir_points,
}
# Bytes a point takes on disk at most, per format (LAZ: a bound on what scans compress to), for
# the free-space check before a long scan.
BYTES_PER_POINT: dict[str, int] = {".las": 36, ".laz": 12, ".ply": 41, ".e57": 40, "": 29}
_SUPPORTED = ".las, .laz, .ply, .e57, or a folder path without suffix (NumPy)"


def output_format(path: str | Path) -> str:
    """The WRITERS key for an output path: its lower-case suffix, "" for a folder."""
    text = str(path)
    if text.endswith("/"):
        return ""
    return Path(text).suffix.lower()


def _writer_key(path: str | Path) -> str:
    key = output_format(path)
    if key not in WRITERS:
        raise OutputError(f"{path}: unknown cloud format {key!r}; write {_SUPPORTED}")
    return key


def _input_format(path: Path) -> str:
    key = "" if path.is_dir() else path.suffix.lower()
    if key not in CHUNK_READERS or (key == "" and not path.is_dir()):
        raise InputFileError(f"{path}: unknown cloud format {path.suffix!r}; bimscan reads {_SUPPORTED}")
    return key


def open_cloud_writer(
    path: str | Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True
) -> CloudWriter:
    """A streamed writer for ``path``, its format chosen by suffix (see ``WRITERS``).

    Raises OutputError for an unknown suffix, a missing parent folder, or an existing output
    (file, folder, or PLY sidecar) without ``overwrite``. ``checksum`` makes ``close()`` report
    the SHA-256 of every file written (one extra read of the output, from the page cache).
    """
    return WRITERS[_writer_key(path)](Path(path), header=header, overwrite=overwrite, checksum=checksum)


def check_cloud_output(path: str | Path, *, overwrite: bool = False) -> None:
    """Raise OutputError now for an output ``open_cloud_writer`` would refuse (unknown suffix,
    missing folder, existing output), so a long job fails before it starts rather than at the end."""
    _writer_key(path)
    check_output_path(Path(path), overwrite=overwrite)


def check_free_space(path: str | Path, *, points: int) -> None:
    """Raise OutputError when the folder of ``path`` has less free space than ``points`` points take
    in its format (``BYTES_PER_POINT``), so a long job fails before it starts rather than at the end."""
    key = _writer_key(path)
    needed = points * BYTES_PER_POINT[key]
    free = shutil.disk_usage(Path(path).parent).free
    if needed > free:
        raise OutputError(f"{path}: the scan may write up to {needed / 1e9:.1f} GB but {Path(path).parent} has "
                          f"{free / 1e9:.1f} GB free; free space or choose another output")


def read_cloud(path: str | Path, *, label_field: str | None = None) -> PointCloud:
    """Read a whole cloud (bimscan's own or another tool's) as one ``PointCloud``.

    ``label_field`` names the field holding labels; None: bimscan files -> their labels,
    foreign files -> ``classification`` (LAS) or a label-like property (PLY) when present (E57:
    only a named ``label_field``).
    Columns a file lacks are None.
    """
    chunks = list(iter_cloud_chunks(path, chunk_points=1 << 62, label_field=label_field))
    return chunks[0] if len(chunks) == 1 else PointCloud.concatenate(chunks)


def iter_cloud_chunks(
    path: str | Path, *, chunk_points: int = 2_000_000, label_field: str | None = None
) -> Iterator[PointCloud]:
    """Stream a cloud as ``PointCloud`` chunks of at most ``chunk_points`` rows (see read_cloud)."""
    path = check_input_path(path)
    chunks = CHUNK_READERS[_input_format(path)](path, chunk_points=chunk_points, label_field=label_field)
    return _finite_points(chunks, path)


def _finite_points(chunks: Iterator[PointCloud], path: Path) -> Iterator[PointCloud]:
    """The chunks as they come; InputFileError at the first point with a NaN or infinite coordinate
    (a damaged file: every figure computed from it would be nonsense)."""
    seen = 0
    for chunk in chunks:
        finite = np.isfinite(chunk.xyz).all(axis=1)
        if not finite.all():
            first = int(np.flatnonzero(~finite)[0])
            raise InputFileError(
                f"{path}: point {seen + first:,} has coordinates {chunk.xyz[first].tolist()} ({int((~finite).sum()):,} "
                "non-finite points in its chunk); the file is damaged: export it again")
        seen += len(chunk)
        yield chunk


def count_points(path: str | Path) -> int:
    """The number of points a cloud file says it holds (its header; bodies shorter than that are refused)."""
    path = check_input_path(path)
    return POINT_COUNTERS[_input_format(path)](path)


def read_cloud_header(path: str | Path) -> CloudHeader | None:
    """The ``CloudHeader`` bimscan stored with a cloud, or None for a foreign file."""
    path = check_input_path(path)
    return HEADER_READERS[_input_format(path)](path)


__all__ = [
    "CHUNK_READERS", "HEADER_READERS", "POINT_COUNTERS", "WRITERS", "CloudWriter", "ObjExport", "WrittenCloud",
    "check_cloud_output", "check_free_space", "count_points", "export_obj", "iter_cloud_chunks", "open_cloud_writer", "output_format", "read_cloud",
    "read_cloud_header", "read_obj",
]

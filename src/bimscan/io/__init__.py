"""Cloud and mesh files: streamed, atomic, reproducible writers and readers.

Clouds: LAS 1.4 (``las``), LAZ (``laz``), binary PLY (``ply``), E57 with one scan per station
(``e57``) and Pointcept-style NumPy folders (``npy``), chosen by the path's suffix (no suffix, or a
trailing ``/``: a NumPy folder); these are ``WRITABLE_FORMATS``. The readers also take plain-text
clouds (``text``, :mod:`bimscan.io.text`) and S3DIS rooms (``s3dis``, :mod:`bimscan.io.s3dis`).
``CLOUD_FORMATS`` is the one vocabulary of format names: every registry here is keyed by it. Every
writer takes ``PointCloud`` chunks as they come, keeps its memory bounded whatever the point
count, writes under a temporary name renamed at close, stores the ``CloudHeader`` (label scheme,
component table, stations, metadata) with the points, and gives the same bytes for the same
points however they were chunked. Labelled copies (``plan_labelled_copy``, ``write_labelled_copy``)
write a user's cloud again with new classes, keeping everything else it holds (``LABELLED_COPIERS``,
one copier per input format; another format through its writer, with the fields it can hold). Meshes: ``export_obj`` (OBJ with one group per component,
one OBJ per component, an index CSV, optionally a HELIOS++ scene) and ``read_obj``.

::

    with open_cloud_writer("scan.laz", header=header) as writer:
        for chunk in chunks:
            writer.write(chunk)
    written = writer.close()          # path, n_points, files, sha256
    cloud = read_cloud("scan.laz")
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator, Sequence
from contextlib import closing
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError, OutputError
from bimscan.io._labelled import CopyCheck, ExtraField, LabelledCopier, field_values_dtype
from bimscan.io._header import present_columns
from bimscan.io._writer import CloudWriter, WrittenCloud, check_input_path, check_output_path
from bimscan.io.e57 import (
    check_e57_columns,
    check_e57_copy,
    copy_e57_labelled,
    count_e57_points,
    e57_carriable,
    e57_fields,
    e57_held,
    iter_e57_chunks,
    iter_e57_fields,
    open_e57_writer,
    read_e57_header,
)
from bimscan.io.las import (
    check_las_copy,
    copy_las_labelled,
    count_las_points,
    iter_las_chunks,
    iter_las_fields,
    las_carriable,
    las_fields,
    las_held,
    open_las_writer,
    open_laz_writer,
    read_las_header,
)
from bimscan.io.npdir import (
    check_npdir_copy,
    copy_npdir_labelled,
    count_npdir_points,
    iter_npdir_chunks,
    iter_npdir_fields,
    npdir_carriable,
    npdir_fields,
    npdir_held,
    open_npdir_writer,
    read_npdir_header,
)
from bimscan.io.obj import ObjExport, export_obj, read_obj
from bimscan.io.ply import (
    check_ply_copy,
    copy_ply_labelled,
    count_ply_points,
    iter_ply_chunks,
    iter_ply_fields,
    open_ply_writer,
    ply_carriable,
    ply_fields,
    ply_held,
    read_ply_header,
    sidecar_path,
)
from bimscan.io.s3dis import count_s3dis_points, is_s3dis_room, iter_s3dis_chunks
from bimscan.io.text import (
    TEXT_SUFFIXES,
    check_text_copy,
    copy_text_labelled,
    count_text_points,
    iter_text_chunks,
    iter_text_fields,
    text_fields,
    text_held,
)
from bimscan.types import CloudHeader, PointCloud

# One vocabulary of cloud formats, shared with the dataset layout (``bimscan.dataset.layout``):
# format name -> the path suffixes that name it ("": a folder path, no suffix or a trailing "/").
# An S3DIS room is a folder too, told by its ``Annotations/`` and never by its name.
CLOUD_FORMATS: dict[str, tuple[str, ...]] = {
    "las": (".las",),
    "laz": (".laz",),
    "ply": (".ply",),
    "e57": (".e57",),
    "npy": ("",),
    "text": TEXT_SUFFIXES,
    "s3dis": (),
}
WRITABLE_FORMATS: tuple[str, ...] = ("las", "laz", "ply", "e57", "npy")

WRITERS: dict[str, Callable[..., CloudWriter]] = {
    "las": open_las_writer,
    "laz": open_laz_writer,
    "ply": open_ply_writer,
    "e57": open_e57_writer,
    "npy": open_npdir_writer,
}
# Every chunk reader takes (path, *, chunk_points, label_field, labels); labels False: label None.
CHUNK_READERS: dict[str, Callable[..., Iterator[PointCloud]]] = {
    "las": iter_las_chunks,
    "laz": iter_las_chunks,
    "ply": iter_ply_chunks,
    "e57": iter_e57_chunks,
    "npy": iter_npdir_chunks,
    "text": iter_text_chunks,
    "s3dis": iter_s3dis_chunks,
}
HEADER_READERS: dict[str, Callable[[str | Path], CloudHeader | None]] = {
    "las": read_las_header,
    "laz": read_las_header,
    "ply": read_ply_header,
    "e57": read_e57_header,
    "npy": read_npdir_header,
    "text": lambda path: None,  # plain text stores no header
    "s3dis": lambda path: None,  # nor does an S3DIS room (its labels: indices in S3DIS_CLASSES)
}
POINT_COUNTERS: dict[str, Callable[[str | Path], int]] = {
    "las": count_las_points,
    "laz": count_las_points,
    "ply": count_ply_points,
    "e57": count_e57_points,
    "npy": count_npdir_points,
    "text": count_text_points,
    "s3dis": count_s3dis_points,
}
# Labelled copies (``plan_labelled_copy``, ``write_labelled_copy``): per input format, the output
# formats a copy keeps everything of the input in, and how (see ``bimscan.io._labelled``).
_LAS_COPIER = LabelledCopier(targets=("las", "laz"), check=check_las_copy, copy=copy_las_labelled, held=las_held,
                             fields=las_fields, iter_fields=iter_las_fields)
LABELLED_COPIERS: dict[str, LabelledCopier] = {
    "las": _LAS_COPIER,
    "laz": _LAS_COPIER,
    "ply": LabelledCopier(targets=("ply",), check=check_ply_copy, copy=copy_ply_labelled, held=ply_held,
                          fields=ply_fields, iter_fields=iter_ply_fields),
    "e57": LabelledCopier(targets=("e57",), check=check_e57_copy, copy=copy_e57_labelled, held=e57_held,
                          fields=e57_fields, iter_fields=iter_e57_fields),
    "npy": LabelledCopier(targets=("npy",), check=check_npdir_copy, copy=copy_npdir_labelled, held=npdir_held,
                          fields=npdir_fields, iter_fields=iter_npdir_fields),
    "text": LabelledCopier(targets=("text",), check=check_text_copy, copy=copy_text_labelled, held=text_held,
                           fields=text_fields, iter_fields=iter_text_fields),
}
# Which of another format's per-point fields (``ExtraField``) each writer stores beside the columns,
# and why not the others: (carried, the others in words).
FIELD_CARRIERS: dict[str, Callable[[tuple[ExtraField, ...]], tuple[tuple[ExtraField, ...], tuple[str, ...]]]] = {
    "las": las_carriable,
    "laz": las_carriable,
    "ply": ply_carriable,
    "e57": e57_carriable,
    "npy": npdir_carriable,
}
# Bytes a point of the paper's scanner takes on disk at most, per format (LAZ: a bound on what
# scans compress to; colour, extra echoes and mobile columns add more), for the free-space check
# before a long scan.
BYTES_PER_POINT: dict[str, int] = {"las": 36, "laz": 12, "ply": 41, "e57": 40, "npy": 32}
# What such a point takes in a typical scan, for a dataset's size estimate: LAZ compresses the
# presets' scans at 10 deg/s to 4.4 (exp6) to 7.4 (exp1) bytes a point, sparser scans to about 9
# (docs/guide/datasets.md); the other formats store a fixed record.
LIKELY_BYTES_PER_POINT: dict[str, float] = BYTES_PER_POINT | {"laz": 6.0}
# A format's name in messages.
FORMAT_NAMES = {"las": "LAS", "laz": "LAZ", "ply": "PLY", "e57": "E57", "npy": "a NumPy folder", "text": "a text cloud",
                "s3dis": "an S3DIS room"}
# what an S3DIS room (read only, never copied) holds beyond its points' columns
_S3DIS_HELD = ("its per-object annotation files (Annotations/)",)
_WRITABLE = ", ".join(s for name in WRITABLE_FORMATS for s in CLOUD_FORMATS[name] if s) + \
    ", or a folder path without suffix (NumPy)"
_READABLE = ", ".join(s for suffixes in CLOUD_FORMATS.values() for s in suffixes if s) + \
    ", a NumPy folder (coord.npy) or an S3DIS room folder (Annotations/)"


def output_format(path: str | Path) -> str | None:
    """The ``WRITABLE_FORMATS`` name for an output path by its suffix ("npy" for a folder path:
    no suffix, or a trailing ``/``), None when no writer takes it."""
    text = str(path)
    suffix = "" if text.endswith("/") else Path(text).suffix.lower()
    return next((name for name in WRITABLE_FORMATS if suffix in CLOUD_FORMATS[name]), None)


def input_format(path: str | Path) -> str:
    """The ``CLOUD_FORMATS`` name of an existing cloud: folders by content (``coord.npy``: "npy",
    ``Annotations/<class>_<n>.txt``: "s3dis"), files by suffix; InputFileError otherwise."""
    path = check_input_path(path)
    if path.is_dir():
        if (path / "coord.npy").is_file():
            return "npy"
        if is_s3dis_room(path):
            return "s3dis"
        raise InputFileError(f"{path}: a folder that is neither a NumPy cloud (no coord.npy) nor an S3DIS room "
                             f"(no Annotations/<class>_<n>.txt); bimscan reads {_READABLE}")
    suffix = path.suffix.lower()
    name = next((n for n, suffixes in CLOUD_FORMATS.items() if suffix and suffix in suffixes), None)
    if name is None:
        raise InputFileError(f"{path}: unknown cloud format {path.suffix!r}; bimscan reads {_READABLE}")
    return name


def _writer_key(path: str | Path) -> str:
    name = output_format(path)
    if name is None:
        raise OutputError(f"{path}: unknown cloud format {Path(str(path)).suffix!r}; write {_WRITABLE}")
    return name


def open_cloud_writer(
    path: str | Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
    fields: tuple[ExtraField, ...] = (),
) -> CloudWriter:
    """A streamed writer for ``path``, its format chosen by suffix (see ``WRITERS``).

    Raises OutputError for an unknown suffix, a missing parent folder, or an existing output
    (file, folder, or PLY sidecar) without ``overwrite``. ``checksum`` makes ``close()`` report
    the SHA-256 of every file written (one extra read of the output, from the page cache).
    ``fields``: per-point fields of another format stored beside the columns (those the format's
    ``FIELD_CARRIERS`` entry carries), their values given with every chunk.
    """
    return WRITERS[_writer_key(path)](Path(path), header=header, overwrite=overwrite, checksum=checksum,
                                      fields=tuple(fields))


def check_cloud_output(path: str | Path, *, overwrite: bool = False, columns: tuple[str, ...] = ()) -> None:
    """Raise OutputError now for an output ``open_cloud_writer`` would refuse (unknown suffix, a path
    that names no output, missing folder, existing output, or with ``overwrite`` one bimscan may not
    replace), and for ``columns`` (``PointCloud.COLUMNS`` names) the format cannot hold, so a long job
    fails before it starts rather than at the end."""
    key = _writer_key(path)
    path = Path(path)
    check_output_path(path, overwrite=overwrite, extra=(sidecar_path(path),) if key == "ply" else (),
                      kind="npy" if key == "npy" else None)
    if key == "e57":
        check_e57_columns(path, columns)


def check_free_space(path: str | Path, *, points: int) -> None:
    """Raise OutputError when the folder of ``path`` has less free space than ``points`` points take
    in its format (``BYTES_PER_POINT``), so a long job fails before it starts rather than at the end."""
    key = _writer_key(path)
    needed = points * BYTES_PER_POINT[key]
    free = shutil.disk_usage(Path(path).parent).free
    if needed > free:
        raise OutputError(f"{path}: the scan may write up to {needed / 1e9:.1f} GB but {Path(path).parent} has "
                          f"{free / 1e9:.1f} GB free; free space or choose another output")


def read_cloud(path: str | Path, *, label_field: str | None = None, labels: bool = True) -> PointCloud:
    """Read a whole cloud (bimscan's own or another tool's, any of ``CLOUD_FORMATS``) as one ``PointCloud``.

    ``label_field`` names the field holding labels; None: bimscan files -> their labels,
    foreign files -> ``classification`` (LAS), a label-like property (PLY) or column (text) when
    present (E57: only a named ``label_field``); S3DIS rooms -> the index of the class in
    ``S3DIS_CLASSES`` (they take no ``label_field``). ``labels`` False: label None, the file's
    labels neither decoded nor checked. Columns a file lacks are None.
    """
    chunks = list(iter_cloud_chunks(path, chunk_points=1 << 62, label_field=label_field, labels=labels))
    if not chunks:  # text files with a header line only
        raise InputFileError(f"{path}: holds no points; pass a cloud with points")
    return chunks[0] if len(chunks) == 1 else PointCloud.concatenate(chunks)


def iter_cloud_chunks(
    path: str | Path, *, chunk_points: int = 2_000_000, label_field: str | None = None, labels: bool = True,
    station_field: str | None = None,
) -> Iterator[PointCloud]:
    """Stream a cloud as ``PointCloud`` chunks of at most ``chunk_points`` rows (see read_cloud).
    ``station_field``: a LAS/LAZ dimension holding each point's station (``point_source_id``)."""
    path = check_input_path(path)
    kind = input_format(path)
    extra = {}
    if station_field is not None:
        if kind not in ("las", "laz"):
            raise InputFileError(f"{path}: only LAS/LAZ files name a field for stations; pass the stations another way")
        extra["station_field"] = station_field
    chunks = CHUNK_READERS[kind](path, chunk_points=chunk_points, label_field=label_field, labels=labels, **extra)
    return _finite_points(chunks, path)


def iter_cloud_runs(path: str | Path, runs: Sequence[tuple[int, int]], *, labels: bool = False,
                    station_field: str | None = None) -> Iterator[tuple[int, PointCloud]]:
    """The points of each (first point, count) run of ``path``, in file order, as (first, chunk): a
    sparse look at a large cloud. LAS/LAZ seek to each run (a LAZ decompresses only the chunks the
    runs fall in); other formats are streamed once and cut. ``runs`` must be sorted and disjoint."""
    path = check_input_path(path)
    kind = input_format(path)
    ordered = list(runs)
    if any(b[0] < a[0] + a[1] for a, b in zip(ordered, ordered[1:])):
        raise ValueError("runs must be sorted and disjoint")
    if kind in ("las", "laz"):
        extra = {} if station_field is None else {"station_field": station_field}
        chunks = CHUNK_READERS[kind](path, chunk_points=1, labels=labels, runs=ordered, **extra)
        for (first, _), chunk in zip(ordered, _finite_points(chunks, path)):
            yield first, chunk
        return
    seen, index = 0, 0
    for chunk in iter_cloud_chunks(path, labels=labels, station_field=station_field):
        end = seen + len(chunk)
        while index < len(ordered) and ordered[index][0] < end:
            first, count = ordered[index]
            start, stop = max(first, seen), min(first + count, end)
            if stop > start:
                yield start, chunk.take(slice(start - seen, stop - seen))
            if first + count > end:  # the run goes on into the next chunk
                break
            index += 1
        seen = end
        if index == len(ordered):
            return


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
    """The number of points a cloud holds: what its header says (bodies shorter than that are refused);
    text clouds and S3DIS rooms, which have no header, by counting their data lines."""
    return POINT_COUNTERS[input_format(path)](path)


@dataclass(frozen=True)
class LabelledCopyPlan:
    """How ``write_labelled_copy`` will write a cloud with new labels, checked before any work.

    source_format / target_format: ``CLOUD_FORMATS`` names. copied: True when the input's own copier
    writes it (``LABELLED_COPIERS``: everything kept but what ``check`` names), False when the
    target format's writer does (the input's ``PointCloud`` columns and ``fields``, its per-point
    fields that format carries; ``check.lost`` names the rest). same_file: the output is the
    input (by any path spelling), replaced at the end.
    """

    source: Path
    target: Path
    source_format: str
    target_format: str
    copied: bool
    check: CopyCheck
    overwrite: bool
    same_file: bool
    fields: tuple[ExtraField, ...] = ()

    def notices(self) -> tuple[str, ...]:
        """One line per kind of thing the output does not keep as the input had it (none: all kept)."""
        lines = []
        if self.check.lost:
            lines.append(f"{self.target} will not hold what {FORMAT_NAMES[self.target_format]} has no place for: "
                         f"{'; '.join(self.check.lost)} of {self.source}")
        if self.check.changed:
            lines.append(f"{self.target}: {'; '.join(self.check.changed)}")
        return tuple(lines)


def labelled_output_format(path: str | Path) -> str | None:
    """The format a labelled copy writes at ``path``: a ``WRITABLE_FORMATS`` name, or "text" (which
    only a text input's copy writes), by suffix; None for an unknown suffix."""
    name = output_format(path)
    if name is None and Path(str(path)).suffix.lower() in TEXT_SUFFIXES:
        return "text"
    return name


def plan_labelled_copy(
    source: str | Path, target: str | Path, *, overwrite: bool = False, top_class: int = 0,
) -> LabelledCopyPlan:
    """Check, before any work, that ``source`` can be written to ``target`` with new class ids up
    to ``top_class``, and say what the output will not keep.

    An input whose format's copier (``LABELLED_COPIERS``) writes the target format is copied with
    everything it holds (a LAS with its header, VLRs, EVLRs and point records; another tool's PLY
    with every property and element; ...); any other pair goes through the target's writer, which
    carries the ``PointCloud`` columns. Raises OutputError for what ``open_cloud_writer`` would
    refuse, for a text output of a non-text input, and for an output that is the input itself (a
    link or another spelling included) unless the copy keeps all of it, naming what would be lost.
    """
    source = check_input_path(source)
    source_format = input_format(source)
    target = Path(target)
    target_format = labelled_output_format(target)
    if target_format is None:
        raise OutputError(f"{target}: unknown cloud format {target.suffix!r}; write {_WRITABLE}, or a text "
                          "cloud's own suffix for a text input")
    copier = LABELLED_COPIERS.get(source_format)
    copied = copier is not None and target_format in copier.targets
    if target_format == "text" and not copied:
        raise OutputError(f"{target}: bimscan writes text clouds only as labelled copies of text clouds; write "
                          f"{_WRITABLE}")
    fields: tuple[ExtraField, ...] = ()
    if copier is not None and copied:
        check = copier.check(source, target_format, top_class)
    elif copier is not None:  # through the target's writer: the columns, and the fields it carries
        fields, refused = FIELD_CARRIERS[target_format](copier.fields(source))
        lost = (("field " if len(refused) == 1 else "fields ") + ", ".join(refused),) if refused else ()
        check = CopyCheck(lost=lost + copier.held(source))
    else:
        check = CopyCheck(lost=_S3DIS_HELD)
    same = os.path.lexists(target) and _same_file(source, target)
    if same and not (copied and check.keeps_everything):
        what = "; ".join([*(f"lost: {item}" for item in check.lost), *check.changed])
        raise OutputError(f"{target} is the input {source} and its labelled copy would not keep all of it ({what}); "
                          "write the labelled cloud to another path")
    if copied:
        check_output_path(target, overwrite=overwrite, extra=(sidecar_path(target),) if target_format == "ply" else (),
                          kind="npy" if target_format == "npy" else None)
    else:
        with closing(iter_cloud_chunks(source, chunk_points=1, labels=False)) as chunks:
            first = next(chunks, None)  # the input's columns, from its first point
        check_cloud_output(target, overwrite=overwrite, columns=() if first is None else present_columns(first))
    return LabelledCopyPlan(source=source, target=target, source_format=source_format, target_format=target_format,
                            copied=copied, check=check, overwrite=overwrite, same_file=same, fields=fields)


def _same_file(first: Path, second: Path) -> bool:
    try:
        return os.path.samefile(first, second)
    except OSError:
        return False


def write_labelled_copy(
    plan: LabelledCopyPlan, labels: np.ndarray, *, header: CloudHeader, checksum: bool = True,
) -> WrittenCloud:
    """Write ``plan.source`` with ``labels`` (N,) uint8, one per point in the order
    ``iter_cloud_chunks`` gives them, to ``plan.target`` (see ``plan_labelled_copy``), streamed
    and staged under a temporary name renamed at the end, so an output that is the input is read
    whole before it is replaced. ``header``: the label scheme and metadata stored with it where
    the format has a place (LAS/LAZ EVLR, PLY sidecar, E57 extension, NumPy ``meta.json``; none in text).
    """
    if plan.copied:
        copier = LABELLED_COPIERS[plan.source_format]
        return copier.copy(plan.source, plan.target, labels, header=header, overwrite=plan.overwrite,
                           checksum=checksum)
    start = 0
    values = None
    if plan.fields:
        values = _Rows(LABELLED_COPIERS[plan.source_format].iter_fields(plan.source, plan.fields),
                       field_values_dtype(plan.fields))
    with open_cloud_writer(plan.target, header=header, overwrite=plan.overwrite, checksum=checksum,
                           fields=plan.fields) as writer:
        for chunk in iter_cloud_chunks(plan.source, labels=False):
            label = np.asarray(labels[start:start + len(chunk)], dtype=np.uint8)
            if len(label) != len(chunk):
                raise ValueError(f"{plan.source}: {len(labels)} labels for more points; pass one label per point")
            writer.write(replace(chunk, label=label), None if values is None else values.take(len(chunk)))
            start += len(chunk)
    if start != len(labels):
        raise ValueError(f"{plan.source}: {len(labels)} labels for {start} points; pass one label per point")
    return writer.close()


class _Rows:
    """Blocks of records from an iterator, handed out ``take(n)`` rows at a time (the fields of
    an input come in blocks of their own size; the writer takes them chunk by chunk of points)."""

    def __init__(self, blocks: Iterator[np.ndarray], dtype: np.dtype) -> None:
        self._blocks = blocks
        self._held: list[np.ndarray] = [np.empty(0, dtype=dtype)]
        self._count = 0

    def take(self, n: int) -> np.ndarray:
        while self._count < n:
            block = next(self._blocks, None)
            if block is None:
                raise ValueError(f"the input's fields end {n - self._count} points before its points")
            self._held.append(block)
            self._count += len(block)
        joined = self._held[0] if len(self._held) == 1 else np.concatenate(self._held)
        self._held, self._count = [joined[n:]], len(joined) - n
        return joined[:n]


def read_cloud_header(path: str | Path) -> CloudHeader | None:
    """The ``CloudHeader`` bimscan stored with a cloud, or None for a foreign file (text and S3DIS: always)."""
    return HEADER_READERS[input_format(path)](Path(path))


__all__ = [
    "BYTES_PER_POINT", "CHUNK_READERS", "CLOUD_FORMATS", "FIELD_CARRIERS", "HEADER_READERS", "LABELLED_COPIERS",
    "LIKELY_BYTES_PER_POINT", "POINT_COUNTERS", "WRITABLE_FORMATS", "WRITERS", "CloudWriter", "CopyCheck", "ExtraField",
    "LabelledCopier", "LabelledCopyPlan",
    "ObjExport", "WrittenCloud", "check_cloud_output", "check_free_space", "count_points", "export_obj", "input_format",
    "iter_cloud_chunks", "iter_cloud_runs", "labelled_output_format", "open_cloud_writer", "output_format", "plan_labelled_copy",
    "read_cloud", "read_cloud_header", "read_obj", "write_labelled_copy",
]

"""Stanford S3DIS rooms: ``<room>/Annotations/<class>_<n>.txt``, each line ``x y z r g b``.

Every annotation file is one object instance of one of 13 classes (ceiling floor wall beam
column window door table chair sofa bookcase board clutter). A room is read into one
:class:`~bimscan.types.PointCloud`: ``label`` is the index of the class in ``S3DIS_CLASSES``
(or in ``class_map`` when given), ``component`` is the index of the annotation file in sorted
order (the instance), xyz in metres, ``rgb`` the colour (when every file has its r g b columns).
Files are read in sorted name order so the same folder always gives the same point order.

Through :mod:`bimscan.io` a room is the cloud format ``s3dis`` (``read_cloud``,
``iter_cloud_chunks``, ``count_points`` take the room folder); labels are then the indices in
``S3DIS_CLASSES``.

A few releases of S3DIS hold files of class ``stairs``; following common practice (the
PointNet preparation scripts), they are read as ``clutter``. The v1.2 release holds a stray
byte (a NUL) in a few lines of Area_5 (PointNet's preparation script fixes Area_5/hallway_6 by
hand): such a line is read without the byte inside a number (``103.0\x000000``: 103.0) or with
it as a separator (``3.1\x00145``: 3.1 and 145), whichever gives the numbers the file's other
lines hold; a line that neither reads is skipped; both are reported (a warning naming the file,
the count and the first line).
"""

from __future__ import annotations

import io
import re
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError
from bimscan.types import PointCloud

S3DIS_CLASSES = (
    "ceiling", "floor", "wall", "beam", "column", "window", "door",
    "table", "chair", "sofa", "bookcase", "board", "clutter",
)
ALIASES = {"stairs": "clutter"}
_ANNOTATION = re.compile(r"^(?P<cls>[A-Za-z]+)_(?P<n>\d+)\.txt$")


def is_s3dis_room(path: str | Path) -> bool:
    """True when ``path`` is a folder holding ``Annotations/<class>_<n>.txt`` files."""
    annotations = Path(path) / "Annotations"
    return annotations.is_dir() and any(_ANNOTATION.match(p.name) for p in annotations.iterdir())


def list_s3dis_rooms(path: str | Path) -> list[Path]:
    """The room folders at ``path``: the room itself, or the rooms of an area or of the dataset root.

    Searches two levels down (``Area_1/office_1`` from the root), sorted by path.
    """
    path = Path(path)
    if is_s3dis_room(path):
        return [path]
    rooms = [p for p in sorted(path.glob("*")) if p.is_dir() and is_s3dis_room(p)]
    rooms += [p for p in sorted(path.glob("*/*")) if p.is_dir() and is_s3dis_room(p)]
    return sorted(rooms)


def class_of_annotation(path: Path) -> str:
    """The S3DIS class named by an annotation file name (``wall_3.txt`` -> ``wall``)."""
    match = _ANNOTATION.match(path.name)
    if match is None:
        raise InputFileError(f"{path}: not an S3DIS annotation name '<class>_<n>.txt'; rename or remove it")
    name = match.group("cls").lower()
    name = ALIASES.get(name, name)
    if name not in S3DIS_CLASSES:
        raise InputFileError(
            f"{path}: unknown S3DIS class {name!r}; expected one of {', '.join(S3DIS_CLASSES)}"
        )
    return name


def _annotation_files(path: Path) -> list[Path]:
    if not is_s3dis_room(path):
        raise InputFileError(
            f"{path}: not an S3DIS room (no Annotations/<class>_<n>.txt inside); pass a room folder"
        )
    return sorted(p for p in (path / "Annotations").iterdir() if p.suffix == ".txt")


def read_s3dis_room(path: str | Path, *, class_map: Mapping[str, int] | None = None, labels: bool = True) -> PointCloud:
    """Read one S3DIS room folder.

    ``class_map`` maps S3DIS class names to label ids (values 0..255; 255 is "unlabelled" by
    bimscan's convention); without it the label is the class's index in ``S3DIS_CLASSES``.
    Returns xyz (N, 3) float64 metres, label (N,) uint8, component (N,) int32 instance index,
    rgb (N, 3) uint8 (None when a file has no colour columns).
    ``labels`` False: the class names are not read (a room with classes of its own labels as
    well; prediction needs the points only) and ``label`` is None.
    """
    path = Path(path)
    files = _annotation_files(path)
    table = {name: i for i, name in enumerate(S3DIS_CLASSES)} if class_map is None else dict(class_map)
    parts: list[PointCloud] = []
    for instance, file in enumerate(files):
        label_id = 0
        if labels:
            name = class_of_annotation(file)
            if name not in table:
                raise InputFileError(
                    f"{file}: class {name!r} is missing from the class map; add it to the mapping file"
                )
            label_id = table[name]
            if not 0 <= label_id <= 255:
                raise InputFileError(f"class map sends {name!r} to {label_id}; label ids must be in 0..255")
        table_ = _read_annotation(file)
        if table_.size and table_.shape[1] < 3:
            raise InputFileError(f"{file}: {table_.shape[1]} column(s) per line; an S3DIS annotation holds x y z r g b")
        table_ = table_.reshape(-1, max(table_.shape[1], 3)) if table_.size else np.zeros((0, 6))
        rgb = np.clip(np.rint(table_[:, 3:6]), 0, 255).astype(np.uint8) if table_.shape[1] >= 6 else None
        parts.append(PointCloud(
            xyz=np.ascontiguousarray(table_[:, :3]),
            label=np.full(len(table_), label_id, dtype=np.uint8),
            component=np.full(len(table_), instance, dtype=np.int32),
            rgb=None if rgb is None else np.ascontiguousarray(rgb),
        ))
    if any(p.rgb is None for p in parts):  # a room is coloured whole or not at all
        parts = [replace(p, rgb=None) for p in parts]
    cloud = PointCloud.concatenate(parts)
    if len(cloud) == 0:
        raise InputFileError(f"{path}: the room's annotation files hold no points; check the download")
    return cloud if labels else replace(cloud, label=None)


_STRAY = re.compile(rb"[^0-9eE+.\-\s]")  # a byte no number or separator holds
# a file with more damaged lines than this share (and more than 10) is not a slip in a release
# but a broken file
MAX_DAMAGED_SHARE = 0.001


def _read_annotation(file: Path) -> np.ndarray:
    """The (N, C) numbers of one annotation file. A line with stray bytes is read without them,
    or with them as separators, when it then holds as many numbers as the file's other lines,
    else skipped; both are reported (a warning). InputFileError when more than
    ``MAX_DAMAGED_SHARE`` of its point lines (and more than 10) are damaged, or a line is
    unreadable without stray bytes (a truncated file)."""
    try:
        return np.loadtxt(file, dtype=np.float64, ndmin=2)
    except ValueError:
        pass  # repaired below, or refused with the reader's own words
    lines = file.read_bytes().split(b"\n")
    width = next((len(line.split()) for line in lines if line.strip() and _STRAY.search(line) is None), 0)
    repaired: list[tuple[int, str]] = []
    skipped: list[tuple[int, str]] = []
    for index, line in enumerate(lines):
        if _STRAY.search(line) is None:
            continue
        mended = next((fields for fields in (_STRAY.sub(b"", line).split(), _STRAY.sub(b" ", line).split())
                       if _numbers(fields) == width), None)
        (repaired if mended else skipped).append((index + 1, line.strip().decode("latin-1")))
        lines[index] = b" ".join(mended) if mended else b""
    damaged = repaired + skipped
    point_lines = sum(1 for line in lines if line.strip()) + len(skipped)  # (skipped lines are blank now)
    if len(damaged) > max(10, MAX_DAMAGED_SHARE * point_lines):
        number, line = min(damaged)
        raise InputFileError(f"{file}: {len(damaged):,} of {point_lines:,} lines hold stray bytes (line {number}: "
                             f"{line!r}); the file is damaged: download it again")
    try:
        table = np.loadtxt(io.BytesIO(b"\n".join(lines)), dtype=np.float64, ndmin=2)
    except ValueError as exc:
        reason = str(exc).split(";")[0].rstrip(".")  # NumPy's words, less its advice on its own API
        raise InputFileError(f"{file}: unreadable point line ({reason}); fix or remove that line") from exc
    parts = []
    if repaired:
        parts.append(f"{len(repaired)} line(s) read without their stray bytes (line {repaired[0][0]}: "
                     f"{repaired[0][1]!r})")
    if skipped:
        parts.append(f"{len(skipped)} unreadable line(s) skipped (line {skipped[0][0]}: {skipped[0][1]!r})")
    warnings.warn(f"{file}: " + "; ".join(parts), stacklevel=3)
    return table


def _numbers(fields: list[bytes]) -> int:
    """How many numbers ``fields`` are (-1: one of them is not a number)."""
    try:
        return len([float(field) for field in fields])
    except ValueError:
        return -1


def iter_s3dis_chunks(
    path: str | Path, *, chunk_points: int = 2_000_000, label_field: str | None = None, labels: bool = True,
) -> Iterator[PointCloud]:
    """Stream an S3DIS room as ``PointCloud`` chunks of at most ``chunk_points`` rows, in the order
    of :func:`read_s3dis_room` (label: the class index in ``S3DIS_CLASSES``; ``labels`` False:
    None). A room has no fields, so a ``label_field`` is refused. Rooms are small (about a million
    points): the room is read whole, then cut.
    """
    if label_field is not None:
        raise InputFileError(f"{path}: an S3DIS room takes no label field ({label_field!r}): its labels are "
                             "the annotation file names; drop the label field")
    if chunk_points < 1:
        raise ValueError(f"chunk_points must be positive, got {chunk_points}")
    room = read_s3dis_room(path, labels=labels)
    for start in range(0, len(room), chunk_points):
        yield room.take(slice(start, start + chunk_points))


def count_s3dis_points(path: str | Path) -> int:
    """The number of points of an S3DIS room: the data lines of its annotation files (counted, not
    parsed)."""
    count = 0
    for file in _annotation_files(Path(path)):
        with file.open("rb") as handle:
            count += sum(1 for line in handle if line.strip() and not line.lstrip().startswith(b"#"))
    return count

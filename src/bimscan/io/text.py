"""Plain-text point clouds: one point per line, ``x y z [r g b] [label]``.

This is the lowest common denominator of real scans exchanged between tools (CloudCompare
"ASCII cloud", S3DIS-style files, ``.xyz``/``.pts`` exports). Columns are separated by
whitespace or commas; ``#`` and ``//`` start comment lines. The column meaning comes from a
header line of names when there is one (``x,y,z,red,green,blue,classification``; ``label``,
``class``, ``classification``, ``scalar_label`` and ``scalar_classification`` name the label,
or the name given as ``label_field``), else from the count on the first data line:

==========  ==========================  ==============================
columns     meaning                     in Leica ``.pts`` files
==========  ==========================  ==============================
3           x y z                       x y z
4           x y z label                 x y z intensity
6           x y z r g b                 x y z r g b
7           x y z r g b label           x y z intensity r g b
==========  ==========================  ==============================

Read them through :mod:`bimscan.io` (format ``text``, suffixes ``TEXT_SUFFIXES``):
``read_cloud``, ``iter_cloud_chunks``, ``count_points``. A first line holding one integer (the
point count of ``.pts`` files) is skipped. Colours become ``rgb`` (0..255 per channel; a header
names them ``r g b`` or ``red green blue``); intensities are read past (``.pts`` intensities,
-2048..2047, are no LAS intensity). Labels must be integers in 0..255 (uint8, as everywhere in
bimscan).
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

import numpy as np

from bimscan.errors import InputFileError
from bimscan.files import atomic_output, check_input_file
from bimscan.io._labelled import LABEL_NAME, CopyCheck, ExtraField, check_label_count, field_values_dtype
from bimscan.io._writer import StagedOutput, WrittenCloud, check_output_path
from bimscan.types import PointCloud

TEXT_SUFFIXES = (".txt", ".xyz", ".pts", ".csv", ".asc")
LABEL_NAMES = ("label", "labels", "class", "classification", "scalar_label", "scalar_classification")
# label column by column count, for files without a header line
LABEL_COLUMN = {3: None, 4: 3, 6: None, 7: 6}
PTS_LABEL_COLUMN = {3: None, 4: None, 6: None, 7: None}  # Leica: intensity, not a label
RGB_COLUMNS = {6: (3, 4, 5), 7: (3, 4, 5)}  # first colour column by column count, without a header
PTS_RGB_COLUMNS = {6: (3, 4, 5), 7: (4, 5, 6)}  # Leica: x y z intensity r g b
RGB_NAMES = (("r", "g", "b"), ("red", "green", "blue"))
_COMMENT = ("#", "//")
_COMMENT_BYTES = tuple(c.encode() for c in _COMMENT)
_SPLIT = re.compile(r"[,\s]+")


@dataclass(frozen=True)
class _Layout:
    delimiter: str | None  # None: any whitespace
    xyz: tuple[int, int, int]
    label: int | None
    columns: int
    data_start: int  # number of lines before the first data line
    rgb: tuple[int, int, int] | None = None
    names: tuple[str, ...] = ()  # the header line's column names as written; () without one


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _detect_layout(path: Path, handle: TextIO, *, label_field: str | None = None, labels: bool = True) -> _Layout:
    consumed = 0
    for line in handle:
        consumed += 1
        stripped = line.strip()
        if not stripped or stripped.startswith(_COMMENT):
            continue
        delimiter = "," if "," in stripped else None
        tokens = [t for t in _SPLIT.split(stripped) if t]
        if len(tokens) == 1 and tokens[0].isdigit():
            continue  # the point count line of .pts files
        if not all(_is_number(t) for t in tokens):
            names = [t.lower() for t in tokens]
            missing = [axis for axis in ("x", "y", "z") if axis not in names]
            if missing:
                raise InputFileError(
                    f"{path}: header line {consumed} {stripped!r} names no column {missing[0]!r}; "
                    "name the coordinate columns x, y, z or drop the header"
                )
            if label_field is not None and label_field.lower() not in names:
                raise InputFileError(
                    f"{path}: no column {label_field!r} to read labels from; the header names {', '.join(tokens)}"
                )
            wanted = (label_field.lower(),) if label_field is not None else LABEL_NAMES
            label = next((names.index(n) for n in wanted if n in names), None)
            xyz = (names.index("x"), names.index("y"), names.index("z"))
            rgb = next((tuple(names.index(n) for n in trio) for trio in RGB_NAMES if all(n in names for n in trio)),
                       None)
            return _Layout(delimiter, xyz, label if labels else None, len(names), consumed, rgb,  # type: ignore[arg-type]
                           tuple(tokens))
        if label_field is not None:
            raise InputFileError(
                f"{path}: no header line naming its columns, so label field {label_field!r} cannot apply; "
                "add a header line (e.g. 'x y z r g b label') or drop --label-field"
            )
        layouts = PTS_LABEL_COLUMN if path.suffix.lower() == ".pts" else LABEL_COLUMN
        if len(tokens) not in layouts:
            raise InputFileError(
                f"{path}: line {consumed} has {len(tokens)} columns; expected 3 (x y z), "
                "4 (x y z label), 6 (x y z r g b) or 7 (x y z r g b label), or a header line naming them"
            )
        label = layouts[len(tokens)] if labels else None
        colours = PTS_RGB_COLUMNS if path.suffix.lower() == ".pts" else RGB_COLUMNS
        return _Layout(delimiter, (0, 1, 2), label, len(tokens), consumed - 1, colours.get(len(tokens)))
    raise InputFileError(f"{path}: holds no points; pass a text file with one 'x y z [r g b] [label]' per line")


def _parse_lines(path: Path, lines: list[str], layout: _Layout, first_line: int) -> PointCloud:
    table = _parse_table(path, lines, layout, first_line)
    if table.shape[0] == 0:
        return PointCloud(xyz=np.empty((0, 3)), label=None if layout.label is None else np.empty(0, np.uint8))
    xyz = np.ascontiguousarray(table[:, list(layout.xyz)])
    label = None
    if layout.label is not None:
        raw = table[:, layout.label]
        bad = (raw != np.round(raw)) | (raw < 0) | (raw > 255) | ~np.isfinite(raw)
        if bad.any():
            row = int(np.argmax(bad))
            raise InputFileError(
                f"{path}: label {float(raw[row])!r} near line {first_line + row} is not an integer "
                "in 0..255; labels must be class ids 0..255"
            )
        label = raw.astype(np.uint8)
    rgb = None
    if layout.rgb is not None:
        rgb = np.ascontiguousarray(np.clip(np.rint(np.nan_to_num(table[:, list(layout.rgb)])), 0, 255).astype(np.uint8))
    return PointCloud(xyz=xyz, label=label, rgb=rgb)


def _parse_table(path: Path, lines: list[str], layout: _Layout, first_line: int) -> np.ndarray:
    """The point lines ``lines`` (from line ``first_line``) as an (M, columns) float64 table."""
    try:
        table = np.loadtxt(
            lines, dtype=np.float64, delimiter=layout.delimiter, comments=_COMMENT, ndmin=2,
        )
    except ValueError as exc:
        # numpy counts rows from 0 within this chunk; report the line in the file
        row = re.search(r"row (\d+)", str(exc))
        where = first_line + (int(row.group(1)) if row else 0)
        raise InputFileError(
            f"{path}: unreadable point line near line {where} ({str(exc).rstrip('.')}); fix or remove it"
        ) from exc
    if table.shape[0] and table.shape[1] != layout.columns:
        raise InputFileError(
            f"{path}: lines from {first_line} have {table.shape[1]} columns, the first data line had "
            f"{layout.columns}; every line needs the same columns"
        )
    return table


def iter_text_chunks(
    path: str | Path, *, chunk_points: int = 1_000_000, label_field: str | None = None, labels: bool = True,
) -> Iterator[PointCloud]:
    """Stream a text cloud as :class:`PointCloud` chunks of at most ``chunk_points`` points.

    xyz (N, 3) float64 in the file's units (metres expected); label (N,) uint8 when the file has
    a label column, else None. ``label_field`` names the label column of a file with a header
    line (InputFileError for a file without one). ``labels`` False skips the label column
    (label None, its values unchecked), for callers that do not use labels. Memory stays
    bounded by the chunk size.
    """
    path = Path(path)
    if chunk_points < 1:
        raise ValueError(f"chunk_points must be at least 1, got {chunk_points}")
    if not path.is_file():
        raise InputFileError(f"{path}: no such file; check the path")
    with path.open("r", encoding="utf-8", errors="strict") as handle:
        try:
            layout = _detect_layout(path, handle, label_field=label_field, labels=labels)
        except UnicodeDecodeError as exc:
            raise InputFileError(f"{path}: not a text file ({exc.reason}); pass 'x y z [label]' text") from exc
    with path.open("r", encoding="utf-8") as handle:
        lines_iter = itertools.islice(handle, layout.data_start, None)
        line_number = layout.data_start + 1
        while True:
            try:
                lines = list(itertools.islice(lines_iter, chunk_points))
            except UnicodeDecodeError as exc:
                raise InputFileError(f"{path}: not UTF-8 text after line {line_number}; fix the file") from exc
            if not lines:
                return
            chunk = _parse_lines(path, lines, layout, line_number)
            line_number += len(lines)
            if len(chunk):
                yield chunk


def count_text_points(path: str | Path) -> int:
    """The number of data lines of a text cloud (comment and blank lines not counted); the lines
    are counted, not parsed, so a damaged line shows only on reading."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such file; check the path")
    with path.open("r", encoding="utf-8", errors="strict") as handle:
        try:
            layout = _detect_layout(path, handle)
        except UnicodeDecodeError as exc:
            raise InputFileError(f"{path}: not a text file ({exc.reason}); pass 'x y z [label]' text") from exc
    count = 0
    with path.open("rb") as handle:
        for line in itertools.islice(handle, layout.data_start, None):
            stripped = line.strip()
            if stripped and not stripped.startswith(_COMMENT_BYTES):
                count += 1
    return count


def write_text_cloud(path: str | Path, cloud: PointCloud, *, overwrite: bool = False) -> Path:
    """Write ``x y z [r g b] [label]`` lines (colour and labels when the cloud has them); atomic,
    deterministic bytes.

    Coordinates are written with 6 decimals (micrometres for metre units), so a round trip
    keeps xyz within 5e-7 m and the labels exactly.
    """
    path = Path(path)
    check_output_path(path, overwrite=overwrite)
    with atomic_output(path) as temp, temp.open("w", encoding="utf-8", newline="\n") as out:
        out.write("# x y z" + (" r g b" if cloud.rgb is not None else "")
                  + (" label\n" if cloud.label is not None else "\n"))
        step = 500_000  # bounded formatting memory for big clouds
        fmt = "%.6f %.6f %.6f" + (" %d %d %d" if cloud.rgb is not None else "") + (" %d" if cloud.label is not None else "")
        for start in range(0, len(cloud), step):
            columns = [cloud.xyz[start:start + step]]
            if cloud.rgb is not None:
                columns.append(cloud.rgb[start:start + step].astype(np.float64))
            if cloud.label is not None:
                columns.append(cloud.label[start:start + step].astype(np.float64)[:, None])
            np.savetxt(out, np.hstack(columns), fmt=fmt)
    return path


# -- labelled copies ------------------------------------------------------------------------------
#
# A labelled copy keeps a text cloud as it was, line for line: comment and blank lines, a header
# line, a .pts count line, every column of every point line as it was written. The class goes to
# the label column the reader finds (``LABEL_NAMES`` in a header line, the 4th of 4 or 7th of 7
# columns without one), or to a column appended to every point line (named ``label`` in the
# header line, if any). Leica .pts files without a header line read 4 and 7 columns as intensity:
# a header line naming the columns is added before their first point line, so the labels read back.

_TOKEN = re.compile(rb"[^,\s]+")
PTS_NAMES = {3: "x y z", 4: "x y z intensity", 6: "x y z r g b", 7: "x y z intensity r g b"}
COPY_BLOCK_LINES = 1 << 18  # point lines a labelled copy holds at a time


def _copy_layout(path: Path) -> _Layout:
    with path.open("r", encoding="utf-8", errors="strict") as handle:
        try:
            return _detect_layout(path, handle)
        except UnicodeDecodeError as exc:
            raise InputFileError(f"{path}: not a text file ({exc.reason}); pass 'x y z [label]' text") from exc


def _adds_names(path: Path, layout: _Layout) -> bool:
    """Whether a labelled copy adds a header line: a .pts file without one, which reads the
    columns after x y z as intensity and colour, never as labels."""
    return not layout.names and layout.label is None and path.suffix.lower() == ".pts"


def check_text_copy(path: Path, target_format: str, top_class: int) -> CopyCheck:
    """What a labelled copy of the text cloud ``path`` does not keep as it was: a header line added
    to a .pts file that has none."""
    layout = _copy_layout(check_input_file(path, what="a text cloud"))
    if _adds_names(path, layout):
        return CopyCheck(changed=(f"a header line '{PTS_NAMES[layout.columns]} label' is added before the first point "
                                  "(a .pts file's columns after x y z are intensity and colour, never labels)",))
    return CopyCheck()


def _field_columns(path: Path, layout: _Layout) -> list[tuple[ExtraField, int]]:
    """(field, column index) of every column the reader does not take (x y z, colour, label), named
    as the header line names it, else as a .pts file's columns are (intensity), else column_<n>."""
    taken = {*layout.xyz, *(layout.rgb or ()), *(() if layout.label is None else (layout.label,))}
    named = layout.names or (tuple(PTS_NAMES[layout.columns].split()) if path.suffix.lower() == ".pts" else ())
    fields, used = [], set()
    for index in range(layout.columns):
        if index in taken:
            continue
        name = named[index] if named else f"column_{index + 1}"
        while name.lower() in used:  # two columns of one name: the later one numbered
            name = f"{name}_{index + 1}"
        used.add(name.lower())
        fields.append((ExtraField(name, "<f8"), index))
    return fields


def text_fields(path: Path) -> tuple[ExtraField, ...]:
    """The columns of the text cloud ``path`` the reader does not take, as float64 fields."""
    path = check_input_file(path, what="a text cloud")
    return tuple(field for field, _ in _field_columns(path, _copy_layout(path)))


def iter_text_fields(path: Path, fields: tuple[ExtraField, ...]) -> Iterator[np.ndarray]:
    """The values of ``fields`` (of ``text_fields``) of every point line, blocks of records."""
    path = check_input_file(path, what="a text cloud")
    layout = _copy_layout(path)
    columns = {field.name: index for field, index in _field_columns(path, layout)}
    with path.open("r", encoding="utf-8") as handle:
        lines_iter = itertools.islice(handle, layout.data_start, None)
        line_number = layout.data_start + 1
        while lines := list(itertools.islice(lines_iter, COPY_BLOCK_LINES)):
            table = _parse_table(path, lines, layout, line_number)
            line_number += len(lines)
            values = np.empty(len(table), dtype=field_values_dtype(fields))
            for field in fields:
                values[field.name] = table[:, columns[field.name]] if len(table) else []
            yield values


def text_held(path: Path) -> tuple[str, ...]:
    """A text cloud holds nothing beyond its columns (the ``text_fields`` and the ones read)."""
    return ()


def copy_text_labelled(
    source: Path, target: Path, labels: np.ndarray, *, header: object = None, overwrite: bool = False,
    checksum: bool = True,
) -> WrittenCloud:
    """Copy the text cloud ``source`` to ``target`` with ``labels`` (N,) uint8 in its label column
    (see the section comment); registered as ``LABELLED_COPIERS["text"]``. Plain text stores no
    header: ``header`` (the class names) is not written."""
    source = check_input_file(source, what="a text cloud")
    layout = _copy_layout(source)
    delimiter = b"," if layout.delimiter == "," else b" "
    add_names = _adds_names(source, layout)
    done = 0
    with StagedOutput(target, overwrite=overwrite, checksum=checksum) as staged, source.open("rb") as handle:
        out = staged.open(staged.file(target))
        for number in range(layout.data_start):
            line = handle.readline()
            if layout.names and layout.label is None and number == layout.data_start - 1:
                body = line.rstrip(b"\r\n")  # the header line: name the new column
                line = body + delimiter + LABEL_NAME.encode("ascii") + line[len(body):]
            out.write(line)
        while True:
            lines = list(itertools.islice(handle, COPY_BLOCK_LINES))
            if not lines:
                break
            parts = []
            for line in lines:
                stripped = line.strip()
                if not stripped or stripped.startswith(_COMMENT_BYTES):
                    parts.append(line)
                    continue
                if done >= len(labels):
                    raise ValueError(f"{source}: more point lines than the {len(labels)} labels; pass one label per point")
                if add_names and done == 0:
                    names = f"{PTS_NAMES[layout.columns]} {LABEL_NAME}".encode("ascii")
                    parts.append(names + (b"\r\n" if line.endswith(b"\r\n") else b"\n"))
                labelled = _labelled_line(line, int(labels[done]), layout.label, delimiter)
                if labelled is None:
                    shown = line.strip()[:80].decode("utf-8", "replace")
                    raise InputFileError(f"{source}: point line {done + 1:,} {shown!r} has fewer columns than "
                                         "the first; fix or remove it")
                parts.append(labelled)
                done += 1
            out.write(b"".join(parts))
        check_label_count(labels, done, source)
        return staged.commit(n_points=done)


def _labelled_line(line: bytes, label: int, index: int | None, delimiter: bytes) -> bytes | None:
    """A point line with its token ``index`` replaced by ``label`` (None: ``label`` appended after
    its last value, before a trailing comment); everything else as it was. None when the line has
    no token ``index``."""
    body = line.rstrip(b"\r\n")
    end = len(body)
    for marker in _COMMENT_BYTES:  # an inline comment, which the reader drops
        found = body.find(marker)
        if found >= 0:
            end = min(end, found)
    text = str(label).encode("ascii")
    if index is None:
        values = body[:end].rstrip()
        return values + delimiter + text + body[len(values):] + line[len(body):]
    token = next((m for i, m in enumerate(_TOKEN.finditer(body, 0, end)) if i == index), None)
    if token is None:
        return None
    return body[: token.start()] + text + body[token.end():] + line[len(body):]

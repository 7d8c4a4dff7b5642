"""What the labelled copies of every format share (``bimscan.io.write_labelled_copy``).

A labelled copy is a cloud's own file with one field changed: the class of every point. Each
input format has a ``LabelledCopier``, registered in ``bimscan.io.LABELLED_COPIERS`` under the
format's name: the output formats it copies into keeping everything the input holds, a check
that says before any work what it cannot keep, and the copy itself, streamed and staged under a
temporary name like every writer.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from bimscan.io._writer import WrittenCloud

LABEL_NAME = "label"  # the label field a copy adds where its input has none (PLY property, text column)


@dataclass(frozen=True)
class CopyCheck:
    """What a labelled copy will not keep of its input, in words, known before any work.

    lost: what the output has no place for ("the CRS (WKT VLR)", "extra dimension 'gt'"); changed:
    what it keeps in another form ("point format 3 becomes 7"). Both empty: the output holds
    everything the input held, and only the labels differ.
    """

    lost: tuple[str, ...] = ()
    changed: tuple[str, ...] = ()

    @property
    def keeps_everything(self) -> bool:
        return not self.lost and not self.changed

    def __add__(self, other: CopyCheck) -> CopyCheck:
        return CopyCheck(lost=self.lost + other.lost, changed=self.changed + other.changed)


@dataclass(frozen=True)
class ExtraField:
    """A per-point field of a cloud beyond ``PointCloud``'s columns (a LAS extra dimension, a PLY
    property such as ``nx``, a text column, a NumPy array), which a writer of another format can
    carry beside the columns. name: as the input names it; dtype: NumPy dtype of its values
    (little-endian); description: a line for formats that keep one (LAS extra bytes)."""

    name: str
    dtype: str
    description: str = ""


def field_values_dtype(fields: tuple[ExtraField, ...]) -> np.dtype:
    """The structured dtype of a block of ``fields`` values (one record per point)."""
    return np.dtype([(f.name, f.dtype) for f in fields])


# copy(source, target, labels, *, header, overwrite, checksum) -> WrittenCloud
CopyFunction = Callable[..., "WrittenCloud"]


@dataclass(frozen=True)
class LabelledCopier:
    """How clouds of one format are copied with new labels.

    targets: the output formats (``bimscan.io.CLOUD_FORMATS`` names) written by ``copy``, which
    keeps everything ``check`` does not name. check(source, target format, highest class id):
    what the copy cannot keep. copy(source, target, labels, *, header, overwrite, checksum): the
    copy, ``labels`` (N,) uint8 in the order the format's chunk reader gives the points.
    held(source): what the file holds beyond the columns of a ``PointCloud`` and its ``fields``,
    in words (a CRS, other elements, ...), which a copy into another format does not carry.
    fields(source): its per-point fields beyond the columns; iter_fields(source, fields): their
    values, blocks of records (``field_values_dtype``) in the order the chunk reader gives the points.
    """

    targets: tuple[str, ...]
    check: Callable[[Path, str, int], CopyCheck]
    copy: CopyFunction
    held: Callable[[Path], tuple[str, ...]]
    fields: Callable[[Path], tuple[ExtraField, ...]]
    iter_fields: Callable[[Path, tuple[ExtraField, ...]], Iterator[np.ndarray]]


def check_label_count(labels: np.ndarray, n_points: int, where: Path) -> None:
    """ValueError (a caller's mistake, not the user's) unless ``labels`` has one class per point."""
    if labels.ndim != 1 or len(labels) != n_points:
        raise ValueError(f"{where}: {len(labels)} labels for {n_points} points; pass one label per point")


__all__ = ["LABEL_NAME", "CopyCheck", "ExtraField", "LabelledCopier", "check_label_count", "field_values_dtype"]

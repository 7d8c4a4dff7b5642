"""Blocks: the network's input units (Table 2: N points, bounding-box centring, scale normalisation).

Why vertical columns over the full height: in a building the classes differ mostly by their
vertical context (the floor slab below, the ceiling covering and the beams above, walls and
columns joining them), and a TLS scan is levelled (Z up) in synthetic and real data alike. A
column keeps that context whole; horizontal tiling keeps blocks small enough that 8192 points
still resolve components (a 4 m x 4 m column of a 3 m storey holds about 60 m2 of surface:
8192 points sample it every 8-9 cm). Columns are anchored at multiples of the column size in
absolute coordinates, so no pass over the data is needed to place them.

Normalisation: centre on the block's bounding-box centre and divide by the largest half
extent, so coordinates lie in [-1, 1] and shapes keep their aspect ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bimscan.learn.train_config import IGNORE_LABEL

_KEY_OFFSET = 1 << 31


def locate_columns(xy: np.ndarray, *, size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Integer column indices (ix, iy), each (N,) int64, of (N, 2) float64 x/y in metres."""
    cells = np.floor(np.asarray(xy, dtype=np.float64) / size_m).astype(np.int64)
    return cells[:, 0], cells[:, 1]


def encode_column_key(ix: np.ndarray, iy: np.ndarray) -> np.ndarray:
    """One sortable int64 key per (ix, iy) pair; valid for |ix|, |iy| < 2**30."""
    return ix * (1 << 32) + (iy + _KEY_OFFSET)


def decode_column_key(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`encode_column_key`."""
    iy = key % (1 << 32) - _KEY_OFFSET
    ix = (key - (iy + _KEY_OFFSET)) // (1 << 32)
    return ix, iy


def normalize_block(xyz: np.ndarray, *, lower: np.ndarray | None = None, upper: np.ndarray | None = None) -> np.ndarray:
    """Centre (N, 3) coordinates on a bounding box and scale by its largest half extent.

    ``lower``/``upper`` (3,) give the box (the whole block's, when ``xyz`` is a sample of it);
    by default the points' own bounds. Returns (N, 3) float32 in [-1, 1] for points in the box.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if lower is None or upper is None:
        lower, upper = xyz.min(axis=0), xyz.max(axis=0)
    centre = (np.asarray(lower) + np.asarray(upper)) / 2.0
    half = float(np.max((np.asarray(upper) - np.asarray(lower)) / 2.0))
    scale = half if half > 0 else 1.0  # a single point or a degenerate block: only centre it
    return ((xyz - centre) / scale).astype(np.float32)


@dataclass(frozen=True)
class Block:
    """One network input: xyz (N, D) float32, the normalised coordinates then any extra
    channels (:mod:`bimscan.learn.features`), label (N,) int64 (255 = ignore,
    padding included), mask (N,) bool (False = padding), index (N,) int64 into the points the
    block was drawn from (-1 = padding)."""

    xyz: np.ndarray
    label: np.ndarray
    mask: np.ndarray
    index: np.ndarray


def pad_block(
    xyz: np.ndarray, label: np.ndarray | None, index: np.ndarray, *, points: int,
    lower: np.ndarray | None = None, upper: np.ndarray | None = None, extra: np.ndarray | None = None,
) -> Block:
    """Normalise up to ``points`` selected points and zero-pad to exactly ``points`` rows.

    ``xyz`` (M, 3) float64 and ``label`` (M,) uint8 are the selected points, ``index`` (M,) their
    indices in the source; M <= points. ``extra`` (M, E): more input channels, appended as they are.
    """
    m = len(xyz)
    if m > points:
        raise ValueError(f"{m} points do not fit a block of {points}")
    channels = 3 + (0 if extra is None else extra.shape[1])
    out_xyz = np.zeros((points, channels), dtype=np.float32)
    out_label = np.full(points, IGNORE_LABEL, dtype=np.int64)
    mask = np.zeros(points, dtype=bool)
    out_index = np.full(points, -1, dtype=np.int64)
    if m:
        out_xyz[:m, :3] = normalize_block(xyz, lower=lower, upper=upper)
        if extra is not None:
            out_xyz[:m, 3:] = extra
        if label is not None:
            out_label[:m] = label
        mask[:m] = True
        out_index[:m] = index
    return Block(out_xyz, out_label, mask, out_index)


def sample_block(
    xyz: np.ndarray, label: np.ndarray | None, *, points: int, rng: np.random.Generator,
) -> Block:
    """Table 2's block sampling: ``points`` drawn without replacement when the block has more,
    all of them plus zero padding when fewer; normalised on the bounding box of all M points.

    ``xyz`` (M, 3) float, ``label`` (M,) uint8 or None (then every label is 255).
    """
    m = len(xyz)
    lower, upper = np.min(xyz, axis=0), np.max(xyz, axis=0)
    index = np.sort(rng.choice(m, size=points, replace=False)) if m > points else np.arange(m)
    return pad_block(
        xyz[index], None if label is None else label[index], index, points=points, lower=lower, upper=upper,
    )


def plan_passes(m: int, *, points: int, rng: np.random.Generator, max_passes: int = 0) -> list[np.ndarray]:
    """Split a block of ``m`` points into groups of ``points`` that see every point once.

    The points are shuffled and cut into ceil(m / points) groups; the last group is topped up
    with random points from the other groups, so every group is a uniform random sample of
    the block of the same size as in training (no padding unless m < points). With
    ``max_passes`` > 0 at most that many groups are returned (points left out get their labels
    from their nearest labelled neighbour). Returns a list of (points,) or (m,) int64 arrays.
    """
    if m <= points:
        return [np.arange(m, dtype=np.int64)]
    order = rng.permutation(m)
    passes = math.ceil(m / points)
    if max_passes > 0:
        passes = min(passes, max_passes)
    groups = [order[i * points:(i + 1) * points] for i in range(passes)]
    short = points - len(groups[-1])
    if short > 0:
        # top up from the points of the earlier groups (never repeats a point in this group)
        extra = rng.choice((passes - 1) * points, size=short, replace=False)
        groups[-1] = np.concatenate([groups[-1], order[extra]])
    return groups

"""Streaming subsampling: a voxel grid (dataset units) and a uniform random sample (display).

``VoxelSubsampler`` keeps the first point, in stream order, of every occupied voxel of an
axis-aligned grid anchored at a fixed origin. Deciding needs only the set of voxels seen so far,
never the points: memory grows with the *output* (8 bytes per kept point, in sorted runs), not
with the input, and the result depends only on the stream's order, not on how it was chunked.
Scans stream station by station, so where stations overlap the earlier station's point wins.

``UniformSampler`` keeps a uniform random sample of at most ``k`` points of a stream of unknown
length (the ``k`` smallest of one seeded random key per point), in O(k) memory.
"""

from __future__ import annotations

import numpy as np

from bimscan.constraints import Range, range_problem
from bimscan.errors import ConfigError
from bimscan.types import PointCloud

VOXEL_SIZE_M = Range(0.0, None, low_open=True)  # what a voxel's edge can be (a dataset spec's voxel_size_m too)
VOXEL_SIZE_HINT = "metres, a voxel's edge"
_BITS = 21  # bits per axis in a voxel key: 2,097,152 voxels along each axis
_SPAN = 1 << _BITS


class _SortedKeySet:
    """A growing set of int64 keys as a few sorted runs (a log-structured merge).

    Runs are kept with strictly decreasing sizes by merging a new run into its smaller
    neighbours, so there are O(log n) runs and every key is copied O(log n) times in total.
    """

    def __init__(self) -> None:
        self.runs: list[np.ndarray] = []

    def __len__(self) -> int:
        return sum(len(r) for r in self.runs)

    def contains(self, keys: np.ndarray) -> np.ndarray:
        """Boolean (n,) membership of sorted ``keys``."""
        found = np.zeros(len(keys), dtype=bool)
        for run in self.runs:
            pos = np.searchsorted(run, keys)
            inside = pos < len(run)
            found[inside] |= run[pos[inside]] == keys[inside]
        return found

    def add(self, keys: np.ndarray) -> None:
        """Add sorted keys that are not in the set yet."""
        if len(keys) == 0:
            return
        run = keys
        while self.runs and len(self.runs[-1]) <= 2 * len(run):
            run = np.sort(np.concatenate([self.runs.pop(), run]), kind="stable")
        self.runs.append(run)


class VoxelSubsampler:
    """Keep the first point of every voxel of edge ``voxel_size_m`` over a stream of chunks.

    origin: (3,) metres, the grid's corner (use the model's lower corner, e.g. ``cloud_origin``),
    so the same points give the same voxels in every run. Raises ConfigError for a voxel size
    that is not a positive number, and ValueError for points farther than 2**21 voxels from the
    origin along an axis.
    """

    def __init__(self, voxel_size_m: float, *, origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        problem = range_problem("voxel_size_m", voxel_size_m, VOXEL_SIZE_M, hint=VOXEL_SIZE_HINT)
        if problem is not None:
            raise ConfigError(problem)
        self.voxel_size_m = float(voxel_size_m)
        self.origin = np.asarray(origin, dtype=np.float64)
        self._seen = _SortedKeySet()

    def voxel_keys(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) int64 voxel key of each point of ``xyz`` (N, 3) float64 metres."""
        # offset by half the span: points below the origin (noise, a foreign origin) still fit
        index = np.floor((xyz - self.origin) / self.voxel_size_m).astype(np.int64) + _SPAN // 2
        if len(index) and (index.min() < 0 or index.max() >= _SPAN):
            far = float(np.abs(xyz - self.origin).max())
            raise ConfigError(f"a point lies {far:.6g} m from the voxel grid's origin, beyond "
                             f"{_SPAN // 2 * self.voxel_size_m:.1f} m ({_SPAN // 2} voxels); use a larger voxel")
        return (index[:, 0] << (2 * _BITS)) | (index[:, 1] << _BITS) | index[:, 2]

    def filter(self, chunk: PointCloud) -> PointCloud:
        """The points of ``chunk`` that fall in voxels no earlier point occupied, in stream order."""
        if len(chunk) == 0:
            return chunk
        keys = self.voxel_keys(chunk.xyz)
        unique, first = np.unique(keys, return_index=True)  # sorted keys, first row of each
        new = ~self._seen.contains(unique)
        self._seen.add(unique[new])
        keep = np.sort(first[new])
        return chunk if len(keep) == len(chunk) else chunk.take(keep)


class UniformSampler:
    """A uniform random sample of at most ``k`` points of a stream whose length is not known.

    Every point draws a key from a seeded generator in stream order; the ``k`` smallest keys
    win. Points whose key cannot make the sample any more are dropped on arrival, the rest are
    buffered and merged into the sample when the buffer reaches ``k`` rows. ``result()`` returns
    the sample in stream order. Memory: at most 2k rows.
    """

    def __init__(self, k: int, *, seed: int = 0) -> None:
        if k < 1:
            raise ConfigError(f"sample size {k} is impossible; give at least 1 point")
        self.k = int(k)
        self._rng = np.random.default_rng(seed)
        self._parts: list[tuple[PointCloud, np.ndarray, np.ndarray]] = []  # (rows, keys, stream positions)
        self._buffered = 0
        self._threshold = np.inf  # the largest key of a full sample: no larger key can enter
        self.seen = 0

    def add(self, chunk: PointCloud) -> None:
        n = len(chunk)
        if n == 0:
            return
        keys = self._rng.random(n)
        first = self.seen
        self.seen += n
        if np.isfinite(self._threshold):
            # about k * n / seen points pass: a long stream costs one comparison per point
            enter = np.flatnonzero(keys < self._threshold)  # indices: cheaper than a mask for few rows
            if len(enter) == 0:
                return
            chunk, keys, order = chunk.take(enter), keys[enter], enter + first
        else:
            order = np.arange(first, first + n, dtype=np.int64)
        self._parts.append((chunk, keys, order))
        self._buffered += len(keys)
        if self._buffered >= 2 * self.k:
            self._merge()

    def _merge(self) -> None:
        if len(self._parts) == 1 and self._buffered <= self.k:
            return
        rows = PointCloud.concatenate([p[0] for p in self._parts])
        keys = np.concatenate([p[1] for p in self._parts])
        order = np.concatenate([p[2] for p in self._parts])
        if len(keys) > self.k:
            best = np.argpartition(keys, self.k - 1)[: self.k]
            rows, keys, order = rows.take(best), keys[best], order[best]
            self._threshold = float(keys.max())
        self._parts = [(rows, keys, order)]
        self._buffered = len(keys)

    def result(self) -> PointCloud:
        """The sample (at most k points) in stream order; an empty xyz-only cloud if nothing came."""
        if not self._parts:
            return PointCloud(xyz=np.empty((0, 3)))
        self._merge()
        rows, _, order = self._parts[0]
        return rows.take(np.argsort(order, kind="stable"))

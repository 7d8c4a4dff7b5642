"""Density normalisation: one point per voxel of a regular grid, chosen by the points alone.

Why: a TLS scan is dense near each station and sparse far away, and the pattern is the
scanner's, not the building's; S3DIS-like real rooms are resampled to yet another density. A
network fed raw points learns the density pattern. Grid sampling (Pointcept's ``GridSample``,
mode "train"/"test") keeps one point per occupied ``grid_m`` voxel, applied identically to
synthetic training scenes and real test scenes, so both reach the network at one density.

Two rules, each depending only on the set of points (not on their order, on how a stream is
chunked or on which block reads them: a voxel has the same representative in every block that
holds it):

- training tiles (``grid_representatives``, ``grid_sample``): the voxel's point with the
  smallest hash of its coordinates' bits, voxels anchored at multiples of ``grid_m``;
- labelling (``voxel_representatives``): the point nearest the voxel's centre, coordinates
  counted on a ``QUANTUM_M`` lattice from the scene's first points, so a file format (float
  rounding) or a georeferencing offset changes no representative.
"""

from __future__ import annotations

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix(value: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on (N,) uint64 (a bijection with good avalanche)."""
    z = value.copy()
    z ^= z >> np.uint64(30)
    z *= np.uint64(0xBF58476D1CE4E5B9)
    z ^= z >> np.uint64(27)
    z *= np.uint64(0x94D049BB133111EB)
    z ^= z >> np.uint64(31)
    return z


QUANTUM_M = 1e-4  # coordinates are voxelised on a 0.1 mm lattice: finer than any scanner's precision


def voxel_index(xyz: np.ndarray, grid_m: float) -> np.ndarray:
    """(N, 3) int64 voxel indices of (N, 3) coordinates in metres.

    Coordinates are first rounded to ``QUANTUM_M``: a point a file format stored one bit apart
    (LAS integers times a scale, decimal text) stays in its voxel even on a voxel's face, where
    millimetre data puts every hundredth coordinate of a 0.1 m grid."""
    quantum = np.rint(np.asarray(xyz, dtype=np.float64) / QUANTUM_M).astype(np.int64)
    return quantum // max(1, round(grid_m / QUANTUM_M))


def voxel_hash(xyz: np.ndarray, grid_m: float, *, seed: int = 0) -> np.ndarray:
    """(N,) uint64 hash of each point's voxel (equal within a voxel; collisions 2**-64)."""
    cells = voxel_index(xyz, grid_m).view(np.uint64)
    with np.errstate(over="ignore"):
        h = _mix(np.full(len(cells), np.uint64(seed % (1 << 64)), dtype=np.uint64) + _GOLDEN)
        for axis in range(3):
            h = _mix(h ^ (cells[:, axis] + _GOLDEN))
    return h


def point_hash(xyz: np.ndarray) -> np.ndarray:
    """(N,) uint64 hash of each point's float64 coordinate bits: the order-free tie-break."""
    bits = np.ascontiguousarray(np.asarray(xyz, dtype=np.float64)).view(np.uint64).reshape(-1, 3)
    with np.errstate(over="ignore"):
        h = np.full(len(bits), _GOLDEN, dtype=np.uint64)
        for axis in range(3):
            h = _mix(h ^ bits[:, axis])
    return h


def grid_representatives(xyz: np.ndarray, grid_m: float) -> tuple[np.ndarray, np.ndarray]:
    """One representative point per occupied voxel.

    Returns (R,) int64 indices of the representatives, ascending, and (N,) int64 ``rep_of``:
    for every point, the index of its voxel's representative (a representative maps to itself).
    """
    n = len(xyz)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    cells = voxel_index(xyz, grid_m)
    secondary = point_hash(xyz)
    # lexsort: last key first -> by voxel (x, y, z), then by the coordinate hash
    order = np.lexsort((secondary, cells[:, 2], cells[:, 1], cells[:, 0]))
    sorted_cells = cells[order]
    starts = np.flatnonzero(np.r_[True, (sorted_cells[1:] != sorted_cells[:-1]).any(axis=1)])
    return _first_of_each_voxel(order, starts)


def _first_of_each_voxel(order: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The representatives (ascending) and every point's representative, from ``order`` (the points
    sorted by voxel, the chosen one first in each) and ``starts`` (where each voxel's run begins)."""
    n = len(order)
    rep_of = np.empty(n, dtype=np.int64)
    rep_of[order] = np.repeat(order[starts], np.diff(np.r_[starts, n]))
    return np.sort(order[starts]), rep_of


def grid_sample(xyz: np.ndarray, grid_m: float) -> np.ndarray:
    """(R,) int64 ascending indices of one point per occupied ``grid_m`` voxel (see the module)."""
    return grid_representatives(xyz, grid_m)[0]


def voxel_representatives(xyz: np.ndarray, grid_m: float) -> tuple[np.ndarray, np.ndarray]:
    """One representative per occupied voxel, for labelling: the point nearest the voxel's centre
    (ties: the first), so points a file format rounded differently, or moved by an offset that the
    caller subtracted, keep their representatives. ``xyz`` (N, 3) relative to the scene's origin.

    Returns (R,) int64 indices of the representatives, ascending, and (N,) int64 ``rep_of``: for
    every point, the index of its voxel's representative (a representative maps to itself).
    """
    n = len(xyz)
    if n == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64)
    cells = voxel_index(xyz, grid_m)
    step = max(1, round(grid_m / QUANTUM_M))  # the distance on the same lattice: no float tie differs
    offset = (np.rint(np.asarray(xyz, dtype=np.float64) / QUANTUM_M).astype(np.int64) - cells * step) * 2 - step
    distance = np.einsum("ij,ij->i", offset, offset)  # int64, (2 x lattice steps)^2
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    voxels = float(span[0]) * float(span[1]) * float(span[2])
    if voxels < 2.0**62:  # one int64 key per voxel: one sort key less
        key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
        distances = 3 * step * step + 1  # distance <= 3 step^2
        if voxels * distances * n < 2.0**62:  # a margin for the float product
            # voxel, distance and the point's index packed in one int64: sorting the values (a
            # vectorised sort) is several times faster than an argsort or a lexsort, and the index
            # in the low digits breaks ties by the first point as the stable sort did
            packed = np.sort((key * distances + distance) * n + np.arange(n, dtype=np.int64))
            order = packed % n
            sorted_key = packed // (n * distances)
        else:
            order = np.lexsort((distance, key))  # stable: ties keep the first
            sorted_key = key[order]
        starts = np.flatnonzero(np.r_[True, sorted_key[1:] != sorted_key[:-1]])
    else:
        order = np.lexsort((distance, cells[:, 2], cells[:, 1], cells[:, 0]))
        sorted_cells = cells[order]
        starts = np.flatnonzero(np.r_[True, (sorted_cells[1:] != sorted_cells[:-1]).any(axis=1)])
    return _first_of_each_voxel(order, starts)

"""Cloud-to-mesh distances within a band, for every point of a large scan.

Embree's closest-point query (``ModelSurfaces.closest``) answers any distance but walks its BVH
for every point: about a million points a second on two cores. Comparison only needs the model
surface within ``band_m`` of each point (farther points are clutter, or not the model's), which
allows the approach of CloudCompare's cloud-to-mesh distance: a grid of cells over the model,
each listing the triangles within ``band_m`` of it, and the exact point-to-triangle distance
(Ericson, *Real-Time Collision Detection*, 2005, section 5.1.5) to the few triangles of the
point's cell, compiled and run in parallel over the points.

A triangle is listed in every cell of its bounding box grown by the band whose box lies within
the band of the triangle's plane, so a point's cell lists every triangle within ``band_m`` of
the point (conservatively: some farther too, whose exact distance then rules them out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from bimscan.types import SceneMesh

MAX_CELLS = 24_000_000  # cells of the grid at most: larger sites get coarser cells
MIN_CELL_M = 0.1  # cells as wide as the band, and no finer: at the default band of 0.15 m, a point's cell
                  # lists about half as many triangles as cells twice that (1.9x faster queries on the duplex)


@dataclass(frozen=True)
class BandGrid:
    """Triangles per cell: origin (3,) float64 world metres of the grid's corner, cell_m, shape (3,)
    int64 cells per axis, start (cells + 1,) int64 offsets into triangles (T,) int32, band_m."""

    origin: np.ndarray
    cell_m: float
    shape: np.ndarray
    start: np.ndarray
    triangles: np.ndarray
    band_m: float


@nb.njit(cache=True, nogil=True)
def _cell_range(lo: float, hi: float, origin: float, cell: float, n: int) -> tuple[int, int]:
    a = int(np.floor((lo - origin) / cell))
    b = int(np.floor((hi - origin) / cell))
    return max(a, 0), min(b, n - 1)


@nb.njit(cache=True, nogil=True)
def _fill(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, cell: float, shape: np.ndarray, band: float,
          count: np.ndarray, out: np.ndarray, start: np.ndarray, write: bool) -> None:
    half_diagonal = 0.5 * cell * np.sqrt(3.0)
    ny, nz = shape[1], shape[2]
    for f in range(faces.shape[0]):
        a, b, c = vertices[faces[f, 0]], vertices[faces[f, 1]], vertices[faces[f, 2]]
        normal = np.cross(b - a, c - a)
        length = np.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
        if length > 0:
            normal = normal / length
        ranges = np.empty((3, 2), dtype=np.int64)
        for axis in range(3):
            lo = min(a[axis], b[axis], c[axis]) - band
            hi = max(a[axis], b[axis], c[axis]) + band
            ranges[axis, 0], ranges[axis, 1] = _cell_range(lo, hi, origin[axis], cell, shape[axis])
        for i in range(ranges[0, 0], ranges[0, 1] + 1):
            for j in range(ranges[1, 0], ranges[1, 1] + 1):
                for k in range(ranges[2, 0], ranges[2, 1] + 1):
                    if length > 0:
                        cx = origin[0] + (i + 0.5) * cell - a[0]
                        cy = origin[1] + (j + 0.5) * cell - a[1]
                        cz = origin[2] + (k + 0.5) * cell - a[2]
                        if abs(cx * normal[0] + cy * normal[1] + cz * normal[2]) > band + half_diagonal:
                            continue  # the cell lies farther than the band from the triangle's plane
                    index = (i * ny + j) * nz + k
                    if write:
                        out[start[index] + count[index]] = f
                    count[index] += 1


def build_band_grid(mesh: SceneMesh, *, band_m: float, cell_m: float | None = None) -> BandGrid:
    """The cell -> triangles lists of ``mesh`` for distances up to ``band_m`` (see the module docs)."""
    lo, hi = mesh.bounds()
    lo, hi = lo - band_m, hi + band_m
    size = np.maximum(hi - lo, 1e-6)
    cell = max(MIN_CELL_M, band_m) if cell_m is None else cell_m
    cell = max(cell, float(np.prod(size) / MAX_CELLS) ** (1.0 / 3.0))
    shape = np.maximum(np.ceil(size / cell).astype(np.int64), 1)
    vertices = np.ascontiguousarray(mesh.vertices - lo)
    faces = np.ascontiguousarray(mesh.faces)
    origin = np.zeros(3)
    n_cells = int(np.prod(shape))
    count = np.zeros(n_cells, dtype=np.int64)
    start = np.zeros(n_cells + 1, dtype=np.int64)
    _fill(vertices, faces, origin, cell, shape, band_m, count, np.zeros(0, np.int32), start, False)
    np.cumsum(count, out=start[1:])
    triangles = np.empty(int(start[-1]), dtype=np.int32)
    count[:] = 0
    _fill(vertices, faces, origin, cell, shape, band_m, count, triangles, start, True)
    return BandGrid(origin=lo, cell_m=float(cell), shape=shape, start=start, triangles=triangles, band_m=float(band_m))


@nb.njit(cache=True, nogil=True, inline="always")
def _closest_on_triangle(px: float, py: float, pz: float, t: np.ndarray) -> tuple[float, float, float]:
    """The point of triangle ``t`` = (a, b - a, c - a, ...) closest to p (Ericson 2005, 5.1.5),
    in scalars (no array is made per triangle)."""
    ax, ay, az, abx, aby, abz, acx, acy, acz = t[0], t[1], t[2], t[3], t[4], t[5], t[6], t[7], t[8]
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return ax + abx, ay + aby, az + abz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz
    cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return ax + acx, ay + acy, az + acz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return ax + abx + w * (acx - abx), ay + aby + w * (acy - aby), az + abz + w * (acz - abz)
    denominator = 1.0 / (va + vb + vc)
    v, w = vb * denominator, vc * denominator
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@nb.njit(cache=True, parallel=True)
def _query(points: np.ndarray, origin: np.ndarray, table: np.ndarray, cell: float, shape: np.ndarray,
           start: np.ndarray, triangles: np.ndarray, band: float, distance: np.ndarray, nearest: np.ndarray,
           triangle: np.ndarray, second: np.ndarray, face_component: np.ndarray, skip_component: np.ndarray) -> None:
    """Nearest triangle within the band of each point (world; the grid and ``table`` are relative to
    ``origin``), its nearest point on it (world), and the distance to the nearest triangle of
    another component than that one's (``second``); with ``skip_component`` (N,) (else empty),
    triangles of each point's given component are left out."""
    skipping = skip_component.shape[0] > 0
    ny, nz = shape[1], shape[2]
    limit = band * band
    for n in nb.prange(points.shape[0]):
        px, py, pz = points[n, 0] - origin[0], points[n, 1] - origin[1], points[n, 2] - origin[2]
        best, best_other = limit, limit
        best_triangle, best_component = -1, -1
        qx = qy = qz = 0.0
        i = int(np.floor(px / cell))
        j = int(np.floor(py / cell))
        k = int(np.floor(pz / cell))
        if 0 <= i < shape[0] and 0 <= j < shape[1] and 0 <= k < shape[2]:
            index = (i * ny + j) * nz + k
            for slot in range(start[index], start[index + 1]):
                f = triangles[slot]
                c = face_component[f]
                if skipping and c == skip_component[n]:
                    continue
                t = table[f]
                plane = (px - t[0]) * t[9] + (py - t[1]) * t[10] + (pz - t[2]) * t[11]
                if plane * plane > best_other:
                    continue  # its plane alone is farther than both answers so far
                cx, cy, cz = _closest_on_triangle(px, py, pz, t)
                d = (px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2
                if c == best_component:
                    if d < best:
                        best, best_triangle = d, f
                        qx, qy, qz = cx, cy, cz
                elif d < best:
                    if best_triangle >= 0:
                        best_other = best
                    best, best_triangle, best_component = d, f, c
                    qx, qy, qz = cx, cy, cz
                elif d < best_other:
                    best_other = d
        distance[n] = np.sqrt(best) if best_triangle >= 0 else np.inf
        second[n] = np.sqrt(best_other) if best_other < limit else np.inf
        nearest[n, 0], nearest[n, 1], nearest[n, 2] = qx + origin[0], qy + origin[1], qz + origin[2]
        triangle[n] = best_triangle


@dataclass(frozen=True)
class BandAnswer:
    """distance (N,) float64 metres to the nearest triangle (inf beyond the band); point (N, 3)
    float64 world metres on it (undefined beyond the band); triangle (N,) int64 (-1 beyond the band);
    second (N,) float64 the distance to the nearest triangle of any other component (inf beyond)."""

    distance: np.ndarray
    point: np.ndarray
    triangle: np.ndarray
    second: np.ndarray


class BandDistances:
    """Exact distances (within the band) of points to a mesh's triangles; world metres in and out."""

    def __init__(self, mesh: SceneMesh, *, band_m: float, cell_m: float | None = None) -> None:
        self.mesh = mesh
        self.grid = build_band_grid(mesh, band_m=band_m, cell_m=cell_m)
        self._face_component = np.ascontiguousarray(mesh.face_component, dtype=np.int64)
        corners = mesh.vertices[mesh.faces] - self.grid.origin  # (F, 3, 3), grid-local
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
        # per triangle: a, b - a, c - a, unit normal (zero for a degenerate one: its plane rejects nothing)
        self._table = np.ascontiguousarray(np.concatenate(
            [corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], normal], axis=1))

    @property
    def band_m(self) -> float:
        return self.grid.band_m

    def query(self, points: np.ndarray, *, other_than: np.ndarray | None = None) -> BandAnswer:
        """The nearest model surface within the band of each of ``points`` (N, 3) float64 world
        metres. ``other_than`` (N,) int: only triangles of other components than each point's given
        one count (how near another element is to a surface sample)."""
        points = np.ascontiguousarray(points, dtype=np.float64)
        n = len(points)
        distance = np.empty(n)
        nearest = np.zeros((n, 3))
        triangle = np.empty(n, dtype=np.int64)
        second = np.empty(n)
        grid = self.grid
        skip = np.zeros(0, np.int64) if other_than is None else np.ascontiguousarray(other_than, dtype=np.int64)
        _query(points, np.asarray(grid.origin, dtype=np.float64), self._table, grid.cell_m, grid.shape, grid.start,
               grid.triangles, grid.band_m, distance, nearest, triangle, second, self._face_component, skip)
        return BandAnswer(distance=distance, point=nearest, triangle=triangle, second=second)

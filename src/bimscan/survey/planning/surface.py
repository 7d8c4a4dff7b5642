"""Points spread over the surfaces of the elements to cover: what coverage is measured on.

Each element (component) of the chosen classes gets ``max(min_samples, area x samples_per_m2)``
samples spread over its triangles in proportion to their areas (systematic sampling along the
element's cumulative area, so every triangle gets its share to within one sample) and, within a
triangle, on a shifted low-discrepancy (R2) sequence, so they lie evenly, not in clumps. Every
sample stands for the same share of its element's area. Samples sit just inside their triangles
(1 % towards the centroid), so a ray aimed at one meets that triangle, not an edge it shares.
Where a sample lies does not depend on how its triangle is wound (its corners are taken in the
order of their vertex indices), so a model exported with its faces turned the other way is
sampled the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimscan.types import SceneMesh

# The R2 sequence's generators (Roberts 2018: the plastic number's powers), for even points in a square.
_R2 = (0.7548776662466927, 0.5698402909980532)
_INSET = 0.99  # samples are pulled this far towards their triangle's centroid


@dataclass(frozen=True)
class SurfaceSamples:
    """Surface samples: xyz (S, 3) float64 world metres; normal (S, 3) float64 unit normal of the
    triangle (from its winding until ``visibility.facing_stations`` turns it towards the stations
    that see it; visibility uses it two-sided); component (S,) int64; triangle (S,)
    int64 index into the mesh's faces; area_m2 (S,) float64, the surface each sample stands for."""

    xyz: np.ndarray
    normal: np.ndarray
    component: np.ndarray
    triangle: np.ndarray
    area_m2: np.ndarray

    def __len__(self) -> int:
        return int(len(self.xyz))

    def take(self, index: np.ndarray) -> SurfaceSamples:
        return SurfaceSamples(xyz=self.xyz[index], normal=self.normal[index], component=self.component[index],
                              triangle=self.triangle[index], area_m2=self.area_m2[index])


def triangle_areas(mesh: SceneMesh) -> np.ndarray:
    """(F,) float64 area of each triangle, square metres."""
    v, f = mesh.vertices, mesh.faces
    return 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)


def sample_surfaces(mesh: SceneMesh, wanted: np.ndarray, *, samples_per_m2: float, min_samples: int,
                    seed: int) -> SurfaceSamples:
    """Samples on the triangles of the components with ``wanted`` (C,) bool (see the module docs).
    Same mesh, settings and seed: the same samples."""
    rng = np.random.default_rng(seed)
    area = triangle_areas(mesh)
    keep = wanted[mesh.face_component] & (area > 1e-9)
    faces = np.flatnonzero(keep)
    faces = faces[np.argsort(mesh.face_component[faces], kind="stable")]
    component = mesh.face_component[faces].astype(np.int64)
    if len(faces) == 0:
        empty = np.zeros((0, 3))
        return SurfaceSamples(xyz=empty, normal=empty.copy(), component=np.zeros(0, np.int64),
                              triangle=np.zeros(0, np.int64), area_m2=np.zeros(0))
    starts = np.flatnonzero(np.r_[True, component[1:] != component[:-1]])
    ends = np.r_[starts[1:], len(faces)]
    chosen_faces, weights = [], []
    for start, end in zip(starts, ends):
        a = area[faces[start:end]]
        total = float(a.sum())
        n = max(min_samples, int(round(total * samples_per_m2)))
        cumulative = np.cumsum(a)
        positions = (np.arange(n) + rng.random()) * (total / n)  # systematic: one random offset per element
        index = np.minimum(np.searchsorted(cumulative, positions, side="right"), end - start - 1)
        chosen_faces.append(faces[start:end][index])
        weights.append(np.full(n, total / n))
    triangle = np.concatenate(chosen_faces)
    area_m2 = np.concatenate(weights)
    # the k-th sample of a triangle takes the k-th point of an R2 sequence shifted at random per triangle
    order = np.argsort(triangle, kind="stable")
    sorted_triangle = triangle[order]
    first = np.r_[True, sorted_triangle[1:] != sorted_triangle[:-1]]
    group_start = np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order)) - group_start
    shift = rng.random((mesh.n_triangles, 2))
    u = (shift[triangle, 0] + rank * _R2[0]) % 1.0
    w = (shift[triangle, 1] + rank * _R2[1]) % 1.0
    root = np.sqrt(u)  # uniform on the triangle (Osada et al. 2002)
    b0, b1, b2 = 1 - root, root * (1 - w), root * w
    v = mesh.vertices[np.sort(mesh.faces[triangle], axis=1)]  # the corners in index order: winding-free
    point = b0[:, None] * v[:, 0] + b1[:, None] * v[:, 1] + b2[:, None] * v[:, 2]
    centroid = v.mean(axis=1)
    xyz = centroid + _INSET * (point - centroid)
    normal = mesh.face_normals()[triangle]
    return SurfaceSamples(xyz=xyz, normal=normal, component=mesh.face_component[triangle].astype(np.int64),
                          triangle=triangle.astype(np.int64), area_m2=area_m2)

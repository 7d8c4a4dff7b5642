"""The model's surfaces as registration and comparison see them: closest points on its triangles
(Embree's BVH through Open3D), and even samples spread over them.

Normals are taken two-sided: the winding an authoring tool gave a triangle says nothing here.
``outward_normals`` turns each triangle's normal away from its own element's inside (the side
a scan meets it from), so that signed distances read "in front of the model surface" (+) and
"behind it" (-) whatever the winding.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bimscan.scan.engine import mesh_centre
from bimscan.survey.planning.surface import SurfaceSamples, sample_surfaces, triangle_areas
from bimscan.types import SceneMesh

QUERY_POINTS = 1_000_000  # closest-point queries per engine call (float32 copies: 12 MB)


@dataclass(frozen=True)
class ClosestPoints:
    """Closest points of query points on the model: point (N, 3) float64 world metres, distance (N,)
    float64 metres, normal (N, 3) float64 unit normal of the triangle (outward, see the module docs),
    triangle (N,) int64, component (N,) int64."""

    point: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    triangle: np.ndarray
    component: np.ndarray


class ModelSurfaces:
    """Closest-point queries on a model's mesh (world metres in and out). The engine works in a
    local frame around the mesh's centre, so georeferenced models keep millimetres in float32."""

    def __init__(self, mesh: SceneMesh) -> None:
        import open3d as o3d

        self.mesh = mesh
        self.centre = mesh_centre(mesh)
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor((mesh.vertices - self.centre).astype(np.float32)),
                                  o3d.core.Tensor(mesh.faces.astype(np.uint32)))

    @cached_property
    def outward(self) -> np.ndarray:
        """(F, 3) float64 unit normals of the triangles, turned away from their element's inside."""
        return outward_normals(self.mesh)

    def closest(self, points: np.ndarray) -> ClosestPoints:
        """The closest model surface point of each of ``points`` (N, 3) float64 world metres."""
        import open3d as o3d

        n = len(points)
        nearest = np.empty((n, 3), dtype=np.float64)
        triangle = np.empty(n, dtype=np.int64)
        for start in range(0, n, QUERY_POINTS):
            part = points[start:start + QUERY_POINTS]
            answer = self._scene.compute_closest_points(o3d.core.Tensor((part - self.centre).astype(np.float32)))
            nearest[start:start + len(part)] = answer["points"].numpy().astype(np.float64) + self.centre
            triangle[start:start + len(part)] = answer["primitive_ids"].numpy().astype(np.int64)
        distance = np.linalg.norm(points - nearest, axis=1)
        return ClosestPoints(point=nearest, distance=distance, normal=self.outward[triangle], triangle=triangle,
                             component=self.mesh.face_component[triangle].astype(np.int64))

    def samples(self, *, samples_per_m2: float, seed: int, wanted: np.ndarray | None = None,
                min_samples: int = 1) -> SurfaceSamples:
        """Even samples over the triangles of the ``wanted`` (C,) bool components (None: all), with
        outward normals."""
        n_components = int(self.mesh.face_component.max()) + 1 if self.mesh.n_triangles else 0
        chosen = np.ones(n_components, dtype=bool) if wanted is None else wanted
        samples = sample_surfaces(self.mesh, chosen, samples_per_m2=samples_per_m2, min_samples=min_samples,
                                  seed=seed)
        return SurfaceSamples(xyz=samples.xyz, normal=self.outward[samples.triangle], component=samples.component,
                              triangle=samples.triangle, area_m2=samples.area_m2)


def outward_normals(mesh: SceneMesh) -> np.ndarray:
    """(F, 3) float64 unit normals, each turned to point away from its element's inside.

    An element's inside is judged by its own triangles: the normal of a triangle points out when
    it points away from the element's area-weighted centre along the triangle's own direction
    (true for every face of a convex solid: a wall, a slab, a column, a beam's flange faces
    mostly), whatever the winding the authoring tool gave it.
    """
    normals = mesh.face_normals()
    if not mesh.n_triangles:
        return normals
    corners = mesh.vertices[mesh.faces]
    centroid = corners.mean(axis=1)
    area = triangle_areas(mesh)
    component = mesh.face_component
    n = int(component.max()) + 1
    weight = np.bincount(component, weights=area, minlength=n)
    centre = np.stack([np.bincount(component, weights=area * centroid[:, axis], minlength=n) for axis in range(3)],
                      axis=1) / np.maximum(weight, 1e-300)[:, None]
    away = np.einsum("ij,ij->i", normals, centroid - centre[component])
    return np.where((away < 0)[:, None], -normals, normals)

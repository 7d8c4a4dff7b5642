"""Probing a scene with rays: first hits, every surface along vertical lines, and solids.

Station planning and checks (``survey``) and site dressing (``site``) ask the scene geometric
questions (what is under this spot, how much headroom is there, is this point inside a wall)
through one ``Prober``: a ray engine over the scene's mesh and its triangle -> component table.
Probes run on Open3D's Embree scene whatever engine scans, so a plan or a dressed scene never
depends on the scan engine.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np

from bimscan.scan.engine import Open3DEngine
from bimscan.types import SceneMesh

_DIAGONAL = float(np.sqrt(0.5))
INSIDE_PROBE_DIRECTIONS = (
    (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0),
    (_DIAGONAL, _DIAGONAL, 0.0), (-_DIAGONAL, _DIAGONAL, 0.0), (_DIAGONAL, -_DIAGONAL, 0.0), (-_DIAGONAL, -_DIAGONAL, 0.0),
)
DOWN = np.array([0.0, 0.0, -1.0])
UP = np.array([0.0, 0.0, 1.0])
LAYER_STEP_M = 1e-3  # a vertical probe goes on this far beyond each surface it meets
MAX_LAYERS = 1024  # surfaces met along one vertical line, at most (a tall building with its furniture)


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) float32 unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = math.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)


class Prober:
    """Ray probes of one mesh: first hits and the triangle or component hit, every surface along
    vertical lines, and whether points lie inside closed solids. ``threads``: Embree's cores (0 = all)."""

    def __init__(self, mesh: SceneMesh, *, threads: int = 0) -> None:
        self.mesh = mesh
        self.engine = Open3DEngine(mesh, threads=threads)
        self.face_component = mesh.face_component
        self.n_components = int(mesh.face_component.max()) + 1 if len(mesh.face_component) else 0

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals of the mesh's triangles (computed once)."""
        return self.mesh.face_normals()

    def _rays(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        rays = np.empty((len(directions) if np.ndim(origins) == 1 else len(origins), 6), dtype=np.float32)
        rays[:, :3] = origins - self.engine.centre
        rays[:, 3:] = directions
        return rays

    def cast_faces(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """origins (N, 3) or (3,) world metres, unit directions (N, 3) -> distance (N,) float64
        (inf: no hit), triangle (N,) int64 (-1: no hit)."""
        if len(directions) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        t, triangle = self.engine.cast(self._rays(origins, directions))
        hit = np.isfinite(t) & (triangle < len(self.face_component))
        return np.where(hit, t, np.inf).astype(np.float64), np.where(hit, triangle.astype(np.int64), -1)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """origins (N, 3) or (3,) world metres, unit directions (N, 3) -> distance (N,) float64
        (inf: no hit), component (N,) int64 (-1: no hit)."""
        t, triangle = self.cast_faces(origins, directions)
        component = np.where(triangle >= 0, self.face_component[np.maximum(triangle, 0)], -1).astype(np.int64)
        return t, component

    def surfaces_below(self, xy: np.ndarray, z_from: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every surface met by vertical lines cast down from ``z_from`` at xy (N, 2) world metres:
        (line index (K,) int64, z (K,) float64 world metres, triangle (K,) int64), line by line
        from the top down. A probe goes on ``LAYER_STEP_M`` past each surface, so faces closer
        together than that (two elements sharing a face) count once."""
        lines: list[np.ndarray] = []
        heights: list[np.ndarray] = []
        triangles: list[np.ndarray] = []
        active = np.arange(len(xy))
        z = np.full(len(xy), float(z_from))
        for _ in range(MAX_LAYERS):
            if len(active) == 0:
                break
            origins = np.column_stack([xy[active], z[active]])
            t, triangle = self.cast_faces(origins, np.broadcast_to(DOWN, origins.shape))
            hit = triangle >= 0
            active, t, triangle = active[hit], t[hit], triangle[hit]
            z_hit = z[active] - t
            lines.append(active)
            heights.append(z_hit)
            triangles.append(triangle)
            z[active] = z_hit - LAYER_STEP_M
        if not lines:
            return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64)
        line, height, triangle = np.concatenate(lines), np.concatenate(heights), np.concatenate(triangles)
        order = np.lexsort((-height, line))
        return line[order], height[order], triangle[order]

    def inside_solid(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: points (N, 3) world metres inside a closed solid: at least six of eight
        horizontal rays from the point (the axes and the diagonals) meet a face from behind (faces
        wound outward, as IfcOpenShell writes closed shells). A vote, because a ray along a wall
        ends where walls abut, on two coincident faces, and which of them the BVH reports differs
        between Embree builds; the diagonals leave a wall through its long faces."""
        if len(points) == 0:
            return np.zeros(0, dtype=bool)
        normals = self.face_normals
        behind = np.zeros(len(points), dtype=int)
        for direction in INSIDE_PROBE_DIRECTIONS:
            rays = np.empty((len(points), 6), dtype=np.float32)
            rays[:, :3] = points - self.engine.centre
            rays[:, 3:] = direction
            t, triangle = self.engine.cast(rays)
            hit = np.isfinite(t) & (triangle < len(normals))
            facing = np.zeros(len(points))
            facing[hit] = normals[triangle[hit]] @ np.asarray(direction)
            behind += facing > 0
        return behind >= 6

    def solid_containing(self, point: np.ndarray, *, n_rays: int = 96) -> int | None:
        """The component whose closed surface encloses ``point`` (3,) world metres, or None.

        Counts the crossings of each component along rays in all directions: from inside a
        closed solid nearly every ray crosses it an odd number of times. Unlike ``inside_solid``
        this does not trust the winding of the model's triangles.
        """
        ray_ids, triangle = self.engine.list_intersections(self._rays(np.asarray(point, dtype=np.float64),
                                                                      sphere_directions(n_rays)))
        valid = triangle < len(self.face_component)
        if not valid.any() or self.n_components == 0:
            return None
        component = self.face_component[triangle[valid]].astype(np.int64)
        pairs, counts = np.unique(ray_ids[valid] * self.n_components + component, return_counts=True)
        odd = pairs[counts % 2 == 1] % self.n_components
        if len(odd) == 0:
            return None
        candidates, rays_odd = np.unique(odd, return_counts=True)
        best = int(np.argmax(rays_odd))
        return int(candidates[best]) if rays_odd[best] >= 0.8 * n_rays else None

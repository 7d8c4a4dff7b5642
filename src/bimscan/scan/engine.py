"""Ray engines: a real BVH ray caster behind one small interface.

``RayEngine.cast(rays)`` takes (N, 6) float32 rays (origin xyz, unit direction xyz, in the
engine's local frame: world minus ``centre``) and returns the hit distance (N,) float32 (inf
where nothing is hit) and the hit triangle index (N,) uint32. One merged mesh, so the triangle
index maps straight to a component (thousands of separate meshes cast about 10x slower).

``ENGINES`` holds the available engines: ``open3d`` (Embree through Open3D's RaycastingScene,
all cores, the default) and ``embreex`` (Embree 4 through embreex; it holds the GIL, so it runs
on one core per process). A GPU engine (e.g. NVIDIA Warp) plugs in by adding an entry.
Coordinates are re-centred before the float32 conversion so georeferenced models (site
coordinates in the hundreds of kilometres) keep millimetre precision.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from bimscan.errors import ConfigError
from bimscan.types import SceneMesh

MISS = np.uint32(0xFFFFFFFF)


class RayEngine(Protocol):
    name: str
    centre: np.ndarray  # (3,) float64, world position of the local origin

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """rays (N, 6) float32 local -> (t_hit (N,) float32, triangle (N,) uint32)."""
        ...


def mesh_centre(mesh: SceneMesh) -> np.ndarray:
    """A round local origin near the middle of the mesh (whole metres, so offsets stay exact)."""
    lo, hi = mesh.bounds()
    return np.round((lo + hi) / 2.0)


class Open3DEngine:
    """Embree via Open3D's RaycastingScene; casts on all cores (or ``threads``)."""

    name = "open3d"

    def __init__(self, mesh: SceneMesh, *, threads: int = 0) -> None:
        import open3d as o3d

        self._o3d = o3d
        self.centre = mesh_centre(mesh)
        self.threads = threads
        self._scene = o3d.t.geometry.RaycastingScene(nthreads=threads)
        vertices = np.ascontiguousarray(mesh.vertices - self.centre, dtype=np.float32)
        faces = np.ascontiguousarray(mesh.faces, dtype=np.uint32)
        self._scene.add_triangles(o3d.core.Tensor.from_numpy(vertices), o3d.core.Tensor.from_numpy(faces))

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        result = self._scene.cast_rays(self._o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays)), nthreads=self.threads)
        return result["t_hit"].numpy(), result["primitive_ids"].numpy()

    def list_intersections(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every crossing of every ray: (ray index (K,) int64, triangle (K,) uint32)."""
        result = self._scene.list_intersections(self._o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays)))
        return result["ray_ids"].numpy().astype(np.int64), result["primitive_ids"].numpy()


class EmbreexEngine:
    """Embree 4 via embreex (one core: it holds the GIL)."""

    name = "embreex"

    def __init__(self, mesh: SceneMesh, *, threads: int = 0) -> None:
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError as exc:
            raise ConfigError("ray engine 'embreex' is not installed; pip install 'bimscan[embree]' or use --engine open3d") from exc
        self.centre = mesh_centre(mesh)
        self._scene = rtcore_scene.EmbreeScene()
        vertices = np.ascontiguousarray(mesh.vertices - self.centre, dtype=np.float32)
        TriangleMesh(self._scene, vertices, np.ascontiguousarray(mesh.faces, dtype=np.int32))

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        origins = np.ascontiguousarray(rays[:, :3])
        directions = np.ascontiguousarray(rays[:, 3:])
        out = self._scene.run(origins, directions, output=1)
        t_hit = np.asarray(out["tfar"], dtype=np.float32)
        primitive = np.asarray(out["primID"]).astype(np.int64)
        missed = primitive < 0
        t_hit[missed] = np.inf
        return t_hit, np.where(missed, MISS, primitive).astype(np.uint32)


ENGINES: dict[str, Callable[..., RayEngine]] = {"open3d": Open3DEngine, "embreex": EmbreexEngine}
DEFAULT_ENGINE = "open3d"


def make_engine(mesh: SceneMesh, *, name: str = DEFAULT_ENGINE, threads: int = 0) -> RayEngine:
    """Build the named engine over ``mesh``."""
    if name not in ENGINES:
        raise ConfigError(f"unknown ray engine {name!r}; choose one of {', '.join(ENGINES)}")
    return ENGINES[name](mesh, threads=threads)

"""Ray engines: a real BVH ray caster behind one small interface.

``RayEngine.cast(rays)`` takes (N, 6) float32 rays (origin xyz, unit direction xyz, in the
engine's local frame: world minus ``centre``) and returns the hit distance (N,) float32 (inf
where nothing is hit) and the hit triangle index (N,) uint32. One merged mesh, so the triangle
index maps straight to a component (thousands of separate meshes cast about 10x slower).

``ENGINES`` holds the available engines: ``open3d`` (Embree through Open3D's RaycastingScene,
all cores, the default), ``embreex`` (Embree 4 through embreex; it holds the GIL, so it runs
on one core per process) and ``warp`` (NVIDIA Warp: a BVH on a CUDA GPU, or on Warp's CPU
device where no GPU is visible; ``scan.warp_engine``). ``resolve_engine("auto")`` picks Warp on
CUDA and Open3D otherwise. Coordinates are re-centred before the float32 conversion so
georeferenced models (site coordinates in the hundreds of kilometres) keep millimetre precision.

An engine may also offer the fused scan path ``cast_and_finish(pattern, heading_deg, lines, hits,
faces, outputs) -> kept``: it generates the rays of a chunk of mirror lines, casts them and does
the per-hit work of ``kernels.finish_hits`` itself (Warp: on the device, so hits never travel
back unfinished), writing the same points in the same order. ``VirtualScanner`` uses it when
present; the types it takes are ``bimscan.scan.pattern``'s ``PulsePattern`` and ``LineChunk``
(``PulsePattern.line_chunks``) and ``HitSettings`` and ``FaceTables`` below.
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import importlib.util
import sys
import types
from collections.abc import Callable
from dataclasses import dataclass
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


_PLOTLY_VIEWER = "open3d.visualization.draw_plotly"
_PLOTLY_NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")


def import_open3d() -> types.ModuleType:
    """Open3D, imported without its Plotly/Dash web viewer until something calls the viewer.

    ``import open3d`` imports ``open3d.visualization.draw_plotly``, and with it Plotly and the
    Dash web framework: about half of Open3D's import (0.7-0.9 s of 1.4-1.8 s on the 2-core
    machine), paid by every process that casts rays (each ``bimscan scan``, each build worker)
    and never used by bimscan. A stand-in takes that module's place while Open3D is imported; its
    three functions import the real viewer on their first call and put the real functions in
    ``open3d.visualization``, so code in the same process that draws with Plotly loses nothing."""
    if "open3d" in sys.modules:
        return sys.modules["open3d"]
    stand_in = types.ModuleType(_PLOTLY_VIEWER, "Open3D's Plotly viewer, imported on first use (bimscan.scan.engine)")
    for name in _PLOTLY_NAMES:
        setattr(stand_in, name, _viewer_on_first_call(name))
    sys.modules[_PLOTLY_VIEWER] = stand_in
    try:
        import open3d
    finally:
        if sys.modules.get(_PLOTLY_VIEWER) is stand_in:
            del sys.modules[_PLOTLY_VIEWER]  # the next import of the viewer is the real one
    return open3d


def _viewer_on_first_call(name: str) -> Callable[..., object]:
    def call(*args: object, **kwargs: object) -> object:
        viewer = importlib.import_module(_PLOTLY_VIEWER)
        visualization = sys.modules["open3d.visualization"]
        for each in _PLOTLY_NAMES:  # as ``from .draw_plotly import ...`` leaves them
            setattr(visualization, each, getattr(viewer, each))
        return getattr(viewer, name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    return call


class Open3DEngine:
    """Embree via Open3D's RaycastingScene; casts on all cores (or ``threads``)."""

    name = "open3d"

    def __init__(self, mesh: SceneMesh, *, threads: int = 0) -> None:
        o3d = import_open3d()

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


def make_warp_engine(mesh: SceneMesh, *, threads: int = 0) -> RayEngine:
    """NVIDIA Warp's engine on the default device (the first CUDA GPU, else Warp's CPU device).

    Imported here, on use, so ``import bimscan`` neither needs nor waits for Warp.
    """
    if importlib.util.find_spec("warp") is None:
        raise ConfigError("ray engine 'warp' needs NVIDIA Warp, which is not installed; "
                          "pip install 'bimscan[gpu]' or use --engine open3d")
    from bimscan.scan.warp_engine import WarpEngine

    return WarpEngine(mesh, threads=threads)


ENGINES: dict[str, Callable[..., RayEngine]] = {"open3d": Open3DEngine, "embreex": EmbreexEngine,
                                                "warp": make_warp_engine}
DEFAULT_ENGINE = "open3d"
AUTO_ENGINE = "auto"  # not an engine: a name resolved once by resolve_engine


def cuda_driver_loads() -> bool:
    """Whether the NVIDIA driver library loads (no GPU without it; Warp need not start to know)."""
    names = ("nvcuda.dll",) if sys.platform == "win32" else ("libcuda.so.1", "libcuda.so")
    for name in names:
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


@functools.cache
def warp_sees_cuda() -> bool:
    """Whether NVIDIA Warp is installed and sees a CUDA device (starts Warp: about a second)."""
    if importlib.util.find_spec("warp") is None or not cuda_driver_loads():
        return False
    from bimscan.scan.warp_engine import cuda_available

    return cuda_available()


def resolve_engine(name: str) -> str:
    """An engine name as given -> the ``ENGINES`` name to use.

    ``"auto"``: ``"warp"`` when Warp is installed and a CUDA device is visible, ``"open3d"``
    otherwise (Warp's CPU device runs on one core, far slower than Embree on all of them).
    Other names are checked and returned as they are.
    """
    if name == AUTO_ENGINE:
        return "warp" if warp_sees_cuda() else DEFAULT_ENGINE
    if name not in ENGINES:
        raise ConfigError(f"unknown ray engine {name!r}; choose one of {', '.join([*ENGINES, AUTO_ENGINE])}")
    return name


def make_engine(mesh: SceneMesh, *, name: str = DEFAULT_ENGINE, threads: int = 0) -> RayEngine:
    """Build the named engine over ``mesh`` (``"auto"`` resolved by ``resolve_engine``)."""
    return ENGINES[resolve_engine(name)](mesh, threads=threads)


@dataclass(frozen=True, eq=False)
class FaceTables:
    """What a hit reads of its triangle (built once per scene and scanner; see ``finish_hits``).

    component: (F,) int32 component of each triangle. label: (F,) uint8 class of each triangle.
    brightness: (F, 3) float32 unit normal scaled by 65535 * reflectance of its component.
    Compared by identity, so an engine can keep a device copy for the object it was given.
    """

    component: np.ndarray
    label: np.ndarray
    brightness: np.ndarray


@dataclass(frozen=True)
class HitSettings:
    """One station's constants of the per-hit work (the scalar arguments of ``finish_hits``).

    origin_world: (3,) float64 beam origin in world metres; origin_local: (3,) float32 the same
    in the engine's frame (world minus ``centre``). key: the station's noise generator key
    (``kernels.noise_key``). A hit is kept at a true range in [min_range_m, max_range_m].
    """

    origin_world: np.ndarray
    origin_local: np.ndarray
    min_range_m: float
    max_range_m: float
    key: int
    range_sigma_m: float
    angle_sigma_rad: float
    time0_s: float
    pulse_period_s: float
    intensity_ref_m: float
    station_id: int

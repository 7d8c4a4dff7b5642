"""The virtual scanner over one scene: pulses -> rays -> engine -> labelled point chunks."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numba
import numpy as np

from bimscan.scan.engine import FaceTables, HitSettings, LineChunk, RayEngine, make_engine
from bimscan.scan.kernels import finish_hits, generate_rays, noise_key, station_normals
from bimscan.scan.noise import NoiseModel
from bimscan.scan.pattern import PulsePattern
from bimscan.scan.device import ScannerModel
from bimscan.scan.recipe import ScanRecipe
from bimscan.types import PointCloud, SceneMesh, Station

DEFAULT_REFLECTANCE = 0.5
INTENSITY_REFERENCE_M = 5.0  # intensity falls with (5 m / range)^2 beyond 5 m


def sphere_directions(n: int) -> np.ndarray:
    """(n, 3) float32 unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = math.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)


def registration_error(noise: NoiseModel, key: np.uint64) -> tuple[np.ndarray, np.ndarray]:
    """The station's rigid registration error: rotation (3, 3) about the vertical and shift (3,) metres."""
    draws = station_normals(key)
    yaw = math.radians(noise.registration_sigma_deg) * draws[3]
    c, s = math.cos(yaw), math.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rotation, noise.registration_sigma_m * draws[:3]


class VirtualScanner:
    """A scanner model placed in one scene mesh; scans stations into labelled point chunks.

    mesh: the merged scene mesh; component_label: (C,) uint8 class of each component.
    reflectance: (C,) float32 in [0, 1] for the intensity model (default 0.5 everywhere).
    threads: cores for the engine and the fused kernels (0 = all).
    """

    def __init__(self, mesh: SceneMesh, component_label: np.ndarray, *, scanner: ScannerModel,
                 engine: str | RayEngine = "open3d", threads: int = 0, reflectance: np.ndarray | None = None) -> None:
        self.mesh = mesh
        self.scanner = scanner
        self.engine = engine if not isinstance(engine, str) else make_engine(mesh, name=engine, threads=threads)
        self.threads = threads
        self.component_label = np.ascontiguousarray(component_label, dtype=np.uint8)
        n_components = len(self.component_label)
        self.reflectance = (np.full(n_components, DEFAULT_REFLECTANCE, dtype=np.float32) if reflectance is None
                            else np.ascontiguousarray(reflectance, dtype=np.float32))
        self.face_component = np.ascontiguousarray(mesh.face_component, dtype=np.int32)
        # what the hit kernel reads per triangle (see finish_hits)
        self.face_label = self.component_label[self.face_component]
        self.face_brightness = (mesh.face_normals() * (65535.0 * self.reflectance[self.face_component])[:, None]
                                ).astype(np.float32)
        self._face_tables = FaceTables(component=self.face_component, label=self.face_label,
                                       brightness=self.face_brightness)
        # Working buffers of scan_station, reused (outputs are fresh arrays): one scan at a time
        # per VirtualScanner.
        self._ray_buffer = np.empty((0, 6), dtype=np.float32)
        self._pulse_buffer = np.empty(0, dtype=np.int64)
        self._output_buffers: tuple[np.ndarray, ...] = (np.empty((0, 3)),)
        self._probe: RayEngine | None = None

    def _set_threads(self) -> None:
        if self.threads:
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))

    def scan_station(self, station: Station, recipe: ScanRecipe, *, time0_s: float = 0.0,
                     on_pulses: Callable[[int], None] | None = None,
                     reuse_buffers: bool = False) -> Iterator[PointCloud]:
        """Stream the labelled points of one station scanned with ``recipe``, chunk by chunk.

        ``recipe.scanner`` must be this scanner's model. Chunks follow mirror lines and hold about
        ``recipe.chunk_pulses`` pulses; output points are the same whatever the chunk size (noise
        is indexed by pulse number). ``on_pulses(n)`` is
        called with each chunk's pulse count (for progress bars). With ``reuse_buffers`` the
        chunks are views into output arrays that the next chunk overwrites (no fresh memory per
        chunk, about 5 % faster): for consumers that write each chunk out before asking for the next.
        """
        if recipe.scanner != self.scanner:
            raise ValueError(f"the recipe's scanner {recipe.scanner.name!r} is not this VirtualScanner's "
                             f"{self.scanner.name!r}")
        self._set_threads()
        noise = recipe.noise
        pattern = PulsePattern.of(recipe.settings, self.scanner)
        origin_world = np.asarray(station.position, dtype=np.float64)
        origin_local = origin_world - self.engine.centre
        key = np.uint64(noise_key(recipe.seed, station.id, recipe.noise_stream))
        angle_sigma = math.radians(noise.angle_sigma_deg)
        registration = registration_error(noise, key) if noise.registers_with_error else None
        # An engine with a fused path (Warp) generates, casts and finishes each chunk on its device;
        # it implements finish_hits as it is here (the paper's realism), so it fills the same points
        # in the same order. Other engines cast here and finish_hits finishes on the host.
        fused = getattr(self.engine, "cast_and_finish", None)
        hits = HitSettings(origin_world=origin_world, origin_local=origin_local.astype(np.float32),
                           min_range_m=self.scanner.min_range_m, max_range_m=self.scanner.max_range_m, key=int(key),
                           range_sigma_m=noise.range_sigma_m, angle_sigma_rad=angle_sigma, time0_s=time0_s,
                           pulse_period_s=1.0 / pattern.pulse_freq_hz, intensity_ref_m=INTENSITY_REFERENCE_M,
                           station_id=station.id)
        for first_line, stop_line in pattern.chunks(recipe.chunk_pulses):
            start, stop = pattern.line_pulses(first_line, stop_line)
            counts = stop - start
            offsets = np.zeros(len(counts), dtype=np.int64)
            np.cumsum(counts[:-1], out=offsets[1:])
            n = int(counts.sum())
            if n == 0:
                continue
            if fused is not None:
                columns = self._outputs(n, reuse_buffers)
                if on_pulses is not None:
                    on_pulses(n)
                lines = LineChunk(first_line=first_line, start=start, stop=stop, offsets=offsets, n=n)
                kept = fused(pattern, station.heading_deg, lines, hits, self._face_tables, columns)
                if kept:
                    yield self._chunk_cloud(columns, kept, registration, origin_world)
                continue
            if len(self._ray_buffer) < n:  # working buffers reused across chunks and stations
                self._ray_buffer = np.empty((n, 6), dtype=np.float32)
                self._pulse_buffer = np.empty(n, dtype=np.int64)
            rays, pulse = self._ray_buffer[:n], self._pulse_buffer[:n]
            generate_rays(start, stop, offsets, first_line, pattern.dphase, pattern.sweep_deg, pattern.head_start_deg,
                          pattern.head_deg_per_pulse, station.heading_deg, origin_local.astype(np.float32), rays, pulse)
            t_hit, triangle = self.engine.cast(rays)
            xyz, label, component, station_column, intensity, time = self._outputs(n, reuse_buffers)
            if on_pulses is not None:
                on_pulses(n)
            kept = finish_hits(t_hit, triangle, rays, pulse, self.face_component, self.face_label,
                               self.face_brightness, origin_world, self.scanner.min_range_m,
                               self.scanner.max_range_m, key, noise.range_sigma_m, angle_sigma, time0_s,
                               1.0 / pattern.pulse_freq_hz, INTENSITY_REFERENCE_M, station.id, xyz, label, component,
                               station_column, intensity, time)
            if kept == 0:
                continue
            yield self._chunk_cloud((xyz, label, component, station_column, intensity, time), kept, registration,
                                    origin_world)

    @staticmethod
    def _chunk_cloud(columns: tuple[np.ndarray, ...], kept: int, registration: tuple[np.ndarray, np.ndarray] | None,
                     origin_world: np.ndarray) -> PointCloud:
        """The first ``kept`` rows of a chunk's output columns, moved by the station's registration error."""
        xyz, label, component, station_column, intensity, time = columns
        if registration is not None:
            rotation, shift = registration
            local = xyz[:kept] - origin_world
            xyz[:kept] = local @ rotation.T + origin_world + shift
        return PointCloud(xyz=xyz[:kept], label=label[:kept], component=component[:kept],
                          station=station_column[:kept], intensity=intensity[:kept], time=time[:kept])

    def _outputs(self, n: int, reuse: bool) -> tuple[np.ndarray, ...]:
        """Output columns for n rays: fresh, or views of buffers kept for the next chunk."""
        if reuse and len(self._output_buffers[0]) >= n:
            return tuple(b[:n] for b in self._output_buffers)
        # kept buffers of a GPU engine live in page-locked memory, which its copies fill at full speed
        allocate = getattr(self.engine, "empty_outputs", None) if reuse else None
        if allocate is not None:
            columns = allocate(n)
        else:
            columns = (np.empty((n, 3), dtype=np.float64), np.empty(n, dtype=np.uint8), np.empty(n, dtype=np.int32),
                       np.empty(n, dtype=np.uint16), np.empty(n, dtype=np.uint16), np.empty(n, dtype=np.float64))
        if reuse:
            self._output_buffers = columns
        return columns

    def cast(self, origins_world: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hits of rays: origins (3,) or (N, 3) world metres, unit directions (N, 3).

        Returns the distance (N,) float64 (inf where nothing is hit) and the hit component
        (N,) int32 (-1 for a miss). For probing the scene (station planning and checks).
        """
        rays = np.empty((len(directions), 6), dtype=np.float32)
        rays[:, :3] = np.asarray(origins_world, dtype=np.float64) - self.engine.centre
        rays[:, 3:] = directions
        t_hit, triangle = self.engine.cast(rays)
        n_faces = len(self.face_component)
        component = np.where(triangle < n_faces, self.face_component[np.minimum(triangle, n_faces - 1)], -1)
        return t_hit.astype(np.float64), component.astype(np.int32)

    def solid_containing(self, point_world: np.ndarray, *, n_rays: int = 96) -> int | None:
        """The component whose closed surface encloses ``point_world``, or None.

        Counts the crossings of each component along rays in all directions: from inside a
        closed solid nearly every ray crosses it an odd number of times. Unlike a test on
        triangle normals this does not trust the winding of the model's triangles.
        """
        from bimscan.scan.engine import Open3DEngine

        count_crossings = getattr(self.engine, "count_crossings", None)
        if count_crossings is not None:  # crossings per component counted by the engine itself (Warp)
            rays = np.empty((n_rays, 6), dtype=np.float32)
            rays[:, :3] = np.asarray(point_world, dtype=np.float64) - self.engine.centre
            rays[:, 3:] = sphere_directions(n_rays)
            rays_odd = (count_crossings(rays) % 2 == 1).sum(axis=0)
            if not rays_odd.any():
                return None
            best = int(np.argmax(rays_odd))
            return best if rays_odd[best] >= 0.8 * n_rays else None
        if hasattr(self.engine, "list_intersections"):
            probe = self.engine
        else:  # engines without it (embreex): an Open3D scene for these rare probes
            if self._probe is None:
                self._probe = Open3DEngine(self.mesh, threads=self.threads)
            probe = self._probe
        rays = np.empty((n_rays, 6), dtype=np.float32)
        rays[:, :3] = np.asarray(point_world, dtype=np.float64) - probe.centre
        rays[:, 3:] = sphere_directions(n_rays)
        ray_ids, triangle = probe.list_intersections(rays)
        valid = triangle < len(self.face_component)
        if not valid.any():
            return None
        component = self.face_component[triangle[valid]].astype(np.int64)
        pairs, counts = np.unique(ray_ids[valid] * len(self.component_label) + component, return_counts=True)
        odd = pairs[counts % 2 == 1] % len(self.component_label)
        if len(odd) == 0:
            return None
        candidates, rays_odd = np.unique(odd, return_counts=True)
        best = int(np.argmax(rays_odd))
        return int(candidates[best]) if rays_odd[best] >= 0.8 * n_rays else None

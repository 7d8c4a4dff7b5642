"""The virtual scanner over one scene: pulses -> rays -> engine -> labelled point chunks."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

import numba
import numpy as np

from bimscan.scan.asbuilt import Deviations
from bimscan.scan.engine import FaceTables, HitSettings, RayEngine, make_engine
from bimscan.scan.kernels import finish_hits, generate_rays, noise_key, station_normals
from bimscan.scan.lidars import Lidar
from bimscan.scan.multibeam import finish_moving_hits, moving_rays
from bimscan.scan.risley import RisleyScanner, risley_rays
from bimscan.scan.noise import NoiseModel
from bimscan.scan import waveform
from bimscan.scan.device import ScannerModel, ScanSettings
from bimscan.scan.pattern import PulsePattern
from bimscan.scan.sensor import SensorModel
from bimscan.progress import StageClock
from bimscan.types import ComponentSurfaces, ComponentTable, PointCloud, SceneMesh, Station

if TYPE_CHECKING:
    from bimscan.survey.drift import DriftTrack
    from bimscan.survey.trajectory import Trajectory

DEFAULT_REFLECTANCE = 0.5
_POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)
INTENSITY_REFERENCE_M = 5.0  # intensity falls with (5 m / range)^2 beyond 5 m
# lidars on one platform at most: LAS 1.4's scanner_channel numbers four scanners, and each
# pass's noise keys leave room for that many (survey.platform checks platforms against it)
MAX_MOUNTS = 4


class StationRecipe(Protocol):
    """What scanning one station needs of a recipe (``survey.recipe.ScanRecipe`` has it all): the
    device, what a station does, noise, sensor effects, the noise generator's key and the chunk size."""

    scanner: ScannerModel
    settings: ScanSettings
    noise: NoiseModel
    sensor: SensorModel
    seed: int
    noise_stream: str
    chunk_pulses: int
    mobile: Any  # survey.mobile.MobileScan of a mobile scan, None for a tripod survey


def registration_error(noise: NoiseModel, key: np.uint64) -> tuple[np.ndarray, np.ndarray]:
    """The station's rigid registration error: rotation (3, 3) about the vertical and shift (3,) metres."""
    draws = station_normals(key)
    yaw = math.radians(noise.registration_sigma_deg) * draws[3]
    c, s = math.cos(yaw), math.sin(yaw)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rotation, noise.registration_sigma_m * draws[:3]


class VirtualScanner:
    """A scanner model placed in one scene mesh; scans stations into labelled point chunks.

    mesh: the merged scene mesh (as built: already moved by ``deviations`` when given);
    component_label: (C,) uint8 class of each component. reflectance: (C,) float32 in [0, 1] for
    the paper path's intensity model (default 0.5 everywhere). components / surfaces: the
    component table and the IFC surface facts, for the sensor effects' materials, glass and
    colour (classes alone without surfaces; all defaults without either). deviations: the
    as-built transforms the mesh was moved by (recorded in metadata). threads: cores for the
    engine and the fused kernels (0 = all).
    """

    def __init__(self, mesh: SceneMesh, component_label: np.ndarray, *, scanner: ScannerModel,
                 engine: str | RayEngine = "open3d", threads: int = 0, reflectance: np.ndarray | None = None,
                 components: ComponentTable | None = None, surfaces: ComponentSurfaces | None = None,
                 deviations: Deviations | None = None) -> None:
        self.mesh = mesh
        self.components = components
        self.surfaces = surfaces
        self.deviations = deviations
        self.as_built: tuple | None = None  # what decided the deviations (set by survey.place_scanner)
        self._sensor_tables: dict[tuple, waveform.SensorTables] = {}
        self._work_buffers: dict[str, np.ndarray] = {}  # the sensor path's working arrays, kept across chunks
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
        # where the scans' time goes: "rays" (generating them), "cast" (the engine's queries); the
        # survey adds "scan" (all of it), so the rest (noise, labels, compaction) is scan - rays - cast
        self.clock = StageClock()

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The engine's ``cast`` of ``rays`` (N, 6), timed as the clock's "cast" step."""
        start = time.perf_counter()
        try:
            return self.engine.cast(rays)
        finally:
            self.clock.add("cast", time.perf_counter() - start)

    def _set_threads(self) -> None:
        if self.threads:
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))

    def scan_station(self, station: Station, recipe: StationRecipe, *, time0_s: float = 0.0,
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
        if not recipe.sensor.is_paper:
            yield from self._scan_station_sensor(station, recipe, time0_s=time0_s, on_pulses=on_pulses,
                                                 reuse_buffers=reuse_buffers)
            return
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
        for lines in pattern.line_chunks(recipe.chunk_pulses):
            n = lines.n
            if fused is not None:
                columns = self._outputs(n, reuse_buffers)
                if on_pulses is not None:
                    on_pulses(n)
                with self.clock.step("cast"):  # rays made, cast and finished in one device call
                    kept = fused(pattern, station.heading_deg, lines, hits, self._face_tables, columns)
                if kept:
                    yield self._chunk_cloud(columns, kept, registration, origin_world)
                continue
            if len(self._ray_buffer) < n:  # working buffers reused across chunks and stations
                self._ray_buffer = np.empty((n, 6), dtype=np.float32)
                self._pulse_buffer = np.empty(n, dtype=np.int64)
            rays, pulse = self._ray_buffer[:n], self._pulse_buffer[:n]
            with self.clock.step("rays"):
                pattern.fill_rays(lines, station.heading_deg, origin_local.astype(np.float32), rays, pulse)
            t_hit, triangle = self.cast(rays)
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

    def scan_pass(self, trajectory: Trajectory, part: slice, pass_id: int, mount_index: int, recipe: StationRecipe,
                  *, drift: DriftTrack | None = None, on_pulses: Callable[[int], None] | None = None,
                  reuse_buffers: bool = False) -> Iterator[PointCloud]:
        """Stream the labelled points of one pass of a mobile scan by one of its platform's lidars.

        ``recipe.mobile`` says the platform, lidar, rotation rate and drift; ``part`` selects the
        pass's samples of ``trajectory``. Pulses are numbered from the start of the pass and fire
        as the lidar's firing sequence says (``scan.multibeam``); noise is drawn per pulse number
        from the key of (seed, noise stream, pass and mount), so chunking changes nothing. The
        drift (``survey.drift``), when given, moves every point and its beam origin.
        """
        mobile = recipe.mobile
        lidar, mount = mobile.lidar, mobile.platform.mounts[mount_index]
        self._set_threads()
        t = np.ascontiguousarray(trajectory.t[part])
        xyz_track = np.ascontiguousarray(trajectory.xyz[part])
        ypr = trajectory.ypr(part)
        total = mobile.pass_pulses(float(t[-1] - t[0]))
        n_beams = lidar.n_beams
        noise = recipe.noise
        key = np.uint64(noise_key(recipe.seed, pass_id * MAX_MOUNTS + mount_index, recipe.noise_stream))
        fill_rays = _moving_ray_kernel(lidar, mobile.rotation_hz, float(trajectory.t[0]), t, xyz_track, ypr,
                                       mount.lever_arm(),
                                       np.ascontiguousarray(mount.rotation()), 2 * math.pi * mount.head_rotation_hz,
                                       np.asarray(self.engine.centre, dtype=np.float64))
        ring_of_beam = lidar.ring_of_beam()
        chunk = max(n_beams, (recipe.chunk_pulses // n_beams) * n_beams)
        for first in range(0, total, chunk):
            n = min(chunk, total - first)
            rays = self._work("mobile_rays", (n, 6), np.float32)
            origin = self._work("mobile_origin", (n, 3), np.float64)
            pulse_time = self._work("mobile_time", (n,), np.float64)
            with self.clock.step("rays"):
                fill_rays(first, n, rays, origin, pulse_time)
            t_hit, triangle = self.cast(rays)
            if on_pulses is not None:
                on_pulses(n)
            if recipe.sensor.is_paper:
                columns = self._mobile_outputs(n, reuse_buffers)
                xyz, label, component, station_column, intensity, time, ring, sensor = columns
                kept = finish_moving_hits(t_hit, triangle, rays, origin, pulse_time, np.int64(first), np.int64(n_beams),
                                          ring_of_beam, self.face_component, self.face_label, self.face_brightness,
                                          lidar.min_range_m, lidar.max_range_m, key, noise.range_sigma_m,
                                          math.radians(noise.angle_sigma_deg), INTENSITY_REFERENCE_M, pass_id, xyz,
                                          label, component, station_column, intensity, time, ring, sensor)
                cloud = PointCloud(xyz=xyz[:kept], label=label[:kept], component=component[:kept],
                                   station=station_column[:kept], intensity=intensity[:kept], time=time[:kept],
                                   ring=ring[:kept], sensor_xyz=sensor[:kept])
            else:
                cloud = self._mobile_sensor_points(recipe, first, n, rays, origin, pulse_time, t_hit, triangle, key,
                                                   pass_id, ring_of_beam)
                kept = len(cloud)
            if kept == 0:
                continue
            if drift is not None:
                drift.apply(cloud.xyz, cloud.sensor_xyz, cloud.time)
            channel = self._work("mobile_channel", (kept,), np.uint8) if reuse_buffers else np.empty(kept, np.uint8)
            channel[:] = mount_index
            yield dataclasses.replace(cloud, channel=channel)

    def _mobile_sensor_points(self, recipe: StationRecipe, first_pulse: int, n: int, rays: np.ndarray,
                              origin: np.ndarray, pulse_time: np.ndarray, t_hit: np.ndarray, triangle: np.ndarray,
                              key: np.uint64, pass_id: int, ring_of_beam: np.ndarray) -> PointCloud:
        """One chunk of a mobile scan with the sensor effects a moving lidar's pulses can have alone
        (materials, colour, geometric noise, as-built waviness: ``SensorModel.for_mobile``): the
        tripod path's kernels, with a beam origin per pulse. One echo per pulse (no footprint, no
        glass), so a pulse's return is its centre ray's hit; its noise draws are the paper path's."""
        sensor, noise, lidar = recipe.sensor, recipe.noise, recipe.mobile.lidar
        tables = self.sensor_tables(sensor)
        pulse = self._work("pulse", (n,), np.int64)
        pulse[:] = np.arange(first_pulse, first_pulse + n)  # the noise key's pulse numbers, as the paper path's
        count = self._work("count", (n,), np.int32)
        slots = sensor.max_returns if sensor.returns == "all" else 1
        n_slots = n * slots  # the gathered returns: scratch shared with the tripod path's
        out_t, out_energy = self._work("t", (n_slots,), np.float64), self._work("energy", (n_slots,), np.float32)
        out_comp, out_tri = self._work("comp", (n_slots,), np.int32), self._work("tri", (n_slots,), np.uint32)
        out_cos = self._work("cos", (n_slots,), np.float32)
        out_number, out_count_of = self._work("number", (n_slots,), np.uint8), self._work("of", (n_slots,), np.uint8)
        none_int, none_float = np.zeros(0, np.int64), np.zeros(0)
        waveform.gather_returns(
            0, n, t_hit, triangle, np.zeros(n, dtype=np.bool_), rays, pulse, np.zeros(n + 1, dtype=np.int64),
            none_int, none_int, none_float, np.zeros(0, np.uint32), np.ones(1), 2, self.face_component,
            tables.face_normal, tables.reflectance, tables.face_transparency, False, 0.0, lidar.min_range_m,
            lidar.max_range_m, 0.0, key, False, 1.0, waveform.detection_constant(sensor.speckle_cells),
            sensor.speckle_cells, waveform.MODE_CODES[sensor.returns], slots, out_t, out_comp, out_tri, out_energy,
            out_cos, out_number, out_count_of, count)
        n_out = int(count.sum())
        xyz, label, component = np.empty((n_out, 3)), np.empty(n_out, np.uint8), np.empty(n_out, np.int32)
        station, intensity, time = np.empty(n_out, np.uint16), np.empty(n_out, np.uint16), np.empty(n_out)
        number, count_of = np.empty(n_out, np.uint8), np.empty(n_out, np.uint8)
        rgb, source = np.empty((n_out, 3), np.uint8), self._work("source", (n_out,), np.int64)
        geometric = sensor.on("geometric_noise")
        waveform.finish_returns(
            0, n, slots, count, out_t, out_comp, out_tri, out_energy, out_cos, out_number, out_count_of, rays, pulse,
            origin, 1, key, noise.range_sigma_m, sensor.range_noise_ppm if geometric else 0.0, geometric,
            math.cos(math.radians(sensor.max_incidence_deg)), math.radians(noise.angle_sigma_deg), 0.0, 0.0,
            INTENSITY_REFERENCE_M, pass_id, self.component_label, tables.face_normal, sensor.on("color"), tables.color,
            sensor.color_noise, sensor.ambient, sensor.waviness_m if sensor.on("deviations") else 0.0,
            sensor.waviness_wavelength_m, tables.phase, xyz, label, component, station, intensity, time, number,
            count_of, rgb, source)
        return PointCloud(xyz=xyz, label=label, component=component, station=station, intensity=intensity,
                          time=pulse_time[source], ring=ring_of_beam[source % lidar.n_beams],
                          sensor_xyz=origin[source], rgb=rgb if sensor.on("color") else None)

    def _mobile_outputs(self, n: int, reuse: bool) -> tuple[np.ndarray, ...]:
        """Output columns of a mobile chunk: fresh, or views of kept buffers."""
        if reuse:
            return (self._work("m_xyz", (n, 3), np.float64), self._work("m_label", (n,), np.uint8),
                    self._work("m_component", (n,), np.int32), self._work("m_station", (n,), np.uint16),
                    self._work("m_intensity", (n,), np.uint16), self._work("m_time", (n,), np.float64),
                    self._work("m_ring", (n,), np.uint8), self._work("m_sensor", (n, 3), np.float64))
        return (np.empty((n, 3)), np.empty(n, np.uint8), np.empty(n, np.int32), np.empty(n, np.uint16),
                np.empty(n, np.uint16), np.empty(n), np.empty(n, np.uint8), np.empty((n, 3)))

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

    def sensor_tables(self, sensor: SensorModel) -> waveform.SensorTables:
        """Per-component and per-triangle tables of the sensor kernels for ``sensor`` (built once)."""
        from bimscan.scan.surfaces import PAPER_REFLECTANCE, glazing_faces, load_material_table, surface_table

        cache_key = (sensor.needs_surfaces, sensor.on("materials"), sensor.on("glass"), sensor.material_table)
        if cache_key not in self._sensor_tables:
            n = len(self.component_label)
            reflectance = np.full(n, PAPER_REFLECTANCE, dtype=np.float64)
            transparency = np.zeros(n)
            color = np.full((n, 3), 0.7, dtype=np.float64)
            if sensor.needs_surfaces:
                ifc_class = self.components.ifc_class if self.components is not None else np.full(n, "", dtype=str)
                ancestry = dict(self.components.class_ancestry) if self.components is not None else {}
                table = surface_table(self.surfaces, ifc_class, ancestry, load_material_table(sensor.material_table),
                                      material_reflectance=sensor.on("materials"))
                reflectance = table.reflectance.astype(np.float64)
                transparency = table.transparency.astype(np.float64) if sensor.on("glass") else transparency
                color = table.color.astype(np.float64)
            phase = self.deviations.phase if self.deviations is not None else np.zeros(n)
            normals = self.mesh.face_normals().astype(np.float32)
            face_transparency = np.ascontiguousarray(
                glazing_faces(transparency, self.face_component, self.mesh.face_transparency))
            self._sensor_tables[cache_key] = waveform.SensorTables(
                reflectance=reflectance, face_transparency=face_transparency, color=color,
                phase=np.asarray(phase, dtype=np.float64), face_normal=np.ascontiguousarray(normals),
                transparent_face=face_transparency > 0.0)
        return self._sensor_tables[cache_key]

    def _work(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """A working array of ``shape``: a view of a buffer kept for the next chunk (grown when too small)."""
        buffer = self._work_buffers.get(name)
        if buffer is None or len(buffer) < shape[0]:
            buffer = np.empty((max(shape[0], 1), *shape[1:]), dtype=dtype)
            self._work_buffers[name] = buffer
        return buffer[:shape[0]]

    def _scan_station_sensor(self, station: Station, recipe: StationRecipe, *, time0_s: float,
                             on_pulses: Callable[[int], None] | None, reuse_buffers: bool) -> Iterator[PointCloud]:
        """scan_station with the sensor effects (see ``bimscan.scan.waveform`` for the steps)."""
        sensor, noise, device = recipe.sensor, recipe.noise, self.scanner
        tables = self.sensor_tables(sensor)
        pattern = PulsePattern.of(recipe.settings, device)
        origin_world = np.asarray(station.position, dtype=np.float64)
        origin_local = (origin_world - self.engine.centre).astype(np.float32)
        key = np.uint64(noise_key(recipe.seed, station.id, recipe.noise_stream))
        registration = registration_error(noise, key) if noise.registers_with_error else None
        footprint, glass = sensor.on("footprint"), sensor.on("glass")
        adaptive = footprint and sensor.adaptive_footprint
        off, azimuth, weight = waveform.subray_pattern(sensor.beam_sample_quality if footprint else 1,
                                                       device.beam_divergence_rad)
        n_sub = len(off) - 1
        layers = sensor.max_glass_layers if glass else 0
        mode = waveform.MODE_CODES[sensor.returns]
        slots = sensor.max_returns if sensor.returns == "all" else 1
        reach_scale = device.reach_constant() * recipe.settings.pulse_freq_hz / device.reach_pulse_freq_hz
        detect_a = waveform.detection_constant(sensor.speckle_cells)
        n_faces = len(self.face_component)
        min_cos = math.cos(math.radians(sensor.max_incidence_deg))
        for first_line, stop_line in pattern.chunks(recipe.chunk_pulses):
            halo_lo = max(0, first_line - 1) if adaptive else first_line
            halo_hi = min(pattern.n_lines, stop_line + 1) if adaptive else stop_line
            start, stop = pattern.line_pulses(halo_lo, halo_hi)
            counts = stop - start
            offsets = np.zeros(len(counts) + 1, dtype=np.int64)
            np.cumsum(counts, out=offsets[1:])
            j0, j1 = first_line - halo_lo, stop_line - halo_lo
            first, n_int = int(offsets[j0]), int(offsets[j1] - offsets[j0])
            if n_int == 0:
                continue
            n_all = int(offsets[-1])
            rays = self._work("rays", (n_all, 6), np.float32)
            pulse = self._work("pulse", (n_all,), np.int64)
            with self.clock.step("rays"):
                generate_rays(start, stop, offsets[:-1], halo_lo, pattern.dphase, pattern.sweep_deg,
                              pattern.head_start_deg, pattern.head_deg_per_pulse, station.heading_deg, origin_local,
                              rays, pulse)
            t0, tri0 = self.cast(rays)
            flagged = np.zeros(n_all, dtype=np.bool_)  # pulses that get the whole sub-ray pattern
            if footprint and n_sub:
                if adaptive:
                    flagged[self._straddling(rays, t0, tri0, start, halo_lo, pattern, offsets, counts, j0, j1,
                                             sensor.edge_depth_m)] = True
                else:
                    flagged[first:first + n_int] = True
            extra = self._extra_hits(rays, t0, tri0, flagged, first, n_int, off, azimuth, tables, layers, n_faces)
            e_pulse, e_sub, e_layer, e_t, e_tri = extra
            extra_offsets = np.zeros(n_all + 1, dtype=np.int64)
            np.cumsum(np.bincount(e_pulse, minlength=n_all), out=extra_offsets[1:])
            if on_pulses is not None:
                on_pulses(n_int)
            n_slots = n_int * slots
            out_t, out_energy = self._work("t", (n_slots,), np.float64), self._work("energy", (n_slots,), np.float32)
            out_comp, out_tri = self._work("comp", (n_slots,), np.int32), self._work("tri", (n_slots,), np.uint32)
            out_cos = self._work("cos", (n_slots,), np.float32)
            out_number, out_count_of = self._work("number", (n_slots,), np.uint8), self._work("of", (n_slots,), np.uint8)
            count = self._work("count", (n_int,), np.int32)
            waveform.gather_returns(
                first, n_int, t0, tri0, flagged, rays, pulse, extra_offsets, e_sub, e_layer, e_t, e_tri, weight,
                (n_sub + 1) * (layers + 1) + 1, self.face_component, tables.face_normal, tables.reflectance,
                tables.face_transparency, glass, sensor.glass_return_probability, device.min_range_m, device.max_range_m,
                device.range_resolution_m, key, sensor.on("detection"), reach_scale, detect_a, sensor.speckle_cells,
                mode, slots, out_t, out_comp, out_tri, out_energy, out_cos, out_number, out_count_of, count)
            n_out = int(count.sum())
            if n_out == 0:
                continue
            out = self._work if reuse_buffers else (lambda _, shape, dtype: np.empty(shape, dtype))
            xyz, label, component = out("xyz", (n_out, 3), np.float64), out("label", (n_out,), np.uint8), out(
                "component", (n_out,), np.int32)
            station_column, intensity, time = out("station", (n_out,), np.uint16), out(
                "intensity", (n_out,), np.uint16), out("time", (n_out,), np.float64)
            number, count_of = out("return_number", (n_out,), np.uint8), out("number_of_returns", (n_out,), np.uint8)
            rgb = out("rgb", (n_out, 3), np.uint8)
            waveform.finish_returns(
                first, n_int, slots, count, out_t, out_comp, out_tri, out_energy, out_cos, out_number, out_count_of,
                rays, pulse, origin_world[None, :], 0, key, noise.range_sigma_m,
                sensor.range_noise_ppm if sensor.on("geometric_noise") else 0.0, sensor.on("geometric_noise"), min_cos,
                math.radians(noise.angle_sigma_deg), time0_s, 1.0 / pattern.pulse_freq_hz, INTENSITY_REFERENCE_M,
                station.id, self.component_label, tables.face_normal, sensor.on("color"), tables.color,
                sensor.color_noise, sensor.ambient, sensor.waviness_m if sensor.on("deviations") else 0.0,
                sensor.waviness_wavelength_m, tables.phase, xyz, label, component, station_column, intensity, time,
                number, count_of, rgb, self._work("source", (n_out,), np.int64))
            if registration is not None:
                rotation, shift_m = registration
                xyz = (xyz - origin_world) @ rotation.T + origin_world + shift_m
            yield PointCloud(xyz=xyz, label=label, component=component, station=station_column, intensity=intensity,
                             time=time, return_number=number, number_of_returns=count_of,
                             rgb=rgb if sensor.on("color") else None)

    def _straddling(self, rays: np.ndarray, t0: np.ndarray, tri0: np.ndarray, start: np.ndarray, line0: int,
                    pattern: PulsePattern, offsets: np.ndarray, counts: np.ndarray, j0: int, j1: int,
                    edge_depth_m: float) -> np.ndarray:
        """Indices of the pulses of lines j0..j1-1 whose footprint straddles an edge: a neighbour in the
        scan grid disagrees (``waveform.flag_edges``), and a probe ray at the footprint's edge towards
        that neighbour meets another surface than the centre ray (``waveform.straddling``)."""
        device = self.scanner
        phase0 = start * pattern.dphase - (line0 + np.arange(len(start)))
        shift = np.zeros(len(start), dtype=np.int64)
        shift[:-1] = np.rint((phase0[:-1] - phase0[1:]) / pattern.dphase).astype(np.int64)
        bits = np.zeros(len(t0), dtype=np.uint8)
        waveform.flag_edges(t0, tri0, self.face_component, device.min_range_m, device.max_range_m, offsets[:-1],
                            counts, shift, j0, j1, edge_depth_m, bits)
        candidates = np.flatnonzero(bits)
        if len(candidates) == 0:
            return candidates
        probe_bits = bits[candidates]
        probe_offsets = np.zeros(len(candidates) + 1, dtype=np.int64)
        np.cumsum(_POPCOUNT[probe_bits], out=probe_offsets[1:])
        probes = np.empty((int(probe_offsets[-1]), 6), dtype=np.float32)
        waveform.probe_rays(rays, candidates, probe_bits, probe_offsets, device.beam_divergence_rad / 2.0, probes)
        t_probe, tri_probe = self.cast(probes)
        return candidates[waveform.straddling(candidates, probe_offsets, t0, tri0, t_probe, tri_probe,
                                              self.face_component, device.min_range_m, device.max_range_m,
                                              edge_depth_m)]

    def _extra_hits(self, rays: np.ndarray, t0: np.ndarray, tri0: np.ndarray, flagged: np.ndarray, first: int,
                    n_int: int, off: np.ndarray, azimuth: np.ndarray, tables: waveform.SensorTables, layers: int,
                    n_faces: int) -> tuple[np.ndarray, ...]:
        """Hits besides each pulse's centre hit, sorted by (pulse, sub-ray, layer): the centre ray's hits
        behind transparent surfaces, the flagged pulses' sub-ray hits and theirs behind glass.

        Returns (ray index (K,) int64, sub-ray (K,) int64, layer (K,) int64, range (K,) float64,
        triangle (K,) uint32).
        """
        n_sub = len(off) - 1
        parts = []
        if layers:
            centre = slice(first, first + n_int)
            index, layer, t, tri = waveform.cast_layers(self, rays[centre], t0[centre], tri0[centre],
                                                        tables.transparent_face, layers)
            parts.append((index + first, np.zeros(len(index), np.int64), layer, t, tri))
        flagged_index = np.flatnonzero(flagged)
        if n_sub and len(flagged_index):
            sub_rays = np.empty((len(flagged_index) * n_sub, 6), dtype=np.float32)
            waveform.footprint_rays(rays, flagged_index, np.cos(off[1:]), np.sin(off[1:]), np.cos(azimuth[1:]),
                                    np.sin(azimuth[1:]), sub_rays)
            t_sub, tri_sub = self.cast(sub_rays)
            sub_pulse = np.repeat(flagged_index, n_sub)
            sub_id = np.tile(np.arange(1, n_sub + 1, dtype=np.int64), len(flagged_index))
            hit = tri_sub < n_faces
            parts.append((sub_pulse[hit], sub_id[hit], np.zeros(int(hit.sum()), np.int64),
                          t_sub[hit].astype(np.float64), tri_sub[hit]))
            if layers:
                index, layer, t, tri = waveform.cast_layers(self, sub_rays, t_sub, tri_sub,
                                                            tables.transparent_face, layers)
                parts.append((sub_pulse[index], sub_id[index], layer, t, tri))
        if not parts:
            return (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0),
                    np.zeros(0, np.uint32))
        e_pulse, e_sub, e_layer, e_t, e_tri = (np.concatenate(column) for column in zip(*parts))
        if len(parts) > 1 or layers:
            order = np.argsort((e_pulse * (n_sub + 1) + e_sub) * (layers + 1) + e_layer, kind="stable")
            e_pulse, e_sub, e_layer, e_t, e_tri = e_pulse[order], e_sub[order], e_layer[order], e_t[order], e_tri[order]
        return (np.ascontiguousarray(e_pulse), np.ascontiguousarray(e_sub), np.ascontiguousarray(e_layer),
                np.ascontiguousarray(e_t, dtype=np.float64), np.ascontiguousarray(e_tri, dtype=np.uint32))

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


def _moving_ray_kernel(lidar: Lidar, rotation_hz: float | None, clock_origin: float, track_t: np.ndarray,
                       track_xyz: np.ndarray, track_ypr: np.ndarray, lever: np.ndarray, mount_rotation: np.ndarray,
                       head_rad_s: float, centre: np.ndarray) -> Callable[[int, int, np.ndarray, np.ndarray, np.ndarray], None]:
    """fill(first, n, rays, origin, time): the rays of pulses first .. first + n - 1 of a pass along the
    track, for the lidar's kind (a spinning multi-beam lidar's or a Risley scanner's kernel, its
    prisms' clock starting at ``clock_origin``, the trajectory's first time)."""
    cycle_s, n_beams, t0 = lidar.firing_cycle_us * 1e-6, np.int64(lidar.n_beams), float(track_t[0])
    if isinstance(lidar, RisleyScanner):
        prisms, spin, incident = lidar.prism_table(), lidar.spin_table(), lidar.incident()

        def fill(first: int, n: int, rays: np.ndarray, origin: np.ndarray, time: np.ndarray) -> None:
            risley_rays(np.int64(first), np.int64(n), n_beams, cycle_s, t0, clock_origin, prisms, spin, incident,
                        track_t, track_xyz, track_ypr, lever, mount_rotation, head_rad_s, centre, rays, origin, time)
        return fill
    firing = np.asarray(lidar.firing_offset_us, dtype=np.float64) * 1e-6
    elevation = np.radians(np.asarray(lidar.beam_elevation_deg, dtype=np.float64))
    cos_el, sin_el = np.cos(elevation), np.sin(elevation)
    azimuth_offset = np.radians(np.asarray(lidar.beam_azimuth_offset_deg, dtype=np.float64))

    def fill(first: int, n: int, rays: np.ndarray, origin: np.ndarray, time: np.ndarray) -> None:
        moving_rays(np.int64(first), np.int64(n), n_beams, cycle_s, t0, firing, cos_el, sin_el, azimuth_offset,
                    2 * math.pi * rotation_hz, track_t, track_xyz, track_ypr, lever, mount_rotation, head_rad_s,
                    centre, rays, origin, time)
    return fill

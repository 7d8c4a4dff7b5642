"""NVIDIA Warp ray engine: one BVH (``wp.Mesh``) per scene on a CUDA GPU or Warp's CPU device.

``WarpEngine.cast`` is the engine interface of ``scan.engine`` (rays in, first hits out): what
station planning, probes and the host-finished paths use. ``WarpEngine.cast_and_finish`` is the
fused scan path: three kernel launches per chunk of mirror lines, all on the device,

1. ``_generate_and_cast``: one thread per pulse makes its ray (the mirror and head angles of
   ``kernels.generate_rays``), casts it with ``wp.mesh_query_ray`` and flags whether the hit is
   kept (a true range in [min_range, max_range]);
2. an inclusive prefix sum of the flags (``wp.utils.array_scan``): each kept hit's output row,
   so the points keep the order of their rays, as the CPU path's block compaction does;
3. ``_finish``: the per-hit work of ``kernels.finish_hits`` (range and angle noise, xyz, label,
   component, intensity, station, time) written straight to the output rows,

and only the finished rows come back to the host. The noise is the CPU path's generator:
SplitMix64 counters keyed by ``kernels.noise_key`` (computed on the host) and indexed by the
pulse number, turned into normal deviates through the same quantile tables, so a scan equals the
CPU engines' scan to the float32 rounding of hit distances (tests/scan/test_warp_engine.py).
The arithmetic after the cast is float64, as on the CPU.

Warp compiles this module's kernels on first use (its bundled Clang for the CPU device, NVRTC
for CUDA) and caches them under ``wp.config.kernel_cache_dir`` (``~/.cache/warp/<version>``;
the environment variable ``WARP_CACHE_PATH`` moves it). Warp's CPU device runs a kernel on one
core: it is the path CI tests run on, not a fast one.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from bimscan.errors import ConfigError
from bimscan.scan.engine import MISS, FaceTables, HitSettings, mesh_centre
from bimscan.scan.kernels import _QUANTILE_GRID, _QUANTILE_SMALL, _SUB, _SUB_BITS
from bimscan.scan.pattern import LineChunk, PulsePattern
from bimscan.types import SceneMesh

wp.config.log_level = wp.LOG_WARNING  # no banner and no "module loaded" lines: bimscan reports its own progress
# forward kernels only: no adjoints to generate and compile (about half the compile time)
wp.set_module_options({"enable_backward": False})


def _init_warp() -> None:
    """Start Warp with what its native library prints (``Warp CUDA warning: ...`` on stdout or
    stderr, past Python's streams) caught at the file descriptors and passed on as Python
    warnings, which the CLI prints as ``warning:`` lines like every other."""
    import ctypes
    import os
    import sys
    import tempfile
    import warnings

    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryFile() as capture:
        saved = (os.dup(1), os.dup(2))
        os.dup2(capture.fileno(), 1)
        os.dup2(capture.fileno(), 2)
        try:
            wp.init()
        finally:
            try:
                ctypes.CDLL(None).fflush(None)  # C streams buffer when not a terminal
            except (OSError, AttributeError):
                pass
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
        capture.seek(0)
        printed = capture.read().decode("utf-8", "replace")
    for line in printed.splitlines():
        line = line.strip()
        if line:
            warnings.warn(line.replace("Warp CUDA warning:", "Warp:", 1), stacklevel=2)


_init_warp()

# The generator's constants (kernels.py): SplitMix64 and the key mixing.
_GOLDEN = wp.constant(wp.uint64(0x9E3779B97F4A7C15))
_STREAM = wp.constant(wp.uint64(0xD1B54A32D192ED03))
_M1 = wp.constant(wp.uint64(0xBF58476D1CE4E5B9))
_M2 = wp.constant(wp.uint64(0x94D049BB133111EB))
_LOW32 = wp.constant(wp.uint64(0xFFFFFFFF))
_HALF32 = wp.constant(wp.uint64(0x80000000))
_SUB_W = wp.constant(_SUB)
_SUB_BITS_W = wp.constant(_SUB_BITS)
_DEG = wp.constant(wp.float64(math.pi / 180.0))
_NO_HIT = wp.constant(wp.float32(math.inf))
_MISS_W = wp.constant(wp.uint32(int(MISS)))
# The largest ray length the query is given where no range limit applies (float32 max).
_FAR = float(np.finfo(np.float32).max)


@wp.func
def _mix64(z: wp.uint64) -> wp.uint64:
    """SplitMix64 finaliser (kernels._mix64): unsigned 64-bit products wrap as in NumPy."""
    a = (z ^ (z >> wp.uint64(30))) * _M1
    b = (a ^ (a >> wp.uint64(27))) * _M2
    return b ^ (b >> wp.uint64(31))


@wp.func
def _floor_log2(b: wp.uint32) -> wp.int32:
    """Index of the highest set bit of b > 0 (31 minus its leading zeros), by halving."""
    e = wp.int32(0)
    x = b
    if x >= wp.uint32(65536):
        x = x >> wp.uint32(16)
        e = e + 16
    if x >= wp.uint32(256):
        x = x >> wp.uint32(8)
        e = e + 8
    if x >= wp.uint32(16):
        x = x >> wp.uint32(4)
        e = e + 4
    if x >= wp.uint32(4):
        x = x >> wp.uint32(2)
        e = e + 2
    if x >= wp.uint32(2):
        e = e + 1
    return e


@wp.func
def _normal_from_bits(bits: wp.uint64, grid: wp.array2d(dtype=wp.float64),
                      small: wp.array(dtype=wp.float64)) -> wp.float64:
    """Standard normal quantile of (bits + 0.5) / 2^32 (kernels._normal_from_bits, same tables)."""
    upper = bits >= _HALF32
    b = wp.uint32(bits)
    if upper:
        b = wp.uint32(_LOW32 - bits)
    z = wp.float64(0.0)
    if b < wp.uint32(2 * _SUB_W):
        z = small[wp.int32(b)]
    else:
        e = _floor_log2(b)
        shift = wp.uint32(e - _SUB_BITS_W)
        m = wp.int32(b >> shift) - _SUB_W
        base = wp.uint32(_SUB_W + m) << shift
        f = wp.float64(b - base) / wp.float64(wp.uint32(1) << shift)
        z0 = grid[e, m]
        z = z0 + f * (grid[e, m + 1] - z0)
    if upper:
        z = -z
    return z


@wp.func
def _small_sincos(a: wp.float64) -> wp.vec2d:
    """(sin a, cos a); the Taylor series of kernels._small_sincos below 0.05 rad."""
    if wp.abs(a) < wp.float64(0.05):
        a2 = a * a
        s = a * (wp.float64(1.0) - a2 * (wp.float64(1.0 / 6.0) - a2 * wp.float64(1.0 / 120.0)))
        c = wp.float64(1.0) - a2 * (wp.float64(0.5) - a2 * (wp.float64(1.0 / 24.0) - a2 * wp.float64(1.0 / 720.0)))
        return wp.vec2d(s, c)
    return wp.vec2d(wp.sin(a), wp.cos(a))


@wp.kernel
def _cast(mesh: wp.uint64, rays: wp.array2d(dtype=wp.float32), max_t: wp.float32,
          t_hit: wp.array(dtype=wp.float32), face: wp.array(dtype=wp.uint32)):
    """First hit of each ray (N, 6): distance (inf for a miss) and triangle (MISS for a miss)."""
    i = wp.tid()
    origin = wp.vec3(rays[i, 0], rays[i, 1], rays[i, 2])
    direction = wp.vec3(rays[i, 3], rays[i, 4], rays[i, 5])
    query = wp.mesh_query_ray(mesh, origin, direction, max_t)
    if query.result:
        t_hit[i] = query.t
        face[i] = wp.uint32(query.face)
    else:
        t_hit[i] = _NO_HIT
        face[i] = _MISS_W


@wp.kernel
def _generate_and_cast(mesh: wp.uint64, start: wp.array(dtype=wp.int64), count: wp.array(dtype=wp.int32),
                       offsets: wp.array(dtype=wp.int32), line0: wp.int64, dphase: wp.float64,
                       sweep_deg: wp.float64, head_deg: wp.float64, head_deg_per_pulse: wp.float64,
                       origin: wp.vec3, max_t: wp.float32, min_range_m: wp.float64, max_range_m: wp.float64,
                       direction: wp.array(dtype=wp.vec3), pulse: wp.array(dtype=wp.int64),
                       t_hit: wp.array(dtype=wp.float32), face: wp.array(dtype=wp.int32),
                       kept: wp.array(dtype=wp.int32)):
    """Pulse m of line j (a 2-D launch over lines and pulses): its ray, first hit and kept flag.

    The angles are kernels.generate_rays' (elevation from the mirror phase of the line's first
    pulse plus m steps, azimuth from the head angle), computed directly rather than by its
    rotation recurrence; both are exact to ~1e-13 rad, far below the float32 rounding of the
    direction.
    """
    j, m = wp.tid()
    if m >= count[j]:
        return
    first = start[j]
    r = offsets[j] + m
    phase = wp.float64(first) * dphase - wp.float64(line0 + wp.int64(j))
    el = (wp.float64(-0.5) * sweep_deg + sweep_deg * phase) * _DEG + wp.float64(m) * (sweep_deg * dphase * _DEG)
    az = (head_deg + wp.float64(first) * head_deg_per_pulse) * _DEG + wp.float64(m) * (head_deg_per_pulse * _DEG)
    ce = wp.cos(el)
    d = wp.vec3(wp.float32(ce * wp.cos(az)), wp.float32(ce * wp.sin(az)), wp.float32(wp.sin(el)))
    direction[r] = d
    pulse[r] = first + wp.int64(m)
    query = wp.mesh_query_ray(mesh, origin, d, max_t)
    keep = wp.int32(0)
    if query.result:
        t_hit[r] = query.t
        face[r] = query.face
        t = wp.float64(query.t)
        if t >= min_range_m and t <= max_range_m:
            keep = wp.int32(1)
    kept[r] = keep


@wp.kernel
def _finish(kept: wp.array(dtype=wp.int32), row: wp.array(dtype=wp.int32), t_hit: wp.array(dtype=wp.float32),
            face: wp.array(dtype=wp.int32), direction: wp.array(dtype=wp.vec3), pulse: wp.array(dtype=wp.int64),
            face_component: wp.array(dtype=wp.int32), face_label: wp.array(dtype=wp.uint8),
            face_brightness: wp.array(dtype=wp.vec3), grid: wp.array2d(dtype=wp.float64),
            small: wp.array(dtype=wp.float64), origin: wp.vec3d, key: wp.uint64, range_sigma_m: wp.float64,
            angle_sigma_rad: wp.float64, time0_s: wp.float64, pulse_period_s: wp.float64,
            intensity_ref_m: wp.float64, station_id: wp.uint16,
            xyz: wp.array(dtype=wp.vec3d), label: wp.array(dtype=wp.uint8), component: wp.array(dtype=wp.int32),
            station: wp.array(dtype=wp.uint16), intensity: wp.array(dtype=wp.uint16),
            time: wp.array(dtype=wp.float64)):
    """kernels.finish_hits for one kept hit, written to row (inclusive prefix sum) - 1.

    Range gets N(0, range_sigma) along the beam; the recorded azimuth and elevation get
    N(0, angle_sigma) each; xyz = origin + measured range * direction(recorded angles).
    Intensity = 65535 * reflectance * |cos(incidence)| * min(1, (ref / range)^2).
    """
    i = wp.tid()
    if kept[i] == 0:
        return
    out = row[i] - 1
    t = wp.float64(t_hit[i])
    tri = face[i]
    d = direction[i]
    dx = wp.float64(d[0])
    dy = wp.float64(d[1])
    dz = wp.float64(d[2])
    p = pulse[i]
    r = t
    mx = dx
    my = dy
    mz = dz
    if range_sigma_m > wp.float64(0.0) or angle_sigma_rad > wp.float64(0.0):
        # kernels._pulse_normals: three deviates from two 64-bit hashes of (key, pulse)
        k = key ^ (wp.uint64(p) * _GOLDEN)
        h0 = _mix64(k)
        h1 = _mix64(k ^ _STREAM)
        n_range = _normal_from_bits(h0 >> wp.uint64(32), grid, small)
        n_az = _normal_from_bits(h0 & _LOW32, grid, small)
        n_el = _normal_from_bits(h1 >> wp.uint64(32), grid, small)
        r = t + range_sigma_m * n_range
        # turn the azimuth, then the elevation (as finish_hits)
        a = _small_sincos(angle_sigma_rad * n_az)
        hx = dx * a[1] - dy * a[0]
        hy = dy * a[1] + dx * a[0]
        e = _small_sincos(angle_sigma_rad * n_el)
        ce = wp.sqrt(dx * dx + dy * dy)
        scale = wp.float64(1.0)
        if ce > wp.float64(1e-12):
            scale = e[1] - dz * e[0] / ce
        mx = hx * scale
        my = hy * scale
        mz = dz * e[1] + ce * e[0]
    xyz[out] = wp.vec3d(origin[0] + r * mx, origin[1] + r * my, origin[2] + r * mz)
    component[out] = face_component[tri]
    label[out] = face_label[tri]
    fall = wp.min(wp.float64(1.0), intensity_ref_m / t)
    b = face_brightness[tri]
    value = wp.abs(dx * wp.float64(b[0]) + dy * wp.float64(b[1]) + dz * wp.float64(b[2])) * fall * fall
    intensity[out] = wp.uint16(wp.int32(wp.min(wp.float64(65535.0), wp.max(wp.float64(0.0), value + wp.float64(0.5)))))
    station[out] = station_id
    time[out] = time0_s + wp.float64(p) * pulse_period_s


def cuda_available() -> bool:
    """Whether Warp sees a CUDA device (initialises Warp)."""
    return wp.is_cuda_available()


def default_device() -> str:
    """Where a WarpEngine runs unless told: the first CUDA device, else Warp's CPU device."""
    return "cuda:0" if wp.is_cuda_available() else "cpu"


def _grow(buffers: dict[str, wp.array], name: str, n: int, dtype: type, device: wp.Device) -> wp.array:
    """The first n rows of a reusable device buffer (reallocated, 25 % larger, when too small)."""
    array = buffers.get(name)
    if array is None or len(array) < n:
        array = wp.empty(max(n, int(n * 1.25)), dtype=dtype, device=device)
        buffers[name] = array
    return array[:n]


class WarpEngine:
    """Warp's BVH over the scene mesh on ``device`` ("cuda:0", "cpu"; default: CUDA if visible).

    The mesh is uploaded and its BVH built (SAH) once; ``cast`` and ``cast_and_finish`` then only
    move rays in and hits or points out. ``threads`` is accepted for the engine interface and
    unused: a Warp launch uses the whole GPU, or one core on the CPU device.
    """

    name = "warp"

    def __init__(self, mesh: SceneMesh, *, threads: int = 0, device: str | None = None) -> None:
        del threads
        self.device = wp.get_device(device or default_device())
        self.centre = mesh_centre(mesh)
        self.n_faces = int(mesh.n_triangles)
        vertices = np.ascontiguousarray(mesh.vertices - self.centre, dtype=np.float32)
        faces = np.ascontiguousarray(mesh.faces, dtype=np.int32).reshape(-1)
        self._points = wp.array(vertices, dtype=wp.vec3, device=self.device)
        self._indices = wp.array(faces, dtype=wp.int32, device=self.device)
        self._mesh = wp.Mesh(points=self._points, indices=self._indices, bvh_constructor="sah")
        self._grid = wp.array(_QUANTILE_GRID, dtype=wp.float64, device=self.device)
        self._small = wp.array(_QUANTILE_SMALL, dtype=wp.float64, device=self.device)
        self._face_component = np.ascontiguousarray(mesh.face_component, dtype=np.int32)
        self._faces: FaceTables | None = None
        self._face_arrays: tuple[wp.array, wp.array, wp.array] | None = None
        self._buffers: dict[str, wp.array] = {}

    @property
    def on_cpu(self) -> bool:
        return self.device.is_cpu

    def _to_device(self, array: np.ndarray, dtype: type) -> wp.array:
        """A device array of ``array``: a view of its memory on the CPU device, a copy on CUDA."""
        return wp.array(np.ascontiguousarray(array), dtype=dtype, device=self.device, copy=not self.on_cpu)

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """rays (N, 6) float32 local -> (t_hit (N,) float32, inf for a miss; triangle (N,) uint32, MISS)."""
        rays = np.ascontiguousarray(rays, dtype=np.float32)
        t_hit = np.empty(len(rays), dtype=np.float32)
        triangle = np.empty(len(rays), dtype=np.uint32)
        if len(rays) == 0:
            return t_hit, triangle
        device_rays = self._to_device(rays, wp.float32)
        if self.on_cpu:
            self.query(device_rays, wp.array(t_hit, device="cpu", copy=False), wp.array(triangle, device="cpu", copy=False))
            return t_hit, triangle
        device_t = wp.empty(len(rays), dtype=wp.float32, device=self.device)
        device_face = wp.empty(len(rays), dtype=wp.uint32, device=self.device)
        self.query(device_rays, device_t, device_face)
        return device_t.numpy(), device_face.numpy()

    def query(self, rays: wp.array, t_hit: wp.array, face: wp.array, *, max_t: float = _FAR) -> None:
        """``cast`` on arrays already on the device: rays (N, 6) float32 -> t_hit (N,) float32,
        face (N,) uint32 (asynchronous on CUDA; for benchmarks of the raw query)."""
        wp.launch(_cast, dim=rays.shape[0], inputs=[self._mesh.id, rays, max_t], outputs=[t_hit, face],
                  device=self.device)

    def empty_outputs(self, n: int) -> tuple[np.ndarray, ...]:
        """Output columns for n rays (as ``cast_and_finish`` takes them) that the scanner keeps
        for its next chunks: page-locked host memory on CUDA (device-to-host copies run at full
        bus speed only into it), plain NumPy arrays on the CPU device."""
        shapes = (((n, 3), np.float64), (n, np.uint8), (n, np.int32), (n, np.uint16), (n, np.uint16), (n, np.float64))
        if self.on_cpu:
            return tuple(np.empty(shape, dtype=dtype) for shape, dtype in shapes)
        # the NumPy views keep their Warp arrays (and so the pinned memory) alive
        return tuple(wp.empty(shape, dtype=wp.dtype_from_numpy(np.dtype(dtype)), device="cpu", pinned=True).numpy()
                     for shape, dtype in shapes)

    def _device_faces(self, faces: FaceTables) -> tuple[wp.array, wp.array, wp.array]:
        """Device copies of the per-triangle tables (uploaded once per FaceTables object)."""
        if faces is self._faces and self._face_arrays is not None:
            return self._face_arrays
        if len(faces.component) != self.n_faces:
            raise ConfigError(f"face tables of {len(faces.component)} triangles for a mesh of {self.n_faces}")
        self._face_arrays = (
            wp.array(np.ascontiguousarray(faces.component, dtype=np.int32), dtype=wp.int32, device=self.device),
            wp.array(np.ascontiguousarray(faces.label, dtype=np.uint8), dtype=wp.uint8, device=self.device),
            wp.array(np.ascontiguousarray(faces.brightness, dtype=np.float32), dtype=wp.vec3, device=self.device))
        self._faces = faces
        return self._face_arrays

    def cast_and_finish(self, pattern: PulsePattern, heading_deg: float, lines: LineChunk, hits: HitSettings,
                        faces: FaceTables, outputs: tuple[np.ndarray, ...]) -> int:
        """The fused scan path of one chunk: rays, cast, per-hit work on the device.

        outputs: (xyz (n, 3) float64, label (n,) uint8, component (n,) int32, station (n,)
        uint16, intensity (n,) uint16, time (n,) float64), n >= lines.n; the first ``kept``
        rows are filled, in ray order, exactly as ``kernels.finish_hits`` fills them.
        Returns ``kept``.
        """
        n = lines.n
        if n == 0:
            return 0
        if n >= 2**31:
            raise ConfigError(f"a chunk of {n:,} rays is too large for the Warp engine; lower chunk_pulses below 2^31")
        device = self.device
        counts = (lines.stop - lines.start).astype(np.int32)
        width = int(counts.max())
        start = self._to_device(lines.start.astype(np.int64), wp.int64)
        count = self._to_device(counts, wp.int32)
        offsets = self._to_device(lines.offsets.astype(np.int32), wp.int32)
        b = self._buffers
        direction = _grow(b, "direction", n, wp.vec3, device)
        pulse = _grow(b, "pulse", n, wp.int64, device)
        t_hit = _grow(b, "t_hit", n, wp.float32, device)
        face = _grow(b, "face", n, wp.int32, device)
        kept = _grow(b, "kept", n, wp.int32, device)
        row = _grow(b, "row", n, wp.int32, device)
        # the query needs no hit beyond the maximum range (a first hit further away is dropped
        # anyway): a shorter ray prunes the BVH walk; the margin keeps hits at max_range exactly
        max_t = float(np.nextafter(np.float32(hits.max_range_m * (1 + 1e-6)), np.float32(np.inf)))
        wp.launch(_generate_and_cast, dim=(len(counts), width), device=device, inputs=[
            self._mesh.id, start, count, offsets, int(lines.first_line), pattern.dphase, pattern.sweep_deg,
            pattern.head_start_deg + heading_deg, pattern.head_deg_per_pulse,
            wp.vec3(*(float(v) for v in hits.origin_local)), max_t, hits.min_range_m, hits.max_range_m,
        ], outputs=[direction, pulse, t_hit, face, kept])
        wp.utils.array_scan(kept, row, inclusive=True)
        total = int(row[n - 1:n].numpy()[0])
        if total == 0:
            return 0
        xyz, label, component, station, intensity, time = outputs
        host = (xyz, label, component, station, intensity, time)
        dtypes = (wp.vec3d, wp.uint8, wp.int32, wp.uint16, wp.uint16, wp.float64)
        if self.on_cpu:  # the kernel writes straight into the NumPy outputs
            targets = [wp.array(h, dtype=dt, device=device, copy=False) for h, dt in zip(host, dtypes)]
        else:
            targets = [_grow(b, f"out{k}", total, dt, device) for k, dt in enumerate(dtypes)]
        component_table, label_table, brightness_table = self._device_faces(faces)
        wp.launch(_finish, dim=n, device=device, inputs=[
            kept, row, t_hit, face, direction, pulse, component_table, label_table, brightness_table, self._grid,
            self._small, wp.vec3d(*(float(v) for v in hits.origin_world)), wp.uint64(int(hits.key)), hits.range_sigma_m,
            hits.angle_sigma_rad, hits.time0_s, hits.pulse_period_s, hits.intensity_ref_m, wp.uint16(hits.station_id),
        ], outputs=targets)
        if not self.on_cpu:
            for h, source, dt in zip(host, targets, dtypes):
                wp.copy(wp.array(h[:total], dtype=dt, device="cpu", copy=False), source, count=total)
            wp.synchronize_device(device)
        return total

"""The Warp engine's fused device path: rays, cast and per-hit work on the device give the CPU
path's points (same order, labels, components, stations, times; xyz to float32 rounding of the
hit distances); ``auto`` resolves once and is recorded. Runs on Warp's CPU device (CI); the
``gpu`` tests compare a CUDA device with it where one is present.
"""

from __future__ import annotations

import dataclasses
import importlib.util

import numpy as np
import pytest

from bimscan.pipeline import load_scene, scan_model
from bimscan.scan import engine as engine_module
from bimscan.scan.device import SCANNERS, ScanSettings
from bimscan.scan.engine import Open3DEngine, RayEngine, resolve_engine
from bimscan.scan.noise import NoiseModel
from bimscan.survey.recipe import ScanRecipe
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.types import PointCloud, Station
from bimscan.io import read_cloud, read_cloud_header

if importlib.util.find_spec("warp") is None:
    pytest.skip("NVIDIA Warp is not installed (pip install 'bimscan[gpu]')", allow_module_level=True)

from bimscan.scan.warp_engine import WarpEngine, cuda_available  # noqa: E402 (after the skip)

VZ400 = SCANNERS["riegl_vz400"]
SETTINGS = ScanSettings(pulse_freq_hz=60000, scan_freq_hz=100, head_deg_per_s=36)  # 250,000 pulses
STATION = Station(id=3, position=(4.0, 3.0, 1.7), heading_deg=20.0)
# every noise the fused kernel draws, and the registration error applied after it
NOISE = NoiseModel(range_sigma_m=0.005, angle_sigma_deg=0.03, registration_sigma_m=0.003, registration_sigma_deg=0.02)
needs_cuda = pytest.mark.skipif(not cuda_available(), reason="no CUDA device visible to Warp (GPU tests run on a GPU machine)")


class HostFinished:
    """An engine's cast alone (no fused path): the scanner then finishes hits on the host."""

    def __init__(self, engine: RayEngine) -> None:
        self.engine = engine
        self.name = engine.name
        self.centre = engine.centre

    def cast(self, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.engine.cast(rays)


@pytest.fixture(scope="module")
def room(box_room_ifc):
    return load_scene(box_room_ifc)


@pytest.fixture(scope="module")
def warp_cpu(room) -> WarpEngine:
    """One engine on Warp's CPU device per module: its kernels compile (or load from Warp's cache) once."""
    return WarpEngine(room.mesh, device="cpu")


def scan(room, engine, *, station: Station = STATION, scanner=VZ400, time0_s: float = 0.0, **fields) -> PointCloud:
    recipe = ScanRecipe(scanner=scanner, **({"settings": SETTINGS, "preset": None, "noise": NOISE, "seed": 7} | fields))
    virtual = VirtualScanner(room.mesh, room.components.label, scanner=scanner, engine=engine)
    return PointCloud.concatenate(list(virtual.scan_station(station, recipe, time0_s=time0_s)))


def assert_same_points(cloud: PointCloud, reference: PointCloud, *, xyz_m: float) -> None:
    assert len(cloud) == len(reference) > 0
    assert np.abs(cloud.xyz - reference.xyz).max() <= xyz_m
    for column in ("label", "component", "station"):
        assert np.array_equal(getattr(cloud, column), getattr(reference, column)), column
    # the same pulses in the same order (pulses are >= 1 microsecond apart; a time differs from the
    # CPU's at most in its last bit, where one side fuses time0 + pulse * period into one FMA)
    assert np.abs(cloud.time - reference.time).max() < 1e-9
    # intensity rounds a float64 product to uint16: the last bit of a different contraction may
    # move a value sitting on .5 by one count
    difference = np.abs(cloud.intensity.astype(int) - reference.intensity)
    assert difference.max() <= 1 and (difference > 0).mean() < 1e-3


def test_the_fused_path_writes_what_host_finishing_writes_from_the_same_hits(room, warp_cpu):
    assert hasattr(warp_cpu, "cast_and_finish")
    fused = scan(room, warp_cpu, time0_s=12.5)
    host = scan(room, HostFinished(warp_cpu), time0_s=12.5)
    assert_same_points(fused, host, xyz_m=1e-8)  # the same float32 hits: only float64 rounding differs
    assert fused.time.min() >= 12.5 and (fused.station == STATION.id).all()


def test_the_fused_path_equals_the_open3d_scan_to_float32_rounding(room, warp_cpu):
    assert_same_points(scan(room, warp_cpu), scan(room, "open3d"), xyz_m=1e-5)


def scan_reusing_buffers(room, engine, **fields) -> PointCloud:
    """A scan whose chunks share output buffers (as the pipeline runs it), each chunk copied out."""
    recipe = ScanRecipe(scanner=VZ400, **({"settings": SETTINGS, "preset": None, "noise": NOISE, "seed": 7} | fields))
    virtual = VirtualScanner(room.mesh, room.components.label, scanner=VZ400, engine=engine)
    chunks = virtual.scan_station(STATION, recipe, reuse_buffers=True)
    return PointCloud.concatenate([PointCloud(**{c: None if getattr(chunk, c) is None else getattr(chunk, c).copy()
                                                 for c in PointCloud.COLUMNS}) for chunk in chunks])


def test_the_fused_path_does_not_depend_on_the_chunk_size_or_reused_buffers(room, warp_cpu):
    whole = scan(room, warp_cpu)
    for chunked in (scan(room, warp_cpu, chunk_pulses=9_000), scan_reusing_buffers(room, warp_cpu, chunk_pulses=9_000)):
        for column in PointCloud.COLUMNS:
            assert np.array_equal(getattr(whole, column), getattr(chunked, column)), column


def test_the_fused_path_drops_hits_beyond_the_range_limits_as_the_cpu_path_does(room, warp_cpu):
    short = dataclasses.replace(VZ400, max_range_m=3.5)
    noiseless = NoiseModel.off()
    fused = scan(room, warp_cpu, scanner=short, noise=noiseless)
    assert 0 < len(fused) < SETTINGS.expected_pulses(VZ400)
    ranges = np.linalg.norm(fused.xyz - np.array(STATION.position), axis=1)
    assert ranges.max() <= 3.5 + 1e-5 and ranges.min() >= short.min_range_m - 1e-5
    assert_same_points(fused, scan(room, "open3d", scanner=short, noise=noiseless), xyz_m=1e-5)


def test_rays_leaving_an_open_model_give_no_points_on_the_fused_path(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(-5, -5, -0.3), size=(10, 10, 0.3))
    model.add_box("IfcWall", origin=(-5, 3, 0), size=(10, 0.2, 3))
    scene = load_scene(model.write(tmp_path / "open.ifc"))
    station = Station(id=0, position=(0.0, 0.0, 1.7))
    fused = scan(scene, WarpEngine(scene.mesh, device="cpu"), station=station)
    assert 0 < len(fused) < SETTINGS.expected_pulses(VZ400)
    assert_same_points(fused, scan(scene, Open3DEngine(scene.mesh), station=station), xyz_m=1e-5)


def test_auto_picks_warp_only_where_warp_sees_a_cuda_device(monkeypatch):
    monkeypatch.setattr(engine_module, "warp_sees_cuda", lambda: True)
    assert resolve_engine("auto") == "warp"
    assert ScanRecipe(engine="auto").engine == "warp"
    monkeypatch.setattr(engine_module, "warp_sees_cuda", lambda: False)
    assert resolve_engine("auto") == "open3d"
    recipe = ScanRecipe(engine="auto")
    assert recipe.engine == "open3d" and recipe.to_json()["engine"] == "open3d"
    assert recipe.fingerprint() == ScanRecipe(engine="open3d").fingerprint()
    assert resolve_engine("warp") == "warp"


def test_a_scan_with_the_warp_engine_records_it_and_lands_on_the_room_faces(box_room_ifc, tmp_path):
    recipe = ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, seed=1, engine="warp", noise=NoiseModel.off())
    out = scan_model(box_room_ifc, tmp_path / "room.laz", recipe, progress=False).path
    assert read_cloud_header(out).metadata["engine"] == "warp"
    cloud = read_cloud(out)
    # noise-free: every point on a face of the 8 x 6 x 3.5 m box room (to the LAS 0.1 mm step)
    x, y, z = cloud.xyz.T
    on_face = np.minimum.reduce([np.abs(x - 0.0), np.abs(x - 8.0), np.abs(y - 0.0), np.abs(y - 6.0),
                                 np.abs(z - 0.0), np.abs(z - 3.5)])
    assert len(cloud) > 10_000 and on_face.max() < 1e-3


@pytest.mark.gpu
@needs_cuda
def test_the_gpu_casts_the_same_first_hits_as_warps_cpu_device(room, warp_cpu):
    gpu = WarpEngine(room.mesh, device="cuda:0")
    rng = np.random.default_rng(5)
    rays = np.empty((20000, 6), dtype=np.float32)
    rays[:, :3] = rng.uniform((0.5, 0.5, 0.2), (7.5, 5.5, 3.3), size=(20000, 3)) - gpu.centre
    directions = rng.normal(size=(20000, 3))
    rays[:, 3:] = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    t_gpu, triangle_gpu = gpu.cast(rays)
    t_cpu, triangle_cpu = warp_cpu.cast(rays)
    np.testing.assert_allclose(t_gpu, t_cpu, atol=1e-5)
    assert np.array_equal(room.mesh.face_component[triangle_gpu], room.mesh.face_component[triangle_cpu])
    # crossings per component (station probes): a ray through a shared edge may count once or twice
    differ = (gpu.count_crossings(rays[:500]) != warp_cpu.count_crossings(rays[:500])).any(axis=1)
    assert differ.mean() < 0.01


@pytest.mark.gpu
@needs_cuda
def test_a_gpu_scan_equals_the_cpu_devices_and_host_finishing(room, warp_cpu):
    # (no Open3D here: GPU machines may lack it; the CPU device equals Open3D in the tests above)
    gpu_engine = WarpEngine(room.mesh, device="cuda:0")
    gpu = scan(room, gpu_engine, time0_s=3.0)
    assert_same_points(gpu, scan(room, warp_cpu, time0_s=3.0), xyz_m=1e-5)
    assert_same_points(gpu, scan(room, HostFinished(gpu_engine), time0_s=3.0), xyz_m=1e-8)
    # the pinned output buffers of a CUDA engine (reused by the chunks) give the same points
    reused = scan_reusing_buffers(room, gpu_engine, chunk_pulses=50_000)
    for column in PointCloud.COLUMNS:
        assert np.array_equal(getattr(reused, column), getattr(scan(room, gpu_engine), column)), column


def test_what_warps_native_library_prints_becomes_python_warnings(monkeypatch):
    import os

    from bimscan.scan import warp_engine

    def noisy_init():
        os.write(1, b"Warp CUDA warning: Could not find the driver.\n")
        os.write(2, b"Warp CUDA warning: second line\n")

    monkeypatch.setattr(warp_engine.wp, "init", noisy_init)
    with pytest.warns(UserWarning) as caught:
        warp_engine._init_warp()
    assert [str(w.message) for w in caught] == ["Warp: Could not find the driver.", "Warp: second line"]

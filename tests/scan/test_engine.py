"""Every ray engine keeps the same contract: first hits at the true distances on the right
triangles, misses as inf and MISS, millimetres far from the origin, whole scans alike.

Engines run where they are installed: Open3D always, embreex and Warp (on its CPU device, as CI
runs it) when present; a missing one is skipped with the reason.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from bimscan.errors import ConfigError
from bimscan.pipeline import load_scene
from bimscan.scan import engine as engine_module
from bimscan.scan.device import SCANNERS, ScanSettings
from bimscan.scan.engine import MISS, EmbreexEngine, Open3DEngine, RayEngine, make_engine, resolve_engine
from bimscan.scan.noise import NoiseModel
from bimscan.survey.recipe import ScanRecipe
from bimscan.scan.probe import sphere_directions
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.types import PointCloud, SceneMesh, Station

VZ400 = SCANNERS["riegl_vz400"]
ENGINE_NAMES = ["open3d", "embreex", "warp-cpu"]


def build_engine(name: str, mesh: SceneMesh) -> RayEngine:
    """The named engine over ``mesh``, or skip the test when it is not installed."""
    if name == "open3d":
        return Open3DEngine(mesh)
    if name == "embreex":
        if importlib.util.find_spec("embreex") is None:
            pytest.skip("embreex is not installed (pip install 'bimscan[embree]')")
        return EmbreexEngine(mesh)
    if importlib.util.find_spec("warp") is None:
        pytest.skip("NVIDIA Warp is not installed (pip install 'bimscan[gpu]')")
    from bimscan.scan.warp_engine import WarpEngine

    return WarpEngine(mesh, device="cpu")


@pytest.fixture(scope="module")
def room(box_room_ifc):
    return load_scene(box_room_ifc)


@pytest.fixture(scope="module", params=ENGINE_NAMES)
def engine(request, room) -> RayEngine:
    return build_engine(request.param, room.mesh)


def rays_from(engine: RayEngine, origin_world, directions) -> np.ndarray:
    rays = np.empty((len(directions), 6), dtype=np.float32)
    rays[:, :3] = np.asarray(origin_world, dtype=np.float64) - engine.centre
    rays[:, 3:] = directions
    return rays


def test_rays_along_the_axes_hit_the_inner_faces_of_the_room_at_their_distances(engine, room):
    # the box room's inside is 8 x 6 x 3.5 m with the floor top at z = 0
    directions = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float32)
    t_hit, triangle = engine.cast(rays_from(engine, (4.0, 3.0, 1.7), directions))
    assert t_hit.dtype == np.float32 and triangle.dtype == np.uint32
    np.testing.assert_allclose(t_hit, [4.0, 4.0, 3.0, 3.0, 1.8, 1.7], atol=1e-5)
    names = room.components.name[room.mesh.face_component[triangle]]
    assert list(names) == ["east", "west", "north", "south", "roof", "floor"]


def test_rays_that_leave_the_model_report_inf_and_the_miss_index(engine):
    directions = sphere_directions(64)
    t_hit, triangle = engine.cast(rays_from(engine, (100.0, 100.0, 100.0), directions[directions[:, 2] > 0.1]))
    assert np.isinf(t_hit).all() and (triangle == MISS).all()


def test_no_rays_give_empty_answers(engine):
    t_hit, triangle = engine.cast(np.empty((0, 6), dtype=np.float32))
    assert len(t_hit) == 0 and len(triangle) == 0


def test_every_engine_finds_the_same_first_hits_as_open3d(engine, room):
    rng = np.random.default_rng(4)
    origins = rng.uniform((0.5, 0.5, 0.2), (7.5, 5.5, 3.3), size=(4000, 3))
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    reference = Open3DEngine(room.mesh)
    rays = np.empty((4000, 6), dtype=np.float32)
    rays[:, :3] = origins - engine.centre
    rays[:, 3:] = directions
    t_hit, triangle = engine.cast(rays)
    t_ref, triangle_ref = reference.cast(rays)
    np.testing.assert_allclose(t_hit, t_ref, atol=1e-5)
    face_component = room.mesh.face_component
    assert np.array_equal(face_component[triangle], face_component[triangle_ref])


@pytest.mark.parametrize("name", ENGINE_NAMES)
def test_a_georeferenced_model_keeps_millimetres_500_km_from_the_origin(name, room):
    shift = np.array([500_000.0, 5_000_000.0, 300.0])
    mesh = SceneMesh(vertices=room.mesh.vertices + shift, faces=room.mesh.faces, face_component=room.mesh.face_component)
    engine = build_engine(name, mesh)
    directions = np.array([[1, 0, 0], [0, -1, 0], [0, 0, -1]], dtype=np.float32)
    t_hit, _ = engine.cast(rays_from(engine, shift + (4.0, 3.0, 1.7), directions))
    np.testing.assert_allclose(t_hit, [4.0, 3.0, 1.7], atol=1e-4)


def test_a_station_scanned_with_every_engine_gives_the_same_points(engine, room):
    settings = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36)
    recipe = ScanRecipe(scanner=VZ400, settings=settings, preset=None, noise=NoiseModel(), seed=2)
    station = Station(id=1, position=(4.0, 3.0, 1.7), heading_deg=30.0)
    clouds = []
    for ray_engine in (engine, Open3DEngine(room.mesh)):
        scanner = VirtualScanner(room.mesh, room.components.label, scanner=VZ400, engine=ray_engine)
        clouds.append(PointCloud.concatenate(list(scanner.scan_station(station, recipe))))
    cloud, reference = clouds
    assert len(cloud) == len(reference) == settings.expected_pulses(VZ400)  # a closed room: every pulse returns
    np.testing.assert_allclose(cloud.xyz, reference.xyz, atol=1e-5)
    for column in ("label", "component", "station"):
        assert np.array_equal(getattr(cloud, column), getattr(reference, column)), column
    assert np.abs(cloud.time - reference.time).max() < 1e-9  # the same pulses (1 microsecond apart at most)
    assert np.abs(cloud.intensity.astype(int) - reference.intensity).max() <= 1


def test_asking_for_warp_where_it_is_not_installed_says_how_to_install_it(monkeypatch, room):
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(engine_module.importlib.util, "find_spec",
                        lambda name, *args: None if name == "warp" else find_spec(name, *args))
    engine_module.warp_sees_cuda.cache_clear()
    try:
        with pytest.raises(ConfigError, match=r"bimscan\[gpu\]"):
            make_engine(room.mesh, name="warp")
        assert resolve_engine("auto") == "open3d"  # no Warp: the CPU engine
    finally:
        engine_module.warp_sees_cuda.cache_clear()
    with pytest.raises(ConfigError, match="choose one of open3d, embreex, warp, auto"):
        resolve_engine("optix")


def test_open3d_is_imported_without_its_plotly_viewer_which_still_works_when_called():
    import subprocess
    import sys

    script = """
import sys
import numpy as np
from bimscan.scan.engine import import_open3d
o3d = import_open3d()
assert "dash" not in sys.modules and "plotly" not in sys.modules, "the web viewer was imported"
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).random((10, 3))))
figure = o3d.visualization.get_plotly_fig([cloud])
assert type(figure).__name__ == "Figure" and "dash" in sys.modules
assert o3d.visualization.draw_plotly.__module__ == "open3d.visualization.draw_plotly"  # the real function now
print("ok")
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]

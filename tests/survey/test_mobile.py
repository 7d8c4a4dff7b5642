"""Mobile scans end to end: trajectories (files and planned walks), drift, the CLI and datasets."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import open3d as o3d
import pytest

from bimscan.errors import ConfigError, InputFileError, OutputError, ScannerSettingsError, StationError
from bimscan.io import read_cloud, read_cloud_header
from bimscan.pipeline import load_scene, scan_model
from bimscan.scan.device import SCANNERS
from bimscan.scan.probe import Prober
from bimscan.survey.drift import REFERENCE_PATH_M, DriftModel, drift_track
from bimscan.survey.platform import PLATFORMS, load_platform
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.stations import plan_stations
from bimscan.survey.trajectory import Trajectory, read_trajectory, trajectory_path, write_trajectory
from bimscan.survey.walk import plan_walk

HANDHELD = PLATFORMS["handheld"]


def line_trajectory(length_m: float, *, speed: float = 1.0, samples: int = 200, passes: int = 1) -> Trajectory:
    parts = []
    for p in range(passes):
        s = np.linspace(0.0, length_m, samples)
        parts.append((s / speed + p * (length_m / speed + 10.0), np.column_stack([s, np.zeros(samples), np.zeros(samples)]),
                      np.full(samples, p)))
    t, xyz, pass_id = (np.concatenate(c) for c in zip(*parts))
    zeros = np.zeros(len(t))
    return Trajectory(t=t, xyz=xyz, roll=zeros, pitch=zeros, yaw=zeros, pass_id=pass_id.astype(np.int32))


# -- trajectory files ------------------------------------------------------------------------------

def test_a_trajectory_round_trips_through_its_csv(tmp_path):
    trajectory = line_trajectory(12.0, passes=2)
    trajectory = Trajectory(t=trajectory.t, xyz=trajectory.xyz + [0.0, 0.0, 0.25], roll=np.radians(np.sin(trajectory.t)),
                            pitch=trajectory.pitch, yaw=np.radians(170.0 + trajectory.t), pass_id=trajectory.pass_id)
    path = write_trajectory(tmp_path / "walk.csv", trajectory)
    back = read_trajectory(path)
    assert np.abs(back.t - trajectory.t).max() < 1e-6
    assert np.abs(back.xyz - trajectory.xyz).max() < 1e-6
    assert np.abs(np.angle(np.exp(1j * (back.yaw - trajectory.yaw)))).max() < 1e-7
    assert back.n_passes == 2 and np.array_equal(back.pass_id, trajectory.pass_id)
    assert path.read_text().splitlines()[0] == "t,x,y,z,roll,pitch,yaw,pass"


@pytest.mark.parametrize(("text", "message"), [
    ("t,x,y,z\n0,0,0,0\n1,1,0,0\n", "lacks column"),
    ("t,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n0,1,0,0,0,0,0\n", "must increase"),
    ("t,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n1,nan,0,0,0,0,0\n", "finite"),
    ("t,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n1,a,0,0,0,0,0\n", "data line 3"),
    ("t,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n", "at least 2"),
    ("t,x,y,z,roll,pitch,yaw\n0,0,0,0,0,0,0\n90000,1,0,0,0,0,0\n", "in seconds"),
])
def test_a_bad_trajectory_file_gets_one_line_naming_the_problem(tmp_path, text, message):
    path = tmp_path / "walk.csv"
    path.write_text(text)
    with pytest.raises(InputFileError, match=message) as caught:
        read_trajectory(path)
    assert "\n" not in str(caught.value) and str(path) in str(caught.value)


def test_a_trajectory_file_with_a_byte_order_mark_reads_its_header(tmp_path):
    path = tmp_path / "excel.csv"  # what spreadsheet programs write as "CSV UTF-8"
    path.write_bytes(b"\xef\xbb\xbft,x,y,z,roll,pitch,yaw\r\n0,0,0,0,0,0,0\r\n2,1,0,0,0,0,90\r\n")
    trajectory = read_trajectory(path)
    assert trajectory.t.tolist() == [0.0, 2.0] and trajectory.yaw[1] == pytest.approx(math.pi / 2)


# -- drift ------------------------------------------------------------------------------------------

def test_drift_grows_with_the_square_root_of_the_distance_walked():
    model = DriftModel(sigma_m=0.02, smoothing_m=0.0)
    trajectory = line_trajectory(40.0)
    ends = np.array([drift_track(trajectory, model, seed).offset[-1] for seed in range(600)])
    expected = 0.02 * math.sqrt(40.0 / REFERENCE_PATH_M)
    assert np.std(ends[:, 0]) == pytest.approx(expected, rel=0.12)
    assert np.std(ends[:, 2]) == pytest.approx(expected * model.vertical_ratio, rel=0.12)
    middle = np.array([drift_track(trajectory, model, seed).offset[20] for seed in range(600)])
    assert np.std(middle[:, 0]) == pytest.approx(0.02 * math.sqrt(20.0 / REFERENCE_PATH_M), rel=0.12)


def test_drift_is_zero_at_the_start_of_each_pass_and_at_every_loop_closure():
    base = line_trajectory(30.0, passes=2)
    trajectory = Trajectory(t=base.t, xyz=base.xyz, roll=base.roll, pitch=base.pitch, yaw=base.yaw,
                            pass_id=base.pass_id, closures=np.array([15.0, 30.0]))
    track = drift_track(trajectory, DriftModel(sigma_m=0.05), seed=4)
    offset, yaw = track.at(np.array([0.0, 15.0, 30.0, 40.0]))
    assert np.abs(offset[:3]).max() < 1e-12 and np.abs(yaw[:3]).max() < 1e-12
    assert np.abs(offset[3]).max() == 0.0  # pass 1 starts at t = 40 s, pinned too
    free, _ = track.at(np.array([7.0, 22.0]))
    assert np.abs(free).max() > 1e-4  # between pins the error is there


def test_drift_moves_each_sweep_rigidly_about_its_sensor():
    track = drift_track(line_trajectory(20.0), DriftModel(sigma_m=0.05, heading_sigma_deg=1.0), seed=1)
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-5, 5, (100, 3))
    sensor = np.tile([1.0, 2.0, 1.5], (100, 1))
    moved, moved_sensor = xyz.copy(), sensor.copy()
    track.apply(moved, moved_sensor, np.full(100, 12.0))
    before = np.linalg.norm(xyz[:, None] - xyz[None], axis=2)
    after = np.linalg.norm(moved[:, None] - moved[None], axis=2)
    assert np.abs(after - before).max() < 1e-9
    assert np.abs(moved - xyz).max() > 1e-4


def test_impossible_drift_settings_are_refused():
    with pytest.raises(ConfigError, match=r"^drift sigma_m must be a number in \[0, 1\] \(metres per 10 m walked\), "
                                          r"got 5$"):
        DriftModel(sigma_m=5.0)
    with pytest.raises(ConfigError, match=r"^drift smoothing_m must be a number in \[0, 100\], got inf$"):
        DriftModel(smoothing_m=float("inf"))


# -- planned walks ------------------------------------------------------------------------------------

def walk_checks(scene, trajectory, report, stations):
    """What every planned walk must be: closed loops, on walkable floor inside the building, at a
    walking pace with realistic turns, through every station of the tripod plan."""
    prober = Prober(scene.mesh)
    assert report.missed == () and len(report.visited) == len(stations)
    for part in trajectory.pass_slices():
        xyz = trajectory.xyz[part]
        assert np.linalg.norm(xyz[0] - xyz[-1]) < 1e-9  # back to its start
        step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
        dt = np.diff(trajectory.t[part])
        assert (step / dt).max() <= HANDHELD.walking_speed_m_s + 1e-6
        turn = np.abs(np.diff(np.unwrap(trajectory.yaw[part]))) / dt
        assert np.degrees(turn).max() <= HANDHELD.max_turn_deg_per_s + 1e-6
    # every sample stands on something within a step below, has a roof overhead and is in no solid
    feet = trajectory.xyz + [0.0, 0.0, 0.3]
    down, _ = prober.cast(feet, np.tile([0.0, 0.0, -1.0], (len(feet), 1)))
    assert (down <= 0.3 + 0.25).all()
    # inside the building: a roof overhead, or on a room of the model open to the sky (a roof
    # terrace), within half a metre of its outline
    up, _ = prober.cast(trajectory.xyz + [0.0, 0.0, 0.5], np.tile([0.0, 0.0, 1.0], (len(feet), 1)))
    open_sky = ~np.isfinite(up)
    near_room = np.zeros(len(feet), dtype=bool)
    for room in scene.spaces:
        lo, hi = room.vertices.min(axis=0) - [0.5, 0.5, 0.6], room.vertices.max(axis=0) + 0.5
        near_room |= ((trajectory.xyz >= lo) & (trajectory.xyz <= hi)).all(axis=1)
    assert (~open_sky | near_room).all()
    # in no solid but the doors the operator opens
    chest = trajectory.xyz + [0.0, 0.0, 1.0]
    doors = scene.components.descends_from(("IfcDoor",), parents=True)
    for point in chest[prober.inside_solid(chest)]:
        solid = prober.solid_containing(point)
        assert solid is None or doors[solid], (point, scene.components.ifc_class[solid])
    # every station's floor is passed within a metre
    floors = np.array([[s.position[0], s.position[1], s.floor_z] for s in stations])
    nearest = np.min(np.linalg.norm(floors[:, None, :] - trajectory.xyz[None], axis=2), axis=1)
    assert nearest.max() < 1.0


@pytest.fixture(scope="module")
def office(tmp_path_factory):
    from bimscan.ifc.generate import make_building

    return make_building(tmp_path_factory.mktemp("walk") / "office.ifc", seed=4, storeys=2, style="office").path


def planned(path):
    scene = load_scene(path)
    prober = Prober(scene.mesh)
    stations, _ = plan_stations(scene, prober, SCANNERS["riegl_vz400"])
    trajectory, report = plan_walk(scene, prober, HANDHELD, stations)
    return scene, stations, trajectory, report


def test_a_planned_walk_through_a_two_storey_building_climbs_its_stairs_and_closes_its_loop(office):
    scene, stations, trajectory, report = planned(office)
    walk_checks(scene, trajectory, report, stations)
    assert trajectory.n_passes == 1  # the stairs join the storeys
    storeys = {round(float(s.floor_z), 1) for s in stations}
    assert len(storeys) >= 2 and np.ptp(trajectory.xyz[:, 2]) >= min(np.ptp(list(storeys)), 2.5)
    assert len(trajectory.closures) >= 1


def test_a_planned_walk_through_the_shared_duplex_visits_every_room_of_the_tripod_plan(shared_ifc):
    scene, stations, trajectory, report = planned(shared_ifc("duplex.ifc"))
    walk_checks(scene, trajectory, report, stations)
    rooms = {s.room for s in stations if s.room}
    assert set(report.rooms) == rooms


def test_a_model_with_nowhere_to_walk_fails_in_one_line(tmp_path):
    from tests.conftest import TinyModel

    model = TinyModel()
    model.add_box("IfcWall", origin=(0.0, 0.0, 0.0), size=(4.0, 0.2, 3.0), name="lonely wall")
    scene = load_scene(model.write(tmp_path / "wall.ifc"))
    with pytest.raises(StationError, match="--trajectory FILE.csv"):
        plan_walk(scene, Prober(scene.mesh), HANDHELD, ())


# -- scans -----------------------------------------------------------------------------------------

def test_a_handheld_scan_without_noise_puts_every_point_on_the_surface_it_is_labelled_with(office, tmp_path):
    scene, stations, trajectory, _ = planned(office)
    first = trajectory.t[0]
    window = (trajectory.t <= first + 12.0)  # the first twelve seconds of the walk
    piece = Trajectory(t=trajectory.t[window], xyz=trajectory.xyz[window], roll=trajectory.roll[window],
                       pitch=trajectory.pitch[window], yaw=trajectory.yaw[window],
                       pass_id=np.zeros(int(window.sum()), dtype=np.int32))
    walk = write_trajectory(tmp_path / "piece.csv", piece)
    recipe = ScanRecipe.resolve(platform="handheld", trajectory=str(walk), noise=_no_noise())
    result = scan_model(office, tmp_path / "hh.laz", recipe, progress=False)
    cloud = read_cloud(result.path)
    assert len(cloud) > 1_000_000
    mesh = scene.mesh
    rs = o3d.t.geometry.RaycastingScene()
    centre = np.round(mesh.vertices.mean(axis=0))
    rs.add_triangles(o3d.core.Tensor((mesh.vertices - centre).astype(np.float32)),
                     o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    sample = np.random.default_rng(0).choice(len(cloud), 200_000, replace=False)
    distance = rs.compute_distance(o3d.core.Tensor((cloud.xyz[sample] - centre).astype(np.float32))).numpy()
    assert distance.max() < 0.01
    # the label is the class of the component the point lies on
    assert np.array_equal(cloud.label, scene.components.label[cloud.component])
    own = np.empty(len(sample))
    for c in np.unique(cloud.component[sample]):
        faces = mesh.faces[mesh.face_component == c]
        one = o3d.t.geometry.RaycastingScene()
        one.add_triangles(o3d.core.Tensor((mesh.vertices - centre).astype(np.float32)),
                          o3d.core.Tensor(faces.astype(np.uint32)))
        mask = cloud.component[sample] == c
        own[mask] = one.compute_distance(o3d.core.Tensor((cloud.xyz[sample][mask] - centre).astype(np.float32))).numpy()
    assert own.max() < 0.01
    # the cloud carries its mobile columns, and the trajectory went beside it
    assert cloud.ring.max() == 15 and cloud.sensor_xyz is not None and set(np.unique(cloud.channel)) == {0}
    assert read_trajectory(trajectory_path(result.path)).t[-1] == pytest.approx(piece.t[-1], abs=1e-6)
    assert read_cloud_header(result.path).metadata["mobile"]["platform"]["name"] == "handheld"


def _no_noise():
    from bimscan.scan.noise import NoiseModel

    return NoiseModel.off()


def test_a_mobile_scan_is_reproducible_to_the_byte_and_drift_moves_it(office, tmp_path):
    walk = write_trajectory(tmp_path / "short.csv", _short_walk(office))
    outs = []
    for name, drift in (("a", 0.02), ("b", 0.02), ("c", 0.0)):
        recipe = ScanRecipe.resolve(platform="handheld", trajectory=str(walk), drift=DriftModel(sigma_m=drift), seed=5)
        outs.append(scan_model(office, tmp_path / f"{name}.laz", recipe, progress=False).path.read_bytes())
    assert outs[0] == outs[1] and outs[0] != outs[2]


def _short_walk(path) -> Trajectory:
    scene = load_scene(path)
    lo, hi = scene.mesh.bounds()
    start = np.array([lo[0] + 2.0, (lo[1] + hi[1]) / 2.0, 0.0])
    t = np.linspace(0.0, 3.0, 31)
    xyz = start + np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    return Trajectory(t=t, xyz=xyz, roll=np.zeros_like(t), pitch=np.zeros_like(t), yaw=np.zeros_like(t),
                      pass_id=np.zeros(len(t), dtype=np.int32))


def test_a_trajectory_outside_the_model_is_refused_before_the_scan(office, tmp_path):
    far = _short_walk(office)
    far = Trajectory(t=far.t, xyz=far.xyz + [500.0, 0.0, 0.0], roll=far.roll, pitch=far.pitch, yaw=far.yaw,
                     pass_id=far.pass_id)
    walk = write_trajectory(tmp_path / "far.csv", far)
    with pytest.raises(StationError, match="outside the model"):
        scan_model(office, tmp_path / "far.laz", ScanRecipe.resolve(platform="handheld", trajectory=str(walk)),
                   progress=False)
    assert not (tmp_path / "far.laz").exists() and not trajectory_path(tmp_path / "far.laz").exists()


def test_a_trajectory_with_a_huge_coordinate_is_refused_in_a_short_line(office, tmp_path):
    walk = tmp_path / "huge.csv"
    walk.write_text("t,x,y,z,roll,pitch,yaw\n0,1e300,1,1,0,0,0\n10,2,1,1,0,0,0\n")
    with pytest.raises(StationError) as caught:
        scan_model(office, tmp_path / "huge.laz", ScanRecipe.resolve(platform="handheld", trajectory=str(walk)),
                   progress=False)
    message = str(caught.value).removeprefix(str(walk))
    assert message.startswith(": pose 0 (t = 0 s) at 1e+300, 1, 1 lies more than 5 m outside the model (x 0..27.1,")
    assert len(message) < 200 and max(len(word) for word in message.split()) < 20  # no 300-digit number


def test_a_mobile_scan_to_e57_is_refused_before_any_work(office, tmp_path):
    with pytest.raises(OutputError, match="one pose per scan"):
        scan_model(office, tmp_path / "hh.e57", ScanRecipe.resolve(platform="handheld"), progress=False)


def test_the_cli_scans_with_a_handheld_and_refuses_a_drift_on_the_tripod(office, tmp_path):
    walk = write_trajectory(tmp_path / "short.csv", _short_walk(office))
    out = tmp_path / "hh.ply"
    run = subprocess.run([sys.executable, "-m", "bimscan.cli.main", "scan", str(office), str(out), "--platform", "handheld",
                          "--trajectory", str(walk), "--drift", "0.01"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "walk of 3 s in 1 pass" in run.stdout and trajectory_path(out).is_file()
    bad = subprocess.run([sys.executable, "-m", "bimscan.cli.main", "scan", str(office), str(tmp_path / "t.laz"), "--drift",
                          "0.01"], capture_output=True, text=True)
    assert bad.returncode != 0 and "needs a mobile platform" in bad.stderr and "Traceback" not in bad.stderr


def test_a_platform_file_is_read_with_its_mounts(tmp_path):
    path = tmp_path / "pole.toml"
    path.write_text('description = "a lidar on a pole"\nwalking_speed_m_s = 0.8\n'
                    '[[mounts]]\nheight_m = 2.5\ntilt_deg = 30.0\n')
    platform = load_platform(path)
    assert platform.name == "pole" and platform.mounts[0].height_m == 2.5
    with pytest.raises(ConfigError, match="neither a file nor a known platform"):
        load_platform("segway")
    path.write_text('description = "a lidar on a pole"\nwalking_speed_m_s = 0.8\n')  # where is the lidar?
    with pytest.raises(ConfigError, match=r"pole.toml: the platform has no \[\[mounts\]\]; add one") as caught:
        load_platform(path)
    assert "\n" not in str(caught.value)


def _lidar_file(folder, name: str, **changes) -> str:
    """The VLP-16's file with some keys changed, as a file of its own."""
    from importlib import resources

    text = (resources.files("bimscan.scan") / "scanners" / "velodyne_vlp16.toml").read_text("utf-8")
    lines = [line for line in text.splitlines() if line.split(" = ")[0] not in {"name", *changes}]
    path = folder / f"{name}.toml"
    path.write_text("\n".join([f'name = "{name}"', *lines, *(f"{k} = {v!r}" for k, v in changes.items())]) + "\n")
    return str(path)


def test_a_walk_that_sees_nothing_names_its_lidar_and_range_not_the_tripod_scanner(box_room_ifc, tmp_path):
    walk = tmp_path / "walk.csv"  # across the 8 x 6 m room, every wall farther than the lidar's 0.3 m
    walk.write_text("t,x,y,z,roll,pitch,yaw\n0,3,3,0,0,0,0\n1,3.05,3,0,0,0,0\n")
    recipe = ScanRecipe.resolve(platform="backpack", trajectory=str(walk),
                                lidar=_lidar_file(tmp_path, "short_puck", max_range_m=0.3))
    with pytest.raises(StationError, match="has no point") as caught:
        scan_model(box_room_ifc, tmp_path / "none.laz", recipe, progress=False)
    message = str(caught.value)
    assert "between 0.09144 and 0.3 m (the range of 2 x short_puck on the backpack platform)" in message
    assert "riegl" not in message.lower() and "station" not in message
    assert not (tmp_path / "none.laz").exists() and not trajectory_path(tmp_path / "none.laz").exists()


def test_a_walk_too_short_to_fire_is_refused_before_the_model_is_read(tmp_path):
    walk = tmp_path / "blink.csv"  # 20 microseconds: less than one VLP-16 firing sequence (55.296 us)
    walk.write_text("t,x,y,z,roll,pitch,yaw\n0,3,3,0,0,0,0\n0.00002,3,3,0,0,0,0\n")
    recipe = ScanRecipe.resolve(platform="handheld", trajectory=str(walk))
    with pytest.raises(ScannerSettingsError, match="less than one firing sequence of the velodyne_vlp16"):
        scan_model(tmp_path / "unread.ifc", tmp_path / "x.laz", recipe, progress=False)


def test_a_planned_walk_over_its_pulse_budget_is_refused_before_the_scan(office, tmp_path):
    recipe = ScanRecipe.resolve(platform="handheld", max_walk_pulses=1_000_000)
    with pytest.raises(ScannerSettingsError, match=r"the walk would fire [0-9.e+]+ pulses \([0-9,]+ s x 1 x "
                                                   r"velodyne_vlp16.*budget of 1,000,000.*--max-walk-pulses"):
        scan_model(office, tmp_path / "hh.laz", recipe, progress=False)
    assert list(tmp_path.iterdir()) == []


# -- datasets --------------------------------------------------------------------------------------

def test_a_dataset_spec_builds_a_mobile_unit_beside_a_tripod_one_and_keeps_its_walk(office, tmp_path):
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.layout import DatasetFolder, verify_unit
    from bimscan.dataset.spec import load_spec

    walk = write_trajectory(tmp_path / "walk.csv", _short_walk(office))
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(f'name = "m"\nformats = ["npy"]\n[[scenes]]\nname = "office"\nifc = "{office}"\n'
                         f'trajectory = "walk.csv"\n'
                         '[[configs]]\nname = "tls"\npreset = "exp1"\nhead_deg_per_s = 60.0\n'
                         '[[configs]]\nname = "hh"\nplatform = "handheld"\ndrift_m = 0.01\n')
    spec = load_spec(spec_path)
    assert spec.scenes[0].trajectory == str(walk)
    report = build_dataset(spec, tmp_path / "ds", executor="serial", progress=False)
    assert [e.status for e in report.entries] == ["done", "done"] and report.failed == 0
    folder = DatasetFolder(tmp_path / "ds")
    unit = folder.unit_dir("office__hh")
    assert read_trajectory(unit / "trajectory.csv").t[-1] == pytest.approx(3.0)
    cloud = read_cloud(unit / "cloud")
    assert cloud.ring is not None and cloud.sensor_xyz is not None
    record = folder.read_unit("office__hh")
    assert "trajectory.csv" in record.checksums
    assert verify_unit(unit, expected_fingerprint=record.fingerprint) is None
    (unit / "trajectory.csv").write_text("t,x,y,z,roll,pitch,yaw\n")  # damaged: the unit is no longer whole
    assert "trajectory.csv" in verify_unit(unit, expected_fingerprint=record.fingerprint)


@pytest.mark.parametrize(("config", "message"), [
    ('platform = "handheld"\npreset = "exp1"', "no TLS 'preset'"),
    ('preset = "exp1"\ndrift_m = 0.01', "for mobile configurations"),
    ('platform = "segway"', "neither a file nor a known platform"),
    ('platform = "handheld"\nlidar = "riegl_vz400"', "rotating-mirror TLS for the tripod"),
])
def test_a_bad_mobile_configuration_is_refused_when_the_spec_is_read(office, tmp_path, config, message):
    from bimscan.dataset.spec import load_spec

    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(f'[[scenes]]\nname = "office"\nifc = "{office}"\n[[configs]]\nname = "c"\n{config}\n')
    with pytest.raises(ConfigError, match=message):
        load_spec(spec_path)


# -- HELIOS++ export ---------------------------------------------------------------------------------

def test_the_helios_survey_of_a_mobile_scan_points_every_beam_where_bimscan_does():
    """The exported trajectory, mount and head settings, read with HELIOS++'s conventions (CANONICAL
    attitude Rx(roll) Ry(pitch) Rz(yaw), global mount rotations, VLP-16 beam along +Y at head
    angle 0), give each pulse the direction and origin bimscan's kernel gives it."""
    import xml.etree.ElementTree as ET

    from scipy.spatial.transform import Rotation

    from bimscan.io.helios import helios_mobile_files
    from bimscan.scan.multibeam import moving_rays
    from bimscan.survey.mobile import MobileScan
    from bimscan.scan.multibeam import LIDARS

    t = np.linspace(0.0, 2.0, 9)
    walk = Trajectory(t=t, xyz=np.column_stack([t, 0.3 * t, 0.1 * t]), roll=np.radians(4.0 * np.sin(t)),
                      pitch=np.radians(3.0 * np.cos(t)), yaw=np.radians(30.0 * t), pass_id=np.zeros(9, dtype=np.int32))
    mobile = MobileScan(platform=HANDHELD, lidar=LIDARS["velodyne_vlp16"], rotation_hz=10.0)
    files = helios_mobile_files(walk, mobile, scene_id="s", name="s")
    survey = ET.fromstring(files["helios/survey.xml"]).find("survey")
    assert survey.get("platform") == "interpolated" and survey.get("rotationSpec") == "CANONICAL"
    mount = survey.find("scannerMount")
    lever = np.array([float(mount.get(a)) for a in "xyz"])
    mount_rotation = np.eye(3)
    for rot in mount.findall("rot"):  # global rotations, in order
        mount_rotation = Rotation.from_euler(rot.get("axis"), float(rot.get("angle_deg")), degrees=True).as_matrix() \
            @ mount_rotation
    settings = survey.find("leg").find("scannerSettings")
    head_start, head_rate = float(settings.get("headRotateStart_deg")), float(settings.get("headRotatePerSec_deg"))
    rows = np.array([[float(v) for v in line.split(",")] for line in files["helios/trajectory_mount0.trj"].decode()
                     .splitlines() if not line.startswith("#")])
    # bimscan's rays of the first 0.5 s
    lidar = mobile.lidar
    n = mobile.pass_pulses(0.5)
    rays, origin, pulse_time = np.empty((n, 6), np.float32), np.empty((n, 3)), np.empty(n)
    el = np.radians(np.asarray(lidar.beam_elevation_deg))
    m = HANDHELD.mounts[0]
    moving_rays(np.int64(0), np.int64(n), np.int64(16), lidar.firing_cycle_us * 1e-6, 0.0,
                np.asarray(lidar.firing_offset_us) * 1e-6, np.cos(el), np.sin(el), np.zeros(16), 2 * math.pi * 10.0,
                walk.t, walk.xyz, walk.ypr(), m.lever_arm(), m.rotation(), 2 * math.pi * m.head_rotation_hz,
                np.zeros(3), rays, origin, pulse_time)
    pick = np.linspace(0, n - 1, 400).astype(int)
    for i in pick:
        time = pulse_time[i]
        angles = [np.interp(time, rows[:, 0], rows[:, c]) for c in (1, 2, 3)]
        attitude = Rotation.from_euler("XYZ", angles, degrees=True).as_matrix()
        position = np.array([np.interp(time, rows[:, 0], rows[:, c]) for c in (4, 5, 6)])
        head = math.radians(head_start + head_rate * time)
        elevation = el[i % 16]
        beam = np.array([-math.cos(elevation) * math.sin(head), math.cos(elevation) * math.cos(head),
                         math.sin(elevation)])
        assert np.abs(attitude @ mount_rotation @ beam - rays[i, 3:]).max() < 2e-3
        assert np.abs(position + attitude @ lever - origin[i]).max() < 2e-3


def test_a_walk_crosses_rooms_whose_storey_was_exported_without_its_floor_slab(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    for name, x0 in (("west room", 0.0), ("east room", 6.0)):  # two rooms side by side, no floor slab
        model.add_box("IfcSpace", origin=(x0, 0.0, 0.0), size=(5.8, 5.0, 2.8), name=name)
    for name, origin, size in (("south", (-0.2, -0.2, 0.0), (12.2, 0.2, 2.8)), ("north", (-0.2, 5.0, 0.0), (12.2, 0.2, 2.8)),
                               ("west", (-0.2, 0.0, 0.0), (0.2, 5.0, 2.8)), ("east", (11.8, 0.0, 0.0), (0.2, 5.0, 2.8)),
                               ("party wall south", (5.8, 0.0, 0.0), (0.2, 2.0, 2.8)),  # a 1 m opening between
                               ("party wall north", (5.8, 3.0, 0.0), (0.2, 2.0, 2.8))):
        model.add_box("IfcWall", origin=origin, size=size, name=name)
    model.add_box("IfcSlab", origin=(-0.2, -0.2, 2.8), size=(12.2, 5.4, 0.3), predefined_type="ROOF", name="roof")
    scene = load_scene(model.write(tmp_path / "noslab.ifc"))
    prober = Prober(scene.mesh)
    stations, _ = plan_stations(scene, prober, SCANNERS["riegl_vz400"])
    trajectory, report = plan_walk(scene, prober, HANDHELD, stations)
    assert report.missed == () and set(report.rooms) == {"west room", "east room"}
    assert trajectory.n_passes == 1 and np.abs(trajectory.xyz[:, 2]).max() < 1e-6  # on the rooms' own floor
    assert trajectory.xyz[:, 0].min() < 5.0 and trajectory.xyz[:, 0].max() > 7.0  # through the opening


def test_a_walk_goes_through_the_stations_of_a_station_file(office, tmp_path):
    from bimscan.survey.survey import choose_trajectory

    scene = load_scene(office)
    stations, _ = plan_stations(scene, Prober(scene.mesh), SCANNERS["riegl_vz400"])
    chosen = stations[:2]
    path = tmp_path / "two.csv"
    path.write_text("x,y,z\n" + "".join(f"{s.position[0]},{s.position[1]},{s.position[2]}\n" for s in chosen))
    recipe = ScanRecipe.resolve(platform="handheld", stations_from=str(path))
    trajectory, report = choose_trajectory(scene, recipe)
    assert report.waypoints == 2 and report.missed == ()
    floors = np.array([[s.position[0], s.position[1], s.floor_z] for s in chosen])
    assert np.min(np.linalg.norm(floors[:, None] - trajectory.xyz[None], axis=2), axis=1).max() < 1.0

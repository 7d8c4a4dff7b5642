"""Multi-beam lidars on a moving platform: firing sequence, exact time and ring, poses, counts, noise."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bimscan.errors import ConfigError, ScannerSettingsError
from bimscan.pipeline import load_scene
from bimscan.scan.device import load_scanner
from bimscan.scan.lidars import load_lidar
from bimscan.scan.multibeam import LIDARS, MultiBeamScanner
from bimscan.scan.noise import NoiseModel
from bimscan.scan.sensor import EFFECTS, MOBILE_EFFECTS, SensorModel
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.survey.mobile import MobileScan
from bimscan.survey.platform import PLATFORMS, Mount, Platform
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.trajectory import Trajectory
from bimscan.types import PointCloud

VLP16 = LIDARS["velodyne_vlp16"]
ROOM = np.array([8.0, 6.0, 3.5])  # the box room's inside (tests/conftest.py)


@pytest.fixture(scope="module")
def box(box_room_ifc):
    scene = load_scene(box_room_ifc)
    return scene, VirtualScanner(scene.mesh, scene.components.label, scanner=load_scanner())


def still(seconds: float, position=(4.0, 3.0, 0.0), yaw_deg: float = 0.0) -> Trajectory:
    t = np.array([0.0, seconds])
    return Trajectory(t=t, xyz=np.array([position, position], dtype=float), roll=np.zeros(2), pitch=np.zeros(2),
                      yaw=np.radians([yaw_deg, yaw_deg]), pass_id=np.zeros(2, dtype=np.int32))


def walking(seconds: float) -> Trajectory:
    """A walk along x through the room with a turning heading and a little pitch and roll."""
    t = np.linspace(0.0, seconds, 21)
    x = 2.0 + 4.0 * t / seconds
    xyz = np.column_stack([x, 3.0 + 0.5 * np.sin(t), np.full_like(t, 0.1)])
    return Trajectory(t=t, xyz=xyz, roll=np.radians(3.0 * np.sin(2 * t)), pitch=np.radians(2.0 * np.cos(t)),
                      yaw=np.radians(40.0 * np.sin(0.7 * t)), pass_id=np.zeros(len(t), dtype=np.int32))


def mobile_recipe(platform: Platform, *, noise=NoiseModel.off(), rotation_hz=10.0, **fields) -> ScanRecipe:
    return ScanRecipe(noise=noise, mobile=MobileScan(platform=platform, lidar=VLP16, rotation_hz=rotation_hz), **fields)


def upright(height=1.2, head_hz=0.0, tilt=0.0) -> Platform:
    return Platform(name="test", mounts=(Mount(height_m=height, forward_m=0.2, tilt_deg=tilt,
                                               head_rotation_hz=head_hz),))


def scan(scanner, trajectory, recipe) -> PointCloud:
    return PointCloud.concatenate([c for part_id, part in enumerate(trajectory.pass_slices())
                                   for m in range(len(recipe.mobile.platform.mounts))
                                   for c in scanner.scan_pass(trajectory, part, part_id, m, recipe)])


def test_the_vlp16_file_holds_the_datasheet_firing_sequence():
    assert VLP16.n_beams == 16
    assert VLP16.pulse_rate_hz == pytest.approx(16 / 55.296e-6)  # "about 300,000 points per second"
    assert sorted(VLP16.beam_elevation_deg) == list(np.arange(-15.0, 16.0, 2.0))
    ring = VLP16.ring_of_beam()
    assert np.array_equal(np.argsort(VLP16.beam_elevation_deg), np.argsort(ring))  # ring 0 is the lowest beam


def test_every_built_in_multibeam_scanner_is_consistent_and_not_a_tls():
    assert len(LIDARS) >= 2 and any(lidar.n_beams >= 32 for lidar in LIDARS.values())
    for name, lidar in LIDARS.items():
        assert lidar.pulse_rate_hz > 1e5
        with pytest.raises(ConfigError, match="multi-beam"):
            load_scanner(name)


def test_a_scanner_file_with_beams_missing_a_firing_time_is_refused(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\nkind = "multibeam"\nbeam_elevation_deg = [0.0, 1.0]\n'
                    'beam_azimuth_offset_deg = [0.0, 0.0]\nfiring_offset_us = [0.0]\n')
    with pytest.raises(ScannerSettingsError, match="one entry per beam"):
        load_lidar(path)
    with pytest.raises(ConfigError, match="neither a file nor a known lidar"):
        load_lidar("no_such_lidar")


def test_a_standing_scan_in_a_closed_room_fires_whole_sequences_and_every_pulse_returns(box):
    _, scanner = box
    recipe = mobile_recipe(upright())
    cloud = scan(scanner, still(0.05), recipe)
    sequences = math.floor(0.05 / (VLP16.firing_cycle_us * 1e-6))
    assert len(cloud) == 16 * sequences == recipe.mobile.pass_pulses(0.05)


def test_each_point_carries_its_exact_firing_time_beam_elevation_and_azimuth(box):
    _, scanner = box
    cloud = scan(scanner, still(0.2), mobile_recipe(upright(), rotation_hz=10.0))
    direction = cloud.xyz - cloud.sensor_xyz
    elevation = np.degrees(np.arcsin(direction[:, 2] / np.linalg.norm(direction, axis=1)))
    by_ring = np.sort(np.asarray(VLP16.beam_elevation_deg))[cloud.ring]
    assert np.abs(elevation - by_ring).max() < 1e-6
    # the time says which beam fired: sequence * 55.296 us + beam * 2.304 us
    beam = np.argsort(np.argsort(VLP16.beam_elevation_deg))  # beam -> ring; invert it
    beam_of_ring = np.empty(16, dtype=int)
    beam_of_ring[beam] = np.arange(16)
    cycle = VLP16.firing_cycle_us * 1e-6
    offset = np.asarray(VLP16.firing_offset_us)[beam_of_ring[cloud.ring]] * 1e-6
    sequence = (cloud.time - offset) / cycle
    assert np.abs(sequence - np.round(sequence)).max() < 1e-6
    # azimuth = 360 degrees * rotation rate * time (the head spins from +x, the platform faces +x)
    azimuth = np.arctan2(direction[:, 1], direction[:, 0])
    expected = 2 * math.pi * 10.0 * cloud.time
    assert np.abs(np.angle(np.exp(1j * (azimuth - expected)))).max() < 1e-6


def test_while_walking_turning_and_tilting_every_point_stays_on_the_room_and_the_sensor_follows_the_path(box):
    scene, scanner = box
    trajectory = walking(2.0)
    recipe = mobile_recipe(upright(head_hz=0.5, tilt=90.0))
    cloud = scan(scanner, trajectory, recipe)
    inside = cloud.xyz
    to_plane = np.minimum(np.abs(inside), np.abs(inside - ROOM)).min(axis=1)  # distance to the nearest room face
    assert to_plane.max() < 1e-4
    assert np.array_equal(cloud.label, scene.components.label[cloud.component])
    # the beam origin: the platform's position at the pulse's time plus the mount's lever arm turned
    # by the platform's orientation and the head's turn at the start of the pulse's firing sequence
    k = np.linspace(0, len(cloud) - 1, 50).astype(int)
    cycle = VLP16.firing_cycle_us * 1e-6
    for i in k:
        position = trajectory.position_at(np.array([cloud.time[i]]))[0]
        t = math.floor(cloud.time[i] / cycle + 1e-9) * cycle
        yaw = np.interp(t, trajectory.t, trajectory.yaw)
        pitch = np.interp(t, trajectory.t, trajectory.pitch)
        roll = np.interp(t, trajectory.t, trajectory.roll)
        rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
        ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]])
        rx = np.array([[1, 0, 0], [0, math.cos(roll), -math.sin(roll)], [0, math.sin(roll), math.cos(roll)]])
        head = 2 * math.pi * 0.5 * t
        rh = np.array([[math.cos(head), -math.sin(head), 0], [math.sin(head), math.cos(head), 0], [0, 0, 1]])
        expected = position + rz @ ry @ rx @ rh @ np.array([0.2, 0.0, 1.2])
        assert np.abs(cloud.sensor_xyz[i] - expected).max() < 1e-9


def test_the_output_does_not_depend_on_the_chunk_size_and_noise_follows_the_scanners_accuracy(box):
    scene, scanner = box
    noise = NoiseModel(range_sigma_m=0.03, angle_sigma_deg=0.0)
    small = scan(scanner, walking(0.5), mobile_recipe(upright(), noise=noise, chunk_pulses=1000, seed=3))
    large = scan(scanner, walking(0.5), mobile_recipe(upright(), noise=noise, seed=3))
    for column in ("xyz", "time", "ring", "label", "sensor_xyz"):
        assert np.array_equal(getattr(small, column), getattr(large, column)), column
    exact = scan(scanner, walking(0.5), mobile_recipe(upright()))
    error = np.linalg.norm(large.xyz - large.sensor_xyz, axis=1) - np.linalg.norm(exact.xyz - exact.sensor_xyz, axis=1)
    assert np.std(error) == pytest.approx(0.03, rel=0.05)
    assert abs(np.mean(error)) < 0.002


def test_a_backpack_with_two_lidars_numbers_them_as_channels(box):
    _, scanner = box
    recipe = mobile_recipe(PLATFORMS["backpack"])
    cloud = scan(scanner, still(0.02, position=(4.0, 3.0, -0.5)), recipe)
    assert set(np.unique(cloud.channel)) == {0, 1}
    for channel, mount in enumerate(PLATFORMS["backpack"].mounts):
        origin = cloud.sensor_xyz[cloud.channel == channel]
        assert np.allclose(origin, [4.0 + mount.forward_m, 3.0, -0.5 + mount.height_m])


def test_a_rotation_rate_outside_the_device_warns_and_is_refused_under_strict():
    assert "outside velodyne_vlp16's rotation rates" in mobile_recipe(upright(), rotation_hz=25.0).warnings[0]
    with pytest.raises(ScannerSettingsError, match="--strict"):
        mobile_recipe(upright(), rotation_hz=25.0, strict=True)
    with pytest.raises(ScannerSettingsError, match="^rotation_hz must be a number > 0, got -1$"):
        MobileScan(platform=upright(), lidar=VLP16, rotation_hz=-1.0)


def test_sensor_effects_and_station_registration_are_refused_for_a_mobile_scan():
    full = ScanRecipe.resolve(platform="handheld", realism="full").sensor
    assert [e for e in EFFECTS if full.on(e)] == list(MOBILE_EFFECTS)  # "full": every effect a mobile scan has
    for effect in ("footprint", "glass", "detection"):
        with pytest.raises(ConfigError, match=f"{effect}: simulated for tripod scans only"):
            ScanRecipe.resolve(platform="handheld", sensor={effect: True})
    with pytest.raises(ConfigError, match="--drift"):
        ScanRecipe.resolve(platform="handheld", noise=NoiseModel(registration_sigma_m=0.01))
    with pytest.raises(ConfigError, match="needs a mobile platform"):
        ScanRecipe.resolve(trajectory="walk.csv")


def test_a_mobile_recipe_records_its_platform_and_lidar_and_a_tripod_recipe_is_unchanged():
    mobile = ScanRecipe.resolve(platform="handheld").to_json()
    assert mobile["mobile"]["scanner"]["name"] == "velodyne_vlp16" and "settings" not in mobile
    assert "sensor" not in mobile  # a paper mobile scan records what it did before the sensor effects
    coloured = ScanRecipe.resolve(platform="handheld", sensor={"color": True}).to_json()
    assert coloured["sensor"]["color"] is True and coloured["sensor"]["footprint"] is False
    tripod = ScanRecipe.resolve().to_json()
    assert "mobile" not in tripod and tripod["scanner"]["name"] == "riegl_vz400"


def test_a_scanner_mount_that_no_one_can_carry_is_refused():
    with pytest.raises(ConfigError, match=r"^mount height_m must be a number in \[0, 5\] \(metres, for a walking "
                                          r"operator\), got 12$"):
        Mount(height_m=12.0)
    with pytest.raises(ConfigError, match="^mount forward_m must be a finite number, got nan$"):
        Mount(forward_m=float("nan"))
    with pytest.raises(ConfigError, match="mounts"):
        Platform(name="empty", mounts=())
    with pytest.raises(ConfigError, match=r"^platform 'fast': walking_speed_m_s must be a number in \[0.05, 5\], "
                                          r"got 9$"):
        Platform(name="fast", mounts=(Mount(),), walking_speed_m_s=9.0)


def test_multibeam_scanner_checks_its_own_numbers():
    with pytest.raises(ScannerSettingsError, match="rotation_hz"):
        MultiBeamScanner(name="x", beam_elevation_deg=(0.0,), beam_azimuth_offset_deg=(0.0,), firing_offset_us=(0.0,),
                         rotation_hz=50.0)


@pytest.fixture(scope="module")
def placed(box_room_ifc):
    """The box room and a scanner placed by the survey (with its components' surfaces)."""
    from bimscan.survey.survey import place_scanner

    scene = load_scene(box_room_ifc)
    return scene, place_scanner(scene, ScanRecipe())


def floor_points(cloud: PointCloud) -> np.ndarray:
    """Mask of the points on the room's floor: the flat component lowest down (normal +z)."""
    flat = [c for c in np.unique(cloud.component) if np.std(cloud.xyz[cloud.component == c, 2]) < 0.01]
    floor = min(flat, key=lambda c: np.mean(cloud.xyz[cloud.component == c, 2]))
    return cloud.component == floor


def test_mobile_points_take_colour_and_range_noise_that_grows_with_range_and_incidence(placed):
    scene, scanner = placed
    track, platform = walking(0.5), upright(tilt=90.0)  # the lidar on its side: the floor at every incidence
    noise = NoiseModel(range_sigma_m=0.005, angle_sigma_deg=0.0)
    paper = scan(scanner, track, mobile_recipe(platform, noise=noise, seed=3))
    coloured = scan(scanner, track, mobile_recipe(platform, noise=noise, seed=3,
                                                  sensor=SensorModel(color=True, color_noise=0.0, ambient=0.5)))
    for column in ("xyz", "time", "ring", "label", "component", "sensor_xyz"):  # the same pulses, the same draws
        assert np.allclose(getattr(coloured, column), getattr(paper, column), atol=1e-9), column
    assert paper.rgb is None and coloured.rgb is not None
    floor = floor_points(coloured)
    d = coloured.xyz[floor] - coloured.sensor_xyz[floor]
    shade = 0.5 + 0.5 * np.abs(d[:, 2]) / np.linalg.norm(d, axis=1)
    style = coloured.rgb[floor].astype(float) / shade[:, None]  # the floor's style colour, whatever the incidence
    assert floor.sum() > 10_000 and np.ptp(shade) > 0.3
    assert np.ptp(style, axis=0).max() < 1.0 / shade.min() + 1.0  # rounding to integers only

    exact = scan(scanner, track, mobile_recipe(platform, seed=3, sensor=SensorModel(geometric_noise=True,
                                                                                     range_noise_ppm=0.0)))
    noisy = scan(scanner, track, mobile_recipe(platform, noise=noise, seed=3,
                                               sensor=SensorModel(geometric_noise=True, range_noise_ppm=1000.0)))
    assert np.array_equal(exact.time, noisy.time)
    on_floor = floor_points(exact)
    d = exact.xyz[on_floor] - exact.sensor_xyz[on_floor]
    distance = np.linalg.norm(d, axis=1)
    cos = np.maximum(np.abs(d[:, 2]) / distance, math.cos(math.radians(SensorModel().max_incidence_deg)))
    error = np.linalg.norm(noisy.xyz[on_floor] - noisy.sensor_xyz[on_floor], axis=1) - distance
    z = error / ((0.005 + 1e-3 * distance) / cos)
    assert z.std() == pytest.approx(1.0, rel=0.03) and abs(z.mean()) < 4 / math.sqrt(len(z))
    assert error[cos < 0.5].std() > 2.0 * error[cos > 0.9].std()


def test_mobile_effects_do_not_depend_on_the_chunk_size_and_as_built_points_lie_on_the_moved_mesh(box_room_ifc):
    import open3d as o3d

    from bimscan.survey.survey import place_scanner

    scene = load_scene(box_room_ifc)
    full = mobile_recipe(upright(), seed=5, noise=NoiseModel(range_sigma_m=0.005, angle_sigma_deg=0.01),
                         sensor=SensorModel(realism="full", waviness_m=0.002))
    scanner = place_scanner(scene, full)
    whole = scan(scanner, walking(0.3), full)
    chunked = scan(scanner, walking(0.3), dataclasses.replace(full, chunk_pulses=1000))
    for column in ("xyz", "time", "ring", "component", "sensor_xyz", "intensity", "rgb"):
        assert np.array_equal(getattr(whole, column), getattr(chunked, column)), column

    as_built = mobile_recipe(upright(), seed=5, sensor=SensorModel(deviations=True, position_tolerance_m=0.05,
                                                                   level_tolerance_m=0.04))
    scanner = place_scanner(scene, as_built)
    cloud = scan(scanner, walking(0.3), as_built)

    def distance(mesh) -> np.ndarray:
        surfaces = o3d.t.geometry.RaycastingScene()
        surfaces.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                               o3d.core.Tensor(mesh.faces.astype(np.uint32)))
        return surfaces.compute_distance(o3d.core.Tensor(cloud.xyz.astype(np.float32))).numpy()

    assert distance(scanner.mesh).max() < 2e-4  # on the as-built surfaces
    assert np.median(distance(scene.mesh)) > 1e-3  # not where the IFC has them

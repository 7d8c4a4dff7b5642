"""Risley-prism lidars: the optics (Snell's law through turning wedges), the built-in patterns
against their datasheets, the field-of-view coverage measure, and scanning from a moving platform."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bimscan.errors import ConfigError, ScannerSettingsError
from bimscan.pipeline import load_scene
from bimscan.scan.device import load_scanner
from bimscan.scan.lidars import MOBILE_LIDARS, load_lidar
from bimscan.scan.noise import NoiseModel
from bimscan.scan.risley import RISLEY_SCANNERS, Prism, RisleyScanner, fov_coverage
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.survey.mobile import MobileScan
from bimscan.survey.platform import Mount, Platform
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.trajectory import Trajectory
from bimscan.types import PointCloud


def one_prism(wedge_deg: float, index: float, face: str = "entrance", rotation_hz: float = 10.0) -> RisleyScanner:
    return RisleyScanner(name="one", prisms=(Prism(wedge_deg=wedge_deg, refractive_index=index, rotation_hz=rotation_hz,
                                                   inclined_face=face),))


@pytest.mark.parametrize("face", ["entrance", "exit"])
def test_one_wedge_deviates_the_beam_by_the_closed_form_of_snells_law(face):
    wedge, n = math.radians(20.0), 1.51
    if face == "entrance":  # enters the inclined face at the wedge angle, leaves the flat face
        inside = wedge - math.asin(math.sin(wedge) / n)
        expected = math.asin(n * math.sin(inside))
    else:  # crosses the flat face straight, leaves the inclined face at incidence = the wedge angle
        expected = math.asin(n * math.sin(wedge)) - wedge
    scanner = one_prism(20.0, n, face)
    t = np.linspace(0.0, 0.1, 7)
    d = scanner.directions(t)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.arccos(d[:, 2]), expected, atol=1e-12)
    # the deviation turns with the prism: its azimuth follows 360 degrees x rotation_hz x t (towards the
    # wedge's thick end, away from the inclined face's normal)
    azimuth = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    np.testing.assert_allclose(np.diff(azimuth), 2 * math.pi * 10.0 * np.diff(t), atol=1e-12)


def test_a_thin_wedge_deviates_by_n_minus_one_times_its_angle():
    scanner = one_prism(0.5, 1.5)
    deviation = math.degrees(math.acos(scanner.directions(np.zeros(1))[0, 2]))
    assert deviation == pytest.approx(0.25, rel=1e-3)  # (n - 1) alpha, the thin-prism law


def test_wedges_that_reflect_the_beam_totally_are_refused():
    with pytest.raises(ScannerSettingsError, match="totally reflected"):
        one_prism(55.0, 2.0)
    with pytest.raises(ScannerSettingsError, match="channel_x_deg and channel_y_deg"):
        RisleyScanner(name="x", prisms=(Prism(wedge_deg=5.0, rotation_hz=1.0),), channel_x_deg=(0.0, 1.0),
                      channel_y_deg=(0.0,))


@pytest.mark.parametrize("name", sorted(RISLEY_SCANNERS))
def test_every_built_in_risley_pattern_spans_its_datasheet_field_of_view(name):
    scanner = RISLEY_SCANNERS[name]
    across, along = scanner.pattern_extent_deg()
    wide = along if scanner.spinning else max(across, along)  # a spinning head: 360 by its vertical FOV
    assert wide == pytest.approx(scanner.fov_deg, abs=1.0)
    with pytest.raises(ConfigError, match="Risley-prism lidar for mobile scanning"):
        load_scanner(name)


def test_the_datasheets_two_axis_fields_of_view():
    assert RISLEY_SCANNERS["livox_mid40"].pattern_extent_deg() == pytest.approx((38.4, 38.4), abs=0.2)
    assert RISLEY_SCANNERS["livox_mid70"].pattern_extent_deg() == pytest.approx((70.4, 70.4), abs=0.2)
    avia_x, avia_y = RISLEY_SCANNERS["livox_avia"].pattern_extent_deg()  # "FOV 70.4 x 77.2 degrees"
    assert sorted([avia_x, avia_y]) == pytest.approx([70.4, 77.2], abs=0.5)
    line_x, line_y = RISLEY_SCANNERS["dji_zenmuse_l2_repetitive"].pattern_extent_deg()  # "70 x 3 degrees"
    assert line_y == pytest.approx(70.0, abs=0.5) and line_x < 6.0


def test_the_mid360_like_head_scans_360_degrees_by_its_datasheet_band_at_200k_points_a_second():
    """Livox Mid-360: "FOV 360 degrees horizontal, -7 to 52 degrees vertical", 200,000 points/s,
    four lasers; the head's optics are assumed (its scanner file), the figures are Livox's."""
    mid360 = RISLEY_SCANNERS["livox_mid360"]
    assert mid360.spinning and mid360.n_beams == 4 and mid360.total_pulse_rate_hz == 200_000
    low, high = mid360.elevation_range_deg(0.1)  # every frame (10 Hz) reaches both edges of the band
    assert low == pytest.approx(-7.0, abs=0.05) and high == pytest.approx(52.0, abs=0.05)
    azimuth_extent, _ = mid360.pattern_extent_deg(0.1)
    assert azimuth_extent > 359.5
    # the four lasers' bands abut: every degree of the band is reached within a second
    t = np.arange(50_000) / mid360.pulse_rate_hz
    elevation = np.degrees(np.arcsin(np.concatenate([mid360.directions(t, c)[:, 2] for c in range(4)])))
    counts = np.histogram(elevation, bins=59, range=(-7.0, 52.0))[0]
    assert counts.min() > 0.2 * counts.mean()
    # non-repetitive: a frame does not retrace the last one
    first, later = mid360.directions(t[:20000], 1), mid360.directions(t[:20000] + 0.1, 1)
    assert np.degrees(np.arccos(np.clip((first * later).sum(axis=1), -1, 1))).mean() > 1.0


def test_a_spinning_head_turns_the_optics_about_the_sensor_z_axis():
    """The head's formula (scan.risley's docs) against the rotation it describes: the optics' frame
    raised by the axis elevation, then turned by 360 spin_hz t about z."""
    from scipy.spatial.transform import Rotation

    head = RisleyScanner(name="head", prisms=(Prism(wedge_deg=8.0, rotation_hz=37.0),), channel_x_deg=(5.0,),
                         channel_y_deg=(-3.0,), spin_hz=4.0, axis_elevation_deg=20.0)
    still = dataclasses.replace(head, spin_hz=0.0, axis_elevation_deg=0.0)
    t = np.linspace(0.0, 0.3, 11)
    optics = still.directions(t)
    # optics frame (x up-across, y, z along the axis) -> sensor frame at spin 0 and elevation 0: z -> x, x -> z
    to_sensor = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    for k, time in enumerate(t.tolist()):
        turn = Rotation.from_euler("yz", [-20.0, 360.0 * 4.0 * time], degrees=True)  # about y, then about z
        np.testing.assert_allclose(head.directions(np.array([time]))[0], turn.apply(to_sensor @ optics[k]), atol=1e-12)
    with pytest.raises(ScannerSettingsError, match="axis_elevation_deg places a spinning head"):
        dataclasses.replace(head, spin_hz=0.0)


def test_a_spinning_head_is_refused_where_its_optics_cannot_go(tmp_path):
    from bimscan.io.helios import helios_risley_scanner_xml
    from bimscan.survey.flight import check_pointable

    mid360 = RISLEY_SCANNERS["livox_mid360"]
    with pytest.raises(ConfigError, match="do not spin"):
        helios_risley_scanner_xml(mid360)
    with pytest.raises(ConfigError, match="spinning head"):
        check_pointable(mid360)


def test_the_non_repetitive_pattern_does_not_repeat_and_the_repetitive_one_does():
    rosette, line = RISLEY_SCANNERS["livox_mid40"], RISLEY_SCANNERS["dji_zenmuse_l2_repetitive"]
    t = np.arange(20000) / rosette.pulse_rate_hz
    first, later = rosette.directions(t), rosette.directions(t + 0.1)
    assert np.degrees(np.arccos(np.clip((first * later).sum(axis=1), -1, 1))).mean() > 1.0
    period = 1.0 / 50.0 * 1.0  # the L2's prisms turn at 50, -50 and -150 Hz: every 20 ms the same
    t = np.arange(5000) / line.pulse_rate_hz
    np.testing.assert_allclose(line.directions(t + period, 2), line.directions(t, 2), atol=1e-9)


def test_coverage_of_random_spots_is_what_the_poisson_law_predicts():
    rng = np.random.default_rng(0)
    fov, spot, count = 20.0, 0.3, 6000
    radius = np.radians(fov / 2) * np.sqrt(rng.uniform(0, 1, count))  # uniform over the disc (small angles)
    azimuth = rng.uniform(0, 2 * np.pi, count)
    d = np.column_stack([np.sin(radius) * np.cos(azimuth), np.sin(radius) * np.sin(azimuth), np.cos(radius)])
    expected = 1 - math.exp(-count * (spot / 2) ** 2 / (fov / 2) ** 2)
    assert fov_coverage(d, fov, spot, cell_deg=0.01) == pytest.approx(expected, abs=0.02)


def test_the_mid40_fills_its_field_of_view_over_time_as_livox_describes():
    """Livox: "the FOV coverage of Livox Mid series sensors within 100 ms is similar to that of
    traditional 32-line LiDAR sensors" (about 20 %), and it grows with the integration time."""
    mid40 = RISLEY_SCANNERS["livox_mid40"]
    spot = math.degrees(mid40.beam_divergence_rad)
    shares = [fov_coverage(mid40.directions(np.arange(int(s * mid40.pulse_rate_hz)) / mid40.pulse_rate_hz),
                           mid40.fov_deg, spot, cell_deg=0.04) for s in (0.1, 0.5)]
    assert 0.15 <= shares[0] <= 0.25 and 0.6 <= shares[1] <= 0.75


def test_lidar_files_of_both_kinds_load_and_a_tls_file_is_refused(tmp_path):
    assert set(RISLEY_SCANNERS) <= set(MOBILE_LIDARS)
    path = tmp_path / "wedge.toml"
    path.write_text('name = "wedge"\nkind = "risley"\npulse_rate_hz = 50000\n[[prisms]]\nwedge_deg = 10\n'
                    'rotation_hz = 30\n[[prisms]]\nwedge_deg = 10\nrotation_hz = -20\n')
    lidar = load_lidar(path)
    assert isinstance(lidar, RisleyScanner) and len(lidar.prisms) == 2 and lidar.total_pulse_rate_hz == 50000
    path.write_text('name = "bad"\nkind = "risley"\n[[prisms]]\nwedge_deg = 10\nrotation_hz = 30\nspeed = 3\n')
    with pytest.raises(ConfigError, match="speed"):
        load_lidar(path)


def test_a_rotation_rate_for_a_risley_lidar_is_refused():
    platform = Platform(name="p", mounts=(Mount(),))
    with pytest.raises(ScannerSettingsError, match="no head rotation rate"):
        MobileScan(platform=platform, lidar=RISLEY_SCANNERS["livox_mid70"], rotation_hz=10.0)
    assert MobileScan(platform=platform, lidar=RISLEY_SCANNERS["livox_mid70"]).rotation_hz is None


@pytest.fixture(scope="module")
def box(box_room_ifc):
    scene = load_scene(box_room_ifc)
    return scene, VirtualScanner(scene.mesh, scene.components.label, scanner=load_scanner())


def test_a_standing_risley_scan_in_a_closed_room_returns_every_pulse_along_the_optics(box):
    _, scanner = box
    lidar = RISLEY_SCANNERS["livox_avia"]
    platform = Platform(name="p", mounts=(Mount(height_m=1.5, tilt_deg=0.0),))  # looking up, at the ceiling
    recipe = ScanRecipe(noise=NoiseModel.off(), mobile=MobileScan(platform=platform, lidar=lidar))
    t = np.array([0.0, 0.05])
    still = Trajectory(t=t, xyz=np.array([[4.0, 3.0, 0.0]] * 2), roll=np.zeros(2), pitch=np.zeros(2),
                       yaw=np.zeros(2), pass_id=np.zeros(2, dtype=np.int32))
    cloud = PointCloud.concatenate(list(scanner.scan_pass(still, slice(None), 0, 0, recipe)))
    fired = recipe.mobile.pass_pulses(0.05)
    assert fired == 6 * int(0.05 * 40000) and len(cloud) == fired  # a closed room: every pulse returns
    assert np.array_equal(np.bincount(cloud.ring, minlength=6), np.full(6, fired // 6))
    ray = cloud.xyz - cloud.sensor_xyz
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    for channel in range(6):
        mine = cloud.ring == channel
        np.testing.assert_allclose(ray[mine], lidar.directions(cloud.time[mine], channel), atol=2e-5)
    np.testing.assert_allclose(cloud.sensor_xyz, [[4.0, 3.0, 1.5]] * len(cloud), atol=1e-9)


def test_a_standing_mid360_scan_returns_every_pulse_along_its_spinning_optics(box):
    _, scanner = box
    lidar = RISLEY_SCANNERS["livox_mid360"]
    platform = Platform(name="p", mounts=(Mount(height_m=1.2, tilt_deg=0.0),))  # upright: its head turns about z
    recipe = ScanRecipe(noise=NoiseModel.off(), mobile=MobileScan(platform=platform, lidar=lidar))
    t = np.array([0.0, 0.1])
    still = Trajectory(t=t, xyz=np.array([[4.0, 3.0, 0.0]] * 2), roll=np.zeros(2), pitch=np.zeros(2),
                       yaw=np.zeros(2), pass_id=np.zeros(2, dtype=np.int32))
    cloud = PointCloud.concatenate(list(scanner.scan_pass(still, slice(None), 0, 0, recipe)))
    assert len(cloud) == recipe.mobile.pass_pulses(0.1) == 4 * int(0.1 * 50000)  # a closed room: all return
    ray = cloud.xyz - cloud.sensor_xyz
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    for channel in range(4):
        mine = cloud.ring == channel
        np.testing.assert_allclose(ray[mine], lidar.directions(cloud.time[mine], channel), atol=2e-5)
    elevation = np.degrees(np.arcsin(np.clip(ray[:, 2], -1, 1)))
    assert elevation.min() == pytest.approx(-7.0, abs=0.1) and elevation.max() == pytest.approx(52.0, abs=0.1)
    azimuth = np.sort(np.degrees(np.arctan2(ray[:, 1], ray[:, 0])))
    assert np.diff(np.r_[azimuth, azimuth[0] + 360]).max() < 1.0  # one turn of the head: all round


def test_a_risley_scan_is_the_same_bytes_in_any_chunking(box):
    _, scanner = box
    platform = Platform(name="p", mounts=(Mount(height_m=1.2, tilt_deg=90.0, head_rotation_hz=0.5),))
    recipe = ScanRecipe(noise=NoiseModel(), seed=4, mobile=MobileScan(platform=platform,
                                                                      lidar=RISLEY_SCANNERS["livox_mid70"]))
    t = np.linspace(0.0, 0.3, 5)
    walk = Trajectory(t=t, xyz=np.column_stack([2 + 10 * t, np.full(5, 3.0), np.zeros(5)]), roll=np.zeros(5),
                      pitch=np.zeros(5), yaw=np.radians(30 * t), pass_id=np.zeros(5, dtype=np.int32))
    whole = PointCloud.concatenate(list(scanner.scan_pass(walk, slice(None), 0, 0, recipe)))
    pieces = PointCloud.concatenate(list(scanner.scan_pass(walk, slice(None), 0, 0,
                                                           dataclasses.replace(recipe, chunk_pulses=997))))
    assert len(whole) > 20000
    for column in ("xyz", "time", "ring", "label", "intensity"):
        assert np.array_equal(getattr(whole, column), getattr(pieces, column))


def test_a_turned_mount_on_a_turned_platform_points_the_pattern_and_the_prisms_start_at_the_trajectory(box):
    """A mount tilted and turned on a platform turned and pitched, on a clock starting at 100 s: each
    point lies along R_platform R_mount d(t - 100), d the sensor-frame direction of its channel."""
    from scipy.spatial.transform import Rotation

    _, scanner = box
    lidar = RISLEY_SCANNERS["livox_avia"]
    mount = Mount(height_m=1.0, forward_m=0.3, tilt_deg=70.0, yaw_deg=20.0)
    recipe = ScanRecipe(noise=NoiseModel.off(), mobile=MobileScan(platform=Platform(name="p", mounts=(mount,)),
                                                                 lidar=lidar))
    t = np.array([100.0, 100.02])
    yaw, pitch = math.radians(30.0), math.radians(10.0)
    still = Trajectory(t=t, xyz=np.array([[4.0, 3.0, 0.5]] * 2), roll=np.zeros(2), pitch=np.full(2, pitch),
                       yaw=np.full(2, yaw), pass_id=np.zeros(2, dtype=np.int32))
    cloud = PointCloud.concatenate(list(scanner.scan_pass(still, slice(None), 0, 0, recipe)))
    assert len(cloud) == recipe.mobile.pass_pulses(0.02)
    turn = Rotation.from_euler("ZYX", [yaw, pitch, 0.0]).as_matrix() @ mount.rotation()
    ray = cloud.xyz - cloud.sensor_xyz
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    for channel in range(lidar.n_beams):
        mine = cloud.ring == channel
        expected = lidar.directions(cloud.time[mine] - 100.0, channel) @ turn.T
        np.testing.assert_allclose(ray[mine], expected, atol=2e-5)
    np.testing.assert_allclose(cloud.sensor_xyz[0], [4.0, 3.0, 0.5] + turn @ [0, 0, 0] + Rotation.from_euler(
        "ZYX", [yaw, pitch, 0.0]).as_matrix() @ mount.lever_arm(), atol=1e-9)

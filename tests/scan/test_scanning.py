"""The virtual scanner on real geometry: counts, surfaces, window, coverage, noise, determinism."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from bimscan.pipeline import load_scene
from bimscan.scan.noise import NoiseModel
from bimscan.scan.pattern import PulsePattern
from bimscan.scan.device import PRESETS, SCANNERS, ScanSettings
from bimscan.survey.recipe import ScanRecipe
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.types import PointCloud, Station

VZ400 = SCANNERS["riegl_vz400"]
EXACT = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36)
CENTRE = Station(id=0, position=(4.0, 3.0, 1.7))


@pytest.fixture(scope="module")
def box(box_room_ifc):
    scene = load_scene(box_room_ifc)
    return scene, VirtualScanner(scene.mesh, scene.components.label, scanner=VZ400)


def scan(scanner, station=CENTRE, settings=EXACT, noise=NoiseModel.off(), seed=0, **recipe_fields) -> PointCloud:
    recipe = ScanRecipe(scanner=scanner.scanner, settings=settings, preset=None, noise=noise, seed=seed, **recipe_fields)
    return PointCloud.concatenate(list(scanner.scan_station(station, recipe)))


def distances_to_components(scene, cloud: PointCloud) -> np.ndarray:
    """Distance of every point to the surface of the component it is labelled with."""
    out = np.empty(len(cloud))
    for c in np.unique(cloud.component):
        faces = scene.mesh.faces[scene.mesh.face_component == c]
        rs = o3d.t.geometry.RaycastingScene()
        rs.add_triangles(o3d.core.Tensor(scene.mesh.vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
        mask = cloud.component == c
        out[mask] = rs.compute_distance(o3d.core.Tensor(cloud.xyz[mask].astype(np.float32))).numpy()
    return out


def test_a_closed_room_scanned_from_its_centre_gives_exactly_the_predicted_pulse_count(box):
    _, scanner = box
    cloud = scan(scanner)
    assert len(cloud) == 100_000 == EXACT.expected_pulses(VZ400)


def test_without_noise_every_point_lies_on_the_component_it_is_labelled_with(box):
    scene, scanner = box
    cloud = scan(scanner)
    assert distances_to_components(scene, cloud).max() < 1e-4
    assert np.array_equal(cloud.label, scene.components.label[cloud.component])


def test_points_respect_the_elevation_window_and_cover_360_degrees(box):
    _, scanner = box
    cloud = scan(scanner)
    d = cloud.xyz - np.array(CENTRE.position)
    elevation = np.degrees(np.arctan2(d[:, 2], np.hypot(d[:, 0], d[:, 1])))
    azimuth = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 360
    assert elevation.min() >= -40 - 1e-3 and elevation.max() < 60 + 1e-3
    assert elevation.min() < -39 and elevation.max() > 59  # the whole window is used
    assert np.histogram(azimuth, bins=36, range=(0, 360))[0].min() > 0.8 * len(cloud) / 36


def test_the_head_heading_rotates_the_start_of_the_scan(box):
    _, scanner = box
    settings = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36, head_stop_deg=90)
    turned = Station(id=0, position=CENTRE.position, heading_deg=180)
    d = scan(scanner, turned, settings).xyz - np.array(CENTRE.position)
    azimuth = np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 360
    assert azimuth.min() > 179 and azimuth.max() < 271


def test_noise_matches_the_configured_sigmas_pulse_by_pulse(box):
    _, scanner = box
    settings = ScanSettings(pulse_freq_hz=60000, scan_freq_hz=100, head_deg_per_s=36)
    exact = scan(scanner, settings=settings)
    noisy = scan(scanner, settings=settings, noise=NoiseModel(range_sigma_m=0.005, angle_sigma_deg=0.03), seed=7)
    assert np.array_equal(exact.time, noisy.time)  # the same pulses hit (min range is far from every wall)
    o = np.array(CENTRE.position)
    a, b = exact.xyz - o, noisy.xyz - o
    range_error = np.linalg.norm(b, axis=1) - np.linalg.norm(a, axis=1)
    el_error = np.degrees(np.arctan2(b[:, 2], np.hypot(b[:, 0], b[:, 1])) - np.arctan2(a[:, 2], np.hypot(a[:, 0], a[:, 1])))
    az_error = np.degrees((np.arctan2(b[:, 1], b[:, 0]) - np.arctan2(a[:, 1], a[:, 0]) + math.pi) % (2 * math.pi) - math.pi)
    n = len(exact)
    assert n > 200_000
    for error, sigma in ((range_error, 0.005), (el_error, 0.03), (az_error, 0.03)):
        assert abs(error.mean()) < 4 * sigma / math.sqrt(n)
        assert error.std() == pytest.approx(sigma, rel=0.01)
    # independent draws: range and angle errors uncorrelated
    assert abs(np.corrcoef(range_error, el_error)[0, 1]) < 0.01
    # and the distance to the hit surface follows: |signed distance| / cos(incidence) ~ range noise on walls
    assert np.median(np.abs(range_error)) == pytest.approx(0.005 * 0.6745, rel=0.03)


def test_output_is_identical_whatever_the_chunk_size(box):
    _, scanner = box
    noise = NoiseModel()
    big = scan(scanner, noise=noise, seed=3)
    small = scan(scanner, noise=noise, seed=3, chunk_pulses=7_000)
    for column in PointCloud.COLUMNS:
        assert np.array_equal(getattr(big, column), getattr(small, column)), column


def test_output_is_identical_whatever_the_thread_count(box_room_ifc):
    scene = load_scene(box_room_ifc)
    clouds = []
    for threads in (1, 2):
        scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=VZ400, threads=threads)
        clouds.append(scan(scanner, noise=NoiseModel(), seed=5))
    for column in PointCloud.COLUMNS:
        assert np.array_equal(getattr(clouds[0], column), getattr(clouds[1], column)), column


def test_different_seeds_and_stations_draw_different_noise(box):
    _, scanner = box
    a = scan(scanner, noise=NoiseModel(), seed=1)
    b = scan(scanner, noise=NoiseModel(), seed=2)
    c = scan(scanner, Station(id=1, position=CENTRE.position), noise=NoiseModel(), seed=1)
    assert not np.allclose(a.xyz, b.xyz) and not np.allclose(a.xyz, c.xyz)


def test_points_beyond_range_limits_are_dropped(box_room_ifc):
    scene = load_scene(box_room_ifc)
    from dataclasses import replace

    short = replace(VZ400, max_range_m=3.0)
    scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=short)
    cloud = scan(scanner)
    ranges = np.linalg.norm(cloud.xyz - np.array(CENTRE.position), axis=1)
    assert 0 < len(cloud) < 100_000 and ranges.max() <= 3.0 + 1e-5 and ranges.min() >= 1.5


def test_intensity_follows_the_documented_model_on_a_wall(box):
    # intensity = 65535 * reflectance (0.5) * |cos incidence| * min(1, (5 m / range)^2), rounded
    _, scanner = box
    cloud = scan(scanner)
    d = cloud.xyz - np.array(CENTRE.position)
    r = np.linalg.norm(d, axis=1)
    east = np.abs(cloud.xyz[:, 0] - 8.0) < 1e-6  # the inner face of the east wall, normal along x
    expected = 65535 * 0.5 * np.abs(d[east, 0]) / r[east] * np.minimum(1.0, (5.0 / r[east]) ** 2)
    assert east.sum() > 1000
    assert np.abs(cloud.intensity[east] - expected).max() <= 1.0


def test_rays_through_an_opening_yield_no_points(tiny_model, tmp_path):
    # a floor and one wall only: everything above the horizon that misses the wall escapes
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(-5, -5, -0.3), size=(10, 10, 0.3))
    model.add_box("IfcWall", origin=(-5, 3, 0), size=(10, 0.2, 3))
    scene = load_scene(model.write(tmp_path / "open.ifc"))
    scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=VZ400)
    cloud = scan(scanner, Station(id=0, position=(0.0, 0.0, 1.7)))
    pattern_count = PulsePattern.of(EXACT, VZ400).count()
    assert 0 < len(cloud) < pattern_count
    assert np.isfinite(cloud.xyz).all()


def test_extents_stay_while_counts_grow_with_the_pulse_rate(box):
    scene, scanner = box
    counts, extents = {}, {}
    for name, preset in PRESETS.items():
        from dataclasses import replace

        cloud = scan(scanner, settings=replace(preset, head_deg_per_s=60.0), noise=NoiseModel(), seed=1)
        counts[name] = len(cloud)
        extents[name] = cloud.xyz.max(axis=0) - cloud.xyz.min(axis=0)
    assert counts["exp1"] < counts["exp3"] < counts["exp5"]
    assert counts["exp2"] < counts["exp4"] < counts["exp6"]
    for name in counts:
        np.testing.assert_allclose(extents[name], extents["exp6"], atol=0.05)


def test_registration_error_moves_each_station_rigidly_by_the_configured_sigmas(box):
    from bimscan.scan.kernels import noise_key
    from bimscan.scan.virtual_scanner import registration_error

    _, scanner = box
    noise = NoiseModel(range_sigma_m=0.0, angle_sigma_deg=0.0, registration_sigma_m=0.01, registration_sigma_deg=0.05)
    exact = scan(scanner)
    moved = scan(scanner, noise=noise, seed=9)
    assert np.array_equal(exact.time, moved.time)
    rotation, shift = registration_error(noise, np.uint64(noise_key(9, 0)))
    o = np.array(CENTRE.position)
    np.testing.assert_allclose(moved.xyz, (exact.xyz - o) @ rotation.T + o + shift, atol=1e-9)
    # rigid: distances between points are kept
    i, j = np.arange(0, len(exact), 997), np.arange(5, len(exact), 997)[: len(np.arange(0, len(exact), 997))]
    i = i[: len(j)]
    np.testing.assert_allclose(np.linalg.norm(moved.xyz[i] - moved.xyz[j], axis=1),
                               np.linalg.norm(exact.xyz[i] - exact.xyz[j], axis=1), atol=1e-9)
    # over many stations the draws follow the sigmas
    draws = np.array([registration_error(noise, np.uint64(noise_key(9, s)))[1] for s in range(4000)])
    assert draws.std(axis=0) == pytest.approx([0.01] * 3, rel=0.06)


def test_noise_quantiles_match_the_normal_distribution_to_2e_5_sigma():
    from scipy.special import ndtri

    from bimscan.scan.kernels import _normal_from_bits

    rng = np.random.default_rng(0)
    bits = np.concatenate([rng.integers(0, 2**32, 20000, dtype=np.uint64), np.arange(0, 300, dtype=np.uint64),
                           2**32 - 1 - np.arange(0, 300, dtype=np.uint64), 2**31 + np.arange(-300, 300).astype(np.uint64)])
    values = np.array([_normal_from_bits(np.uint64(b)) for b in bits])
    exact = ndtri((bits.astype(np.float64) + 0.5) / 2**32)
    assert np.abs(values - exact).max() < 2e-5

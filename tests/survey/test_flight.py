"""Drone flights: the planned flight's geometry (clearance, heights, grid, take-off), the ground
around the building, the GNSS/INS error, a drone scan end to end, and what a drone refuses."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from matplotlib.path import Path as PolygonPath

from bimscan.errors import ConfigError, ScannerSettingsError
from bimscan.io import read_cloud, read_cloud_header
from bimscan.pipeline import load_scene, scan_model
from bimscan.scan.risley import RISLEY_SCANNERS
from bimscan.site.model import SiteModel
from bimscan.survey.drift import GnssInsModel, drift_track, gauss_markov
from bimscan.survey.flight import FlightSettings, footprint_hull, lidar_half_extent_deg, plan_flight
from bimscan.survey.platform import PLATFORMS, load_platform
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.trajectory import Trajectory

L2 = RISLEY_SCANNERS["dji_zenmuse_l2"]
# an L-shaped building 30 x 20 m, 12 m high, its ground floor at z = 0
PLAN = np.array([[0, 0], [30, 0], [30, 8], [12, 8], [12, 20], [0, 20]], dtype=float)


def distance_to_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Plan distance of each point to a closed polygon's edges."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    ab = b - a
    t = np.clip(((points[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    nearest = a + t[..., None] * ab
    return np.linalg.norm(points[:, None, :] - nearest, axis=-1).min(axis=1)


@pytest.fixture(scope="module")
def flight():
    settings = FlightSettings()
    trajectory, report = plan_flight(PLAN, (-0.3, 12.0), (0.0, 4.0, 8.0), settings, lidar_half_extent_deg(L2))
    return settings, trajectory, report


def test_orbits_keep_their_clearance_and_face_the_building(flight):
    settings, trajectory, report = flight
    hull = footprint_hull(PLAN)
    on_orbit = np.isin(np.round(trajectory.xyz[:, 2], 6), np.round(report.orbit_heights, 6))
    xy = trajectory.xyz[on_orbit, :2]
    assert on_orbit.sum() > 50
    inside = PolygonPath(hull).contains_points(xy)
    assert not inside.any()
    assert distance_to_polygon(xy, hull).min() >= settings.orbit_clearance_m - 0.05
    # facing the building: each leg of an orbit is flown facing the left normal of its direction of
    # travel (the ring is counter-clockwise), to within a micro-degree
    on_ring = on_orbit & (distance_to_polygon(trajectory.xyz[:, :2], hull) <= settings.orbit_clearance_m + 1e-6)
    index = np.flatnonzero(on_ring[1:] & on_ring[:-1]) + 1  # legs along the ring (not the way to it)
    travel = trajectory.xyz[index, :2] - trajectory.xyz[index - 1, :2]
    moving = np.linalg.norm(travel, axis=1) > 1e-6
    travel = travel[moving] / np.linalg.norm(travel[moving], axis=1, keepdims=True)
    yaw = trajectory.yaw[index[moving]]
    facing = np.column_stack([np.cos(yaw), np.sin(yaw)])
    left = np.column_stack([-travel[:, 1], travel[:, 0]])
    np.testing.assert_allclose((facing * left).sum(axis=1), 1.0, atol=1e-9)
    towards = hull.mean(axis=0) - trajectory.xyz[index[moving], :2]
    assert ((towards * facing).sum(axis=1) > 0).all()
    np.testing.assert_allclose(trajectory.pitch[on_orbit], math.radians(settings.orbit_pitch_deg), atol=1e-9)


def test_orbit_heights_cover_the_facade_and_the_grid_flies_over_the_top(flight):
    settings, trajectory, report = flight
    band = 2 * settings.orbit_clearance_m * math.tan(math.radians(lidar_half_extent_deg(L2)[0]))
    heights = np.array(report.orbit_heights)
    assert heights.min() >= 3.0 - 0.05 - 1e-9 and heights.max() <= 12.0
    assert heights.min() - band / 2 <= -0.05 and heights.max() + band / 2 >= 12.0  # every storey in a band
    assert report.grid_z == pytest.approx(12.0 + settings.grid_height_m)
    swath = 2 * settings.grid_height_m * math.tan(math.radians(lidar_half_extent_deg(L2)[1]))
    assert report.grid_spacing_m <= swath * (1 - settings.side_overlap) + 1e-9
    on_grid = np.isclose(trajectory.xyz[:, 2], report.grid_z) & np.isclose(trajectory.pitch, math.pi / 2)
    assert on_grid.sum() > 50 and trajectory.xyz[:, 2].max() == pytest.approx(report.grid_z)


def test_the_flight_takes_off_and_lands_outside_at_the_ground_within_its_limits(flight):
    settings, trajectory, report = flight
    start, end = trajectory.xyz[0], trajectory.xyz[-1]
    np.testing.assert_allclose(start, end)
    assert start[2] == pytest.approx(-0.05 + 0.3)  # the ground floor's 0 less 5 cm, plus the standing height
    assert distance_to_polygon(start[None, :2], footprint_hull(PLAN))[0] >= settings.orbit_clearance_m
    dt = np.diff(trajectory.t)
    assert (dt > 0).all()
    horizontal = np.linalg.norm(np.diff(trajectory.xyz[:, :2], axis=0), axis=1) / dt
    vertical = np.abs(np.diff(trajectory.xyz[:, 2])) / dt
    turn = np.abs(np.diff(np.unwrap(trajectory.yaw))) / dt
    assert horizontal.max() <= settings.speed_m_s * (1 + 1e-9)
    assert vertical.max() <= settings.climb_speed_m_s * (1 + 1e-9)
    assert np.degrees(turn.max()) <= settings.max_turn_deg_per_s * (1 + 1e-6)
    assert report.duration_s == pytest.approx(trajectory.duration_s())


def test_gauss_markov_error_has_its_sigma_and_correlation():
    rng = np.random.default_rng(0)
    x = gauss_markov(rng, 200_000, 0.5, 10.0, np.array([0.02, 0.5]))
    assert x[:, 0].std() == pytest.approx(0.02, rel=0.05) and x[:, 1].std() == pytest.approx(0.5, rel=0.05)
    lag = 20  # 10 s: one correlation time
    r = np.corrcoef(x[:-lag, 0], x[lag:, 0])[0, 1]
    assert r == pytest.approx(math.exp(-1.0), abs=0.03)


def test_a_gnss_track_is_reproducible_and_off_by_default(flight):
    _, trajectory, _ = flight
    model = GnssInsModel.rtk(0.01)
    a, b = drift_track(trajectory, model, 3), drift_track(trajectory, model, 3)
    assert np.array_equal(a.offset, b.offset) and np.array_equal(a.yaw, b.yaw)
    assert 0 < np.abs(a.offset[:, :2]).max() < 5 * 0.01 and 0 < np.abs(a.offset[:, 2]).max() < 5 * 0.015
    assert 0 < np.degrees(np.abs(a.yaw)).max() < 5 * 0.05
    assert GnssInsModel().is_off and not model.is_off
    assert model.vertical_sigma_m == pytest.approx(0.015) and model.heading_sigma_deg == pytest.approx(0.05)


def test_what_a_drone_refuses():
    with pytest.raises(ConfigError, match="multi-beam lidar"):
        ScanRecipe.resolve(platform="drone", lidar="velodyne_vlp16")
    with pytest.raises(ConfigError, match="a drone has none"):
        ScanRecipe.resolve(platform="drone", stations_from="stations.csv")
    with pytest.raises(ConfigError, match="no TLS 'preset'"):
        ScanRecipe.resolve(platform="drone", preset="exp1")
    with pytest.raises(ScannerSettingsError, match="no head rotation rate"):
        ScanRecipe.resolve(platform="drone", rotation_hz=10.0)
    with pytest.raises(ScannerSettingsError, match="give --gnss instead"):
        from bimscan.survey.drift import DriftModel

        ScanRecipe.resolve(platform="drone", drift=DriftModel(sigma_m=0.01))
    with pytest.raises(ScannerSettingsError, match="a GNSS/INS error"):
        ScanRecipe.resolve(platform="handheld", drift=GnssInsModel.rtk(0.01))


def test_a_walking_platform_file_with_a_flight_table_is_refused(tmp_path):
    path = tmp_path / "walker.toml"
    path.write_text("[[mounts]]\nheight_m = 1.2\n[flight]\nspeed_m_s = 3.0\n")
    with pytest.raises(ConfigError, match="a walking platform walks"):
        load_platform(path)


def test_a_drone_recipe_adds_the_ground_and_records_it_only_then():
    recipe = ScanRecipe.resolve(platform="drone")
    assert recipe.site.ground_margin_m == PLATFORMS["drone"].flight.ground_margin_m
    assert "ground_margin_m" in recipe.site.to_json()
    assert "ground_margin_m" not in SiteModel().to_json()  # a site without ground records what it did before
    assert "kind" not in ScanRecipe.resolve(platform="handheld").mobile.to_json()["platform"]


@pytest.fixture(scope="module")
def drone_scan(box_room_ifc, tmp_path_factory):
    folder = tmp_path_factory.mktemp("drone")
    platform = folder / "quick_drone.toml"
    platform.write_text('kind = "flying"\ndefault_scanner = "livox_mid70"\n[[mounts]]\nheight_m = 0.0\ntilt_deg = 90.0\n'
                        "[flight]\nspeed_m_s = 8.0\nclimb_speed_m_s = 5.0\ngrid_height_m = 8.0\n"
                        "orbit_clearance_m = 4.0\nground_margin_m = 10.0\nmax_turn_deg_per_s = 90.0\n")
    recipe = ScanRecipe.resolve(platform=str(platform), seed=5)
    result = scan_model(box_room_ifc, folder / "drone.laz", recipe, progress=False)
    return result, read_cloud(result.path)


def test_a_drone_scan_sees_the_ground_roof_and_walls_from_outside(drone_scan, box_room_ifc):
    result, cloud = drone_scan
    table = result.survey.scene.components
    ground = np.flatnonzero(table.ifc_class == "Terrain.Ground")
    assert len(ground) == 1
    names = result.survey.scene.scheme.names
    counts = {names[k]: int(v) for k, v in enumerate(np.bincount(cloud.label, minlength=len(names)))}
    on_ground = cloud.component == ground[0]
    assert on_ground.sum() > 0.2 * len(cloud) and counts["Others"] >= on_ground.sum()
    assert counts["Slab"] > 1000 and counts["Wall&Column"] > 1000  # the roof from above, the walls from the orbit
    # nothing from inside the closed room: every point lies on the outer faces or the ground
    inside = ((cloud.xyz[:, 0] > 0.01) & (cloud.xyz[:, 0] < 7.99) & (cloud.xyz[:, 1] > 0.01) & (cloud.xyz[:, 1] < 5.99)
              & (cloud.xyz[:, 2] > 0.01) & (cloud.xyz[:, 2] < 3.49))
    assert not inside.any()
    ground_z = cloud.xyz[on_ground, 2]
    assert np.median(ground_z) == pytest.approx(-0.05, abs=0.1)
    recorded = read_cloud_header(result.path).metadata["trajectory"]["flight"]
    assert recorded["grid_lines"] == result.survey.walk.grid_lines >= 1


def test_a_tripod_scan_of_a_site_with_ground_never_sees_the_ground_indoors(box_room_ifc):
    from bimscan.pipeline import site_and_stations
    from bimscan.survey.survey import prepare_survey, run_survey

    scene = load_scene(box_room_ifc)
    recipe = dataclasses.replace(ScanRecipe(), site=SiteModel(ground_margin_m=20.0))
    chosen = site_and_stations(scene, recipe)
    ground = np.flatnonzero(chosen.scene.components.ifc_class == "Terrain.Ground")[0]
    survey = prepare_survey(chosen.scene, recipe, stations=chosen.stations)
    hits = sum(int((chunk.component == ground).sum()) for chunk in run_survey(survey))
    assert hits == 0


QUICK_DRONE = ('kind = "flying"\ndefault_scanner = "livox_mid70"\n[[mounts]]\nheight_m = 0.0\ntilt_deg = 90.0\n'
               "[flight]\nspeed_m_s = 8.0\nclimb_speed_m_s = 5.0\ngrid_height_m = 8.0\norbit_clearance_m = 4.0\n"
               "ground_margin_m = 10.0\nmax_turn_deg_per_s = 90.0\n")


def test_a_dataset_spec_builds_a_drone_unit_with_its_flight_and_ground(box_room_ifc, tmp_path):
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.layout import DatasetFolder
    from bimscan.dataset.spec import load_spec
    from bimscan.survey.trajectory import read_trajectory

    (tmp_path / "quick_drone.toml").write_text(QUICK_DRONE)
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(f'name = "d"\nformats = ["npy"]\n[[scenes]]\nname = "box"\nifc = "{box_room_ifc}"\n'
                         '[[configs]]\nname = "fly"\nplatform = "quick_drone.toml"\n')
    report = build_dataset(load_spec(spec_path), tmp_path / "ds", executor="serial", progress=False)
    assert [e.status for e in report.entries] == ["done"] and report.failed == 0
    unit = DatasetFolder(tmp_path / "ds").unit_dir("box__fly")
    flight = read_trajectory(unit / "trajectory.csv")
    assert flight.xyz[:, 2].max() == pytest.approx(3.8 + 8.0, abs=0.01)  # the grid over the roof's top
    cloud = read_cloud(unit / "cloud")
    assert cloud.ring is not None and (cloud.label == 4).sum() > 0.2 * len(cloud)  # Others: the ground, mostly


def test_yard_objects_stand_on_the_ground_outside_the_footprint_apart_and_reproducibly(box_room_ifc):
    from bimscan.site.ground import YARD_CLEARANCE_M, yard_objects
    from bimscan.survey.flight import footprint_hull

    scene = load_scene(box_room_ifc)
    objects = yard_objects(scene, 20.0, 2.0, seed=3)
    again = yard_objects(scene, 20.0, 2.0, seed=3)
    area = (8.5 + 40) * (6.5 + 40) - (8.5 + 2 * YARD_CLEARANCE_M) * (6.5 + 2 * YARD_CLEARANCE_M)
    assert 0.8 * 2.0 * area / 100 <= len(objects) <= 2.0 * area / 100 + 1  # a few may find no free spot
    assert [o.kind for o in objects] == [o.kind for o in again]
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(objects, again))
    hull = footprint_hull(scene.mesh.vertices[:, :2])
    for obj in objects:
        assert obj.vertices[:, 2].min() == pytest.approx(-0.05, abs=1e-9)  # on the ground
        assert distance_to_polygon(obj.vertices[:, :2], hull).min() >= YARD_CLEARANCE_M - 1e-6
        assert not PolygonPath(hull).contains_points(obj.vertices[:, :2]).any()
    centres = np.array([o.vertices[:, :2].mean(axis=0) for o in objects])
    assert len({o.kind for o in objects}) >= 4 and len(centres) == len(np.unique(np.round(centres, 3), axis=0))


def test_a_yard_needs_the_ground():
    with pytest.raises(ConfigError, match="yard objects"):
        ScanRecipe.resolve(site=SiteModel(yard_density=1.0))
    assert ScanRecipe.resolve(platform="drone", site=SiteModel(yard_density=1.0)).site.yard_density == 1.0


def test_a_narrow_line_gets_many_orbits_none_twice_and_none_below_three_metres():
    line = RISLEY_SCANNERS["dji_zenmuse_l2_repetitive"]
    _, report = plan_flight(PLAN, (-0.3, 12.0), (0.0, 4.0, 8.0), FlightSettings(), lidar_half_extent_deg(line))
    heights = report.orbit_heights
    assert len(heights) > 10 and len(set(heights)) == len(heights) and min(heights) >= -0.05 + 3.0 - 1e-9


def test_orbits_pass_over_what_stands_under_them_and_take_off_where_nothing_stands():
    settings = FlightSettings()
    free, free_report = plan_flight(PLAN, (-0.3, 12.0), (0.0,), settings, lidar_half_extent_deg(L2))
    on_first = np.flatnonzero(np.isclose(free.xyz[:, 2], free_report.orbit_heights[0]))
    ring_spot = free.xyz[on_first[len(on_first) // 2]]  # half way round the first orbit
    tower = np.array([[ring_spot[0] + dx, ring_spot[1] + dy, z] for dx in (-0.5, 0.5) for dy in (-0.5, 0.5)
                      for z in (-0.05, 6.0)])
    start = free.xyz[0]
    container = np.array([[start[0] + dx, start[1] + dy, z] for dx in (-2, 2) for dy in (-1, 1) for z in (0.0, 2.6)])
    _, report = plan_flight(PLAN, (-0.3, 12.0), (0.0,), settings, lidar_half_extent_deg(L2),
                            obstacles=np.vstack([tower, container]))
    assert min(report.orbit_heights) >= 6.0 + 1.5 - 1e-9
    assert np.hypot(*(container[:, :2] - np.array(report.takeoff[:2])).T).min() > 3.0


def test_the_ground_level_of_models_with_a_basement_at_absolute_heights_and_without_storeys():
    from bimscan.survey.flight import ground_level

    assert ground_level(-3.3, (-3.0, 0.0, 3.0)) == pytest.approx(-0.05)  # the basement is below the ground
    assert ground_level(116.7, (117.0, 120.0, 123.0)) == pytest.approx(116.95)  # placed at its height
    assert ground_level(-0.4, ()) == pytest.approx(-0.45)  # no storey: below the lowest point


def test_a_flight_file_may_reach_far_beyond_the_model_but_not_a_kilometre(box_room_ifc, tmp_path):
    from bimscan.errors import StationError
    from bimscan.survey.trajectory import write_trajectory

    def flight(reach_m: float):
        t = np.array([0.0, 0.5, 1.0])
        xyz = np.array([[4.0, -8.0, 5.0], [4.0, -8.0 - reach_m / 2, 30.0], [4.0, -8.0 - reach_m, 30.0]])
        return write_trajectory(tmp_path / f"f{reach_m:g}.csv", Trajectory(
            t=t, xyz=xyz, roll=np.zeros(3), pitch=np.radians([0.0, 45.0, 90.0]), yaw=np.radians([90.0] * 3),
            pass_id=np.zeros(3, dtype=np.int32)))

    recipe = ScanRecipe.resolve(platform="drone", trajectory=str(flight(200.0)), seed=1)
    result = scan_model(box_room_ifc, tmp_path / "far.laz", recipe, progress=False)
    assert result.points > 1000 and result.survey.walk is None
    with pytest.raises(StationError, match="more than 500 m outside the model"):
        scan_model(box_room_ifc, tmp_path / "too_far.laz", ScanRecipe.resolve(
            platform="drone", trajectory=str(flight(1000.0))), progress=False)


def test_gnss_error_moves_a_drone_scans_points_by_about_its_sigma(drone_scan, box_room_ifc, tmp_path):
    """5 cm per horizontal axis, 7.5 cm vertically and 0.25 degree of heading (up to 9 cm at 20 m)."""
    result, clean = drone_scan
    moved_recipe = dataclasses.replace(result.survey.recipe, mobile=dataclasses.replace(
        result.survey.recipe.mobile, drift=GnssInsModel.rtk(0.05)))
    moved = read_cloud(scan_model(box_room_ifc, tmp_path / "gnss.laz", moved_recipe, progress=False).path)
    assert len(moved) == len(clean)  # the same pulses hit: the error moves points after the scan
    shift = np.linalg.norm(moved.xyz - clean.xyz, axis=1)
    assert 0.01 < np.median(shift) < 0.5 and np.isfinite(shift).all()


def test_a_dataset_spec_gives_a_drones_gnss_error_and_refuses_it_on_a_tripod(box_room_ifc, tmp_path):
    from bimscan.dataset.spec import load_spec

    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(f'name = "d"\n[[scenes]]\nname = "box"\nifc = "{box_room_ifc}"\n'
                         '[[configs]]\nname = "fly"\nplatform = "drone"\ngnss_m = 0.02\n')
    spec = load_spec(spec_path)
    drift = spec.recipe(spec.scenes[0], spec.configs[0]).mobile.drift
    assert isinstance(drift, GnssInsModel) and drift.horizontal_sigma_m == 0.02 and drift.vertical_sigma_m == 0.03
    spec_path.write_text(f'name = "d"\n[[scenes]]\nname = "box"\nifc = "{box_room_ifc}"\n'
                         '[[configs]]\nname = "tls"\npreset = "exp1"\ngnss_m = 0.02\n')
    with pytest.raises(ConfigError, match="'gnss_m' are for mobile configurations"):
        load_spec(spec_path)


def test_the_coverage_command_writes_every_outer_element_and_refuses_to_replace_without_overwrite(
        drone_scan, box_room_ifc, tmp_path, capsys):
    import csv

    from bimscan.cli.main import main

    result, _ = drone_scan
    out = tmp_path / "coverage.csv"
    assert main(["coverage", str(box_room_ifc), str(result.path), str(out)]) == 0
    rows = {row["ifc_class"] + " " + row["name"]: row for row in csv.DictReader(out.open())}
    walls = [row for key, row in rows.items() if key.startswith("IfcWall")]
    assert len(walls) == 4 and all(row["status"] == "covered" and float(row["covered_share"]) >= 0.8 for row in walls)
    assert rows["IfcSlab roof"]["status"] == "covered" and rows["IfcSlab roof"]["facing"] == "up"
    assert rows["IfcSlab floor"]["status"] == "below the ground"  # its sides and underside: under the ground
    assert "5 of the 5 above the ground covered on >= 80% at 100 points/m2" in capsys.readouterr().out
    assert main(["coverage", str(box_room_ifc), str(result.path), str(out)]) == 1  # there: refused, as scan refuses
    assert "already exists; pass --overwrite to replace it" in capsys.readouterr().err
    assert main(["coverage", str(box_room_ifc), str(result.path), str(out), "--share", "1.5"]) == 2

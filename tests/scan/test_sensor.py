"""Sensor realism: each effect against what its model predicts, labels exact, output independent
of chunking and threads, and the paper's scanner unchanged."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import open3d as o3d
import pytest

from bimscan.errors import ConfigError
from bimscan.pipeline import load_scene
from bimscan.process.checks import check_semantics
from bimscan.scan import waveform
from bimscan.scan.device import SCANNERS, ScanSettings
from bimscan.scan.noise import NoiseModel
from bimscan.scan.pattern import PulsePattern
from bimscan.survey.recipe import ScanRecipe
from bimscan.scan.sensor import SensorModel
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.survey.survey import prepare_survey, survey_metadata
from bimscan.types import PointCloud, Station

VZ400 = SCANNERS["riegl_vz400"]
ORIGIN = (0.0, 0.0, 1.7)
ONLY = dict(realism="paper")  # effects switched on one at a time below


def scan(scene, sensor: SensorModel, settings: ScanSettings, *, scanner=VZ400, noise=NoiseModel.off(), seed=0,
         station=Station(id=0, position=ORIGIN), **fields) -> PointCloud:
    recipe = ScanRecipe(scanner=scanner, settings=settings, preset=None, noise=noise, seed=seed, sensor=sensor, **fields)
    survey = prepare_survey(scene, recipe, stations=(station,))
    chunks = []
    for chunk in survey.scanner.scan_station(station, recipe):
        check_semantics(chunk, scene.components)  # every chunk: labels are the components'
        chunks.append(chunk)
    return PointCloud.concatenate(chunks)


def component_named(scene, name: str) -> int:
    return int(np.flatnonzero(scene.components.name == name)[0])


def style(model, element, *, rgb, transparency=0.0, name="style", item=0):
    """Give ``element``'s body (its ``item``-th item) a surface style (colour and transparency)."""
    import ifcopenshell.api.style  # noqa: F401

    created = model.api.run("style.add_style", model.file, name=name)
    model.api.run("style.add_surface_style", model.file, style=created, ifc_class="IfcSurfaceStyleShading",
                  attributes={"SurfaceColour": {"Name": None, "Red": rgb[0], "Green": rgb[1], "Blue": rgb[2]},
                              "Transparency": transparency})
    model.api.run("style.assign_item_style", model.file, item=element.Representation.Representations[0].Items[item],
                  style=created)


def test_the_footprint_of_a_03_mrad_beam_on_a_wall_10_m_away_is_3_mm_wide(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", origin=(10.0, -2.0, 0.0), size=(0.2, 4.0, 3.5), name="wall")
    scene = load_scene(model.write(tmp_path / "wall.ifc"))
    scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=VZ400)
    off, azimuth, weight = waveform.subray_pattern(3, VZ400.beam_divergence_rad)
    assert len(off) == 1 + 6 + 12 and weight.sum() == pytest.approx(1.0)  # HELIOS++'s pattern at quality 3
    centre = np.zeros((1, 6), dtype=np.float32)
    centre[0, :3] = np.asarray(ORIGIN) - scanner.engine.centre
    centre[0, 3] = 1.0
    rays = np.empty((len(off) - 1, 6), dtype=np.float32)
    waveform.footprint_rays(centre, np.array([0]), np.cos(off[1:]), np.sin(off[1:]), np.cos(azimuth[1:]),
                            np.sin(azimuth[1:]), rays)
    t, triangle = scanner.engine.cast(rays)
    assert (triangle < len(scene.mesh.faces)).all()
    hits = rays[:, :3].astype(np.float64) + rays[:, 3:] * t[:, None]
    assert np.allclose(hits[:, 0], hits[0, 0], atol=1e-5)  # all on the wall's face
    spread = hits[:, 1:].max(axis=0) - hits[:, 1:].min(axis=0)  # across y and z
    np.testing.assert_allclose(spread, 10.0 * 0.3e-3, rtol=0.01)  # 3.0 mm both ways


@pytest.fixture(scope="module")
def step_edge(tiny_model, tmp_path_factory):
    """Two parallel planes, 0.3 m apart (less than the 0.75 m range resolution): the front one's
    top edge at the scanner's height."""
    model = tiny_model("IFC4")
    model.add_box("IfcWall", origin=(4.0, -3.0, 0.7), size=(0.05, 6.0, 1.0), name="front")
    model.add_box("IfcWall", origin=(4.3, -3.0, 0.7), size=(0.05, 6.0, 2.0), name="back")
    return load_scene(model.write(tmp_path_factory.mktemp("step") / "step.ifc"))


def test_a_step_edge_gives_points_between_the_planes_in_the_proportion_the_divergence_predicts(step_edge):
    divergence = 4e-3
    wide = dataclasses.replace(VZ400, beam_divergence_rad=divergence)
    settings = ScanSettings(pulse_freq_hz=50000, scan_freq_hz=97, head_deg_per_s=6, head_start_deg=-30, head_stop_deg=30)
    thin = scan(step_edge, SensorModel(**ONLY), settings, scanner=wide)
    beam = scan(step_edge, SensorModel(**ONLY, footprint=True), settings, scanner=wide)
    def at_the_step(cloud: PointCloud) -> np.ndarray:  # strictly between the planes, near the step (not the top edge)
        return (cloud.xyz[:, 0] > 4.0 + 1e-3) & (cloud.xyz[:, 0] < 4.3 - 1e-3) & (np.abs(cloud.xyz[:, 2] - ORIGIN[2]) < 0.2)

    between = at_the_step(beam)
    assert not at_the_step(thin).any()
    # the model: a pulse mixes both planes when its axis passes within half the divergence of the
    # edge (the sub-ray pattern's outer ring reaches +-divergence/2 straight up and down); the edge
    # is at elevation 0 for every azimuth
    pattern = PulsePattern.of(settings, wide)
    start, stop = pattern.line_pulses(0, pattern.n_lines)
    pulses = np.concatenate([np.arange(a, b) for a, b in zip(start, stop)])
    elevation = np.radians(pattern.elevation_deg(pulses))
    predicted = int((np.abs(elevation) < divergence / 2).sum())
    assert abs(int(between.sum()) - predicted) <= 2
    step = math.radians(settings.vertical_step_deg(wide))
    assert between.sum() / pattern.n_lines == pytest.approx(divergence / step, rel=0.05)
    # mixed points: between the planes, on the components that share the energy
    assert set(np.unique(beam.component[between])) <= {component_named(step_edge, "front"),
                                                         component_named(step_edge, "back")}
    assert (beam.number_of_returns[between] == 1).all()  # the echoes merged into one return, not split
    # silhouettes grow by half a footprint: pulses whose axis just misses an edge now return
    assert len(beam) > len(thin)


@pytest.fixture(scope="module")
def pole_scene(tiny_model, tmp_path_factory):
    """A 2 cm pole 3 m in front of the scanner, a wall 8 m away behind it."""
    model = tiny_model("IFC4")
    model.add_box("IfcMember", origin=(3.0, -0.01, 0.0), size=(0.02, 0.02, 3.0), name="pole")
    model.add_box("IfcWall", origin=(8.0, -3.0, 0.0), size=(0.2, 6.0, 3.0), name="wall")
    return load_scene(model.write(tmp_path_factory.mktemp("pole") / "pole.ifc"))


def test_a_thin_pole_before_a_wall_gives_first_returns_on_the_pole_and_last_returns_on_the_wall(pole_scene):
    wide = dataclasses.replace(VZ400, beam_divergence_rad=6e-3)
    settings = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36, head_start_deg=-5,
                            head_stop_deg=5, elevation_min_deg=-20, elevation_max_deg=20)
    pole, wall = component_named(pole_scene, "pole"), component_named(pole_scene, "wall")
    cloud = scan(pole_scene, SensorModel(**ONLY, footprint=True, returns="all"), settings, scanner=wide)
    two = cloud.number_of_returns == 2
    assert two.sum() > 40
    first, last = two & (cloud.return_number == 1), two & (cloud.return_number == 2)
    assert (cloud.component[first] == pole).all() and (cloud.component[last] == wall).all()
    x = cloud.xyz[:, 0]
    assert (np.abs(x[first] - 3.01) < 0.02).all() and (np.abs(x[last] - 8.0) < 0.01).all()
    assert np.array_equal(np.sort(cloud.time[first]), np.sort(cloud.time[last]))  # the same pulses
    firsts = scan(pole_scene, SensorModel(**ONLY, footprint=True, returns="first"), settings, scanner=wide)
    lasts = scan(pole_scene, SensorModel(**ONLY, footprint=True, returns="last"), settings, scanner=wide)
    split = np.isin(firsts.time, cloud.time[first])
    assert (firsts.component[split] == pole).all()
    assert (lasts.component[np.isin(lasts.time, cloud.time[last])] == wall).all()
    assert len(firsts) == len(lasts) == len(np.unique(cloud.time))  # one point per pulse that returned


@pytest.fixture(scope="module")
def window_scene(tiny_model, tmp_path_factory):
    """A glazed window (transparency 0.9, blue) 3 m in front of the scanner, a wall 6 m away."""
    model = tiny_model("IFC4")
    window = model.add_box("IfcWindow", origin=(3.0, -0.5, 1.2), size=(0.02, 1.0, 1.0), name="window")
    style(model, window, rgb=(0.2, 0.4, 0.9), transparency=0.9, name="glazing")
    wall = model.add_box("IfcWall", origin=(6.0, -4.0, 0.0), size=(0.2, 8.0, 3.0), name="wall")
    style(model, wall, rgb=(0.8, 0.6, 0.4), name="render")
    return load_scene(model.write(tmp_path_factory.mktemp("window") / "window.ifc"))


WINDOW_SETTINGS = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=18, head_start_deg=-25,
                               head_stop_deg=25, elevation_min_deg=-15, elevation_max_deg=15)


def test_glass_returns_nothing_with_transparency_on_and_the_wall_behind_appears(window_scene):
    window, wall = component_named(window_scene, "window"), component_named(window_scene, "wall")
    opaque = scan(window_scene, SensorModel(**ONLY), WINDOW_SETTINGS)
    clear = scan(window_scene, SensorModel(**ONLY, glass=True, glass_return_probability=0.0), WINDOW_SETTINGS)
    glazed = opaque.time[opaque.component == window]  # the pulses that meet the glass
    assert len(glazed) > 1000 and (opaque.component == wall).sum() > 1000
    assert not (clear.component == window).any()
    through = np.isin(clear.time, glazed)
    assert through.sum() == len(glazed)  # every glazed pulse now reaches the wall behind
    assert (clear.component[through] == wall).all() and (clear.xyz[through, 0] > 5.99).all()


def test_a_partial_return_chance_gives_glass_echoes_at_the_configured_rate(window_scene):
    window = component_named(window_scene, "window")
    opaque = scan(window_scene, SensorModel(**ONLY), WINDOW_SETTINGS)
    cloud = scan(window_scene, SensorModel(**ONLY, glass=True, glass_return_probability=0.3, returns="first"),
                 WINDOW_SETTINGS)
    glazed = np.isin(cloud.time, opaque.time[opaque.component == window])
    # two crossings (the pane's two faces), each echoing with probability 0.3
    assert (cloud.component[glazed] == window).mean() == pytest.approx(1 - 0.7**2, abs=0.03)
    every = scan(window_scene, SensorModel(**ONLY, glass=True, glass_return_probability=0.3, returns="all"),
                 WINDOW_SETTINGS)
    behind = np.isin(every.time, opaque.time[opaque.component == window]) & (every.component != window)
    assert behind.sum() == glazed.sum()  # with all returns, the wall behind is still seen through every pane


def test_points_take_their_surface_style_colour_shaded_by_incidence(window_scene):
    wall = component_named(window_scene, "wall")
    sensor = SensorModel(**ONLY, color=True, color_noise=0.0, ambient=0.5)
    cloud = scan(window_scene, sensor, WINDOW_SETTINGS)
    on_wall = cloud.component == wall
    d = cloud.xyz[on_wall] - np.asarray(ORIGIN)
    cos = np.abs(d[:, 0]) / np.linalg.norm(d, axis=1)
    expected = 255.0 * np.array([0.8, 0.6, 0.4]) * (0.5 + 0.5 * cos)[:, None]
    assert np.abs(cloud.rgb[on_wall] - expected).max() <= 1.0
    noisy = scan(window_scene, dataclasses.replace(sensor, color_noise=0.05), WINDOW_SETTINGS)
    ratio = noisy.rgb[noisy.component == wall, 0] / np.maximum(cloud.rgb[on_wall, 0], 1)
    assert ratio.std() == pytest.approx(0.05, rel=0.15)


@pytest.fixture(scope="module")
def long_wall(tiny_model, tmp_path_factory):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", origin=(5.0, -20.0, -2.0), size=(0.2, 40.0, 8.0), name="wall")
    return load_scene(model.write(tmp_path_factory.mktemp("long") / "long.ifc"))


def test_the_return_fraction_falls_with_incidence_as_the_range_equation_with_speckle_says(long_wall):
    # a scanner that reaches 12 m at reflectance 0.9: on a wall 5 m away the detection probability
    # goes from 0.8 head-on to below 0.2 at 60 degrees
    short = dataclasses.replace(VZ400, reach_reflectance=(0.9,), reach_range_m=(12.0,), reach_pulse_freq_hz=100000.0)
    settings = ScanSettings(pulse_freq_hz=100000, scan_freq_hz=100, head_deg_per_s=20, head_start_deg=-70,
                            head_stop_deg=70, elevation_min_deg=-15, elevation_max_deg=15)
    every = scan(long_wall, SensorModel(**ONLY), settings, scanner=short)
    detected = scan(long_wall, SensorModel(**ONLY, detection=True), settings, scanner=short)
    d = every.xyz - np.asarray(ORIGIN)
    distance = np.linalg.norm(d, axis=1)
    cos = np.abs(d[:, 0]) / distance
    s = 0.5 * cos / (short.reach_constant() * distance**2)  # reflectance 0.5 (materials off), same pulse rate
    model = np.exp(-math.log(2.0) / s)
    kept = np.isin(every.time, detected.time)
    incidence = np.degrees(np.arccos(cos))
    fractions = []
    for low in range(0, 70, 10):
        in_bin = (incidence >= low) & (incidence < low + 10)
        assert in_bin.sum() > 5000
        fractions.append(kept[in_bin].mean())
        assert kept[in_bin].mean() == pytest.approx(model[in_bin].mean(), abs=0.02), low
    assert fractions[0] > 0.75 and fractions[-1] < 0.25 and np.all(np.diff(fractions) < 0)


def test_range_noise_grows_with_range_and_one_over_cos_incidence(long_wall):
    settings = ScanSettings(pulse_freq_hz=100000, scan_freq_hz=100, head_deg_per_s=20, head_start_deg=-70,
                            head_stop_deg=70, elevation_min_deg=-15, elevation_max_deg=15)
    noise = NoiseModel(range_sigma_m=0.005, angle_sigma_deg=0.0)
    exact = scan(long_wall, SensorModel(**ONLY), settings)
    noisy = scan(long_wall, SensorModel(**ONLY, geometric_noise=True, range_noise_ppm=1000.0), settings, noise=noise,
                 seed=3)
    assert np.array_equal(exact.time, noisy.time)
    o = np.asarray(ORIGIN)
    distance = np.linalg.norm(exact.xyz - o, axis=1)
    error = np.linalg.norm(noisy.xyz - o, axis=1) - distance
    cos = np.abs(exact.xyz[:, 0] - o[0]) / distance
    z = error / ((0.005 + 1e-3 * distance) / cos)
    assert z.std() == pytest.approx(1.0, rel=0.02) and abs(z.mean()) < 4 / math.sqrt(len(z))
    far = cos < 0.5
    assert error[far].std() > 2.5 * error[cos > 0.95].std()


@pytest.fixture(scope="module")
def box(box_room_ifc):
    return load_scene(box_room_ifc)


BOX_SETTINGS = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36)
BOX_STATION = Station(id=0, position=(4.0, 3.0, 1.7))


def test_as_built_deviations_move_each_component_rigidly_by_the_recorded_transform(box):
    sensor = SensorModel(**ONLY, deviations=True, position_tolerance_m=0.05, plumb_tolerance_m=0.05,
                         level_tolerance_m=0.04)
    recipe = ScanRecipe(settings=BOX_SETTINGS, preset=None, noise=NoiseModel.off(), seed=5, sensor=sensor)
    survey = prepare_survey(box, recipe, stations=(BOX_STATION,))
    cloud = PointCloud.concatenate(list(survey.scanner.scan_station(BOX_STATION, recipe)))
    assert np.array_equal(cloud.label, box.components.label[cloud.component])
    recorded = survey_metadata(survey)["as_built"]["components"]
    assert recorded["global_id"] == list(box.components.global_id)
    from bimscan.scan.asbuilt import Deviations

    deviations = Deviations(global_id=np.array(recorded["global_id"]), centre_m=np.array(recorded["centre_m"]),
                            shift_m=np.array(recorded["shift_m"]), tilt_rad=np.radians(recorded["tilt_deg"]),
                            vertical=np.array(recorded["vertical"]), phase=np.zeros(len(box.components)))
    mesh = box.mesh
    for c in range(len(box.components)):
        faces = mesh.faces[mesh.face_component == c]
        points = cloud.xyz[cloud.component == c]
        moved = deviations.transform(mesh.vertices, np.full(len(mesh.vertices), c))
        assert distance_to(moved, faces, points).max() < 2e-4, c  # on the moved component
        # not where the IFC has it: off the original surface by more than twice the tolerance of
        # "on the moved one" (the draw is per GlobalId, and the test model's are new every run)
        assert np.median(distance_to(mesh.vertices, faces, points)) > 4e-4, c
    assert deviations.vertical.sum() == 4  # the walls; the slabs are horizontal


def distance_to(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def test_as_built_draws_follow_the_tolerance_sigmas():
    from bimscan.scan.asbuilt import sample_deviations
    from bimscan.types import SceneMesh

    n = 4000
    cube = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 3.0]])
    vertices = np.concatenate([cube + [5.0 * i, 0, 0] for i in range(n)])
    faces = np.concatenate([np.array([[0, 1, 3], [0, 2, 3], [1, 2, 3]]) + 4 * i for i in range(n)]).astype(np.int32)
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=np.repeat(np.arange(n, dtype=np.int32), 3))
    sensor = SensorModel(deviations=True)
    deviations = sample_deviations(mesh, np.array([f"gid{i}" for i in range(n)]), sensor, seed=1)
    assert deviations.shift_m.std(axis=0) == pytest.approx([0.0125, 0.0125, 0.0095], rel=0.05)
    again = sample_deviations(mesh, np.array([f"gid{i}" for i in range(n)]), sensor, seed=1)
    assert np.array_equal(deviations.shift_m, again.shift_m)
    other = sample_deviations(mesh, np.array([f"gid{i}" for i in range(n)]), sensor, seed=2)
    assert not np.allclose(deviations.shift_m, other.shift_m)


@pytest.fixture(scope="module")
def framed_window_scene(tiny_model, tmp_path_factory):
    """One window of two items 3 m in front of the scanner: a glazed pane (transparency 0.9, z 1.2-2.0)
    over a sill without a style (z 1.0-1.2, 0.1 m deep); a wall 6 m away."""
    model = tiny_model("IFC4")
    window = model.add_box("IfcWindow", origin=(3.0, -0.5, 1.2), size=(0.02, 1.0, 0.8), name="window")
    f = model.file
    profile = f.createIfcRectangleProfileDef("AREA", None, f.createIfcAxis2Placement2D(
        f.createIfcCartesianPoint((0.05, 0.5)), None), 0.1, 1.0)
    sill = f.createIfcExtrudedAreaSolid(profile, f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, -0.2)),
                                                                           None, None),
                                        f.createIfcDirection((0.0, 0.0, 1.0)), 0.2)
    body = window.Representation.Representations[0]
    body.Items = (*body.Items, sill)
    style(model, window, rgb=(0.2, 0.4, 0.9), transparency=0.9, name="glazing", item=0)
    model.add_box("IfcWall", origin=(6.0, -4.0, 0.0), size=(0.2, 8.0, 3.0), name="wall")
    return load_scene(model.write(tmp_path_factory.mktemp("framed") / "framed.ifc"))


def test_the_parse_keeps_each_triangles_style_transparency(framed_window_scene):
    scene = framed_window_scene
    window, wall = component_named(scene, "window"), component_named(scene, "wall")
    alpha = scene.mesh.face_transparency
    corners = scene.mesh.vertices[scene.mesh.faces]  # (F, 3, 3)
    of_window = scene.mesh.face_component == window
    pane = of_window & (corners[:, :, 2] > 1.2 - 1e-9).all(axis=1) & (corners[:, :, 0] < 3.02 + 1e-9).all(axis=1)
    sill = of_window & ~pane
    assert pane.sum() == 12 and sill.sum() == 12  # two boxes
    np.testing.assert_allclose(alpha[pane], 0.9, atol=1e-6)
    assert np.isnan(alpha[sill]).all() and np.isnan(alpha[scene.mesh.face_component == wall]).all()
    assert scene.surfaces.transparency[window] == pytest.approx(0.9)  # the component: its highest


def test_glass_passes_the_beam_through_a_windows_pane_but_not_its_frame(framed_window_scene):
    window, wall = component_named(framed_window_scene, "window"), component_named(framed_window_scene, "wall")
    opaque = scan(framed_window_scene, SensorModel(**ONLY), WINDOW_SETTINGS)
    clear = scan(framed_window_scene, SensorModel(**ONLY, glass=True, glass_return_probability=0.0), WINDOW_SETTINGS)
    at_window = opaque.component == window
    pane = at_window & (opaque.xyz[:, 2] > 1.2 + 1e-3)
    sill = at_window & (opaque.xyz[:, 2] < 1.2 - 1e-3)
    assert pane.sum() > 1000 and sill.sum() > 200
    through = np.isin(clear.time, opaque.time[pane])
    assert through.sum() == pane.sum() and (clear.component[through] == wall).all()  # every pane pulse passes
    kept = clear.component == window
    assert np.isin(opaque.time[sill], clear.time[kept]).all()  # the sill stays where it was
    assert (clear.xyz[kept, 2] < 1.2 + 1e-3).all()  # and nothing of the pane does


def test_glazing_faces_pass_only_the_styled_panes_of_a_component_that_tells_them_apart():
    from bimscan.scan.surfaces import glazing_faces

    component = np.array([0, 0, 0, 1, 1, 2])  # a window (pane, frame, unstyled), a glass plate, a wall
    style = np.array([0.9, 0.0, np.nan, np.nan, np.nan, 0.0], dtype=np.float32)
    alpha = glazing_faces(np.array([0.9, 0.8, 0.0]), component, style)
    np.testing.assert_allclose(alpha, [0.9, 0.0, 0.0, 0.8, 0.8, 0.0])  # the plate: glass by its name, whole
    np.testing.assert_allclose(glazing_faces(np.array([0.9, 0.8, 0.0]), component, None), [0.9, 0.9, 0.9, 0.8, 0.8, 0.0])


@pytest.fixture(scope="module")
def busy_room(tiny_model, tmp_path_factory):
    """An 8 x 6 x 3.5 m room with a column, a pole and a glazed window: edges, glass and returns."""
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(-0.25, -0.25, -0.3), size=(8.5, 6.5, 0.3), name="floor")
    model.add_box("IfcSlab", origin=(-0.25, -0.25, 3.5), size=(8.5, 6.5, 0.3), name="roof")
    model.add_box("IfcWall", origin=(-0.25, -0.25, 0.0), size=(8.5, 0.25, 3.5), name="south")
    model.add_box("IfcWall", origin=(-0.25, 6.0, 0.0), size=(8.5, 0.25, 3.5), name="north")
    model.add_box("IfcWall", origin=(-0.25, 0.0, 0.0), size=(0.25, 6.0, 3.5), name="west")
    model.add_box("IfcWall", origin=(8.0, 0.0, 0.0), size=(0.25, 6.0, 3.5), name="east")
    model.add_box("IfcColumn", origin=(6.0, 1.0, 0.0), size=(0.3, 0.3, 3.5), name="column")
    model.add_box("IfcMember", origin=(2.0, 4.5, 0.0), size=(0.03, 0.03, 3.5), name="pole")
    window = model.add_box("IfcWindow", origin=(1.0, 5.5, 0.8), size=(2.0, 0.02, 1.4), name="window")
    style(model, window, rgb=(0.5, 0.7, 0.9), transparency=0.9)
    return load_scene(model.write(tmp_path_factory.mktemp("busy") / "busy.ifc"))


def test_full_realism_output_is_identical_whatever_the_chunk_size_and_thread_count(busy_room):
    full = SensorModel(realism="full")
    noise = NoiseModel()
    big = scan(busy_room, full, BOX_SETTINGS, noise=noise, seed=3, station=BOX_STATION)
    small = scan(busy_room, full, BOX_SETTINGS, noise=noise, seed=3, station=BOX_STATION, chunk_pulses=7_000)
    assert (big.number_of_returns > 1).any() and big.rgb is not None
    for column in PointCloud.COLUMNS:
        assert np.array_equal(getattr(big, column), getattr(small, column)), column
    clouds = []
    for threads in (1, 2):
        recipe = ScanRecipe(settings=BOX_SETTINGS, preset=None, noise=noise, seed=3, sensor=full, threads=threads)
        survey = prepare_survey(busy_room, recipe, stations=(BOX_STATION,))
        clouds.append(PointCloud.concatenate(list(survey.scanner.scan_station(BOX_STATION, recipe))))
    for column in PointCloud.COLUMNS:
        assert np.array_equal(getattr(clouds[0], column), getattr(clouds[1], column)), column
        assert np.array_equal(getattr(clouds[0], column), getattr(big, column)), column


def test_the_adaptive_footprint_samples_only_pulses_next_to_edges(busy_room):
    full = SensorModel(realism="full")
    recipe = ScanRecipe(settings=BOX_SETTINGS, preset=None, seed=1, sensor=full)
    survey = prepare_survey(busy_room, recipe, stations=(BOX_STATION,))
    scanner = survey.scanner
    pattern = PulsePattern.of(BOX_SETTINGS, VZ400)
    start, stop = pattern.line_pulses(0, pattern.n_lines)
    counts = stop - start
    offsets = np.zeros(len(counts) + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    from bimscan.scan.kernels import generate_rays

    rays = np.empty((offsets[-1], 6), dtype=np.float32)
    pulse = np.empty(offsets[-1], dtype=np.int64)
    origin = (np.asarray(BOX_STATION.position) - scanner.engine.centre).astype(np.float32)
    generate_rays(start, stop, offsets[:-1], 0, pattern.dphase, pattern.sweep_deg, 0.0, pattern.head_deg_per_pulse,
                  0.0, origin, rays, pulse)
    t, tri = scanner.engine.cast(rays)
    phase0 = start * pattern.dphase - np.arange(len(start))
    shift = np.zeros(len(start), dtype=np.int64)
    shift[:-1] = np.rint((phase0[:-1] - phase0[1:]) / pattern.dphase)
    bits = np.zeros(len(t), dtype=np.uint8)
    waveform.flag_edges(t, tri, scanner.face_component, VZ400.min_range_m, VZ400.max_range_m, offsets[:-1], counts,
                        shift, 0, len(counts), full.edge_depth_m, bits)
    flag = bits > 0
    component = np.where(tri < len(scanner.face_component), scanner.face_component[np.minimum(tri, len(tri) - 1)], -1)
    assert 0 < flag.mean() < 0.08  # a coarse scan (1 degree steps): about 4 pulses per line meet a junction
    # every pulse next to a component change along its line is flagged
    change = np.flatnonzero(component[1:] != component[:-1])
    same_line = np.searchsorted(offsets, change, side="right") == np.searchsorted(offsets, change + 1, side="right")
    assert flag[change[same_line]].all() and flag[change[same_line] + 1].all()


def test_paper_realism_is_the_scanner_without_sensor_settings_bit_for_bit(box, tmp_path):
    plain = ScanRecipe(settings=BOX_SETTINGS, preset=None, seed=2)
    paper = ScanRecipe(settings=BOX_SETTINGS, preset=None, seed=2, sensor=SensorModel(realism="paper"))
    assert plain.to_json() == paper.to_json() and "sensor" not in paper.to_json()
    assert "pulse_length_ns" not in paper.to_json()["scanner"]
    a = scan(box, SensorModel(), BOX_SETTINGS, noise=NoiseModel(), seed=2, station=BOX_STATION)
    b = scan(box, SensorModel(realism="paper"), BOX_SETTINGS, noise=NoiseModel(), seed=2, station=BOX_STATION)
    for column in PointCloud.COLUMNS:
        x, y = getattr(a, column), getattr(b, column)
        assert (x is None and y is None) or np.array_equal(x, y), column
    assert a.return_number is None and a.number_of_returns is None and a.rgb is None  # the paper's columns only


def test_full_realism_is_recorded_and_changes_the_fingerprint():
    paper = ScanRecipe(settings=BOX_SETTINGS, preset=None)
    full = ScanRecipe(settings=BOX_SETTINGS, preset=None, sensor=SensorModel(realism="full"))
    recorded = full.to_json()["sensor"]
    assert recorded["footprint"] is True and recorded["deviations"] is True and recorded["realism"] == "full"
    assert full.to_json()["scanner"]["pulse_length_ns"] == 5.0
    assert full.fingerprint() != paper.fingerprint()
    assert SensorModel(realism="full", glass=False).resolved().glass is False


@pytest.mark.parametrize("change, message", [
    ({"realism": "photo"}, "realism takes 'paper', 'full', got 'photo'"),
    ({"returns": "second"}, "returns takes 'first', 'last', 'strongest', 'all', got 'second'"),
    ({"beam_sample_quality": 0}, "beam_sample_quality must be an integer in 1..6, got 0"),
    ({"glass_return_probability": 1.5}, r"glass_return_probability must be a number in \[0, 1\], got 1.5"),
    ({"footprint": "yes"}, "footprint must be true or false, got 'yes'"),
])
def test_impossible_sensor_settings_are_refused_naming_the_setting(change, message):
    with pytest.raises(ConfigError, match=message):
        SensorModel(**change)


# A value away from the default for every setting that acts through an effect (SETTING_EFFECTS).
CHANGED = {"beam_sample_quality": 4, "adaptive_footprint": False, "edge_depth_m": 0.01, "returns": "all",
           "max_returns": 5, "speckle_cells": 2, "range_noise_ppm": 20.0, "max_incidence_deg": 80.0,
           "material_table": "materials.toml", "glass_return_probability": 0.2, "max_glass_layers": 7,
           "color_noise": 0.06, "ambient": 0.4, "position_tolerance_m": 0.03, "level_tolerance_m": 0.02,
           "plumb_tolerance_m": 0.03, "sigmas_per_tolerance": 3.0, "waviness_m": 0.002,
           "waviness_wavelength_m": 3.0}
NEEDS = {"max_returns": {"returns": "all"}, "waviness_wavelength_m": {"waviness_m": 0.002}}  # besides an effect


def test_every_sensor_setting_names_the_effects_it_acts_through():
    from bimscan.scan.sensor import EFFECTS, SETTING_EFFECTS

    settings = {f.name for f in dataclasses.fields(SensorModel)} - set(EFFECTS) - {"realism"}
    assert set(SETTING_EFFECTS) == settings == set(CHANGED)
    assert all(set(effects) <= set(EFFECTS) for effects in SETTING_EFFECTS.values())


@pytest.mark.parametrize("name", sorted(CHANGED))
def test_a_sensor_setting_is_refused_exactly_where_none_of_its_effects_is_on(name):
    from bimscan.scan.sensor import SETTING_EFFECTS

    off = dict.fromkeys(SETTING_EFFECTS[name], False)
    with pytest.raises(ConfigError, match=f"would change nothing.*{name} = ") as caught:
        ScanRecipe(sensor=SensorModel(**off, **NEEDS.get(name, {}), **{name: CHANGED[name]}))
    message = str(caught.value)
    assert "\n" not in message and re.search(rf"leave [a-z_, ]*\b{name}\b[a-z_, ]* out$", message)
    for effect in SETTING_EFFECTS[name]:  # any one of its effects on: it acts, and is taken
        on = SensorModel(**off | {effect: True}, **NEEDS.get(name, {}), **{name: CHANGED[name]})
        assert on.idle_settings() == {}
    assert SensorModel(**{name: getattr(SensorModel(), name)}).idle_settings() == {}  # at its default: nothing said


def test_the_settings_refused_without_their_effect_change_no_point_of_a_scan(box):
    """What the refusal rests on: with detection on but neither footprint nor glass, a pulse has one
    echo, so the echo choice, the number of returns kept and the sub-ray rings change no column."""
    base = SensorModel(detection=True)
    plain = scan(box, base, BOX_SETTINGS, seed=2, station=BOX_STATION)
    recipe = ScanRecipe(settings=BOX_SETTINGS, preset=None, noise=NoiseModel.off(), seed=2, sensor=base)
    idle = dataclasses.replace(base, returns="all", max_returns=7, beam_sample_quality=5)
    object.__setattr__(recipe, "sensor", idle)  # past the refusal, to scan what it refuses
    survey = prepare_survey(box, recipe.with_fields(sensor=base), stations=(BOX_STATION,))
    cloud = PointCloud.concatenate(list(survey.scanner.scan_station(BOX_STATION, recipe)))
    assert len(plain) > 10_000
    for column in PointCloud.COLUMNS:
        x, y = getattr(plain, column), getattr(cloud, column)
        assert (x is None and y is None) or np.array_equal(x, y), column

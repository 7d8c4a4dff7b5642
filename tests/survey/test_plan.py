"""The survey planner on small models built in code: station counts that follow from the geometry,
coverage the scan confirms, registration through open doors only, and clear refusals."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bimscan.errors import ConfigError, StationError
from bimscan.io import iter_cloud_chunks, read_cloud_header
from bimscan.pipeline import build_site, load_scene, scan_model
from bimscan.scan.device import PRESETS, SCANNERS
from bimscan.scan.probe import Prober
from bimscan.site.model import SiteModel, StageSettings
from bimscan.survey.planning.config import PlanConfig
from bimscan.survey.planning.graph import normal_bins, scan_order
from bimscan.survey.planning.measure import patch_density, patch_matrix, points_per_sample
from bimscan.survey.planning.plan import (
    LadderRung, check_survey, evaluate, impossible_line, plan_survey, prepare_space,
)
from bimscan.survey.planning.surface import sample_surfaces, triangle_areas
from bimscan.survey.planning.visibility import BeamGrid
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.stations import format_stations, read_stations, station_problem
from bimscan.types import Station

VZ400 = SCANNERS["riegl_vz400"]
W = 0.25  # walls
S = 0.3  # slabs


def plan_space(path, *, recipe: ScanRecipe | None = None, scene=None, given=(), **settings):
    recipe = recipe or ScanRecipe()
    scene = scene if scene is not None else load_scene(path)
    return prepare_space(scene, recipe.scanner, recipe.settings, PlanConfig(**settings), given=tuple(given))


def l_shaped_room(tiny_model, path):
    """An L of two 4 m wide legs, 9 m long on the outside: x 0..9 by y 0..4, and x 0..4 by y 0..9."""
    model = tiny_model("IFC4")
    for z, kind in ((-S, "FLOOR"), (3.0, "ROOF")):
        model.add_box("IfcSlab", origin=(-W, -W, z), size=(9 + 2 * W, 4 + 2 * W, S), predefined_type=kind,
                      name=f"{kind} A")
        model.add_box("IfcSlab", origin=(-W, 4 + W, z), size=(4 + 2 * W, 5, S), predefined_type=kind, name=f"{kind} B")
    walls = (("south", (-W, -W, 0.0), (9 + 2 * W, W, 3.0)), ("east A", (9.0, 0.0, 0.0), (W, 4.0, 3.0)),
             ("north A", (4.0, 4.0, 0.0), (5 + W, W, 3.0)), ("east B", (4.0, 4 + W, 0.0), (W, 5 - W, 3.0)),
             ("north B", (-W, 9.0, 0.0), (4 + 2 * W, W, 3.0)), ("west", (-W, 0.0, 0.0), (W, 9.0, 3.0)))
    for name, origin, size in walls:
        model.add_box("IfcWall", origin=origin, size=size, name=name)
    return model.write(path)


def two_rooms(tiny_model, path, *, door: bool):
    """Rooms A (x 0..6) and B (x 6.25..12.25), 5 m deep, each with its own walls, joined by a 1 m
    opening in the wall between them (with a door leaf in it when ``door``)."""
    model = tiny_model("IFC4")
    length = 12.25
    for z, kind in ((-S, "FLOOR"), (3.0, "ROOF")):
        model.add_box("IfcSlab", origin=(-W, -W, z), size=(length + 2 * W, 5 + 2 * W, S), predefined_type=kind)
    for room, x0 in (("A", 0.0), ("B", 6.25)):
        x_outer = -W if room == "A" else length
        model.add_box("IfcWall", origin=(x0, -W, 0.0), size=(6.0, W, 3.0), name=f"south {room}")
        model.add_box("IfcWall", origin=(x0, 5.0, 0.0), size=(6.0, W, 3.0), name=f"north {room}")
        model.add_box("IfcWall", origin=(x_outer, -W, 0.0), size=(W, 5 + 2 * W, 3.0), name=f"end {room}")
    model.add_box("IfcWall", origin=(6.0, -W, 0.0), size=(W, 2.25, 3.0), name="between south")
    model.add_box("IfcWall", origin=(6.0, 3.0, 0.0), size=(W, 2.25, 3.0), name="between north")
    if door:
        model.add_box("IfcDoor", origin=(6.08, 2.0, 0.0), size=(0.08, 1.0, 2.9), name="door")
    return model.write(path)


def test_a_box_room_needs_one_station_for_its_walls(box_room_ifc):
    plan = plan_survey(plan_space(box_room_ifc, classes=("Wall&Column",)))
    assert len(plan.stations) == 1
    assert evaluate(plan).classes["Wall&Column"]["covered_fraction"] >= 0.95


def test_the_floor_under_the_scanner_needs_a_second_station(box_room_ifc):
    # the VZ-400 emits down to -40 degrees only: a circle of 2 m under the tripod is never scanned from it
    space = plan_space(box_room_ifc, classes=("Slab",))
    plan = plan_survey(space)
    assert len(plan.stations) == 2
    assert plan.solver.milp_status == "infeasible"  # HiGHS proves that no single station covers the slabs
    one = dataclasses.replace(plan, chosen=plan.chosen[:1], stations=plan.stations[:1])
    assert evaluate(one).classes["Slab"]["covered_fraction"] < 0.95


def test_an_l_shaped_room_needs_two_stations_and_no_fewer(tiny_model, tmp_path):
    space = plan_space(l_shaped_room(tiny_model, tmp_path / "l.ifc"), classes=("Wall&Column",))
    plan = plan_survey(space)
    assert len(plan.stations) == 2
    assert plan.solver.milp_status == "infeasible"  # no one station sees both legs well enough
    legs = {("A" if s.position[0] > 4 else "B" if s.position[1] > 4 else "corner") for s in plan.stations}
    assert legs != {"corner"}
    evaluation = evaluate(plan)
    assert evaluation.classes["Wall&Column"]["covered_fraction"] >= 0.95 and evaluation.parts == 1


def test_checking_a_plan_that_leaves_out_a_room_reports_that_rooms_walls_short(tiny_model, tmp_path):
    path = two_rooms(tiny_model, tmp_path / "two.ifc", door=False)
    full = plan_survey(plan_space(path, classes=("Wall&Column",)))
    in_a = tuple(s for s in full.stations if s.position[0] < 6.0)
    assert in_a and len(in_a) < len(full.stations)
    checked = evaluate(check_survey(plan_space(path, classes=("Wall&Column",), given=in_a), in_a))
    status = {e.name: e for e in checked.elements}
    assert status["end B"].status == "short" and status["end B"].covered_fraction < 0.5
    assert status["north B"].covered_fraction < 0.5
    assert status["end A"].status == "covered" and status["north A"].status == "covered"
    assert not checked.met()
    # the plan's own stations cover both rooms, and the check of the full plan agrees with the plan
    assert evaluate(full).met()


def test_a_closed_door_splits_the_registration_graph_and_an_open_one_joins_it(tiny_model, tmp_path):
    path = two_rooms(tiny_model, tmp_path / "door.ifc", door=True)
    closed = plan_survey(plan_space(path, classes=("Wall&Column",)))
    assert evaluate(closed).parts == 2
    recipe = ScanRecipe(site=SiteModel(stage=StageSettings(exclude=("IfcDoor",))))
    opened = plan_survey(plan_space(path, recipe=recipe, scene=build_site(load_scene(path), recipe),
                                    classes=("Wall&Column",)))
    evaluation = evaluate(opened)
    assert evaluation.parts == 1 and evaluation.edges
    # scan order: every station after the first registers to one scanned before it
    edges = {(a, b) for a, b, *_ in evaluation.edges}
    for later in range(1, len(opened.stations)):
        assert any((earlier, later) in edges for earlier in range(later))


def test_an_impossible_density_is_one_line_with_the_best_coverage_per_class(box_room_ifc):
    space = plan_space(box_room_ifc, classes=("Wall&Column", "Slab"), density_pts_m2=200_000.0)
    line = impossible_line(space)
    assert line is not None and "\n" not in line
    assert "Wall&Column" in line and "--density" in line and "200000 points/m2" in line
    for name in ("Wall&Column", "Slab"):
        best = float(line.split(f"{name} ")[1].split(" %")[0])
        assert 0.0 < best < 95.0
    with pytest.raises(StationError) as caught:
        plan_survey(space)
    assert str(caught.value) == line


def test_an_unknown_class_names_the_schemes_classes(box_room_ifc):
    with pytest.raises(ConfigError, match="Wall&Column, Beam, Covering, Slab, Others"):
        plan_space(box_room_ifc, classes=("Walls",))


@pytest.mark.parametrize(("settings", "message"), [
    ({"coverage": (1.5,)}, r"^coverage takes numbers in \(0, 1\] \(fractions, e.g. 0.95\), got 1.5 in \[1.5\]$"),
    ({"coverage": (0.9, 0.8)}, "one per class"),
    ({"max_incidence_deg": 89.0}, (r"^max_incidence_deg must be a number in \(0, 85\] \(degrees from the surface "
                                   r"normal\), got 89$")),
    ({"density_pts_m2": -1.0}, "^density_pts_m2 must be a number > 0, got -1$"),
    ({"solver": "cplex"}, "^solver takes 'auto', 'greedy', 'milp', got 'cplex'$"),
    ({"overlap": 1.0}, r"^overlap must be a number in \[0, 1\) \(a fraction\), got 1$"),
    ({"min_direction_share": 0.34}, r"^min_direction_share must be a number in \[0, 0.333333\] \(a surface facing"),
    ({"search_rounds": -1}, r"^search_rounds must be an integer >= 0 \(0: no search\), got -1$"),
    ({"solver": "greedy", "milp_time_limit_s": 5.0},
     r"^milp_time_limit_s = 5 would change nothing: solver = 'greedy' runs no MILP; leave it out, or choose 'milp' "
     r"or 'auto' instead$"),
    ({"solver": "milp", "milp_max_groups": 10}, r"^milp_max_groups = 10 would change nothing: solver = 'milp' runs"),
    ({"coverage_ladder": (0.8, 0.0)}, r"^coverage_ladder takes numbers in \(0, 1\]"),
])
def test_impossible_settings_are_refused_with_the_value(settings, message):
    with pytest.raises(ConfigError, match=message):
        PlanConfig(**settings)


def test_surface_samples_share_each_elements_area_and_repeat_with_the_seed(box_room_ifc):
    scene = load_scene(box_room_ifc)
    wanted = np.ones(len(scene.components), dtype=bool)
    a = sample_surfaces(scene.mesh, wanted, samples_per_m2=25.0, min_samples=8, seed=3)
    b = sample_surfaces(scene.mesh, wanted, samples_per_m2=25.0, min_samples=8, seed=3)
    assert np.array_equal(a.xyz, b.xyz)
    area = np.bincount(scene.mesh.face_component, weights=triangle_areas(scene.mesh))
    assert np.allclose(np.bincount(a.component, weights=a.area_m2), area)
    # every sample lies on its own triangle
    v = scene.mesh.vertices[scene.mesh.faces[a.triangle]]
    assert np.allclose(np.einsum("ij,ij->i", a.xyz - v[:, 0], a.normal), 0.0, atol=1e-9)
    per_element = np.bincount(a.component)
    assert np.all(np.abs(per_element - np.maximum(8, np.round(area * 25.0))) <= 1)


def test_the_density_model_uses_the_presets_angular_steps():
    grid = BeamGrid.of(PRESETS["exp3"], VZ400)
    assert math.degrees(grid.vertical_step_rad) == pytest.approx(240.0 * 240.0 / 100_000.0)
    assert math.degrees(grid.horizontal_step_rad) == pytest.approx(10.0 / 240.0)
    # a surface 5 m away, facing the beam on the horizon: one point per r^2 dv dh
    expected = 1.0 / (25.0 * grid.vertical_step_rad * grid.horizontal_step_rad)
    assert grid.density(np.array([5.0]), np.array([1.0]), np.array([0.0]))[0] == pytest.approx(expected)
    assert grid.reach_m(expected) == pytest.approx(5.0)
    # tilted by 60 degrees: half; seen 45 degrees up: the azimuth lines are closer, sqrt(2) more
    assert grid.density(np.array([5.0]), np.array([0.5]), np.array([math.pi / 4]))[0] == pytest.approx(
        expected * 0.5 * math.sqrt(2.0))


def test_normal_bins_tell_floors_from_walls_of_different_directions():
    normals = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0.6, 0, 0.8]], dtype=float)
    bins = normal_bins(normals)
    assert bins[0] == bins[1] == 0
    assert bins[2] == bins[3] != bins[4]
    assert bins[5] not in (0, bins[2])


def test_scan_order_walks_the_registration_graph():
    heads = np.array([[0.0, 0, 1.7], [10, 0, 1.7], [5, 0, 1.7], [0, 5, 1.7]])
    edges = np.zeros((4, 4), dtype=bool)
    for a, b in ((0, 2), (2, 1), (0, 3)):
        edges[a, b] = edges[b, a] = True
    order = scan_order(np.array([1, 2, 0, 3]), heads, edges)
    assert order[0] == 0  # the south-west corner first
    for k in range(1, 4):
        assert edges[order[k], order[:k]].any()


def test_a_station_file_of_the_plan_reads_back_with_its_floors_and_storeys(box_room_ifc, tmp_path):
    plan = plan_survey(plan_space(box_room_ifc))
    path = tmp_path / "stations.csv"
    path.write_text(format_stations(plan.stations, comments=("a plan",)), "utf-8")
    scene = load_scene(box_room_ifc)
    back = read_stations(path, scene, Prober(scene.mesh), VZ400)
    assert len(back) == len(plan.stations)
    for a, b in zip(plan.stations, back):
        assert b.id == a.id and b.storey == a.storey
        assert np.allclose(a.position, b.position, atol=1e-4) and b.floor_z == pytest.approx(a.floor_z, abs=1e-4)


@pytest.mark.slow
def test_the_scan_of_a_plan_shows_the_coverage_the_plan_estimates(box_room_ifc, tmp_path):
    # a fast scan (head 3x faster: a third of the points) and a density to match
    recipe = ScanRecipe.resolve(preset="exp3", head_deg_per_s=30.0)
    space = plan_space(box_room_ifc, recipe=recipe, classes=("Wall&Column", "Slab"), density_pts_m2=300.0)
    plan = plan_survey(space)
    stations = tmp_path / "stations.csv"
    stations.write_text(format_stations(plan.stations), "utf-8")
    cloud = scan_model(box_room_ifc, tmp_path / "scan", recipe.with_fields(stations_from=str(stations)),
                       progress=False).path
    columns = {s.id: int(plan.chosen[s.id]) for s in read_cloud_header(cloud).stations}  # the plan's, in order
    counts = points_per_sample(iter_cloud_chunks(cloud), space.samples, space.visibility, columns,
                               counted=space.klass >= 0)
    patches = patch_matrix(space.samples)
    measured = patch_density(counts, space.samples, per_area=True, patches=patches)
    estimate = evaluate(plan)
    on_scan = evaluate(plan, density=measured)
    for name in ("Wall&Column", "Slab"):
        assert on_scan.classes[name]["covered_fraction"] >= 0.95
        assert abs(on_scan.classes[name]["covered_fraction"] - estimate.classes[name]["covered_fraction"]) <= 0.05
    # the density model against the scan, patch by patch
    predicted = patch_density(estimate.density, space.samples, per_area=False, patches=patches)
    useful = space.visibility.reachable & (predicted > 30.0)
    ratio = np.median(measured[useful] / predicted[useful])
    assert 0.9 <= ratio <= 1.1


def test_a_scan_point_counts_on_the_face_its_station_sees_within_the_incidence_limit(box_room_ifc):
    space = plan_space(box_room_ifc, classes=("Wall&Column",))
    samples, visibility = space.samples, space.visibility
    within = visibility.density_pts_m2 > 0
    edge_on = ~within
    assert within.any() and edge_on.any()
    i, j = visibility.sample[within][0], visibility.sample[edge_on][0]
    seen_by, grazed_by = int(visibility.station[within][0]), int(visibility.station[edge_on][0])
    from bimscan.types import PointCloud

    points = PointCloud(xyz=samples.xyz[[i, j]], component=samples.component[[i, j]].astype(np.int32),
                        station=np.array([0, 1], dtype=np.uint16))
    counts = points_per_sample([points], samples, visibility, {0: seen_by, 1: grazed_by})
    assert counts[i] == 1 and counts.sum() == 1  # the point seen only beyond the limit does not count
    # a point of a station the plan does not know is skipped
    assert points_per_sample([points], samples, visibility, {1: grazed_by}).sum() == 0


def test_planning_the_same_model_twice_gives_the_same_stations(box_room_ifc):
    a = plan_survey(plan_space(box_room_ifc))
    b = plan_survey(plan_space(box_room_ifc))
    assert [s.position for s in a.stations] == [s.position for s in b.stations]


def test_given_stations_join_the_candidates_after_the_spots(box_room_ifc):
    station = Station(id=0, position=(4.0, 3.0, 1.7), floor_z=0.0)
    space = plan_space(box_room_ifc, given=(station,))
    assert len(space.heads) == space.n_spots + 1 and np.allclose(space.heads[-1], station.position)


def test_a_station_in_a_doorway_scans_when_the_stage_leaves_the_door_out(tiny_model, tmp_path):
    # plan and scan judge a tripod spot alike: the station check, on the site as it is scanned
    path = two_rooms(tiny_model, tmp_path / "door.ifc", door=True)
    stations = tmp_path / "stations.csv"
    stations.write_text("x,y,z,height\n3,2.5,1.7,1.7\n6.18,2.5,1.7,1.7\n", "utf-8")  # 2 cm from the door leaf
    doors_open = ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, stations_from=str(stations),
                                    site=SiteModel(stage=StageSettings(exclude=("IfcDoor",))))
    cloud = scan_model(path, tmp_path / "open.laz", doors_open, progress=False).path
    assert [s.position for s in read_cloud_header(cloud).stations] == [(3.0, 2.5, 1.7), (6.18, 2.5, 1.7)]
    with pytest.raises(StationError, match="2 cm from IfcDoor .* closer than a scanner head allows"):
        scan_model(path, tmp_path / "closed.laz", doors_open.with_fields(site=SiteModel()), progress=False)


def test_every_candidate_spot_passes_the_station_check_of_the_scan(tiny_model, tmp_path):
    path = two_rooms(tiny_model, tmp_path / "door.ifc", door=True)
    recipe = ScanRecipe(site=SiteModel(stage=StageSettings(exclude=("IfcDoor",))))
    scene = build_site(load_scene(path), recipe)
    space = plan_space(path, recipe=recipe, scene=scene, classes=("Wall&Column",))
    prober = Prober(scene.mesh)
    for floor, head in zip(space.floors[:space.n_spots], space.heads):
        assert station_problem(Station(id=0, position=tuple(head), floor_z=float(floor[2])), scene, prober) is None


def _rewound(scene, flip: np.ndarray, *, twice: np.ndarray | None = None):
    """The scene with the triangles ``flip`` (F,) bool wound the other way, and those ``twice`` also
    added a second time, wound the other way (a face an authoring tool exports on both sides)."""
    mesh = scene.mesh
    faces = np.where(flip[:, None], mesh.faces[:, ::-1], mesh.faces)
    component = mesh.face_component
    if twice is not None:
        faces = np.concatenate([faces, faces[twice][:, ::-1]])
        component = np.concatenate([component, component[twice]])
    mesh = dataclasses.replace(mesh, faces=np.ascontiguousarray(faces), face_component=component,
                               face_transparency=None)
    return dataclasses.replace(scene, mesh=mesh)


def test_what_a_station_sees_does_not_depend_on_how_the_triangles_are_wound(box_room_ifc):
    scene = load_scene(box_room_ifc)
    coarse = {"samples_per_m2": 9.0, "grid_m": 1.5}
    base = plan_space(box_room_ifc, scene=scene, **coarse)
    slabs = scene.components.ifc_class[scene.mesh.face_component] == "IfcSlab"
    some = np.random.default_rng(1).random(scene.mesh.n_triangles) < 0.5
    for flip in (slabs, some):  # every slab wound inwards; half of all triangles, faces mixed
        other = plan_space(box_room_ifc, scene=_rewound(scene, flip), **coarse)
        assert np.array_equal(other.samples.xyz, base.samples.xyz)
        for column in ("sample", "station", "density_pts_m2"):
            assert np.array_equal(getattr(other.visibility, column), getattr(base.visibility, column)), column
        assert np.array_equal(other.edges, base.edges)
        # the ceiling's underside faces the stations under it (the plan's ceiling view), however it is wound
        seen = base.visibility.seen
        assert np.array_equal(other.samples.normal[seen], base.samples.normal[seen])
        roof = (other.samples.component == list(scene.components.name).index("roof")) & seen
        assert roof.any() and np.all(other.samples.normal[roof, 2] == -1.0)


def test_a_ceiling_exported_twice_once_wound_each_way_is_seen_on_both_copies(box_room_ifc):
    scene = load_scene(box_room_ifc)
    roof = list(scene.components.name).index("roof")
    underside = (scene.mesh.face_component == roof) & (scene.mesh.face_normals()[:, 2] < -0.9)
    visible = []
    for model in (scene, _rewound(scene, np.zeros(scene.mesh.n_triangles, dtype=bool), twice=underside)):
        space = plan_space(box_room_ifc, scene=model, classes=("Slab",), samples_per_m2=9.0, grid_m=1.5)
        on_roof = (space.samples.component == roof) & space.visibility.reachable
        visible.append(space.samples.area_m2[on_roof].sum())
    assert visible[0] > 40.0  # the room's 48 m2 of ceiling, less what hides behind the walls' edges
    assert visible[1] == pytest.approx(2 * visible[0], rel=0.02)


def test_each_rung_of_the_coverage_ladder_costs_what_a_plan_for_that_coverage_does(box_room_ifc):
    plan = plan_survey(plan_space(box_room_ifc, classes=("Slab",), coverage_ladder=(0.5, 0.95)))
    half = plan_survey(plan_space(box_room_ifc, classes=("Slab",), coverage=(0.5,), coverage_ladder=()))
    assert plan.ladder == (LadderRung(coverage=0.5, stations=len(half.stations)),
                           LadderRung(coverage=0.95, stations=len(plan.stations)))
    assert len(half.stations) == 1 < len(plan.stations) and half.ladder == ()


def test_a_ceiling_flush_with_the_slabs_underside_is_seen_whole_and_so_is_the_underside(tiny_model, tmp_path):
    # the covering's underside and the roof slab's lie in one plane: whichever the engine reports, the ray got there
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(-W, -W, -S), size=(6 + 2 * W, 5 + 2 * W, S), predefined_type="FLOOR", name="floor")
    model.add_box("IfcSlab", origin=(-W, -W, 3.0), size=(6 + 2 * W, 5 + 2 * W, S), predefined_type="ROOF", name="roof")
    for name, origin, size in (("south", (-W, -W, 0.0), (6 + 2 * W, W, 3.0)), ("north", (-W, 5.0, 0.0), (6 + 2 * W, W, 3.0)),
                               ("west", (-W, 0.0, 0.0), (W, 5.0, 3.0)), ("east", (6.0, 0.0, 0.0), (W, 5.0, 3.0))):
        model.add_box("IfcWall", origin=origin, size=size, name=name)
    model.add_box("IfcCovering", origin=(0.0, 0.0, 3.0), size=(6.0, 5.0, 0.02), predefined_type="CEILING", name="ceiling")
    space = plan_space(model.write(tmp_path / "flush.ifc"), classes=("Covering", "Slab"), samples_per_m2=9.0,
                       grid_m=1.5)
    names = list(space.scene.components.name)
    x, y, z = space.samples.xyz.T
    middle = (np.abs(z - 3.0) < 1e-6) & (np.abs(x - 3.0) < 2.5) & (np.abs(y - 2.5) < 2.0)  # away from the walls
    for name in ("ceiling", "roof"):
        mine = (space.samples.component == names.index(name)) & middle
        assert mine.sum() > 50 and space.visibility.reachable[mine].all(), name

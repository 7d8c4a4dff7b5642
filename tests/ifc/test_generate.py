"""make_building: seeded buildings of every style as IFC4, checked through IfcOpenShell's own geometry."""

from __future__ import annotations

import hashlib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import ifcopenshell
import ifcopenshell.geom
import ifcopenshell.util.element
import ifcopenshell.util.placement
import numpy as np
import pytest

from bimscan.errors import ConfigError, OutputError
from bimscan.ifc.generate import GeneratedBuilding, build_building_model, make_building
from bimscan.ifc.generate.floor_plan import plan_building
from bimscan.ifc.generate.styles import STYLES

TOLERANCE_M = 0.03  # door casings stand 5 mm proud of the walls; anything more is a bug


@dataclass(frozen=True)
class Triangulated:
    model: ifcopenshell.file
    building: GeneratedBuilding
    expected: tuple[ifcopenshell.entity_instance, ...]  # elements with a body, spaces/openings excluded
    shapes: dict[int, tuple[np.ndarray, np.ndarray]]  # element id -> (vertices (V,3) f8, faces (F,3) i4)


def triangulate(model: ifcopenshell.file, elements: list) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """World-coordinate triangles of ``elements`` from ifcopenshell.geom.iterator."""
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    iterator = ifcopenshell.geom.iterator(settings, model, 2, include=elements)
    shapes: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    assert iterator.initialize(), "the geometry iterator found nothing to triangulate"
    while True:
        shape = iterator.get()
        vertices = np.frombuffer(shape.geometry.verts_buffer, dtype=np.float64).reshape(-1, 3).copy()
        faces = np.frombuffer(shape.geometry.faces_buffer, dtype=np.int32).reshape(-1, 3).copy()
        if len(faces):
            shapes[shape.id] = (vertices, faces)
        if not iterator.next():
            break
    return shapes


def scannable(model: ifcopenshell.file) -> list:
    return [
        p
        for p in model.by_type("IfcProduct")
        if p.Representation is not None and not p.is_a("IfcSpace") and not p.is_a("IfcOpeningElement")
    ]


def first_seed(style: str, storeys: int, wanted) -> int:
    """The first seed whose plan satisfies ``wanted`` (plans are cheap; files are not)."""
    return next(seed for seed in range(200) if wanted(plan_building(seed=seed, storeys=storeys, style=style)))


@pytest.fixture(scope="module")
def two_storeys() -> Triangulated:
    """A two-storey office with downstand beams in view and a non-rectangular outline."""
    seed = first_seed("office", 2, lambda p: p.ceiling_system == "downstand" and p.shape != "rectangle")
    model, building = build_building_model(seed=seed, storeys=2)
    expected = tuple(scannable(model))
    return Triangulated(model, building, expected, triangulate(model, list(expected)))


def world_matrix(element) -> np.ndarray:
    return ifcopenshell.util.placement.get_local_placement(element.ObjectPlacement)


def ray_hits(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Distance to the first hit of each ray on the mesh (inf where it passes), via Open3D."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    rays = np.hstack([origins, np.broadcast_to(direction, origins.shape)]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()


def test_same_seed_gives_byte_identical_files(tmp_path: Path) -> None:
    first = make_building(tmp_path / "a.ifc", seed=3, storeys=2)
    second = make_building(tmp_path / "b.ifc", seed=3, storeys=2)
    assert (tmp_path / "a.ifc").read_bytes() == (tmp_path / "b.ifc").read_bytes()
    assert first.path == tmp_path / "a.ifc" and second.path == tmp_path / "b.ifc"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.ifc", "b.ifc"]  # no temporary files left


@pytest.mark.parametrize("style", sorted(STYLES))
def test_every_style_gives_the_same_bytes_for_the_same_seed_and_differs_from_the_others(style: str) -> None:
    texts = {s: build_building_model(seed=6, storeys=1, style=s)[0].to_string() for s in (style, "office")}
    assert build_building_model(seed=6, storeys=1, style=style)[0].to_string() == texts[style]
    if style != "office":
        assert texts[style] != texts["office"]


def test_file_header_holds_no_clock_time(tmp_path: Path) -> None:
    make_building(tmp_path / "a.ifc", seed=1, storeys=1)
    model = ifcopenshell.open(str(tmp_path / "a.ifc"))
    assert model.schema == "IFC4"
    assert model.header.file_name.time_stamp == "2024-01-01T00:00:00"


def test_different_seeds_give_different_files_and_room_layouts() -> None:
    layouts, texts = [], []
    for seed in (0, 1):
        model, _ = build_building_model(seed=seed, storeys=1)
        texts.append(model.to_string())
        spaces = triangulate(model, model.by_type("IfcSpace"))
        boxes = sorted(tuple(np.round(np.r_[v.min(0), v.max(0)], 2)) for v, _ in spaces.values())
        layouts.append(boxes)
    assert texts[0] != texts[1]
    assert layouts[0] != layouts[1]


def test_global_ids_are_unique_and_follow_the_seed() -> None:
    ids = {}
    for seed in (0, 1):
        model, _ = build_building_model(seed=seed, storeys=1)
        ids[seed] = [e.GlobalId for e in model.by_type("IfcRoot")]
        assert len(set(ids[seed])) == len(ids[seed])
        assert all(len(g) == 22 for g in ids[seed])
    assert not set(ids[0]) & set(ids[1])


def test_every_placed_element_triangulates_and_counts_match_placed(two_storeys: Triangulated) -> None:
    failed = [(e.is_a(), e.Name) for e in two_storeys.expected if e.id() not in two_storeys.shapes]
    assert failed == []
    counts = Counter(two_storeys.model.by_id(i).is_a() for i in two_storeys.shapes)
    assert dict(counts) == dict(two_storeys.building.placed)


def test_triangle_bounds_match_footprint_and_height(two_storeys: Triangulated) -> None:
    vertices = np.concatenate([v for v, _ in two_storeys.shapes.values()])
    xmin, ymin, xmax, ymax = two_storeys.building.footprint_m
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    np.testing.assert_allclose(lo[:2], (xmin, ymin), atol=TOLERANCE_M)
    np.testing.assert_allclose(hi[:2], (xmax, ymax), atol=TOLERANCE_M)
    assert hi[2] == pytest.approx(two_storeys.building.height_m, abs=TOLERANCE_M)
    assert -0.3 <= lo[2] < 0.0  # only the ground slab lies below the ground floor level
    assert 10.0 <= xmax - xmin <= 40.0 and 8.0 <= ymax - ymin <= 30.0


def test_storeys_are_as_far_apart_as_the_plan_says_and_hold_one_space_per_room(two_storeys: Triangulated) -> None:
    model, building = two_storeys.model, two_storeys.building
    storeys = sorted(model.by_type("IfcBuildingStorey"), key=lambda s: s.Elevation)
    assert tuple(s.Elevation for s in storeys) == building.storey_elevations_m
    spaces = [[p for p in ifcopenshell.util.element.get_parts(s) if p.is_a("IfcSpace")] for s in storeys]
    assert tuple(len(s) for s in spaces) == building.rooms_per_storey
    assert all(6 <= n <= 30 for n in building.rooms_per_storey)
    low, high = STYLES["office"].storey_height_m
    assert np.diff(building.storey_elevations_m)[0] == pytest.approx(building.plan.storey_height_m)
    assert low <= building.plan.storey_height_m <= high
    assert all(space.Representation is not None for group in spaces for space in group)


def test_every_class_of_the_five_class_scheme_is_present(two_storeys: Triangulated) -> None:
    model, placed = two_storeys.model, two_storeys.building.placed
    for cls in ("IfcWall", "IfcColumn", "IfcBeam", "IfcCovering", "IfcSlab"):
        assert placed.get(cls, 0) > 0, cls
    for cls in ("IfcDoor", "IfcWindow", "IfcFurniture", "IfcStairFlight", "IfcRailing"):
        assert placed.get(cls, 0) > 0, cls
    slab_types = {s.PredefinedType for s in model.by_type("IfcSlab")}
    assert {"BASESLAB", "FLOOR", "ROOF", "LANDING"} <= slab_types
    assert {c.PredefinedType for c in model.by_type("IfcCovering")} == {"CEILING"}
    assert len(model.by_type("IfcStair")) == 1


def test_walls_are_as_thick_and_high_as_planned_and_exterior_walls_are_the_thickest(two_storeys: Triangulated) -> None:
    plan = two_storeys.building.plan
    planned = {f"Wall {w.name}": w for w in plan.storeys[0].walls}
    thickness = {}
    for wall in two_storeys.model.by_type("IfcWall"):
        if wall.ContainedInStructure[0].RelatingStructure.Name != "Ground floor":
            continue
        vertices, _ = two_storeys.shapes[wall.id()]
        thickness[wall.Name] = float(np.ptp(vertices[:, :2], axis=0).min())
        assert np.ptp(vertices[:, 2]) == pytest.approx(planned[wall.Name].height_m, abs=1e-6), wall.Name
    assert set(thickness) == set(planned)
    for name, t in thickness.items():
        assert t == pytest.approx(planned[name].thickness_m, abs=1e-6), name
    exterior = {t for name, t in thickness.items() if planned[name].exterior}
    interior = {t for name, t in thickness.items() if not planned[name].exterior}
    assert len({round(t, 3) for t in thickness.values()}) >= 3  # facade, corridor, partitions
    assert min(exterior) >= max(interior) - 0.15  # only a stair core wall may come near a facade


def test_window_and_door_openings_are_cut_through_their_walls(two_storeys: Triangulated) -> None:
    model = two_storeys.model
    checked = Counter()
    for filling in [*model.by_type("IfcDoor"), *model.by_type("IfcWindow")]:
        opening = filling.FillsVoids[0].RelatingOpeningElement
        wall = opening.VoidsElements[0].RelatingBuildingElement
        vertices, faces = two_storeys.shapes[wall.id()]
        m = world_matrix(filling)
        across = m[:3, 1]  # the filling's local y crosses the wall
        wall_top = vertices[:, 2].max() - m[2, 3]  # above the filling's base
        lintel = (filling.OverallHeight + wall_top) / 2  # half way between opening head and wall top
        centre = m[:3, 3] + m[:3, 0] * filling.OverallWidth / 2 + np.array([0, 0, filling.OverallHeight / 2])
        above = m[:3, 3] + m[:3, 0] * filling.OverallWidth / 2 + np.array([0, 0, lintel])
        start = np.stack([centre, above]) - across * 1.0
        t_hit = ray_hits(vertices, faces, start, across)
        assert np.isinf(t_hit[0]), f"a ray through {filling.Name} hits its wall {wall.Name} at {t_hit[0]:.3f} m"
        assert t_hit[1] == pytest.approx(1.0, abs=0.01), f"the wall {wall.Name} is missing above {filling.Name}"
        checked[filling.is_a()] += 1
    assert checked["IfcDoor"] >= 5 and checked["IfcWindow"] >= 5


def test_every_room_has_a_door(two_storeys: Triangulated) -> None:
    model = two_storeys.model
    doors = model.by_type("IfcDoor")
    door_points = np.array(
        [world_matrix(d)[:3, 3] + world_matrix(d)[:3, 0] * d.OverallWidth / 2 for d in doors]
    )
    spaces = model.by_type("IfcSpace")
    shapes = triangulate(model, spaces)
    for space in spaces:
        vertices, _ = shapes[space.id()]
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        # A door sits in a wall of the room: within half a wall thickness (plus slack) of its edge.
        near = (
            (door_points[:, 0] > lo[0] - 0.4)
            & (door_points[:, 0] < hi[0] + 0.4)
            & (door_points[:, 1] > lo[1] - 0.4)
            & (door_points[:, 1] < hi[1] + 0.4)
            & (np.abs(door_points[:, 2] - lo[2]) < 0.01)
        )
        assert near.any(), f"room {space.Name} ({space.LongName}) has no door"


def test_stair_climbs_one_storey_through_an_opening_in_the_slab_above(two_storeys: Triangulated) -> None:
    model, building = two_storeys.model, two_storeys.building
    flights = model.by_type("IfcStairFlight")
    z = np.concatenate([two_storeys.shapes[f.id()][0][:, 2] for f in flights])
    bottom, top = building.storey_elevations_m
    # The first riser starts on the lower floor; the last one is the upper slab's edge.
    assert z.min() == pytest.approx(bottom, abs=1e-6)
    assert top - 0.19 <= z.max() < top - 0.15
    landing = next(s for s in model.by_type("IfcSlab") if s.PredefinedType == "LANDING")
    assert two_storeys.shapes[landing.id()][0][:, 2].max() == pytest.approx((bottom + top) / 2, abs=1e-6)
    upper = next(s for s in model.by_type("IfcSlab") if s.PredefinedType == "FLOOR")
    voids = [r.RelatedOpeningElement for r in upper.HasOpenings]
    assert len(voids) == 1
    # A vertical ray above the upper flight's foot passes the upper slab.
    flight_vertices = np.concatenate([two_storeys.shapes[f.id()][0] for f in flights])
    x, y = flight_vertices[:, :2].mean(axis=0)
    vertices, faces = two_storeys.shapes[upper.id()]
    above = np.array([[x, y, building.storey_elevations_m[1] + 1.0]])
    t_hit = ray_hits(vertices, faces, above, np.array([0.0, 0.0, -1.0]))
    assert np.isinf(t_hit[0])


def test_steps_have_treads_and_risers(two_storeys: Triangulated) -> None:
    flight = two_storeys.model.by_type("IfcStairFlight")[0]
    vertices, _ = two_storeys.shapes[flight.id()]
    levels = np.unique(np.round(vertices[:, 2], 4))
    # Nine or more risers per half storey: ten or more step levels (plus the soffit's corner),
    # most of them one riser, 0.15 to 0.19 m, apart.
    assert len(levels) >= 10
    assert 0.15 <= float(np.median(np.diff(levels))) <= 0.19


def test_beams_hang_below_the_ceilings_which_fill_the_bays_between_them(two_storeys: Triangulated) -> None:
    model, plan = two_storeys.model, two_storeys.building.plan
    ground = plan.storeys[0]
    beam_z = [two_storeys.shapes[b.id()][0][:, 2] for b in model.by_type("IfcBeam")]
    ceiling_z = [two_storeys.shapes[c.id()][0][:, 2] for c in model.by_type("IfcCovering")]
    lower = [z for z in beam_z if z.max() < plan.storey_height_m]
    assert len(lower) == len(plan.beams) and len(ceiling_z) == sum(len(s.ceilings) for s in plan.storeys)
    assert all(z.min() == pytest.approx(plan.beam_bottom_m, abs=1e-6) for z in lower)
    assert all(z.max() == pytest.approx(plan.soffit_m, abs=1e-6) for z in lower)
    covering = [z for z in ceiling_z if z.max() < plan.storey_height_m]
    assert all(z.min() == pytest.approx(plan.ceiling_height_m, abs=1e-6) for z in covering)
    assert plan.beam_bottom_m < plan.ceiling_height_m - 0.25  # in view, as in the S3DIS offices
    assert len(covering) == len(ground.ceilings)


@pytest.mark.parametrize("style", sorted(STYLES))
def test_one_storey_building_has_no_stair(style: str) -> None:
    model, building = build_building_model(seed=4, storeys=1, style=style)
    assert building.storeys == 1 and len(building.rooms_per_storey) == 1 and building.style == style
    assert "IfcStairFlight" not in building.placed and not model.by_type("IfcStair")
    assert {s.PredefinedType for s in model.by_type("IfcSlab")} == {"BASESLAB", "ROOF"}


def test_doors_and_windows_of_one_size_share_a_type_whose_body_they_map() -> None:
    model, building = build_building_model(seed=2, storeys=1)
    for ifc_class in ("IfcDoor", "IfcWindow"):
        occurrences = model.by_type(ifc_class)
        types = {o.IsTypedBy[0].RelatingType.id() for o in occurrences}
        assert 0 < len(types) < len(occurrences)
        for o in occurrences:
            item = o.Representation.Representations[0].Items[0]
            assert item.is_a("IfcMappedItem")
            assert item.MappingSource in o.IsTypedBy[0].RelatingType.RepresentationMaps


def test_an_unknown_style_raises_config_error_naming_the_styles(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="office, residential, site") as info:
        make_building(tmp_path / "b.ifc", seed=0, storeys=1, style="castle")
    assert "castle" in str(info.value) and "\n" not in str(info.value)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("storeys", [0, 11, 50, -1])
def test_storeys_outside_1_to_10_raise_config_error_naming_the_range(storeys: int, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"1\.\.10") as info:
        make_building(tmp_path / "b.ifc", seed=0, storeys=storeys)
    assert "\n" not in str(info.value)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("seed", [-1, 1.5, "3"])
def test_a_seed_that_is_not_a_non_negative_integer_raises_config_error(seed: object) -> None:
    with pytest.raises(ConfigError, match="seed"):
        make_building(None, seed=seed, storeys=1)  # type: ignore[arg-type]


def test_missing_output_folder_raises_output_error(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="does not exist"):
        make_building(tmp_path / "missing" / "b.ifc", seed=0, storeys=1)
    assert not (tmp_path / "missing").exists()


def test_output_without_ifc_suffix_raises_output_error(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match=r"\.ifc"):
        make_building(tmp_path / "b.txt", seed=0, storeys=1)
    assert not any(tmp_path.iterdir())


def test_in_memory_building_matches_the_written_file(tmp_path: Path) -> None:
    written = make_building(tmp_path / "b.ifc", seed=2, storeys=1)
    model, in_memory = build_building_model(seed=2, storeys=1)
    in_memory_digest = hashlib.sha256(model.to_string().encode()).digest()
    assert in_memory_digest == hashlib.sha256((tmp_path / "b.ifc").read_bytes()).digest()
    assert in_memory.path is None and written.placed == in_memory.placed

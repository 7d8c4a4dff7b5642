"""Placement: on the floor, inside rooms, collision-free with the model and each other, doors and
tripod spots clear, reproducible."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.site import ClutterSettings, SiteModel, dress_scene
from tests.site.conftest import component_meshes, edges_cross, raycasting_scene


def added(dressed, original) -> np.ndarray:
    """Component ids of the objects dressing added."""
    return np.arange(len(original.components), len(dressed.components))


def fixtures(dressed, original) -> np.ndarray:
    """Component ids of the objects dressing hung under the ceiling."""
    new = added(dressed, original)
    return new[np.char.startswith(dressed.components.ifc_class[new].astype(str), "Fixture.")]


def test_clutter_is_added_as_new_components_at_about_the_density(office_scene, dressed_office):
    new = added(dressed_office, office_scene)
    state = dressed_office.site
    assert len(new) == sum(state.placed.values()) > 20
    assert all(c.startswith(("Clutter.", "Fixture.", "Person.")) for c in dressed_office.components.ifc_class[new])
    on_floor = len(new) - len(fixtures(dressed_office, office_scene))
    # 0.3 objects per square metre of free floor, rounded per room, some rooms too full for all of them
    assert 0.6 * 0.3 * state.free_floor_m2 <= on_floor <= 0.3 * state.free_floor_m2 + state.rooms + 1
    assert len(set(dressed_office.components.global_id.tolist())) == len(dressed_office.components)
    assert all(len(g) == 22 for g in dressed_office.components.global_id[new])


def test_no_object_crosses_the_model_or_stands_inside_a_solid(office_scene, dressed_office):
    from bimscan.scan.probe import Prober

    model = raycasting_scene(office_scene.mesh.vertices, office_scene.mesh.faces)
    scanner = Prober(office_scene.mesh)
    lifted = np.array([0.0, 0.0, 0.001])  # standing on the floor, not in it
    for c, (v, f) in component_meshes(dressed_office, added(dressed_office, office_scene)).items():
        assert not edges_cross(v + lifted, f, model), dressed_office.components.name[c]
        near = _model_near(office_scene, v.min(axis=0) - 0.05, v.max(axis=0) + 0.05)
        assert not edges_cross(*near, raycasting_scene(v + lifted, f)), dressed_office.components.name[c]
        assert scanner.solid_containing(v[0] + [0.0, 0.0, 0.002]) is None


def _model_near(scene, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = scene.mesh.vertices[scene.mesh.faces]
    near = ((corners.max(axis=1) >= lo) & (corners.min(axis=1) <= hi)).all(axis=1)
    return scene.mesh.vertices, scene.mesh.faces[near]


def test_no_two_objects_cross_each_other(office_scene, dressed_office):
    meshes = component_meshes(dressed_office, added(dressed_office, office_scene))
    items = list(meshes.items())
    for k, (a, (va, fa)) in enumerate(items):
        for b, (vb, fb) in items[k + 1:]:
            if (va.max(axis=0) < vb.min(axis=0)).any() or (vb.max(axis=0) < va.min(axis=0)).any():
                continue
            assert not edges_cross(va, fa, raycasting_scene(vb, fb)), (a, b)
            assert not edges_cross(vb, fb, raycasting_scene(va, fa)), (a, b)


def test_objects_stand_on_the_floor_inside_a_room(office_scene, dressed_office):
    from bimscan.scan.probe import Prober

    scanner = Prober(office_scene.mesh)
    hung = 0
    on_ceiling = set(fixtures(dressed_office, office_scene).tolist())
    for c, (v, _) in component_meshes(dressed_office, added(dressed_office, office_scene)).items():
        if c in on_ceiling:
            continue
        bottom = v[v[:, 2] < v[:, 2].min() + 1e-6]
        t, hit = scanner.cast(bottom[0] + [0.0, 0.0, 0.5], np.array([[0.0, 0.0, -1.0]], np.float32))
        if dressed_office.components.ifc_class[c] == "Clutter.Whiteboard" and t[0] > 1.0:
            assert 0.8 < t[0] - 0.5 < 1.05  # a board hung on the wall, its bottom edge 0.85-1.0 m up
            hung += 1
            continue
        assert t[0] == pytest.approx(0.5, abs=1e-3), dressed_office.components.name[c]  # the floor is right below
        assert office_scene.components.ifc_class[hit[0]] in ("IfcSlab", "IfcCovering")
        footprint = np.column_stack([v[:, :2], np.full(len(v), v[:, 2].min() + 0.1)])
        assert any(space.contains(footprint).all() for space in office_scene.spaces), dressed_office.components.name[c]


def test_fixtures_hang_just_under_a_soffit_in_a_grid_and_clear_of_heads(office_scene, dressed_office):
    from bimscan.scan.probe import Prober
    from bimscan.site.library import MIN_CLEAR_UNDER_FIXTURE_M

    scanner = Prober(office_scene.mesh)
    hung = fixtures(dressed_office, office_scene)
    assert len(hung) >= 2 * dressed_office.site.rooms  # lights and air terminals in most rooms
    level = min(s.elevation_m for s in office_scene.storeys)
    centres = []
    for c, (v, _) in component_meshes(dressed_office, hung).items():
        top = v[v[:, 2] > v[:, 2].max() - 1e-6][0]
        t, hit = scanner.cast(top - [0.0, 0.0, 0.001], np.array([[0.0, 0.0, 1.0]], np.float32))
        assert 0.002 <= t[0] <= 0.003 + 0.02, dressed_office.components.name[c]  # 2 mm under the soffit
        assert office_scene.components.ifc_class[hit[0]] in ("IfcSlab", "IfcCovering", "IfcRoof")
        assert v[:, 2].min() >= level + MIN_CLEAR_UNDER_FIXTURE_M - 1e-6
        if dressed_office.components.predefined_type[c] == "CEILING_LIGHT":
            centres.append((v.min(axis=0) + v.max(axis=0))[:2] / 2)
    # a grid, not a scatter: the lights of a room stand at a spacing of 1.8-2.7 m (0.3 m nudges aside)
    centres = np.array(centres)
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2) + np.eye(len(centres)) * 99
    assert gaps.min() > 0.5 and np.median(gaps.min(axis=1)) < 2.7 + 0.6


def test_furniture_keeps_every_doorway_clear(office_scene, dressed_office):
    doors = np.flatnonzero(office_scene.components.ifc_class == "IfcDoor")
    assert len(doors)
    on_ceiling = set(fixtures(dressed_office, office_scene).tolist())  # above the way through, 2.1 m up
    objects = {c: m for c, m in component_meshes(dressed_office, added(dressed_office, office_scene)).items()
               if c not in on_ceiling}
    for d in doors:
        v = office_scene.mesh.vertices[np.unique(office_scene.mesh.faces[office_scene.mesh.face_component == d])]
        lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
        across = int(np.argmin(hi - lo))  # the thin side of the door runs across the doorway
        grow = np.full(2, 0.05)
        grow[across] = 0.9  # the way through: 0.9 m on either side of the leaf
        for ov, _ in objects.values():
            low = ov[ov[:, 2] < ov[:, 2].min() + 2.0, :2]
            inside = ((low >= lo - grow) & (low <= hi + grow)).all(axis=1)
            assert not inside.any()


def test_every_room_that_had_a_station_still_gets_one(office_scene, dressed_office):
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.survey import choose_stations

    recipe = ScanRecipe()
    _, before = choose_stations(office_scene, recipe)
    stations, after = choose_stations(dressed_office, recipe)
    assert set(after.rooms_without_station) <= set(before.rooms_without_station)
    rooms_with = {s.room for s in stations}
    assert {s.name for s in office_scene.spaces} - set(before.rooms_without_station) <= rooms_with


def test_the_same_seed_gives_the_same_bytes_and_another_seed_other_clutter(office_scene, dressed_office):
    again = dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.3)), seed=5)
    assert again.mesh.vertices.tobytes() == dressed_office.mesh.vertices.tobytes()
    assert again.mesh.faces.tobytes() == dressed_office.mesh.faces.tobytes()
    assert again.components.rows() == dressed_office.components.rows()
    other = dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.3)), seed=6)
    assert other.mesh.vertices.tobytes() != dressed_office.mesh.vertices.tobytes()


def test_kinds_select_what_is_placed_and_density_how_much(office_scene):
    chairs = dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.1, kinds=("chair",))), seed=1)
    assert set(chairs.site.placed) == {"Clutter.Chair"}
    lights = dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.1, kinds=("ceiling",))), seed=1)
    assert set(lights.site.placed) == {"Fixture.Luminaire", "Fixture.AirTerminal"}
    sparse = dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.05, kinds=("site",))), seed=1)
    dense = dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.25, kinds=("site",))), seed=1)
    assert set(sparse.site.placed) | set(dense.site.placed) <= {
        "Clutter.MaterialStack", "Clutter.Pallet", "Clutter.Box", "Clutter.Bucket", "Clutter.CableDrum",
        "Clutter.WasteBin", "Temporary.Ladder", "Temporary.Trestle", "Temporary.ScaffoldTower", "Temporary.Prop"}
    assert sum(dense.site.placed.values()) > 2 * sum(sparse.site.placed.values())


@pytest.mark.parametrize("seed", range(6))
def test_a_model_without_rooms_is_dressed_on_its_free_floor(box_room_ifc, seed):
    from bimscan.pipeline import load_scene

    scene = load_scene(box_room_ifc)
    assert not scene.spaces
    site = SiteModel(clutter=ClutterSettings(density=0.4, kinds=("site", "people")))
    dressed = dress_scene(scene, site, seed=seed)
    new = added(dressed, scene)
    assert len(new) >= 5
    v = dressed.mesh.vertices[np.unique(dressed.mesh.faces[np.isin(dressed.mesh.face_component, new)])]
    # inside the 8 x 6 m room (not in its 0.25 m walls), on its floor (z = 0), under its 3.5 m ceiling
    assert (v[:, 0] > 0).all() and (v[:, 0] < 8).all() and (v[:, 1] > 0).all() and (v[:, 1] < 6).all()
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-6) and v[:, 2].max() < 3.5


def test_points_inside_walls_are_told_from_points_in_the_room(box_room_ifc):
    from bimscan.pipeline import load_scene
    from bimscan.scan.probe import Prober

    prober = Prober(load_scene(box_room_ifc).mesh)
    points = np.array([[4.0, 6.1, 1.0], [-0.1, 3.0, 1.0], [4.0, -0.2, 0.0], [4.0, 3.0, 1.0], [0.3, 5.7, 1.0]])
    assert prober.inside_solid(points).tolist() == [True, True, True, False, False]


def test_stations_given_in_a_file_keep_their_spots_clear(box_room_ifc, tmp_path):
    from bimscan.pipeline import load_scene, site_and_stations
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.survey import prepare_survey

    stations = tmp_path / "stations.csv"
    stations.write_text("x,y,height\n4,3,1.7\n2,2,1.7\n")
    site = SiteModel(clutter=ClutterSettings(density=0.8, kinds=("site", "office")))
    recipe = ScanRecipe(stations_from=str(stations), site=site, seed=1)
    scene = site_and_stations(load_scene(box_room_ifc), recipe).scene
    new = np.arange(len(scene.components) - sum(scene.site.placed.values()), len(scene.components))
    v = scene.mesh.vertices[np.unique(scene.mesh.faces[np.isin(scene.mesh.face_component, new)])]
    assert len(new) >= 10
    for x, y in ((4, 3), (2, 2)):
        assert np.hypot(v[:, 0] - x, v[:, 1] - y).min() > 0.5  # the tripod's spot and its legs' reach
    assert len(prepare_survey(scene, recipe).stations) == 2  # both stations pass their checks


def test_a_survey_refuses_a_scene_not_dressed_for_its_recipe(office_scene):
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.survey import prepare_survey

    with pytest.raises(ValueError, match="not dressed with this recipe's site model"):
        prepare_survey(office_scene, ScanRecipe(site=SiteModel(clutter=ClutterSettings(density=0.1))))


@pytest.fixture(scope="module")
def suspended_office(tmp_path_factory):
    """A generated office with a suspended ceiling (tiles under a service void) and its lit version."""
    from bimscan.ifc.generate import make_building
    from bimscan.pipeline import load_scene

    built = make_building(tmp_path_factory.mktemp("suspended") / "office.ifc", seed=203, storeys=1, style="office")
    scene = load_scene(built.path, use_cache=False)
    return scene, dress_scene(scene, SiteModel(clutter=ClutterSettings(density=0.1, kinds=("ceiling",))), seed=0)


def test_lay_in_lights_are_set_into_cut_tiles_and_seen_through_them(suspended_office):
    import open3d as o3d

    from bimscan.site.library import TROFFER_RECESS_M

    scene, lit = suspended_office
    n = len(scene.components)
    model = raycasting_scene(lit.mesh.vertices, lit.mesh.faces[lit.mesh.face_component < n])  # the cut model
    original = raycasting_scene(scene.mesh.vertices, scene.mesh.faces)
    coverings = scene.components.ifc_class == "IfcCovering"
    set_in = 0
    for c, (v, f) in component_meshes(lit, fixtures(lit, scene)).items():
        centre = (v.min(axis=0) + v.max(axis=0)) / 2
        ray = np.array([[centre[0], centre[1], v[:, 2].min() - 0.3, 0.0, 0.0, 1.0]], np.float32)
        before = original.cast_rays(o3d.core.Tensor(ray))
        if not coverings[_component_at(scene, before)]:
            continue
        underside = ray[0, 2] + float(before["t_hit"].numpy()[0])
        if v[:, 2].min() < underside - 1e-4:
            continue  # mounted under the tiles, not set into them
        set_in += 1
        inset = v.copy()  # 2 mm inside its outline: it touches the opening's edges, as a trim does
        inset[:, :2] -= 0.002 * np.sign(v[:, :2] - centre[:2])
        assert not edges_cross(inset, f, model), lit.components.name[c]  # the tiles are cut where it sits
        seen = raycasting_scene(lit.mesh.vertices, lit.mesh.faces).cast_rays(o3d.core.Tensor(ray))
        depth = ray[0, 2] + float(seen["t_hit"].numpy()[0]) - underside
        assert TROFFER_RECESS_M[0] - 1e-4 <= depth <= TROFFER_RECESS_M[1] + 1e-4  # its louvre, up in the opening
    assert set_in >= 10


def _component_at(scene, hit) -> int:
    return int(scene.mesh.face_component[int(hit["primitive_ids"].numpy()[0])])

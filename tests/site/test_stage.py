"""Construction stages: what is built at each stage, partial states, work-schedule dates."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from bimscan.errors import ConfigError
from bimscan.site import SiteModel, StageSettings, dress_scene
from bimscan.site.stage import built_components
from bimscan.types import BuildDates


def classes_of(scene) -> Counter:
    return Counter(scene.components.ifc_class.tolist())


def test_structure_keeps_only_slabs_walls_columns_beams_and_stairs(office_scene):
    structure = dress_scene(office_scene, SiteModel(stage=StageSettings(name="structure")), seed=0)
    have, before = classes_of(structure), classes_of(office_scene)
    assert set(have) <= {"IfcSlab", "IfcWall", "IfcColumn", "IfcBeam", "IfcStair", "IfcStairFlight", "IfcMember"}
    for cls in ("IfcSlab", "IfcWall", "IfcColumn", "IfcBeam"):
        assert have[cls] == before[cls] > 0
    for cls in ("IfcCovering", "IfcDoor", "IfcWindow", "IfcFurniture"):
        assert before[cls] > 0 and have[cls] == 0
    assert structure.site.removed == {c: before[c] for c in ("IfcCovering", "IfcDoor", "IfcFurniture", "IfcWindow")}
    # the mesh holds exactly the kept components' triangles, densely renumbered
    assert structure.mesh.face_component.max() == len(structure.components) - 1
    kept = np.isin(office_scene.components.ifc_class, list(have))
    assert structure.mesh.n_triangles == int(kept[office_scene.mesh.face_component].sum())


def test_enclosed_adds_windows_and_doors_but_no_coverings_or_furniture(office_scene):
    enclosed = classes_of(dress_scene(office_scene, SiteModel(stage=StageSettings(name="enclosed")), seed=0))
    before = classes_of(office_scene)
    assert enclosed["IfcDoor"] == before["IfcDoor"] and enclosed["IfcWindow"] == before["IfcWindow"]
    assert enclosed["IfcCovering"] == enclosed["IfcFurniture"] == 0


def test_finished_without_clutter_is_the_model_itself(office_scene):
    assert dress_scene(office_scene, SiteModel(), seed=0) is office_scene


def test_include_and_exclude_lists_choose_classes(office_scene):
    walls_only = dress_scene(office_scene, SiteModel(stage=StageSettings(include=("IfcWall", "IfcSlab"))), seed=0)
    assert set(classes_of(walls_only)) == {"IfcWall", "IfcSlab"}
    no_beams = dress_scene(office_scene, SiteModel(stage=StageSettings(exclude=("IfcBeam",))), seed=0)
    assert classes_of(no_beams)["IfcBeam"] == 0 and classes_of(no_beams)["IfcCovering"] > 0


def test_parts_of_a_stair_follow_the_stair(tmp_path, tiny_model):
    from bimscan.pipeline import load_scene

    model = tiny_model()
    model.add_box("IfcSlab", origin=(0, 0, -0.3), size=(4, 4, 0.3))
    stair = model.api.run("root.create_entity", model.file, ifc_class="IfcStair", name="stair")
    model.api.run("spatial.assign_container", model.file, relating_structure=model.storey, products=[stair])
    flight = model.add_box("IfcStairFlight", origin=(1, 1, 0), size=(1, 3, 1.5), contain=False)
    rail = model.add_box("IfcRailing", origin=(2.1, 1, 0), size=(0.05, 3, 1.0), contain=False)
    model.api.run("aggregate.assign_object", model.file, relating_object=stair, products=[flight, rail])
    scene = load_scene(model.write(tmp_path / "stair.ifc"), use_cache=False)
    kept = built_components(scene, StageSettings(name="structure"), seed=0)
    assert dict(zip(scene.components.ifc_class.tolist(), kept.tolist())) == {
        "IfcSlab": True, "IfcStairFlight": True, "IfcRailing": True}


def test_missing_walls_are_a_seeded_growing_fraction_taking_their_doors_with_them(office_scene):
    walls = int((office_scene.components.ifc_class == "IfcWall").sum())
    gone = {}
    for fraction in (0.3, 0.7):
        stage = StageSettings(name="enclosed", walls_missing_fraction=fraction)
        kept = built_components(office_scene, stage, seed=3)
        gone[fraction] = set(office_scene.components.global_id[~kept].tolist())
        missing_walls = int((~kept & (office_scene.components.ifc_class == "IfcWall")).sum())
        assert 0 < missing_walls < walls
    assert gone[0.3] < gone[0.7]  # a larger fraction removes a superset
    assert built_components(office_scene, StageSettings(walls_missing_fraction=1.0), seed=3)[
        office_scene.components.ifc_class == "IfcDoor"].sum() == 0  # no wall, no door
    again = built_components(office_scene, StageSettings(name="enclosed", walls_missing_fraction=0.3), seed=3)
    assert set(office_scene.components.global_id[~again].tolist()) == gone[0.3]


def _ceiling_area(scene) -> float:
    ceilings = np.flatnonzero(scene.components.predefined_type == "CEILING")
    faces = scene.mesh.faces[np.isin(scene.mesh.face_component, ceilings)]
    v = scene.mesh.vertices[faces]
    return float(np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum() / 2)


def test_open_ceilings_leave_bays_without_panels(office_scene):
    full = _ceiling_area(office_scene)
    half = dress_scene(office_scene, SiteModel(stage=StageSettings(ceilings_open_fraction=0.5)), seed=1)
    none = dress_scene(office_scene, SiteModel(stage=StageSettings(ceilings_open_fraction=1.0)), seed=1)
    assert 0.2 * full < _ceiling_area(half) < 0.8 * full
    assert _ceiling_area(none) == pytest.approx(0.0, abs=1e-9)
    assert len(half.components) == len(office_scene.components)  # the ceilings stay components, with holes


def test_props_stand_under_the_slab_on_a_grid_in_structure(office_scene):
    from bimscan.scan.probe import Prober

    propped = dress_scene(office_scene, SiteModel(stage=StageSettings(name="structure", props_fraction=1.0)), seed=2)
    props = np.flatnonzero(propped.components.ifc_class == "Temporary.Prop")
    assert len(props) > 20 and propped.site.placed == {"Temporary.Prop": len(props)}
    structure = dress_scene(office_scene, SiteModel(stage=StageSettings(name="structure")), seed=2)
    scanner = Prober(structure.mesh)
    for c in props:
        v = propped.mesh.vertices[np.unique(propped.mesh.faces[propped.mesh.face_component == c])]
        t, hit = scanner.cast(v.mean(axis=0), np.array([[0.0, 0.0, 1.0]], np.float32))
        assert structure.components.ifc_class[hit[0]] == "IfcSlab"
        assert v[:, 2].max() == pytest.approx(v.mean(axis=0)[2] + t[0] - 0.005, abs=0.002)  # 5 mm below the soffit


def test_a_date_keeps_what_the_work_schedule_has_built(office_scene):
    walls = np.flatnonzero(office_scene.components.ifc_class == "IfcWall")
    gids = office_scene.components.global_id
    schedule = {gids[walls[0]]: BuildDates(built="2024-03-10"), gids[walls[1]]: BuildDates(built="2024-05-01"),
                gids[walls[2]]: BuildDates(built="2024-01-01", removed="2024-04-01")}

    def standing(at: str) -> set[str]:
        kept = built_components(office_scene, StageSettings(at=at), seed=0, schedule=schedule)
        return {gids[w] for w in walls[:3] if kept[w]}

    assert standing("2024-02-01") == {gids[walls[2]]}
    assert standing("2024-03-10") == {gids[walls[0]], gids[walls[2]]}
    assert standing("2024-04-15") == {gids[walls[0]]}
    assert standing("2024-06-01") == {gids[walls[0]], gids[walls[1]]}
    assert built_components(office_scene, StageSettings(at="2024-06-01"), seed=0, schedule=schedule).sum() == \
        len(office_scene.components) - 1  # only the demolished wall is gone


def test_a_stage_where_nothing_stands_is_refused(office_scene):
    with pytest.raises(ConfigError, match="nothing of the model stands"):
        dress_scene(office_scene, SiteModel(stage=StageSettings(include=("IfcRamp",))), seed=0)


@pytest.mark.parametrize("stage, message", [
    ({"name": "roughcast"}, "^stage name takes 'structure', 'enclosed', 'finished', got 'roughcast'$"),
    ({"walls_missing_fraction": 1.5}, r"^stage walls_missing_fraction must be a number in \[0, 1\], got 1.5$"),
    ({"props_fraction": float("nan")}, r"^stage props_fraction must be a number in \[0, 1\], got nan$"),
    ({"at": "next week"}, "YYYY-MM-DD"),
    ({"include": (3,)}, "not an IFC class"),
])
def test_impossible_stage_settings_are_refused(stage, message):
    with pytest.raises(ConfigError, match=message):
        StageSettings(**stage)


@pytest.mark.parametrize("stage, message", [
    # a typo matched nothing and changed nothing: the doors stayed closed (issue 50)
    ({"exclude": ("IfcDoors",)}, "stage exclude: unknown IFC class 'IfcDoors' (no IfcProduct class of IFC2X3, IFC4 "
                                 "or IFC4X3); did you mean 'IfcDoor'?"),
    ({"include": ("IfcWall", "IfcFoo")}, "stage include: unknown IFC class 'IfcFoo'"),
    ({"include": ("Wall",)}, "did you mean 'IfcWall'?"),
    ({"exclude": ("IfcPropertySet",)}, "'IfcPropertySet' is an IFC class but no product (IfcProduct)"),
    ({"exclude": ("Qwxyzzy",)}, "give classes of elements such as 'IfcWall'"),
])
def test_unknown_ifc_classes_in_a_stage_are_refused_naming_the_nearest(stage, message):
    with pytest.raises(ConfigError) as caught:
        StageSettings(**stage)
    assert message in str(caught.value) and "\n" not in str(caught.value)


def test_stage_classes_are_taken_in_any_case_and_kept_in_the_schemas_spelling():
    stage = StageSettings(include=("ifcwall", "IFCSLAB"), exclude=("ifcdoor", "IfcBuiltElement"))
    assert stage.include == ("IfcWall", "IfcSlab") and stage.exclude == ("IfcDoor", "IfcBuiltElement")
    with pytest.raises(ConfigError, match="does nothing at stage"):  # a covering left out in lower case is seen
        StageSettings(exclude=("ifccovering",), ceilings_open_fraction=0.5)


@pytest.mark.parametrize("angle", [0.0, 0.5])
def test_an_opening_is_cut_through_a_board_and_nothing_else(angle):
    from bimscan.site.shapes import MeshBuilder
    from bimscan.site.stage import cut_openings
    from bimscan.types import SceneMesh

    b = MeshBuilder()
    b.box((0.0, 0.0, 2.7), (4.0, 3.0, 2.72))  # a ceiling board
    b.box((0.0, 0.0, 0.0), (4.0, 3.0, 0.2))  # a slab under it, not to be cut
    vertices, faces = b.build()
    component = np.repeat(np.arange(2, dtype=np.int32), 12)
    styles = np.repeat(np.array([np.nan, 0.5], dtype=np.float32), 12)  # the slab styled, the board not
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=component, face_transparency=styles)
    c, s = np.cos(angle), np.sin(angle)
    local = np.array([[-0.6, -0.3], [0.6, -0.3], [0.6, 0.3], [-0.6, 0.3]])
    hole = np.array([2.0, 1.5]) + local @ np.array([[c, s], [-s, c]])
    cut = cut_openings(mesh, np.array([True, False]), [hole])

    def area(m: SceneMesh, which: int, normal_z: float) -> float:
        tri = m.vertices[m.faces[m.face_component == which]]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) / 2
        return float(n[np.sign(n[:, 2]) == normal_z, 2].sum() * normal_z)

    # each triangle keeps its style: the slab's untouched, the board's pieces none
    assert len(cut.face_transparency) == len(cut.faces)
    assert (cut.face_transparency[cut.face_component == 1] == 0.5).all()
    assert np.isnan(cut.face_transparency[cut.face_component == 0]).all()
    for side in (-1.0, 1.0):  # underside and top: 12 m2 less the 0.72 m2 opening
        assert area(cut, 0, side) == pytest.approx(12.0 - 0.72, abs=1e-9)
        assert area(cut, 1, side) == pytest.approx(12.0)
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(cut.vertices.astype(np.float32)), o3d.core.Tensor(cut.faces.astype(np.uint32)))
    rays = np.array([[2.0, 1.5, 2.5, 0, 0, 1], [0.5, 0.5, 2.5, 0, 0, 1]], dtype=np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    assert np.isinf(t[0]) and t[1] == pytest.approx(0.2, abs=1e-5)  # through the opening; the board beside it
    again = cut_openings(mesh, np.array([True, False]), [hole])
    assert again.vertices.tobytes() == cut.vertices.tobytes() and again.faces.tobytes() == cut.faces.tobytes()


def test_furniture_with_only_a_demolition_task_is_not_there_before_its_storey_is_built(tmp_path, tiny_model):
    from bimscan.ifc.schedule import read_schedule
    from bimscan.pipeline import load_scene

    model = tiny_model()
    run, f = model.api.run, model.file
    model.add_box("IfcSlab", origin=(0, 0, -0.3), size=(6, 6, 0.3), name="floor")
    chair = model.add_box("IfcFurniture", origin=(2, 2, 0), size=(0.5, 0.5, 0.9), name="chair")
    works = run("sequence.add_work_schedule", f, name="works")
    for name, predefined, finish, product in (("ground floor", "CONSTRUCTION", "2024-01-15", model.storey),
                                              ("clear the chairs", "DEMOLITION", "2024-05-01", chair)):
        t = run("sequence.add_task", f, work_schedule=works, name=name, predefined_type=predefined)
        run("sequence.edit_task_time", f, task_time=run("sequence.add_task_time", f, task=t),
            attributes={"ScheduleStart": finish, "ScheduleFinish": finish})
        run("sequence.assign_product", f, relating_product=product, related_object=t)
    path = model.write(tmp_path / "chair.ifc")
    scene, schedule = load_scene(path, use_cache=False), read_schedule(path)
    standing = {at: dict(zip(scene.components.name.tolist(),
                             built_components(scene, StageSettings(at=at), seed=0, schedule=schedule).tolist()))
                for at in ("2024-01-01", "2024-03-01", "2024-06-01")}
    assert standing == {"2024-01-01": {"floor": False, "chair": False},  # no floor yet: no chair floating over it
                        "2024-03-01": {"floor": True, "chair": True},
                        "2024-06-01": {"floor": True, "chair": False}}


def test_a_generated_buildings_schedule_raises_it_task_by_task_until_all_of_it_stands(office_scene, tmp_path):
    from bimscan.ifc.generate import make_building
    from bimscan.ifc.schedule import read_schedule

    # the office of the scene, with a work schedule: the same elements under the same GlobalIds
    building = make_building(tmp_path / "office.ifc", seed=1, storeys=1, schedule_start="2024-03-04")
    schedule = read_schedule(building.path)
    gids, classes = office_scene.components.global_id.tolist(), office_scene.components.ifc_class
    assert all(schedule[g].built is not None for g in gids)

    def standing(at: str) -> np.ndarray:
        return built_components(office_scene, StageSettings(at=at), seed=0, schedule=schedule)

    finishes = sorted({task.finish for task in building.works})
    counts = [int(standing(day).sum()) for day in ["2024-03-01", *finishes]]
    assert counts[0] == 0 and counts[-1] == len(gids)
    assert all(a < b for a, b in zip(counts, counts[1:]))  # every finish adds what its task built
    assert set(classes[standing(finishes[0])].tolist()) == {"IfcSlab", "IfcColumn", "IfcBeam"}  # the structure
    assert standing("2030-01-01").all()

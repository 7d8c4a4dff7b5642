"""Loading IFC (load_ifc, labelled by load_scene) on generated buildings of every style: what the
plan places is what the loader finds, with the class and label the plan says."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from bimscan.ifc.generate import make_building
from bimscan.ifc.generate.floor_plan import BuildingPlan, plan_building, planned_elements, storey_name
from bimscan.ifc.generate.styles import STYLES
from bimscan.pipeline import load_scene
from bimscan.types import BimScene


def first_seed(style: str, storeys: int, wanted) -> int:
    return next(seed for seed in range(200) if wanted(plan_building(seed=seed, storeys=storeys, style=style)))


@pytest.mark.parametrize(
    "style, seed, storeys",
    [("office", 0, 2), ("office", 1, 2), ("office", 5, 1), ("residential", 1, 2), ("residential", 3, 1), ("site", 2, 1),
     ("site", 7, 1)],  # office 1 at 2 storeys: a double-height hall
)
def test_generated_buildings_load_with_the_planned_elements_labels_bounds_and_rooms(style, seed, storeys, tmp_path):
    building = make_building(tmp_path / "b.ifc", seed=seed, storeys=storeys, style=style)
    scene = load_scene(building.path, strict=True)  # the generator writes files nothing needs repairing in
    assert scene.failed == () and scene.report.clean
    assert scene.report.declared_elements == len(scene.components)
    names = scene.scheme.names
    table = scene.components
    found = Counter(
        (str(s), str(n), str(c), str(p), names[int(label)])
        for s, n, c, p, label in zip(table.storey, table.name, table.ifc_class, table.predefined_type, table.label)
    )
    planned = Counter(
        (storey_name(e.storey), e.name, e.ifc_class, e.predefined_type, e.label) for e in planned_elements(building.plan)
    )
    assert found == planned
    assert dict(Counter(table.ifc_class.tolist())) == dict(building.placed)
    lo, hi = scene.mesh.bounds()
    xmin, ymin, xmax, ymax = building.footprint_m
    np.testing.assert_allclose([lo[0], lo[1], hi[0], hi[1]], [xmin, ymin, xmax, ymax], atol=0.03)
    assert hi[2] == pytest.approx(building.height_m, abs=0.01)
    assert lo[2] == pytest.approx(-building.plan.slab_m, abs=0.01)
    per_storey = [[s for s in scene.spaces if s.storey == st.name] for st in scene.storeys]
    assert [len(rooms) for rooms in per_storey] == list(building.rooms_per_storey)
    for storey, rooms in zip(building.plan.storeys, per_storey):
        boxes = sorted(tuple(np.round(np.r_[s.vertices.min(0)[:2], s.vertices.max(0)[:2]], 3)) for s in rooms)
        planned_boxes = sorted((r.rect.x0, r.rect.y0, r.rect.x1, r.rect.y1) for r in storey.rooms)
        np.testing.assert_allclose(boxes, planned_boxes, atol=1e-3)


def up_from(scene: BimScene, points: np.ndarray, direction=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Distance and IFC class of the first surface straight above each point (or along
    ``direction``; Open3D BVH)."""
    import open3d as o3d

    raycaster = o3d.t.geometry.RaycastingScene()
    raycaster.add_triangles(
        o3d.core.Tensor(scene.mesh.vertices.astype(np.float32)), o3d.core.Tensor(scene.mesh.faces.astype(np.uint32))
    )
    rays = np.hstack([points, np.tile(direction, (len(points), 1))]).astype(np.float32)
    hit = raycaster.cast_rays(o3d.core.Tensor(rays))
    t, face = hit["t_hit"].numpy(), hit["primitive_ids"].numpy()
    assert np.isfinite(t).all()
    return t, scene.components.ifc_class[scene.mesh.face_component[face]]


def over_no_wall(plan: BuildingPlan) -> list:
    walls = [w.footprint for w in plan.storeys[0].walls]
    return [b for b in plan.beams if not any(w.x0 <= b.rect.centre[0] <= w.x1 and w.y0 <= b.rect.centre[1] <= w.y1
                                             for w in walls)]


def looking_up(plan: BuildingPlan, scene: BimScene, start_m: float = 2.12) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """What a point ``start_m`` above the ground floor (above doors and furniture) sees straight up,
    under the middle of every beam and of every room's largest ceiling piece (or its centre)."""
    ground = plan.storeys[0]
    # Beams over a wall's top are skipped: the point would stand inside the wall.
    beams = np.array([[*b.rect.centre, start_m] for b in over_no_wall(plan)]).reshape(-1, 3)
    rooms = []
    for room in ground.rooms:
        if room.kind == "stairwell":
            continue
        ceiling = next((c for c in ground.ceilings if c.room == room.number), None)
        spot = max(ceiling.rects, key=lambda r: r.area).centre if ceiling else room.rect.centre
        if not any(c.x0 <= spot[0] <= c.x1 and c.y0 <= spot[1] <= c.y1 for c in plan.columns):
            rooms.append([*spot, start_m])
    return {"beams": up_from(scene, beams) if len(beams) else (np.zeros(0), np.zeros(0)),
            "rooms": up_from(scene, np.array(rooms))}


def test_in_an_office_with_downstand_beams_the_beams_are_seen_below_the_ceiling_coverings(tmp_path) -> None:
    seed = first_seed("office", 1, lambda p: p.ceiling_system == "downstand")
    building = make_building(tmp_path / "b.ifc", seed=seed, storeys=1)
    plan, scene = building.plan, load_scene(tmp_path / "b.ifc")
    seen = looking_up(plan, scene)
    t, classes = seen["beams"]
    assert set(classes) == {"IfcBeam"}
    np.testing.assert_allclose(t, plan.beam_bottom_m - 2.12, atol=1e-3)
    assert len(t) >= len(plan.beams) / 2
    t, classes = seen["rooms"]
    covered = [r for r in plan.storeys[0].rooms if r.has_ceiling and r.kind != "stairwell"]
    assert Counter(classes)["IfcCovering"] == len(covered)
    assert np.allclose(t[classes == "IfcCovering"], plan.ceiling_height_m - 2.12, atol=1e-3)
    assert plan.beam_bottom_m < plan.ceiling_height_m - 0.25


def test_a_suspended_ceiling_hides_the_beams_and_an_exposed_soffit_is_the_slab(tmp_path) -> None:
    hidden = first_seed("office", 1, lambda p: p.ceiling_system == "suspended")
    building = make_building(tmp_path / "hidden.ifc", seed=hidden, storeys=1)
    plan = building.plan
    t, classes = looking_up(plan, load_scene(building.path))["beams"]
    covered = [r.rect for r in plan.storeys[0].rooms if r.has_ceiling]
    beams = over_no_wall(plan)
    under_ceiling = np.array([any(r.x0 < b.rect.centre[0] < r.x1 and r.y0 < b.rect.centre[1] < r.y1 for r in covered)
                              for b in beams])
    assert under_ceiling.sum() >= len(beams) / 2
    assert set(classes[under_ceiling]) == {"IfcCovering"}  # the tiles hide every beam above them
    assert t[under_ceiling] == pytest.approx(plan.ceiling_height_m - 2.12, abs=1e-3)
    assert set(classes[~under_ceiling]) <= {"IfcBeam"}
    bare = first_seed("office", 1, lambda p: p.ceiling_system == "exposed")
    building = make_building(tmp_path / "bare.ifc", seed=bare, storeys=1)
    t, classes = looking_up(building.plan, load_scene(building.path))["rooms"]
    assert set(classes) <= {"IfcSlab", "IfcBeam"} and "IfcSlab" in set(classes)
    assert t[classes == "IfcSlab"] == pytest.approx(building.plan.soffit_m - 2.12, abs=1e-3)


def test_a_rectangular_home_gets_an_attic_under_a_gable_roof_that_rises_at_its_pitch(tmp_path) -> None:
    seed = first_seed("residential", 1, lambda p: p.roof is not None)
    building = make_building(tmp_path / "house.ifc", seed=seed, storeys=1, style="residential")
    plan, roof, scene = building.plan, building.plan.roof, load_scene(tmp_path / "house.ifc")
    low, high = STYLES["residential"].roof_pitch_deg
    assert plan.shape == "rectangle" and low <= roof.pitch_deg <= high
    assert [s.name for s in scene.spaces if s.storey == storey_name(1)] == ["Attic Room"]
    # Straight up from the attic floor, across the depth: the roof's underside, on the pitch.
    x = plan.width_m / 2
    ys = np.linspace(plan.exterior_wall_m + 0.2, plan.depth_m - plan.exterior_wall_m - 0.2, 9)
    start = plan.roof_base_m + 0.05
    t, classes = up_from(scene, np.array([[x, y, start] for y in ys]))
    assert set(classes) == {"IfcSlab"}
    from_facade = np.minimum(ys, plan.depth_m - ys)
    expected = roof.knee_m + from_facade * np.tan(np.radians(roof.pitch_deg)) - 0.05
    np.testing.assert_allclose(t, expected, atol=1e-3)
    # Along the ridge, under it, the gable walls close both ends.
    middle = np.array([[x, plan.depth_m / 2, plan.roof_base_m + roof.ridge_m(plan.depth_m) - 0.1]])
    for sign in (-1.0, 1.0):
        t, hit = up_from(scene, middle, direction=(sign, 0.0, 0.0))
        assert hit.tolist() == ["IfcWall"] and t[0] == pytest.approx(x - plan.exterior_wall_m, abs=1e-3)
    assert scene.mesh.bounds()[1][2] == pytest.approx(building.height_m, abs=1e-3)


def test_only_rectangular_homes_get_gable_roofs() -> None:
    plans = [plan_building(seed=seed, storeys=1, style=style) for style in STYLES for seed in range(30)]
    gabled = [p for p in plans if p.roof is not None]
    assert gabled and all(p.style == "residential" and p.shape == "rectangle" for p in gabled)
    homes = [p for p in plans if p.style == "residential" and p.shape == "rectangle"]
    assert len(gabled) < len(homes)  # the style's odds leave some flat


def test_a_double_height_hall_rises_through_the_storey_above_to_the_slab_over_it(tmp_path) -> None:
    seed = first_seed("office", 2, lambda p: p.hall is not None)
    building = make_building(tmp_path / "hall.ifc", seed=seed, storeys=2)
    plan, scene = building.plan, load_scene(building.path, strict=True)
    hall = plan.hall.rect
    assert scene.failed == () and scene.report.clean
    space = next(s for s in scene.spaces if s.storey == storey_name(0) and np.allclose(
        np.r_[s.vertices.min(0)[:2], s.vertices.max(0)[:2]], [hall.x0, hall.y0, hall.x1, hall.y1], atol=1e-3))
    assert np.ptp(space.vertices[:, 2]) == pytest.approx(plan.storey_height_m + plan.soffit_m, abs=1e-3)
    # Straight up from the hall, above doors and furniture, clear of columns: past the upper
    # storey's floor (cut open) to the roof slab or the beams under it; never a covering.
    spots = [(x, hall.centre[1], 2.12) for x in np.linspace(hall.x0 + 0.3, hall.x1 - 0.3, 9)
             if not any(c.x0 - 0.05 <= x <= c.x1 + 0.05 for c in plan.columns)]
    t, classes = up_from(scene, np.array(spots))
    assert set(classes) <= {"IfcSlab", "IfcBeam"} and "IfcSlab" in set(classes)
    top = plan.storey_height_m + plan.soffit_m - 2.12
    np.testing.assert_allclose(t[classes == "IfcSlab"], top, atol=1e-3)
    np.testing.assert_allclose(t[classes == "IfcBeam"], top - plan.beam_depth_m, atol=1e-3)

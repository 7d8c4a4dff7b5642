"""plan_building: the layout rules of generated buildings, over many seeds and every style (no IFC involved)."""

from __future__ import annotations

from collections import Counter, deque

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from bimscan.ifc.generate.floor_plan import (
    BuildingPlan,
    Rect,
    StoreyPlan,
    WallPlan,
    plan_building,
    planned_elements,
    subtract_rects,
)
from bimscan.ifc.generate.styles import DOOR_HEIGHT_M, MAX_SPAN_M, ROOM_M, STYLES, WALL_ABOVE_OPENING_M

seeds = st.integers(min_value=0, max_value=2**32)
storey_counts = st.integers(min_value=1, max_value=4)
styles = st.sampled_from(sorted(STYLES))
EPS = 1e-6  # plans hold millimetre-rounded numbers


def door_centres(wall: WallPlan) -> list[tuple[float, float]]:
    (x0, y0), (x1, y1) = wall.start, wall.end
    ux, uy = (x1 - x0) / wall.length_m, (y1 - y0) / wall.length_m
    return [
        (x0 + ux * (o.offset_m + o.width_m / 2), y0 + uy * (o.offset_m + o.width_m / 2))
        for o in wall.openings
        if o.kind == "door"
    ]


def rooms_beside(storey: StoreyPlan, point: tuple[float, float], reach: float) -> list[int]:
    x, y = point
    probe = Rect(x - reach, y - reach, x + reach, y + reach)
    return [i for i, room in enumerate(storey.rooms) if room.rect.overlaps(probe)]


def inside_outline(plan: BuildingPlan, x: float, y: float) -> bool:
    """Even-odd rule on the outline polygon."""
    inside = False
    points = plan.outline_m
    for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1]):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


def test_same_seed_and_style_give_the_same_plan() -> None:
    for style in STYLES:
        assert plan_building(seed=9, storeys=3, style=style) == plan_building(seed=9, storeys=3, style=style)


def test_office_is_the_default_style_and_styles_give_different_buildings() -> None:
    assert plan_building(seed=4, storeys=2) == plan_building(seed=4, storeys=2, style="office")
    plans = [plan_building(seed=4, storeys=2, style=style) for style in STYLES]
    assert len({(p.width_m, p.depth_m, p.storey_height_m) for p in plans}) == len(plans)


def test_lower_storeys_do_not_change_when_storeys_are_added() -> None:
    for style in STYLES:
        two, three = plan_building(seed=5, storeys=2, style=style), plan_building(seed=5, storeys=3, style=style)
        assert two.storeys == three.storeys[:2]


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_every_room_is_reachable_from_the_corridor_through_doors(seed: int, storeys: int, style: str) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    for storey in plan.storeys:
        links: dict[int, set[int]] = {i: set() for i in range(len(storey.rooms))}
        for wall in storey.walls:
            for point in door_centres(wall):
                beside = rooms_beside(storey, point, wall.thickness_m / 2 + 0.05)
                for a in beside:
                    links[a] |= set(beside) - {a}
        corridor = next(i for i, r in enumerate(storey.rooms) if r.kind == "corridor")
        seen, todo = {corridor}, deque([corridor])
        while todo:
            for j in links[todo.popleft()] - seen:
                seen.add(j)
                todo.append(j)
        assert seen == set(links), f"unreachable rooms {sorted(set(links) - seen)} on storey {storey.index}"
    entrance = [o for w in plan.storeys[0].walls if w.exterior for o in w.openings if o.kind == "door"]
    assert len(entrance) == 1


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_rooms_lie_inside_the_outline_without_overlapping_and_offices_are_2_5_to_8_m(
    seed: int, storeys: int, style: str
) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    xs, ys = [p[0] for p in plan.outline_m], [p[1] for p in plan.outline_m]
    assert (min(xs), min(ys), max(xs), max(ys)) == (0.0, 0.0, plan.width_m, plan.depth_m)
    for storey in plan.storeys:
        rects = [r.rect for r in storey.rooms]
        for r in rects:
            assert all(inside_outline(plan, x, y) for x in (r.x0 + EPS, r.x1 - EPS) for y in (r.y0 + EPS, r.y1 - EPS))
        assert not any(a.overlaps(b, margin_m=-EPS) for i, a in enumerate(rects) for b in rects[i + 1 :])
        for room in storey.rooms:
            if room.kind in ("office", "room"):
                assert ROOM_M[0] - EPS <= room.rect.width <= ROOM_M[1] + EPS, room
                assert ROOM_M[0] - EPS <= room.rect.depth <= ROOM_M[1] + EPS, room
        corridor = next(r for r in storey.rooms if r.kind == "corridor")
        low, high = STYLES[style].corridor_m
        assert low - EPS <= corridor.rect.depth <= high + EPS
        assert corridor.rect.width == pytest.approx(plan.width_m - 2 * plan.exterior_wall_m)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_exterior_walls_follow_the_outline_and_rooms_touch_no_outline_edge_without_a_wall(
    seed: int, storeys: int, style: str
) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    points = plan.outline_m
    edges = list(zip(points, points[1:] + points[:1]))
    assert all(a[0] == b[0] or a[1] == b[1] for a, b in edges)  # rectilinear
    area = sum(a[0] * b[1] - b[0] * a[1] for a, b in edges) / 2
    assert area > 0  # counter-clockwise
    exterior = [w for w in plan.storeys[0].walls if w.exterior]
    assert len(exterior) == len(edges)
    e = plan.exterior_wall_m
    for (x0, y0), (x1, y1) in edges:
        mid = ((x0 + x1) / 2, (y0 + y1) / 2)
        # Half a wall thickness inside the edge's midpoint lies in some exterior wall.
        dx, dy = (x1 - x0, y1 - y0)
        length = (dx * dx + dy * dy) ** 0.5
        probe = (mid[0] - dy / length * e / 2, mid[1] + dx / length * e / 2)
        assert any(
            w.footprint.x0 - EPS <= probe[0] <= w.footprint.x1 + EPS
            and w.footprint.y0 - EPS <= probe[1] <= w.footprint.y1 + EPS
            for w in exterior
        )
    if plan.shape != "rectangle":
        assert len(points) > 4


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
@example(seed=24883, storeys=4, style="office")  # a room whose corridor frontage a column nearly fills
def test_openings_fit_their_walls_below_lintels_and_keep_clear_of_columns_beams_and_each_other(
    seed: int, storeys: int, style: str
) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    structure = [*plan.columns, *(b.rect for b in plan.beams)]
    for storey in plan.storeys:
        for wall in storey.walls:
            spans = sorted((o.offset_m, o.offset_m + o.width_m) for o in wall.openings)
            assert all(0.0 <= a and b <= wall.length_m + EPS for a, b in spans)
            assert all(b0 <= a1 for (_, b0), (a1, _) in zip(spans, spans[1:])), wall.name
            for o in wall.openings:
                assert o.sill_m + o.height_m <= wall.height_m - 0.05, (wall.name, o.name)
                if o.kind == "window":
                    assert o.sill_m + o.height_m <= plan.ceiling_height_m - WALL_ABOVE_OPENING_M + EPS
            (x0, y0), (x1, y1) = wall.start, wall.end
            ux, uy = (x1 - x0) / wall.length_m, (y1 - y0) / wall.length_m
            t = wall.thickness_m / 2
            for (a, b), o in zip(spans, sorted(wall.openings, key=lambda o: o.offset_m)):
                ends = [(x0 + ux * s, y0 + uy * s) for s in (a, b)]
                footprint = Rect(
                    min(p[0] for p in ends) - t * abs(uy),
                    min(p[1] for p in ends) - t * abs(ux),
                    max(p[0] for p in ends) + t * abs(uy),
                    max(p[1] for p in ends) + t * abs(ux),
                )
                assert not any(footprint.overlaps(c) for c in plan.columns), f"{o.name} in {wall.name} hits a column"
                if o.kind == "window":
                    assert not any(footprint.overlaps(s, margin_m=0.05) for s in structure), o.name


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_furniture_stands_in_rooms_clear_of_columns_and_room_centres(seed: int, storeys: int, style: str) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    for storey in plan.storeys:
        for piece in storey.furniture:
            room = next(r for r in storey.rooms if r.rect.contains(piece.rect))
            cx, cy = room.rect.centre
            assert room.kind in ("office", "room", "store", "open-plan")
            assert not piece.rect.overlaps(Rect(cx - 0.5, cy - 0.5, cx + 0.5, cy + 0.5))
            assert not any(piece.rect.overlaps(c) for c in plan.columns)
        rects = [p.rect for p in storey.furniture]
        assert not any(a.overlaps(b) for i, a in enumerate(rects) for b in rects[i + 1 :])
    if not STYLES[style].furniture:
        assert all(not s.furniture for s in plan.storeys)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=st.integers(min_value=2, max_value=4), style=styles)
def test_stair_void_is_clear_of_columns_and_beams(seed: int, storeys: int, style: str) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    stair = plan.stair
    assert stair is not None
    void = stair.opening
    # Touching is fine (the void ends at the column faces); float noise is not an overlap.
    assert not any(void.overlaps(c, margin_m=-EPS) for c in plan.column_rects())
    assert not any(void.overlaps(b, margin_m=-EPS) for b in plan.beam_rects())
    assert 0.15 <= stair.riser_m <= 0.19
    assert 2 * stair.risers_per_flight * stair.riser_m == pytest.approx(plan.storey_height_m)
    well = next(r for r in plan.storeys[0].rooms if r.kind == "stairwell").rect
    assert well.contains(void)
    assert (void.y0, void.y1) == pytest.approx((well.y0, well.y1))  # flights fill the well wall to wall


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_storey_and_ceiling_heights_lie_in_the_style_ranges_and_beams_keep_headroom(
    seed: int, storeys: int, style: str
) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    table = STYLES[style]
    assert table.storey_height_m[0] - EPS <= plan.storey_height_m <= table.storey_height_m[1] + EPS
    assert table.ceiling_height_m[0] - EPS <= plan.ceiling_height_m <= table.ceiling_height_m[1] + EPS
    assert plan.ceiling_height_m <= plan.soffit_m
    if plan.beams:
        assert table.min_beam_bottom_m - EPS <= plan.beam_bottom_m < plan.soffit_m
        assert plan.beam_bottom_m > DOOR_HEIGHT_M
    else:
        assert plan.beam_bottom_m == plan.soffit_m
    for storey in plan.storeys:
        for room in storey.rooms:
            if room.kind == "hall":  # through the storey above, to the slab over it
                assert not room.has_ceiling and storey.index < len(plan.storeys) - 1
                assert room.height_m == pytest.approx(plan.storey_height_m + plan.soffit_m)
            else:
                assert room.height_m == (plan.ceiling_height_m if room.has_ceiling else plan.soffit_m)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_ceilings_fill_between_visible_beams_and_around_columns_inside_their_rooms(
    seed: int, storeys: int, style: str
) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    visible = plan.beam_bottom_m < plan.ceiling_height_m
    for storey in plan.storeys:
        rooms = {r.number: r for r in storey.rooms}
        assert {c.room for c in storey.ceilings} == {r.number for r in storey.rooms if r.has_ceiling}
        for ceiling in storey.ceilings:
            room = rooms[ceiling.room]
            assert ceiling.bottom_m == plan.ceiling_height_m
            assert ceiling.bottom_m + ceiling.thickness_m <= plan.soffit_m + EPS
            area = sum(r.area for r in ceiling.rects)
            holes = [*plan.columns, *(b.rect for b in plan.beams if visible)]
            expected = room.rect.area - sum((room.rect.intersection(h) or Rect(0, 0, 0, 0)).area for h in holes)
            assert area == pytest.approx(expected, abs=0.01)  # holes never overlap each other
            for r in ceiling.rects:
                assert room.rect.contains(Rect(r.x0 + EPS, r.y0 + EPS, r.x1 - EPS, r.y1 - EPS))
                assert not any(r.overlaps(h, margin_m=-EPS) for h in holes)


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts, style=styles)
def test_beams_span_between_supports_and_walls_stop_under_beams_they_run_along(
    seed: int, storeys: int, style: str
) -> None:
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    walls = plan.storeys[0].walls
    bays = [b - a for a, b in zip(plan.grid_x_m, plan.grid_x_m[1:])]
    for beam in plan.beams:
        r = beam.rect
        # Across the building a span is at most MAX_SPAN_M; along it, one bay between column faces.
        longest = MAX_SPAN_M if beam.along == "y" else max(bays) - plan.column_m
        assert 0.05 <= beam.length_m <= longest + EPS
        ends = ((r.y0, r.y1) if beam.along == "y" else (r.x0, r.x1))
        for end, sign in zip(ends, (-1, 1)):
            # Just beyond each end stands a column, a wall, or a beam along the other axis.
            if beam.along == "y":
                probe = Rect(r.x0, end + sign * 0.01 - 0.001, r.x1, end + sign * 0.01 + 0.001)
            else:
                probe = Rect(end + sign * 0.01 - 0.001, r.y0, end + sign * 0.01 + 0.001, r.y1)
            supports = [*plan.columns, *(w.footprint for w in walls), *(b.rect for b in plan.beams if b is not beam)]
            assert any(s.overlaps(probe) for s in supports), (beam, end)
    for wall in walls:
        for beam in plan.beams:
            shared = beam.rect.intersection(wall.footprint)
            if shared is None or shared.area < 1e-4:
                continue
            if wall.height_m > plan.beam_bottom_m + EPS:  # only a wall's end may reach under a beam
                along = shared.width if wall.along_x else shared.depth
                assert along <= plan.beam_width_m / 2 + EPS, (wall.name, beam)


def test_over_many_seeds_offices_mostly_show_downstand_beams_under_coverings_and_vary_their_outline() -> None:
    plans = [plan_building(seed=seed, storeys=1, style="office") for seed in range(150)]
    systems = Counter(p.ceiling_system for p in plans)
    shapes = Counter(p.shape for p in plans)
    assert systems["downstand"] / len(plans) >= 0.55  # the table's weight is 0.7
    assert 0 < systems["suspended"] < systems["downstand"] and 0 < systems["exposed"] < systems["downstand"]
    assert set(shapes) == {"rectangle", "L", "U", "T", "notch"} and shapes["rectangle"] < len(plans) / 2
    for p in plans:
        assert p.beams and p.columns
        if p.ceiling_system == "downstand":
            assert p.beam_bottom_m < p.ceiling_height_m  # beams in view, coverings between them
            covered = sum(len(s.ceilings) for s in p.storeys)
            rooms = sum(len([r for r in s.rooms if r.kind != "stairwell"]) for s in p.storeys)
            assert covered >= 0.7 * rooms
        if p.ceiling_system == "suspended":
            assert p.ceiling_height_m + p.ceiling_thickness_m < p.beam_bottom_m  # hidden above the tiles
        if p.ceiling_system == "exposed":
            assert all(not s.ceilings for s in p.storeys)
    kinds = Counter(r.kind for p in plans for s in p.storeys for r in s.rooms)
    assert kinds["office"] > kinds["open-plan"] > 0
    windows = Counter(p.window_style for p in plans)
    assert windows["band"] > 0 and windows["punched"] > 0
    settings_ = Counter(p.column_setting for p in plans)
    assert set(settings_) == {"against", "embedded", "setback"}


def test_over_many_seeds_residential_has_no_structure_grid_and_site_no_finishes() -> None:
    for seed in range(60):
        home = plan_building(seed=seed, storeys=1, style="residential")
        assert not home.columns and not home.beams
        assert home.storey_height_m <= 3.0 and home.ceiling_system in ("downstand", "exposed")
        frame = plan_building(seed=seed, storeys=2 if seed % 4 == 0 else 1, style="site")
        assert frame.ceiling_system == "exposed" and frame.columns and frame.beams
        assert all(not s.ceilings and not s.furniture for s in frame.storeys)
        assert any(b.along == "x" for b in frame.beams)
    homes = [plan_building(seed=seed, storeys=1, style="residential") for seed in range(60)]
    offices = [plan_building(seed=seed, storeys=1, style="office") for seed in range(60)]

    def mean_room(plans: list[BuildingPlan], kind: str) -> float:
        areas = [r.rect.area for p in plans for s in p.storeys for r in s.rooms if r.kind == kind]
        return sum(areas) / len(areas)

    assert mean_room(homes, "room") < mean_room(offices, "office")


def test_planned_elements_name_every_element_once_per_storey_with_its_label() -> None:
    for style in STYLES:
        plan = plan_building(seed=3, storeys=3, style=style)
        elements = planned_elements(plan)
        keys = [(e.storey, e.name) for e in elements]
        assert len(keys) == len(set(keys))
        labels = {(e.ifc_class, e.label) for e in elements}
        assert ("IfcWall", "Wall&Column") in labels and ("IfcSlab", "Slab") in labels
        assert all(label == "Others" for cls, label in labels if cls in ("IfcDoor", "IfcWindow", "IfcFurniture"))
        counts = Counter(e.ifc_class for e in elements)
        assert counts["IfcColumn"] == sum(len(plan.storey_columns(k)) for k in range(3))
        assert counts["IfcBeam"] == sum(len(plan.storey_beams(k)) for k in range(3))
        if plan.hall is None:
            assert counts["IfcColumn"] == 3 * len(plan.columns) and counts["IfcBeam"] == 3 * len(plan.beams)
        assert counts["IfcCovering"] == sum(len(s.ceilings) for s in plan.storeys)


def test_a_double_height_hall_is_one_room_through_two_storeys_with_nothing_over_it() -> None:
    plans = [plan_building(seed=seed, storeys=storeys, style=style)
             for style in STYLES for seed in range(16) for storeys in (2, 3)]
    halls = [p for p in plans if p.hall is not None]
    assert {p.style for p in halls} >= {"office", "residential"}
    assert not any(p.hall for p in plans if len(p.storeys) == 1)
    for plan in halls:
        hall, inside = plan.hall, (lambda r: r.overlaps(plan.hall.rect, margin_m=-0.01))
        assert 0 <= hall.storey < len(plan.storeys) - 1 and hall.rect.area >= 20.0
        below, above = plan.storeys[hall.storey], plan.storeys[hall.storey + 1]
        (room,) = [r for r in below.rooms if inside(r.rect)]
        assert (room.kind, room.rect, room.has_ceiling) == ("hall", hall.rect, False)
        assert room.height_m == pytest.approx(plan.storey_height_m + plan.soffit_m)
        assert not any(inside(r.rect) for r in above.rooms) and not any(inside(f.rect) for f in above.furniture)
        assert not any(inside(r) for c in [*below.ceilings, *above.ceilings] for r in c.rects)
        assert not any(inside(b.rect) for _, b in plan.storey_beams(hall.storey))
        assert len(plan.storey_beams(hall.storey + 1)) == len(plan.beams)
        assert not any(inside(c) for _, c, _ in plan.storey_columns(hall.storey + 1))
        for _, column, height in plan.storey_columns(hall.storey):
            assert height == pytest.approx(plan.storey_height_m + plan.soffit_m if inside(column) else plan.soffit_m)
        # the storey above keeps the hall's facade windows: its upper row
        assert _windows_along(above, hall.rect) == _windows_along(below, hall.rect) > 0


def _windows_along(storey: StoreyPlan, rect: Rect) -> int:
    """Windows in the storey's facades whose near edge lies along ``rect``."""
    count = 0
    for wall in storey.walls:
        if wall.exterior and wall.footprint.overlaps(rect, margin_m=0.5):
            for o in wall.openings:
                at = (wall.start[0] if wall.along_x else wall.start[1]) + o.offset_m
                lo, hi = (rect.x0, rect.x1) if wall.along_x else (rect.y0, rect.y1)
                count += o.kind == "window" and lo - 0.01 <= at <= hi
    return count


def test_subtracting_rectangles_leaves_the_area_outside_the_holes() -> None:
    room = Rect(0.0, 0.0, 4.0, 3.0)
    holes = [Rect(1.0, -1.0, 1.3, 4.0), Rect(3.8, 2.8, 4.2, 3.2)]  # a beam across, a column in a corner
    pieces = subtract_rects(room, holes)
    assert sum(p.area for p in pieces) == pytest.approx(12.0 - 0.9 - 0.04)
    assert not any(p.overlaps(h) for p in pieces for h in holes)
    assert not any(a.overlaps(b) for i, a in enumerate(pieces) for b in pieces[i + 1 :])
    assert subtract_rects(room, []) == [room]


def test_one_storey_plan_has_no_stair() -> None:
    for style in STYLES:
        plan = plan_building(seed=0, storeys=1, style=style)
        assert plan.stair is None
        assert not any(r.kind in ("stairwell", "store") for r in plan.storeys[0].rooms)

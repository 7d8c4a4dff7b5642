"""plan_building: the layout rules of demo buildings, over many seeds (no IFC involved)."""

from __future__ import annotations

from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bimscan.ifc.generate.layout import (
    EXTERIOR_WALL_M,
    BuildingPlan,
    Rect,
    StoreyPlan,
    WallPlan,
    plan_building,
)

seeds = st.integers(min_value=0, max_value=2**32)
storey_counts = st.integers(min_value=1, max_value=4)


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


def test_same_seed_gives_the_same_plan() -> None:
    assert plan_building(seed=9, storeys=3) == plan_building(seed=9, storeys=3)


def test_lower_storeys_do_not_change_when_storeys_are_added() -> None:
    two, three = plan_building(seed=5, storeys=2), plan_building(seed=5, storeys=3)
    assert two.storeys == three.storeys[:2]


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts)
def test_every_room_is_reachable_from_the_corridor_through_doors(seed: int, storeys: int) -> None:
    plan = plan_building(seed=seed, storeys=storeys)
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
@given(seed=seeds, storeys=storey_counts)
def test_rooms_lie_inside_the_walls_without_overlapping(seed: int, storeys: int) -> None:
    plan = plan_building(seed=seed, storeys=storeys)
    e = EXTERIOR_WALL_M - 1e-6  # plans hold millimetre-rounded numbers
    inside = Rect(e, e, plan.width_m - e, plan.depth_m - e)
    assert 12.0 <= plan.width_m <= 30.0 and 8.0 <= plan.depth_m <= 20.0
    for storey in plan.storeys:
        rects = [r.rect for r in storey.rooms]
        assert all(inside.contains(r) for r in rects)
        assert not any(a.overlaps(b, margin_m=-1e-6) for i, a in enumerate(rects) for b in rects[i + 1 :])
        assert 4 <= len(rects) <= 12


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts)
def test_openings_fit_their_walls_and_keep_clear_of_columns_and_each_other(seed: int, storeys: int) -> None:
    plan = plan_building(seed=seed, storeys=storeys)
    columns = plan.column_rects()
    for storey in plan.storeys:
        for wall in storey.walls:
            spans = sorted((o.offset_m, o.offset_m + o.width_m) for o in wall.openings)
            assert all(0.0 <= a and b <= wall.length_m for a, b in spans)
            assert all(b0 <= a1 for (_, b0), (a1, _) in zip(spans, spans[1:])), wall.name
            for o in wall.openings:
                assert o.sill_m + o.height_m < plan.clear_height_m - 0.3
            (x0, y0), (x1, y1) = wall.start, wall.end
            ux, uy = (x1 - x0) / wall.length_m, (y1 - y0) / wall.length_m
            t = wall.thickness_m / 2
            for a, b in spans:
                ends = [(x0 + ux * s, y0 + uy * s) for s in (a, b)]
                footprint = Rect(
                    min(p[0] for p in ends) - t * abs(uy),
                    min(p[1] for p in ends) - t * abs(ux),
                    max(p[0] for p in ends) + t * abs(uy),
                    max(p[1] for p in ends) + t * abs(ux),
                )
                assert not any(footprint.overlaps(c) for c in columns), f"an opening in {wall.name} hits a column"


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=storey_counts)
def test_furniture_stands_in_rooms_clear_of_columns_and_room_centres(seed: int, storeys: int) -> None:
    plan = plan_building(seed=seed, storeys=storeys)
    columns = plan.column_rects()
    for storey in plan.storeys:
        for piece in storey.furniture:
            room = next(r for r in storey.rooms if r.rect.contains(piece.rect))
            cx, cy = room.rect.centre
            assert room.kind in ("office", "store")
            assert not piece.rect.overlaps(Rect(cx - 0.5, cy - 0.5, cx + 0.5, cy + 0.5))
            assert not any(piece.rect.overlaps(c) for c in columns)
        rects = [p.rect for p in storey.furniture]
        assert not any(a.overlaps(b) for i, a in enumerate(rects) for b in rects[i + 1 :])


@settings(max_examples=60, deadline=None)
@given(seed=seeds, storeys=st.integers(min_value=2, max_value=10))
def test_stair_void_is_clear_of_columns_and_beams(seed: int, storeys: int) -> None:
    plan = plan_building(seed=seed, storeys=storeys)
    stair = plan.stair
    assert stair is not None
    void = stair.opening
    # Touching is fine (the void ends at the column faces); float noise is not an overlap.
    assert not any(void.overlaps(c, margin_m=-1e-6) for c in plan.column_rects())
    assert not any(void.overlaps(b, margin_m=-1e-6) for b in plan.beam_rects())
    assert 0.15 <= stair.riser_m <= 0.19
    assert 2 * stair.risers_per_flight * stair.riser_m == pytest.approx(plan.storey_height_m)
    well = next(r for r in plan.storeys[0].rooms if r.kind == "stairwell").rect
    assert well.contains(void)
    assert (void.y0, void.y1) == pytest.approx((well.y0, well.y1))  # flights fill the well wall to wall


def test_one_storey_plan_has_no_stair() -> None:
    plan: BuildingPlan = plan_building(seed=0, storeys=1)
    assert plan.stair is None
    assert all(r.kind in ("office", "corridor") for r in plan.storeys[0].rooms)

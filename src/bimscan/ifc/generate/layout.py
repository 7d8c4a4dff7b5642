"""Seeded floor plans of procedural demo buildings: plain numbers, no IFC.

``plan_building`` turns (seed, storeys) into a ``BuildingPlan``: footprint, storey height,
structural grid (columns, downstand beams), stairwell, and per storey the rooms, walls with their
door and window openings, ceilings and furniture. ``building.py`` turns a plan into IFC4. Keeping
the two apart lets the layout rules be read (and tested) without any geometry kernel.

The building is a double-loaded corridor block, the commonest office/school plan: a corridor
along X, a strip of rooms south and north of it, a half-turn stair in a stairwell at the west
end of the north strip (when there is more than one storey; a store room fills the strip behind
it where the strip is deeper than the stair), the entrance at the east end of the
corridor. Columns stand on a grid along the exterior walls and the corridor walls; beams span
across the building (along Y) at the interior grid lines, under every slab.

Coordinates are metres, world axes, Z up; the outer faces of the exterior walls span
``[0, width_m] x [0, depth_m]`` and the ground floor slab's top is at Z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

MIN_STOREYS = 1
MAX_STOREYS = 10

# Fixed dimensions (metres) of the building fabric, chosen from common practice.
EXTERIOR_WALL_M = 0.3
STAIR_GOING_M = 0.28  # tread depth; risers follow from the storey height
STAIR_GAP_M = 0.1  # gap between the two flights of the half-turn stair
LANDING_DEPTH_M = 0.2
DOOR_HEIGHT_M = 2.1
ENTRANCE_WIDTH_M = 1.0
ENTRANCE_HEIGHT_M = 2.2
DOOR_WIDTH_M = 0.9
CEILING_M = 0.025  # ceiling finish layer directly under the slab
MIN_ROOM_M = 2.8  # narrowest room, wall centre to wall centre

RoomKind = Literal["office", "corridor", "stairwell", "store"]
OpeningKind = Literal["door", "window"]
FurnitureKind = Literal["table", "cabinet", "shelf"]


@dataclass(frozen=True)
class Rect:
    """Axis-aligned rectangle in plan, metres: ``x0 <= x1``, ``y0 <= y1``."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def width(self) -> float:
        return self.x1 - self.x0

    @property
    def depth(self) -> float:
        return self.y1 - self.y0

    @property
    def centre(self) -> tuple[float, float]:
        return ((self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2)

    def overlaps(self, other: Rect, *, margin_m: float = 0.0) -> bool:
        """True when the rectangles, each grown by ``margin_m``, share interior area."""
        return (
            self.x0 - margin_m < other.x1 + margin_m
            and other.x0 - margin_m < self.x1 + margin_m
            and self.y0 - margin_m < other.y1 + margin_m
            and other.y0 - margin_m < self.y1 + margin_m
        )

    def contains(self, other: Rect) -> bool:
        return self.x0 <= other.x0 and self.y0 <= other.y0 and other.x1 <= self.x1 and other.y1 <= self.y1


@dataclass(frozen=True)
class OpeningPlan:
    """A door or window in a wall, in the wall's own frame.

    offset_m: from the wall's start point along its axis to the opening's near edge.
    sill_m: from the wall's base (the storey's floor level) to the opening's bottom.
    """

    kind: OpeningKind
    offset_m: float
    width_m: float
    sill_m: float
    height_m: float
    name: str


@dataclass(frozen=True)
class WallPlan:
    """A straight wall by its centre line from ``start`` to ``end`` (plan, metres)."""

    name: str
    start: tuple[float, float]
    end: tuple[float, float]
    thickness_m: float
    exterior: bool
    openings: tuple[OpeningPlan, ...]

    @property
    def length_m(self) -> float:
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])


@dataclass(frozen=True)
class RoomPlan:
    """One room (an IfcSpace): its clear extent between wall faces."""

    number: str
    kind: RoomKind
    rect: Rect
    has_ceiling: bool


@dataclass(frozen=True)
class FurniturePlan:
    """A piece of furniture: footprint in plan, height, and the direction its front faces.

    facing: unit vector (plan) from the piece's back to its front, one of the four axis
    directions; the piece's width runs along the perpendicular.
    """

    kind: FurnitureKind
    rect: Rect
    height_m: float
    facing: tuple[int, int]
    name: str


@dataclass(frozen=True)
class StairPlan:
    """The half-turn stair repeated between every pair of storeys, in plan.

    Flight 1 rises along +X from ``x_start_m`` at the north side of the stairwell to the landing;
    flight 2 rises along -X at the corridor side from the landing back to ``x_start_m``, where
    it arrives at the slab edge. The flights fill the stairwell wall to wall; the slab opening
    above a stair spans ``opening``.
    """

    x_start_m: float
    x_landing_m: float
    x_end_m: float
    flight1_y: tuple[float, float]
    flight2_y: tuple[float, float]
    risers_per_flight: int
    riser_m: float
    going_m: float
    wall_x_m: float  # centre line of the stairwell's east wall, also a column grid line
    store_wall_y_m: float | None  # centre line of the wall between stairwell and store, if any

    @property
    def opening(self) -> Rect:
        return Rect(self.x_start_m, self.flight2_y[0], self.x_end_m, self.flight1_y[1])


@dataclass(frozen=True)
class StoreyPlan:
    """Everything placed on one storey; its floor slab top is at ``elevation_m``."""

    index: int
    elevation_m: float
    rooms: tuple[RoomPlan, ...]
    walls: tuple[WallPlan, ...]
    furniture: tuple[FurniturePlan, ...]


@dataclass(frozen=True)
class BuildingPlan:
    """A whole seeded building. All lengths in metres.

    grid_x_m: X of the column grid lines (column centres); grid_y_m: Y of the column rows.
    Beams run along Y at ``grid_x_m[1:-1]`` under every slab.
    """

    seed: int
    width_m: float
    depth_m: float
    storey_height_m: float
    slab_m: float
    interior_wall_m: float
    column_m: float
    beam_width_m: float
    beam_depth_m: float
    corridor_y_m: tuple[float, float]
    grid_x_m: tuple[float, ...]
    grid_y_m: tuple[float, ...]
    stair: StairPlan | None
    storeys: tuple[StoreyPlan, ...]

    @property
    def height_m(self) -> float:
        """Top of the roof slab (world Z)."""
        return len(self.storeys) * self.storey_height_m

    @property
    def clear_height_m(self) -> float:
        """Floor slab top to the underside of the slab above."""
        return self.storey_height_m - self.slab_m

    def column_rects(self) -> list[Rect]:
        """Plan footprints of all columns (the same on every storey)."""
        h = self.column_m / 2
        return [Rect(x - h, y - h, x + h, y + h) for x in self.grid_x_m for y in self.grid_y_m]

    def beam_rects(self) -> list[Rect]:
        """Plan footprints of all beams (the same under every slab): spans between column faces."""
        c, hb = self.column_m, self.beam_width_m / 2
        ys = self.grid_y_m
        spans = [(ys[0] + c / 2, ys[1] - c / 2), (ys[1] + c / 2, ys[2] - c / 2), (ys[2] + c / 2, ys[3] - c / 2)]
        return [Rect(x - hb, y0, x + hb, y1) for x in self.grid_x_m[1:-1] for y0, y1 in spans]


def _r(value: float) -> float:
    """Round to the millimetre, so the file holds tidy numbers and no float noise."""
    return round(float(value), 3)


def plan_building(*, seed: int, storeys: int) -> BuildingPlan:
    """Plan a seeded double-loaded corridor building with ``storeys`` storeys.

    Building-wide choices come from ``seed`` alone; each storey's rooms and furniture come from
    their own generator seeded by (seed, storey), so a storey's layout does not depend on how
    many storeys sit above it (except that a one-storey building has no stairwell).
    """
    rng = np.random.default_rng([seed, 0])
    e = EXTERIOR_WALL_M
    width = round(float(rng.uniform(12.0, 26.0)), 1)
    depth = round(float(rng.uniform(9.0, 16.0)), 1)
    storey_height = round(float(rng.uniform(3.0, 3.6)), 2)
    slab = float(rng.choice([0.20, 0.22, 0.25]))
    ti = float(rng.choice([0.10, 0.12, 0.15]))
    column = float(rng.choice([0.3, 0.4]))
    beam_width = 0.3
    beam_depth = float(rng.choice([0.4, 0.45, 0.5, 0.55, 0.6]))
    corridor_clear = _r(rng.uniform(1.6, 2.0))
    max_bay = float(rng.uniform(6.0, 7.5))

    # Clear depths of the two room strips: both at least 3 m, so the stair fits the north one.
    strips = depth - 2 * e - corridor_clear - 2 * ti
    south_clear = _r(min(max(strips * rng.uniform(0.4, 0.6), 3.0), strips - 3.0))
    ca = _r(e + south_clear + ti / 2)  # south corridor wall centre line
    cb = _r(ca + ti + corridor_clear)  # north corridor wall centre line
    grid_y = (_r(e + column / 2), ca, cb, _r(depth - e - column / 2))

    stair = None
    x_first = e  # where the north strip's rooms begin
    if storeys > 1:
        stair = _plan_stair(
            storey_height=storey_height,
            column=column,
            beam_width=beam_width,
            interior_wall=ti,
            north=(_r(cb + ti / 2), _r(depth - e)),
        )
        x_first = stair.wall_x_m
    west, east = _r(e + column / 2), _r(width - e - column / 2)
    lines = [west]
    if stair is not None:
        lines.append(x_first)  # a grid line on the stairwell wall keeps beams out of the stair void
    n_bays = max(1, math.ceil((east - lines[-1]) / max_bay))
    lines += [_r(lines[-1] + (east - lines[-1]) * (i + 1) / n_bays) for i in range(n_bays)]
    lines[-1] = east

    plan = BuildingPlan(
        seed=seed,
        width_m=width,
        depth_m=depth,
        storey_height_m=storey_height,
        slab_m=slab,
        interior_wall_m=ti,
        column_m=column,
        beam_width_m=beam_width,
        beam_depth_m=beam_depth,
        corridor_y_m=(ca, cb),
        grid_x_m=tuple(lines),
        grid_y_m=grid_y,
        stair=stair,
        storeys=(),
    )
    storey_plans = tuple(
        _plan_storey(plan, index=k, x_first=x_first, rng=np.random.default_rng([seed, 1, k]))
        for k in range(storeys)
    )
    return replace(plan, storeys=storey_plans)


def _plan_stair(
    *, storey_height: float, column: float, beam_width: float, interior_wall: float, north: tuple[float, float]
) -> StairPlan:
    """The half-turn stair at the west end of the north strip.

    The flights fill the stairwell's depth wall to wall, so the slab opening above leaves no
    unguarded ledge; where the strip is much deeper than the stair needs, a wall closes the
    stairwell and the rest of the strip's depth becomes a store room behind it.
    """
    e, ti = EXTERIOR_WALL_M, interior_wall
    risers = max(2, round(storey_height / 2 / 0.17))
    run = (risers - 1) * STAIR_GOING_M
    y0, y1 = north
    width, store_wall_y = (y1 - y0 - STAIR_GAP_M) / 2, None
    if y1 - y0 - (2 * 1.2 + STAIR_GAP_M) - ti >= 1.2:
        width = 1.2
        store_wall_y = _r(y0 + 2 * width + STAIR_GAP_M + ti / 2)
    # The entry zone in front of the flights leaves room for a door between the west corridor
    # column and the first riser.
    x_start = _r(e + column + DOOR_WIDTH_M + 0.3)
    x_landing = _r(x_start + run)
    # The landing is as deep as a flight is wide; it stops at the face of the columns on the
    # stairwell's east grid line, so no column or beam stands in the stair void.
    x_end = _r(x_landing + width)
    wall_x = _r(x_end + max(column, beam_width) / 2)
    well_y1 = _r(y0 + 2 * width + STAIR_GAP_M)
    return StairPlan(
        x_start_m=x_start,
        x_landing_m=x_landing,
        x_end_m=x_end,
        flight1_y=(_r(well_y1 - width), well_y1),
        flight2_y=(_r(y0), _r(y0 + width)),
        risers_per_flight=risers,
        riser_m=storey_height / (2 * risers),
        going_m=STAIR_GOING_M,
        wall_x_m=wall_x,
        store_wall_y_m=store_wall_y,
    )


def _split_strip(rng: np.random.Generator, x0: float, x1: float, grid_x: tuple[float, ...]) -> list[float]:
    """Partition centre lines splitting [x0, x1] into seeded rooms of at least MIN_ROOM_M.

    A partition that lands next to a column line is moved onto it: the column then stands in
    the wall, as in real plans, instead of leaving a sliver between wall and column.
    """
    length = x1 - x0
    n = int(np.clip(round(length / rng.uniform(4.5, 7.5)), 1, 5))
    while n > 1 and length < n * MIN_ROOM_M:
        n -= 1
    widths = MIN_ROOM_M + (length - n * MIN_ROOM_M) * rng.dirichlet(np.full(n, 5.0))
    cuts: list[float] = []
    for x in x0 + np.cumsum(widths)[:-1]:
        near = min(grid_x, key=lambda g: abs(g - x))
        previous = cuts[-1] if cuts else x0
        for candidate in ((near, x) if abs(near - x) < 0.35 else (x,)):
            if candidate - previous >= MIN_ROOM_M and x1 - candidate >= MIN_ROOM_M:
                cuts.append(_r(candidate))
                break
    return cuts


def _free_intervals(lo: float, hi: float, blocked: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Parts of [lo, hi] not covered by any blocked interval."""
    out, at = [], lo
    for b0, b1 in sorted(blocked):
        if b1 <= at or b0 >= hi:
            continue
        if b0 > at:
            out.append((at, b0))
        at = max(at, b1)
    if at < hi:
        out.append((at, hi))
    return out


def _plan_storey(plan: BuildingPlan, *, index: int, x_first: float, rng: np.random.Generator) -> StoreyPlan:
    """Rooms, walls with openings, and furniture of storey ``index``.

    ``x_first`` is where the north strip's offices begin (east of the stairwell, if any).
    """
    e, ti, c = EXTERIOR_WALL_M, plan.interior_wall_m, plan.column_m
    w, d = plan.width_m, plan.depth_m
    ca, cb = plan.corridor_y_m
    clear_h = plan.clear_height_m
    grid_x = plan.grid_x_m
    # Column zones along a wall line (plus a margin), which doors and windows keep clear of.
    column_zones = [(g - c / 2 - 0.1, g + c / 2 + 0.1) for g in grid_x]

    south_y = (e, _r(ca - ti / 2))
    north_y = (_r(cb + ti / 2), _r(d - e))
    south_cuts = _split_strip(rng, e, w - e, grid_x)
    north_cuts = _split_strip(rng, x_first, w - e, grid_x)

    rooms: list[RoomPlan] = []
    number = iter(range(1, 100))

    def room_number() -> str:
        return f"{index}.{next(number):02d}"

    corridor = RoomPlan(room_number(), "corridor", Rect(e, _r(ca + ti / 2), _r(w - e), _r(cb - ti / 2)), True)
    rooms.append(corridor)
    stair = plan.stair
    strip_rooms: list[tuple[RoomPlan, str]] = []  # rooms along an exterior wall, with its name
    if stair is not None:
        well_y1 = north_y[1] if stair.store_wall_y_m is None else _r(stair.store_wall_y_m - ti / 2)
        rooms.append(RoomPlan(room_number(), "stairwell", Rect(e, north_y[0], _r(x_first - ti / 2), well_y1), False))
        if stair.store_wall_y_m is not None:
            store = Rect(e, _r(stair.store_wall_y_m + ti / 2), _r(x_first - ti / 2), north_y[1])
            rooms.append(RoomPlan(room_number(), "store", store, True))
            strip_rooms.append((rooms[-1], "north"))
    for side, cuts, x_lo, (y0, y1) in (("south", south_cuts, e, south_y), ("north", north_cuts, x_first, north_y)):
        edges = [x_lo, *cuts, w - e]
        for i in range(len(edges) - 1):
            a = edges[i] + (ti / 2 if i > 0 or (side == "north" and plan.stair is not None) else 0.0)
            b = edges[i + 1] - (ti / 2 if i < len(edges) - 2 else 0.0)
            room = RoomPlan(room_number(), "office", Rect(_r(a), y0, _r(b), y1), bool(rng.random() < 0.85))
            rooms.append(room)
            strip_rooms.append((room, side))

    # Openings, collected per wall name, in that wall's frame.
    openings: dict[str, list[OpeningPlan]] = {}
    window_sill = _r(rng.uniform(0.85, 0.95))
    window_head = min(2.25, clear_h - 0.35)

    def add_opening(wall: str, kind: OpeningKind, at: float, width: float, sill: float, height: float) -> None:
        name = f"{kind} {index}.{sum(len(v) for v in openings.values()):02d}"  # unique on the storey
        openings.setdefault(wall, []).append(OpeningPlan(kind, _r(at), _r(width), _r(sill), _r(height), name))

    # Every strip room opens onto the corridor; the corridor wall starts at x = e.
    for room, side in strip_rooms:
        if room.kind == "store":
            continue
        free = _free_intervals(room.rect.x0 + 0.1, room.rect.x1 - 0.1, column_zones)
        free = [(a, b) for a, b in free if b - a >= DOOR_WIDTH_M]
        a, b = free[int(rng.integers(len(free)))]
        x = a + rng.uniform(0.0, b - a - DOOR_WIDTH_M)
        add_opening(f"corridor {side}", "door", x - e, DOOR_WIDTH_M, 0.0, DOOR_HEIGHT_M)
    if stair is not None:
        # Stairwell and store doors open onto the entry zone in front of the first riser.
        add_opening("corridor north", "door", c + 0.15, DOOR_WIDTH_M, 0.0, DOOR_HEIGHT_M)
        if stair.store_wall_y_m is not None:
            add_opening("stair north", "door", 0.15, DOOR_WIDTH_M, 0.0, DOOR_HEIGHT_M)

    # Windows: in the exterior wall of every strip room, one per stretch between columns.
    row_zones = [(y - c / 2 - 0.1, y + c / 2 + 0.1) for y in plan.grid_y_m]

    def add_windows(wall: str, lo: float, hi: float, wall_start: float) -> None:
        for a, b in _free_intervals(lo + 0.2, hi - 0.2, column_zones if wall in ("south", "north") else row_zones):
            if b - a < 1.0:
                continue
            width = min(b - a, rng.uniform(1.2, 2.2))
            at = (a + b) / 2 - width / 2 - wall_start
            add_opening(wall, "window", at, width, window_sill, window_head - window_sill)

    for room, side in strip_rooms:
        add_windows(side, room.rect.x0, room.rect.x1, 0.0)
        # End rooms get a window in the gable wall too (gable walls run from y = e).
        if room.rect.x0 <= e + 1e-9:
            add_windows("west", room.rect.y0, room.rect.y1, e)
        if room.rect.x1 >= w - e - 1e-9:
            add_windows("east", room.rect.y0, room.rect.y1, e)
    # The corridor ends: the entrance door at the east end of the ground floor, windows elsewhere.
    mid = (ca + cb) / 2
    if index == 0:
        add_opening("east", "door", mid - ENTRANCE_WIDTH_M / 2 - e, ENTRANCE_WIDTH_M, 0.0, ENTRANCE_HEIGHT_M)
    else:
        add_windows("east", corridor.rect.y0, corridor.rect.y1, e)
    add_windows("west", corridor.rect.y0, corridor.rect.y1, e)

    def wall(name: str, start: tuple[float, float], end: tuple[float, float], t: float, exterior: bool) -> WallPlan:
        start, end = (_r(start[0]), _r(start[1])), (_r(end[0]), _r(end[1]))
        return WallPlan(name, start, end, t, exterior, tuple(sorted(openings.get(name, []), key=lambda o: o.offset_m)))

    walls = [
        wall("south", (0.0, e / 2), (w, e / 2), e, True),
        wall("north", (0.0, d - e / 2), (w, d - e / 2), e, True),
        wall("west", (e / 2, e), (e / 2, d - e), e, True),
        wall("east", (w - e / 2, e), (w - e / 2, d - e), e, True),
        wall("corridor south", (e, ca), (w - e, ca), ti, False),
        wall("corridor north", (e, cb), (w - e, cb), ti, False),
    ]
    for i, x in enumerate(south_cuts):
        walls.append(wall(f"partition south {i}", (x, e), (x, south_y[1]), ti, False))
    if stair is not None and stair.store_wall_y_m is not None:
        y = stair.store_wall_y_m
        walls.append(wall("stair north", (e, y), (x_first - ti / 2, y), ti, False))
    north_partitions = ([x_first] if stair is not None else []) + north_cuts
    for i, x in enumerate(north_partitions):
        walls.append(wall(f"partition north {i}", (x, north_y[0]), (x, d - e), ti, False))

    furniture = _plan_furniture(plan, rooms, walls, index=index, rng=rng)
    return StoreyPlan(
        index=index,
        elevation_m=_r(index * plan.storey_height_m),
        rooms=tuple(rooms),
        walls=tuple(walls),
        furniture=tuple(furniture),
    )


def _door_zones(walls: list[WallPlan]) -> list[Rect]:
    """Plan areas in front of and behind every door, kept free of furniture."""
    zones = []
    for wall in walls:
        (x0, y0), (_, y1) = wall.start, wall.end
        along_x = abs(y1 - y0) < 1e-9
        for o in wall.openings:
            if o.kind != "door":
                continue
            a, b = o.offset_m - 0.1, o.offset_m + o.width_m + 0.1
            if along_x:
                zones.append(Rect(x0 + a, y0 - 1.1, x0 + b, y0 + 1.1))
            else:
                zones.append(Rect(x0 - 1.1, y0 + a, x0 + 1.1, y0 + b))
    return zones


def _window_zones(walls: list[WallPlan]) -> list[Rect]:
    """Plan areas in front of windows, where tall furniture would block the glass."""
    zones = []
    for wall in walls:
        (x0, y0), (_, y1) = wall.start, wall.end
        along_x = abs(y1 - y0) < 1e-9
        for o in wall.openings:
            if o.kind != "window":
                continue
            a, b = o.offset_m, o.offset_m + o.width_m
            if along_x:
                zones.append(Rect(x0 + a, y0 - 0.8, x0 + b, y0 + 0.8))
            else:
                zones.append(Rect(x0 - 0.8, y0 + a, x0 + 0.8, y0 + b))
    return zones


def _plan_furniture(
    plan: BuildingPlan, rooms: list[RoomPlan], walls: list[WallPlan], *, index: int, rng: np.random.Generator
) -> list[FurniturePlan]:
    """Seeded tables, cabinets and shelves in offices, clear of columns, doors and windows.

    Every office keeps a free square of 1.2 m around its centre, where a scan station can stand.
    """
    columns = [
        Rect(r.x0 - 0.05, r.y0 - 0.05, r.x1 + 0.05, r.y1 + 0.05) for r in plan.column_rects()
    ]
    doors, windows = _door_zones(walls), _window_zones(walls)
    out: list[FurniturePlan] = []
    for room in rooms:
        if room.kind not in ("office", "store"):
            continue
        r = room.rect
        cx, cy = r.centre
        keep_free = [Rect(cx - 0.6, cy - 0.6, cx + 0.6, cy + 0.6), *columns, *doors]
        placed: list[Rect] = []

        def fits(rect: Rect, tall: bool) -> bool:
            if not r.contains(rect):
                return False
            if any(rect.overlaps(o) for o in keep_free) or any(rect.overlaps(o, margin_m=0.05) for o in placed):
                return False
            return not (tall and any(rect.overlaps(o) for o in windows))

        # A table with 0.6 m to walk around it, where the room is big enough.
        long_x = r.width >= r.depth
        a, b = float(rng.uniform(1.2, 1.8)), float(rng.uniform(0.7, 0.9))
        sx, sy = (a, b) if long_x else (b, a)
        if r.width - 1.2 > sx and r.depth - 1.2 > sy:
            for _ in range(40):
                x = rng.uniform(r.x0 + 0.6, r.x1 - 0.6 - sx)
                y = rng.uniform(r.y0 + 0.6, r.y1 - 0.6 - sy)
                rect = Rect(_r(x), _r(y), _r(x + sx), _r(y + sy))
                if fits(rect, tall=False):
                    placed.append(rect)
                    facing = (0, -1) if long_x else (-1, 0)
                    out.append(FurniturePlan("table", rect, 0.74, facing, f"table {index}.{len(out)}"))
                    break
        for _ in range(int(rng.integers(1, 4))):
            kind: FurnitureKind = ("cabinet", "shelf")[int(rng.integers(2))]
            width = float(rng.uniform(0.8, 1.2))
            deep = 0.45 if kind == "cabinet" else 0.35
            height = float(rng.choice([0.8, 1.2, 2.0])) if kind == "cabinet" else float(rng.uniform(1.8, 2.1))
            for _ in range(40):
                side = int(rng.integers(4))  # which room side the back stands against: S, N, W, E
                if side < 2:
                    if r.width < width:
                        continue
                    x = rng.uniform(r.x0, r.x1 - width)
                    y = r.y0 if side == 0 else r.y1 - deep
                    rect, facing = Rect(_r(x), _r(y), _r(x + width), _r(y + deep)), ((0, 1) if side == 0 else (0, -1))
                else:
                    if r.depth < width:
                        continue
                    y = rng.uniform(r.y0, r.y1 - width)
                    x = r.x0 if side == 2 else r.x1 - deep
                    rect, facing = Rect(_r(x), _r(y), _r(x + deep), _r(y + width)), ((1, 0) if side == 2 else (-1, 0))
                if fits(rect, tall=height > 0.8):  # window sills are at 0.85 m or more
                    placed.append(rect)
                    out.append(FurniturePlan(kind, rect, _r(height), facing, f"{kind} {index}.{len(out)}"))
                    break
    return out

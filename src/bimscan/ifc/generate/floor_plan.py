"""Seeded floor plans of procedural buildings: plain numbers, no IFC.

``plan_building`` turns (seed, storeys, style) into a ``BuildingPlan``: outline, storey section
(slab, ceiling, beam depths), structural grid (columns, beams), stairwell, and per storey the
rooms, walls with their door and window openings, ceilings and furniture. ``building.py`` turns
a plan into IFC4; ``planned_elements`` lists what it will place, with the class and label each
element is meant to carry. Every number the plan is drawn from lives in ``styles.py``.

The building is a corridor block, the commonest office, school and apartment plan: a corridor
along X through the whole building, a strip of rooms south and north of it. Along X the building
is cut into *bays* by the column grid lines; each bay has its own strip depth on each side, which
gives the non-rectangular outlines: a deep bay is a wing (L, U, T footprints), a shallow one a
notch. A strip is split into *sections* where its depth changes; a section holds offices (or
rooms) side by side, each with a door to the corridor, or one open-plan area. A half-turn stair
stands at the west end of the north strip (when there is more than one storey; a store fills
the strip behind it where the strip is deeper than the stair), the entrance at the east end of
the corridor. With the style's odds a building of two storeys or more has a double-height hall
(``HallPlan``): one side section is a single room through its storey and the one above, whose
floor is cut open over it (``BuildingPlan.storey_columns`` and ``storey_beams`` say which
columns rise through both storeys and which beams the opening leaves out).

Structure (styles with a column grid): columns on every grid line at both corridor walls and
at the facades (touching the facade, half inside it, or set back from it), plus rows of
free-standing columns across strips deeper than ``MAX_SPAN_M``; beams span across the building
(along Y) on the grid lines, and in some buildings at mid-bay too, from support to support
(facade, column, wall or beam faces); the ``site`` style adds beams along the corridor and
free-standing column rows. A wall that runs under a beam stops at the beam's underside.

Coordinates are metres, world axes, Z up; the outer faces of the exterior walls span
``[0, width_m] x [0, depth_m]`` and the ground floor slab's top is at Z = 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from bimscan.ifc.generate.styles import (
    BAND_PIER_M,
    BAND_WINDOW_M,
    DOOR_HEIGHT_M,
    DOOR_WIDTH_M,
    ENTRANCE_HEIGHT_M,
    ENTRANCE_WIDTH_M,
    FINISH_CEILING_M,
    FINISH_ODDS,
    HALL_MIN_M2,
    LANDING_DEPTH_M,
    MAX_SPAN_M,
    MAX_STOREYS,
    MIN_STOREYS,
    OPEN_PLAN_DOOR_EVERY_M,
    OPENING_STEP_M,
    ROOM_M,
    SERVICE_VOID_M,
    STAIR_GAP_M,
    STAIR_GOING_M,
    STAIR_RISER_M,
    STAIR_WIDTH_M,
    STORE_EXPOSED_ODDS,
    STYLE_KEYS,
    STYLES,
    SUSPENDED_CEILING_M,
    WALL_ABOVE_OPENING_M,
    WINDOW_MARGIN_M,
    BuildingStyle,
    CeilingSystem,
    ColumnSetting,
    RoomKind,
    Shape,
    WindowStyle,
)

__all__ = [
    "LANDING_DEPTH_M", "MAX_STOREYS", "MIN_STOREYS", "BeamPlan", "BuildingPlan", "CeilingPlan", "FurniturePlan",
    "HallPlan", "OpeningPlan", "PlannedElement", "Rect", "RoomPlan", "StairPlan", "StoreyPlan", "WallPlan",
    "plan_building", "planned_elements",
]

OpeningKind = Literal["door", "window"]
FurnitureKind = Literal["table", "cabinet", "shelf"]
Side = Literal["south", "north"]


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
    def area(self) -> float:
        return self.width * self.depth

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

    def intersection(self, other: Rect) -> Rect | None:
        """The shared rectangle, or None when they share no area."""
        x0, y0 = max(self.x0, other.x0), max(self.y0, other.y0)
        x1, y1 = min(self.x1, other.x1), min(self.y1, other.y1)
        return Rect(x0, y0, x1, y1) if x0 < x1 and y0 < y1 else None


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
    """A straight wall by its centre line from ``start`` to ``end`` (plan, metres), along X or Y.

    height_m: from the storey's floor to the wall's top (the slab's underside, or a beam's
    underside where the wall runs under a beam).
    """

    name: str
    start: tuple[float, float]
    end: tuple[float, float]
    thickness_m: float
    height_m: float
    exterior: bool
    openings: tuple[OpeningPlan, ...]

    @property
    def length_m(self) -> float:
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])

    @property
    def along_x(self) -> bool:
        return abs(self.end[1] - self.start[1]) < 1e-9

    @property
    def footprint(self) -> Rect:
        """The wall's rectangle in plan."""
        (x0, y0), (x1, y1), h = self.start, self.end, self.thickness_m / 2
        if self.along_x:
            return Rect(min(x0, x1), y0 - h, max(x0, x1), y0 + h)
        return Rect(x0 - h, min(y0, y1), x0 + h, max(y0, y1))


@dataclass(frozen=True)
class RoomPlan:
    """One room (an IfcSpace): its clear extent between wall faces, and its height (floor to
    its ceiling covering, or to the slab above where it has none)."""

    number: str
    kind: RoomKind
    rect: Rect
    has_ceiling: bool
    height_m: float


@dataclass(frozen=True)
class CeilingPlan:
    """The ceiling covering of one room: rectangles (the room less the columns and any beams
    that hang below it) at ``bottom_m`` above the storey floor, ``thickness_m`` thick."""

    name: str
    room: str
    rects: tuple[Rect, ...]
    bottom_m: float
    thickness_m: float


@dataclass(frozen=True)
class BeamPlan:
    """A beam's footprint in plan; it runs along ``along`` from the slab's underside down to the
    building's ``beam_bottom_m``."""

    rect: Rect
    along: Literal["x", "y"]

    @property
    def length_m(self) -> float:
        return self.rect.width if self.along == "x" else self.rect.depth


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
    wall_x_m: float  # centre line of the stairwell's east (core) wall, also a column grid line
    store_wall_y_m: float | None  # centre line of the wall between stairwell and store, if any

    @property
    def opening(self) -> Rect:
        return Rect(self.x_start_m, self.flight2_y[0], self.x_end_m, self.flight1_y[1])


@dataclass(frozen=True)
class HallPlan:
    """A double-height hall: the side section ``rect`` (its clear extent) of storey ``storey`` is
    one room up to the slab over the storey above; that storey's floor slab has an opening over
    it, nothing stands on that floor there, and no beam crosses it at that level."""

    storey: int
    rect: Rect


@dataclass(frozen=True)
class StoreyPlan:
    """Everything placed on one storey; its floor slab top is at ``elevation_m``."""

    index: int
    elevation_m: float
    rooms: tuple[RoomPlan, ...]
    walls: tuple[WallPlan, ...]
    ceilings: tuple[CeilingPlan, ...]
    furniture: tuple[FurniturePlan, ...]


@dataclass(frozen=True)
class RoofPlan:
    """A gable roof over an attic (the storey above the top storey's slab).

    The ridge runs along X over the middle of the depth. Both roof planes rise at ``pitch_deg``
    from ``knee_m`` above the attic floor at the facades' outer faces (no eaves overhang), and
    are ``thickness_m`` thick across the plane. Gable walls close both ends; knee walls carry
    the long facades up to the roof.
    """

    pitch_deg: float
    knee_m: float
    thickness_m: float

    def ridge_m(self, depth_m: float) -> float:
        """Attic floor to the roof's underside at the ridge."""
        return round(self.knee_m + depth_m / 2 * math.tan(math.radians(self.pitch_deg)), 6)

    def vertical_thickness_m(self) -> float:
        """The roof's thickness measured plumb."""
        return round(self.thickness_m / math.cos(math.radians(self.pitch_deg)), 6)


@dataclass(frozen=True)
class BuildingPlan:
    """A whole seeded building. All lengths in metres, heights above the storey's floor.

    outline_m: the outer faces of the exterior walls, a counter-clockwise rectilinear polygon.
    grid_x_m: X of the column grid lines, west to east; the bays lie between them.
    bay_south_m, bay_north_m: per bay, Y of the inner face of its south and north facade.
    columns, beams: the same on every storey, less those a hall leaves out (``storey_columns``,
    ``storey_beams``). ``beam_bottom_m`` equals ``soffit_m`` where the building has no beams.
    roof: the gable roof over an attic, or None for a flat roof slab.
    hall: a double-height hall, or None.
    """

    seed: int
    style: str
    shape: Shape
    ceiling_system: CeilingSystem
    window_style: WindowStyle
    column_setting: ColumnSetting
    width_m: float
    depth_m: float
    outline_m: tuple[tuple[float, float], ...]
    storey_height_m: float
    slab_m: float
    ceiling_height_m: float
    ceiling_thickness_m: float
    beam_bottom_m: float
    exterior_wall_m: float
    corridor_wall_m: float
    partition_m: float
    core_wall_m: float
    column_m: float
    beam_width_m: float
    corridor_y_m: tuple[float, float]
    grid_x_m: tuple[float, ...]
    bay_south_m: tuple[float, ...]
    bay_north_m: tuple[float, ...]
    columns: tuple[Rect, ...]
    beams: tuple[BeamPlan, ...]
    stair: StairPlan | None
    storeys: tuple[StoreyPlan, ...]
    roof: RoofPlan | None = None
    hall: HallPlan | None = None

    @property
    def roof_base_m(self) -> float:
        """Top of the slab over the top storey (world Z): the flat roof's top, or the attic floor."""
        return round(len(self.storeys) * self.storey_height_m, 6)

    @property
    def height_m(self) -> float:
        """Top of the building (world Z): the flat roof slab's top, or the gable roof's ridge."""
        if self.roof is None:
            return self.roof_base_m
        return round(self.roof_base_m + self.roof.ridge_m(self.depth_m) + self.roof.vertical_thickness_m(), 6)

    @property
    def attic_room(self) -> RoomPlan | None:
        """The attic's one room (its IfcSpace), between the facades' inner faces, up to the ridge."""
        if self.roof is None:
            return None
        e = self.exterior_wall_m
        rect = Rect(e, e, _r(self.width_m - e), _r(self.depth_m - e))
        return RoomPlan(ATTIC_NAME, "room", rect, False, self.roof.ridge_m(self.depth_m))

    @property
    def soffit_m(self) -> float:
        """Floor slab top to the underside of the slab above."""
        return round(self.storey_height_m - self.slab_m, 6)

    @property
    def beam_depth_m(self) -> float:
        return round(self.soffit_m - self.beam_bottom_m, 6)

    def column_rects(self) -> list[Rect]:
        return list(self.columns)

    def beam_rects(self) -> list[Rect]:
        return [b.rect for b in self.beams]

    def storey_columns(self, index: int) -> list[tuple[int, Rect, float]]:
        """(number, rect, height) of the columns standing on storey ``index``: up to the slab
        above, those in the hall through the storey above (where none stands on the hall's
        opening)."""
        hall = self.hall
        out = []
        for i, rect in enumerate(self.columns):
            in_hall = hall is not None and rect.overlaps(hall.rect, margin_m=-0.01)
            if in_hall and hall.storey + 1 == index:
                continue
            tall = in_hall and hall.storey == index
            out.append((i, rect, _r(self.storey_height_m + self.soffit_m) if tall else self.soffit_m))
        return out

    def storey_beams(self, index: int) -> list[tuple[int, BeamPlan]]:
        """(number, beam) of the beams under the slab over storey ``index``: all, but those that
        would cross the hall's opening in that slab."""
        hall = self.hall
        if hall is None or hall.storey != index:
            return list(enumerate(self.beams))
        def crosses(beam: BeamPlan) -> bool:
            part = beam.rect.intersection(hall.rect)
            return part is not None and part.area > 1e-4

        return [(i, b) for i, b in enumerate(self.beams) if not crosses(b)]


@dataclass(frozen=True)
class PlannedElement:
    """One element the author places with a body: what the loader must find.

    label: the class of the paper's five-class scheme (spc5) the element is meant to carry:
    "Wall&Column", "Beam", "Covering", "Slab" or "Others".
    """

    storey: int
    name: str
    ifc_class: str
    predefined_type: str
    label: str


def storey_name(index: int) -> str:
    return "Ground floor" if index == 0 else f"Floor {index}"


def column_name(storey: int, index: int) -> str:
    return f"Column {storey}.{index:02d}"


def beam_name(storey: int, index: int) -> str:
    return f"Beam {storey}.{index:02d}"


def floor_slab_name(storey: int) -> str:
    return f"Floor slab {storey}"


ROOF_SLAB_NAME = "Roof slab"
ATTIC_NAME = "Attic"
GABLE_PARTS = {  # element name -> (IFC class, predefined type, spc5 label) of a gable roof's attic
    "Wall gable west": ("IfcWall", "SOLIDWALL", "Wall&Column"),
    "Wall gable east": ("IfcWall", "SOLIDWALL", "Wall&Column"),
    "Wall knee south": ("IfcWall", "SOLIDWALL", "Wall&Column"),
    "Wall knee north": ("IfcWall", "SOLIDWALL", "Wall&Column"),
    "Roof slab south": ("IfcSlab", "ROOF", "Slab"),
    "Roof slab north": ("IfcSlab", "ROOF", "Slab"),
}
STAIR_GUARD_NAME = "Stair void guard"


def stair_part_names(storey: int) -> dict[str, str]:
    """Names of the parts of the stair that rises from ``storey``."""
    return {
        "flight1": f"Stair {storey} flight 1",
        "flight2": f"Stair {storey} flight 2",
        "landing": f"Stair {storey} landing",
        "handrail": f"Stair {storey} handrail",
    }


FURNITURE_TYPES = {"table": "TABLE", "cabinet": "FILECABINET", "shelf": "SHELF"}


def planned_elements(plan: BuildingPlan) -> tuple[PlannedElement, ...]:
    """Every element with a body that ``building.py`` places for ``plan``, storey by storey."""
    out: list[PlannedElement] = []
    top = len(plan.storeys) - 1
    for sp in plan.storeys:
        k = sp.index

        def add(name: str, ifc_class: str, predefined: str, label: str) -> None:
            out.append(PlannedElement(k, name, ifc_class, predefined, label))

        add(floor_slab_name(k), "IfcSlab", "BASESLAB" if k == 0 else "FLOOR", "Slab")
        for wall in sp.walls:
            add(f"Wall {wall.name}", "IfcWall", "SOLIDWALL" if wall.exterior else "PARTITIONING", "Wall&Column")
            for o in wall.openings:
                add(o.name.capitalize(), "IfcDoor" if o.kind == "door" else "IfcWindow", o.kind.upper(), "Others")
        for i, _, _ in plan.storey_columns(k):
            add(column_name(k, i), "IfcColumn", "COLUMN", "Wall&Column")
        for i, _ in plan.storey_beams(k):
            add(beam_name(k, i), "IfcBeam", "BEAM", "Beam")
        for ceiling in sp.ceilings:
            add(ceiling.name, "IfcCovering", "CEILING", "Covering")
        for piece in sp.furniture:
            add(piece.name.capitalize(), "IfcFurniture", FURNITURE_TYPES[piece.kind], "Others")
        if plan.stair is not None and k < top:
            names = stair_part_names(k)
            add(names["flight1"], "IfcStairFlight", "STRAIGHT", "Others")
            add(names["flight2"], "IfcStairFlight", "STRAIGHT", "Others")
            add(names["landing"], "IfcSlab", "LANDING", "Slab")
            add(names["handrail"], "IfcRailing", "HANDRAIL", "Others")
        if k == top:
            if plan.roof is None:
                add(ROOF_SLAB_NAME, "IfcSlab", "ROOF", "Slab")
            if plan.stair is not None:
                add(STAIR_GUARD_NAME, "IfcRailing", "GUARDRAIL", "Others")
    if plan.roof is not None:
        attic = len(plan.storeys)
        out.append(PlannedElement(attic, floor_slab_name(attic), "IfcSlab", "FLOOR", "Slab"))
        out.extend(PlannedElement(attic, name, *part) for name, part in GABLE_PARTS.items())
    return tuple(out)


EPS = 1e-9


def _r(value: float) -> float:
    """Round to the millimetre, so the file holds tidy numbers and no float noise."""
    return round(float(value), 3)


def _cm(value: float) -> float:
    return round(float(value), 2)


def _pick(rng: np.random.Generator, weights: dict[str, float]) -> str:
    """One key of ``weights``, drawn with probability proportional to its weight."""
    keys = list(weights)
    p = np.array([weights[k] for k in keys], dtype=float)
    return keys[int(rng.choice(len(keys), p=p / p.sum()))]


def _draw(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(*bounds)) if bounds[1] > bounds[0] else float(bounds[0])


# -- the building ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Section:
    """Part of a strip between two walls across it, all of one depth; ``rect`` is its clear extent."""

    side: Side
    bays: tuple[int, ...]
    rect: Rect
    west_wall: tuple[float, float, float, float] | None  # (centre X, thickness, y0, y1) of the wall that starts it
    crossed: bool  # beams along X run across it


def plan_building(*, seed: int, storeys: int, style: str = "office") -> BuildingPlan:
    """Plan a seeded building of ``style`` (a key of ``STYLES``) with ``storeys`` storeys.

    Building-wide choices come from (seed, style) alone; each storey's rooms and furniture come
    from their own generator seeded by (seed, style, storey), so a storey's layout does not
    depend on how many storeys sit above it (except that a one-storey building has no stairwell).
    """
    table = STYLES[style]
    key = STYLE_KEYS[style]
    rng = np.random.default_rng([seed, key, 0])
    has_grid = bool(table.column_m)

    # -- section: slab, ceiling, beams -------------------------------------------------------
    system: CeilingSystem = _pick(rng, table.ceilings)  # type: ignore[assignment]
    slab = _cm(_draw(rng, table.slab_m))
    beam_depth = _cm(_draw(rng, table.beam_depth_m)) if has_grid else 0.0
    if system == "downstand":
        tiles = has_grid and rng.random() < 1.0 - FINISH_ODDS
        plenum = _cm(_draw(rng, table.plenum_m)) if tiles else 0.0
        thickness = SUSPENDED_CEILING_M if plenum > 0 else FINISH_CEILING_M
    elif system == "suspended":
        plenum = _cm(beam_depth + _draw(rng, SERVICE_VOID_M))  # the beams and services fit above the tiles
        thickness = SUSPENDED_CEILING_M
    else:
        plenum, thickness = 0.0, 0.0
    rest = slab + plenum + thickness  # storey height less the ceiling height
    lo = max(table.storey_height_m[0], table.ceiling_height_m[0] + rest)
    hi = max(lo, min(table.storey_height_m[1], table.ceiling_height_m[1] + rest))
    lo_cm, hi_cm = math.ceil(lo * 100 - 1e-6), math.floor(hi * 100 + 1e-6)
    storey_height = (int(rng.integers(lo_cm, hi_cm + 1)) if hi_cm >= lo_cm else lo_cm) / 100
    soffit = storey_height - slab
    ceiling_height = _r(soffit - plenum - thickness)
    if not has_grid:
        beam_bottom = _r(soffit)
    elif system == "downstand":
        low = table.min_beam_bottom_m
        d_hi = min(table.downstand_m[1], ceiling_height - low)
        beam_bottom = _r(ceiling_height - _draw(rng, (min(table.downstand_m[0], d_hi), d_hi)))
    elif system == "suspended":
        beam_bottom = _r(soffit - beam_depth)
    else:
        d_hi = min(table.beam_depth_m[1], soffit - table.min_beam_bottom_m)
        beam_bottom = _r(soffit - _draw(rng, (min(table.beam_depth_m[0], d_hi), d_hi)))

    # -- walls, grid, plan -------------------------------------------------------------------
    e = _cm(_draw(rng, table.exterior_wall_m))
    tc = _cm(_draw(rng, table.corridor_wall_m))
    tp = _cm(_draw(rng, table.partition_m))
    column = float(table.column_m[int(rng.integers(len(table.column_m)))]) if has_grid else 0.0
    beam_width = min(column, _cm(_draw(rng, table.beam_width_m))) if has_grid else 0.0
    setting: ColumnSetting = _pick(rng, table.column_settings)  # type: ignore[assignment]
    setback = _cm(_draw(rng, table.setback_m)) if setting == "setback" else 0.0
    core = max(tc, beam_width)
    corridor = _cm(_draw(rng, table.corridor_m))
    south, north = _cm(_draw(rng, table.strip_m)), _cm(_draw(rng, table.strip_m))
    bay = _cm(_draw(rng, table.bay_m))
    n_bays = int(rng.integers(table.bays[0], table.bays[1] + 1))
    shape: Shape = _pick(rng, table.shapes)  # type: ignore[assignment]
    window_style: WindowStyle = _pick(rng, table.windows)  # type: ignore[assignment]
    secondary = has_grid and rng.random() < table.secondary_beam_odds
    corridor_beams = has_grid and rng.random() < table.corridor_beam_odds
    wing = _cm(_draw(rng, table.wing_m))
    notch = _cm(_draw(rng, table.notch_m))
    shape_rng = np.random.default_rng([seed, key, 2])

    inset = column / 2 if setting != "embedded" else 0.0  # gable grid lines from the gable's inner face
    x0 = _r(e + inset)
    stair = None
    if storeys > 1:
        stair = _plan_stair(storey_height=storey_height, x_west=x0, column=column, core=core, partition=tp,
                            north=(0.0, north))  # placed in Y once the corridor is known
        lines = [x0, stair.wall_x_m] + [_r(stair.wall_x_m + bay * (i + 1)) for i in range(n_bays)]
    else:
        lines = [_r(x0 + bay * i) for i in range(n_bays + 2)]
    width = _r(lines[-1] + inset + e)
    m = len(lines) - 1
    south_d, north_d = _bay_depths(shape_rng, shape, bays=m, south=south, north=north, wing=wing, notch=notch,
                                   stair=stair is not None)
    if south_d == [south] * m and north_d == [north] * m:
        shape = "rectangle"
    roof = _plan_roof(np.random.default_rng([seed, key, 3]), table, rectangle=shape == "rectangle")

    ca = _r(e + max(south_d) + tc / 2)  # south corridor wall centre line
    cb = _r(ca + tc + corridor)  # north corridor wall centre line
    depth = _r(cb + tc / 2 + max(north_d) + e)
    bay_south = tuple(_r(ca - tc / 2 - s) for s in south_d)
    bay_north = tuple(_r(cb + tc / 2 + n) for n in north_d)
    if stair is not None:
        stair = _place_stair_in_y(stair, y0=_r(cb + tc / 2))
    outline = _outline(lines, [_r(y - e) for y in bay_south], [_r(y + e) for y in bay_north], e=e, width=width)

    columns: list[Rect] = []
    beams: list[BeamPlan] = []
    if has_grid:
        columns, at, free = _plan_columns(lines, bay_south, bay_north, ca=ca, cb=cb, column=column, setting=setting,
                                         setback=setback, stair=stair is not None)
        beams = _plan_beams(lines, bay_south, bay_north, at, free, ca=ca, cb=cb, tc=tc, beam_width=beam_width,
                            secondary=secondary, corridor_beams=corridor_beams, x_beams=table.x_beams,
                            stair=stair is not None)

    plan = BuildingPlan(
        seed=seed,
        style=style,
        shape=shape,
        ceiling_system=system,
        window_style=window_style,
        column_setting=setting,
        width_m=width,
        depth_m=depth,
        outline_m=outline,
        storey_height_m=storey_height,
        slab_m=slab,
        ceiling_height_m=ceiling_height,
        ceiling_thickness_m=thickness,
        beam_bottom_m=beam_bottom,
        exterior_wall_m=e,
        corridor_wall_m=tc,
        partition_m=tp,
        core_wall_m=core,
        column_m=column,
        beam_width_m=beam_width,
        corridor_y_m=(ca, cb),
        grid_x_m=tuple(lines),
        bay_south_m=bay_south,
        bay_north_m=bay_north,
        columns=tuple(columns),
        beams=tuple(beams),
        stair=stair,
        storeys=(),
        roof=roof,
    )
    plan = replace(plan, hall=_plan_hall(np.random.default_rng([seed, key, 4]), plan, table, storeys=storeys))
    storey_plans = tuple(
        _plan_storey(plan, table, index=k, rng=np.random.default_rng([seed, key, 1, k])) for k in range(storeys)
    )
    return replace(plan, storeys=storey_plans)


def _plan_hall(rng: np.random.Generator, plan: BuildingPlan, table: BuildingStyle, *, storeys: int) -> HallPlan | None:
    """A double-height hall with the style's odds in a building of two storeys or more: a side
    section no beam along X crosses, at least ``HALL_MIN_M2``, on any storey but the top one."""
    if storeys < 2 or rng.random() >= table.hall_odds:
        return None
    candidates = [s.rect for s in _sections(plan) if not s.crossed and s.rect.area >= HALL_MIN_M2]
    if not candidates:
        return None
    rect = candidates[int(rng.integers(len(candidates)))]
    return HallPlan(int(rng.integers(storeys - 1)), rect)


def _plan_roof(rng: np.random.Generator, table: BuildingStyle, *, rectangle: bool) -> RoofPlan | None:
    """The gable roof of the style's odds over a rectangular footprint, else None (flat). Its own
    random stream: the rest of the building does not depend on the roof."""
    kind = _pick(rng, table.roofs)
    pitch = round(_draw(rng, table.roof_pitch_deg), 1)
    knee = _cm(_draw(rng, table.knee_wall_m))
    thickness = _cm(_draw(rng, table.roof_m))
    if kind != "gable" or not rectangle:
        return None
    return RoofPlan(pitch_deg=pitch, knee_m=knee, thickness_m=thickness)


def _bay_depths(
    rng: np.random.Generator, shape: Shape, *, bays: int, south: float, north: float, wing: float, notch: float,
    stair: bool,
) -> tuple[list[float], list[float]]:
    """Clear strip depth of every bay on each side, giving the footprint ``shape``.

    The stair bay (bay 0, north) and the bay beside it keep the nominal north depth, so the
    stairwell stays rectangular and its east wall is not also a step of the outline.
    """
    s, n = [south] * bays, [north] * bays
    first_north = 2 if stair else 0  # first bay whose north depth may change
    ends = [bays - 1] if bays - 1 >= first_north else []
    if shape == "L":
        side = "north" if ends and rng.random() < 0.5 else "south"
        span = 2 if bays >= 4 and rng.random() < 0.5 else 1
        idx = list(range(bays - span, bays)) if side == "north" or rng.random() < 0.5 else list(range(span))
        if side == "north":
            idx = [i for i in idx if i >= first_north]
        for i in idx:
            (n if side == "north" else s)[i] = max(wing, (n if side == "north" else s)[i])
    elif shape == "U" and bays >= 3:
        for i in (0, bays - 1):
            s[i] = max(wing, south)
    elif shape == "T" and bays >= 3:
        middle = bays // 2
        if middle >= first_north and middle < bays - 1 and rng.random() < 0.5:
            n[middle] = max(wing, north)
        else:
            s[middle] = max(wing, south)
    elif shape == "notch":
        shallow_s, shallow_n = south - notch, north - notch
        options = []
        if shallow_s >= ROOM_M[0] + 0.3:
            options += [("south", 0), ("south", bays - 1)]
        if shallow_n >= ROOM_M[0] + 0.3 and ends:
            options.append(("north", bays - 1))
        if options:
            side, i = options[int(rng.integers(len(options)))]
            if side == "south":
                s[i] = _cm(shallow_s)
            else:
                n[i] = _cm(shallow_n)
    return s, n


def _outline(
    lines: Sequence[float], south_out: Sequence[float], north_out: Sequence[float], *, e: float, width: float
) -> tuple[tuple[float, float], ...]:
    """Counter-clockwise outer outline from each bay's outer facade lines.

    Where the depth steps between two bays, the step wall is centred on their grid line, so the
    deeper bay's outline reaches half a wall thickness past it.
    """
    points = [(0.0, south_out[0])]
    for j in range(1, len(south_out)):
        if south_out[j] != south_out[j - 1]:
            x = _r(lines[j] + (e / 2 if south_out[j - 1] < south_out[j] else -e / 2))
            points += [(x, south_out[j - 1]), (x, south_out[j])]
    points.append((width, south_out[-1]))
    points.append((width, north_out[-1]))
    for j in range(len(north_out) - 1, 0, -1):
        if north_out[j] != north_out[j - 1]:
            x = _r(lines[j] + (e / 2 if north_out[j - 1] > north_out[j] else -e / 2))
            points += [(x, north_out[j]), (x, north_out[j - 1])]
    points.append((0.0, north_out[0]))
    return tuple(points)


def _exterior_walls(outline: Sequence[tuple[float, float]], e: float, height: float) -> list[WallPlan]:
    """One wall per outline edge, its thickness on the inside; walls along X run through the
    corners they share with walls along Y (the corner squares belong to them)."""
    walls = []
    n = len(outline)
    counts: dict[str, int] = {}
    for k in range(n):
        p, q = np.array(outline[k]), np.array(outline[(k + 1) % n])
        prev, nxt = np.array(outline[k - 1]), np.array(outline[(k + 2) % n])
        d = (q - p) / np.linalg.norm(q - p)

        def turn(a: np.ndarray, b: np.ndarray) -> float:
            return float(a[0] * b[1] - a[1] * b[0])

        convex_start, convex_end = turn(p - prev, q - p) > 0, turn(q - p, nxt - q) > 0
        if abs(d[1]) < 1e-9:  # along X: to the outer corner, or past a reflex corner by a wall thickness
            back, ahead = (0.0 if convex_start else e), (0.0 if convex_end else e)
        else:  # along Y: stop at the walls along X
            back, ahead = (-e if convex_start else 0.0), (-e if convex_end else 0.0)
        inward = np.array([-d[1], d[0]])  # the inside lies to the left of a counter-clockwise outline
        a, b = p - d * back + inward * e / 2, q + d * ahead + inward * e / 2
        start, end = (tuple(a), tuple(b)) if (a[0], a[1]) <= (b[0], b[1]) else (tuple(b), tuple(a))
        facing = {(0, -1): "south", (0, 1): "north", (-1, 0): "west", (1, 0): "east"}[
            (int(round(-inward[0])), int(round(-inward[1])))
        ]
        number = counts.get(facing, 0)
        counts[facing] = number + 1
        walls.append(WallPlan(f"{facing} {number}", (_r(start[0]), _r(start[1])), (_r(end[0]), _r(end[1])), e,
                              _r(height), True, ()))
    return walls


def _plan_columns(
    lines: Sequence[float], bay_south: Sequence[float], bay_north: Sequence[float], *, ca: float, cb: float,
    column: float, setting: ColumnSetting, setback: float, stair: bool,
) -> tuple[list[Rect], dict[tuple[int, float], Rect], set[tuple[int, float]]]:
    """Columns on the grid lines: corridor rows, facade rows, free-standing rows in deep bays.

    A line where the facade steps carries only the columns of the shallower side (the step wall
    stands on the rest). Returns the columns, a map (line index, row Y) -> column, and the keys
    of the columns of free-standing rows.
    """
    h = column / 2
    at: dict[tuple[int, float], Rect] = {}
    free: set[tuple[int, float]] = set()

    def offset(line: int, side: Side) -> float:
        if setting == "embedded":
            return 0.0
        if setting == "setback" and not (stair and side == "north" and line <= 1):
            return h + setback
        return h  # the stairwell keeps its corners clear

    m = len(lines) - 1
    for i, x in enumerate(lines):
        adjacent = [j for j in (i - 1, i) if 0 <= j < m]
        rows: list[float] = [ca, cb]
        for side, faces, corridor_row, sign in (("south", bay_south, ca, 1.0), ("north", bay_north, cb, -1.0)):
            depths = {faces[j] for j in adjacent}
            shallow = max(depths) if side == "south" else min(depths)
            perimeter = _r(shallow + sign * offset(i, side))  # type: ignore[arg-type]
            rows.append(perimeter)
            if len(depths) == 1:
                mid = _mid_rows(corridor_row, perimeter)
                rows += mid
                free |= {(i, y) for y in mid}
        for y in rows:
            at[(i, y)] = Rect(_r(x - h), _r(y - h), _r(x + h), _r(y + h))
    ordered = sorted(at.items(), key=lambda item: (item[0][0], item[0][1]))
    return [rect for _, rect in ordered], dict(ordered), free


def _mid_rows(corridor_row: float, perimeter_row: float) -> list[float]:
    """Rows of free-standing columns that keep every span across a strip within MAX_SPAN_M."""
    span = abs(perimeter_row - corridor_row)
    k = math.ceil(span / MAX_SPAN_M - 1e-9) - 1
    return [_r(corridor_row + (perimeter_row - corridor_row) * (i + 1) / (k + 1)) for i in range(k)]


def _plan_beams(
    lines: Sequence[float], bay_south: Sequence[float], bay_north: Sequence[float],
    columns: dict[tuple[int, float], Rect], free: set[tuple[int, float]], *, ca: float, cb: float, tc: float,
    beam_width: float, secondary: bool, corridor_beams: bool, x_beams: bool, stair: bool,
) -> list[BeamPlan]:
    """Beams along Y on the interior grid lines (and at mid-bay when ``secondary``), span by span
    between supports (facade, column, wall or beam faces); with ``x_beams``, beams along X
    between the columns of the corridor rows and of the free-standing rows."""
    m = len(lines) - 1
    hb = beam_width / 2
    along_x: list[BeamPlan] = []
    if x_beams:
        for y in sorted({y for (_, y) in free} | {ca, cb}):
            for i in range(m):
                a, b = columns.get((i, y)), columns.get((i + 1, y))
                on_row = y in (ca, cb) or ((i, y) in free and (i + 1, y) in free)
                over_stair = stair and i == 0 and y == cb  # the stair void starts at this wall's face
                if a is not None and b is not None and on_row and not over_stair:
                    along_x.append(BeamPlan(Rect(a.x1, _r(y - hb), b.x0, _r(y + hb)), "x"))
    y_lines: list[tuple[float, int | None, list[int]]] = [(lines[i], i, [i - 1, i]) for i in range(1, m)]
    if secondary:
        y_lines += [(_r((lines[j] + lines[j + 1]) / 2), None, [j]) for j in range(1 if stair else 0, m)]
    along_y: list[BeamPlan] = []
    for x, line, bays in sorted(y_lines, key=lambda t: t[0]):
        lo, hi = max(bay_south[j] for j in bays), min(bay_north[j] for j in bays)
        # Supports as (south face, north face): facades, corridor walls, columns, crossing beams.
        supports: list[tuple[float, float]] = [(lo, lo), (hi, hi), (ca - tc / 2, ca + tc / 2), (cb - tc / 2, cb + tc / 2)]
        supports += [(r.y0, r.y1) for (i, _), r in columns.items() if i == line]
        supports += [(b.rect.y0, b.rect.y1) for b in along_x if b.rect.x0 < x < b.rect.x1]
        for a, b in _gaps(supports, lo, hi):
            if b - a < 0.05 or b - a > MAX_SPAN_M:
                continue
            if ca < (a + b) / 2 < cb and not corridor_beams:
                continue
            along_y.append(BeamPlan(Rect(_r(x - hb), _r(a), _r(x + hb), _r(b)), "y"))
    return along_y + along_x


def _gaps(supports: list[tuple[float, float]], lo: float, hi: float) -> list[tuple[float, float]]:
    """Open stretches of [lo, hi] between the union of the support intervals."""
    merged: list[list[float]] = []
    for a, b in sorted(supports):
        if merged and a <= merged[-1][1] + 1e-9:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    out = []
    for (_, a), (b, _) in zip(merged, merged[1:]):
        a, b = max(a, lo), min(b, hi)
        if b > a:
            out.append((a, b))
    return out


def _plan_stair(
    *, storey_height: float, x_west: float, column: float, core: float, partition: float, north: tuple[float, float]
) -> StairPlan:
    """The half-turn stair at the west end of the north strip, with Y relative to ``north[0]``.

    The flights fill the stairwell's depth wall to wall, so the slab opening above leaves no
    unguarded ledge; where the strip is much deeper than the stair needs, a wall closes the
    stairwell and the rest of the strip's depth becomes a store room behind it.
    """
    risers = max(2, round(storey_height / 2 / STAIR_RISER_M))
    run = (risers - 1) * STAIR_GOING_M
    y0, y1 = north
    width, store_wall_y = (y1 - y0 - STAIR_GAP_M) / 2, None
    if y1 - y0 - (2 * STAIR_WIDTH_M + STAIR_GAP_M) - partition >= 1.2:
        width = STAIR_WIDTH_M
        store_wall_y = _r(y0 + 2 * width + STAIR_GAP_M + partition / 2)
    # The entry zone in front of the flights leaves room for a door between the west corridor
    # column and the first riser.
    x_start = _r(x_west + column / 2 + DOOR_WIDTH_M + 0.3)
    x_landing = _r(x_start + run)
    # The landing is as deep as a flight is wide; it stops at the face of the core wall and the
    # columns on the stairwell's east grid line, so no column or beam stands in the stair void.
    x_end = _r(x_landing + width)
    wall_x = _r(x_end + max(column, core) / 2)
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


def _place_stair_in_y(stair: StairPlan, *, y0: float) -> StairPlan:
    """The stair planned on a strip starting at Y = 0 moved onto the north strip starting at ``y0``."""

    def move(pair: tuple[float, float]) -> tuple[float, float]:
        return (_r(pair[0] + y0), _r(pair[1] + y0))

    store = None if stair.store_wall_y_m is None else _r(stair.store_wall_y_m + y0)
    return replace(stair, flight1_y=move(stair.flight1_y), flight2_y=move(stair.flight2_y), store_wall_y_m=store)


# -- one storey ---------------------------------------------------------------------------------


def _sections(plan: BuildingPlan) -> list[_Section]:
    """The strips cut where their depth steps; the north strip starts east of the stairwell."""
    e, tc = plan.exterior_wall_m, plan.corridor_wall_m
    ca, cb = plan.corridor_y_m
    lines, w = plan.grid_x_m, plan.width_m
    m = len(lines) - 1
    out = []
    for side, faces in (("south", plan.bay_south_m), ("north", plan.bay_north_m)):
        first = 1 if side == "north" and plan.stair is not None else 0
        start = first
        for j in range(first + 1, m + 1):
            if j < m and faces[j] == faces[start]:
                continue
            west_wall = None
            y_corridor = ca - tc / 2 if side == "south" else cb + tc / 2
            if start == 0:
                x0 = e
            elif start == first:  # east of the stairwell's core wall
                x0 = plan.stair.wall_x_m + plan.core_wall_m / 2  # type: ignore[union-attr]
            else:
                x0 = lines[start] + e / 2
                # As thick as the step wall it continues, from the shallower facade to the corridor.
                shallow = max(faces[start - 1], faces[start]) if side == "south" else min(faces[start - 1], faces[start])
                west_wall = (lines[start], e, shallow, y_corridor)
            x1 = w - e if j == m else lines[j] - e / 2
            y0, y1 = (faces[start], ca - tc / 2) if side == "south" else (cb + tc / 2, faces[start])
            rect = Rect(_r(x0), _r(y0), _r(x1), _r(y1))
            # Beams along X cross the strip here: no partition may stand under them.
            crossed = any(b.along == "x" and b.rect.overlaps(rect) for b in plan.beams)
            out.append(_Section(side, tuple(range(start, j)), rect, west_wall, crossed))  # type: ignore[arg-type]
            start = j
    return out


def _split_strip(
    rng: np.random.Generator, a: float, b: float, *, wall: float, target: tuple[float, float],
    lines: Sequence[tuple[float, float]],
) -> list[float] | None:
    """Centre lines of partitions splitting the clear interval [a, b] into rooms.

    Every room's clear length lies in ``ROOM_M``. ``lines`` are (X, clearance) of grid and beam
    lines: a partition lies on one (a column or beam then stands in the wall, as in real plans)
    or keeps its clearance from it. None when no split satisfies this.
    """
    lo, hi = ROOM_M
    length = b - a
    n_min = max(1, math.ceil((length + wall) / (hi + wall) - 1e-9))
    n_max = max(n_min, math.floor((length + wall) / (lo + wall) + 1e-9))
    for attempt in range(40):
        n = int(np.clip(round(length / rng.uniform(*target)), n_min, n_max))
        if attempt >= 20:
            n = int(rng.integers(n_min, n_max + 1))
        if n == 1:
            return [] if length <= hi else None
        clear = lo + (length - n * lo - (n - 1) * wall) * rng.dirichlet(np.full(n, 5.0))
        cuts = list(a + np.cumsum(clear[:-1] + wall) - wall / 2)
        snapped = []
        for x in cuts:
            near = min(lines, key=lambda g: abs(g[0] - x), default=None)
            if near is not None and abs(near[0] - x) < max(0.35, near[1]):
                x = near[0]
            snapped.append(_r(x))
        if _partitions_fit(snapped, a, b, wall, lines):
            return snapped
    return None


def _partitions_fit(cuts: list[float], a: float, b: float, wall: float, lines: Sequence[tuple[float, float]]) -> bool:
    lo, hi = ROOM_M
    edges = [a - wall / 2, *cuts, b + wall / 2]
    if not all(lo - 1e-9 <= q - p - wall <= hi + 1e-9 for p, q in zip(edges, edges[1:])):
        return False
    return all(abs(x - g) < 1e-9 or abs(x - g) >= c for x in cuts for g, c in lines)


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


def subtract_rects(rect: Rect, holes: Sequence[Rect]) -> list[Rect]:
    """``rect`` less ``holes``, as few axis-aligned rectangles (row strips merged where equal)."""
    cut = [h for h in (rect.intersection(h) for h in holes) if h is not None]
    if not cut:
        return [rect]
    xs = sorted({rect.x0, rect.x1, *(h.x0 for h in cut), *(h.x1 for h in cut)})
    ys = sorted({rect.y0, rect.y1, *(h.y0 for h in cut), *(h.y1 for h in cut)})
    strips: list[tuple[float, float, list[tuple[float, float]]]] = []
    for y0, y1 in zip(ys, ys[1:]):
        spans: list[tuple[float, float]] = []
        for x0, x1 in zip(xs, xs[1:]):
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            if any(h.x0 < cx < h.x1 and h.y0 < cy < h.y1 for h in cut):
                continue
            if spans and abs(spans[-1][1] - x0) < 1e-12:
                spans[-1] = (spans[-1][0], x1)
            else:
                spans.append((x0, x1))
        if strips and strips[-1][2] == spans and abs(strips[-1][1] - y0) < 1e-12:
            strips[-1] = (strips[-1][0], y1, spans)
        else:
            strips.append((y0, y1, spans))
    return [Rect(x0, y0, x1, y1) for y0, y1, spans in strips for x0, x1 in spans if x1 - x0 > 1e-6 and y1 - y0 > 1e-6]


@dataclass
class _StoreyDraft:
    """A storey being planned: what the steps of ``_plan_storey`` add, in order."""

    plan: BuildingPlan
    table: BuildingStyle
    index: int
    rng: np.random.Generator
    rooms: list[RoomPlan] = field(default_factory=list)
    strip_rooms: list[tuple[RoomPlan, Side]] = field(default_factory=list)  # rooms that get a corridor door
    open_areas: set[str] = field(default_factory=set)
    inner_walls: list[tuple[str, tuple[float, float], tuple[float, float], float]] = field(default_factory=list)
    openings: dict[str, list[OpeningPlan]] = field(default_factory=dict)  # per wall name, in the wall's frame
    hall_above: Rect | None = None  # the hall of the storey below, open through this storey (no room, windows)
    _rooms_made: int = 0
    _openings_made: int = 0

    def room(self, kind: RoomKind, rect: Rect, ceiling: bool, *, height_m: float | None = None) -> RoomPlan:
        self._rooms_made += 1
        height = height_m if height_m is not None else self.plan.ceiling_height_m if ceiling else self.plan.soffit_m
        made = RoomPlan(f"{self.index}.{self._rooms_made:02d}", kind,
                        Rect(_r(rect.x0), _r(rect.y0), _r(rect.x1), _r(rect.y1)), ceiling, _r(height))
        self.rooms.append(made)
        return made

    def opening(self, wall: str, kind: OpeningKind, at: float, width: float, sill: float, height: float) -> None:
        name = f"{kind} {self.index}.{self._openings_made:02d}"  # unique on the storey
        self._openings_made += 1
        self.openings.setdefault(wall, []).append(OpeningPlan(kind, _r(at), _r(width), _r(sill), _r(height), name))

    def structure_zones(self, band: Rect, along_x: bool) -> list[tuple[float, float]]:
        """Intervals along a wall (world X or Y) where a column or beam meets it, with a margin."""
        out = []
        for s in [*self.plan.columns, *(b.rect for b in self.plan.beams)]:
            if s.overlaps(band, margin_m=0.02):
                out.append((s.x0 - WINDOW_MARGIN_M, s.x1 + WINDOW_MARGIN_M) if along_x
                           else (s.y0 - WINDOW_MARGIN_M, s.y1 + WINDOW_MARGIN_M))
        return out


def _plan_storey(plan: BuildingPlan, table: BuildingStyle, *, index: int, rng: np.random.Generator) -> StoreyPlan:
    """Rooms, walls with openings, ceilings and furniture of storey ``index``."""
    draft = _StoreyDraft(plan, table, index, rng)
    corridor = _add_rooms(draft)
    _add_doors(draft)
    exterior = _exterior_walls(plan.outline_m, plan.exterior_wall_m, plan.soffit_m)
    _add_windows(draft, exterior, corridor)
    walls = _finish_walls(draft, exterior)
    ceilings = _plan_ceilings(plan, draft.rooms, index=index)
    furniture = _plan_furniture(plan, draft.rooms, walls, index=index, rng=rng) if table.furniture else []
    return StoreyPlan(
        index=index,
        elevation_m=_r(index * plan.storey_height_m),
        rooms=tuple(draft.rooms),
        walls=tuple(walls),
        ceilings=tuple(ceilings),
        furniture=tuple(furniture),
    )


def _add_rooms(draft: _StoreyDraft) -> RoomPlan:
    """The corridor, stairwell and store, and every section's rooms or open-plan area, with the
    walls between them; returns the corridor."""
    plan, table, rng = draft.plan, draft.table, draft.rng
    e, tc, tp = plan.exterior_wall_m, plan.corridor_wall_m, plan.partition_m
    ca, cb = plan.corridor_y_m
    stair = plan.stair
    hc, hb = plan.column_m / 2, plan.beam_width_m / 2
    # Lines a partition must sit on or keep clear of: grid lines (columns) and beam lines.
    clearances: dict[float, float] = {}
    for x, c in [*((x, hc) for x in (plan.grid_x_m if plan.columns else ())),
                 *((b.rect.centre[0], hb) for b in plan.beams if b.along == "y")]:
        clearances[_r(x)] = max(clearances.get(_r(x), 0.0), c + tp / 2 + 0.05)
    snap = sorted(clearances.items())

    covered = plan.ceiling_system != "exposed"
    corridor = draft.room("corridor", Rect(e, ca + tc / 2, plan.width_m - e, cb - tc / 2), covered)
    if stair is not None:
        x_core = stair.wall_x_m - plan.core_wall_m / 2
        well_y1 = plan.bay_north_m[0] if stair.store_wall_y_m is None else stair.store_wall_y_m - tp / 2
        draft.room("stairwell", Rect(e, cb + tc / 2, x_core, well_y1), False)
        if stair.store_wall_y_m is not None:
            store = Rect(e, stair.store_wall_y_m + tp / 2, x_core, plan.bay_north_m[0])
            draft.strip_rooms.append((draft.room("store", store, covered and rng.random() >= STORE_EXPOSED_ODDS),
                                      "north"))
            draft.inner_walls.append(("stair north", (e, stair.store_wall_y_m), (x_core, stair.store_wall_y_m), tp))
        draft.inner_walls.append(("stair core", (stair.wall_x_m, cb + tc / 2), (stair.wall_x_m, plan.bay_north_m[0]),
                                  plan.core_wall_m))

    for section in _sections(plan):
        rect = section.rect
        if section.west_wall is not None:
            x, t, ya, yb = section.west_wall
            draft.inner_walls.append((f"section {section.side} {section.bays[0]}", (x, min(ya, yb)),
                                      (x, max(ya, yb)), t))
        hall = plan.hall
        if hall is not None and rect == hall.rect and draft.index in (hall.storey, hall.storey + 1):
            if draft.index == hall.storey:  # one room, no ceiling, up to the slab over the storey above
                made = draft.room("hall", rect, False, height_m=_r(plan.storey_height_m + plan.soffit_m))
                draft.open_areas.add(made.number)
                draft.strip_rooms.append((made, section.side))
            else:
                draft.hall_above = rect
            continue
        cuts: list[float] | None = None
        if rect.depth <= ROOM_M[1] + 1e-9 and not section.crossed and rng.random() >= table.open_plan_odds:
            inside = [(x, c) for x, c in snap if rect.x0 < x < rect.x1]
            cuts = _split_strip(rng, rect.x0, rect.x1, wall=tp, target=table.room_m, lines=inside)
        if cuts is None:
            area = draft.room("open-plan", rect, covered and rng.random() >= table.exposed_room_odds)
            draft.open_areas.add(area.number)
            draft.strip_rooms.append((area, section.side))
            continue
        edges = [rect.x0 - tp / 2, *cuts, rect.x1 + tp / 2]
        for i, x in enumerate(cuts):
            draft.inner_walls.append((f"partition {section.side} {section.bays[0]}.{i}", (x, rect.y0),
                                      (x, rect.y1), tp))
        for a, b in zip(edges, edges[1:]):
            made = draft.room(table.room_kind, Rect(a + tp / 2, rect.y0, b - tp / 2, rect.y1),
                              covered and rng.random() >= table.exposed_room_odds)
            draft.strip_rooms.append((made, section.side))
    return corridor


def _add_doors(draft: _StoreyDraft) -> None:
    """A corridor door for every strip room (one per OPEN_PLAN_DOOR_EVERY_M of an open-plan
    area's frontage), clear of columns and beam ends; stairwell and store doors."""
    plan, rng = draft.plan, draft.rng
    e, tc = plan.exterior_wall_m, plan.corridor_wall_m
    ca, cb = plan.corridor_y_m
    corridor_walls = {"south": ("corridor south", ca), "north": ("corridor north", cb)}
    for made, side in draft.strip_rooms:
        if made.kind == "store":
            continue
        wall_name, y = corridor_walls[side]
        band = Rect(e, y - tc / 2, plan.width_m - e, y + tc / 2)
        count = max(1, round(made.rect.width / OPEN_PLAN_DOOR_EVERY_M)) if made.number in draft.open_areas else 1
        for part in range(count):
            lo = made.rect.x0 + made.rect.width * part / count
            hi = made.rect.x0 + made.rect.width * (part + 1) / count
            x = _door_spot(rng, lo + 0.1, hi - 0.1, draft.structure_zones(band, True),
                           [c for c in plan.columns if c.overlaps(band)])
            draft.opening(wall_name, "door", x - e, DOOR_WIDTH_M, 0.0, DOOR_HEIGHT_M)
    if plan.stair is not None:
        # Stairwell and store doors open onto the entry zone in front of the first riser.
        x_door = plan.grid_x_m[0] + plan.column_m / 2 + 0.15
        draft.opening("corridor north", "door", x_door - e, DOOR_WIDTH_M, 0.0, DOOR_HEIGHT_M)
        if plan.stair.store_wall_y_m is not None:
            draft.opening("stair north", "door", 0.15, DOOR_WIDTH_M, 0.0, DOOR_HEIGHT_M)


def _add_windows(draft: _StoreyDraft, exterior: list[WallPlan], corridor: RoomPlan) -> None:
    """Windows in every facade stretch a room (not the stairwell) lies against, clear of columns
    and beam ends; the entrance door at the corridor's east end on the ground floor."""
    plan, table, rng = draft.plan, draft.table, draft.rng
    ca, cb = plan.corridor_y_m
    sill = _cm(_draw(rng, table.window_sill_m))
    head = math.floor(min(table.window_head_m, plan.ceiling_height_m - WALL_ABOVE_OPENING_M) * 100 + 1e-6) / 100
    band_windows = plan.window_style == "band"
    # the rooms, and the hall of the storey below where it rises through this one (its upper windows)
    lit = [(made.rect, made is corridor) for made in draft.rooms if made.kind != "stairwell"]
    if draft.hall_above is not None:
        lit.append((draft.hall_above, False))
    for wall in exterior:
        fp = wall.footprint
        along_x = wall.along_x
        for r, is_corridor in lit:
            if along_x:
                touching = abs(r.y0 - fp.y1) < 1e-6 or abs(r.y1 - fp.y0) < 1e-6
                lo, hi = max(r.x0, fp.x0), min(r.x1, fp.x1)
            else:
                touching = abs(r.x0 - fp.x1) < 1e-6 or abs(r.x1 - fp.x0) < 1e-6
                lo, hi = max(r.y0, fp.y0), min(r.y1, fp.y1)
            if not touching or hi - lo < 0.5:
                continue
            start = wall.start[0] if along_x else wall.start[1]
            if is_corridor and not along_x and wall.start[0] > plan.width_m / 2 and draft.index == 0:
                mid = (ca + cb) / 2
                draft.opening(wall.name, "door", mid - ENTRANCE_WIDTH_M / 2 - start, ENTRANCE_WIDTH_M, 0.0,
                              ENTRANCE_HEIGHT_M)
                continue
            blocked = draft.structure_zones(fp, along_x)
            for a, b in _free_intervals(lo + WINDOW_MARGIN_M, hi - WINDOW_MARGIN_M, blocked):
                for at, width in _window_spans(rng, a, b, band=band_windows, widths=table.window_m):
                    draft.opening(wall.name, "window", at - start, width, sill, head - sill)


def _finish_walls(draft: _StoreyDraft, exterior: list[WallPlan]) -> list[WallPlan]:
    """Every wall of the storey with its openings; interior walls stop under beams they run along."""
    plan, openings = draft.plan, draft.openings
    e, tc = plan.exterior_wall_m, plan.corridor_wall_m
    w = plan.width_m
    walls = [replace(wall, openings=tuple(sorted(openings.get(wall.name, []), key=lambda o: o.offset_m)))
             for wall in exterior]
    # Corridor walls under beams along X are built bay by bay (the pieces meet inside the
    # columns), so each piece stops under its own beam or, where there is none, at the slab.
    breaks = [e, *plan.grid_x_m[1:-1], w - e] if any(b.along == "x" for b in plan.beams) else [e, w - e]
    inner = []
    for name, y in (("corridor south", plan.corridor_y_m[0]), ("corridor north", plan.corridor_y_m[1])):
        pieces = list(zip(breaks, breaks[1:]))
        if len(pieces) == 1:
            inner.append((name, (e, y), (w - e, y), tc))
            continue
        for k, (a, b) in enumerate(pieces):
            inner.append((f"{name} {k}", (a, y), (b, y), tc))
        for o in openings.pop(name, []):  # doors keep clear of the columns where pieces meet
            x = e + o.offset_m
            k = next(i for i, (a, b) in enumerate(pieces) if a - EPS <= x and x + o.width_m <= b + EPS)
            openings.setdefault(f"{name} {k}", []).append(replace(o, offset_m=_r(x - pieces[k][0])))
    inner += draft.inner_walls
    for name, start, end, t in inner:
        start, end = (_r(start[0]), _r(start[1])), (_r(end[0]), _r(end[1]))
        made = WallPlan(name, start, end, t, plan.soffit_m, False,
                        tuple(sorted(openings.get(name, []), key=lambda o: o.offset_m)))
        walls.append(replace(made, height_m=_wall_height(plan, made)))
    return [wall for wall in walls if wall.length_m > 1e-6]


def _door_spot(
    rng: np.random.Generator, lo: float, hi: float, blocked: list[tuple[float, float]], columns: list[Rect]
) -> float:
    """Near edge (world coordinate along the wall) of a door in [lo, hi], clear of columns and,
    where there is room, of beam ends."""
    column_zones = [(c.x0 - 0.1, c.x1 + 0.1) for c in columns]
    column_faces = [(c.x0, c.x1) for c in columns]  # a narrow room: the door may touch the column
    for zones in (blocked, column_zones, column_faces):
        free = [(a, b) for a, b in _free_intervals(lo, hi, zones) if b - a >= DOOR_WIDTH_M]
        if free:
            a, b = free[int(rng.integers(len(free)))]
            return a + rng.uniform(0.0, b - a - DOOR_WIDTH_M)
    return (lo + hi) / 2 - DOOR_WIDTH_M / 2  # rooms are wider than any column zone leaves; never reached


def _window_spans(
    rng: np.random.Generator, a: float, b: float, *, band: bool, widths: tuple[float, float]
) -> list[tuple[float, float]]:
    """(near edge, width) of the windows in the free wall stretch [a, b]: one punched window in
    the middle, or a band of equal windows filling it, separated by narrow piers."""
    step = OPENING_STEP_M
    if band:
        if b - a < 0.8:
            return []
        k = math.ceil((b - a + BAND_PIER_M) / (BAND_WINDOW_M + BAND_PIER_M))
        pane = math.floor(((b - a - (k - 1) * BAND_PIER_M) / k) / step + 1e-9) * step
        if pane < 0.6:
            return []
        total = k * pane + (k - 1) * BAND_PIER_M
        first = (a + b) / 2 - total / 2
        return [(first + i * (pane + BAND_PIER_M), pane) for i in range(k)]
    if b - a < 1.0:
        return []
    width = math.floor(min(b - a, rng.uniform(*widths)) / step + 1e-9) * step
    return [((a + b) / 2 - width / 2, width)]


def _wall_height(plan: BuildingPlan, wall: WallPlan) -> float:
    """The slab's underside, or the underside of a beam running along the wall above it."""
    fp = wall.footprint
    for beam in plan.beams:
        along = (beam.along == "x") == wall.along_x
        if along and beam.rect.overlaps(fp) and (beam.rect.intersection(fp) or fp).area > 1e-4:
            return plan.beam_bottom_m
    return plan.soffit_m


def _plan_ceilings(plan: BuildingPlan, rooms: list[RoomPlan], *, index: int) -> list[CeilingPlan]:
    """Coverings of the rooms that have one, cut around columns and around beams that hang below
    them (downstand system), at the building's ceiling height."""
    if plan.ceiling_system == "exposed":
        return []
    visible = [b.rect for b in plan.beams] if plan.beam_bottom_m < plan.ceiling_height_m else []
    out = []
    for made in rooms:
        if not made.has_ceiling:
            continue
        rects = subtract_rects(made.rect, [*plan.columns, *visible])
        rects = [Rect(_r(r.x0), _r(r.y0), _r(r.x1), _r(r.y1)) for r in rects]
        rects = [r for r in rects if r.width > 1e-6 and r.depth > 1e-6]
        if rects:
            out.append(CeilingPlan(f"Ceiling {made.number}", made.number, tuple(rects), plan.ceiling_height_m,
                                   plan.ceiling_thickness_m))
    return out


def _door_zones(walls: Sequence[WallPlan]) -> list[Rect]:
    """Plan areas in front of and behind every door, kept free of furniture."""
    zones = []
    for wall in walls:
        (x0, y0) = wall.start
        for o in wall.openings:
            if o.kind != "door":
                continue
            a, b = o.offset_m - 0.1, o.offset_m + o.width_m + 0.1
            if wall.along_x:
                zones.append(Rect(x0 + a, y0 - 1.1, x0 + b, y0 + 1.1))
            else:
                zones.append(Rect(x0 - 1.1, y0 + a, x0 + 1.1, y0 + b))
    return zones


def _window_zones(walls: Sequence[WallPlan]) -> list[Rect]:
    """Plan areas in front of windows, where tall furniture would block the glass."""
    zones = []
    for wall in walls:
        (x0, y0) = wall.start
        for o in wall.openings:
            if o.kind != "window":
                continue
            a, b = o.offset_m, o.offset_m + o.width_m
            if wall.along_x:
                zones.append(Rect(x0 + a, y0 - 0.8, x0 + b, y0 + 0.8))
            else:
                zones.append(Rect(x0 - 0.8, y0 + a, x0 + 0.8, y0 + b))
    return zones


def _plan_furniture(
    plan: BuildingPlan, rooms: list[RoomPlan], walls: Sequence[WallPlan], *, index: int, rng: np.random.Generator
) -> list[FurniturePlan]:
    """Seeded tables, cabinets and shelves in offices, rooms, stores and open-plan areas, clear of
    columns, doors and windows.

    Every room keeps a free square of 1.2 m around its centre, where a scan station can stand.
    """
    columns = [Rect(r.x0 - 0.05, r.y0 - 0.05, r.x1 + 0.05, r.y1 + 0.05) for r in plan.columns]
    doors, windows = _door_zones(walls), _window_zones(walls)
    out: list[FurniturePlan] = []
    for room in rooms:
        if room.kind not in ("office", "room", "store", "open-plan"):
            continue
        r = room.rect
        cx, cy = r.centre
        near = [o for o in (*columns, *doors) if o.overlaps(r)]
        keep_free = [Rect(cx - 0.6, cy - 0.6, cx + 0.6, cy + 0.6), *near]
        glass = [o for o in windows if o.overlaps(r)]
        placed: list[Rect] = []

        def fits(rect: Rect, tall: bool) -> bool:
            if not r.contains(rect):
                return False
            if any(rect.overlaps(o) for o in keep_free) or any(rect.overlaps(o, margin_m=0.05) for o in placed):
                return False
            return not (tall and any(rect.overlaps(o) for o in glass))

        # Tables with 0.6 m to walk around them, where the room is big enough: one per room,
        # about one per 12 m2 of an open-plan area.
        tables = 1 if room.kind != "open-plan" else int(np.clip(r.area // 12, 1, 8))
        for _ in range(tables):
            long_x = r.width >= r.depth
            a, b = float(rng.uniform(1.2, 1.8)), float(rng.uniform(0.7, 0.9))
            sx, sy = (a, b) if long_x else (b, a)
            if not (r.width - 1.2 > sx and r.depth - 1.2 > sy):
                break
            for _ in range(40):
                x = rng.uniform(r.x0 + 0.6, r.x1 - 0.6 - sx)
                y = rng.uniform(r.y0 + 0.6, r.y1 - 0.6 - sy)
                rect = Rect(_r(x), _r(y), _r(x + sx), _r(y + sy))
                if fits(rect, tall=False) and not any(rect.overlaps(o, margin_m=0.6) for o in placed):
                    placed.append(rect)
                    facing = (0, -1) if long_x else (-1, 0)
                    out.append(FurniturePlan("table", rect, 0.74, facing, f"table {index}.{len(out)}"))
                    break
        pieces = int(rng.integers(1, 4)) * (1 if room.kind != "open-plan" else 2)
        for _ in range(pieces):
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
                if fits(rect, tall=height > 0.8):  # window sills are at 0.8 m or more
                    placed.append(rect)
                    out.append(FurniturePlan(kind, rect, _r(height), facing, f"{kind} {index}.{len(out)}"))
                    break
    return out

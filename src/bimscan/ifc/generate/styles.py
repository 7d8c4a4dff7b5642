"""Every number a generated building is drawn from, in one place: fixed dimensions and the style table.

A *style* (``office``, ``residential``, ``site``) is a row of ``STYLES``: ranges that plan
dimensions are drawn from (uniformly, metres) and the odds of building-wide choices (footprint
shape, ceiling system, window type, where perimeter columns stand). ``floor_plan.plan_building``
draws from the row; nothing else in the generator holds a dimension.

Sources of the ranges (docs/guide/generated-buildings.md has the table):

* Rooms, ceilings, beams of ``office``: measured on the real S3DIS Area 6 rooms
  (``../shared/data/real/s3dis_area6``): offices about 5.8 x 2.9 m and 3.7-3.8 x 2.7-3.3 m,
  hallways 2.1 m wide, ceiling 2.57-2.78 m above the floor, downstand beams in 10 of 12 rooms
  hanging 0.5-0.6 m below the ceiling to 2.15-2.22 m above the floor, columns in 7 rooms, mostly
  embedded in walls.
* Storey heights: offices are commonly built 3.0-4.0 m floor to floor (a 2.5-3.2 m clear height
  plus ceiling void and slab), homes 2.6-3.0 m (2.4-2.7 m rooms); both within the 2.6-4 m the
  issue asks for.
* Gable roofs of ``residential``: pitches of 30-45 degrees, knee walls (the facade carried on
  above the attic floor to the eaves) of 0.5-1.2 m and roofs 0.2-0.3 m thick (rafters,
  insulation, boarding) are usual for pitched-roof houses in Central Europe, e.g. the
  two-storey AC20-FZK-Haus sample (a 30-degree gable over an attic storey).
* Doors 0.9 x 2.1 m, stairs with 0.28 m goings and risers near 0.17 m, slabs 0.16-0.35 m, walls
  0.1-0.45 m thick, column grids 5-8 m: common building practice.
* Interior walls 0.1-0.3 m between their faces: drywall partitions (a 50-100 mm metal stud and
  one or two 12.5 mm boards a face) are 0.1-0.15 m; masonry ones are a unit of 115, 175 or 240 mm
  (the DIN 4172 widths) and 10-15 mm of plaster a face, 0.14-0.27 m, the load-bearing ones the
  thicker (the AC20-FZK-Haus's interior walls measure about 0.25 m on its scan).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

MIN_STOREYS = 1
MAX_STOREYS = 10
# Bumped whenever the same options make a different building: dataset builds record it and make
# their generated scenes again when it changed (2: attics under gable roofs; 3: interior walls up to 0.3 m thick;
# 4: double-height halls).
GENERATOR_VERSION = 4

# -- fixed dimensions (metres) -------------------------------------------------------------

HALL_MIN_M2 = 20.0  # a double-height hall's floor area at least (an entrance hall, an atrium, a gallery)
STAIR_GOING_M = 0.28  # tread depth; risers follow from the storey height
STAIR_RISER_M = 0.17  # target riser height
STAIR_GAP_M = 0.1  # gap between the two flights of the half-turn stair
STAIR_WIDTH_M = 1.2  # flight width where the stairwell is deep enough to hold a store behind it
LANDING_DEPTH_M = 0.2
DOOR_WIDTH_M = 0.9
DOOR_HEIGHT_M = 2.1
ENTRANCE_WIDTH_M = 1.0
ENTRANCE_HEIGHT_M = 2.2
FINISH_CEILING_M = 0.025  # a board or plaster ceiling fixed directly under the slab
SUSPENDED_CEILING_M = 0.02  # ceiling tiles hung below the slab
ROOM_M = (2.5, 8.0)  # clear side lengths of every office and room (open-plan areas, corridors excepted)
MAX_SPAN_M = 7.5  # longest column-to-column span; deeper strips get a row of free-standing columns
WINDOW_MARGIN_M = 0.15  # wall kept beside the room's corners and any column or beam end
BAND_PIER_M = 0.15  # wall between the windows of a window band
BAND_WINDOW_M = 5.4  # widest window of a band (three panels)
WINDOW_PANEL_M = 1.8  # widest panel of a window; wider windows get mullions (up to three panels)
OPENING_STEP_M = 0.05  # window widths are multiples of this (so windows repeat, as catalogue sizes do)
WALL_ABOVE_OPENING_M = 0.25  # least wall (lintel) over the top of any window
OPEN_PLAN_DOOR_EVERY_M = 8.0  # an open-plan area gets a corridor door per this much frontage
FINISH_ODDS = 0.5  # downstand ceilings: a finish directly under the slab (else tiles in a void, plenum_m)
SERVICE_VOID_M = (0.1, 0.3)  # suspended ceilings: void between the beams' underside and the tiles
STORE_EXPOSED_ODDS = 0.5  # a store room has no ceiling covering (when the building has them)

StyleName = Literal["office", "residential", "site"]
# downstand: ceiling coverings fill the bays between downstand beams that stay in view (with no
#   beams: a finish layer under a flat slab); suspended: a suspended ceiling hides the beams above
#   it; exposed: no coverings, slab soffits and beams in view.
CeilingSystem = Literal["downstand", "suspended", "exposed"]
Shape = Literal["rectangle", "L", "U", "T", "notch"]
WindowStyle = Literal["punched", "band"]
# flat: a flat roof slab over the top storey; gable: an attic over the top storey's slab, under a
#   roof pitched from the long facades up to a ridge along the building (rectangular footprints
#   only: other shapes get flat roofs), closed by gable walls at both ends.
RoofKind = Literal["flat", "gable"]
# against: perimeter columns stand inside the facade, touching it; embedded: half inside the
# facade wall; setback: free-standing a little way in from the facade.
ColumnSetting = Literal["against", "embedded", "setback"]
RoomKind = Literal["office", "room", "open-plan", "hall", "corridor", "stairwell", "store"]
Range = tuple[float, float]


@dataclass(frozen=True)
class BuildingStyle:
    """What one style draws its buildings from.

    Ranges are (low, high) in metres, drawn uniformly; ``*_odds`` are probabilities; the
    dictionaries are relative weights of building-wide choices. A style without columns
    (``column_m == ()``) has load-bearing walls: no columns, no beams.
    """

    storey_height_m: Range  # floor to floor
    ceiling_height_m: Range  # floor to the ceiling surface (the covering, or the slab where exposed)
    slab_m: Range
    exterior_wall_m: Range
    corridor_wall_m: Range  # the two walls along the corridor (often load-bearing, thicker)
    partition_m: Range  # walls between rooms
    corridor_m: Range  # clear width
    strip_m: Range  # clear depth of the rooms on each side of the corridor
    wing_m: Range  # clear depth of a wing (L, U, T footprints)
    notch_m: Range  # how much shallower a notched bay is than the rest of its side
    room_m: Range  # target room length along the corridor
    bay_m: Range  # column grid spacing along the building
    bays: tuple[int, int]  # number of bays besides the stair bay (inclusive)
    column_m: tuple[float, ...]  # square column sizes to pick from
    beam_width_m: Range
    beam_depth_m: Range  # slab underside to beam bottom, where beams are exposed or hidden
    downstand_m: Range  # ceiling surface to beam bottom, where ceilings fill between beams
    plenum_m: Range  # slab underside to ceiling between downstand beams (0 half the time: a finish)
    min_beam_bottom_m: float  # beams keep this much headroom
    setback_m: Range  # facade inner face to the face of setback columns
    window_sill_m: Range
    window_head_m: float  # highest window head (lower where the ceiling is low)
    window_m: Range  # punched window width
    ceilings: dict[CeilingSystem, float]
    roofs: dict[RoofKind, float]
    roof_pitch_deg: tuple[float, float]  # gable roofs: slope of both roof planes, degrees
    knee_wall_m: Range  # gable roofs: attic floor to the roof's underside at the facades' outer faces
    roof_m: Range  # gable roofs: thickness across the roof plane
    shapes: dict[Shape, float]
    windows: dict[WindowStyle, float]
    column_settings: dict[ColumnSetting, float]
    open_plan_odds: float  # a side section of a storey is one open-plan area instead of rooms
    hall_odds: float  # a building of two or more storeys has a double-height hall (one side section, two storeys)
    exposed_room_odds: float  # an office or room has no ceiling covering (when the building has them)
    secondary_beam_odds: float  # beams also run at the middle of every bay
    corridor_beam_odds: float  # beams cross the corridor (else its ceiling is flat)
    x_beams: bool  # beams also run along the building, on the corridor and free-standing rows
    furniture: bool
    room_kind: RoomKind  # what its ordinary rooms are called


STYLES: dict[str, BuildingStyle] = {
    # Cellular offices off a corridor, like the S3DIS Area 6 floor: suspended or finished
    # ceilings between visible downstand beams in most buildings, columns in the walls.
    "office": BuildingStyle(
        storey_height_m=(2.8, 4.0),
        ceiling_height_m=(2.5, 3.2),
        slab_m=(0.2, 0.3),
        exterior_wall_m=(0.25, 0.4),
        corridor_wall_m=(0.12, 0.3),
        partition_m=(0.1, 0.25),
        corridor_m=(1.6, 2.4),
        strip_m=(3.0, 6.5),
        wing_m=(7.0, 12.0),
        notch_m=(1.0, 2.5),
        room_m=(2.8, 6.0),
        bay_m=(5.0, 7.5),
        bays=(2, 3),
        column_m=(0.3, 0.4, 0.5),
        beam_width_m=(0.25, 0.4),
        beam_depth_m=(0.4, 0.6),
        downstand_m=(0.3, 0.6),
        plenum_m=(0.1, 0.3),
        min_beam_bottom_m=2.15,
        setback_m=(0.6, 1.2),
        window_sill_m=(0.8, 1.0),
        window_head_m=2.4,
        window_m=(1.2, 2.2),
        ceilings={"downstand": 0.7, "suspended": 0.15, "exposed": 0.15},
        roofs={"flat": 1.0},
        roof_pitch_deg=(0.0, 0.0),
        knee_wall_m=(0.0, 0.0),
        roof_m=(0.0, 0.0),
        shapes={"rectangle": 0.3, "L": 0.2, "U": 0.15, "T": 0.15, "notch": 0.2},
        windows={"band": 0.5, "punched": 0.5},
        column_settings={"embedded": 0.45, "against": 0.35, "setback": 0.2},
        open_plan_odds=0.2,
        hall_odds=0.4,
        exposed_room_odds=0.05,
        secondary_beam_odds=0.6,
        corridor_beam_odds=0.3,
        x_beams=False,
        furniture=True,
        room_kind="office",
    ),
    # Flats off a central hallway: smaller rooms, lower storeys, load-bearing walls (no column
    # grid, no beams), finished or bare slab ceilings, punched windows; most rectangular ones
    # under a gable roof with an attic.
    "residential": BuildingStyle(
        storey_height_m=(2.6, 3.0),
        ceiling_height_m=(2.4, 2.75),
        slab_m=(0.16, 0.22),
        exterior_wall_m=(0.3, 0.45),
        corridor_wall_m=(0.15, 0.3),
        partition_m=(0.1, 0.27),
        corridor_m=(1.1, 1.5),
        strip_m=(3.0, 5.0),
        wing_m=(5.5, 7.5),
        notch_m=(0.8, 1.5),
        room_m=(2.6, 4.5),
        bay_m=(4.0, 6.0),
        bays=(2, 3),
        column_m=(),
        beam_width_m=(0.0, 0.0),
        beam_depth_m=(0.0, 0.0),
        downstand_m=(0.0, 0.0),
        plenum_m=(0.0, 0.0),
        min_beam_bottom_m=2.15,
        setback_m=(0.0, 0.0),
        window_sill_m=(0.85, 1.0),
        window_head_m=2.2,
        window_m=(1.0, 1.6),
        ceilings={"downstand": 0.6, "exposed": 0.4},
        roofs={"flat": 0.3, "gable": 0.7},
        roof_pitch_deg=(30.0, 45.0),
        knee_wall_m=(0.5, 1.2),
        roof_m=(0.2, 0.3),
        shapes={"rectangle": 0.4, "L": 0.25, "notch": 0.2, "T": 0.15},
        windows={"punched": 1.0},
        column_settings={"against": 1.0},
        open_plan_odds=0.1,
        hall_odds=0.2,
        exposed_room_odds=0.0,
        secondary_beam_odds=0.0,
        corridor_beam_odds=0.0,
        x_beams=False,
        furniture=True,
        room_kind="room",
    ),
    # A structural frame as on a building site: bare slabs, a column grid with beams both
    # ways, large open areas, no ceilings or furniture.
    "site": BuildingStyle(
        storey_height_m=(3.0, 4.0),
        ceiling_height_m=(2.8, 3.7),
        slab_m=(0.25, 0.35),
        exterior_wall_m=(0.25, 0.35),
        corridor_wall_m=(0.15, 0.3),
        partition_m=(0.1, 0.25),
        corridor_m=(2.0, 3.0),
        strip_m=(4.5, 7.5),
        wing_m=(9.0, 14.0),
        notch_m=(1.5, 3.0),
        room_m=(4.0, 7.5),
        bay_m=(6.0, 8.0),
        bays=(2, 3),
        column_m=(0.4, 0.5, 0.6),
        beam_width_m=(0.3, 0.45),
        beam_depth_m=(0.5, 0.8),
        downstand_m=(0.0, 0.0),
        plenum_m=(0.0, 0.0),
        min_beam_bottom_m=2.4,
        setback_m=(0.8, 1.5),
        window_sill_m=(0.9, 1.0),
        window_head_m=2.3,
        window_m=(1.5, 2.5),
        ceilings={"exposed": 1.0},
        roofs={"flat": 1.0},
        roof_pitch_deg=(0.0, 0.0),
        knee_wall_m=(0.0, 0.0),
        roof_m=(0.0, 0.0),
        shapes={"rectangle": 0.3, "L": 0.25, "U": 0.15, "T": 0.15, "notch": 0.15},
        windows={"band": 0.5, "punched": 0.5},
        column_settings={"setback": 0.5, "against": 0.3, "embedded": 0.2},
        open_plan_odds=0.7,
        hall_odds=0.4,
        exposed_room_odds=1.0,
        secondary_beam_odds=0.3,
        corridor_beam_odds=1.0,
        x_beams=True,
        furniture=False,
        room_kind="room",
    ),
}

# Random streams are keyed by style: the same seed in another style is another building.
STYLE_KEYS: dict[str, int] = {"office": 0, "residential": 1, "site": 2}
DEFAULT_STYLE = "office"

"""Where a tripod can stand: level floor surfaces found in the model's geometry.

Storeys and spaces say where floors should be; real exports do not always have them (structural
models without spaces, storeys without floor slabs, split levels, basements, roofs as slabs), so
the surfaces themselves decide. Vertical probes on a grid over the model meet every surface along
their line (``Prober.surfaces_below``); a *tripod spot* is a point on one of them where a surveyor
could set a tripod up:

- the surface is nearly horizontal (tilt at most ``MAX_TILT_DEG``) and belongs to an element a
  tripod stands on: a slab, a floor covering, a ramp, a plate, a footing, a stair (its landings),
  a roof; or any element but furniture and fittings where it lies at the floor of an IfcSpace
  (the space says a floor is there); a model with none of these (every floor exported as a
  proxy, say) takes any element but furniture and fittings, and so does a model where nothing
  else gives a spot (precast floor units exported as beams, say). Where a room (an IfcSpace) has no
  such surface anywhere at its floor (storeys exported without their slabs), the tripod stands
  on the room's own floor: the bottom of the space;
- the three feet of the tripod, ``LEG_RADIUS_M`` out, rest on it level within ``LEG_LEVEL_M``
  (stair treads, beam tops and slab edges fail);
- there is headroom for the instrument and a margin (``HEADROOM_MARGIN_M``) above it, or open sky;
- a circle of ``clearance_m`` around the tripod is free at three heights (this also rejects
  points inside solids: their own faces are close all round);
- seen from the instrument, most of the steep downward view meets something
  (``DOWN_CONE_Z``, the station check's own test), so the checks accept the station.

Where the model has spots indoors (under a slab or roof, or in a room), only those are used: a
station on a roof or in the open is a last resort, for open structures with nothing overhead.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bimscan.scan.probe import Prober, sphere_directions
from bimscan.types import BimScene, Space

STANDABLE_CLASSES = ("IfcSlab", "IfcCovering", "IfcRamp", "IfcRampFlight", "IfcPlate", "IfcFooting", "IfcStair",
                     "IfcStairFlight", "IfcRoof")
NOT_STANDABLE_COVERINGS = ("CEILING", "CLADDING", "ROOFING", "INSULATION", "MEMBRANE", "SLEEVING", "WRAPPING")
# what a tripod never stands on, even at a room's floor: furniture, fittings, the site's objects
NEVER_STANDABLE = ("IfcFurnishingElement", "IfcDistributionElement", "IfcFlowTerminal", "IfcFlowSegment",
                   "IfcFlowFitting", "IfcFlowController", "IfcEnergyConversionDevice", "IfcDoor", "IfcWindow",
                   "IfcRailing", "IfcTransportElement", "Clutter", "Temporary", "Person", "Fixture")
MAX_TILT_DEG = 8.0  # floors with falls (1-2 %) and ramps up to about 14 %
LEG_RADIUS_M = 0.35  # a survey tripod's feet stand about 0.7 m apart
LEG_LEVEL_M = 0.03
HEADROOM_MARGIN_M = 0.3  # above the instrument's top
SPACE_FLOOR_TOLERANCE_M = 0.35  # a surface this close to a space's bottom is its floor
CLEAR_HEIGHTS_M = (0.3, 1.0)  # plus the instrument height
CLEAR_DIRECTIONS = 16
STATION_CHECK_RAYS = 2048  # rays of the station check (``stations.check_station``)
DOWN_CONE_Z = -0.85  # the check's steep downward view: directions with z below this
GRID_SHIFT_M = 0.0123  # probes off round coordinates, so they do not run along modelled faces


ON_ROOM_FLOOR = -1  # the component of a spot on a room's own floor (no element there)


@dataclass(frozen=True)
class TripodSpots:
    """Spots where a tripod can stand: floor (M, 3) float64 world metres (the point on the surface
    under the tripod's centre), component (M,) int64 (the element stood on; ``ON_ROOM_FLOOR`` for
    the floor of a room the model has no floor element in), covered (M,) bool (something overhead)."""

    floor: np.ndarray
    component: np.ndarray
    covered: np.ndarray

    def __len__(self) -> int:
        return int(len(self.floor))

    def take(self, index: np.ndarray) -> TripodSpots:
        return TripodSpots(floor=self.floor[index], component=self.component[index], covered=self.covered[index])

    @staticmethod
    def join(parts: list[TripodSpots]) -> TripodSpots:
        if not parts:
            return TripodSpots(floor=np.zeros((0, 3)), component=np.zeros(0, np.int64), covered=np.zeros(0, bool))
        return TripodSpots(floor=np.concatenate([p.floor for p in parts]),
                           component=np.concatenate([p.component for p in parts]),
                           covered=np.concatenate([p.covered for p in parts]))


def standable_components(scene: BimScene, *, any_element: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """((C,) bool: floors by class, (C,) bool: anything but furniture and fittings). With
    ``any_element``, or in a model with no floor by class, the second for both."""
    components = scene.components
    never = components.descends_from(NEVER_STANDABLE, parents=True)
    coverings = components.descends_from(("IfcCovering",))
    not_a_floor = coverings & np.isin(np.char.upper(components.predefined_type), NOT_STANDABLE_COVERINGS)
    floors = components.descends_from(STANDABLE_CLASSES, parents=True) & ~not_a_floor & ~never
    anything = ~never & ~not_a_floor
    return (floors if floors.any() and not any_element else anything), anything


def rooms_of(scene: BimScene) -> list[Space]:
    """The spaces that are rooms (at least 1 m tall; thin slivers and 2D areas are not)."""
    return [s for s in scene.spaces if len(s.vertices) and np.ptp(s.vertices[:, 2]) >= 1.0]


def in_room(room: Space, floor: np.ndarray) -> np.ndarray:
    """(M,) bool: floor points (M, 3) in the room: inside its footprint, at its floor (not higher
    than 1 m above its bottom, nor more than the tolerance below it)."""
    if len(floor) == 0:
        return np.zeros(0, dtype=bool)
    z0 = float(room.vertices[:, 2].min())
    near_bottom = (floor[:, 2] > z0 - SPACE_FLOOR_TOLERANCE_M - 0.3) & (floor[:, 2] < z0 + 1.0)
    inside = np.zeros(len(floor), dtype=bool)
    if near_bottom.any():
        inside[near_bottom] = room.contains(floor[near_bottom] + [0.0, 0.0, 0.05], below_m=SPACE_FLOOR_TOLERANCE_M + 0.3)
    return inside


def grid_columns(lo: np.ndarray, hi: np.ndarray, *, grid_m: float, max_columns: int) -> np.ndarray:
    """(N, 2) xy of probe columns on a grid over the box lo..hi (xy), at most about ``max_columns``."""
    area = max(float((hi[0] - lo[0]) * (hi[1] - lo[1])), 1e-6)
    grid = max(grid_m, math.sqrt(area / max_columns))
    xs = np.arange(lo[0] + grid / 2 + GRID_SHIFT_M, hi[0], grid)
    ys = np.arange(lo[1] + grid / 2 + GRID_SHIFT_M, hi[1], grid)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    return np.column_stack([gx.ravel(), gy.ravel()])


def find_tripod_spots(scene: BimScene, prober: Prober, columns: np.ndarray, *, instrument_m: float,
                      clearance_m: float, any_element: bool = False) -> TripodSpots:
    """The tripod spots (see the module docs) on the vertical lines at ``columns`` (N, 2) xy:
    first those on elements, then those on the floors of rooms the model gives no floor.
    ``any_element``: stand on any element but furniture and fittings (a structural model whose
    floors are precast units exported as beams, say)."""
    if len(columns) == 0 or scene.mesh.n_triangles == 0:
        return TripodSpots.join([])
    _, hi = scene.mesh.bounds()
    line, z, triangle = prober.surfaces_below(columns, float(hi[2]) + 1.0)
    normals = prober.face_normals
    level = np.abs(normals[triangle, 2]) >= math.cos(math.radians(MAX_TILT_DEG))
    component = scene.mesh.face_component[triangle].astype(np.int64)
    floors, anything = standable_components(scene, any_element=any_element)
    ok = level & floors[component]
    room_floors = []
    for room in rooms_of(scene):
        z0 = float(room.vertices[:, 2].min())
        inside = columns_in(room, columns)
        if not inside.any():
            continue
        # a level surface at a room's floor is a floor, whatever the element (not furniture)
        at_floor = inside[line] & (np.abs(z - z0) <= SPACE_FLOOR_TOLERANCE_M) & level
        ok |= at_floor & anything[component]
        if not (at_floor & floors[component]).any():  # no floor element in the room (a storey without slabs): its own floor
            bare = np.flatnonzero(inside)
            room_floors.append(np.column_stack([columns[bare], np.full(len(bare), z0)]))
    floor = np.column_stack([columns[line[ok]], z[ok]])
    spots = TripodSpots(floor=floor, component=component[ok], covered=np.zeros(len(floor), dtype=bool))
    spots = _with_headroom(prober, spots, instrument_m)
    spots = spots.take(_legs_level(prober, spots.floor))
    spots = spots.take(_clear_circle(prober, spots.floor, instrument_m, clearance_m))
    spots = spots.take(_ground_in_view(prober, spots.floor + [0.0, 0.0, instrument_m]))
    if not room_floors:
        return spots
    floor = np.unique(np.concatenate(room_floors), axis=0)  # rooms that overlap give a spot once
    on_rooms = TripodSpots(floor=floor, component=np.full(len(floor), ON_ROOM_FLOOR, dtype=np.int64),
                           covered=np.zeros(len(floor), dtype=bool))
    on_rooms = _with_headroom(prober, on_rooms, instrument_m)
    on_rooms = on_rooms.take(_clear_circle(prober, on_rooms.floor, instrument_m, clearance_m))
    return TripodSpots.join([spots, on_rooms])


def columns_in(room: Space, columns: np.ndarray) -> np.ndarray:
    """(N,) bool: columns (N, 2) xy inside the room's footprint."""
    r_lo, r_hi = room.vertices[:, :2].min(axis=0), room.vertices[:, :2].max(axis=0)
    near = np.flatnonzero((columns >= r_lo).all(axis=1) & (columns <= r_hi).all(axis=1))
    inside = np.zeros(len(columns), dtype=bool)
    z0 = float(room.vertices[:, 2].min())
    inside[near] = room.contains(np.column_stack([columns[near], np.full(len(near), z0 + 0.05)]))
    return inside


def on_room_floor(scene: BimScene, floor: np.ndarray) -> np.ndarray:
    """(M,) bool: floor points (M, 3) on the floor of a room (IfcSpace): inside its footprint, at
    its bottom within ``SPACE_FLOOR_TOLERANCE_M`` (a tripod there stands on the room's floor even
    where the model has no slab)."""
    out = np.zeros(len(floor), dtype=bool)
    for room in rooms_of(scene):
        near = np.abs(floor[:, 2] - float(room.vertices[:, 2].min())) <= SPACE_FLOOR_TOLERANCE_M
        if near.any():
            out[near] |= columns_in(room, floor[near, :2])
    return out


def _with_headroom(prober: Prober, spots: TripodSpots, instrument_m: float) -> TripodSpots:
    """The spots with room for the instrument above them, marked covered when something is overhead."""
    origins = spots.floor + [0.0, 0.0, 0.05]
    t_up, _ = prober.cast(origins, np.broadcast_to(np.array([0.0, 0.0, 1.0]), origins.shape))
    room = t_up + 0.05 >= instrument_m + HEADROOM_MARGIN_M  # inf (open sky) passes
    return TripodSpots(floor=spots.floor[room], component=spots.component[room], covered=np.isfinite(t_up[room]))


def _legs_level(prober: Prober, floor: np.ndarray) -> np.ndarray:
    """(M,) bool: the tripod's three feet rest on a surface level with the spot."""
    if len(floor) == 0:
        return np.zeros(0, dtype=bool)
    angles = np.radians([90.0, 210.0, 330.0])
    feet = np.stack([np.cos(angles), np.sin(angles), np.zeros(3)], axis=1) * LEG_RADIUS_M
    start = 0.3
    origins = (floor[:, None, :] + feet[None] + [0.0, 0.0, start]).reshape(-1, 3)
    t, _ = prober.cast(origins, np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape))
    return (np.abs(t - start) <= LEG_LEVEL_M).reshape(len(floor), 3).all(axis=1)


def _clear_circle(prober: Prober, floor: np.ndarray, instrument_m: float, clearance_m: float) -> np.ndarray:
    """(M,) bool: nothing within ``clearance_m`` of the tripod's axis at three heights."""
    angles = np.linspace(0, 2 * math.pi, CLEAR_DIRECTIONS, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    clear = np.ones(len(floor), dtype=bool)
    for h in (*CLEAR_HEIGHTS_M, instrument_m):
        origins = np.repeat(floor + [0.0, 0.0, h], len(ring), axis=0)
        t, _ = prober.cast(origins, np.tile(ring, (len(floor), 1)))
        clear &= (t.reshape(len(floor), len(ring)) >= clearance_m).all(axis=1)
    return clear


def down_cone_directions() -> np.ndarray:
    """The station check's steep downward view: (K, 3) float32 unit directions."""
    directions = sphere_directions(STATION_CHECK_RAYS)
    return directions[directions[:, 2] < DOWN_CONE_Z]


def _ground_in_view(prober: Prober, heads: np.ndarray, *, chunk: int = 4096) -> np.ndarray:
    """(M,) bool: from the beam origin at ``heads`` (M, 3), most of the steep downward view meets
    something (the station check's test; a station over a void or at a slab's edge fails it)."""
    cone = down_cone_directions()
    ok = np.zeros(len(heads), dtype=bool)
    for start in range(0, len(heads), chunk):
        part = heads[start:start + chunk]
        t, _ = prober.cast(np.repeat(part, len(cone), axis=0), np.tile(cone, (len(part), 1)))
        ok[start:start + chunk] = np.isfinite(t).reshape(len(part), len(cone)).mean(axis=1) >= 0.5
    return ok

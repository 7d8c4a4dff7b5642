"""Free floor: where objects can stand, found by ray probes through the scan engine.

Every room (an IfcSpace at least 1 m tall; without them, every connected free floor area of a
storey) gets a grid of ``CELL_M`` cells in the room's own axes (the direction of its longest
floor edge). A cell is *free* when a ray cast down from ``PROBE_M`` above the floor meets a floor
element (slab, covering, ramp, plate, footing) near the room's floor level (in a room the model
has no floor element in at all, a storey exported without its slabs, when it meets nothing down
to the room's own floor): nothing stands on it up to that height and
the probe did not start inside a solid (a probe inside a wall or a cabinet meets that element
first, or, where a wall's bottom face lies on the slab's top face, its horizontal rays meet the
wall's faces from behind). A ray up from the same point gives the *headroom* (clear height above the floor) and the
element overhead. Cells near doors (1 m on either side of the leaf), around stairs and at kept
tripod spots are *kept out*: nothing is put there.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bimscan.scan.probe import Prober
from bimscan.types import BimScene, SceneMesh, Space

CELL_M = 0.1
GRID_SHIFT_M = 0.0123  # off any round coordinate of a model
PROBE_M = 1.0
FLOOR_TOLERANCE_M = 0.35  # a floor surface this far from the room's floor level still counts (finishes, falls)
# what a floor can be made of (a ground-bearing slab is sometimes modelled as a footing)
FLOOR_CLASSES = ("IfcSlab", "IfcCovering", "IfcRamp", "IfcRampFlight", "IfcPlate", "IfcFooting")
DOOR_CLEARANCE_M = 1.0  # on either side of a door leaf: the swing and the way through
STAIR_CLEARANCE_M = 0.8
TRIPOD_RESERVE_M = 0.8  # radius kept clear around the spot reserved for a station in every room
TRIPOD_CLEAR_M = 0.45  # the clear circle a tripod needs (the station planner asks for 0.4 m)
TRIPOD_HEADROOM_M = 2.1  # instrument height (1.7 m on a VZ-400 tripod) and margin
MAX_CELLS = 4_000_000  # per room grid; larger floors get coarser cells
# Rooms whose name says they are for passing through: objects there stand against the walls (the
# way through stays clear, as escape routes must).
CIRCULATION = re.compile(r"corridor|hall|lobby|foyer|stair|landing|circulation|passage|flur|gang|treppe", re.I)


@dataclass
class RoomFloor:
    """The floor grid of one room, in the room's axes.

    angle_rad: the room's x axis in the world (world xy = rotation(angle) @ room xy). origin:
    room-frame xy of the grid's lower corner. Arrays are (ny, nx): inside (in the room's
    footprint), free (floor with nothing on it), floor_z (metres, world), headroom_m (clear
    height above the floor), overhead (component above, -1 none), keep_out (doors, stairs,
    tripod spots).
    """

    name: str
    storey: str
    key: str  # stable identity (the IfcSpace GlobalId, or storey and area number) for seeding
    level_z: float
    angle_rad: float
    origin: np.ndarray
    cell_m: float
    inside: np.ndarray
    free: np.ndarray
    floor_z: np.ndarray
    headroom_m: np.ndarray
    overhead: np.ndarray
    keep_out: np.ndarray

    @property
    def circulation(self) -> bool:
        """A corridor, hall or stair (by its name): objects stand against its walls only."""
        return bool(CIRCULATION.search(self.name))

    @property
    def shape(self) -> tuple[int, int]:
        return self.inside.shape  # type: ignore[return-value]

    @property
    def available(self) -> np.ndarray:
        return self.free & ~self.keep_out

    def free_area_m2(self) -> float:
        """Free floor not kept out, square metres."""
        return float(self.available.sum()) * self.cell_m**2

    def rotation(self) -> np.ndarray:
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        return np.array([[c, -s], [s, c]])

    def cell_centres(self) -> np.ndarray:
        """(ny, nx, 2) room-frame xy of the cell centres."""
        ny, nx = self.shape
        xs = self.origin[0] + (np.arange(nx) + 0.5) * self.cell_m
        ys = self.origin[1] + (np.arange(ny) + 0.5) * self.cell_m
        return np.stack(np.meshgrid(xs, ys, indexing="xy"), axis=-1)

    def to_world(self, xy_room: np.ndarray) -> np.ndarray:
        return xy_room @ self.rotation().T

    def to_room(self, xy_world: np.ndarray) -> np.ndarray:
        return xy_world @ self.rotation()


def component_mask(scene: BimScene, classes: Sequence[str], *, parents: bool = False) -> np.ndarray:
    """(C,) bool: components whose class (or, with ``parents``, whose aggregate's class) descends
    from one of ``classes``."""
    return scene.components.descends_from(classes, parents=parents)


def component_bounds(mesh: SceneMesh, n_components: int) -> tuple[np.ndarray, np.ndarray]:
    """Per component (C, 3) min and max corner of its triangles' vertices (inf/-inf without triangles)."""
    lo = np.full((n_components, 3), np.inf)
    hi = np.full((n_components, 3), -np.inf)
    if len(mesh.faces):
        order = np.argsort(mesh.face_component, kind="stable")
        component = mesh.face_component[order]
        corners = mesh.vertices[mesh.faces[order]]  # (F, 3, 3), grouped by component
        starts = np.flatnonzero(np.concatenate([[True], component[1:] != component[:-1]]))
        lo[component[starts]] = np.minimum.reduceat(corners.min(axis=1), starts)
        hi[component[starts]] = np.maximum.reduceat(corners.max(axis=1), starts)
    return lo, hi


def _room_angle(space: Space) -> float:
    """The direction (radians, in [0, pi/2)) of the longest edge of the room's floor."""
    v, f = space.vertices, space.faces
    z0 = v[:, 2].min()
    low = np.abs(v[:, 2] - z0) < 0.01
    faces = f[low[f].all(axis=1)]
    if len(faces) == 0:
        return 0.0
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    edges = unique[counts == 1]  # the outline (a diagonal of the triangulation is shared by two faces)
    if len(edges) == 0:
        return 0.0
    d = v[edges[:, 1], :2] - v[edges[:, 0], :2]
    longest = d[np.argmax(np.hypot(d[:, 0], d[:, 1]))]
    return float(math.atan2(longest[1], longest[0]) % (math.pi / 2))


def _levels(scene: BimScene) -> list[tuple[str, float, float]]:
    """(storey, elevation, next elevation) of every storey taller than 1 m (one level without storeys)."""
    lo, hi = scene.mesh.bounds()
    storeys = sorted(scene.storeys, key=lambda s: s.elevation_m)
    if not storeys:
        return [("", float(lo[2]), float(hi[2]) + 1.0)]
    out = []
    for i, s in enumerate(storeys):
        nxt = storeys[i + 1].elevation_m if i + 1 < len(storeys) else float(hi[2]) + 1.0
        if nxt - s.elevation_m > 1.0:
            out.append((s.name, s.elevation_m, nxt))
    return out


def _probe(prober: Prober, xy: np.ndarray, level_z: float, height_m: float,
           floor_components: np.ndarray, *, own_floor: bool = False) -> tuple[np.ndarray, ...]:
    """Probe cells at world xy (N, 2): (free, floor_z, headroom, overhead component). With
    ``own_floor`` (a room the model has no floor element in) a cell with nothing on it down to the
    level stands on the level itself."""
    start = level_z + min(PROBE_M, 0.5 * height_m)
    origins = np.column_stack([xy, np.full(len(xy), start)])
    t_down, below = prober.cast(origins, np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape))
    floor_z = start - t_down
    if own_floor:
        free = floor_z < level_z - FLOOR_TOLERANCE_M  # nothing down to the level (inf: nothing at all)
        floor_z = np.full(len(xy), level_z)
    else:
        free = (below >= 0) & floor_components[np.maximum(below, 0)] & (np.abs(floor_z - level_z) < FLOOR_TOLERANCE_M)
    free[free] = ~prober.inside_solid(origins[free])
    t_up, above = prober.cast(origins, np.broadcast_to(np.array([0.0, 0.0, 1.0]), origins.shape))
    headroom = np.where(free, start - floor_z + np.minimum(t_up, 50.0), 0.0)
    return free, np.where(free, floor_z, level_z), headroom, np.where(free, above, -1)


def _grid(angle: float, xy_world: np.ndarray, cell: float) -> tuple[np.ndarray, tuple[int, int], float]:
    """Room-frame origin and (ny, nx) of a grid covering the points, and the cell size used."""
    c, s = math.cos(angle), math.sin(angle)
    room = xy_world @ np.array([[c, -s], [s, c]])
    # the grid is shifted off round coordinates, so that probes do not run along modelled faces
    lo, hi = room.min(axis=0) - GRID_SHIFT_M, room.max(axis=0)
    size = np.maximum(hi - lo, cell)
    cell = max(cell, math.sqrt(float(size[0] * size[1]) / MAX_CELLS))
    nx, ny = (int(math.ceil(v / cell)) for v in size)
    return lo, (ny, nx), cell


def find_room_floors(scene: BimScene, prober: Prober, *, zones: Sequence[tuple[np.ndarray, np.ndarray, float]] = (),
                     keep_clear: Sequence[tuple[float, float, float]] = (), cell_m: float = CELL_M) -> list[RoomFloor]:
    """The floor grids of every room (see the module docs).

    zones: keep-out rectangles in world xy as (centre (2,), half axes (2, 2) as rows (axis * half
    length), z of their floor) for doors and stairs (see ``keep_out_zones``); keep_clear: spots
    (x, y, floor z) to keep clear (given stations). A tripod spot is reserved in every room.
    """
    floor_components = component_mask(scene, FLOOR_CLASSES)
    if not floor_components.any():
        floor_components[:] = True  # no slabs at all: any surface is a floor
    rooms: list[RoomFloor] = []
    spaces = [s for s in scene.spaces if np.ptp(s.vertices[:, 2]) >= 1.0]  # rooms, not slivers
    if spaces:
        for space in spaces:
            z0, z1 = float(space.vertices[:, 2].min()), float(space.vertices[:, 2].max())
            angle = _room_angle(space)
            origin, (ny, nx), cell = _grid(angle, space.vertices[:, :2], cell_m)
            room = _empty_room(space.name, space.storey, space.global_id, z0, angle, origin, cell, ny, nx)
            centres = room.to_world(room.cell_centres().reshape(-1, 2))
            inside = space.contains(np.column_stack([centres, np.full(len(centres), z0 + 0.5)]))
            _fill(room, prober, centres, inside, z1 - z0, floor_components, own_floor=True)
            rooms.append(room)
    else:
        lo, hi = scene.mesh.bounds()
        corners = np.array([[lo[0], lo[1]], [hi[0], hi[1]]])
        for storey, elevation, next_elevation in _levels(scene):
            origin, (ny, nx), cell = _grid(0.0, corners, cell_m)
            level = _empty_room(storey, storey, storey, elevation, 0.0, origin, cell, ny, nx)
            centres = level.to_world(level.cell_centres().reshape(-1, 2))
            everywhere = np.ones(len(centres), dtype=bool)
            _fill(level, prober, centres, everywhere, next_elevation - elevation, floor_components)
            rooms += _split_areas(level)
    for room in rooms:
        _mark_keep_out(room, zones, keep_clear)
        _reserve_tripod_spot(room)
    return rooms


def _empty_room(name: str, storey: str, key: str, level_z: float, angle: float, origin: np.ndarray, cell: float,
                ny: int, nx: int) -> RoomFloor:
    return RoomFloor(name=name, storey=storey, key=key, level_z=level_z, angle_rad=angle, origin=origin, cell_m=cell,
                     inside=np.zeros((ny, nx), bool), free=np.zeros((ny, nx), bool),
                     floor_z=np.full((ny, nx), level_z), headroom_m=np.zeros((ny, nx)),
                     overhead=np.full((ny, nx), -1, dtype=np.int64), keep_out=np.zeros((ny, nx), bool))


def _fill(room: RoomFloor, prober: Prober, centres: np.ndarray, inside: np.ndarray, height: float,
          floor_components: np.ndarray, *, own_floor: bool = False) -> None:
    shape = room.shape
    room.inside[:] = inside.reshape(shape)
    index = np.flatnonzero(inside)
    free, floor_z, headroom, overhead = _probe(prober, centres[index], room.level_z, height, floor_components)
    if own_floor and len(index) and not free.any():  # no floor element in the room: it stands on its own floor
        free, floor_z, headroom, overhead = _probe(prober, centres[index], room.level_z, height, floor_components,
                                                   own_floor=True)
    for target, values in ((room.free, free), (room.floor_z, floor_z), (room.headroom_m, headroom),
                           (room.overhead, overhead)):
        target.reshape(-1)[index] = values


def _split_areas(level: RoomFloor) -> list[RoomFloor]:
    """A storey's free floor split into connected areas (walls part them; doorways join them)."""
    from scipy import ndimage

    labels, count = ndimage.label(level.free)
    if count == 0:
        return []
    sizes = np.bincount(labels.ravel())[1:]
    rooms = []
    for k in np.flatnonzero(sizes * level.cell_m**2 >= 1.0) + 1:
        mask = labels == k
        rooms.append(RoomFloor(
            name=f"{level.storey or 'floor'} area {len(rooms) + 1}", storey=level.storey,
            key=f"{level.key}#{len(rooms) + 1}", level_z=level.level_z, angle_rad=0.0, origin=level.origin,
            cell_m=level.cell_m, inside=mask, free=level.free & mask, floor_z=level.floor_z,
            headroom_m=level.headroom_m, overhead=level.overhead, keep_out=np.zeros_like(mask)))
    return rooms


def keep_out_zones(scene: BimScene) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Keep-out rectangles (world xy) around doors (``DOOR_CLEARANCE_M`` on either side of the leaf)
    and stairs (``STAIR_CLEARANCE_M`` around), each with its lowest z."""
    lo, hi = component_bounds(scene.mesh, len(scene.components))
    zones = []
    doors = np.flatnonzero(component_mask(scene, ("IfcDoor",), parents=True))
    stairs = np.flatnonzero(component_mask(scene, ("IfcStair", "IfcStairFlight", "IfcRamp", "IfcRampFlight"),
                                           parents=True))
    faces_of = np.argsort(scene.mesh.face_component, kind="stable")
    starts = np.searchsorted(scene.mesh.face_component[faces_of], np.arange(len(scene.components) + 1))
    for c in doors:
        points = scene.mesh.vertices[np.unique(scene.mesh.faces[faces_of[starts[c]:starts[c + 1]]])][:, :2]
        if len(points) < 2:
            continue
        centre = points.mean(axis=0)
        # the leaf's width runs along the principal axis of its vertices; the way through is across it
        _, _, axes = np.linalg.svd(points - centre, full_matrices=False)
        along = axes[0] if len(axes) else np.array([1.0, 0.0])
        across = np.array([-along[1], along[0]])
        half_along = float(np.abs((points - centre) @ along).max()) + 0.2
        half_across = float(np.abs((points - centre) @ across).max()) + DOOR_CLEARANCE_M
        zones.append((centre, np.stack([along * half_along, across * half_across]), float(lo[c, 2])))
    for c in stairs:
        if not np.isfinite(lo[c]).all():
            continue
        centre = (lo[c, :2] + hi[c, :2]) / 2
        half = (hi[c, :2] - lo[c, :2]) / 2 + STAIR_CLEARANCE_M
        zones.append((centre, np.array([[half[0], 0.0], [0.0, half[1]]]), float(lo[c, 2])))
    return zones


def _mark_keep_out(room: RoomFloor, zones: Sequence[tuple[np.ndarray, np.ndarray, float]],
                   keep_clear: Sequence[tuple[float, float, float]]) -> None:
    centres = room.to_world(room.cell_centres().reshape(-1, 2))
    out = room.keep_out.reshape(-1)
    for centre, half_axes, z in zones:
        if not (room.level_z - 1.0 < z < room.level_z + 2.0):
            continue  # a door or stair of another storey
        rel = centres - centre
        inside = np.ones(len(centres), dtype=bool)
        for axis in half_axes:
            length2 = float(axis @ axis)
            if length2 > 0:
                inside &= np.abs(rel @ axis) <= length2
        out |= inside
    for x, y, z in keep_clear:
        if abs(z - room.level_z) < 1.0:
            out |= np.hypot(centres[:, 0] - x, centres[:, 1] - y) <= TRIPOD_RESERVE_M


def _reserve_tripod_spot(room: RoomFloor) -> None:
    """Keep a disc clear around the spot nearest the middle of the room where a tripod fits, so that
    the station planner (run after the clutter) finds a station in every room that had one."""
    from scipy import ndimage

    radius = int(math.ceil(TRIPOD_CLEAR_M / room.cell_m))
    yy, xx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
    disc = xx**2 + yy**2 <= radius**2
    usable = ndimage.binary_erosion(room.available & (room.headroom_m >= TRIPOD_HEADROOM_M), structure=disc)
    if not usable.any():
        return
    centres = room.cell_centres()
    middle = centres[room.available].mean(axis=0)
    candidates = np.argwhere(usable)
    distance = np.linalg.norm(centres[usable] - middle, axis=1)
    j, i = candidates[int(np.argmin(distance))]
    spot = centres[j, i]
    room.keep_out |= np.linalg.norm(centres - spot, axis=-1) <= TRIPOD_RESERVE_M

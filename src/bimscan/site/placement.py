"""Placing objects on a room's free floor: collision-free with the model and with each other.

A candidate pose (centre, heading) of an object of footprint ``w x d`` and height ``h`` is kept
when (1) every floor cell under its footprint is free, not kept out, level within 2 cm and has
headroom above the object; (2) its footprint, grown by ``GAP_M``, overlaps no object placed
before (exact rectangle test); (3) rays through its box find nothing: horizontal rays along its
width and depth every ``SWEEP_M`` at several heights, and vertical rays every ``SWEEP_M`` from
its top to the floor, through the box grown by ``CLEARANCE_M`` (a ray that starts inside a
wall or a column meets it at once). Objects go
against a wall (their back ``GAP_M`` from the face a horizontal ray finds) or stand free,
aligned with the room or turned any way; in corridors and halls (by the room's name) only against
a wall, so the way through stays clear.

Ceiling kinds (luminaires, air terminals) are laid out as a designer lays them out: one object
drawn per room, repeated on an even grid over the room's footprint (``n = round(extent /
spacing)`` per axis, the outer ones half a pitch from the walls). A grid point is kept when rays
up from ``MIN_CLEAR_UNDER_FIXTURE_M`` above the floor, at its centre and its corners, meet the
same ceiling, covering, slab or roof soffit level within ``LEVEL_M`` (not a beam, a wall top or
the sky); the object then hangs ``MOUNT_GAP_M`` under the lowest of them, clears every object on
the floor under it, crosses no other ceiling object and no ray through its box meets the model.
Panel lights under a suspended ceiling are mostly set into it (lay-in troffers): the point must
then lie under one level ceiling covering no thicker than ``MAX_COVERING_M`` with a void above it
deep enough for the housing (rays up through the tile and on), and the covering is cut at the
footprint (``stage.cut_openings``); where no point has such a void (a ceiling fixed to the
soffit), the room's panels are mounted on it instead. A point that fails is tried aside
(``NUDGES_M``). All draws come from the room's own generator, so a room's objects do not depend
on the other rooms.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from bimscan.scan.probe import Prober
from bimscan.site.floor import RoomFloor
from bimscan.site.library import (
    MIN_CLEAR_UNDER_FIXTURE_M,
    TROFFER_FRACTION,
    ClutterKind,
    ClutterObject,
    recessed_troffer,
)
from bimscan.site.shapes import yaw_matrix

GAP_M = 0.03  # between objects, and between an object's back and the wall it stands against
SWEEP_M = 0.05  # spacing of the collision rays through a candidate's box
CLEARANCE_M = 0.01  # the rays sweep the box grown by this: nothing of the model comes closer
WALL_HEIGHTS_M = np.array([0.05, 0.4, 0.75, 1.1, 1.5, 1.9, 2.3])  # where the distance to a wall is measured
LEVEL_M = 0.02  # the floor under an object is level within this
ATTEMPTS = 16  # candidate poses tried per object
DRAWS = 3  # objects drawn (sizes) per placement before giving up
COMPANION_CHAIR = 0.8  # chance that a desk gets a chair in front of it
PROP_SPACING_M = 1.5  # back-propping grid under slabs (typically 1.2-1.8 m)
MOUNT_GAP_M = 0.002  # between a ceiling object's top and the ceiling
MAX_CEILING_M = 12.0  # a soffit further above the floor is no room's ceiling (an atrium, the sky)
MAX_COVERING_M = 0.1  # a ceiling board thicker than this is no suspended ceiling to set a troffer in
LAY_IN_MAX_M = 0.2  # a ceiling light this deep is a pendant, not a panel
# tries aside of a grid point (past a beam, or past a fixture of another kind at the same point)
NUDGES_M = ((0.0, 0.0), (0.45, 0.0), (-0.45, 0.0), (0.0, 0.45), (0.0, -0.45),
            (0.9, 0.0), (-0.9, 0.0), (0.0, 0.9), (0.0, -0.9))


@dataclass(frozen=True)
class PlacedObject:
    """An object standing in a room: its mesh in world metres and its footprint.

    vertices: (V, 3) float64 world; faces: (F, 3) int32; footprint: (4, 2) world xy corners;
    base_z: the floor height it stands on.
    """

    kind: str
    class_name: str
    room: str
    room_key: str  # the room's identity (IfcSpace GlobalId, or storey and area number)
    storey: str
    vertices: np.ndarray
    faces: np.ndarray
    footprint: np.ndarray
    base_z: float  # for a ceiling object: the height of its lowest point
    opening: bool = False  # set into a suspended ceiling: the ceiling is cut at its footprint


@dataclass
class _Pose:
    centre: np.ndarray  # room-frame xy of the footprint's centre
    yaw: float  # radians, relative to the room's axes


class RoomPlacer:
    """Places objects in one room, one at a time (see the module docs)."""

    def __init__(self, room: RoomFloor, prober: Prober, rng: np.random.Generator) -> None:
        self.room = room
        self.prober = prober
        self.rng = rng
        self.rects: list[np.ndarray] = []  # (4, 2) room-frame corners of every footprint on the floor
        self._boxes = np.zeros((0, 4))  # their axis-aligned boxes (x0, y0, x1, y1), to test few exactly
        self._tops: list[float] = []  # the world height of each floor object's top
        self._ceiling_rects: list[np.ndarray] = []  # footprints of the objects under the ceiling
        self.placed: list[PlacedObject] = []
        centres = room.cell_centres()
        self._centres = centres
        available = room.available
        self._cells = centres[available]
        # cells along walls, per direction of the wall (+x, +y, -x, -y in the room's axes)
        self._wall_cells = []
        for dx, dy in ((1, 0), (0, 1), (-1, 0), (0, -1)):
            neighbour = np.zeros_like(room.free)
            shifted = np.roll(room.free, shift=(-dy, -dx), axis=(0, 1))
            neighbour[:] = shifted
            if dx == 1:
                neighbour[:, -1] = False
            elif dx == -1:
                neighbour[:, 0] = False
            elif dy == 1:
                neighbour[-1, :] = False
            else:
                neighbour[0, :] = False
            self._wall_cells.append(centres[available & ~neighbour])
        # the distance from every wall cell to the face beside it, at heights up to 2.4 m (one cast)
        self._wall_distance = []
        for direction, cells in enumerate(self._wall_cells):
            out = np.array(((1, 0), (0, 1), (-1, 0), (0, -1))[direction], dtype=float)
            index = np.array([self._cell_of(c) for c in cells], dtype=int).reshape(-1, 2)
            floor = room.floor_z[index[:, 0], index[:, 1]] if len(cells) else np.zeros(0)
            origins = np.column_stack([np.repeat(room.to_world(cells), len(WALL_HEIGHTS_M), axis=0),
                                       np.repeat(floor, len(WALL_HEIGHTS_M)) + np.tile(WALL_HEIGHTS_M, len(cells))])
            t, _ = prober.cast(origins, np.tile(np.append(room.to_world(out[None])[0], 0.0), (len(origins), 1)))
            self._wall_distance.append(t.reshape(len(cells), len(WALL_HEIGHTS_M)))
        usable = room.headroom_m[available]
        self.typical_headroom_m = float(np.percentile(usable, 25)) if len(usable) else 0.0

    # ------------------------------------------------------------------ drawing and trying objects

    def place_kind(self, kind: ClutterKind) -> PlacedObject | None:
        """Draw objects of ``kind`` and try poses until one fits; None when none does."""
        if len(self._cells) == 0:
            return None
        for _ in range(DRAWS):
            against_wall = self.rng.random() < kind.wall_probability or (
                self.room.circulation and kind.wall_probability > 0)
            if kind.name == "prop":
                placed = self._place_prop(kind)
                if placed is not None:
                    return placed
                continue
            obj = kind.make(self.rng, self.typical_headroom_m, against_wall)
            if obj is None:
                continue
            for _ in range(ATTEMPTS):
                pose = self._wall_pose(obj) if against_wall else self._free_pose(obj, kind)
                base = None if pose is None else self._fits(obj, pose)
                if pose is not None and base is not None:
                    placed = self._commit(kind, obj, pose, base)
                    if kind.name == "desk" and self.rng.random() < COMPANION_CHAIR:
                        self._companion_chair(pose, obj)
                    return placed
        return None

    def place_prop_grid(self, kind: ClutterKind, slab_components: np.ndarray) -> int:
        """Props on a ``PROP_SPACING_M`` grid under slab soffits (back-propping); returns how many."""
        room = self.room
        centres = self._centres
        lo = centres[room.inside].min(axis=0) if room.inside.any() else np.zeros(2)
        hi = centres[room.inside].max(axis=0) if room.inside.any() else np.zeros(2)
        count = 0
        for x in np.arange(lo[0] + PROP_SPACING_M / 2, hi[0], PROP_SPACING_M):
            for y in np.arange(lo[1] + PROP_SPACING_M / 2, hi[1], PROP_SPACING_M):
                j, i = self._cell_of(np.array([x, y]))
                if j < 0 or not room.available[j, i]:
                    continue
                above = room.overhead[j, i]
                if above < 0 or not slab_components[above]:
                    continue
                obj = kind.make(self.rng, float(room.headroom_m[j, i]), False)
                pose = _Pose(np.array([x, y]), 0.0)
                base = None if obj is None else self._fits(obj, pose, spanning=True)
                if obj is not None and base is not None:
                    self._commit(kind, obj, pose, base)
                    count += 1
        return count

    def place_ceiling_grid(self, kind: ClutterKind, soffits: np.ndarray, coverings: np.ndarray) -> int:
        """Objects of a ceiling kind on an even grid over the room (see the module docs); returns how
        many. soffits: (components,) bool, what a fixture may hang from (coverings, slabs, roofs);
        coverings: the ceiling coverings, where panel lights are mostly set in (lay-in troffers)."""
        room = self.room
        inside = self._centres[room.inside]
        if len(inside) == 0:
            return 0
        lo, hi = inside.min(axis=0) - room.cell_m / 2, inside.max(axis=0) + room.cell_m / 2
        spacing = self.rng.uniform(*kind.spacing_m)
        counts = np.maximum(1, np.round((hi - lo) / spacing)).astype(int)
        xs = lo[0] + (np.arange(counts[0]) + 0.5) * (hi[0] - lo[0]) / counts[0]
        ys = lo[1] + (np.arange(counts[1]) + 0.5) * (hi[1] - lo[1]) / counts[1]
        nodes = np.array([(x, y) for x in xs for y in ys])
        ceiling, component = self._ceiling_above(nodes, soffits)
        found = np.isfinite(ceiling)
        if not found.any():
            return 0
        clear = float(np.percentile(ceiling[found] - room.level_z, 25))
        obj = kind.make(self.rng, clear - LEVEL_M - MOUNT_GAP_M, False)  # the soffit varies by LEVEL_M
        if obj is None:
            return 0
        yaw = math.pi / 2 * int(self.rng.integers(2))  # long luminaires along or across the room
        set_in = (kind.lay_in and obj.size_m[2] < LAY_IN_MAX_M
                  and coverings[component[found]].mean() > 0.5 and self.rng.random() < TROFFER_FRACTION)
        if set_in:
            count = self._ceiling_grid(kind, recessed_troffer(self.rng, obj), nodes[found], yaw, coverings, True)
            if count:
                return count
            # no void above the tiles for a housing (a ceiling fixed to the soffit): mounted on it
        return self._ceiling_grid(kind, obj, nodes[found], yaw, soffits, False)

    def _ceiling_grid(self, kind: ClutterKind, obj: ClutterObject, nodes: np.ndarray, yaw: float,
                      soffits: np.ndarray, set_in: bool) -> int:
        count = 0
        for node in nodes:
            for nudge in NUDGES_M:
                pose = _Pose(node + np.asarray(nudge), yaw)
                if set_in:
                    base = self._lay_in_fits(obj, pose, soffits)
                else:
                    top = self._ceiling_fits(obj, pose, soffits)
                    base = None if top is None else top - obj.size_m[2]
                if base is not None:
                    self._commit(kind, obj, pose, base, on_ceiling=True, opening=set_in)
                    count += 1
                    break
        return count

    def _ceiling_above(self, xy_room: np.ndarray, soffits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The height of the soffit over each room-frame point (N, 2), NaN where there is none (outside
        the room, inside a solid, under a beam or open to the sky), and its component (-1: none)."""
        room = self.room
        cells = [self._cell_of(c) for c in xy_room]
        origins = np.column_stack([room.to_world(xy_room), np.full(len(xy_room), room.level_z + MIN_CLEAR_UNDER_FIXTURE_M)])
        t, component = self.prober.cast(origins, np.tile([0.0, 0.0, 1.0], (len(origins), 1)))
        ok = np.array([j >= 0 and room.inside[j, i] for j, i in cells], dtype=bool)
        ok &= (component >= 0) & (t < MAX_CEILING_M - MIN_CLEAR_UNDER_FIXTURE_M)
        ok[ok] = soffits[component[ok]] & ~self.prober.inside_solid(origins[ok])
        return np.where(ok, origins[:, 2] + np.where(ok, t, 0.0), np.nan), np.where(ok, component, -1)

    def _level_soffit(self, obj: ClutterObject, pose: _Pose, points: np.ndarray,
                      soffits: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The soffit's height and component over ``points`` (the pose's centre and corners), or None
        when the pose meets another ceiling object or the soffit there is missing or not level."""
        if any(_overlap(self._footprint(obj, pose, GAP_M), other) for other in self._ceiling_rects):
            return None
        ceiling, component = self._ceiling_above(points, soffits)
        if not np.isfinite(ceiling).all() or ceiling.max() - ceiling.min() > LEVEL_M:
            return None
        return ceiling, component

    def _lay_in_fits(self, obj: ClutterObject, pose: _Pose, coverings: np.ndarray) -> float | None:
        """The height of the ceiling's underside where a lay-in troffer goes (its z = 0), or None when
        the ceiling there is not one level covering, too thin a void above it holds the housing, or
        the housing would meet the model or another fixture."""
        points = np.vstack([pose.centre[None], self._footprint(obj, pose)])
        found = self._level_soffit(obj, pose, points, coverings)
        if found is None:
            return None
        ceiling, component = found
        underside = float(ceiling.min())
        world = np.column_stack([self.room.to_world(points), ceiling + 0.001])
        up = np.tile([0.0, 0.0, 1.0], (len(points), 1))
        thickness, inside = self.prober.cast(world, up)  # the covering's top face, met from inside
        if not (inside == component).all() or thickness.max() > MAX_COVERING_M:
            return None
        above = world.copy()
        above[:, 2] += thickness + 0.002
        void, _ = self.prober.cast(above, up)
        top_of_covering = float((ceiling + 0.001 + thickness).max())
        if underside + obj.size_m[2] > float((above[:, 2] + void).min()) - MOUNT_GAP_M:
            return None  # the housing does not fit under the slab
        housing = dataclasses.replace(obj, size_m=(obj.size_m[0], obj.size_m[1],
                                                   underside + obj.size_m[2] - top_of_covering - 0.002))
        if housing.size_m[2] > 0 and self._box_hits(housing, pose, top_of_covering + 0.002, spanning=True):
            return None
        return underside

    def _ceiling_fits(self, obj: ClutterObject, pose: _Pose, soffits: np.ndarray) -> float | None:
        """The height of the object's top under the ceiling, or None when the pose collides."""
        found = self._level_soffit(obj, pose, np.vstack([pose.centre[None], self._footprint(obj, pose)]), soffits)
        if found is None:
            return None
        top = float(found[0].min()) - MOUNT_GAP_M
        bottom = top - obj.size_m[2]
        if bottom < self.room.level_z + MIN_CLEAR_UNDER_FIXTURE_M:
            return None
        grown = self._footprint(obj, pose, GAP_M)
        if any(t > bottom - GAP_M and _overlap(grown, rect) for rect, t in zip(self.rects, self._tops)):
            return None  # something on the floor reaches up to it
        return None if self._box_hits(obj, pose, bottom, spanning=True) else top

    def _place_prop(self, kind: ClutterKind) -> PlacedObject | None:
        for _ in range(ATTEMPTS):
            centre = self._cells[self.rng.integers(len(self._cells))]
            j, i = self._cell_of(centre)
            obj = kind.make(self.rng, float(self.room.headroom_m[j, i]), False)
            pose = _Pose(centre.copy(), 0.0)
            base = None if obj is None else self._fits(obj, pose, spanning=True)
            if obj is not None and base is not None:
                return self._commit(kind, obj, pose, base)
        return None

    def _companion_chair(self, desk_pose: _Pose, desk: ClutterObject) -> None:
        from bimscan.site.library import CLUTTER_KINDS

        kind = CLUTTER_KINDS["chair"]
        chair = kind.make(self.rng, self.typical_headroom_m, False)
        if chair is None:
            return
        offset = np.array([self.rng.uniform(-0.2, 0.2) * desk.size_m[0],
                           -(desk.size_m[1] / 2 + chair.size_m[1] / 2 + GAP_M + self.rng.uniform(0.0, 0.15))])
        pose = _Pose(desk_pose.centre + _rotate2(offset, desk_pose.yaw),
                     desk_pose.yaw + math.pi + self.rng.uniform(-0.4, 0.4))
        base = self._fits(chair, pose)
        if base is not None:
            self._commit(kind, chair, pose, base)

    # ------------------------------------------------------------------------------------ poses

    def _free_pose(self, obj: ClutterObject, kind: ClutterKind) -> _Pose:
        centre = self._cells[self.rng.integers(len(self._cells))] + self.rng.uniform(-0.5, 0.5, 2) * self.room.cell_m
        if kind.free_yaw:
            yaw = self.rng.uniform(0.0, 2 * math.pi)
        else:
            yaw = self.rng.integers(4) * math.pi / 2 + (self.rng.uniform(-0.15, 0.15) if kind.group == "site" else 0.0)
        return _Pose(centre, float(yaw))

    def _wall_pose(self, obj: ClutterObject) -> _Pose | None:
        """Back against a wall: a cell along a wall, the wall's face found by a horizontal ray."""
        direction = int(self.rng.integers(4))
        cells = self._wall_cells[direction]
        if len(cells) == 0:
            return None
        k = int(self.rng.integers(len(cells)))
        cell = cells[k]
        out = np.array(((1, 0), (0, 1), (-1, 0), (0, -1))[direction], dtype=float)
        # the nearest face over the object's height (a table's top overhangs its legs)
        reach = WALL_HEIGHTS_M <= max(obj.size_m[2], WALL_HEIGHTS_M[0])
        distance = float(self._wall_distance[direction][k][reach].min())
        if not np.isfinite(distance) or distance > 2 * self.room.cell_m:
            return None  # the free floor ends at an object or an edge, not a wall
        lateral = np.array([-out[1], out[0]]) * self.rng.uniform(-0.5, 0.5) * self.room.cell_m
        centre = cell + out * (distance - GAP_M - obj.size_m[1] / 2) + lateral
        yaw = math.atan2(out[1], out[0]) - math.pi / 2  # the object's back (+y) faces the wall
        return _Pose(centre, yaw)

    # ---------------------------------------------------------------------------------- checks

    def _cell_of(self, xy_room: np.ndarray) -> tuple[int, int]:
        ny, nx = self.room.shape
        i, j = (int(math.floor(v)) for v in (xy_room - self.room.origin) / self.room.cell_m)
        return (j, i) if 0 <= i < nx and 0 <= j < ny else (-1, -1)

    def _footprint(self, obj: ClutterObject, pose: _Pose, grow: float = 0.0) -> np.ndarray:
        w, d = obj.size_m[0] / 2 + grow, obj.size_m[1] / 2 + grow
        corners = np.array([[-w, -d], [w, -d], [w, d], [-w, d]])
        return pose.centre + _rotate2(corners, pose.yaw)

    def _fits(self, obj: ClutterObject, pose: _Pose, *, spanning: bool = False) -> float | None:
        """The floor height the object would stand on, or None when the pose collides."""
        room = self.room
        w, d, h = obj.size_m
        # (1) the floor cells under the footprint
        rect = self._footprint(obj, pose)
        lo, hi = rect.min(axis=0), rect.max(axis=0)
        ny, nx = room.shape
        i0, j0 = (int(math.floor(v)) for v in (lo - room.origin) / room.cell_m)
        i1, j1 = (int(math.floor(v)) for v in (hi - room.origin) / room.cell_m)
        if i0 < 0 or j0 < 0 or i1 >= nx or j1 >= ny:
            return None
        window = self._centres[j0:j1 + 1, i0:i1 + 1]
        local = _rotate2(window.reshape(-1, 2) - pose.centre, -pose.yaw)
        # at least half a cell each way: a board a few centimetres deep still covers the row of cells
        # along its length (else only the cell at its centre was checked, and a wall board could
        # reach across a door's keep-out)
        half_w, half_d = max(w, room.cell_m) / 2, max(d, room.cell_m) / 2
        under = ((np.abs(local[:, 0]) <= half_w) & (np.abs(local[:, 1]) <= half_d)).reshape(window.shape[:2])
        if not under.any():  # smaller than a cell: the cell holding its centre
            j, i = self._cell_of(pose.centre)
            under = np.zeros(window.shape[:2], dtype=bool)
            under[j - j0, i - i0] = True
        if not room.available[j0:j1 + 1, i0:i1 + 1][under].all():
            return None
        floor = room.floor_z[j0:j1 + 1, i0:i1 + 1][under]
        if floor.max() - floor.min() > LEVEL_M:
            return None
        base = float(floor.max())
        headroom = room.headroom_m[j0:j1 + 1, i0:i1 + 1][under] - (base - floor)
        if headroom.min() < h + (0.002 if spanning else 0.02):
            return None
        # (2) the other objects
        if self._overlaps_placed(self._footprint(obj, pose, GAP_M)):
            return None
        # (3) rays through the box
        return None if self._box_hits(obj, pose, base, spanning=spanning) else base

    def _box_hits(self, obj: ClutterObject, pose: _Pose, base: float, *, spanning: bool) -> bool:
        m = CLEARANCE_M
        w, d, h = obj.size_m[0] + 2 * m, obj.size_m[1] + 2 * m, obj.size_m[2]
        top = h + (0.001 if spanning else m)  # a prop or a fixture stops short of the soffit it is under
        low = min(0.02, h / 2)  # a thin fixture's box is a few millimetres deep
        heights = np.unique(np.concatenate([[low], np.arange(0.3, top, 0.4), [top]]))
        xs = np.linspace(-w / 2, w / 2, max(2, int(math.ceil(w / SWEEP_M)) + 1))
        ys = np.linspace(-d / 2, d / 2, max(2, int(math.ceil(d / SWEEP_M)) + 1))
        origins, directions, lengths = [], [], []
        for z in heights:
            origins.append(np.column_stack([np.full(len(ys), xs[0]), ys, np.full(len(ys), z)]))
            directions.append(np.tile([1.0, 0.0, 0.0], (len(ys), 1)))
            lengths.append(np.full(len(ys), xs[-1] - xs[0]))
            origins.append(np.column_stack([xs, np.full(len(xs), ys[0]), np.full(len(xs), z)]))
            directions.append(np.tile([0.0, 1.0, 0.0], (len(xs), 1)))
            lengths.append(np.full(len(xs), ys[-1] - ys[0]))
        gx, gy = (a.ravel() for a in np.meshgrid(xs, ys, indexing="xy"))
        origins.append(np.column_stack([gx, gy, np.full(len(gx), top)]))
        directions.append(np.tile([0.0, 0.0, -1.0], (len(gx), 1)))
        lengths.append(np.full(len(gx), top - low))
        local_o, local_d, length = np.concatenate(origins), np.concatenate(directions), np.concatenate(lengths)
        rotation = self._rotation(pose)
        world_o = local_o @ rotation.T
        world_o[:, :2] += self.room.to_world(pose.centre[None])[0]
        world_o[:, 2] += base
        t, _ = self.prober.cast(world_o, local_d @ rotation.T)
        return bool((t < length).any())

    def _overlaps_placed(self, rect: np.ndarray) -> bool:
        lo, hi = rect.min(axis=0), rect.max(axis=0)
        boxes = self._boxes
        near = np.flatnonzero((boxes[:, 0] < hi[0]) & (boxes[:, 2] > lo[0])
                              & (boxes[:, 1] < hi[1]) & (boxes[:, 3] > lo[1]))
        return any(_overlap(rect, self.rects[k]) for k in near)

    def _rotation(self, pose: _Pose) -> np.ndarray:
        return yaw_matrix(self.room.angle_rad + pose.yaw)

    def _commit(self, kind: ClutterKind, obj: ClutterObject, pose: _Pose, base: float, *,
                on_ceiling: bool = False, opening: bool = False) -> PlacedObject:
        room = self.room
        rect = self._footprint(obj, pose)
        vertices = obj.vertices @ self._rotation(pose).T
        vertices[:, :2] += room.to_world(pose.centre[None])[0]
        vertices[:, 2] += base
        placed = PlacedObject(kind=kind.name, class_name=obj.class_name, room=room.name, room_key=room.key,
                              storey=room.storey, vertices=vertices, faces=obj.faces, footprint=room.to_world(rect),
                              base_z=base, opening=opening)
        if on_ceiling:
            self._ceiling_rects.append(rect)
        else:
            self.rects.append(rect)
            self._tops.append(base + obj.size_m[2])
            self._boxes = np.vstack([self._boxes, np.concatenate([rect.min(axis=0), rect.max(axis=0)])[None]])
        self.placed.append(placed)
        return placed


def _rotate2(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """True when two convex polygons (k, 2) share interior area (separating axis test)."""
    for poly in (a, b):
        edges = poly[[1, 2, 3, 0]] - poly if len(poly) == 4 else np.roll(poly, -1, axis=0) - poly
        normals = np.column_stack([-edges[:, 1], edges[:, 0]])
        pa, pb = a @ normals.T, b @ normals.T
        if ((pa.max(axis=0) <= pb.min(axis=0)) | (pb.max(axis=0) <= pa.min(axis=0))).any():
            return False
    return True

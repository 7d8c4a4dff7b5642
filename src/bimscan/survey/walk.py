"""Walks planned from the model: the path a surveyor takes with a mobile scanner (``--trajectory auto``).

The walk visits what a tripod survey of the same model would scan from: the stations of
``stations.plan_stations`` (one or more per room of every storey) are its waypoints. Between
them it follows the floors the model has:

1. *Walkable cells.* Vertical probes on a ``grid_m`` grid meet every surface
   (``Prober.surfaces_below``). A cell is walkable on an upward-facing surface of an element a
   person walks on (anything but furniture, fittings, windows, railings and site objects; a
   door's threshold is floor), level within ``MAX_TILT_DEG`` (stairs and ramps within
   ``MAX_STAIR_TILT_DEG``), or on the bottom of a room (an IfcSpace) with no such surface at its
   floor anywhere (storeys exported without their slabs); with the platform's ``headroom_m`` above it and a circle of its ``body_radius_m`` clear at
   three heights. Doors do not block: the operator opens them (door leaves and frames are
   passed through by every probe of the walk), so rooms connect through their door openings.
2. *Steps.* Neighbouring cells (8-neighbourhood) connect where their floors differ by at most
   ``MAX_STEP_M`` (a stair riser) and a horizontal probe at knee height between them meets
   nothing but doors: stairs join storeys where the model has them. A step costs its length,
   more near walls (``WALL_MARGIN_M``), so walks keep to the middle of corridors.
3. *Route.* Each part of the building that can be walked from one of its waypoints to all
   others is walked in one pass: a closed tour through its waypoints (nearest neighbour, then
   2-opt on walking distances), starting and ending at its lowest waypoint nearest the model's
   corner, so the walk returns to its start as surveyors close their loops. Parts that cannot
   be reached from each other (no stair in the model) are separate passes.
4. *Shape and time.* The grid path is shortened (straight where the floor allows), its corners
   rounded, sampled every ``SAMPLE_M`` and timed: ``walking_speed_m_s`` on floors,
   ``stair_speed_m_s`` on stairs, and never turning faster than ``max_turn_deg_per_s``.
   The platform faces along its walk (yaw), level (pitch = roll = 0).

Loop closures (``Trajectory.closures``) are the times the walk comes back within
``CLOSURE_RADIUS_M`` of where it was ``CLOSURE_MIN_PATH_M`` or more of walking earlier.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from bimscan.errors import StationError
from bimscan.scan.probe import Prober
from bimscan.survey.platform import Platform
from bimscan.survey.spots import GRID_SHIFT_M, SPACE_FLOOR_TOLERANCE_M, columns_in, rooms_of, standable_components
from bimscan.survey.trajectory import Trajectory
from bimscan.types import BimScene, Station

MAX_TILT_DEG = 8.0
MAX_STAIR_TILT_DEG = 40.0
STAIR_CLASSES = ("IfcStair", "IfcStairFlight", "IfcRamp", "IfcRampFlight")
PASSABLE_CLASSES = ("IfcDoor",)  # the operator opens doors
MAX_STEP_M = 0.22
MAX_STAIR_SLOPE = 0.9  # rise over going of the steepest stair a walk takes (about 42 degrees)
KNEE_M = 0.45
CLEAR_HEIGHTS_M = (0.3, 1.0, 1.6)
CLEAR_DIRECTIONS = 16
WALL_MARGIN_M = 0.8  # steps closer than this to a wall cost more (up to 3x at the wall)
SAMPLE_M = 0.1
CORNER_WINDOW_M = 0.5  # corners are rounded by averaging positions this far along the path each way
CLOSURE_RADIUS_M = 1.0
CLOSURE_MIN_PATH_M = 20.0
PASS_GAP_S = 10.0  # the scanner pauses between passes (carried to the next part of the building)
MAX_THROUGH = 8  # passable surfaces one probe passes through at most
DOORWAY_M = 0.35  # a room's own floor reaches this far past its outline (through its walls' openings)


@dataclass(frozen=True)
class WalkReport:
    """What a planned walk covers: waypoints (the tripod plan's stations) visited and missed (their
    indices), and the rooms visited (the stations' rooms). Its passes, metres and seconds are the
    trajectory's (``Trajectory.n_passes``, ``length_m``, ``duration_s``)."""

    waypoints: int
    visited: tuple[int, ...]
    missed: tuple[int, ...]
    rooms: tuple[str, ...]


@dataclass(frozen=True)
class WalkGrid:
    """Walkable cells: xyz (N, 3) floor points, cell (N, 2) int grid index, clearance (N,) metres to
    the nearest obstacle at knee-to-chest height (capped), and the grid's origin and step."""

    xyz: np.ndarray
    cell: np.ndarray
    clearance: np.ndarray
    origin: np.ndarray
    step: float
    shape: tuple[int, int]


def _through(prober: Prober, passable: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distances (N,) to the first hit that is not a passable component (inf: none)."""
    total = np.zeros(len(origins))
    result = np.full(len(origins), np.inf)
    active = np.arange(len(origins))
    position = np.array(origins, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    for _ in range(MAX_THROUGH):
        if len(active) == 0:
            break
        t, component = prober.cast(position[active], directions[active])
        hit = component >= 0
        blocked = hit & ~passable[np.maximum(component, 0)]
        result[active[blocked]] = total[active[blocked]] + t[blocked]
        go_on = hit & ~blocked
        step = t[go_on] + 1e-3
        total[active[go_on]] += step
        position[active[go_on]] += directions[active[go_on]] * step[:, None]
        active = active[go_on]
    return result


def walkable_grid(scene: BimScene, prober: Prober, platform: Platform, *, grid_m: float = 0.2,
                  max_columns: int = 400_000) -> WalkGrid:
    """The walkable cells of the scene (step 1 of the module docs)."""
    lo, hi = scene.mesh.bounds()
    area = max(float((hi[0] - lo[0]) * (hi[1] - lo[1])), 1e-6)
    step = max(grid_m, math.sqrt(area / max_columns))
    nx = max(1, int(math.ceil((hi[0] - lo[0]) / step)))
    ny = max(1, int(math.ceil((hi[1] - lo[1]) / step)))
    origin = np.array([lo[0] + GRID_SHIFT_M, lo[1] + GRID_SHIFT_M])
    gx, gy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    cells = np.column_stack([gx.ravel(), gy.ravel()])
    columns = origin + (cells + 0.5) * step
    line, z, triangle = prober.surfaces_below(columns, float(hi[2]) + 1.0)
    components = scene.components
    passable = components.descends_from(PASSABLE_CLASSES, parents=True)
    _, anything = standable_components(scene, any_element=True)
    stair = components.descends_from(STAIR_CLASSES, parents=True)
    normal_z = prober.face_normals[triangle, 2]
    component = scene.mesh.face_component[triangle].astype(np.int64)
    limit = np.where(stair[component], math.cos(math.radians(MAX_STAIR_TILT_DEG)), math.cos(math.radians(MAX_TILT_DEG)))
    ok = (normal_z >= limit) & (anything | passable)[component]  # a door's threshold is floor
    floor = np.column_stack([columns[line[ok]], z[ok]])
    cell = cells[line[ok]]
    bare = _bare_room_floors(scene, columns, line, z, ok)  # rooms the model gives no floor element
    if len(bare):
        floor = np.concatenate([floor, np.column_stack([columns[bare[:, 0].astype(np.int64)], bare[:, 1]])])
        cell = np.concatenate([cell, cells[bare[:, 0].astype(np.int64)]])
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), floor.shape)
    room = _through(prober, passable, floor + [0.0, 0.0, 0.02], up) + 0.02 >= platform.headroom_m
    floor, cell = floor[room], cell[room]
    angles = np.linspace(0.0, 2 * math.pi, CLEAR_DIRECTIONS, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    clear = np.ones(len(floor), dtype=bool)
    clearance = np.full(len(floor), WALL_MARGIN_M)
    for height in CLEAR_HEIGHTS_M:
        origins = np.repeat(floor + [0.0, 0.0, height], len(ring), axis=0)
        t = _through(prober, passable, origins, np.tile(ring, (len(floor), 1))).reshape(len(floor), len(ring))
        nearest = t.min(axis=1) if len(floor) else np.zeros(0)
        clear &= nearest >= platform.body_radius_m
        clearance = np.minimum(clearance, nearest)
    return WalkGrid(xyz=floor[clear], cell=cell[clear], clearance=clearance[clear], origin=origin, step=step,
                    shape=(nx, ny))


def _bare_room_floors(scene: BimScene, columns: np.ndarray, line: np.ndarray, z: np.ndarray,
                      walkable: np.ndarray) -> np.ndarray:
    """(K, 2) [column index, floor z] of cells on the own floor of rooms (IfcSpaces) that have no
    walkable surface at their floor anywhere (storeys exported without their slabs): the operator
    walks on the room's floor, as a tripod stands on it (``spots.find_tripod_spots``). A room's
    floor reaches ``DOORWAY_M`` past its outline, into the door openings of its walls (spaces end at
    the wall faces); the clearance check drops the cells inside the walls."""
    found = []
    for room in rooms_of(scene):
        z0 = float(room.vertices[:, 2].min())
        inside = columns_in(room, columns)
        for shift in ((DOORWAY_M, 0.0), (-DOORWAY_M, 0.0), (0.0, DOORWAY_M), (0.0, -DOORWAY_M)):
            inside |= columns_in(room, columns + shift)
        if not inside.any():
            continue
        if (walkable & inside[line] & (np.abs(z - z0) <= SPACE_FLOOR_TOLERANCE_M)).any():
            continue
        index = np.flatnonzero(inside)
        found.append(np.column_stack([index, np.full(len(index), z0)]))
    return np.concatenate(found) if found else np.zeros((0, 2))


def walk_graph(grid: WalkGrid, prober: Prober, passable: np.ndarray) -> coo_matrix:
    """Steps between neighbouring walkable cells (step 2 of the module docs) as a symmetric sparse
    matrix of costs."""
    n = len(grid.xyz)
    nx, _ = grid.shape
    key = grid.cell[:, 1].astype(np.int64) * nx + grid.cell[:, 0]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    rows, cols = [], []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        target = (grid.cell[:, 1] + dy).astype(np.int64) * nx + grid.cell[:, 0] + dx
        valid = (grid.cell[:, 0] + dx < nx) & (grid.cell[:, 1] + dy >= 0)
        start = np.searchsorted(sorted_key, target, side="left")
        stop = np.searchsorted(sorted_key, target, side="right")
        depth = int((stop - start).max()) if n else 0
        for j in range(depth):
            has = valid & (start + j < stop)
            a = np.flatnonzero(has)
            b = order[start[has] + j]
            near = np.abs(grid.xyz[b, 2] - grid.xyz[a, 2]) <= MAX_STEP_M
            rows.append(a[near])
            cols.append(b[near])
    a = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    b = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    # a knee-height probe from one cell to the other meets nothing but doors
    knee_a = grid.xyz[a] + [0.0, 0.0, KNEE_M]
    delta = grid.xyz[b] + [0.0, 0.0, KNEE_M] - knee_a
    length = np.linalg.norm(delta, axis=1)
    free = _through(prober, passable, knee_a, delta / np.maximum(length, 1e-9)[:, None]) >= length
    a, b, length = a[free], b[free], length[free]
    margin = np.minimum(grid.clearance[a], grid.clearance[b])
    cost = length * (1.0 + 2.0 * np.clip(1.0 - margin / WALL_MARGIN_M, 0.0, 1.0))
    return coo_matrix((np.concatenate([cost, cost]), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))


def _tour(distance: np.ndarray, start: int) -> list[int]:
    """A closed tour through every index of the square ``distance`` matrix from ``start``: nearest
    neighbour, then 2-opt until no exchange shortens it."""
    w = len(distance)
    tour, left = [start], set(range(w)) - {start}
    while left:
        here = tour[-1]
        nearest = min(left, key=lambda j: (distance[here, j], j))
        tour.append(nearest)
        left.remove(nearest)
    improved = w > 3
    while improved:
        improved = False
        for i in range(1, w - 1):
            for k in range(i + 1, w):
                a, b = tour[i - 1], tour[i]
                c, d = tour[k], tour[(k + 1) % w]
                if distance[a, c] + distance[b, d] < distance[a, b] + distance[c, d] - 1e-9:
                    tour[i:k + 1] = reversed(tour[i:k + 1])
                    improved = True
    return tour


def _cell_lookup(grid: WalkGrid) -> np.ndarray:
    """(nx * ny, L) walkable nodes of each cell (-1 padded), for the straightness checks."""
    nx, ny = grid.shape
    key = grid.cell[:, 1].astype(np.int64) * nx + grid.cell[:, 0]
    order = np.argsort(key, kind="stable")
    counts = np.bincount(key, minlength=nx * ny)
    depth = max(1, int(counts.max()) if len(counts) else 1)
    table = np.full((nx * ny, depth), -1, dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(order)) - first[key[order]]
    table[key[order], rank] = order
    return table


def _on_floor(grid: WalkGrid, table: np.ndarray, points: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Whether each point (M, 3) lies over a walkable cell whose floor is within ``tolerance`` of
    its z, and that floor's z."""
    nx, ny = grid.shape
    cell = np.floor((points[:, :2] - grid.origin) / grid.step).astype(np.int64)
    inside = (cell[:, 0] >= 0) & (cell[:, 0] < nx) & (cell[:, 1] >= 0) & (cell[:, 1] < ny)
    nodes = np.full((len(points), table.shape[1]), -1, dtype=np.int64)
    nodes[inside] = table[cell[inside, 1] * nx + cell[inside, 0]]
    dz = np.where(nodes >= 0, np.abs(grid.xyz[np.maximum(nodes, 0), 2] - points[:, 2:3]), np.inf)
    best = dz.argmin(axis=1)
    ok = dz[np.arange(len(points)), best] <= tolerance
    z = np.where(ok, grid.xyz[nodes[np.arange(len(points)), best], 2], points[:, 2])
    return ok, z


def _straighten(grid: WalkGrid, table: np.ndarray, path: np.ndarray, lookahead: int = 80) -> np.ndarray:
    """The path (M, 3) with runs replaced by straight lines wherever every point of the line is on
    walkable floor (string pulling)."""
    kept = [0]
    i = 0
    while i < len(path) - 1:
        best = i + 1
        for j in range(min(len(path) - 1, i + lookahead), i + 1, -1):
            length = float(np.linalg.norm(path[j, :2] - path[i, :2]))
            if abs(path[j, 2] - path[i, 2]) > MAX_STEP_M + MAX_STAIR_SLOPE * length:
                continue  # steeper than any stair: a shortcut between storeys
            samples = max(2, int(length / (grid.step * 0.25)) + 1)
            f = np.linspace(0.0, 1.0, samples)[:, None]
            line = path[i] + f * (path[j] - path[i])
            ok, floor_z = _on_floor(grid, table, line, MAX_STEP_M + 0.05)
            if ok.all() and np.abs(np.diff(floor_z)).max(initial=0.0) <= MAX_STEP_M:
                best = j
                break
        kept.append(best)
        i = best
    return path[kept]


def _resample(path: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` metres (horizontal) along the polyline (M, 3), both ends kept."""
    seg = np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return path[:1]
    n = max(2, int(math.ceil(s[-1] / spacing)) + 1)
    at = np.linspace(0.0, s[-1], n)
    return np.column_stack([np.interp(at, s, path[:, axis]) for axis in range(3)])


def _round_corners(grid: WalkGrid, table: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Positions averaged over ``CORNER_WINDOW_M`` each way (ends fixed), kept only where the
    averaged point is still on walkable floor; z follows the floor under each point."""
    half = max(1, int(round(CORNER_WINDOW_M / SAMPLE_M)))
    if len(points) <= 2 * half + 1:
        return points
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    smooth = points.copy()
    for axis in range(2):
        padded = np.concatenate([np.full(half, points[0, axis]), points[:, axis], np.full(half, points[-1, axis])])
        smooth[:, axis] = np.convolve(padded, kernel, mode="valid")
    ok, _ = _on_floor(grid, table, smooth, MAX_STEP_M + 0.05)
    smooth[~ok] = points[~ok]
    _, floor_z = _on_floor(grid, table, smooth, MAX_STEP_M + 0.05)
    padded = np.concatenate([np.full(half, floor_z[0]), floor_z, np.full(half, floor_z[-1])])
    smooth[:, 2] = np.convolve(padded, kernel, mode="valid")
    smooth[0], smooth[-1] = points[0], points[-1]
    return smooth


def _timed(points: np.ndarray, platform: Platform, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Times (M,) and yaw (M,) radians of the walk through ``points`` (step 4 of the module docs)."""
    delta = np.diff(points, axis=0)
    horizontal = np.linalg.norm(delta[:, :2], axis=1)
    heading = np.unwrap(np.arctan2(delta[:, 1], delta[:, 0]))
    yaw = np.concatenate([[heading[0]], (heading[:-1] + heading[1:]) / 2.0, [heading[-1]]]) if len(heading) else \
        np.zeros(len(points))
    steep = np.abs(delta[:, 2]) > 0.25 * np.maximum(horizontal, 1e-9)
    speed = np.where(steep, platform.stair_speed_m_s, platform.walking_speed_m_s)
    turn = np.abs(np.diff(yaw))
    dt = np.maximum(np.linalg.norm(delta, axis=1) / speed, turn / math.radians(platform.max_turn_deg_per_s))
    dt = np.maximum(dt, 1e-3)
    return t0 + np.concatenate([[0.0], np.cumsum(dt)]), yaw


def loop_closures(t: np.ndarray, xyz: np.ndarray, pass_id: np.ndarray) -> np.ndarray:
    """Times where a pass comes back within ``CLOSURE_RADIUS_M`` of a place it left at least
    ``CLOSURE_MIN_PATH_M`` of walking earlier (one per return)."""
    closures = []
    for p in range(int(pass_id.max()) + 1 if len(pass_id) else 0):
        idx = np.flatnonzero(pass_id == p)
        step = np.linalg.norm(np.diff(xyz[idx], axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(step)])
        tree = cKDTree(xyz[idx] * [1.0, 1.0, 2.0])
        last = -np.inf
        for k in range(len(idx)):
            if s[k] - last < CLOSURE_MIN_PATH_M / 2:
                continue
            near = tree.query_ball_point(xyz[idx[k]] * [1.0, 1.0, 2.0], CLOSURE_RADIUS_M)
            if any(s[k] - s[j] >= CLOSURE_MIN_PATH_M for j in near):
                closures.append(t[idx[k]])
                last = s[k]
    return np.asarray(closures, dtype=np.float64)


def plan_walk(scene: BimScene, prober: Prober, platform: Platform, stations: tuple[Station, ...], *,
              grid_m: float = 0.2) -> tuple[Trajectory, WalkReport]:
    """The planned walk through ``stations`` (the tripod plan's; see the module docs) for ``platform``.

    Raises StationError when no station stands on walkable floor (nothing to walk to)."""
    grid = walkable_grid(scene, prober, platform, grid_m=grid_m)
    passable = scene.components.descends_from(PASSABLE_CLASSES, parents=True)
    if len(grid.xyz) == 0:
        raise StationError(f"{scene.source}: no floor to walk on (no level floor with {platform.headroom_m:g} m of "
                           f"headroom and {platform.body_radius_m:g} m clear around the operator); give the walk in "
                           "a file with --trajectory FILE.csv")
    if not stations:
        raise StationError(f"{scene.source}: no station of a tripod plan to walk through; give the walk in a file with "
                           "--trajectory FILE.csv")
    graph = walk_graph(grid, prober, passable).tocsr()
    table = _cell_lookup(grid)
    tree = cKDTree(grid.xyz * [1.0, 1.0, 3.0])
    floors = np.array([[s.position[0], s.position[1], s.floor_z if s.floor_z is not None else s.position[2] - 1.7]
                       for s in stations])
    distance, nearest = tree.query(floors * [1.0, 1.0, 3.0], distance_upper_bound=1.5)
    on_walk = np.isfinite(distance)
    if not on_walk.any():
        raise StationError(f"{scene.source}: no room of the tripod plan can be walked to (no walkable floor within 1.5 m "
                           "of any station); give the walk in a file with --trajectory FILE.csv")
    _, part = connected_components(graph, directed=False)
    node_of = {int(i): int(nearest[i]) for i in np.flatnonzero(on_walk)}
    parts: dict[int, list[int]] = {}
    for station_index, node in node_of.items():
        parts.setdefault(int(part[node]), []).append(station_index)
    lo, _ = scene.mesh.bounds()
    order = sorted(parts, key=lambda p: min((grid.xyz[node_of[i], 2], i) for i in parts[p]))
    t_all, xyz_all, yaw_all, pass_all = [], [], [], []
    t0 = 0.0
    walked: list[int] = []
    for pass_index, p in enumerate(order):
        members = parts[p]
        nodes = np.array([node_of[i] for i in members])
        dist, pred = dijkstra(graph, directed=False, indices=nodes, return_predecessors=True)
        if len(nodes) == 1:  # one station in this part: walk to the farthest reachable cell and back
            reach = np.where(np.isfinite(dist[0]), dist[0], -1.0)
            far = int(np.argmax(reach))
            nodes = np.array([nodes[0], far])
            dist2, pred2 = dijkstra(graph, directed=False, indices=[far], return_predecessors=True)
            dist, pred = np.vstack([dist, dist2]), np.vstack([pred, pred2])
        corner = np.linalg.norm(grid.xyz[nodes, :2] - lo[:2], axis=1)
        start = int(np.lexsort((corner, np.round(grid.xyz[nodes, 2], 1)))[0])
        tour = _tour(dist[:, nodes], start)
        legs = [grid.xyz[[int(nodes[start])]]]
        for a, b in zip(tour, tour[1:] + tour[:1]):
            leg = [int(nodes[a])]
            node = int(nodes[b])
            tail = []
            while node != nodes[a] and node >= 0:
                tail.append(node)
                node = int(pred[a, node])
            leg.extend(reversed(tail))
            if len(leg) > 1:  # each leg straightened alone, so the walk passes every waypoint
                legs.append(_straighten(grid, table, grid.xyz[np.array(leg)])[1:])
        path = np.concatenate(legs)
        points = _round_corners(grid, table, _resample(path, SAMPLE_M))
        if len(points) < 2:  # a part with one spot to stand on: nothing to walk
            continue
        t, yaw = _timed(points, platform, t0)
        walked.extend(members)
        t_all.append(t)
        xyz_all.append(points)
        yaw_all.append(yaw)
        pass_all.append(np.full(len(t), pass_index, dtype=np.int32))
        t0 = float(t[-1]) + PASS_GAP_S
    if not t_all:
        raise StationError(f"{scene.source}: the planned walk has no length (a single spot to stand on); give the walk "
                           "in a file with --trajectory FILE.csv")
    t, xyz = np.concatenate(t_all), np.concatenate(xyz_all)
    pass_id = np.concatenate(pass_all)
    pass_id = np.unique(pass_id, return_inverse=True)[1].astype(np.int32)
    zeros = np.zeros(len(t))
    trajectory = Trajectory(t=t, xyz=xyz, roll=zeros, pitch=zeros.copy(), yaw=np.concatenate(yaw_all), pass_id=pass_id,
                            closures=loop_closures(t, xyz, pass_id))
    visited = tuple(sorted(walked))
    rooms = tuple(sorted({stations[i].room for i in visited if stations[i].room}))
    report = WalkReport(waypoints=len(stations), visited=visited,
                        missed=tuple(i for i in range(len(stations)) if i not in walked), rooms=rooms)
    return trajectory, report

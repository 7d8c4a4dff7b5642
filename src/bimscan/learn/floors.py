"""The floor under every point, found from the points alone, as a real scan allows.

The ``height`` input feature is a point's height above its own storey's floor. A building has
several floors (storeys, split levels, a basement, landings), so one floor per scene (its lowest
points) puts every point above the first storey out of the range the network learned; the floor
must be found where the point is. Nothing but the points is used, so synthetic and real scans
get their floors the same way.

Model. The scene is cut into square tiles of ``TILE_M`` (in xy) and, inside a tile, into cells
of ``CELL_M`` and height bins of ``BIN_M``: a cell-bin is *occupied* when a point falls in it
(counts of points do not matter, so the scan's density does not). In each cell, a run of
adjacent occupied bins is a *surface*, and the empty heights between surfaces tell which way each
faces, as the scanner's rays did: a gap taller than ``AIR_M`` is room air, a shorter one a slab's
inside (with its ceiling void) or the room under a table. A surface *faces up* (a floor's top)
when room air is over it up to the next surface and either a slab's underside or nothing scanned
lies under it (a ground floor), or when nothing is over it but a ceiling lies just under it (a
roof terrace). It *faces down* (a ceiling, a slab's underside) when room air is under it. A
surface with nothing over it and no ceiling under it tells nothing: the terrain outside, or a
ceiling over the scanner's blind cone or over a lamp. Nothing scanned under a surface counts
for facing up only in the bottom storey (within ``STOREY_M`` of the lowest floor): higher up a
floor stands on a slab, and a surface over nothing is a ceiling over a tripod's blind cone or
over a floor hidden by furniture.

In a tile, a *candidate* floor is a height where at least ``UPWARD_FRACTION`` of the tile's
occupied cells face up (two adjacent bins together) and at least ``DENSE_FRACTION`` hold points.
It is a floor when its cells face up ``SIDE_RATIO`` times as often as down; going up, a floor
less than ``STOREY_M`` above the previous one, or covering less than ``FLOOR_FRACTION`` of the
tile, is not one (a table, a bed, a landing). Except: a candidate at most ``SLAB_M`` over the
previous floor, covering as much and facing up nearly as often (within ``SIDE_RATIO``), takes its
place. The two are one slab seen from both sides: its top where the floor shows, its underside
where rays from below passed a suspended ceiling and the floor over it is hidden (an underside
over a ceiling void looks like a floor on a slab). The floor is the slab's top. The whole
scene's floors are found the same way from all tiles at once (a storey above covering at least
``SCENE_FLOOR_FRACTION`` of the scene: upper storeys are smaller, and their furniture hides much
of their floor). A tile's candidate within ``SCENE_MATCH_M`` of a scene floor needs only to face
up more often than down; one away from every scene floor is a floor of its own (a split level)
only when it covers most of its tile, what stands on it rises from it (walls, furniture, seen
within ``NEAR_M`` to ``FAR_M`` above it, against below it), and the scene's floor under it is
hidden in its tile (a table stands over a floor that shows). A point's floor is the highest
floor of its tile at most ``ABOVE_TOLERANCE_M`` above it (the floor's own points lie on it), or
less where a ceiling (a layer facing down) lies closer under the floor: under a thin slab seen
from above (a flat roof with a station on it, a terrace over rooms), the ceiling is the room's
below, whose floor is lower (``_reach``); a point below every floor takes the lowest. Tiles without a floor (a floor hidden under furniture,
a tile of wall only) take the scene's floors, and a tile's floors are completed by the scene
floors it does not show.

A point's *storey* is the scene floor nearest its own floor (``storey_of``): blocks of the network
are cut per storey, so a column of a five-storey building is five blocks of one storey each, as
a single room is one.

This is the "nearest dominant upward-facing horizontal surface below it in its column": dominant
is the coverage test, upward-facing the air over it and the slab or ground under it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimscan.errors import LearnError

TILE_M = 2.0
CELL_M = 0.25
BIN_M = 0.05
DENSE_FRACTION = 0.2
FLOOR_FRACTION = 0.35  # a floor above another covers at least this share of its tile
SCENE_FLOOR_FRACTION = 0.15  # ... or of the whole scene's footprint (upper storeys are smaller, and furnished)
AIR_M = 1.2  # an empty height over this is room air; a slab with its ceiling void is thinner
SLAB_M = 0.4  # a slab's top over its underside, finishes included (a seat, a bed stands higher)
STOREY_M = 2.3  # floors of one tile at least this far apart (lower: a table, a landing, a beam's underside)
ABOVE_TOLERANCE_M = 0.15  # a floor's own points lie on it (noise, finishes)
UPWARD_FRACTION = 0.05  # a candidate floor: at least this share of the column's cells face up at its height
NEAR_M, FAR_M = 0.1, 0.6  # the bands beside a split level where what stands on it, or under it, shows
SIDE_RATIO = 1.5  # one way this much more often than the other tells which way a layer faces
SCENE_MATCH_M = 0.15  # a tile's candidate this close to a scene floor is that floor (finishes, a slab's tolerance)
LOCAL_FLOOR_FRACTION = 0.5  # a tile's floor at no floor of the scene (a split level) covers half a tile
_CELLS_PER_TILE = int(round(TILE_M / CELL_M))
_NOTHING = 1 << 30  # the "gap" over a cell's highest surface and under its lowest: nothing scanned
_BIN_BITS = 20  # height bins of one key (1 m / BIN_M * 2**20 m: any building)
_CELL_BITS = 21


def _keys(xyz: np.ndarray) -> np.ndarray:
    """(N,) int64 key of each point's (cell x, cell y, height bin), sortable by cell then bin;
    ``xyz`` relative to the map's origin."""
    cells = np.floor(xyz[:, :2] / CELL_M).astype(np.int64) + (1 << (_CELL_BITS - 1))
    bins = np.floor(xyz[:, 2] / BIN_M).astype(np.int64) + (1 << (_BIN_BITS - 1))
    if len(xyz) and (cells.min() < 0 or cells.max() >= 1 << _CELL_BITS or bins.min() < 0 or bins.max() >= 1 << _BIN_BITS):
        raise LearnError("a scene spans more than the floor map reaches (about 260 km across, 26 km high); "
                         "check its coordinates' unit")
    return (cells[:, 0] << (_CELL_BITS + _BIN_BITS)) | (cells[:, 1] << _BIN_BITS) | bins


@dataclass(frozen=True)
class _Column:
    """What decides a column's floors (a tile's, or the whole scene's): per height bin from
    ``low`` (bin index), the cells occupied at the bin or the next (``coverage``), the occupied
    cell-bins (``occupied``), and the cells occupied at any height (``footprint``). Additive
    over disjoint tiles."""

    low: int
    coverage: np.ndarray
    occupied: np.ndarray
    footprint: int
    upward: np.ndarray  # per bin, the cells' surfaces facing up whose top is in it (see _column)
    upward_on_nothing: np.ndarray  # ... of those, the ones with nothing scanned under them (a ground floor)
    downward: np.ndarray  # per bin, the cells' surfaces facing down whose bottom is in it


class FloorMapBuilder:
    """Collects a scene's occupancy and builds its ``FloorMap``. Points may come in any order
    (``add``: the occupied cell-bins are kept until ``build``, memory the building's surface, not
    its points) or a set of whole tiles at a time (``add_tiles``: summarised at once and let go,
    memory a few numbers per tile)."""

    def __init__(self, *, origin: np.ndarray | None = None) -> None:
        self._parts: list[np.ndarray] = []
        self._pending = 0
        self._keys = np.empty(0, dtype=np.int64)
        self._tiles: dict[int, _Column] = {}
        # tiles and bins count from the scene's origin (default: the lower corner of the first
        # points added), so a georeferencing offset does not move them against the points
        self._origin = None if origin is None else np.asarray(origin, dtype=np.float64)

    def _relative(self, xyz: np.ndarray) -> np.ndarray:
        xyz = np.asarray(xyz, dtype=np.float64)
        if self._origin is None:
            self._origin = xyz.min(axis=0)
        return xyz - self._origin

    def add(self, xyz: np.ndarray) -> None:
        """Add a chunk of (N, 3) float64 points in metres."""
        if len(xyz):
            part = np.unique(_keys(self._relative(xyz)))
            self._parts.append(part)
            self._pending += len(part)
            if self._pending > max(len(self._keys), 1 << 20):
                self._merge()

    def add_tiles(self, xyz: np.ndarray) -> None:
        """Add (N, 3) points holding every point of the tiles they fall in (no later ``add``
        or ``add_tiles`` may bring more points of those tiles)."""
        if len(xyz):
            self._tiles.update(_tile_columns(np.unique(_keys(self._relative(xyz)))))

    def _merge(self) -> None:
        if self._parts:
            self._keys = np.unique(np.concatenate([self._keys, *self._parts]))
            self._parts, self._pending = [], 0

    def build(self) -> FloorMap:
        self._merge()
        tiles = dict(self._tiles)
        tiles.update(_tile_columns(self._keys))
        return floor_map_of_tiles(tiles, origin=np.zeros(3) if self._origin is None else self._origin)


@dataclass(frozen=True)
class FloorMap:
    """Floors per tile: ``tiles`` (T, 2) int64 tile indices (sorted as keys), ``starts`` (T + 1,)
    offsets into ``floors`` (F,) float64 metres, ascending within a tile; ``scene_floors`` (S,)
    the floors of the whole scene (for tiles without one; at least one value)."""

    tiles: np.ndarray
    starts: np.ndarray
    floors: np.ndarray
    scene_floors: np.ndarray
    origin: np.ndarray  # (3,) metres: tiles are counted from it (floors are absolute)
    reach: np.ndarray | None = None  # (F,) how far below each floor its own points lie (None: ABOVE_TOLERANCE_M)
    scene_reach: np.ndarray | None = None  # (S,) the same for the scene's floors

    def floor_under(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) float64: the floor under each of (N, 3) points (see the module docs)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        out = np.empty(len(xyz))
        tile = np.floor((xyz[:, :2] - self.origin[:2]) / TILE_M).astype(np.int64)
        key = _tile_key(tile)
        known = _tile_key(self.tiles)
        position = np.searchsorted(known, key)
        found = (position < len(known)) & (known[np.minimum(position, len(known) - 1)] == key) if len(known) else \
            np.zeros(len(xyz), dtype=bool)
        reach = self.reach if self.reach is not None else np.full(len(self.floors), ABOVE_TOLERANCE_M)
        for k in np.unique(position[found]):
            rows = np.flatnonzero(found & (position == k))
            span = slice(self.starts[k], self.starts[k + 1])
            out[rows] = _highest_below(self.floors[span], reach[span], xyz[rows, 2])
        rest = np.flatnonzero(~found)
        if len(rest):
            scene_reach = self.scene_reach if self.scene_reach is not None else \
                np.full(len(self.scene_floors), ABOVE_TOLERANCE_M)
            out[rest] = _highest_below(self.scene_floors, scene_reach, xyz[rest, 2])
        return out


_TILE_OFFSET = 1 << 23  # tile indices within +-2**23 (16,000 km of 2 m tiles)


def storey_of(floor_map: FloorMap, floor: np.ndarray) -> np.ndarray:
    """(N,) int64 storey of points whose floors (N,) are ``floor`` (from ``floor_under``): the
    index of the scene's floor nearest it (a split level joins the storey it is part of)."""
    scene = floor_map.scene_floors
    index = np.clip(np.searchsorted(scene, floor), 1, max(len(scene) - 1, 1))
    if len(scene) == 1:
        return np.zeros(len(floor), dtype=np.int64)
    lower = scene[index - 1]
    upper = scene[np.minimum(index, len(scene) - 1)]
    return np.where(np.abs(floor - lower) <= np.abs(upper - floor), index - 1, index).astype(np.int64)


def _tile_key(tile: np.ndarray) -> np.ndarray:
    return ((tile[:, 0] + _TILE_OFFSET) << 24) | (tile[:, 1] + _TILE_OFFSET)


def _highest_below(floors: np.ndarray, reach: np.ndarray, z: np.ndarray) -> np.ndarray:
    """For each z, the highest of ``floors`` (ascending) at most its ``reach`` above it, else the
    lowest (floors are more than ABOVE_TOLERANCE_M >= reach apart, so floors - reach ascend too)."""
    index = np.searchsorted(floors - reach, z, side="right") - 1
    return floors[np.maximum(index, 0)]


def _reach(column: _Column, z: float) -> float:
    """How far below floor ``z`` (metres from the map's origin, a bin boundary) a point still lies on
    it: ``ABOVE_TOLERANCE_M``, or less when a ceiling lies closer under it. A ceiling is a layer
    whose surfaces face down (room air under them) over a candidate's share of the column's cells;
    its run of bins starts at its bottom bin and may take the next, and the floor's own run is
    another (an empty bin parts them), so the floor's points lie above the ceiling's run."""
    top = int(round(z / BIN_M)) - column.low
    many = max(UPWARD_FRACTION * column.footprint, 3)
    for depth in range(1, int(round(ABOVE_TOLERANCE_M / BIN_M)) + 3):
        b = top - depth
        if 0 <= b < len(column.downward) and column.downward[b] >= many and column.downward[b] > column.upward[b]:
            return min(ABOVE_TOLERANCE_M, max(depth - 2, 0) * BIN_M)
    return ABOVE_TOLERANCE_M


def _decode(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell x, cell y and height bin of occupancy keys."""
    cx = (keys >> (_CELL_BITS + _BIN_BITS)) - (1 << (_CELL_BITS - 1))
    cy = ((keys >> _BIN_BITS) & ((1 << _CELL_BITS) - 1)) - (1 << (_CELL_BITS - 1))
    bins = (keys & ((1 << _BIN_BITS) - 1)) - (1 << (_BIN_BITS - 1))
    return cx, cy, bins


def _tile_columns(keys: np.ndarray) -> dict[int, _Column]:
    """Tile key -> the summary of its occupied cell-bins, for unique occupancy keys."""
    if len(keys) == 0:
        return {}
    cx, cy, bins = _decode(keys)
    tile_key = _tile_key(np.column_stack([np.floor_divide(cx, _CELLS_PER_TILE), np.floor_divide(cy, _CELLS_PER_TILE)]))
    order = np.argsort(tile_key, kind="stable")
    tile_key, cell, bins = tile_key[order], (cx * (1 << 32) + cy)[order], bins[order]
    starts = np.flatnonzero(np.r_[True, tile_key[1:] != tile_key[:-1]])
    ends = np.r_[starts[1:], len(tile_key)]
    return {int(tile_key[a]): _column(cell[a:b], bins[a:b]) for a, b in zip(starts.tolist(), ends.tolist(), strict=True)}


def _column(cell: np.ndarray, bins: np.ndarray) -> _Column:
    """The summary of one tile's occupied cell-bins (``cell`` ascending, ``bins`` ascending
    within a cell, as occupancy keys sort)."""
    low = int(bins.min())
    height = int(bins.max()) - low + 2
    _, cell_id = np.unique(cell, return_inverse=True)
    pairs = np.unique(np.concatenate([cell_id * height + (bins - low), cell_id * height + (bins - low - 1)]))
    pairs = pairs[(pairs % height) < height - 1]
    coverage = np.bincount(pairs % height, minlength=height)[:height - 1]
    occupied = np.bincount(bins - low, minlength=height)[:height - 1]
    # a cell's runs of adjacent occupied bins are its surfaces (a surface's noise spans a few
    # bins); the empty height above and below each, up to the next one in its cell
    same_cell = cell_id[1:] == cell_id[:-1]
    starts = np.flatnonzero(np.r_[True, ~(same_cell & (np.diff(bins) == 1))])
    ends = np.r_[starts[1:], len(bins)] - 1
    bottom, top, run_cell = bins[starts], bins[ends], cell_id[starts]
    next_same = run_cell[1:] == run_cell[:-1]
    gap = np.where(next_same, bottom[1:] - top[:-1], _NOTHING)  # between each run and the next
    gap_up, gap_down = np.r_[gap, _NOTHING], np.r_[_NOTHING, gap]
    air = int(round(AIR_M / BIN_M))
    # seen from below: room air under it (a ceiling, a slab's underside)
    faces_down = (gap_down > air) & (gap_down != _NOTHING)
    # seen from above: room air over it up to a ceiling, and under it a slab's underside or
    # nothing scanned (a ground floor); or nothing over it and a ceiling close under it (a roof
    # terrace over the top storey). Nothing over it and no ceiling under it tells nothing: the
    # terrain outside, a ceiling over the scanner's blind cone, or over a beam or a lamp
    ceiling_under = np.r_[False, faces_down[:-1] & next_same]
    faces_up = (gap_up > air) & (((gap_up != _NOTHING) & ((gap_down <= air) | (gap_down == _NOTHING)))
                                 | ((gap_up == _NOTHING) & (gap_down <= air) & ceiling_under))
    upward = np.bincount(top[faces_up] - low, minlength=height)[:height - 1]
    on_nothing = faces_up & (gap_down == _NOTHING)
    upward_on_nothing = np.bincount(top[on_nothing] - low, minlength=height)[:height - 1]
    downward = np.bincount(bottom[faces_down] - low, minlength=height)[:height - 1]
    return _Column(low=low, coverage=coverage, occupied=occupied, footprint=int(cell_id.max()) + 1,
                   upward=upward, upward_on_nothing=upward_on_nothing, downward=downward)


def _sum(columns: list[_Column]) -> _Column:
    """The column of disjoint columns together (the whole scene of its tiles)."""
    low = min(c.low for c in columns)
    high = max(c.low + len(c.coverage) for c in columns)
    sums = {name: np.zeros(high - low, np.int64)
            for name in ("coverage", "occupied", "upward", "upward_on_nothing", "downward")}
    for c in columns:
        for name, total in sums.items():
            total[c.low - low:c.low - low + len(c.coverage)] += getattr(c, name)
    return _Column(low=low, footprint=sum(c.footprint for c in columns), **sums)


def floor_map_of_tiles(tiles: dict[int, _Column], *, origin: np.ndarray) -> FloorMap:
    """The floor map of a scene from its tiles' summaries, keyed relative to ``origin`` (see the
    module docs)."""
    if not tiles:
        return FloorMap(tiles=np.zeros((0, 2), np.int64), starts=np.zeros(1, np.int64), floors=np.zeros(0),
                        scene_floors=np.array([float(origin[2])]), origin=origin)
    whole = _sum(list(tiles.values()))
    scene = _floors(whole, scene_floors=None)
    if len(scene) == 0:  # no floor anywhere: the lowest occupied height, as a last resort
        scene = np.array([float(whole.low) * BIN_M])
    keys, offsets, floors, reach = [], [0], [], []
    for key in sorted(tiles):
        found = _floors(tiles[key], scene_floors=scene)
        if len(found):
            # the scene's floors fill the storeys the tile does not show (a floor under furniture)
            missing = [z for z in scene if np.abs(found - z).min() > SCENE_MATCH_M]
            keys.append(key)
            tile_floors = np.sort(np.concatenate([found, missing])).tolist()
            floors.extend(tile_floors)
            reach.extend(_reach(tiles[key], z) for z in tile_floors)
            offsets.append(len(floors))
    key_array = np.asarray(keys, dtype=np.int64)
    tile_index = np.column_stack([(key_array >> 24) - _TILE_OFFSET, (key_array & 0xFFFFFF) - _TILE_OFFSET])
    return FloorMap(tiles=tile_index.reshape(-1, 2), starts=np.asarray(offsets, np.int64),
                    floors=np.asarray(floors, dtype=np.float64) + origin[2],
                    scene_floors=np.asarray(scene, dtype=np.float64) + origin[2], origin=origin,
                    reach=np.asarray(reach, dtype=np.float64),
                    scene_reach=np.asarray([_reach(whole, z) for z in scene], dtype=np.float64))


def _layers(column: _Column) -> list[int]:
    """The candidate floors of a column: one per run of bins where upward-facing cells are
    common (two adjacent bins together, as ``coverage``), its bin (relative to ``low``) with
    the most of them and enough coverage; a slab's two faces are apart by their facing, however
    thin the slab."""
    upward = column.upward[:-1] + column.upward[1:] if len(column.upward) > 1 else column.upward.copy()
    many = upward >= max(UPWARD_FRACTION * column.footprint, 3)
    layers, b = [], 0
    while b < len(many):
        if many[b]:
            e = b
            while e + 1 < len(many) and many[e + 1]:
                e += 1
            # the most upward faces; of equals (a surface in one bin counts in two pairs), the best covered
            best = b + int(np.argmax(upward[b:e + 1] * (column.footprint + 1) + column.coverage[b:e + 1]))
            if column.coverage[best] >= max(DENSE_FRACTION * column.footprint, 3):
                layers.append(best)
            b = e + 1
        else:
            b += 1
    return layers


def _split_level(column: _Column, layer: int, scene_floors: np.ndarray) -> bool:
    """Whether a tile's layer off the scene's floors is a floor of its own (a split level): it
    covers most of its tile, what stands on it (walls, furniture) rises from it more than
    anything stands under it (a table's legs, the chairs at it), and the scene's floor under it
    is hidden in its tile (a table stands over a floor that shows)."""
    near, far = int(round(NEAR_M / BIN_M)), int(round(FAR_M / BIN_M))
    above = column.occupied[layer + 2 + near:layer + 2 + far].sum()
    below = column.occupied[max(layer - far, 0):max(layer - near, 0)].sum()
    if column.coverage[layer] < LOCAL_FLOOR_FRACTION * max(column.footprint, _CELLS_PER_TILE**2) or \
            not above > SIDE_RATIO * below + 2:
        return False
    z = column.low + layer + 1  # in bins
    for floor in scene_floors / BIN_M:
        under = int(round(floor)) - column.low - 1  # the scene floor's layer bin in this column
        if 0 < z - floor < STOREY_M / BIN_M and 0 <= under < len(column.coverage) and \
                column.coverage[max(under - 1, 0):under + 2].max() >= DENSE_FRACTION * column.footprint:
            return False
    return True


def _floors(column: _Column, *, scene_floors: np.ndarray | None) -> np.ndarray:
    """The floors (ascending, metres, relative to the map's origin) of a column (see the module
    docs): of a tile when ``scene_floors`` is given (a candidate within ``SCENE_MATCH_M`` of one
    needs only to face up more often than down), else of the whole scene."""
    coverage, footprint = column.coverage, column.footprint
    share = FLOOR_FRACTION if scene_floors is not None else SCENE_FLOOR_FRACTION
    out: list[float] = []
    last_up = last_coverage = 0  # the last floor's upward faces and coverage (see SLAB_M)
    for layer in _layers(column):
        z = (column.low + layer + 1) * BIN_M  # the boundary of the layer's two bins
        window = slice(max(layer - 1, 0), layer + 3)  # the layer's bins and one either side (noise)
        # a surface facing down is this layer's when it starts in its bins or the one over them; one
        # starting lower is another surface (a ceiling under a thin slab seen from above: a roof
        # with a station on it), which upward runs ending in the layer cannot be
        up, down = int(column.upward[window].sum()), int(column.downward[layer:layer + 3].sum())
        bottom = scene_floors[:1] if scene_floors is not None else out[:1]  # the lowest floor known
        if len(bottom) and z - bottom[0] >= STOREY_M - 1e-9:
            # nothing scanned under a surface makes it a floor only in the bottom storey (a
            # ground floor, a split level over a crawl space): higher up, a floor stands on a
            # slab, and a surface over nothing is a ceiling over a tripod's blind cone or over a
            # floor hidden by furniture
            up -= int(column.upward_on_nothing[window].sum())
        near_scene = scene_floors is not None and bool(len(scene_floors)) and \
            np.abs(scene_floors - z).min() <= SCENE_MATCH_M
        if not (up > SIDE_RATIO * down + 2 or (near_scene and up > down)):
            continue  # a ceiling (room air under it), or nothing tells and no floor of the scene is there
        if scene_floors is not None and not near_scene and not _split_level(column, layer, scene_floors):
            continue  # a table, a counter, a bed: not a floor of its own
        if out and z - out[-1] < STOREY_M - 1e-9:
            # one slab seen twice: its top where its floor shows, its underside where the floor
            # over it is hidden and rays from below reach the underside past a suspended ceiling
            # (which makes the underside look like a floor on a slab): the floor is the top
            if z - out[-1] <= SLAB_M + 1e-9 and SIDE_RATIO * up >= last_up and \
                    coverage[layer] >= last_coverage and (len(out) == 1 or coverage[layer] >= share * footprint):
                out[-1], last_up, last_coverage = z, up, int(coverage[layer])
            continue  # else a table, a bed, a landing on the floor below
        if out and coverage[layer] < share * footprint:
            continue  # a storey above: its floor spans much of the column (a beam's underside a strip)
        out.append(z)
        last_up, last_coverage = up, int(coverage[layer])
    return np.asarray(out, dtype=np.float64)

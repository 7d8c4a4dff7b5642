"""The floor under every point, found from the points alone, as a real scan allows.

The ``height`` input feature is a point's height above its own storey's floor. A building has
several floors (storeys, split levels, a basement, landings), so one floor per scene (its lowest
points) puts every point above the first storey out of the range the network learned; the floor
must be found where the point is. Nothing but the points is used, so synthetic and real scans
get their floors the same way.

Model. The scene is cut into square tiles of ``TILE_M`` (in xy) and, inside a tile, into cells
of ``CELL_M`` and height bins of ``BIN_M``: a cell-bin is *occupied* when a point falls in it
(counts of points do not matter, so the scan's density does not). In each tile a *layer* is a
height where at least ``DENSE_FRACTION`` of the tile's occupied cells hold points (two adjacent
bins together, so a surface on a bin boundary counts once): a floor, a ceiling, a slab's
underside, a large table. Going up the layers of a tile, a layer is a *ceiling* when nothing is
above it (a roof or the top storey's ceiling), or when the next layer lies within ``SLAB_M``
above it with (almost) nothing between them (the two faces of a slab: the lower one is the
ceiling under it); every other layer is a *floor*, and a floor less than ``STOREY_M`` above the
previous floor of its tile, or covering less than ``FLOOR_FRACTION`` of it, is not one (a table, a
landing, a beam's underside). A point's floor
is the highest floor of its tile at most ``ABOVE_TOLERANCE_M`` above it (the floor's own points
lie on it); a point below every floor takes the lowest. Tiles without a floor (a floor hidden
under furniture, a tile of wall only) take the floors of the whole scene, found the same way
from all tiles at once.

A point's *storey* is the scene floor nearest its own floor (``storey_of``): blocks of the network
are cut per storey, so a column of a five-storey building is five blocks of one storey each, as
a single room is one.

This is the "nearest dominant upward-facing horizontal surface below it in its column": dominant
is the coverage test, upward-facing the slab and roof tests (a slab's top is seen from above,
its underside from below, with the slab's inside empty between them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimscan.errors import LearnError

TILE_M = 2.0
CELL_M = 0.25
BIN_M = 0.05
DENSE_FRACTION = 0.2
FLOOR_FRACTION = 0.35  # a floor above another covers at least this share of its column
SLAB_M = 1.0  # a slab (with a ceiling void) is thinner than this; a storey is taller
STOREY_M = 2.3  # floors of one tile at least this far apart (lower: a table, a landing, a beam's underside)
ABOVE_TOLERANCE_M = 0.15  # a floor's own points lie on it (noise, finishes)
BETWEEN_FRACTION = 0.05  # "nothing between" the two faces of a slab: under this share of the layer's cells
NEAR_M, FAR_M = 0.1, 0.6  # the bands beside a layer where what stands on it, or hangs under it, shows
SIDE_RATIO = 1.5  # one band this much fuller than the other tells which way a layer faces
SCENE_MATCH_M = 0.3  # a tile's layer that its sides do not explain is a floor this close to one of the scene's
LOCAL_FLOOR_FRACTION = 0.5  # a tile's floor at no floor of the scene (a split level) covers half a tile
_CELLS_PER_TILE = int(round(TILE_M / CELL_M))
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
        for k in np.unique(position[found]):
            rows = np.flatnonzero(found & (position == k))
            out[rows] = _highest_below(self.floors[self.starts[k]:self.starts[k + 1]], xyz[rows, 2])
        rest = np.flatnonzero(~found)
        if len(rest):
            out[rest] = _highest_below(self.scene_floors, xyz[rest, 2])
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


def _highest_below(floors: np.ndarray, z: np.ndarray) -> np.ndarray:
    """For each z, the highest of ``floors`` (ascending) at most ABOVE_TOLERANCE_M above it, else the lowest."""
    index = np.searchsorted(floors, z + ABOVE_TOLERANCE_M, side="right") - 1
    return floors[np.maximum(index, 0)]


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
    low = int(bins.min())
    height = int(bins.max()) - low + 2
    _, cell_id = np.unique(cell, return_inverse=True)
    pairs = np.unique(np.concatenate([cell_id * height + (bins - low), cell_id * height + (bins - low - 1)]))
    pairs = pairs[(pairs % height) < height - 1]
    coverage = np.bincount(pairs % height, minlength=height)[:height - 1]
    occupied = np.bincount(bins - low, minlength=height)[:height - 1]
    return _Column(low=low, coverage=coverage, occupied=occupied, footprint=int(cell_id.max()) + 1)


def _sum(columns: list[_Column]) -> _Column:
    """The column of disjoint columns together (the whole scene of its tiles)."""
    low = min(c.low for c in columns)
    high = max(c.low + len(c.coverage) for c in columns)
    coverage, occupied = np.zeros(high - low, np.int64), np.zeros(high - low, np.int64)
    for c in columns:
        coverage[c.low - low:c.low - low + len(c.coverage)] += c.coverage
        occupied[c.low - low:c.low - low + len(c.occupied)] += c.occupied
    return _Column(low=low, coverage=coverage, occupied=occupied, footprint=sum(c.footprint for c in columns))


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
    keys, offsets, floors = [], [0], []
    for key in sorted(tiles):
        found = _floors(tiles[key], scene_floors=scene)
        if len(found):
            # the scene's floors fill the storeys the tile does not show (a floor under furniture)
            missing = [z for z in scene if np.abs(found - z).min() > SCENE_MATCH_M]
            keys.append(key)
            floors.extend(np.sort(np.concatenate([found, missing])).tolist())
            offsets.append(len(floors))
    key_array = np.asarray(keys, dtype=np.int64)
    tile_index = np.column_stack([(key_array >> 24) - _TILE_OFFSET, (key_array & 0xFFFFFF) - _TILE_OFFSET])
    return FloorMap(tiles=tile_index.reshape(-1, 2), starts=np.asarray(offsets, np.int64),
                    floors=np.asarray(floors, dtype=np.float64) + origin[2],
                    scene_floors=np.asarray(scene, dtype=np.float64) + origin[2], origin=origin)


def _layers(column: _Column) -> list[int]:
    """The layers of a column: one per run of dense bins, its best-covered bin (relative to ``low``)."""
    coverage = column.coverage
    dense = coverage >= max(DENSE_FRACTION * column.footprint, 3)
    layers, b = [], 0
    while b < len(dense):
        if dense[b]:
            e = b
            while e + 1 < len(dense) and dense[e + 1]:
                e += 1
            layers.append(b + int(np.argmax(coverage[b:e + 1])))
            b = e + 1
        else:
            b += 1
    return layers


def _floors(column: _Column, *, scene_floors: np.ndarray | None) -> np.ndarray:
    """The floors (ascending, metres) of a column (see the module docs). A layer whose sides do
    not tell which way it faces is decided by the scene's floors when given (a floor within
    ``SCENE_MATCH_M`` of one), else by the slab and roof tests."""
    layers = _layers(column)
    coverage, occupied, low, footprint = column.coverage, column.occupied, column.low, column.footprint
    out: list[float] = []
    slab_bins, near, far = int(round(SLAB_M / BIN_M)), int(round(NEAR_M / BIN_M)), int(round(FAR_M / BIN_M))
    for i, layer in enumerate(layers):
        z = (low + layer + 1) * BIN_M  # the boundary of the layer's two bins
        if occupied[layer + 3:].sum() == 0:
            continue  # a roof, or the top storey's ceiling: nothing above it
        # what stands on a floor (walls, furniture) rises from it; what a ceiling closes hangs below it
        above = occupied[layer + 2 + near:layer + 2 + far].sum()
        below = occupied[max(layer - far, 0):max(layer - near, 0)].sum()
        if below > SIDE_RATIO * above + 2:
            continue  # a ceiling: the room is under it
        nxt = layers[i + 1] if i + 1 < len(layers) else None
        if nxt is not None and nxt - layer <= slab_bins and \
                occupied[layer + 2:nxt - 1].sum() <= BETWEEN_FRACTION * coverage[layer]:
            continue  # the underside of a slab whose top is the next layer (the floor above counts as "above" it)
        near_scene = scene_floors is not None and bool(len(scene_floors)) and \
            np.abs(scene_floors - z).min() <= SCENE_MATCH_M
        if scene_floors is not None and not near_scene and \
                coverage[layer] < LOCAL_FLOOR_FRACTION * max(footprint, _CELLS_PER_TILE**2):
            continue  # a floor of its own (a split level) covers most of its tile; a table does not
        if not above > SIDE_RATIO * below + 2 and scene_floors is not None and not near_scene:
            continue  # the sides do not tell, and no floor of the scene is there
        if out and (z - out[-1] < STOREY_M - 1e-9 or coverage[layer] < FLOOR_FRACTION * footprint):
            continue  # a storey above: its floor spans most of the column (a beam's underside a strip)
        out.append(z)
    return np.asarray(out, dtype=np.float64)

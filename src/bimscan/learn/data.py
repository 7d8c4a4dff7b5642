"""Scenes for training and evaluation: discovery, label mapping, streamed reading, training tiles.

A *scene* is one point cloud with (optional) labels, in any format :mod:`bimscan.io` reads
(``CLOUD_FORMATS``): a bimscan cloud (LAS/LAZ/PLY/E57/NumPy folder), a real scan a user brings
(the same formats, labels in ``classification`` or a named dimension; or plain text), or an
S3DIS room. A bimscan dataset folder (``manifest.json``) stands for its finished units, an S3DIS
area or root folder for its rooms.

Labels are mapped to training ids 0..C-1 on reading (255 = unlabelled, skipped by loss and
metrics): by a mapping file when given, else by class name when the cloud stores its scheme
(bimscan clouds; S3DIS class names with the shipped mapping), else taken as they are.

Training reads every scene once, streamed, and keeps for each column (see
:mod:`bimscan.learn.blocks`) a uniform random subset of at most ``cache_points`` points (the
points with the smallest random keys, merged chunk by chunk), so memory is bounded by
columns x cache_points whatever the scene size. Those tiles can be cached on disk.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Iterator, Sequence
from contextlib import closing
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from bimscan.dataset.layout import DatasetFolder, unit_folder_cloud
from bimscan.errors import InputFileError, LearnError
from bimscan.files import atomic_output
from bimscan.io import CLOUD_FORMATS, input_format, iter_cloud_chunks, read_cloud_header
from bimscan.io.s3dis import S3DIS_CLASSES, list_s3dis_rooms
from bimscan.learn.blocks import locate_columns, encode_column_key, pad_block, sample_block, decode_column_key
from bimscan.learn.density import point_hash, voxel_hash
from bimscan.learn.features import extra_features
from bimscan.learn.floors import TILE_M, FloorMapBuilder, storey_of
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES, IGNORE_LABEL, AugmentConfig, BlockConfig, InputConfig
from bimscan.learn.mapping import (
    LabelMapping, apply_label_table, build_label_table, load_s3dis_mapping,
)
from bimscan.types import CloudHeader, PointCloud

ASPRS_UNCLASSIFIED = (0, 1)
GREY = 128  # the colour of a point whose scene has none, for a network that reads colour  # LAS classification "created, never classified" and "unclassified"
CHUNK_POINTS = 1_000_000
# a scene wider than this or taller than BUILDING_HEIGHT_M, read as metres, is likely in another unit
BUILDING_EXTENT_M = 2_000.0
BUILDING_HEIGHT_M = 300.0
# the units a scan brought to bimscan is likely in when not metres: (name, units per metre), smallest first
OTHER_UNITS = (("millimetres", 1000.0), ("centimetres", 100.0), ("inches", 39.37), ("feet", 3.281))


@dataclass(frozen=True)
class SceneSource:
    """One scene to read: where, what kind, how its labels map.

    ``kind``: the scene's format name in ``bimscan.io.CLOUD_FORMATS`` ("las", "laz", "ply", "e57",
    "npy", "text", or "s3dis" for an S3DIS room).
    """

    path: Path
    kind: str
    name: str
    label_field: str | None = None
    mapping: LabelMapping | None = None


def _scene_format(path: Path) -> str | None:
    """The ``bimscan.io`` format name of a path holding one cloud, None for anything else."""
    try:
        return input_format(path)
    except InputFileError:
        return None


def _dataset_units(path: Path) -> list[tuple[str, Path]]:
    folder = DatasetFolder(path)
    units = [(entry.id, entry.cloud_file(path)) for entry in folder.read_manifest().done()]
    if not units:
        raise LearnError(f"{path}: the dataset has no unit with status 'done'; build it first (or resume the build)")
    return units


def list_scenes(
    paths: Sequence[str | Path], *, label_field: str | None = None, mapping: LabelMapping | None = None,
) -> list[SceneSource]:
    """Expand user paths into scenes: datasets into their done units (a unit folder is its cloud),
    S3DIS areas into rooms.

    ``label_field`` names the field holding the labels: a LAS/LAZ dimension, a PLY property, a
    NumPy folder's ``<name>.npy``, a column named in a text cloud's header line. S3DIS rooms have
    no fields (their labels are the annotation file names) and do not take it, so a list of
    S3DIS rooms only with a ``label_field`` is refused. Raises InputFileError for paths that do
    not exist or hold no known kind of scene.
    """
    scenes: list[SceneSource] = []
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise InputFileError(f"{path}: no such file or folder; check the path")
        if path.is_dir() and DatasetFolder(path).is_dataset():
            for unit_id, unit_path in _dataset_units(path):
                scenes.append(SceneSource(unit_path, input_format(unit_path), unit_id, label_field, mapping))
        elif path.is_dir() and (cloud := unit_folder_cloud(path)) is not None:  # one unit of a dataset
            scenes.append(SceneSource(cloud, input_format(cloud), path.name, label_field, mapping))
        elif (kind := _scene_format(path)) is not None:
            name = path.name if path.is_dir() else path.stem
            scenes.append(SceneSource(path, kind, name, None if kind == "s3dis" else label_field, mapping))
        elif path.is_dir() and (rooms := list_s3dis_rooms(path)):
            for room in rooms:  # an S3DIS area or root folder
                scenes.append(SceneSource(room, "s3dis", f"{room.parent.name}/{room.name}", None, mapping))
        else:
            suffixes = "/".join(suffix for suffixes in CLOUD_FORMATS.values() for suffix in suffixes if suffix)
            raise InputFileError(f"{path}: not a scene; pass a {suffixes} cloud, a bimscan NumPy cloud folder, "
                                 "dataset folder or unit folder, or an S3DIS room/area folder")
    seen: dict[Path, SceneSource] = {}
    for scene in scenes:
        first = seen.setdefault(scene.path.resolve(), scene)
        if first is not scene:
            raise LearnError(f"{scene.path}: scene {scene.name!r} is listed twice (also as {first.name!r}); name each "
                             "scene once (a scene set's weight draws its blocks more often)")
    if label_field is not None and scenes and all(s.kind == "s3dis" for s in scenes):
        raise LearnError(
            f"label field {label_field!r} cannot apply to S3DIS rooms: their labels are the annotation file "
            "names; drop --label-field (a scene set's label_field)"
        )
    return scenes


def stored_header(source: SceneSource) -> CloudHeader | None:
    """The CloudHeader bimscan stored with the scene, or None (foreign files, text, S3DIS)."""
    return read_cloud_header(source.path)


def build_scene_label_table(
    source: SceneSource, *, class_names: Sequence[str], header: CloudHeader | None = None,
) -> np.ndarray:
    """The (256,) int16 table mapping this scene's label ids to training ids.

    ``header``: the scene's stored header when the caller has read it already.
    """
    if source.kind == "s3dis":
        mapping = source.mapping or load_s3dis_mapping()
        return build_label_table(
            class_names=class_names, mapping=mapping, source_names=dict(enumerate(S3DIS_CLASSES)),
        )
    names = None
    if source.label_field is None:
        header = header if header is not None else stored_header(source)
        if header is not None:
            names = header.scheme.names
    return build_label_table(class_names=class_names, mapping=source.mapping, source_names=names)


def require_labels(sources: Sequence[SceneSource], *, class_names: Sequence[str], where: str) -> None:
    """LearnError naming the first scene whose first points carry no label of ``class_names``
    (a cloud without a label column, or labels its mapping sends nowhere): scored scenes are
    checked in seconds, before any build or training. ``where``: what named them, for the message."""
    for source in sources:
        table = build_scene_label_table(source, class_names=class_names)
        first = next(iter_raw_chunks(source, chunk_points=1 << 16), None)
        if first is None or first.label is None:
            raise LearnError(f"{source.path}: holds no labels ({where}: scenes to score on need ground truth); give "
                             "a labelled cloud, or name its label column or dimension (label_field)")
        if not (table[first.label.astype(np.int64)] != IGNORE_LABEL).any():
            raise LearnError(f"{source.path}: none of its first {len(first):,} points has a label of the classes "
                             f"{', '.join(class_names)} ({where}); check its labels and the scene set's mapping")


def likely_unit(wide: float, tall: float) -> str | None:
    """The first of ``OTHER_UNITS`` in which a scene ``wide`` (the larger horizontal extent) by
    ``tall`` units is building-sized and at least a storey (2 m) tall, None when none is."""
    return next((name for name, per_m in OTHER_UNITS
                 if wide / per_m <= BUILDING_EXTENT_M and 2.0 <= tall / per_m <= BUILDING_HEIGHT_M), None)


def unit_refusal(path: Path, *, lower: np.ndarray, upper: np.ndarray, points: int, columns: int,
                 blocks: BlockConfig, first: bool = False) -> str | None:
    """The one line that refuses a scene not in metres, or None: when another unit makes its extent
    (``lower``/``upper`` (3,)) building-sized and its ``points`` are spread over so many of the
    network's ``blocks.size_m`` columns (``columns``: how many hold points) that they hold fewer
    than ``blocks.min_points`` each on average. Read as metres, such a scene is labelled a nearly
    empty block at a time (a room in millimetres: a point or two per column, minutes instead of
    seconds, and labels of no use) and trains on nothing (training drops columns under
    ``min_points``). A scan in metres holds thousands of points per column, and a site of any
    size, georeferenced or not, is as dense as a room. ``first``: the points are the scene's first
    ones, not all of them (said in the message)."""
    size = upper - lower
    wide, tall = float(max(size[0], size[1])), float(size[2])
    unit = likely_unit(wide, tall)
    if unit is None or columns == 0 or points / columns >= blocks.min_points:
        return None
    which = f"first {points:,}" if first else f"{points:,}"
    return (f"{extent_line(path, wide, tall)}: it looks like {unit}, so scale it to metres first (its {which} points "
            f"spread over {columns:,} columns of {blocks.size_m:g} m, {points / columns:.1f} per column, under [blocks] min_points = {blocks.min_points}: "
            "read as metres, every block would be nearly empty)")


def column_cells(xyz: np.ndarray, size_m: float) -> np.ndarray:
    """(M, 2) float64: the distinct ``size_m`` square columns (x and y indices) the points (N, 3)
    occupy, sorted; floats, so that no extent overflows them."""
    return distinct_rows(np.floor(xyz[:, :2] / size_m))


def distinct_rows(cells: np.ndarray) -> np.ndarray:
    """The distinct rows of (N, 2) ``cells``, sorted (faster than ``np.unique(axis=0)``)."""
    if not len(cells):
        return cells.reshape(0, 2)
    cells = cells[np.lexsort((cells[:, 1], cells[:, 0]))]
    return cells[np.r_[True, (cells[1:] != cells[:-1]).any(axis=1)]]


def extent_line(path: Path, wide: float, tall: float) -> str:
    """"PATH: the scene is W x T units across; bimscan reads metres": the start of the lines that
    say a scene's unit looks wrong."""
    def units(value: float) -> str:
        return f"{value:,.0f}" if value < 1e12 else f"{value:.3g}"

    return f"{path}: the scene is {units(wide)} x {units(tall)} units across; bimscan reads metres"


def check_scene_unit(source: SceneSource, *, blocks: BlockConfig) -> None:
    """LearnError when the scene is by all signs in another unit than metres (``unit_refusal``),
    or holds no points or non-finite coordinates: every command that reads a scan for learning
    calls this first, before any expensive work. Reads the scene's first chunk (at most
    ``CHUNK_POINTS`` points, the whole of a room); a bimscan cloud (a stored header) is written in
    metres and is not read."""
    if stored_header(source) is not None:
        return
    with closing(iter_raw_chunks(source, labels=False)) as chunks:
        first = next((chunk for chunk in chunks if len(chunk)), None)
    if first is None:
        raise LearnError(f"{source.path}: the scene holds no points; pass a non-empty cloud")
    finite = np.isfinite(first.xyz).all(axis=1)
    if not finite.all():
        raise LearnError(f"{source.path}: {int((~finite).sum()):,} of its first {len(first):,} points have non-finite "
                         "coordinates; filter them out first")
    xyz = first.xyz
    refusal = unit_refusal(source.path, lower=xyz.min(axis=0), upper=xyz.max(axis=0), points=len(xyz),
                           columns=len(column_cells(xyz, blocks.size_m)), blocks=blocks,
                           first=len(xyz) >= CHUNK_POINTS)
    if refusal is not None:
        raise LearnError(refusal)


def _reads_asprs_classification(source: SceneSource, header: CloudHeader | None) -> bool:
    """True when the scene's labels are a foreign LAS/LAZ file's ASPRS ``classification`` taken as is."""
    return (source.kind in ("las", "laz") and header is None
            and source.label_field is None and source.mapping is None)


def iter_raw_chunks(
    source: SceneSource, *, chunk_points: int = CHUNK_POINTS, labels: bool = True,
) -> Iterator[PointCloud]:
    """The scene's points as stored (labels unmapped), in a fixed order, chunk by chunk.

    ``labels`` False: the labels are not needed (prediction); they are then neither read nor
    checked (``label`` is None).
    """
    yield from iter_cloud_chunks(source.path, chunk_points=chunk_points, label_field=source.label_field,
                                 labels=labels)


def iter_scene_chunks(
    source: SceneSource, *, class_names: Sequence[str] = DEFAULT_CLASS_NAMES, chunk_points: int = CHUNK_POINTS,
    source_classes: bool = False,
) -> Iterator[PointCloud]:
    """The scene chunk by chunk with labels mapped to training ids (255 where unlabelled).

    ``source_classes``: an S3DIS room's chunks carry each point's own S3DIS class (its index in
    ``S3DIS_CLASSES``) as their ``component``, as a bimscan cloud's carry the component a point
    lies on: where each class of the source went (evaluation's breakdown).

    Every chunk carries ``label`` (N,) uint8; coordinates are checked to be finite. A foreign
    LAS/LAZ whose ``classification`` holds only ASPRS 0/1 ("never classified"/"unclassified")
    has no ground truth: LearnError once the stream ends (before any result is used), unless a
    label field or a mapping says where its labels are.
    """
    header = stored_header(source)
    table = build_scene_label_table(source, class_names=class_names, header=header)
    asprs = _reads_asprs_classification(source, header)
    classified = False
    for chunk in iter_raw_chunks(source, chunk_points=chunk_points):
        if not np.isfinite(chunk.xyz).all():
            bad = int((~np.isfinite(chunk.xyz)).any(axis=1).sum())
            raise LearnError(f"{source.path}: {bad} points have non-finite coordinates; filter them out first")
        if chunk.label is None:
            label = np.full(len(chunk), IGNORE_LABEL, dtype=np.uint8)
        else:
            if asprs and not classified:
                classified = bool((chunk.label > max(ASPRS_UNCLASSIFIED)).any())
            label = apply_label_table(chunk.label, table, where=str(source.path))
        if source_classes and source.kind == "s3dis" and chunk.label is not None:
            chunk = replace(chunk, component=chunk.label.astype(np.int32))
        yield replace(chunk, label=label)
    if asprs and not classified:
        raise LearnError(
            f"{source.path}: no ground-truth labels: its LAS classification is only 0/1 (never classified/"
            "unclassified); pass --label-field (a scene set's label_field) naming the dimension with the labels, or "
            "--mapping (a scene set's mapping)"
        )


def read_labelled_cloud(
    path: str | Path, *, label_field: str | None = None, mapping: LabelMapping | None = None,
    class_names: Sequence[str] = DEFAULT_CLASS_NAMES,
) -> PointCloud:
    """Read one scene whole, labels mapped to training ids (see the module docstring).

    For big scenes prefer :func:`iter_scene_chunks`. ``path`` must name exactly one scene.
    """
    scenes = list_scenes([path], label_field=label_field, mapping=mapping)
    if len(scenes) != 1:
        raise LearnError(f"{path}: holds {len(scenes)} scenes; load them one by one (list_scenes)")
    return PointCloud.concatenate(list(iter_scene_chunks(scenes[0], class_names=class_names)))


# ---------------------------------------------------------------- training tiles


@dataclass(frozen=True)
class TileSet:
    """Columns of one or more scenes, each holding a random subset of its points.

    xyz (P, 3) float32 metres relative to the tile's ``origin``; label (P,) uint8 training ids;
    offsets (T+1,) int64 into xyz/label; origin (T, 3) float64; key (T,) int64 column key;
    count (T,) int64 points of the whole column; scene (T,) int32 index into ``scene_names``;
    height (P,) float32 metres of each point above the floor under it (:mod:`bimscan.learn.floors`).
    """

    xyz: np.ndarray
    label: np.ndarray
    offsets: np.ndarray
    origin: np.ndarray
    key: np.ndarray
    count: np.ndarray
    scene: np.ndarray
    scene_names: tuple[str, ...]
    height: np.ndarray
    rgb: np.ndarray | None = None  # (P, 3) uint8 colour of each point (tiles collected with colour)

    def __len__(self) -> int:
        return int(len(self.offsets) - 1)

    def tile_points(self, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, 3) float64 relative coordinates, (M,) uint8 labels and (M,) float64 heights above
        the floor of one tile."""
        lo, hi = int(self.offsets[index]), int(self.offsets[index + 1])
        return self.xyz[lo:hi].astype(np.float64), self.label[lo:hi], self.height[lo:hi].astype(np.float64)

    def tile_rgb(self, index: int) -> np.ndarray | None:
        """(M, 3) uint8 colour of one tile's points (None: collected without colour)."""
        if self.rgb is None:
            return None
        return self.rgb[int(self.offsets[index]):int(self.offsets[index + 1])]

    @staticmethod
    def concatenate(parts: Sequence[TileSet]) -> TileSet:
        """Join tile sets of different scenes (scene indices renumbered)."""
        names: list[str] = []
        scenes, offsets, total = [], [np.zeros(1, np.int64)], 0
        for part in parts:
            scenes.append(part.scene + len(names))
            names.extend(part.scene_names)
            offsets.append(part.offsets[1:] + total)
            total += int(part.offsets[-1])
        return TileSet(
            xyz=np.concatenate([p.xyz for p in parts]) if parts else np.empty((0, 3), np.float32),
            label=np.concatenate([p.label for p in parts]) if parts else np.empty(0, np.uint8),
            offsets=np.concatenate(offsets),
            origin=np.concatenate([p.origin for p in parts]) if parts else np.empty((0, 3)),
            key=np.concatenate([p.key for p in parts]) if parts else np.empty(0, np.int64),
            count=np.concatenate([p.count for p in parts]) if parts else np.empty(0, np.int64),
            scene=np.concatenate(scenes).astype(np.int32) if parts else np.empty(0, np.int32),
            scene_names=tuple(names),
            height=np.concatenate([p.height for p in parts]) if parts else np.empty(0, np.float32),
            rgb=np.concatenate([p.rgb for p in parts]) if parts and all(p.rgb is not None for p in parts) else None,
        )


def _scene_seed(seed: int, source: SceneSource) -> np.random.SeedSequence:
    # keyed by the scene's name so a scene samples the same whatever else is in the list
    return np.random.SeedSequence([seed, zlib.crc32(source.name.encode("utf-8"))])


def collect_scene_tiles(
    source: SceneSource, *, blocks: BlockConfig, class_names: Sequence[str], seed: int,
    chunk_points: int = CHUNK_POINTS, grid_m: float = 0.0, per_station: bool = False, labelled: bool = True,
    colour: bool = False,
) -> TileSet:
    """Stream one scene into its training columns, keeping <= ``blocks.cache_points`` each.

    ``colour``: keep each point's colour too (``TileSet.rgb``); a scene without colour gets mid
    grey (128), as a network trained with colour sees a scan without it.

    Each point gets a random key; each column keeps its points with the smallest keys, i.e. a
    uniform random subset without replacement, independent of how the stream is chunked.
    Columns with fewer than ``blocks.min_points`` points or no labelled point are dropped.
    ``labelled`` False: an unlabelled scene (domain adaptation): its labels are never read (every
    label is 255) and its columns are kept whatever they hold.

    With ``grid_m`` > 0 (density normalisation, :mod:`bimscan.learn.density`) the key is a hash
    of the point's voxel, the same for all its points, and of the points sharing a voxel only the
    one with the smallest coordinate hash is kept: each column keeps a uniform random subset of
    its occupied voxels, one point each, whatever the stream's order and chunking.

    With ``per_station`` (and a scene that records its stations) every station's points make
    their own columns: a column then holds what one tripod saw, one side of each wall, as a
    scan of one room does, instead of both faces of a wall and the rooms behind it.

    Cost: a chunk's points that cannot enter their (full) column are dropped by one lookup;
    the rest wait until they are a quarter of the kept points, then are sorted and merged
    with the (already sorted) kept ones in one stable sort and cut back to ``cache_points``
    per column, each column gathered once. The kept points are never re-sorted per chunk.
    """
    limit = blocks.cache_points
    rng = np.random.default_rng(_scene_seed(seed, source))
    # kept: the smallest keys per column so far, sorted by (column, key); pending: later
    # candidates in stream order, merged in by _keep_smallest once they are a quarter of kept
    kept_key, kept_prio = np.empty(0, np.int64), np.empty(0, np.float64)
    kept_xyz = np.empty((0, 3), np.float64)
    kept_label = np.empty((0, 4) if colour else 0, np.uint8)
    pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    pending_points = 0
    full_key = np.empty(0, np.int64)  # columns holding `limit` kept points, with their largest key
    full_prio = np.empty(0, np.float64)
    column_keys: list[np.ndarray] = []
    column_counts: list[np.ndarray] = []
    floors = FloorMapBuilder()  # the floor under every point (from all of them, stations merged): a first pass
    def chunks() -> Iterator[PointCloud]:
        if labelled:
            return iter_scene_chunks(source, class_names=class_names, chunk_points=chunk_points)
        return (replace(chunk, label=np.full(len(chunk), IGNORE_LABEL, dtype=np.uint8))
                for chunk in iter_raw_chunks(source, chunk_points=chunk_points, labels=False))

    for chunk in chunks():
        floors.add(chunk.xyz)
    floor_map = floors.build()
    # column indices count from the column of the floor map's origin (the scene's first points),
    # so that georeferenced scans (a UTM northing of 5,400 km is 1.8 million 3 m columns) stay
    # inside the key's per-station and per-storey index ranges; the grid itself stays anchored at
    # multiples of size_m, so the tiles and their order are those of the same points at the origin
    anchor = np.floor(floor_map.origin[:2] / blocks.size_m).astype(np.int64)
    if len(floor_map.tiles):
        span_m = float((floor_map.tiles.max(axis=0) - floor_map.tiles.min(axis=0) + 1).max() * TILE_M)
        if span_m / blocks.size_m + 1 >= _STATION_SHIFT // 2:
            raise LearnError(f"{source.path}: the scene spans {span_m / 1000:,.0f} km, more than training columns of "
                             f"{blocks.size_m:g} m can number; cut it into buildings or sites")
    for chunk in chunks():
        floor = floor_map.floor_under(chunk.xyz)
        ix, iy = locate_columns(chunk.xyz[:, :2], size_m=blocks.size_m)
        ix, iy = ix - anchor[0], iy - anchor[1]
        iy = iy + storey_of(floor_map, floor) * _STOREY_SHIFT  # a column of a building is one block per storey
        if per_station and chunk.station is not None:
            if len(chunk.station) and int(chunk.station.max()) >= _MAX_STATIONS:
                raise LearnError(
                    f"{source.path}: station id {int(chunk.station.max())}: per-station training columns take "
                    f"station ids below {_MAX_STATIONS}; set [blocks] train_columns = \"scene\" for this data"
                )
            ix = ix + chunk.station.astype(np.int64) * _STATION_SHIFT
        key = encode_column_key(ix, iy)
        unique, unique_counts = np.unique(key, return_counts=True)
        column_keys.append(unique)
        column_counts.append(unique_counts)
        xyz, label = chunk.xyz, chunk.label
        if colour:  # the colour rides along with the label: (label, r, g, b) columns
            rgb = chunk.rgb if chunk.rgb is not None else np.full((len(chunk), 3), GREY, dtype=np.uint8)
            label = np.column_stack([label, rgb])
        if grid_m > 0:
            voxel = voxel_hash(xyz, grid_m, seed=seed)
            # one point per (column, voxel) within the chunk (smallest coordinate hash), as
            # _keep_smallest does across chunks: the same tiles whatever the chunking (a voxel
            # seen by two stations stays in both stations' columns)
            order = np.lexsort((point_hash(xyz), voxel, key))
            if len(order):
                sorted_voxel, sorted_key = voxel[order], key[order]
                new_run = (sorted_voxel[1:] != sorted_voxel[:-1]) | (sorted_key[1:] != sorted_key[:-1])
                first = order[np.r_[True, new_run]]
            else:
                first = order
            first.sort()
            key, xyz, label = key[first], xyz[first], label[first]
            prio = (voxel[first] >> np.uint64(11)).astype(np.float64) * 2.0**-53
        else:
            prio = rng.random(len(key))
        if len(full_key):
            # points above their full column's largest kept key can never enter it (with a grid,
            # a point of the largest kept voxel still can: it may be that voxel's representative)
            pos = np.clip(np.searchsorted(full_key, key), 0, len(full_key) - 1)
            threshold = np.where(full_key[pos] == key, full_prio[pos], np.inf)
            take = prio <= threshold if grid_m > 0 else prio < threshold
            key, prio, xyz, label = key[take], prio[take], xyz[take], label[take]
        pending.append((key, prio, xyz, label))
        pending_points += len(key)
        if pending_points >= len(kept_key) // 4:  # measured: a quarter beats a half or a tenth
            kept_key, kept_prio, kept_xyz, kept_label, full_key, full_prio = _keep_smallest(
                [(kept_key, kept_prio, kept_xyz, kept_label), *pending], limit=limit, one_per_key=grid_m > 0,
            )
            pending, pending_points = [], 0
    if pending:
        kept_key, kept_prio, kept_xyz, kept_label, _, _ = _keep_smallest(
            [(kept_key, kept_prio, kept_xyz, kept_label), *pending], limit=limit, one_per_key=grid_m > 0,
        )
    if column_keys:
        keys, inverse = np.unique(np.concatenate(column_keys), return_inverse=True)
        totals = np.bincount(inverse, weights=np.concatenate(column_counts)).astype(np.int64)
        counts = dict(zip(keys.tolist(), totals.tolist(), strict=True))
    else:
        counts = {}
    height = kept_xyz[:, 2] - floor_map.floor_under(kept_xyz)
    kept_rgb = kept_label[:, 1:4] if colour else None
    kept_label = kept_label[:, 0] if colour else kept_label
    return _tiles_from_points(source, kept_key, kept_xyz, kept_label, height, counts, blocks=blocks,
                              labelled=labelled, rgb=kept_rgb, anchor=anchor)


_STATION_SHIFT = 1 << 20  # per-station columns: column x index + station x this (|x index| < 2**19)
_MAX_STATIONS = 1 << 9  # station x _STATION_SHIFT stays inside encode_column_key's |ix| < 2**30
_STOREY_SHIFT = 1 << 20  # per-storey columns: column y index + storey x this (at most 512 storeys)


def _column_x(ix: np.ndarray) -> np.ndarray:
    """The column x index without a per-station shift (identity for unshifted indices)."""
    half = _STATION_SHIFT // 2
    return (ix + half) % _STATION_SHIFT - half


def station_count(tiles: TileSet) -> int:
    """How many stations a per-station tile set's columns come from (1 for a scene without
    stations: its per-station columns are its merged ones)."""
    ix, _ = decode_column_key(tiles.key)
    return max(1, len(np.unique((ix - _column_x(ix)) // _STATION_SHIFT)))


def _column_y(iy: np.ndarray) -> np.ndarray:
    """The column y index without its per-storey shift."""
    half = _STOREY_SHIFT // 2
    return (iy + half) % _STOREY_SHIFT - half


def _keep_smallest(
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]], *, limit: int, one_per_key: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The ``limit`` points with the smallest random keys of each column among ``parts``.

    ``parts``: (column key (M,) int64, random key (M,) float64, xyz (M, 3), label (M,)) in
    stream order. Returns those four columns sorted by (column, random key), ties in stream
    order, then the full columns (F,) int64 with their largest kept random key (F,) float64.
    With ``one_per_key`` (grid sampling: the random key is the voxel's) points sharing a column
    and a key keep only the one with the smallest coordinate hash.
    """
    key = np.concatenate([p[0] for p in parts])
    prio = np.concatenate([p[1] for p in parts])
    order, sorted_column = _sort_by_column_and_key(key, prio)
    if one_per_key and len(order) > 1:
        xyz_all = np.concatenate([p[2] for p in parts])
        ordered_prio = prio[order]
        tie = (sorted_column[1:] == sorted_column[:-1]) & (ordered_prio[1:] == ordered_prio[:-1])
        if tie.any():
            run_start = np.r_[True, ~tie]  # True where a new (column, key) run begins
            run_id = np.cumsum(run_start) - 1
            tied = np.flatnonzero(np.r_[tie, False] | np.r_[False, tie])
            best = tied[np.lexsort((point_hash(xyz_all[order[tied]]), run_id[tied]))]
            first_of_run = np.r_[True, run_id[best][1:] != run_id[best][:-1]]
            keep = np.ones(len(order), dtype=bool)
            keep[tied] = False
            keep[best[first_of_run]] = True  # a run shares column and key: any position keeps the order
            order, sorted_column = order[keep], sorted_column[keep]
    n = len(order)
    starts = np.flatnonzero(np.r_[True, sorted_column[1:] != sorted_column[:-1]]) if n else np.empty(0, np.int64)
    sizes = np.diff(np.r_[starts, n])
    taken = np.minimum(sizes, limit)
    # the first min(size, limit) of each column: True/False runs, one pair per column
    keep = np.repeat(np.tile([True, False], len(starts)), np.column_stack([taken, sizes - taken]).ravel())
    index = order[keep]
    full = starts[sizes >= limit]
    return (
        key[index], prio[index], np.concatenate([p[2] for p in parts])[index],
        np.concatenate([p[3] for p in parts])[index], key[order[full]], prio[order[full + limit - 1]],
    )


def _sort_by_column_and_key(key: np.ndarray, prio: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stable argsort of (M,) column keys then (M,) random keys in [0, 1), and the sorted
    column number of each position (equal within a column).

    Same order as ``np.lexsort((prio, key))``, about three times faster: both go into one
    uint64 per point (column number within the bounding box of the columns, then as many
    leading bits of the random key as fit) sorted by one stable sort, which also merges an
    already sorted leading run in linear time; points sharing the uint64 but not the random
    key (rare) are then put in order by a lexsort of those points only.
    """
    if not len(key):
        return np.empty(0, np.int64), np.empty(0, np.uint64)
    ix, iy = key >> 32, key & 0xFFFFFFFF  # encode_column_key: ix * 2**32 + offset iy
    ix -= ix.min()
    iy -= iy.min()
    ix *= int(iy.max()) + 1
    ix += iy  # the column's number in its bounding box, ordered as the key
    del iy
    composite = ix.view(np.uint64)
    bits = min(53, 64 - int(composite.max()).bit_length())  # random keys are multiples of 2**-53
    composite <<= np.uint64(bits)
    composite |= (prio * 2.0**53).astype(np.uint64) >> np.uint64(53 - bits)
    order = np.argsort(composite, kind="stable")
    ordered = composite[order]
    tie = ordered[1:] == ordered[:-1]
    if tie.any():
        at = np.flatnonzero(np.r_[tie, False] | np.r_[False, tie])
        sub = order[at]
        order[at] = sub[np.lexsort((prio[sub], composite[sub]))]  # stable: stream order kept
    return order, ordered >> np.uint64(bits)


def _tiles_from_points(
    source: SceneSource, key: np.ndarray, xyz: np.ndarray, label: np.ndarray, height: np.ndarray,
    counts: dict[int, int], *, blocks: BlockConfig, anchor: np.ndarray, labelled: bool = True,
    rgb: np.ndarray | None = None,
) -> TileSet:
    """The tiles of a scene's kept points, sorted by column ``key`` (indices counted from the
    column ``anchor`` (2,) int64, see ``collect_scene_tiles``)."""
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.empty(0, np.int64)
    ends = np.r_[starts[1:], len(key)].astype(np.int64) if len(key) else np.empty(0, np.int64)
    parts_xyz, parts_label, parts_height, parts_rgb, offsets, origins, keys, totals = [], [], [], [], [0], [], [], []
    for start, end in zip(starts.tolist(), ends.tolist(), strict=True):
        column = int(key[start])
        labels = label[start:end]
        if counts[column] < blocks.min_points or (labelled and not (labels != IGNORE_LABEL).any()):
            continue
        ix, iy = decode_column_key(np.array([column]))
        ix, iy = _column_x(ix) + anchor[0], _column_y(iy) + anchor[1]
        origin = np.array([ix[0] * blocks.size_m, iy[0] * blocks.size_m, float(xyz[start:end, 2].min())])
        parts_xyz.append((xyz[start:end] - origin).astype(np.float32))
        parts_label.append(labels)
        parts_height.append(height[start:end].astype(np.float32))
        if rgb is not None:
            parts_rgb.append(rgb[start:end])
        offsets.append(offsets[-1] + end - start)
        origins.append(origin)
        keys.append(column)
        totals.append(counts[column])
    return TileSet(
        xyz=np.concatenate(parts_xyz) if parts_xyz else np.empty((0, 3), np.float32),
        label=np.concatenate(parts_label) if parts_label else np.empty(0, np.uint8),
        offsets=np.asarray(offsets, dtype=np.int64),
        origin=np.asarray(origins, dtype=np.float64).reshape(-1, 3),
        key=np.asarray(keys, dtype=np.int64),
        count=np.asarray(totals, dtype=np.int64),
        scene=np.zeros(len(keys), dtype=np.int32),
        scene_names=(source.name,),
        height=np.concatenate(parts_height) if parts_height else np.empty(0, np.float32),
        rgb=None if rgb is None else (np.concatenate(parts_rgb) if parts_rgb else np.empty((0, 3), np.uint8)),
    )


def _fingerprint(path: Path) -> list[object]:
    """Name, size and modification time of a file, or of every file in a folder tree."""
    if path.is_file():
        stat = path.stat()
        return [str(path.resolve()), stat.st_size, stat.st_mtime_ns]
    rows: list[object] = [str(path.resolve())]
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        stat = file.stat()
        rows.append([str(file.relative_to(path)), stat.st_size, stat.st_mtime_ns])
    return rows


def name_tile_cache(
    source: SceneSource, *, blocks: BlockConfig, class_names: Sequence[str], seed: int, grid_m: float = 0.0,
    per_station: bool = False, labelled: bool = True, colour: bool = False,
) -> str:
    """File name of a scene's cached tiles: a digest of everything the tiles depend on."""
    recipe = {  # version: what collecting does (9: column indices count from the scene's first column)
        "version": 9, "scene": _fingerprint(source.path), "name": source.name, "kind": source.kind,
        "label_field": source.label_field, "mapping": None if source.mapping is None else asdict(source.mapping),
        "blocks": asdict(blocks), "class_names": list(class_names), "seed": seed, "grid_m": grid_m,
        "per_station": per_station, **({} if labelled else {"unlabelled": True}), **({"colour": True} if colour else {}),
    }
    digest = hashlib.sha256(json.dumps(recipe, sort_keys=True, default=str).encode()).hexdigest()[:24]
    return f"tiles-{digest}.npz"


def load_or_collect_tiles(
    source: SceneSource, *, blocks: BlockConfig, class_names: Sequence[str], seed: int,
    cache_dir: Path | None = None, build: bool = True, grid_m: float = 0.0, per_station: bool = False,
    labelled: bool = True, colour: bool = False,
) -> TileSet:
    """Tiles of one scene, from ``cache_dir`` when cached there, else collected (and cached).

    With ``build`` False a missing cache entry is an error (DDP ranks other than 0 only read).
    ``labelled`` False: an unlabelled scene (see ``collect_scene_tiles``).
    """
    if cache_dir is None:
        return collect_scene_tiles(source, blocks=blocks, class_names=class_names, seed=seed, grid_m=grid_m,
                                   per_station=per_station, labelled=labelled, colour=colour)
    path = cache_dir / name_tile_cache(source, blocks=blocks, class_names=class_names, seed=seed, grid_m=grid_m,
                                       per_station=per_station, labelled=labelled, colour=colour)
    if path.is_file():
        with np.load(path) as data:
            return TileSet(
                xyz=data["xyz"], label=data["label"], offsets=data["offsets"], origin=data["origin"],
                key=data["key"], count=data["count"], scene=data["scene"], scene_names=(source.name,),
                height=data["height"], rgb=data["rgb"] if "rgb" in data.files else None,
            )
    if not build:
        raise LearnError(f"{path}: tile cache missing (rank 0 should have written it); rerun the training")
    tiles = collect_scene_tiles(source, blocks=blocks, class_names=class_names, seed=seed, grid_m=grid_m,
                                per_station=per_station, labelled=labelled, colour=colour)
    cache_dir.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as temp, temp.open("wb") as out:
        np.savez(
            out, xyz=tiles.xyz, label=tiles.label, offsets=tiles.offsets, origin=tiles.origin,
            key=tiles.key, count=tiles.count, scene=tiles.scene, height=tiles.height,
            **({} if tiles.rgb is None else {"rgb": tiles.rgb}),
        )
    return tiles


class TileDataset:
    """Map-style dataset of training blocks drawn from a :class:`TileSet`.

    Items are addressed by ``(epoch, tile)`` keys: the block of a tile in an epoch is a random
    sample seeded by (seed, epoch, tile), so it is the same whatever process, worker or order
    draws it (the basis of exact resume and of DDP = one process). Each item is a dict of
    ``xyz`` (N, D) float32 (normalised xyz, then the ``inputs`` features), ``label`` (N,) int64
    (255 = ignore/padding), ``mask`` (N,) bool. With ``augment`` the sampled points are
    augmented (:mod:`bimscan.learn.augment`) before the features are computed from them.
    """

    def __init__(
        self, tiles: TileSet, *, points: int, seed: int, inputs: InputConfig | None = None,
        augment: AugmentConfig | None = None,
    ) -> None:
        self.tiles = tiles
        self.points = points
        self.seed = seed
        self.inputs = inputs or InputConfig(grid_m=0.0, features=("xyz",))
        self.augment = augment if augment is not None and augment.enabled else None

    def __len__(self) -> int:
        return len(self.tiles)

    def __getitem__(self, key: tuple[int, int]) -> dict[str, np.ndarray]:
        epoch, index = key
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, epoch, index]))
        xyz, label, height = self.tiles.tile_points(index)
        if self.augment is None and self.inputs.features == ("xyz",):
            block = sample_block(xyz, label, points=self.points, rng=rng)  # the paper's block, bit for bit
            return {"xyz": block.xyz, "label": block.label, "mask": block.mask}
        return draw_block(xyz, label, height, points=self.points, rng=rng, inputs=self.inputs, augment=self.augment,
                          rgb=self.tiles.tile_rgb(index))


def draw_block(xyz: np.ndarray, label: np.ndarray, height: np.ndarray, *, points: int, rng: np.random.Generator,
               inputs: InputConfig, augment: AugmentConfig | None,
               rgb: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """One training block of a tile's points (M, 3) float64 metres with their labels (M,) uint8,
    heights above the floor (M,) and colours (M, 3) uint8 (or None): ``points`` drawn without
    replacement, augmented (``augment``, None: not), its input features computed; a dict of
    ``xyz`` (N, D) float32, ``label`` (N,) int64 and ``mask`` (N,) bool (see ``TileDataset``)."""
    from bimscan.learn.augment import augment_colour, augment_points

    m = len(xyz)
    lower, upper = xyz.min(axis=0), xyz.max(axis=0)  # the whole block's box, as sample_block and inference use
    chosen = np.sort(rng.choice(m, size=points, replace=False)) if m > points else np.arange(m)
    xyz, label, height = xyz[chosen], label[chosen], height[chosen]
    rgb = None if rgb is None else rgb[chosen]
    if augment is not None and augment.enabled:
        xyz, kept, z_scale = augment_points(xyz, config=augment, rng=rng)
        label, chosen, height = label[kept], chosen[kept], height[kept] * z_scale  # a taller storey
        lower, upper = xyz.min(axis=0), xyz.max(axis=0)
        if rgb is not None:
            rgb = augment_colour(rgb[kept], config=augment, rng=rng)
    extra = extra_features(xyz, features=inputs.features, height_m=height, height_scale_m=inputs.height_scale_m,
                           neighbours=inputs.normal_neighbours, wide_neighbours=inputs.wide_neighbours, rgb=rgb)
    block = pad_block(xyz, label, chosen, points=points, lower=lower, upper=upper, extra=extra)
    return {"xyz": block.xyz, "label": block.label, "mask": block.mask}

"""Label every point of a scene with a trained network, in bounded memory, at a cost that follows
the scene's voxels and not its raw points.

Blocks are the training columns (``size_m`` square, full height) slid every ``stride_m``
(``EvalConfig``; k = size / stride overlapping columns along x and along y), and each point's
class is the argmax of the softmax summed over every block pass that saw it.

1. One streamed pass writes the points (xyz, ground truth, original index) into one temporary
   file per x-stripe of width ``stride_m``, counted from the scene's own origin (the lower corner
   of its first chunk), so a georeferencing offset changes neither the stripes nor the voxels;
   the scene's extent is checked for a likely unit mistake.
2. The floor under every point (:mod:`bimscan.learn.floors`) is read from the stripe files, a
   tile column at a time.
3. Stripes are read in x order. With density normalisation (``grid_m`` > 0) each stripe's points
   are reduced once to one representative per voxel (:func:`bimscan.learn.density.voxel_representatives`:
   the point nearest the voxel's centre, so the same points give the same representatives
   whatever file format rounded them); only representatives go through the network. Column i
   needs stripes i .. i+k-1; within it every row of columns is one block: its representatives
   shuffled and cut into groups of N (the last topped up with other points of the block), so each
   is seen once per block at the training density, ``votes`` times over with new shuffles.
   Blocks of fewer than N points run padded to the next power of two, not to N, so sparse
   areas cost what they hold.
4. Once no later column reaches a stripe, its labels are final: every point that is not a
   representative takes the inverse-square-distance mean of the votes of its
   ``label_neighbours`` nearest voted representatives (0: its voxel's representative's), points
   no pass saw (only with ``max_passes``) the class of their nearest voted neighbour, and the
   stripe leaves memory. Memory holds k stripes and the previous stripe's representatives.

Results reach the caller per finished stripe (``on_labels(index, prediction)``), so a caller
writes labels to disk (prediction) or only counts them (evaluation).
"""

from __future__ import annotations

import math
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from bimscan.errors import LearnError
from bimscan.files import work_folder
from bimscan.learn.blocks import Block, pad_block, plan_passes
from bimscan.learn.data import (
    BUILDING_EXTENT_M, BUILDING_HEIGHT_M, CHUNK_POINTS, GREY, SceneSource, column_cells, distinct_rows, extent_line,
    iter_raw_chunks, iter_scene_chunks, likely_unit, unit_refusal,
)
from bimscan.learn.density import voxel_representatives
from bimscan.learn.features import estimate_normals, extra_features
from bimscan.learn.floors import TILE_M, FloorMap, FloorMapBuilder, storey_of
from bimscan.learn.metrics import compute_confusion
from bimscan.learn.model import autocast_context, check_finite_outputs, flush_denormals
from bimscan.learn.regions import NORMAL_NEIGHBOURS, plane_votes
from bimscan.learn.train_config import IGNORE_LABEL, BlockConfig, EvalConfig, InputConfig
from bimscan.progress import progress_bar

SPREAD_CHUNK = 262_144  # points interpolated at a time (see spread_votes)
SPREAD_CELLS = 1.5  # voxels per cell of the vote-spreading grid (bimscan.learn.neighbours)
RECORD = np.dtype([("xyz", "<f8", (3,)), ("label", "u1"), ("index", "<i8")])
PLANE_CLASSES = ("Wall&Column", "Others")  # the classes a vertical plane's votes settle ([eval] plane_votes)


def stripe_record(*, components: bool, colour: bool) -> np.dtype:
    """A stripe file's record: ``RECORD``, with the point's component (predictions counted per
    component) and its colour (a network that reads colour) when asked."""
    fields = RECORD.descr + ([("component", "<i4")] if components else []) + ([("rgb", "u1", (3,))] if colour else [])
    return np.dtype(fields)
STRIPES_NAME = "bimscan-stripes"  # the work folder: .bimscan-stripes.<pid>-<random>.tmp in work_dir or $TMPDIR
MIN_PADDED = 16  # blocks smaller than N run padded to a power of two at least this


@dataclass(frozen=True)
class SceneLabels:
    """Summary of labelling one scene.

    ``confusion`` (C, C) int64 against the scene's ground truth (all zero without labels);
    ``lower``/``upper`` (3,) float64 metres bound the points; ``nearest_filled`` counts points
    no block pass saw (only with ``max_passes``), labelled from their nearest neighbour;
    ``network_points``: the points that went through the network (the representatives);
    ``element_counts`` (E + 1, C) int64: predictions per component id of the scene's points
    (row E: points without a component), when asked for ``elements`` = E, else None.
    """

    name: str
    points: int
    labelled: int
    confusion: np.ndarray
    blocks: int
    passes: int
    nearest_filled: int
    lower: np.ndarray
    upper: np.ndarray
    seconds: float
    network_points: int = 0
    element_counts: np.ndarray | None = None


def _seed(*parts: int) -> np.random.SeedSequence:
    return np.random.SeedSequence([p % (1 << 64) for p in parts])  # column indices may be negative


def padded_size(m: int, points: int) -> int:
    """The rows a block of ``m`` points runs with: ``points`` when full, else the next power of two
    (at least ``MIN_PADDED``): the network's masked layers give the same result either way."""
    if m >= points:
        return points
    return min(points, max(MIN_PADDED, 1 << max(m - 1, 1).bit_length()))


class BlockRunner:
    """Batches blocks through the network (blocks of one padded size together) and adds their
    softmax to ``votes`` (M, C) float32, indexed by the blocks' ``index`` (set ``votes`` before
    adding blocks; ``flush`` before reading it). Outputs that overflow stop it
    (:func:`bimscan.learn.model.check_finite_outputs`; ``name``: the model's, for the message,
    ``scene``: what it labels)."""

    def __init__(self, model: nn.Module, *, device: torch.device, batch_size: int, amp: str,
                 name: str = "the model", scene: str = "the scene") -> None:
        self.model = model
        self.name = name
        self.scene = scene
        self.device = device
        self.batch_size = batch_size
        self.amp = amp
        self.queues: dict[int, list[tuple[Block, float]]] = {}
        self.votes: np.ndarray | None = None
        self.passes = 0

    def add(self, block: Block, weight: float = 1.0) -> None:
        """Queue ``block``; its softmax counts ``weight`` times (one pass standing for identical ones)."""
        queue = self.queues.setdefault(len(block.mask), [])
        queue.append((block, weight))
        if len(queue) >= self.batch_size:
            self._run(queue)
            queue.clear()

    def flush(self) -> None:
        for queue in self.queues.values():
            if queue:
                self._run(queue)
                queue.clear()

    @torch.inference_mode()
    def _run(self, queue: list[tuple[Block, float]]) -> None:
        if self.votes is None:
            raise RuntimeError("BlockRunner.votes must be set before blocks are added")
        xyz = torch.from_numpy(np.stack([b.xyz for b, _ in queue])).to(self.device)
        mask = torch.from_numpy(np.stack([b.mask for b, _ in queue])).to(self.device)
        with autocast_context(self.device, self.amp), flush_denormals():  # the network only (see flush_denormals)
            logits = self.model(xyz, mask)
        check_finite_outputs(logits, mask, model=self.name, where=self.scene)
        probs = torch.softmax(logits.float(), dim=-1).cpu().numpy()
        for (block, weight), prob in zip(queue, probs, strict=True):
            # indices are unique within one pass, so plain fancy-index addition is exact
            self.votes[block.index[block.mask]] += prob[block.mask] if weight == 1.0 else prob[block.mask] * weight
        self.passes += len(queue)


def label_scene(
    model: nn.Module, source: SceneSource, *, class_names: Sequence[str], blocks: BlockConfig,
    evaluation: EvalConfig | None = None, inputs: InputConfig | None = None, device: torch.device | str = "cpu",
    amp: str = "off", use_labels: bool = True, work_dir: Path | None = None,
    on_labels: Callable[[np.ndarray, np.ndarray], None] | None = None, chunk_points: int = CHUNK_POINTS,
    warn: Callable[[str], None] | None = None, elements: int = 0, checkpoint: str | Path | None = None,
) -> SceneLabels:
    """Predict a class for every point of ``source`` (see the module docstring).

    ``model`` must be in eval mode. ``evaluation``: columns, votes, interpolation, passes and the
    shuffles' seed (default: ``EvalConfig()``; a seed left None counts as 0); ``inputs``: what the network was trained on (default: the paper's raw
    XYZ). ``use_labels`` False ignores the scene's labels (prediction of unlabelled or
    foreign-labelled scans). ``on_labels(index, prediction)`` receives (M,) int64 original point
    indices and (M,) uint8 classes, stripe by stripe. Temporary stripe files go to ``work_dir``
    (default: the system's temporary folder). ``warn`` receives one line
    when the scene's extent looks like another unit than metres (default: a Python warning).
    ``elements`` > 0: the scene's points carry component ids (a bimscan cloud's ``component``)
    of that many components; the predictions are counted per component (``element_counts``).
    ``checkpoint``: where ``model``'s weights came from, named when its outputs overflow.
    """
    evaluation = evaluation or EvalConfig()
    inputs = inputs or InputConfig(grid_m=0.0, features=("xyz",))
    labeller = _Labeller(model, source, class_names=class_names, blocks=blocks, evaluation=evaluation, inputs=inputs,
                         device=torch.device(device), amp=amp, seed=evaluation.seed or 0, use_labels=use_labels,
                         on_labels=on_labels, max_passes=evaluation.max_passes, elements=elements,
                         checkpoint=None if checkpoint is None else str(checkpoint))
    return labeller.run(work_dir=work_dir, chunk_points=chunk_points, warn=warn)


@dataclass
class _Stripe:
    """One x-stripe in memory: its records, its representatives (indices into the records),
    their votes (R, C) and heights above the floor (R,) (None without the height feature)."""

    records: np.ndarray
    reps: np.ndarray
    rep_of: np.ndarray
    votes: np.ndarray
    height: np.ndarray  # (R,) metres above the floor under each representative
    storey: np.ndarray  # (R,) int64 storey of each representative (blocks are cut per storey)
    cy: np.ndarray  # (R,) int64 row cell of each representative
    normal: np.ndarray | None = None  # (R, 3) each representative's plane normal (plane votes only)


@dataclass
class _Labeller:
    model: nn.Module
    source: SceneSource
    class_names: Sequence[str]
    blocks: BlockConfig
    evaluation: EvalConfig
    inputs: InputConfig
    device: torch.device
    amp: str
    seed: int
    use_labels: bool
    on_labels: Callable[[np.ndarray, np.ndarray], None] | None
    max_passes: int
    elements: int = 0
    checkpoint: str | None = None  # where the model's weights came from (messages)
    confusion: np.ndarray = field(init=False)
    element_counts: np.ndarray | None = field(init=False, default=None)
    record: np.dtype = field(init=False, default=RECORD)  # a stripe file's record
    labelled: int = 0
    nearest_filled: int = 0
    block_count: int = 0
    network_points: int = 0

    def run(self, *, work_dir: Path | None, chunk_points: int, warn: Callable[[str], None] | None) -> SceneLabels:
        started = time.perf_counter()
        classes = len(self.class_names)
        self.confusion = np.zeros((classes, classes), dtype=np.int64)
        if self.elements > 0:
            self.element_counts = np.zeros((self.elements + 1, classes), dtype=np.int64)
        self.record = stripe_record(components=self.elements > 0, colour="rgb" in self.inputs.features)
        self.plane_classes: tuple[int, int] | None = None
        if self.evaluation.plane_votes:
            missing = [name for name in PLANE_CLASSES if name not in self.class_names]
            if missing:
                raise LearnError(f"[eval] plane_votes: the model has no class {missing[0]!r} (its classes: "
                                 f"{', '.join(self.class_names)}); label without --plane-votes")
            self.plane_classes = (list(self.class_names).index(PLANE_CLASSES[0]),
                                  list(self.class_names).index(PLANE_CLASSES[1]))
        self.stride = self.evaluation.stride_for(self.blocks.size_m)
        self.k = int(round(self.blocks.size_m / self.stride))
        self.runner = BlockRunner(self.model, device=self.device, batch_size=self.evaluation.batch_size, amp=self.amp,
                                  name=self.checkpoint or "the model", scene=str(self.source.path))
        # stripe files in a hidden folder named with this process's id: removed at the end, or by the
        # next run when this one is killed (bimscan.files.work_folder)
        with work_folder(Path(work_dir or tempfile.gettempdir()) / STRIPES_NAME) as temp:
            self.folder = temp
            counts, lower, upper, self.origin = self._bucket(chunk_points)
            self.rows_from = int(np.floor((lower[1] - self.origin[1]) / self.stride))
            self.rows_to = max(self.rows_from, int(np.floor((upper[1] - self.origin[1]) / self.stride)) - self.k + 1)
            _check_extent(self.source, lower, upper, warn, points=sum(counts.values()), blocks=self.blocks,
                          columns=lambda: self._occupied_columns(counts))
            self.floor_map = self._floor_map(counts)
            self._label_stripes(counts)
        return SceneLabels(
            name=self.source.name, points=sum(counts.values()), labelled=self.labelled, confusion=self.confusion,
            blocks=self.block_count, passes=self.runner.passes, nearest_filled=self.nearest_filled, lower=lower,
            upper=upper, seconds=time.perf_counter() - started, network_points=self.network_points,
            element_counts=self.element_counts,
        )

    # -- 1. the scene into stripe files ---------------------------------------------------------

    def _bucket(self, chunk_points: int) -> tuple[dict[int, int], np.ndarray, np.ndarray, np.ndarray]:
        """Stream the scene into per-stripe record files; returns points per stripe, bounds and the
        scene's origin (the lower corner of its first chunk: stripes and voxels count from it)."""
        counts: dict[int, int] = {}
        lower = np.full(3, np.inf)
        upper = np.full(3, -np.inf)
        origin: np.ndarray | None = None
        total = 0
        chunks = (iter_scene_chunks(self.source, class_names=self.class_names, chunk_points=chunk_points,
                                    source_classes=self.elements > 0)
                  if self.use_labels else iter_raw_chunks(self.source, chunk_points=chunk_points, labels=False))
        for chunk in chunks:
            n = len(chunk)
            if n == 0:
                continue
            if not self.use_labels and not np.isfinite(chunk.xyz).all():
                raise LearnError(f"{self.source.path}: some points have non-finite coordinates; filter them out first")
            if origin is None:
                origin = chunk.xyz.min(axis=0)
            records = np.empty(n, dtype=self.record)
            records["xyz"] = chunk.xyz
            records["label"] = chunk.label if self.use_labels and chunk.label is not None else IGNORE_LABEL
            records["index"] = np.arange(total, total + n, dtype=np.int64)
            if self.element_counts is not None:
                records["component"] = chunk.component if chunk.component is not None else -1
            if "rgb" in self.record.names:  # a scan without colour: mid grey, as in training
                records["rgb"] = chunk.rgb if chunk.rgb is not None else GREY
            total += n
            lower = np.minimum(lower, chunk.xyz.min(axis=0))
            upper = np.maximum(upper, chunk.xyz.max(axis=0))
            cx = np.floor((chunk.xyz[:, 0] - origin[0]) / self.stride).astype(np.int64)
            order = np.argsort(cx, kind="stable")
            cx, records = cx[order], records[order]
            starts = np.flatnonzero(np.r_[True, cx[1:] != cx[:-1]])
            for a, b in zip(starts.tolist(), np.r_[starts[1:], n].tolist(), strict=True):
                stripe = int(cx[a])
                with (self.folder / f"{stripe}.bin").open("ab") as out:
                    records[a:b].tofile(out)
                counts[stripe] = counts.get(stripe, 0) + (b - a)
        if total == 0 or origin is None:
            raise LearnError(f"{self.source.path}: the scene holds no points; pass a non-empty cloud")
        return counts, lower, upper, origin

    def _occupied_columns(self, counts: dict[int, int]) -> int:
        """How many of the blocks' columns (``size_m`` square) hold points (one read of the stripe
        files' x and y; a column spans k stripes)."""
        cells = [column_cells(self._read(s)["xyz"] - self.origin, self.blocks.size_m) for s in counts]
        return len(distinct_rows(np.concatenate(cells)))

    def _read(self, stripe: int) -> np.ndarray:
        return np.fromfile(self.folder / f"{stripe}.bin", dtype=self.record)

    # -- 2. floors --------------------------------------------------------------------------------

    def _floor_map(self, counts: dict[int, int]) -> FloorMap:
        """The floor map from the stripe files, read in x order: the floor tiles a stripe completes
        are summarised when it is read (one stripe of margin against rounding), so memory holds a
        tile column's points, not the scene's."""
        builder = FloorMapBuilder(origin=self.origin)
        pending = np.empty((0, 3))
        for stripe in sorted(counts):
            pending = np.concatenate([pending, self._read(stripe)["xyz"]])
            tile = np.floor((pending[:, 0] - self.origin[0]) / TILE_M)
            complete = tile < math.floor(stripe * self.stride / TILE_M)
            builder.add_tiles(pending[complete])
            pending = pending[~complete]
        builder.add_tiles(pending)
        return builder.build()

    # -- 3. and 4. stripes in x order -------------------------------------------------------------

    def _load(self, stripe: int) -> _Stripe:
        records = self._read(stripe)
        xyz = records["xyz"]
        if self.inputs.grid_m > 0:
            reps, rep_of = voxel_representatives(xyz - self.origin, self.inputs.grid_m)
        else:
            reps = rep_of = np.arange(len(records), dtype=np.int64)
        rep_xyz = xyz[reps]
        floor = self.floor_map.floor_under(rep_xyz)
        height, storey = rep_xyz[:, 2] - floor, storey_of(self.floor_map, floor)
        cy = np.floor((rep_xyz[:, 1] - self.origin[1]) / self.stride).astype(np.int64)
        self.network_points += len(reps)
        return _Stripe(records=records, reps=reps, rep_of=rep_of, votes=np.zeros((len(reps), len(self.class_names)),
                       dtype=np.float32), height=height, storey=storey, cy=cy,
                       normal=estimate_normals(rep_xyz, neighbours=NORMAL_NEIGHBOURS)
                       if self.plane_classes is not None else None)

    def _label_stripes(self, counts: dict[int, int]) -> None:
        k = self.k
        stripes = sorted(counts)
        # columns inside the scene's extent only (a column over its edge sees a part of what the
        # inside one sees): each point is covered by up to k x k blocks, fewer at the edges
        last = max(stripes[0], stripes[-1] - k + 1)
        columns = sorted({i for s in stripes for i in range(max(s - k + 1, stripes[0]), min(s, last) + 1)})
        loaded: dict[int, _Stripe] = {}
        previous: _Stripe | None = None  # the last finished stripe's representatives: neighbours across its edge
        with progress_bar(total=len(columns), desc=f"labelling {self.source.name}", unit="column") as bar:
            for position, column in enumerate(columns):
                window = [s for s in range(column, column + k) if s in counts]
                for s in window:
                    if s not in loaded:
                        loaded[s] = self._load(s)
                self._column(column, [loaded[s] for s in window])
                next_column = columns[position + 1] if position + 1 < len(columns) else None
                for s in [s for s in sorted(loaded) if next_column is None or s < next_column]:
                    stripe = loaded.pop(s)
                    neighbours = [previous] if previous is not None and previous is not stripe else []
                    neighbours += list(loaded.values())
                    self._finish(stripe, neighbours)
                    previous = stripe
                bar.update(1)

    def _column(self, column: int, window: list[_Stripe]) -> None:
        """Every block of one column of stripes: rows of k cells along y, one block per storey each."""
        if not window:
            return
        k = self.k
        xyz = np.concatenate([w.records["xyz"][w.reps] for w in window])
        height = np.concatenate([w.height for w in window]) if "height" in self.inputs.features else None
        rgb = np.concatenate([w.records["rgb"][w.reps] for w in window]) if "rgb" in self.record.names else None
        storey = np.concatenate([w.storey for w in window])
        cy = np.concatenate([w.cy for w in window])
        offsets = np.cumsum([0] + [len(w.reps) for w in window])
        self.runner.votes = np.zeros((len(xyz), len(self.class_names)), dtype=np.float32)
        order = np.argsort(cy, kind="stable")
        cy_sorted = cy[order]
        rows = sorted({j for c in np.unique(cy).tolist()
                       for j in range(max(c - k + 1, self.rows_from), min(c, self.rows_to) + 1)})
        for row in rows:
            lo = int(np.searchsorted(cy_sorted, row, side="left"))
            hi = int(np.searchsorted(cy_sorted, row + k - 1, side="right"))
            if hi == lo:
                continue
            in_row = np.sort(order[lo:hi])
            for level in np.unique(storey[in_row]).tolist():  # one block per storey of the column
                self._block(column, row, level, in_row[storey[in_row] == level], xyz, height, rgb)
        self.runner.flush()
        for w, a, b in zip(window, offsets[:-1], offsets[1:], strict=True):
            w.votes += self.runner.votes[a:b]

    def _block(self, column: int, row: int, level: int, members: np.ndarray, xyz: np.ndarray,
               height: np.ndarray | None, rgb: np.ndarray | None = None) -> None:
        """The passes of one block (a column's row of cells, one storey): its points shuffled and
        cut into groups of N, ``votes`` times."""
        blocks, evaluation = self.blocks, self.evaluation
        points = xyz[members]
        heights = None if height is None else height[members]
        colours = None if rgb is None else rgb[members]
        box_lower, box_upper = points.min(axis=0), points.max(axis=0)
        # not seeded by the storey: a storey's blocks are cut as they would be were it scanned alone
        rng = np.random.default_rng(_seed(self.seed, column, row))
        if len(members) <= blocks.points:  # every vote would pass the same points in the same order: one pass counts for all
            groups, weight = plan_passes(len(members), points=blocks.points, rng=rng), float(evaluation.votes)
        else:
            groups = [group for _ in range(evaluation.votes)
                      for group in plan_passes(len(members), points=blocks.points, rng=rng, max_passes=self.max_passes)]
            weight = 1.0
        for group in groups:
            extra = extra_features(points[group], features=self.inputs.features,
                                   height_m=None if heights is None else heights[group],
                                   height_scale_m=self.inputs.height_scale_m, neighbours=self.inputs.normal_neighbours,
                                   wide_neighbours=self.inputs.wide_neighbours,
                                   rgb=None if colours is None else colours[group])
            self.runner.add(pad_block(points[group], None, members[group], points=padded_size(len(group), blocks.points),
                                      lower=box_lower, upper=box_upper, extra=extra), weight)
        self.block_count += 1

    def _finish(self, stripe: _Stripe, neighbours: list[_Stripe]) -> None:
        """Final labels of a stripe: representatives from their votes, the other points from their
        nearest representatives'; the caller gets them and the confusion counts them."""
        records = stripe.records
        xyz = records["xyz"]
        if self.plane_classes is not None:  # the regions over every representative in memory
            around = [stripe, *neighbours]
            stripe.votes = plane_votes(np.concatenate([s.records["xyz"][s.reps] for s in around]),
                                       np.concatenate([s.normal for s in around]),  # type: ignore[misc]
                                       np.concatenate([s.votes for s in around]), np.arange(len(stripe.reps)),
                                       *self.plane_classes)
        pool = [(s.records["xyz"][s.reps], s.votes) for s in neighbours]
        votes = spread_votes(stripe.votes, xyz, stripe.reps, stripe.rep_of, self.evaluation.label_neighbours,
                             others=pool, cell_m=SPREAD_CELLS * self.inputs.grid_m)
        prediction, filled = _decide(xyz, votes, pool)
        self.nearest_filled += filled
        truth = records["label"]
        self.labelled += int((truth != IGNORE_LABEL).sum())
        self.confusion += compute_confusion(truth, prediction, num_classes=len(self.class_names))
        if self.element_counts is not None:
            component = records["component"].astype(np.int64)
            component[(component < 0) | (component >= self.elements)] = self.elements  # no component
            classes = len(self.class_names)
            self.element_counts += np.bincount(component * classes + prediction, minlength=self.element_counts.size
                                               ).reshape(self.element_counts.shape)
        if self.on_labels is not None:
            self.on_labels(records["index"], prediction)


def _check_extent(source: SceneSource, lower: np.ndarray, upper: np.ndarray,
                  warn: Callable[[str], None] | None, *, points: int, blocks: BlockConfig,
                  columns: Callable[[], int]) -> None:
    """The whole scene's extent, once streamed: a LearnError when it is by all signs not in metres
    (``bimscan.learn.data.unit_refusal``, the rule ``check_scene_unit`` applies up front to a
    scene's first points; ``columns()``: how many of the blocks' columns hold points, counted only
    when another unit fits), else one warning when it is larger than a building scanned in metres
    is (it may be in millimetres or feet, and the network's blocks are metres)."""
    size = upper - lower
    wide, tall = float(max(size[0], size[1])), float(size[2])
    unit = likely_unit(wide, tall)
    if unit is not None:
        refusal = unit_refusal(source.path, lower=lower, upper=upper, points=points, columns=columns(), blocks=blocks)
        if refusal is not None:
            raise LearnError(refusal)
    if wide <= BUILDING_EXTENT_M and tall <= BUILDING_HEIGHT_M:
        return
    advice = f": it looks like {unit}, so scale it to metres first" if unit else ": check its unit"
    line = extent_line(source.path, wide, tall) + advice
    (warn or (lambda text: warnings.warn(text, stacklevel=3)))(line)


def spread_votes(
    votes: np.ndarray, xyz: np.ndarray, reps: np.ndarray, rep_of: np.ndarray, neighbours: int,
    *, others: Sequence[tuple[np.ndarray, np.ndarray]] = (), cell_m: float = 0.0,
) -> np.ndarray:
    """(N, C) votes for every point of ``xyz`` (N, 3) from the votes (R, C) of its representatives
    ``reps`` (R,) (indices into ``xyz``; ``rep_of`` (N,) each point's own representative).

    With ``neighbours`` 0 every point takes its voxel representative's votes. Otherwise a
    representative keeps its own and every other point takes sum_i w_i v_i / sum_i w_i over its
    ``neighbours`` nearest voted representatives (among these and ``others``: (xyz, votes) of the
    neighbouring stripes' representatives), w_i = 1 / max(d_i, 1 mm)^2 (Qi et al. 2017,
    PointNet++'s feature propagation): a point near a voxel's face is labelled by the
    representatives around it, not only by the one point its voxel kept (at 0.1 m voxels, 3.2 %
    of the real S3DIS points differ in class from their voxel's representative, 2.8 % from their
    nearest one; counted 2026-11-26 on the 12 shared Area 6 rooms).
    """
    position = np.full(len(xyz), -1, dtype=np.int64)
    position[reps] = np.arange(len(reps))
    if neighbours == 0 or len(reps) == len(xyz):
        return votes[position[rep_of]]
    pool_xyz = [xyz[reps], *(o[0] for o in others)]
    pool_votes = [votes, *(o[1] for o in others)]
    candidate_xyz, candidate_votes = np.concatenate(pool_xyz), np.concatenate(pool_votes)
    voted = candidate_votes.sum(axis=1) > 0
    spread = np.zeros((len(xyz), votes.shape[1]), dtype=np.float32)
    spread[reps] = votes  # the representatives keep theirs
    others_index = np.flatnonzero(position < 0)
    if not voted.any() or len(others_index) == 0:
        return spread
    from scipy.spatial import cKDTree

    tree_xyz, tree_votes = candidate_xyz[voted], candidate_votes[voted]
    k = min(neighbours, len(tree_xyz))
    table = None
    if cell_m > 0:
        from bimscan.learn.neighbours import cell_table, nearest_vote_means

        # bounds of the whole stripe, a column at a time (6x faster than a reduction along axis 0)
        lower, upper = (np.array([reduce(xyz[:, a]) for a in range(3)]) for reduce in (np.min, np.max))
        table = cell_table(tree_xyz, lower, upper, cell_m)
    tree = None
    for start in range(0, len(others_index), SPREAD_CHUNK):  # bounded memory on dense scans
        part = others_index[start:start + SPREAD_CHUNK]
        if table is not None:  # the cells around each point first; a k-d tree where they do not settle it
            out = np.empty((len(part), votes.shape[1]), dtype=np.float32)
            exact = np.empty(len(part), dtype=np.bool_)
            nearest_vote_means(xyz[part], tree_xyz, tree_votes, k, cell_m, *table, out, exact)
            spread[part] = out
            part = part[~exact]
            if len(part) == 0:
                continue
        if tree is None:
            tree = cKDTree(tree_xyz)
        distance, nearest = tree.query(xyz[part], k=k, workers=-1)  # parallel; the same result
        distance, nearest = distance.reshape(len(part), k), nearest.reshape(len(part), k)
        weight = 1.0 / np.maximum(distance, 1e-3) ** 2
        weight /= weight.sum(axis=1, keepdims=True)
        mean = np.zeros((len(part), votes.shape[1]))
        for j in range(k):
            mean += weight[:, j, None] * tree_votes[nearest[:, j]]
        spread[part] = mean
    return spread


def _decide(xyz: np.ndarray, votes: np.ndarray, others: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, int]:
    """Argmax of the votes; points without votes take their nearest voted neighbour's class (from
    these points and the ``others``' (xyz, votes))."""
    prediction = votes.argmax(axis=1).astype(np.uint8)
    unseen = votes.sum(axis=1) == 0
    if not unseen.any():
        return prediction, 0
    from scipy.spatial import cKDTree

    pool_xyz = [xyz[~unseen]]
    pool_label = [prediction[~unseen]]
    for other_xyz, other_votes in others:
        seen = other_votes.sum(axis=1) > 0
        pool_xyz.append(other_xyz[seen])
        pool_label.append(other_votes[seen].argmax(axis=1).astype(np.uint8))
    near_xyz, label = np.concatenate(pool_xyz), np.concatenate(pool_label)
    if len(near_xyz) == 0:
        raise LearnError("no block pass saw any point near an unseen one; raise max_passes (0 = all points)")
    _, nearest = cKDTree(near_xyz).query(xyz[unseen])
    prediction[unseen] = label[nearest]
    return prediction, int(unseen.sum())

"""Label every point of a scene with a trained network, in bounded memory.

Blocks are the training columns (``size_m`` square, full height) slid with ``eval_stride_m``
(k = size / stride overlapping columns along x and along y), and each point's class is the
argmax of the softmax summed over every block pass that saw it.

Bounded memory for scenes of tens of millions of points:

1. One streamed pass writes the points (xyz, ground truth, original index) into one temporary
   file per x-stripe of width ``eval_stride_m``.
2. Block columns are processed in x order. Column i needs stripes i .. i+k-1 only; once it is
   done, stripe i gets no more votes: its labels are final and it is dropped from memory. So
   memory holds k stripes, not the scene.
3. Within a block, the points are shuffled and cut into groups of N (the last topped up with
   other points of the block), so every point is seen once per block at the training
   density, ``eval_votes`` times over with new shuffles; ``max_passes`` can cap the groups per
   shuffle, and points no group saw take the class of their nearest voted neighbour.

With density normalisation (``inputs.grid_m`` > 0, :mod:`bimscan.learn.density`) blocks are
made of one representative point per voxel, as in training (the same point in every block
holding the voxel); every other point takes the distance-weighted votes of its nearest
representatives (``inputs.label_neighbours``; 0: its own voxel's representative's).
Extra input features (normals, shape) are computed per block group exactly as in training; the
height above the floor under each point from the scene's floor map (:mod:`bimscan.learn.floors`).

Results reach the caller per finished stripe (``on_labels(index, prediction)``), so a
caller writes labels to disk (prediction) or only counts them (evaluation).
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from bimscan.errors import LearnError
from bimscan.learn.blocks import Block, pad_block, plan_passes
from bimscan.learn.density import grid_representatives
from bimscan.learn.features import extra_features
from bimscan.learn.floors import TILE_M, FloorMap, FloorMapBuilder
from bimscan.learn.train_config import IGNORE_LABEL, BlockConfig, InputConfig
from bimscan.learn.data import CHUNK_POINTS, SceneSource, iter_raw_chunks, iter_scene_chunks
from bimscan.learn.metrics import compute_confusion
from bimscan.learn.model import autocast_context, flush_denormals
from bimscan.progress import progress_bar
from bimscan.types import PointCloud

SPREAD_CHUNK = 262_144  # points interpolated at a time (see _spread_votes)
RECORD = np.dtype([("xyz", "<f8", (3,)), ("label", "u1"), ("index", "<i8")])


@dataclass(frozen=True)
class SceneLabels:
    """Summary of labelling one scene.

    ``confusion`` (C, C) int64 against the scene's ground truth (all zero without labels);
    ``lower``/``upper`` (3,) float64 metres bound the points; ``nearest_filled`` counts points
    no block pass saw (only with ``max_passes``), labelled from their nearest neighbour.
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


def _seed(*parts: int) -> np.random.SeedSequence:
    return np.random.SeedSequence([p % (1 << 64) for p in parts])  # column indices may be negative


class BlockRunner:
    """Batches blocks through the network and adds their softmax to ``votes`` (M, C) float32,
    indexed by the blocks' ``index`` (set ``votes`` before adding blocks)."""

    def __init__(self, model: nn.Module, *, device: torch.device, batch_size: int, amp: str) -> None:
        self.model = model
        self.device = device
        self.batch_size = batch_size
        self.amp = amp
        self.queue: list[Block] = []
        self.votes: np.ndarray | None = None
        self.passes = 0

    def add(self, block: Block) -> None:
        self.queue.append(block)
        if len(self.queue) >= self.batch_size:
            self.flush()

    @torch.inference_mode()
    def flush(self) -> None:
        if not self.queue:
            return
        if self.votes is None:
            raise RuntimeError("BlockRunner.votes must be set before blocks are added")
        xyz = torch.from_numpy(np.stack([b.xyz for b in self.queue])).to(self.device)
        mask = torch.from_numpy(np.stack([b.mask for b in self.queue])).to(self.device)
        with autocast_context(self.device, self.amp), flush_denormals():  # the network only (see flush_denormals)
            logits = self.model(xyz, mask)
        probs = torch.softmax(logits.float(), dim=-1).cpu().numpy()
        for block, prob in zip(self.queue, probs, strict=True):
            # indices are unique within one pass, so plain fancy-index addition is exact
            self.votes[block.index[block.mask]] += prob[block.mask]
        self.passes += len(self.queue)
        self.queue = []


def label_scene(
    model: nn.Module, source: SceneSource, *, class_names: Sequence[str], blocks: BlockConfig,
    device: torch.device | str = "cpu", batch_size: int = 8, amp: str = "off", seed: int = 0,
    max_passes: int = 0, use_labels: bool = True, work_dir: Path | None = None,
    on_labels: Callable[[np.ndarray, np.ndarray], None] | None = None, chunk_points: int = CHUNK_POINTS,
    inputs: InputConfig | None = None,
) -> SceneLabels:
    """Predict a class for every point of ``source`` (see the module docstring).

    ``model`` must be in eval mode. ``use_labels`` False ignores the scene's labels (prediction
    of unlabelled or foreign-labelled scans). ``on_labels(index, prediction)`` receives (M,)
    int64 original point indices and (M,) uint8 classes, stripe by stripe. Temporary stripe
    files go to ``work_dir`` (default: the system's temporary folder). ``inputs``: what the
    network was trained on (default: the paper's raw XYZ).
    """
    return _label_scene(
        model, source, class_names=class_names, blocks=blocks, device=torch.device(device),
        batch_size=batch_size, amp=amp, seed=seed, max_passes=max_passes, use_labels=use_labels,
        work_dir=work_dir, on_labels=on_labels, chunk_points=chunk_points,
        inputs=inputs or InputConfig(grid_m=0.0, features=("xyz",)),
    )


def _label_scene(
    model: nn.Module, source: SceneSource, *, class_names: Sequence[str], blocks: BlockConfig,
    device: torch.device, batch_size: int, amp: str, seed: int, max_passes: int, use_labels: bool,
    work_dir: Path | None, on_labels: Callable[[np.ndarray, np.ndarray], None] | None, chunk_points: int,
    inputs: InputConfig,
) -> SceneLabels:
    started = time.perf_counter()
    stride = blocks.eval_stride_m
    k = blocks.stride_ratio
    classes = len(class_names)
    runner = BlockRunner(model, device=device, batch_size=batch_size, amp=amp)
    confusion = np.zeros((classes, classes), dtype=np.int64)
    labelled = 0
    nearest_filled = 0
    block_count = 0
    with tempfile.TemporaryDirectory(prefix=".bimscan-stripes-", dir=work_dir) as temp:
        folder = Path(temp)
        counts, lower, upper, cy_range, floor_map = _bucket_points(
            source, folder, class_names=class_names, stride=stride, use_labels=use_labels, chunk_points=chunk_points,
        )
        total = sum(counts.values())
        stripes = sorted(counts)
        last_column = max(stripes[0], stripes[-1] - k + 1)
        last_row = max(cy_range[0], cy_range[1] - k + 1)
        columns = sorted({i for s in stripes for i in range(max(s - k + 1, stripes[0]), min(s, last_column) + 1)})
        loaded: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        with progress_bar(total=len(columns), desc=f"labelling {source.name}", unit="column") as bar:
            for position, column in enumerate(columns):
                window = [s for s in range(column, column + k) if s in counts]
                for s in window:
                    if s not in loaded:
                        records = np.fromfile(folder / f"{s}.bin", dtype=RECORD)
                        loaded[s] = (records, np.zeros((len(records), classes), dtype=np.float32))
                xyz = np.concatenate([loaded[s][0]["xyz"] for s in window])
                height = xyz[:, 2] - floor_map.floor_under(xyz) if "height" in inputs.features else None
                offsets = np.cumsum([0] + [len(loaded[s][0]) for s in window])
                runner.votes = np.zeros((len(xyz), classes), dtype=np.float32)
                if inputs.grid_m > 0:
                    representatives, rep_of = grid_representatives(xyz, inputs.grid_m)
                    is_rep = np.zeros(len(xyz), dtype=bool)
                    is_rep[representatives] = True
                cy = np.floor(xyz[:, 1] / stride).astype(np.int64)
                order = np.argsort(cy, kind="stable")
                cy_sorted = cy[order]
                rows = sorted({j for c in np.unique(cy).tolist()
                               for j in range(max(c - k + 1, cy_range[0]), min(c, last_row) + 1)})
                for row in rows:
                    lo = int(np.searchsorted(cy_sorted, row, side="left"))
                    hi = int(np.searchsorted(cy_sorted, row + k - 1, side="right"))
                    if hi == lo:
                        continue
                    members = order[lo:hi]
                    if inputs.grid_m > 0:
                        members = np.sort(members[is_rep[members]])
                    points = xyz[members]
                    heights = None if height is None else height[members]
                    box_lower, box_upper = points.min(axis=0), points.max(axis=0)
                    rng = np.random.default_rng(_seed(seed, column, row))
                    groups = [group for _ in range(blocks.eval_votes)
                              for group in plan_passes(len(members), points=blocks.points, rng=rng, max_passes=max_passes)]
                    for group in groups:
                        extra = extra_features(
                            points[group], features=inputs.features,
                            height_m=None if heights is None else heights[group],
                            height_scale_m=inputs.height_scale_m, neighbours=inputs.normal_neighbours,
                        )
                        runner.add(pad_block(
                            points[group], None, members[group], points=blocks.points, lower=box_lower, upper=box_upper,
                            extra=extra,
                        ))
                    block_count += 1
                runner.flush()
                if inputs.grid_m > 0:
                    runner.votes = _spread_votes(runner.votes, xyz, representatives, rep_of, inputs.label_neighbours)
                for s, a, b in zip(window, offsets[:-1], offsets[1:], strict=True):
                    loaded[s][1][:] += runner.votes[a:b]
                next_column = columns[position + 1] if position + 1 < len(columns) else None
                finished = [s for s in sorted(loaded) if next_column is None or s < next_column]
                for s in finished:
                    records, votes = loaded.pop(s)
                    prediction, filled = _decide(records, votes, loaded)
                    nearest_filled += filled
                    truth = records["label"]
                    has_truth = truth != IGNORE_LABEL
                    labelled += int(has_truth.sum())
                    confusion += compute_confusion(truth, prediction, num_classes=classes)
                    if on_labels is not None:
                        on_labels(records["index"], prediction)
                bar.update(1)
    return SceneLabels(
        name=source.name, points=total, labelled=labelled, confusion=confusion, blocks=block_count,
        passes=runner.passes, nearest_filled=nearest_filled, lower=lower, upper=upper,
        seconds=time.perf_counter() - started,
    )


def _bucket_points(
    source: SceneSource, folder: Path, *, class_names: Sequence[str], stride: float, use_labels: bool,
    chunk_points: int,
) -> tuple[dict[int, int], np.ndarray, np.ndarray, tuple[int, int], FloorMap]:
    """Stream the scene into per-stripe record files; returns counts, bounds, the y-cell range
    and the floor under every point (:mod:`bimscan.learn.floors`)."""
    counts: dict[int, int] = {}
    lower = np.full(3, np.inf)
    upper = np.full(3, -np.inf)
    cy_min, cy_max = None, None
    total = 0
    chunks = (iter_scene_chunks(source, class_names=class_names, chunk_points=chunk_points) if use_labels
              else iter_raw_chunks(source, chunk_points=chunk_points, labels=False))
    for chunk in chunks:
        n = len(chunk)
        if n == 0:
            continue
        if not use_labels and not np.isfinite(chunk.xyz).all():
            raise LearnError(f"{source.path}: some points have non-finite coordinates; filter them out first")
        records = np.empty(n, dtype=RECORD)
        records["xyz"] = chunk.xyz
        records["label"] = chunk.label if use_labels and chunk.label is not None else IGNORE_LABEL
        records["index"] = np.arange(total, total + n, dtype=np.int64)
        total += n
        lower = np.minimum(lower, chunk.xyz.min(axis=0))
        upper = np.maximum(upper, chunk.xyz.max(axis=0))
        cy = np.floor(chunk.xyz[:, 1] / stride).astype(np.int64)
        cy_min = int(cy.min()) if cy_min is None else min(cy_min, int(cy.min()))
        cy_max = int(cy.max()) if cy_max is None else max(cy_max, int(cy.max()))
        cx = np.floor(chunk.xyz[:, 0] / stride).astype(np.int64)
        order = np.argsort(cx, kind="stable")
        cx, records = cx[order], records[order]
        starts = np.flatnonzero(np.r_[True, cx[1:] != cx[:-1]])
        for a, b in zip(starts.tolist(), np.r_[starts[1:], n].tolist(), strict=True):
            stripe = int(cx[a])
            with (folder / f"{stripe}.bin").open("ab") as out:
                records[a:b].tofile(out)
            counts[stripe] = counts.get(stripe, 0) + (b - a)
    if total == 0 or cy_min is None or cy_max is None:
        raise LearnError(f"{source.path}: the scene holds no points; pass a non-empty cloud")
    return counts, lower, upper, (cy_min, cy_max), _floor_map(folder, counts, stride)


def _floor_map(folder: Path, counts: dict[int, int], stride: float) -> FloorMap:
    """The scene's floor map from its stripe files, read in x order: the floor tiles a stripe
    completes are summarised as soon as it is read (one stripe's width of margin against
    rounding), so memory holds a tile column's points, not the scene's."""
    builder = FloorMapBuilder()
    pending = np.empty((0, 3))
    for stripe in sorted(counts):
        xyz = np.fromfile(folder / f"{stripe}.bin", dtype=RECORD)["xyz"]
        pending = np.concatenate([pending, xyz])
        complete = np.floor(pending[:, 0] / TILE_M) < math.floor(stripe * stride / TILE_M)
        builder.add_tiles(pending[complete])
        pending = pending[~complete]
    builder.add_tiles(pending)
    return builder.build()


def _spread_votes(
    votes: np.ndarray, xyz: np.ndarray, representatives: np.ndarray, rep_of: np.ndarray, neighbours: int,
) -> np.ndarray:
    """Votes for every point from the votes of the voxel representatives (see InputConfig).

    votes (N, C) hold the network's votes at the representatives (zero elsewhere and at
    representatives no pass saw). With ``neighbours`` 0 every point takes its voxel
    representative's votes. Otherwise a representative keeps its own and every other point
    takes sum_i w_i v_i / sum_i w_i over its ``neighbours`` nearest voted representatives,
    w_i = 1 / max(d_i, 1 mm)^2 (Qi et al. 2017, PointNet++'s feature propagation): a point near a
    voxel's face is labelled by the representatives around it, not only by the one point its
    voxel kept (at 0.1 m voxels, 3.6 % of the real S3DIS points differ in class from their
    voxel's representative, 2.9 % from their nearest one).
    """
    if neighbours == 0:
        return votes[rep_of]
    voted = representatives[votes[representatives].sum(axis=1) > 0]
    others = np.flatnonzero(rep_of != np.arange(len(xyz)))
    spread = votes.copy()  # the representatives keep theirs; the others' zeros are replaced below
    if len(voted) == 0 or len(others) == 0:
        return spread
    from scipy.spatial import cKDTree

    k = min(neighbours, len(voted))
    tree, voted_votes = cKDTree(xyz[voted]), votes[voted]
    for start in range(0, len(others), SPREAD_CHUNK):  # bounded memory on dense scans
        part = others[start:start + SPREAD_CHUNK]
        distance, nearest = tree.query(xyz[part], k=k)
        distance, nearest = distance.reshape(len(part), k), nearest.reshape(len(part), k)
        weight = 1.0 / np.maximum(distance, 1e-3) ** 2
        weight /= weight.sum(axis=1, keepdims=True)
        mean = np.zeros((len(part), votes.shape[1]))
        for j in range(k):
            mean += weight[:, j, None] * voted_votes[nearest[:, j]]
        spread[part] = mean
    return spread


def _decide(
    records: np.ndarray, votes: np.ndarray, others: dict[int, tuple[np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, int]:
    """Argmax of the votes; points without votes take their nearest voted neighbour's class."""
    prediction = votes.argmax(axis=1).astype(np.uint8)
    unseen = votes.sum(axis=1) == 0
    if not unseen.any():
        return prediction, 0
    from scipy.spatial import cKDTree

    # neighbours come from this stripe and the stripes still in memory (its x-neighbours)
    pool_xyz = [records["xyz"][~unseen]]
    pool_label = [prediction[~unseen]]
    for other_records, other_votes in others.values():
        seen = other_votes.sum(axis=1) > 0
        pool_xyz.append(other_records["xyz"][seen])
        pool_label.append(other_votes[seen].argmax(axis=1).astype(np.uint8))
    xyz, label = np.concatenate(pool_xyz), np.concatenate(pool_label)
    if len(xyz) == 0:
        raise LearnError("no block pass saw any point near an unseen one; raise max_passes (0 = all points)")
    _, nearest = cKDTree(xyz).query(records["xyz"][unseen])
    prediction[unseen] = label[nearest]
    return prediction, int(unseen.sum())


def replace_labels(chunk: PointCloud, label: np.ndarray) -> PointCloud:
    """``chunk`` with its label column replaced by (N,) uint8 ``label``."""
    return replace(chunk, label=label)

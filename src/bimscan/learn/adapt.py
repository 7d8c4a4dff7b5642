"""Adaptation to unlabelled scans: self-training on class-balanced pseudo-labels of a mean
teacher, on blocks that mix the unlabelled scans with the synthetic ones.

A user has real scans of the building, without labels; the synthetic model errs on them in ways
a few of their own scans would fix (walls behind furniture, boards and closed doors in a wall's
plane). The parts, each a classic of unsupervised domain adaptation for segmentation:

- **Teacher.** The averaged weights (the run's EMA, :class:`bimscan.learn.train.WeightEMA`) label
  the unlabelled scans: a mean teacher (Tarvainen and Valpola 2017), steadier than the weights
  that are trained.
- **Rounds and class-balanced thresholds** (Zou et al. 2018, CBST). At the start of every epoch
  the teacher labels every kept point of every unlabelled column once (its cached points cut
  into groups of the block's size, features as in training, no augmentation). For each class c,
  of the points it calls c the ``pseudo_share`` most confident keep their label: the threshold
  of c is the (1 - share) quantile of their confidence (softmax maximum), at most
  ``max_threshold``. One global threshold would keep the easy classes (walls, floors) and drop
  the rare ones (beams), whose confidence is lower; per class, every class keeps its share. The
  other points are not trained on (label 255).
- **Plane votes.** The teacher's commonest error on real rooms is a wall behind furniture,
  called Others: it labels a wall by what stands in front of it. A wall is a plane it sees above
  the furniture too, so before the thresholds each vertical planar region of a column (grown
  from point to point through neighbours of like normal in each other's plane; a superpoint, as
  superpoint-guided pseudo-labels in 3D domain adaptation use them) gives the class most of its
  points got among ``region_classes`` (Wall&Column, Others) to all of those points. A point
  keeps its own confidence: the vote changes its class, not how sure the teacher was.
- **Column mixing** (after DODA's cuboid mixing, Ding et al. 2022, which mixes synthetic and
  real scenes in 3D cuboids). An adapted block is an unlabelled column with its pseudo-labels
  whose footprint is cut into ``mix_cells`` x ``mix_cells`` cells, of which a random half (at
  least one, never all) take the points and true labels of a synthetic column instead. Cells
  are full-height, so each keeps its floor-to-ceiling context (the height feature of each point
  is its own scene's). The network so sees real surfaces beside synthetic ones in one block, and
  the synthetic labels anchor the classes while the pseudo-labels bring the real data.
- The adapted blocks go through the same augmentation and features as synthetic blocks; they
  train beside them in every micro-batch (one forward, so batch normalisation sees both
  domains), their loss weighted by ``weight``.

Everything is seeded by (seed, epoch, step, block), as the synthetic blocks are: a resumed run
equals an uninterrupted one, and the unlabelled scans' own labels are never read (their tiles
are collected with ``labelled=False``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from torch import nn

from bimscan.errors import LearnError
from bimscan.learn.blocks import pad_block
from bimscan.learn.data import TileSet, draw_block
from bimscan.learn.features import estimate_normals, extra_features
from bimscan.learn.model import autocast_context, flush_denormals
from bimscan.learn.train_config import (
    IGNORE_LABEL, AdaptationSchedule, AdaptConfig, AugmentConfig, InputConfig, TrainRunConfig,
)

_PSEUDO_STREAM = 17  # seed streams of this module (the training loop's are 7 and 11)
# a mixed block keeps the unlabelled column alone when its own cells hold none of its points, or
# when the mix would hold fewer than this (a column at a room's edge fills only part of its footprint)
MIN_MIXED_POINTS = 64
_MIX_STREAM = 19
REGION_NORMAL_NEIGHBOURS = 12  # the normals the plane regions grow by: a 0.1 m grid's 12 nearest span ~0.2 m
VERTICAL_NORMAL_Z = 0.3  # a region is vertical (a wall's plane) when its normals' mean |z| is below this (~17 deg)


@dataclass(frozen=True)
class PseudoLabels:
    """One round's pseudo-labels: ``label`` (P,) uint8 aligned with the unlabelled tiles' points
    (255 where a point's confidence is under its class's threshold), ``thresholds`` (C,) float64,
    ``predicted`` and ``kept`` (C,) int64 points the teacher called each class (after the plane
    votes) and kept; ``revoted``: points whose class a plane vote changed."""

    label: np.ndarray
    thresholds: np.ndarray
    predicted: np.ndarray
    kept: np.ndarray
    revoted: int = 0

    def describe(self, class_names: tuple[str, ...]) -> str:
        """One line: per class the points kept of those predicted, and the threshold."""
        parts = [f"{name} {int(k):,}/{int(p):,} (>= {t:.2f})"
                 for name, k, p, t in zip(class_names, self.kept, self.predicted, self.thresholds, strict=True)]
        return (f"pseudo-labels kept per class: {', '.join(parts)}; {self.revoted:,} point(s) relabelled by their "
                "wall plane's vote")


def class_thresholds(confidence: np.ndarray, prediction: np.ndarray, *, classes: int, share: float,
                     cap: float) -> np.ndarray:
    """(C,) thresholds: for each class, the (1 - ``share``) quantile of the confidence (N,) of the
    points predicted (N,) as it, at most ``cap`` (a class never predicted: ``cap``)."""
    thresholds = np.full(classes, cap, dtype=np.float64)
    for c in range(classes):
        mine = confidence[prediction == c]
        if len(mine):
            thresholds[c] = min(cap, float(np.quantile(mine, 1.0 - share, method="lower")))
    return thresholds


@torch.no_grad()
def pseudo_label_tiles(
    teacher: nn.Module, tiles: TileSet, *, points: int, inputs: InputConfig, config: AdaptConfig, classes: int,
    device: torch.device, batch_size: int, amp: str, seed: int, epoch: int, class_names: Sequence[str],
) -> PseudoLabels:
    """Label every kept point of ``tiles`` with ``teacher`` (in eval mode; see the module docs).
    ``class_names``: the run's, in id order (``config.region_classes`` are among them:
    ``TrainRunConfig`` checks it)."""
    voting = [list(class_names).index(name) for name in config.region_classes]
    teacher.eval()
    probability = np.zeros((len(tiles.label), classes), dtype=np.float32)
    queue: list[tuple[np.ndarray, np.ndarray]] = []  # (block input (N, D), point indices into tiles (M,))

    def run() -> None:
        xyz = torch.from_numpy(np.stack([b.xyz for b, _ in queue])).to(device)
        mask = torch.from_numpy(np.stack([b.mask for b, _ in queue])).to(device)
        with autocast_context(device, amp), flush_denormals():
            logits = teacher(xyz, mask)
        probs = torch.softmax(logits.float(), dim=-1).cpu().numpy()
        for (block, where), prob in zip(queue, probs, strict=True):
            probability[where] = prob[: len(where)]
        queue.clear()

    for index in range(len(tiles)):
        lo, hi = int(tiles.offsets[index]), int(tiles.offsets[index + 1])
        xyz, _, height = tiles.tile_points(index)
        rgb = tiles.tile_rgb(index)
        lower, upper = xyz.min(axis=0), xyz.max(axis=0)
        rng = np.random.default_rng(np.random.SeedSequence([seed, _PSEUDO_STREAM, epoch, index]))
        order = rng.permutation(hi - lo)
        for start in range(0, len(order), points):
            group = np.sort(order[start:start + points])
            extra = extra_features(xyz[group], features=inputs.features, height_m=height[group],
                                   height_scale_m=inputs.height_scale_m, neighbours=inputs.normal_neighbours,
                                   wide_neighbours=inputs.wide_neighbours, rgb=None if rgb is None else rgb[group])
            block = pad_block(xyz[group], None, group, points=points, lower=lower, upper=upper, extra=extra)
            queue.append((block, lo + group))
            if len(queue) >= batch_size:
                run()
    if queue:
        run()
    prediction = probability.argmax(axis=1)
    confidence = probability.max(axis=1).astype(np.float64)
    revoted = 0
    if voting:
        for index in range(len(tiles)):
            lo, hi = int(tiles.offsets[index]), int(tiles.offsets[index + 1])
            xyz, _, _ = tiles.tile_points(index)
            voted = vote_in_planes(xyz, prediction[lo:hi], voting, config)
            revoted += int((voted != prediction[lo:hi]).sum())
            prediction[lo:hi] = voted
    thresholds = class_thresholds(confidence, prediction, classes=classes, share=config.pseudo_share,
                                  cap=config.max_threshold)
    keep = confidence >= thresholds[prediction]
    label = np.where(keep, prediction, IGNORE_LABEL).astype(np.uint8)
    return PseudoLabels(label=label, thresholds=thresholds,
                        predicted=np.bincount(prediction, minlength=classes).astype(np.int64),
                        kept=np.bincount(prediction[keep], minlength=classes).astype(np.int64), revoted=revoted)


def planar_regions(xyz: np.ndarray, *, radius_m: float, angle_deg: float, offset_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Region (N,) int64 of each point of ``xyz`` (N, 3) and its normal (N, 3): points joined
    when they lie within ``radius_m`` of each other, their normals differ by at most
    ``angle_deg`` and each lies within ``offset_m`` of the other's plane (the connected
    components of that graph: a plane grown from point to point, bending by at most the angle
    per step)."""
    normals = estimate_normals(xyz, neighbours=min(REGION_NORMAL_NEIGHBOURS, len(xyz)))
    pairs = cKDTree(xyz).query_pairs(radius_m, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    step = xyz[j] - xyz[i]
    joined = ((np.abs(np.einsum("ij,ij->i", normals[i], normals[j])) >= np.cos(np.radians(angle_deg)))
              & (np.abs(np.einsum("ij,ij->i", step, normals[i])) <= offset_m)
              & (np.abs(np.einsum("ij,ij->i", step, normals[j])) <= offset_m))
    graph = coo_matrix((np.ones(int(joined.sum()), dtype=np.int8), (i[joined], j[joined])), shape=(len(xyz), len(xyz)))
    return connected_components(graph, directed=False)[1].astype(np.int64), normals


def vote_in_planes(xyz: np.ndarray, prediction: np.ndarray, voting: Sequence[int], config: AdaptConfig) -> np.ndarray:
    """``prediction`` (N,) of one column's points ``xyz`` (N, 3) after its vertical planar
    regions' votes: in each, the points predicted one of the ``voting`` class ids all take the
    one most of them got (ties: the first in ``voting``), where they are at least
    ``config.region_min_points``; every other point keeps its class."""
    voted = prediction.copy()
    if len(xyz) < 3:
        return voted
    region, normals = planar_regions(np.asarray(xyz, dtype=np.float64), radius_m=config.region_radius_m,
                                     angle_deg=config.region_angle_deg, offset_m=config.region_offset_m)
    order = np.argsort(region, kind="stable")
    starts = np.flatnonzero(np.r_[True, region[order][1:] != region[order][:-1]])
    candidates = np.asarray(voting)
    for members in np.split(order, starts[1:]):
        if len(members) < config.region_min_points or np.abs(normals[members, 2]).mean() >= VERTICAL_NORMAL_Z:
            continue
        members = members[np.isin(prediction[members], candidates)]
        if len(members) < config.region_min_points:
            continue
        votes = np.array([(prediction[members] == c).sum() for c in candidates])
        voted[members] = candidates[int(votes.argmax())]
    return voted


def mixed_cells(cells: int, rng: np.random.Generator) -> np.ndarray:
    """(cells, cells) bool: the cells a synthetic column fills (a random half, at least one and
    never all; with one cell, none: the unlabelled column alone)."""
    total = cells * cells
    if total == 1:
        return np.zeros((1, 1), dtype=bool)
    chosen = rng.permutation(total)[: max(1, min(total - 1, total // 2))]
    grid = np.zeros(total, dtype=bool)
    grid[chosen] = True
    return grid.reshape(cells, cells)


class AdaptedBlocks:
    """The adapted blocks of a run: unlabelled columns with their round's pseudo-labels, mixed
    with synthetic columns (see the module docs). ``block(epoch, slot)`` is seeded by (seed,
    epoch, slot) alone: any process drawing slot s of an epoch draws the same block."""

    def __init__(self, target: TileSet, source: TileSet, *, points: int, size_m: float, seed: int,
                 inputs: InputConfig, augment: AugmentConfig | None, config: AdaptConfig) -> None:
        self.target = target
        self.source = source
        self.points = points
        self.size_m = size_m
        self.seed = seed
        self.inputs = inputs
        self.augment = augment
        self.config = config
        self.pseudo: np.ndarray | None = None

    def set_pseudo_labels(self, labels: PseudoLabels) -> None:
        self.pseudo = labels.label

    def block(self, epoch: int, slot: int) -> dict[str, np.ndarray]:
        """One adapted block (``TileDataset``'s item layout)."""
        if self.pseudo is None:
            raise RuntimeError("AdaptedBlocks needs a round's pseudo-labels (set_pseudo_labels) first")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, _MIX_STREAM, epoch, slot]))
        t = int(rng.integers(len(self.target)))
        lo, hi = int(self.target.offsets[t]), int(self.target.offsets[t + 1])
        xyz, _, height = self.target.tile_points(t)
        rgb = self.target.tile_rgb(t)
        label = self.pseudo[lo:hi]
        cells = self.config.mix_cells
        synthetic = mixed_cells(cells, rng)
        if synthetic.any():
            s = int(rng.integers(len(self.source)))
            s_xyz, s_label, s_height = self.source.tile_points(s)
            s_rgb = self.source.tile_rgb(s)
            # both tiles' coordinates are relative to their column's corner: cells line up
            own = ~synthetic[_cell(xyz, cells, self.size_m)]
            taken = synthetic[_cell(s_xyz, cells, self.size_m)]
            if own.any() and own.sum() + taken.sum() >= MIN_MIXED_POINTS:  # else the unlabelled column alone
                xyz = np.concatenate([xyz[own], s_xyz[taken]])
                label = np.concatenate([label[own], s_label[taken]])
                height = np.concatenate([height[own], s_height[taken]])
                rgb = None if rgb is None or s_rgb is None else np.concatenate([rgb[own], s_rgb[taken]])
        return draw_block(xyz, label, height, points=self.points, rng=rng, inputs=self.inputs, augment=self.augment,
                          rgb=rgb)

    def batch(self, epoch: int, first_slot: int, count: int) -> dict[str, torch.Tensor]:
        """``count`` blocks of slots ``first_slot`` .. + count - 1, stacked as tensors."""
        items = [self.block(epoch, first_slot + j) for j in range(count)]
        return {key: torch.from_numpy(np.stack([item[key] for item in items])) for key in ("xyz", "label", "mask")}


def _cell(xyz: np.ndarray, cells: int, size_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's cell (row, column) of a column's footprint cut into cells x cells."""
    index = np.clip(np.floor(xyz[:, :2] / (size_m / cells)).astype(np.int64), 0, cells - 1)
    return index[:, 0], index[:, 1]




def adaptation_config(checkpoint: Path, scans: Sequence[Path], *, synthetic: Sequence[Path] = (),
                      schedule: AdaptationSchedule | None = None, device: str | None = None) -> TrainRunConfig:
    """The training configuration that adapts ``checkpoint`` to ``scans`` (unlabelled; see
    ``AdaptationSchedule``). ``synthetic``: labelled training data in place of the checkpoint's own
    (LearnError when neither is here). Paths come back absolute."""
    from bimscan.learn.checkpoint import read_checkpoint
    from bimscan.learn.train_config import DataConfig, SceneSet, parse_config
    from bimscan.toml_files import resolve_path

    schedule = schedule or AdaptationSchedule()
    payload = read_checkpoint(checkpoint, require=("config", "class_names", "model", "ema"))
    stored = parse_config(payload["config"], where=f"{checkpoint} [config]")
    if synthetic:
        train = (SceneSet(scenes=tuple(str(Path(p).resolve()) for p in synthetic)),)
    else:  # its relative paths are relative to where its configuration was (recorded with the run)
        base = Path(str(payload.get("base_dir", ".")))
        train = tuple(replace(scenes, scenes=tuple(str(resolve_path(base, p).resolve()) for p in scenes.scenes),
                              mapping=None if scenes.mapping is None else str(resolve_path(base, scenes.mapping)))
                      for scenes in stored.data.train)
        missing = [scene for scenes in train for scene in scenes.scenes if not Path(scene).exists()]
        if missing:
            raise LearnError(f"{checkpoint}: the synthetic data it trained on is not here ({missing[0]}); pass "
                             "--synthetic PATH (a dataset it trained on, or any labelled scans of its classes)")
    data = DataConfig(train=train, val=None, adapt=(SceneSet(scenes=tuple(str(Path(p).resolve()) for p in scans)),),
                      class_names=stored.data.class_names)
    train_settings = replace(stored.train, epochs=schedule.epochs, max_lr=stored.train.max_lr * schedule.lr_factor,
                             freeze=(), **({"device": device} if device else {}))
    return replace(stored, data=data, train=train_settings)


__all__ = ["AdaptationSchedule", "AdaptedBlocks", "PseudoLabels", "adaptation_config", "class_thresholds",
           "mixed_cells", "planar_regions", "pseudo_label_tiles", "vote_in_planes"]

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
from torch import nn

from bimscan.errors import LearnError
from bimscan.learn.blocks import pad_block
from bimscan.learn.data import TileSet, draw_block
from bimscan.learn.features import extra_features
from bimscan.learn.model import CHECKPOINT_ADVICE, autocast_context, check_finite_outputs, flush_denormals
from bimscan.learn.train_config import (
    IGNORE_LABEL, AdaptationSchedule, AdaptConfig, AugmentConfig, InputConfig, TrainRunConfig,
)

_PSEUDO_STREAM = 17  # seed streams of this module (the training loop's are 7 and 11)
# a mixed block keeps the unlabelled column alone when its own cells hold none of its points, or
# when the mix would hold fewer than this (a column at a room's edge fills only part of its footprint)
MIN_MIXED_POINTS = 64
_MIX_STREAM = 19


@dataclass(frozen=True)
class PseudoLabels:
    """One round's pseudo-labels: ``label`` (P,) uint8 aligned with the unlabelled tiles' points
    (255 where a point's confidence is under its class's threshold), ``thresholds`` (C,) float64,
    ``predicted`` and ``kept`` (C,) int64 points the teacher called each class and kept."""

    label: np.ndarray
    thresholds: np.ndarray
    predicted: np.ndarray
    kept: np.ndarray

    def describe(self, class_names: tuple[str, ...]) -> str:
        """One line: per class the points kept of those predicted, and the threshold."""
        parts = [f"{name} {int(k):,}/{int(p):,} (>= {t:.2f})"
                 for name, k, p, t in zip(class_names, self.kept, self.predicted, self.thresholds, strict=True)]
        return "pseudo-labels kept per class: " + ", ".join(parts)


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
    device: torch.device, batch_size: int, amp: str, seed: int, epoch: int, name: str = "the teacher",
    advice: str = CHECKPOINT_ADVICE,
) -> PseudoLabels:
    """Label every kept point of ``tiles`` with ``teacher`` (in eval mode; see the module docs).
    Outputs that overflow stop it (``check_finite_outputs``; ``name``: the teacher's weights,
    ``advice``: what to do, for the message)."""
    teacher.eval()
    probability = np.zeros((len(tiles.label), classes), dtype=np.float32)
    queue: list[tuple[np.ndarray, np.ndarray]] = []  # (block input (N, D), point indices into tiles (M,))

    def run() -> None:
        xyz = torch.from_numpy(np.stack([b.xyz for b, _ in queue])).to(device)
        mask = torch.from_numpy(np.stack([b.mask for b, _ in queue])).to(device)
        with autocast_context(device, amp), flush_denormals():
            logits = teacher(xyz, mask)
        check_finite_outputs(logits, mask, model=name, where="the unlabelled scans", advice=advice)
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
    thresholds = class_thresholds(confidence, prediction, classes=classes, share=config.pseudo_share,
                                  cap=config.max_threshold)
    keep = confidence >= thresholds[prediction]
    label = np.where(keep, prediction, IGNORE_LABEL).astype(np.uint8)
    return PseudoLabels(label=label, thresholds=thresholds,
                        predicted=np.bincount(prediction, minlength=classes).astype(np.int64),
                        kept=np.bincount(prediction[keep], minlength=classes).astype(np.int64))


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
    train_settings = replace(stored.train, **schedule.changes(stored.train),  # type: ignore[arg-type]
                             **({"device": device} if device else {}))
    return replace(stored, data=data, train=train_settings)


__all__ = ["AdaptationSchedule", "AdaptedBlocks", "PseudoLabels", "adaptation_config", "class_thresholds",
           "mixed_cells", "pseudo_label_tiles"]

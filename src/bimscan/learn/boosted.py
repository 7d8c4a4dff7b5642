"""Gradient-boosted trees on per-point geometric features: the second model family (``[model]
kind = "gbm"``).

The classical pipeline of point-cloud segmentation (Weinmann et al. 2015, "Semantic point cloud
interpretation based on optimal neighborhoods"; Hackel et al. 2016): features that describe each
point's local shape and its place in the scene, classified point by point by gradient-boosted
trees (LightGBM, Ke et al. 2017). The trees read the very blocks the PCT reads (the columns,
density grid and ``[input]`` features of :mod:`bimscan.learn.features`, computed from each
block's own points), so training, evaluation, prediction, ensembles and sim2real take either
family alike. What they see of a point (``tree_feature_names``):

- its place in its block's column: normalised z, its rank among the block's heights (0 lowest,
  1 highest) and its distance below the block's highest and above its lowest point (normalised
  units): a ceiling is its column's top, a floor its bottom, whatever the storey's height;
- what lies above and below it: the block's points binned in plan into ``CELL`` squares
  (Weinmann et al.'s 2D accumulation features): the cell's share of the block's points, its
  height span and the standard deviation of its heights, and the point's distance below the
  cell's highest and above its lowest point (a beam has the ceiling just above it, a wall spans
  its cell from floor to ceiling, a table top has the floor below it);
- ``height`` above the floor under it (the storey's), with that input;
- from ``normals``: n_z (0 on a wall, 1 on a slab; n_x and n_y say only which way a wall faces,
  which rotation augmentation makes noise, and are left out);
- ``shape`` and ``shape_wide``: linearity, planarity and scattering at one or two scales;
- ``rgb``: the colour, and the colour minus the block's median colour (contrast with the
  surrounding surface: a board on a wall, a door in it).

Training draws every block ``[train] epochs`` times with the run's augmentation, keeps an even
share of each block's labelled points (``[model] gbm_points`` in all), weights them by the run's
class weights and fits ``gbm_rounds`` rounds. LightGBM runs deterministic and row-wise on
``[train] cpu_threads`` threads (0: every core), so the same inputs and seed give the same trees.
The checkpoint holds the trees as LightGBM's model text (plain data, read with
``weights_only=True`` like the PCT's weights).
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from bimscan.errors import LearnError
from bimscan.learn.checkpoint import save_checkpoint
from bimscan.learn.data import TileDataset
from bimscan.learn.features import FEATURE_CHANNELS
from bimscan.learn.metrics import compute_confusion
from bimscan.learn.plots import plot_training_curves, write_history_csv
from bimscan.learn.train import (
    TRAIN_TERMS, DistributedContext, GlobalBatchSampler, RunTerms, TrainResult, class_weights_from_labels,
    metric_row, prepare_run_inputs, tile_draws, validate,
)
from bimscan.learn.train_config import IGNORE_LABEL, ModelConfig, TrainRunConfig, dump_config
from bimscan.progress import progress_bar

BOOSTER_KEY = "booster"  # the checkpoint's "model" (and "ema") entry: LightGBM's model text
# plan cells of the accumulation features, in the block's normalised units (a 3 m block: about
# 0.15 m; Weinmann et al. 2015 use 0.25 m)
CELL = 0.1


def tree_feature_names(features: tuple[str, ...]) -> list[str]:
    """The trees' per-point features for a block of ``[input] features`` (see the module docstring)."""
    names = ["z", "z_rank", "below_top", "above_bottom", "cell_share", "cell_span", "cell_spread",
             "below_cell_top", "above_cell_bottom"]
    for name in features[1:]:
        if name == "height":
            names.append("height")
        elif name == "normals":
            names.append("normal_z")
        elif name in ("shape", "shape_wide"):
            names += [f"{name}_{part}" for part in ("linearity", "planarity", "scattering")]
        elif name == "rgb":
            names += ["red", "green", "blue", "red_contrast", "green_contrast", "blue_contrast"]
    return names


def block_tree_features(block: np.ndarray, features: tuple[str, ...]) -> np.ndarray:
    """(M, F) float32 tree features of one block's M real points (rows of ``block``: normalised xyz
    then the ``[input] features`` channels, padding removed)."""
    z = block[:, 2]
    m = len(block)
    rank = np.empty(m, dtype=np.float32)
    rank[np.argsort(z, kind="stable")] = np.arange(m, dtype=np.float32) / max(m - 1, 1)
    columns = [z, rank, z.max() - z, z - z.min()] if m else [z, rank, z, z]
    columns += _cell_features(block[:, :3])
    at = 3
    for name in features[1:]:
        width = FEATURE_CHANNELS[name]
        part = block[:, at:at + width]
        if name == "height":
            columns.append(part[:, 0])
        elif name == "normals":
            columns.append(part[:, 2])
        elif name in ("shape", "shape_wide"):
            columns += [part[:, 0], part[:, 1], part[:, 2]]
        elif name == "rgb":
            contrast = part - np.median(part, axis=0) if m else part
            columns += [*part.T, *contrast.T]
        at += width
    return np.stack(columns, axis=1).astype(np.float32)


def _cell_features(xyz: np.ndarray) -> list[np.ndarray]:
    """Per point: its plan cell's share of the points, height span, height standard deviation,
    and the point's distance below the cell's top and above its bottom."""
    m = len(xyz)
    if m == 0:
        return [np.zeros(0, dtype=np.float32)] * 5
    cells = np.floor(xyz[:, :2] / CELL).astype(np.int64)  # a block spans [-1, 1]: a few dozen cells a side
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    _, cell, counts = np.unique(key, return_inverse=True, return_counts=True)  # 1-D: no row-wise sort
    z = xyz[:, 2].astype(np.float64)
    top = np.full(len(counts), -np.inf)
    bottom = np.full(len(counts), np.inf)
    np.maximum.at(top, cell, z)
    np.minimum.at(bottom, cell, z)
    mean = np.bincount(cell, weights=z, minlength=len(counts)) / counts
    spread = np.sqrt(np.maximum(np.bincount(cell, weights=z * z, minlength=len(counts)) / counts - mean ** 2, 0.0))
    return [(counts[cell] / m).astype(np.float32), (top - bottom)[cell].astype(np.float32),
            spread[cell].astype(np.float32), (top[cell] - z).astype(np.float32), (z - bottom[cell]).astype(np.float32)]


class BoostedTrees(nn.Module):
    """LightGBM trees as a segmentation model: ``forward(xyz, mask)`` of a batch of blocks (B, N, D)
    gives (B, N, C) log class probabilities (padding rows 0), what inference and ensembles read
    from the PCT. It has no weights to train by gradient; ``booster_text`` is its state."""

    def __init__(self, booster_text: str, *, features: tuple[str, ...], classes: int) -> None:
        super().__init__()
        import lightgbm

        self.booster_text = booster_text
        self.features = features
        self.classes = classes
        self.booster = lightgbm.Booster(model_str=booster_text)
        expected = tree_feature_names(features)
        if self.booster.feature_name() != expected:
            raise LearnError(f"its trees split on {len(self.booster.feature_name())} features that are not the "
                             f"{len(expected)} this bimscan computes from [input] features {list(features)} (trees of "
                             "another version or a damaged checkpoint); train them again")
        if self.booster.num_model_per_iteration() != classes:
            raise LearnError(f"its trees tell {self.booster.num_model_per_iteration()} classes apart, not its "
                             f"{classes} class names; the checkpoint is damaged")

    def forward(self, xyz: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        blocks = xyz.detach().float().cpu().numpy()
        keep = mask.detach().cpu().numpy().astype(bool)
        rows = [block_tree_features(block[kept], self.features) for block, kept in zip(blocks, keep, strict=True)]
        out = np.zeros((*blocks.shape[:2], self.classes), dtype=np.float32)
        if sum(len(r) for r in rows):
            probabilities = self.predict(np.concatenate(rows))
            out[keep] = np.log(np.clip(probabilities, 1e-30, None))
        return torch.from_numpy(out).to(xyz.device)

    def predict(self, rows: np.ndarray) -> np.ndarray:
        """(M, C) class probabilities of (M, F) tree features, on PyTorch's thread count."""
        return np.asarray(self.booster.predict(rows, num_threads=torch.get_num_threads()), dtype=np.float32
                          ).reshape(len(rows), self.classes)

    def describe(self) -> str:
        trees = self.booster.num_trees()
        return f"gradient-boosted trees ({trees // self.classes} rounds x {self.classes} classes)"


def boosted_trees_from(payload: dict[str, Any], config: TrainRunConfig, *, path: str | Path) -> BoostedTrees:
    """The trees a ``kind = "gbm"`` checkpoint holds (one-line errors for a damaged one)."""
    state = payload.get("model")
    text = state.get(BOOSTER_KEY) if isinstance(state, dict) else None
    if not isinstance(text, str) or not text.startswith("tree"):
        raise LearnError(f"{path}: damaged checkpoint, its [model] kind is \"gbm\" and it holds no trees; "
                         "train it again")
    try:
        return BoostedTrees(text, features=config.input.features, classes=len(payload["class_names"]))
    except LearnError as exc:
        raise LearnError(f"{path}: {exc}") from None
    except Exception as exc:  # LightGBM's own parse errors, at this one boundary
        raise LearnError(f"{path}: damaged checkpoint, its trees do not load ({str(exc).splitlines()[0][:120]}); "
                         "train it again") from None


def lightgbm_parameters(model: ModelConfig, *, classes: int, seed: int, threads: int) -> dict[str, Any]:
    """LightGBM's settings for a run: multiclass, deterministic, row-wise (same trees every run)."""
    return {
        "objective": "multiclass", "num_class": classes, "num_leaves": model.gbm_leaves,
        "learning_rate": model.gbm_learning_rate, "min_data_in_leaf": model.gbm_min_leaf_points,
        "feature_fraction": 0.9, "lambda_l2": 1.0, "max_bin": 255, "seed": seed, "deterministic": True,
        "force_row_wise": True, "num_threads": threads or os.cpu_count() or 1, "verbose": -1,
    }


def _blocks_as_they_are(items: list[dict[str, np.ndarray]]) -> list[dict[str, np.ndarray]]:
    """The DataLoader's batch: the blocks themselves, unstacked (a module-level function: workers
    started by spawn or forkserver pickle it)."""
    return items


def train_boosted(config: TrainRunConfig, *, ctx: DistributedContext, base_dir: Path, out_dir: Path | None,
                  resume: bool, init: Path | None, log: Callable[[str], None] | None,
                  terms: RunTerms = TRAIN_TERMS) -> TrainResult:
    """Train gradient-boosted trees as ``config`` says (see the module docstring); ``last.pt``,
    ``metrics.csv`` and ``curves.png`` go to the run's folder, as a PCT run's do."""
    import lightgbm

    emit = log or (lambda text: print(text, file=sys.stderr, flush=True))
    settings, model = config.train, config.model
    kind = '[model] kind = "gbm"'
    if ctx.world > 1:
        raise LearnError(f"{kind} trains in one process (LightGBM uses every core itself); run it without torchrun")
    if init is not None or settings.freeze or config.data.adapt:
        raise LearnError(f"{kind}: its trees are fitted from nothing and do not start from a checkpoint; fine-tune "
                         "or adapt a PCT model, or train the trees on the labelled data with the synthetic")
    if resume:  # (last.pt is written when the trees are whole)
        raise LearnError(f"{kind}: a run of trees writes its checkpoint once, whole, so there is nothing to resume; "
                         f"{terms.new_run}")
    started = time.perf_counter()
    inputs = prepare_run_inputs(config, ctx=ctx, base_dir=base_dir, out_dir=out_dir, resume=False, init=None,
                                terms=terms)
    classes = len(config.data.class_names)
    train_set = TileDataset(inputs.train_tiles, points=config.blocks.points, seed=settings.seed, inputs=config.input,
                            augment=config.augment)
    val_set = None if inputs.val_tiles is None else TileDataset(
        inputs.val_tiles, points=config.blocks.points, seed=settings.seed, inputs=config.input)
    draws = tile_draws(inputs.train_tiles, [len(s) for s in inputs.train_sets],
                       [scenes.weight for scenes in config.data.train])
    sampler = GlobalBatchSampler(len(train_set), batch_size=1, accumulation=1, world=1, rank=0, seed=settings.seed,
                                 draws=draws)
    blocks_drawn = sampler.steps_per_epoch * settings.epochs
    share = max(1, math.ceil(model.gbm_points / max(blocks_drawn, 1)))  # points kept per block
    names = tree_feature_names(config.input.features)
    emit(f"training gradient-boosted trees ({model.gbm_rounds} rounds, {model.gbm_leaves} leaves, {len(names)} "
         f"features) on {len(train_set)} blocks from {len(set(inputs.train_tiles.scene_names))} scenes drawn "
         f"{settings.epochs} time(s), up to {share} points each; validating on {0 if val_set is None else len(val_set)} "
         "blocks")
    loader = torch.utils.data.DataLoader(
        train_set, batch_sampler=sampler, num_workers=settings.num_workers,
        persistent_workers=settings.num_workers > 0, collate_fn=_blocks_as_they_are)
    rows, labels = [], []
    with progress_bar(total=blocks_drawn, desc="block features", unit="block") as bar:
        for epoch in range(settings.epochs):
            sampler.set_epoch(epoch)
            for step, items in enumerate(loader):
                for k, item in enumerate(items):
                    real = item["mask"]  # the block's points (the rest is padding)
                    label = item["label"][real]
                    labelled = label != IGNORE_LABEL
                    features = block_tree_features(item["xyz"][real], config.input.features)[labelled]
                    label = label[labelled]
                    if len(label) > share:
                        rng = np.random.default_rng(np.random.SeedSequence([settings.seed, 23, epoch, step, k]))
                        pick = np.sort(rng.choice(len(label), size=share, replace=False))
                        features, label = features[pick], label[pick]
                    rows.append(features)
                    labels.append(label.astype(np.int32))
                bar.update(1)
    table, target = np.concatenate(rows), np.concatenate(labels)
    del rows, labels
    weights = class_weights_from_labels(inputs.train_tiles.label, classes=classes, mode=settings.class_weights)
    sample_weight = None if weights is None else weights[target].astype(np.float32)
    dataset = lightgbm.Dataset(table, label=target, weight=sample_weight, feature_name=names, free_raw_data=False,
                               params={"verbose": -1, "max_bin": 255})
    parameters = lightgbm_parameters(model, classes=classes, seed=settings.seed, threads=settings.cpu_threads)
    with progress_bar(total=model.gbm_rounds, desc="boosting", unit="round") as bar:
        booster = lightgbm.train(parameters, dataset, num_boost_round=model.gbm_rounds,
                                 callbacks=[lambda env: bar.update(1)])
    text = booster.model_to_string()
    trees = BoostedTrees(text, features=config.input.features, classes=classes)
    probabilities = trees.predict(table)
    train_confusion = compute_confusion(target, probabilities.argmax(axis=1), num_classes=classes)
    train_loss = float(-np.log(np.clip(probabilities[np.arange(len(target)), target], 1e-30, None)).sum())
    row: dict[str, float] = {"epoch": settings.epochs, "lr": model.gbm_learning_rate}
    row.update(metric_row("train", torch.from_numpy(train_confusion), train_loss, float(len(target))))
    if val_set is not None:
        val_confusion, val_loss, val_points = validate(
            trees, val_set, ctx=ctx, batch_size=config.eval.batch_size, amp="off", classes=classes,
            name="the trees", advice="train them again")
        row.update(metric_row("val", val_confusion, val_loss, val_points))
    else:
        row.update(metric_row("val", None, 0.0, 0.0))
    row["seconds"] = time.perf_counter() - started
    history = [row]
    payload = {
        "config": dump_config(config), "class_names": list(config.data.class_names), "epoch": settings.epochs,
        "model": {BOOSTER_KEY: text}, "ema": {BOOSTER_KEY: text}, "history": history,
        "parameters": booster.num_trees(), "training_points": len(target), "base_dir": str(base_dir.resolve()),
        "init": None,
    }
    last = inputs.out / "last.pt"
    save_checkpoint(last, payload)
    write_history_csv(history, inputs.out / "metrics.csv")
    plot_training_curves(history, inputs.out / "curves.png", title=f"gradient-boosted trees on {inputs.out.name}")
    emit(f"trained {trees.describe()} on {len(target):,} points in {row['seconds']:.1f} s: "
         f"train mIoU {row['train_miou']:.3f}"
         + ("" if math.isnan(row["val_miou"]) else f" | val OA {row['val_oa']:.3f} mIoU {row['val_miou']:.3f} "
            f"kappa {row['val_kappa']:.3f}"))
    return TrainResult(out_dir=inputs.out, checkpoint=last, epochs_done=settings.epochs, history=history,
                       parameters=booster.num_trees())

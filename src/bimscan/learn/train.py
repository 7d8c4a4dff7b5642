"""Training PCT on synthetic scenes, validated on real ones (the paper's Table 2 recipe).

Adam with OneCycleLR (cosine annealing), weight decay, gradient accumulation, AMP with a
GradScaler on CUDA (float32 on CPU), an EMA of the weights used for validation and saved for
evaluation, DDP under ``torchrun`` (NCCL on CUDA, Gloo on CPU), a checkpoint per epoch, metric
history as CSV and curves as PNG.

Reproducibility and the DDP contract: the optimizer sees one *global batch* per step,
``batch_size x processes x accumulation_steps`` blocks. Each epoch is a seeded permutation of
the tiles, cut into global batches, each cut into micro-batches of ``batch_size``; process r
runs micro-batches r*A .. r*A+A-1 of every global batch (A = accumulation steps). A block's
points are drawn with a generator seeded by (seed, epoch, tile) and each micro-batch reseeds
torch (dropout) from (seed, epoch, step, micro-batch), and BatchNorm running statistics are
folded in once per optimizer step from sums over the whole global batch
(:class:`~bimscan.learn.model.MaskedBatchNorm1d`). Hence one process with A' = A x P gives
the same weights as P processes with A (up to floating-point summation order), and resuming
from a checkpoint gives the same result as never stopping (bit for bit on CPU).
"""

from __future__ import annotations

import contextlib
import copy
import datetime
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import nn

from bimscan.errors import LearnError
from bimscan.files import check_output_folder, claim_output, folder_entries, prepare_output_folder, remove_path
from bimscan.processes import die_with_parent
from bimscan.learn.checkpoint import (
    MODEL_KEYS, capture_rng_state, load_state, read_checkpoint, restore_rng_state, save_checkpoint,
)
from bimscan.learn.train_config import (
    IGNORE_LABEL, SceneSet, TrainConfig, TrainRunConfig, dump_config, parse_config, setting_effect,
)
from bimscan.toml_files import resolve_path
from bimscan.learn.adapt import AdaptedBlocks, pseudo_label_tiles
from bimscan.learn.data import (
    SceneSource, TileDataset, TileSet, check_scene_unit, list_scenes, load_or_collect_tiles, station_count,
)
from bimscan.learn.features import input_channels
from bimscan.learn.mapping import load_label_mapping
from bimscan.learn.metrics import METRIC_NAMES, compute_metrics
from bimscan.learn.model import (
    PCTSegmentation, autocast_context, build_model, commit_batch_statistics, count_parameters, flush_denormals,
    non_finite_outputs, outputs_finite, pick_device,
)
from bimscan.learn.plots import plot_training_curves, write_history_csv
from bimscan.progress import progress_bar

VAL_EPOCH_KEY = 2**31  # validation blocks are drawn once, with this fixed "epoch"
# what resuming reads from last.pt besides MODEL_KEYS
RESUME_KEYS = (*MODEL_KEYS, "ema_steps", "optimizer", "scheduler", "scaler", "rng", "history", "world_size", "device")


@dataclass(frozen=True)
class DistributedContext:
    """This process's place in a (possibly single-process) run."""

    world: int
    rank: int
    local_rank: int
    device: torch.device
    owns_group: bool  # we initialised the process group and must destroy it

    @property
    def is_main(self) -> bool:
        return self.rank == 0


@dataclass(frozen=True)
class RunTerms:
    """How the command that runs a training names what its user gave it, in the lines that refuse
    or stop the run: ``bimscan train``'s words (a configuration, ``--init``, ``--resume``,
    ``out_dir``) by default. ``bimscan adapt`` has its own (``bimscan.cli.learn_commands``): its
    user gave a checkpoint, scans and a folder, and its run is configured from the checkpoint.

    ``run``: what a run is called; ``activity``: what it does; ``start``: the checkpoint a run
    starts from; ``new_run``: how to start another; ``again``: how to continue an interrupted one;
    ``other_start``: what to do when the run to continue started from another checkpoint;
    ``named``: the settings the command takes as arguments, by (section, key), with the argument's
    name (an option, "--epochs", or a positional one, "SCAN..."); ``settings_of``: where the other
    settings come from (None: the configuration; a checkpoint's path: "[train] batch_size of
    PATH"); ``diverged``: what to do when the run's loss or weights stop being finite ("{max_lr}":
    its max_lr); ``few_blocks``: what to do when its data hold fewer blocks than one step takes.
    """

    run: str = "run"
    activity: str = "training"
    start: str = "--init"
    new_run: str = "start a new run in another out_dir"
    again: str = "resume with the same configuration (--resume)"
    other_start: str = "--resume continues it as it started: leave --init out"
    named: dict[tuple[str, str], str] = field(default_factory=dict)
    settings_of: str | None = None
    diverged: str = "start again in another out_dir with a lower [train] max_lr (now {max_lr})"
    few_blocks: str = "lower [train] batch_size or accumulation_steps, or train on more data"

    def name(self, section: str, key: str) -> str:
        """How the user names ``[section] key``: an argument of the command, or the setting itself."""
        if (section, key) in self.named:
            return self.named[(section, key)]
        return f"[{section}] {key}" if self.settings_of is None else f"[{section}] {key} of {self.settings_of}"

    def when_diverged(self, max_lr: float) -> str:
        """What to do when a run at ``max_lr`` diverges (``diverged`` with it filled in)."""
        return self.diverged.replace("{max_lr}", f"{max_lr:g}")

    def given(self, section: str, key: str, value: object) -> str:
        """How the user gives ``[section] key`` the ``value``: ``--device cpu``, ``[train] device = "cpu"``."""
        named = self.named.get((section, key))
        if named is not None and named.startswith("--"):
            return f"{named} {value}"
        return f"{self.name(section, key)} = " + (f'"{value}"' if isinstance(value, str) else str(value))


TRAIN_TERMS = RunTerms()


def init_distributed(device_setting: str) -> DistributedContext:
    """Join the ``torchrun`` process group when WORLD_SIZE > 1 and pick this process's device."""
    use_cuda = pick_device(device_setting).type == "cuda"
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistributedContext(1, 0, 0, torch.device("cuda", 0) if use_cuda else torch.device("cpu"), False)
    rank, local_rank = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    owns = False
    if use_cuda:
        torch.cuda.set_device(local_rank)
    if not dist.is_initialized():
        # generous timeout: processes wait at a barrier while the others read their scenes
        dist.init_process_group(backend="nccl" if use_cuda else "gloo", timeout=datetime.timedelta(hours=2))
        owns = True
    device = torch.device("cuda", local_rank) if use_cuda else torch.device("cpu")
    return DistributedContext(world, rank, local_rank, device, owns)


def _seed_int(*parts: int) -> int:
    return int(np.random.SeedSequence(list(parts)).generate_state(1, dtype=np.uint64)[0] % (2**63 - 1))


def tile_draws(tiles: TileSet, scenes_per_set: list[int], weights: list[float]) -> np.ndarray | None:
    """(T,) float draws per epoch of each tile: its scene set's weight (None when every weight is
    1: each tile once). ``scenes_per_set``: how many of the tiles' scenes (in order) each set holds."""
    if all(w == 1.0 for w in weights):
        return None
    per_scene = np.repeat(np.asarray(weights, dtype=np.float64), scenes_per_set)
    return per_scene[tiles.scene]


class GlobalBatchSampler:
    """This process's micro-batches of ``(epoch, tile)`` keys for one epoch (see module docs).

    Replaces ``DistributedSampler``: that one deals indices to processes round-robin, so a
    micro-batch would hold other blocks than in a one-process run and BatchNorm statistics,
    dropout and the result would differ. Here global batch t holds permutation entries
    t*G .. t*G+G-1 (wrapping around at the end of the epoch, so every tile is seen) and
    process r takes its A contiguous micro-batches of it. ``draws`` (T,): how often each tile
    is drawn per epoch (the whole part that many times, the fraction at random by the epoch's
    seed); None: each once.
    """

    def __init__(self, size: int, *, batch_size: int, accumulation: int, world: int, rank: int, seed: int,
                 draws: np.ndarray | None = None) -> None:
        if size < 1:
            raise LearnError("no training blocks: every tile was dropped; lower blocks.min_points or check the data")
        self.size = size
        self.batch_size = batch_size
        self.accumulation = accumulation
        self.world = world
        self.rank = rank
        self.seed = seed
        self.draws = draws
        self.epoch = 0
        self.global_batch = batch_size * accumulation * world
        # the blocks an epoch draws: each tile once, or as its scene set's weight says
        self.epoch_blocks = size if draws is None else max(1, int(round(float(draws.sum()))))
        self.steps_per_epoch = math.ceil(self.epoch_blocks / self.global_batch)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def __len__(self) -> int:
        return self.steps_per_epoch * self.accumulation

    def _epoch_tiles(self, rng: np.random.Generator) -> np.ndarray:
        if self.draws is None:
            return rng.permutation(self.size)
        whole = np.floor(self.draws).astype(np.int64)
        extra = rng.random(self.size) < self.draws - whole  # the fraction of a draw, at random
        tiles = np.repeat(np.arange(self.size), whole + extra)
        return rng.permutation(tiles) if len(tiles) else rng.permutation(self.size)

    def __iter__(self) -> Iterator[list[tuple[int, int]]]:
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 7, self.epoch]))
        order = np.resize(self._epoch_tiles(rng), self.steps_per_epoch * self.global_batch)
        for step in range(self.steps_per_epoch):
            for k in range(self.accumulation):
                micro = self.rank * self.accumulation + k
                start = step * self.global_batch + micro * self.batch_size
                yield [(self.epoch, int(i)) for i in order[start:start + self.batch_size]]


def check_global_batch(sampler: GlobalBatchSampler, *, terms: RunTerms = TRAIN_TERMS) -> None:
    """LearnError when one optimizer step takes more than twice the blocks an epoch draws: every
    block would be in every step at least twice, and a step of 4096 blocks over 30 (a batch_size
    typed for another machine) an epoch of thousands of draws of the same blocks, a minute instead
    of a second, and nothing more learnt. A global batch up to twice the epoch's blocks is drawn
    as usual, wrapping around to the epoch's first blocks (so a few rooms still train with Table
    2's batch); the run's first line says how many blocks an epoch draws. Checked once the blocks
    are known, before the network is built."""
    if sampler.global_batch <= 2 * sampler.epoch_blocks:
        return
    raise LearnError(
        f"one optimizer step takes a global batch of {sampler.global_batch:,} blocks ({terms.name('train', 'batch_size')} "
        f"{sampler.batch_size} x {sampler.world} process(es) x {terms.name('train', 'accumulation_steps')} "
        f"{sampler.accumulation}), more than twice the {sampler.epoch_blocks:,} an epoch draws from the training data: "
        f"every step would repeat each {sampler.global_batch / sampler.epoch_blocks:,.1f} times; {terms.few_blocks}")


class WeightEMA:
    """Exponential moving average of the weights: ema = d * ema + (1 - d) * weights, per step.

    d = min(alpha, (1 + t) / (10 + t)) at optimizer step t (the warm-up of timm's ModelEma):
    Table 2's alpha = 0.99 from step 890 on, while early on the average is not dominated by
    the random initial weights (with a fixed 0.99, 25 % of the EMA would still be the initial
    weights after 138 steps). BatchNorm running statistics are averaged the same way, so they
    match the averaged weights.
    """

    def __init__(self, model: nn.Module, *, alpha: float) -> None:
        self.alpha = alpha
        self.steps = 0
        self.module = copy.deepcopy(model).eval()
        for parameter in self.module.parameters():
            parameter.requires_grad_(False)

    def decay(self) -> float:
        return min(self.alpha, (1.0 + self.steps) / (10.0 + self.steps))

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        weight = 1.0 - self.decay()
        for ema_parameter, parameter in zip(self.module.parameters(), model.parameters(), strict=True):
            ema_parameter.lerp_(parameter.detach(), weight)
        for (name, ema_buffer), (_, buffer) in zip(self.module.named_buffers(), model.named_buffers(), strict=True):
            if name.endswith("running_mean") or name.endswith("running_var"):
                ema_buffer.lerp_(buffer, weight)
        self.steps += 1

    def state_dict(self) -> dict[str, torch.Tensor]:
        return self.module.state_dict()

    def load_state_dict(self, state: dict[str, torch.Tensor], *, steps: int) -> None:
        self.module.load_state_dict(state)
        self.steps = steps


def compute_loss(
    logits: torch.Tensor, label: torch.Tensor, weight: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean cross entropy over labelled points (label != 255; padding carries 255).

    logits (B, N, C) float, label (B, N) int64, ``weight`` (C,) float32 class weights or None.
    Returns (mean loss, number of points counted). Weighted, the mean is over the weights of
    the counted points (PyTorch's "mean" reduction), so the loss keeps its scale.
    """
    flat_logits = logits.reshape(-1, logits.shape[-1]).float()
    flat_label = label.reshape(-1)
    total = F.cross_entropy(flat_logits, flat_label, weight=weight, ignore_index=IGNORE_LABEL, reduction="sum")
    counted = flat_label != IGNORE_LABEL
    count = counted.sum()
    if weight is None:
        return total / count.clamp_min(1).to(total.dtype), count
    norm = weight[flat_label.clamp(0, len(weight) - 1)].masked_fill(~counted, 0.0).sum()
    return total / norm.clamp_min(1e-12), count


def class_weights_from_labels(label: np.ndarray, *, classes: int, mode: str) -> np.ndarray | None:
    """(C,) float32 loss weights from training labels (``[train] class_weights``), or None for "none".

    f_c = share of class c among the labelled points; w_c = 1 / f_c ("inverse") or 1 / sqrt(f_c)
    ("inverse_sqrt"), normalised to mean 1 over the classes present; absent classes weigh 0
    (they have no points to weigh anyway).
    """
    if mode == "none":
        return None
    counts = np.bincount(label[label < classes].astype(np.int64), minlength=classes).astype(np.float64)
    if counts.sum() == 0:
        return None
    share = counts / counts.sum()
    present = share > 0
    weights = np.zeros(classes)
    weights[present] = 1.0 / (share[present] if mode == "inverse" else np.sqrt(share[present]))
    weights[present] /= weights[present].mean()
    return weights.astype(np.float32)


def run_micro_batch(
    model: nn.Module, xyz: torch.Tensor, label: torch.Tensor, mask: torch.Tensor, *,
    scaler: torch.amp.GradScaler, amp: str, accumulation: int, weight: torch.Tensor | None = None,
    adapted: int = 0, adapted_weight: float = 1.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One micro-batch: forward (autocast on CUDA), masked loss, scaled backward of loss / A.

    xyz (B, N, 3) float32, label (B, N) int64, mask (B, N) bool on the model's device.
    Returns (logits (B, N, C), mean loss, labelled points, the loss trained on: the mean loss, with
    the adapted blocks' added). The benchmark times this too.
    Runs with denormals flushed (:func:`bimscan.learn.model.flush_denormals`): the network only,
    never the loader's features. ``adapted``: the last that many blocks are adapted ones
    (:mod:`bimscan.learn.adapt`), whose mean loss adds ``adapted_weight`` times to the others';
    the loss and count returned are the others' (the synthetic blocks').
    """
    with flush_denormals():
        with autocast_context(xyz.device, amp):
            logits = model(xyz, mask)
        if not adapted:
            loss, count = compute_loss(logits, label, weight)
            scaler.scale(loss / accumulation).backward()
            return logits, loss, count, loss
        own = len(xyz) - adapted
        loss, count = compute_loss(logits[:own], label[:own], weight)
        adapted_loss, _ = compute_loss(logits[own:], label[own:], weight)
        objective = loss + adapted_weight * adapted_loss
        scaler.scale(objective / accumulation).backward()
    return logits, loss, count, objective


def finish_step(
    model: nn.Module, *, optimizer: torch.optim.Optimizer, scaler: torch.amp.GradScaler,
    scheduler: torch.optim.lr_scheduler.LRScheduler | None, ema: WeightEMA | None,
) -> None:
    """The optimizer step after the last micro-batch of a global batch (denormals flushed, as
    :func:`run_micro_batch`)."""
    with flush_denormals():
        scaler.step(optimizer)
        scaler.update()
        optimizer.zero_grad(set_to_none=True)
        if scheduler is not None:
            scheduler.step()
        commit_batch_statistics(model)
        if ema is not None:
            ema.update(model)


def check_diverged(model: nn.Module, *, loss: torch.Tensor, finite_loss: torch.Tensor, epoch: int, step: int,
                   checkpoint: Path, settings: TrainConfig, started_from: dict[str, Any] | None = None,
                   terms: RunTerms = TRAIN_TERMS) -> None:
    """LearnError when a loss or the outputs of the optimizer step (``finite_loss``: a bool tensor,
    False when a micro-batch's loss was NaN or infinite or its outputs overflowed,
    :func:`bimscan.learn.model.outputs_finite`) or the weights it left are not finite (an exploding
    step): the run stops there, before anything is saved, so the last checkpoint (the
    last finished epoch's) stays the last finite one. One synchronisation per step. Every process
    of a DDP run holds the same weights, so all stop at the same step. (Under float16 AMP the
    gradient scaler skips a step whose gradients overflow: the weights stay finite and training goes
    on; a loss that overflows is the network's outputs overflowing, which no scaling mends.) Outputs
    that overflow at the first step of a run started from a checkpoint (``started_from``; a resumed
    run is past its first epoch) are that checkpoint's weights' doing: the message names it."""
    total = torch.stack([p.detach().float().sum() for p in model.parameters()]).sum()
    if bool(torch.isfinite(total) & finite_loss):
        return
    kept = (f"{checkpoint} (epoch {epoch}) is the last finite checkpoint and is kept" if epoch > 0 and checkpoint.is_file()
            else "no checkpoint was written")
    what = ("the loss or the network's outputs overflow" if not bool(finite_loss)
            else "the weights are no longer finite")
    if not bool(finite_loss) and epoch == 0 and step == 0 and started_from is not None:
        # the first step's forward passes ran on the weights it started from, as they were loaded
        raise LearnError(f"{started_from['checkpoint']}: its weights make the network's outputs overflow (loss "
                         f"{float(loss.detach()):.4g} at the first step of the {terms.run} that starts from it): they "
                         f"are finite but absurd; {kept}; start from another checkpoint")
    raise LearnError(f"{terms.activity} diverged at epoch {epoch + 1}, step {step + 1} (loss {float(loss.detach()):.4g}): "
                     f"{what}; {kept}; {terms.when_diverged(settings.max_lr)}")


def _update_confusion(confusion: torch.Tensor, logits: torch.Tensor, label: torch.Tensor) -> None:
    # fixed-size tensor operations only (no boolean indexing, no bincount): the GPU is not waited for
    classes = confusion.shape[0]
    pairs = torch.where(label != IGNORE_LABEL, label * classes + logits.argmax(dim=-1), classes * classes).reshape(-1)
    counts = torch.zeros(classes * classes + 1, dtype=confusion.dtype, device=confusion.device)
    counts.index_add_(0, pairs, torch.ones_like(pairs))  # unlabelled points land in the extra last bin
    confusion += counts[:-1].view(classes, classes)


def _all_reduce(tensor: torch.Tensor, ctx: DistributedContext) -> torch.Tensor:
    if ctx.world > 1:
        dist.all_reduce(tensor)
    return tensor


def _all_finite(finite: torch.Tensor, ctx: DistributedContext) -> torch.Tensor:
    """``finite`` (a bool tensor) of every process together: a loss or output that is not finite in
    one stops them all at the same step (under float16 AMP the weights stay finite everywhere)."""
    if ctx.world == 1:
        return finite
    return _all_reduce((~finite).to(torch.int32), ctx) == 0


@dataclass(frozen=True)
class TrainResult:
    """What a training run left behind."""

    out_dir: Path
    checkpoint: Path
    epochs_done: int
    history: list[dict[str, float]]
    parameters: int


def resolve_scene_set(scenes: SceneSet, *, base: Path) -> list[SceneSource]:
    """The scenes of a scene set, its paths and mapping resolved against ``base``."""
    mapping = None if scenes.mapping is None else load_label_mapping(resolve_path(base, scenes.mapping))
    return list_scenes([resolve_path(base, p) for p in scenes.scenes], label_field=scenes.label_field, mapping=mapping)


def _collect_tiles(
    sources: list[SceneSource], *, config: TrainRunConfig, cache_dir: Path, ctx: DistributedContext,
    columns: str = "scene", labelled: bool = True,
) -> TileSet:
    """Tiles of every scene, cut as ``columns`` says (``[blocks] train_columns``: "scene",
    "station" or "both"); ``labelled`` False: scenes whose labels are never read (adaptation).
    Under DDP each process reads every P-th scene into the on-disk tile cache, then all read the
    whole cache: one pass over the data, spread over processes."""

    def tiles_of(source: SceneSource, per_station: bool, *, build: bool = True) -> TileSet:
        return load_or_collect_tiles(
            source, blocks=config.blocks, class_names=config.data.class_names, seed=config.train.seed,
            cache_dir=cache_dir, build=build, grid_m=config.input.grid_m, per_station=per_station, labelled=labelled,
            colour="rgb" in config.input.features,
        )

    def cut(source: SceneSource, *, build: bool = True) -> list[TileSet]:
        if columns == "scene":
            return [tiles_of(source, False, build=build)]
        apart = tiles_of(source, True, build=build)
        if columns == "station" or station_count(apart) == 1:
            return [apart]  # a scene of one station or none (a real room): its merged columns are these
        return [apart, tiles_of(source, False, build=build)]

    mine = [s for i, s in enumerate(sources) if i % ctx.world == ctx.rank]
    built: dict[Path, list[TileSet]] = {}
    with progress_bar(total=len(mine), desc="reading scenes", unit="scene", enabled=ctx.is_main) as bar:
        for source in mine:
            built[source.path] = cut(source)
            bar.update(1)
    if ctx.world > 1:
        dist.barrier()
    parts = [tiles for source in sources for tiles in (built.get(source.path) or cut(source, build=False))]
    return TileSet.concatenate(parts)


def read_start(path: Path, config: TrainRunConfig) -> dict[str, Any]:
    """The checkpoint fine-tuning starts from, read and checked (before any work): LearnError
    unless its network is this one (model, inputs, classes)."""
    payload = read_checkpoint(path)
    parent = parse_config(payload["config"], where=f"{path} [config]")
    for what, mine, theirs in (("[model]", config.model, parent.model), ("[input] features", config.input.features,
                               parent.input.features), ("class names", config.data.class_names, tuple(payload["class_names"]))):
        if mine != theirs:
            raise LearnError(f"{path}: the run to start from has other {what} ({theirs}) than this one ({mine}); "
                             "fine-tune with the same network and classes")
    return payload


def start_from(model: PCTSegmentation, path: Path, payload: dict[str, Any]) -> dict[str, Any]:
    """Load the EMA weights (what a run is evaluated with) of ``payload`` (:func:`read_start` of
    ``path``) into ``model``: fine-tuning starts from them. Returns what the new checkpoint records
    of where it started."""
    from bimscan.files import file_sha256

    load_state(model, payload["ema"], what="EMA weights", path=path)
    return {"checkpoint": str(path), "sha256": file_sha256(path), "epoch": int(payload["epoch"])}


def check_same_start(recorded: dict[str, Any] | None, init: Path, checkpoint: Path, *,
                     terms: RunTerms = TRAIN_TERMS) -> None:
    """LearnError unless ``init`` is the checkpoint the run being resumed started from (``recorded``:
    what its checkpoint says of its start, None when it started from random weights)."""
    from bimscan.files import file_sha256

    if recorded is None:
        raise LearnError(f"{terms.start} {init}: the {terms.run} in {checkpoint.parent} started from random weights "
                         f"and continues as it started; leave {terms.start} out, or {terms.new_run}")
    if recorded.get("sha256") != file_sha256(init):
        raise LearnError(f"{terms.start} {init}: the {terms.run} in {checkpoint.parent} started from another checkpoint "
                         f"({recorded.get('checkpoint')}); {terms.other_start}")


def freeze(model: PCTSegmentation, parts: tuple[str, ...]) -> tuple[nn.Module, ...]:
    """Keep ``parts`` of ``model`` ("embedding", "attention") as they are while training: their
    parameters get no gradient, and :func:`train_mode` keeps their normalisation statistics.
    Returns the frozen modules."""
    modules = {"embedding": (model.embed1, model.embed2), "attention": tuple(model.attention)}
    frozen = tuple(module for part in parts for module in modules[part])
    for module in frozen:
        module.requires_grad_(False)
    return frozen


def train_mode(model: nn.Module, frozen: tuple[nn.Module, ...]) -> None:
    """``model.train()`` but the frozen modules in eval mode: batch-norm statistics are weights too,
    updated in train mode without any gradient."""
    model.train()
    for module in frozen:
        module.eval()


def check_resumable(state: dict[str, Any], config: TrainRunConfig, *, device: str, world: int, where: Path,
                    terms: RunTerms = TRAIN_TERMS) -> None:
    """LearnError, before any work, when the run stored in ``state`` (``where``: its last.pt) cannot
    continue as ``config`` on this ``device`` kind with ``world`` processes: the first setting that
    differs from the run's, except those that do not change the model it trains (their
    ``setting_effect`` is "scores" or "runtime"; "device" may change as long as it picks the same
    kind of device), and for an interrupted run another kind of device or another number of
    processes. The stored config is complete (keys added since then carry their defaults). A run
    that did all its epochs is called finished, not interrupted, and only a new run is offered."""
    stored = dump_config(parse_config(state["config"], where=f"{where} [config]"))
    finished = int(state["epoch"]) >= int(stored["train"]["epochs"])  # type: ignore[index]
    run = f"the {'finished' if finished else 'interrupted'} {terms.run}"
    advice = terms.new_run if finished else f"{terms.again}, or {terms.new_run}"
    for section, values in dump_config(config).items():
        for key, value in values.items():  # type: ignore[union-attr]
            old = stored.get(section, {}).get(key)  # type: ignore[union-attr]
            if setting_effect(section, key) != "model":
                continue
            if _plain(old) != _plain(value):
                raise LearnError(f"{where}: {terms.name(section, key)} was {_shown(old)} in {run} and is "
                                 f"{_shown(value)} now; {advice}")
    if finished:  # nothing left to run: where it would have run is moot
        return
    if state["device"] != device:
        raise LearnError(f"{where}: {run} trained on {state['device']} and would continue on {device}; continue it "
                         f"on {state['device']} ({terms.given('train', 'device', state['device'])}) or {terms.new_run}")
    if state["world_size"] != world:
        raise LearnError(f"{where}: {run} used {state['world_size']} process(es), this one {world}; continue it with "
                         f"the same number (torchrun --nproc_per_node {state['world_size']}) or {terms.new_run}")


def _plain(value: object) -> object:
    """A stored setting comparable with a current one (tuples come back from storage as lists)."""
    return [_plain(v) for v in value] if isinstance(value, tuple | list) else value


def _shown(value: object) -> str:
    """A setting for a message: scene sets as the scenes they name."""
    if isinstance(value, tuple | list) and value and all(isinstance(v, dict) and "scenes" in v for v in value):
        return repr([scene for v in value for scene in v["scenes"]])
    return repr(_plain(value))


@torch.no_grad()
def validate(
    model: nn.Module, dataset: TileDataset, *, ctx: DistributedContext, batch_size: int, amp: str, classes: int,
    name: str = "the averaged weights", advice: str = "train again with a lower [train] max_lr",
) -> tuple[torch.Tensor, float, float]:
    """The validation set's confusion, loss sum and labelled points with ``model``; outputs that
    overflow (:func:`bimscan.learn.model.outputs_finite`) stop the run (``name``, ``advice``: for
    the message)."""
    confusion = torch.zeros(classes, classes, dtype=torch.int64, device=ctx.device)
    sums = torch.zeros(2, dtype=torch.float64, device=ctx.device)  # loss x points, points
    model.eval()
    finite = torch.ones((), dtype=torch.bool, device=ctx.device)
    mine = list(range(ctx.rank, len(dataset), ctx.world))
    for start in range(0, len(mine), batch_size):
        items = [dataset[(VAL_EPOCH_KEY, i)] for i in mine[start:start + batch_size]]
        xyz = torch.from_numpy(np.stack([it["xyz"] for it in items])).to(ctx.device)
        label = torch.from_numpy(np.stack([it["label"] for it in items])).to(ctx.device)
        mask = torch.from_numpy(np.stack([it["mask"] for it in items])).to(ctx.device)
        with autocast_context(ctx.device, amp), flush_denormals():
            logits = model(xyz, mask)
        finite &= outputs_finite(logits, mask)  # checked once, at the end: no synchronisation per batch
        loss, count = compute_loss(logits, label)
        sums += torch.stack([loss.double() * count, count.double()])
        _update_confusion(confusion, logits, label)
    _all_reduce(confusion, ctx)
    _all_reduce(sums, ctx)
    if not bool(_all_finite(finite, ctx)):  # every process stops, not only the one that saw it
        raise non_finite_outputs(model=name, where="the validation blocks", advice=advice)
    return confusion, float(sums[0]), float(sums[1])


def metric_row(prefix: str, confusion: torch.Tensor | None, loss_sum: float, points: float) -> dict[str, float]:
    if confusion is None:
        return {f"{prefix}_{name}": math.nan for name in ("loss", *METRIC_NAMES)}
    metrics = compute_metrics(confusion.cpu().numpy())
    row = {f"{prefix}_{name}": value for name, value in metrics.scalars().items()}
    row[f"{prefix}_loss"] = loss_sum / points if points else math.nan
    return row


def use_cpu_threads(threads: int) -> None:
    """PyTorch's intra-op threads (0: leave its default); see ``TrainConfig.cpu_threads``."""
    if threads > 0:
        torch.set_num_threads(threads)


def train_model(
    config: TrainRunConfig, *, base_dir: Path, out_dir: Path | None = None, resume: bool = False,
    init: Path | None = None, on_step_end: Callable[[int, int], None] | None = None,
    log: Callable[[str], None] | None = None, terms: RunTerms = TRAIN_TERMS,
) -> TrainResult:
    """Train the model as configured (PCT; ``[model] kind = "gbm"``: trees, see
    :mod:`bimscan.learn.boosted`); checkpoints, ``metrics.csv`` and ``curves.png`` go to ``out_dir``.

    ``base_dir`` anchors the config's relative paths; ``out_dir`` overrides ``[train] out_dir``.
    ``resume`` continues from ``out_dir/last.pt`` (the interrupted epoch restarts from its
    beginning). ``init``: a checkpoint whose weights (its EMA, the ones it is evaluated with)
    the run starts from instead of random ones (fine-tuning; the checkpoint records it).
    ``on_step_end(epoch, step)`` is called after every optimizer step (0-based). ``terms``: how the
    command running it names its inputs in the lines that refuse or stop it (``RunTerms``).
    Run under ``torchrun`` for DDP; every process calls this function.
    """
    settings = config.train
    use_cpu_threads(settings.cpu_threads)
    ctx = init_distributed(settings.device)
    try:
        if config.model.kind == "gbm":
            from bimscan.learn.boosted import train_boosted

            return train_boosted(config, ctx=ctx, base_dir=base_dir, out_dir=out_dir, resume=resume, init=init,
                                 log=log, terms=terms)
        return _train(config, settings=settings, ctx=ctx, base_dir=base_dir, out_dir=out_dir, resume=resume,
                      init=init, on_step_end=on_step_end, log=log, terms=terms)
    finally:
        if ctx.owns_group and dist.is_initialized():
            dist.destroy_process_group()


@dataclass
class _Run:
    """A training run set up (``_set_up``): what its epochs (``_train_epoch``) and checkpoints
    (``_save_epoch``) need, and where it stands (``history``, ``start_epoch``, ``best_miou``)."""

    config: TrainRunConfig
    ctx: DistributedContext
    out: Path
    base_dir: Path  # what the configuration's relative paths are relative to
    emit: Callable[[str], None]
    model: PCTSegmentation
    ddp_model: nn.Module
    ema: WeightEMA
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    scaler: torch.amp.GradScaler
    sampler: GlobalBatchSampler
    loader: torch.utils.data.DataLoader
    val_set: TileDataset | None
    weight: torch.Tensor | None
    frozen: tuple[nn.Module, ...]
    frozen_parameters: int
    parameters: int
    adapted: AdaptedBlocks | None
    target_tiles: TileSet | None
    started_from: dict[str, Any] | None
    history: list[dict[str, float]]
    terms: RunTerms = TRAIN_TERMS  # how the command names its inputs (messages)
    start_epoch: int = 0
    best_miou: float = -math.inf

    @property
    def settings(self) -> TrainConfig:
        return self.config.train

    @property
    def last_path(self) -> Path:
        return self.out / "last.pt"

    @property
    def best_path(self) -> Path:
        return self.out / "best.pt"


def _train(
    config: TrainRunConfig, *, settings: TrainConfig, ctx: DistributedContext, base_dir: Path, out_dir: Path | None,
    resume: bool, init: Path | None, on_step_end: Callable[[int, int], None] | None,
    log: Callable[[str], None] | None, terms: RunTerms = TRAIN_TERMS,
) -> TrainResult:
    emit = log or (lambda text: print(text, file=sys.stderr, flush=True))
    run = _set_up(config, ctx=ctx, base_dir=base_dir, out_dir=out_dir, resume=resume, init=init, emit=emit,
                  terms=terms)
    for epoch in range(run.start_epoch, settings.epochs):
        row = _train_epoch(run, epoch, on_step_end)
        _save_epoch(run, epoch, row)
        if ctx.world > 1:
            dist.barrier()  # nobody races ahead of the checkpoint
    return TrainResult(out_dir=run.out, checkpoint=run.last_path, epochs_done=len(run.history), history=run.history,
                       parameters=run.parameters)


def _read_tiles(config: TrainRunConfig, val_sources: list[SceneSource], train_sources: list[SceneSource],
                target_sources: list[SceneSource], *, cache_dir: Path, ctx: DistributedContext,
                terms: RunTerms = TRAIN_TERMS) -> tuple[TileSet | None, TileSet, TileSet | None]:
    """The validation, training and adaptation tiles of a run (LearnError where a set holds none)."""
    # the validation scenes first: they are few, and unusable ones should stop the run early
    val_tiles = _collect_tiles(val_sources, config=config, cache_dir=cache_dir, ctx=ctx) if val_sources else None
    if val_tiles is not None and len(val_tiles) == 0:
        raise LearnError(
            f"[data] val: no column of its {len(val_sources)} scene(s) has ground truth and at least blocks.min_points "
            f"({config.blocks.min_points}) points; give the val scenes labels ([data.val] label_field / mapping) or "
            "leave val out"
        )
    train_tiles = _collect_tiles(train_sources, config=config, cache_dir=cache_dir, ctx=ctx,
                                 columns=config.blocks.train_columns)
    target_tiles = None
    if target_sources:
        target_tiles = _collect_tiles(target_sources, config=config, cache_dir=cache_dir, ctx=ctx,
                                      columns=config.blocks.train_columns, labelled=False)
        if len(target_tiles) == 0:
            raise LearnError(f"{terms.name('data', 'adapt')}: no column of its {len(target_sources)} scene(s) holds "
                             f"{terms.name('blocks', 'min_points')} ({config.blocks.min_points}) points; give scans of "
                             "the building's rooms")
    return val_tiles, train_tiles, target_tiles


# What a run writes into its folder (``bimscan.files`` output folder names).
RUN_OUTPUTS = ("last.pt", "best.pt", "metrics.csv", "curves.png", "tile-cache/")


def is_earlier_run(folder: Path) -> bool:
    """Whether ``folder`` is a run folder made before output folders had records: it holds last.pt
    (read, and so checked to be a bimscan checkpoint, by ``--resume`` before anything is written),
    or only a tile cache and temporaries (a run killed in its first epoch)."""
    if (folder / "last.pt").is_file():
        return True
    return all(name == "tile-cache/" or (name.startswith(".") and name.endswith(".tmp"))
               for name in folder_entries(folder))


@dataclass
class RunInputs:
    """A run's inputs, checked and read (``prepare_run_inputs``): its folder, training scene sets,
    tiles (validation and adaptation: None when not given), and with ``--resume`` the checkpoint's
    ``state``, with ``--init`` the ``parent`` checkpoint read."""

    out: Path
    train_sets: list[list[SceneSource]]
    val_tiles: TileSet | None
    train_tiles: TileSet
    target_tiles: TileSet | None
    state: dict[str, Any] | None
    parent: dict[str, Any] | None


def prepare_run_inputs(config: TrainRunConfig, *, ctx: DistributedContext, base_dir: Path, out_dir: Path | None,
                       resume: bool, init: Path | None, terms: RunTerms = TRAIN_TERMS) -> RunInputs:
    """Every input of a run checked (before the output folder appears), the folder prepared and the
    tiles read; a bad input leaves no folder this run made."""
    settings = config.train
    out = Path(out_dir) if out_dir is not None else resolve_path(base_dir, settings.out_dir)
    last_path = out / "last.pt"
    if not resume and last_path.exists():
        raise LearnError(f"{out}: already holds a training run; pass --resume to continue it or choose another out_dir")
    if resume and not last_path.is_file():
        raise LearnError(f"{last_path}: no checkpoint to resume from; start without --resume")
    train_sets = [resolve_scene_set(scenes, base=base_dir) for scenes in config.data.train]
    train_sources = [source for sources in train_sets for source in sources]
    val_sources = [] if config.data.val is None else resolve_scene_set(config.data.val, base=base_dir)
    target_sources = [source for scenes in config.data.adapt for source in resolve_scene_set(scenes, base=base_dir)]
    if settings.freeze and init is None and not resume:
        raise LearnError(f"[train] freeze = {list(settings.freeze)} keeps those parts of the network as they start, and "
                         "without --init they start random; pass --init CHECKPOINT (fine-tuning) or leave freeze out")
    if target_sources and init is None and not resume:
        raise LearnError("[data] adapt: adapting to unlabelled scans starts from a trained model (their pseudo-labels "
                         "are its predictions); pass --init CHECKPOINT, or train on labelled data first")
    if ctx.is_main:  # a user's folder, or a user's metrics.csv in it, is refused before any work
        check_output_folder(out, names=RUN_OUTPUTS, made_by=is_earlier_run)
    state = read_checkpoint(last_path, require=RESUME_KEYS) if resume else None
    if state is not None and init is not None:
        check_same_start(state.get("init"), init, last_path, terms=terms)
    if state is not None:  # accumulation_steps among the settings
        check_resumable(state, config, device=ctx.device.type, world=ctx.world, where=last_path, terms=terms)
    parent = None if init is None or resume else read_start(init, config)
    for source in (*val_sources, *train_sources, *target_sources):  # a scan in millimetres: one line now
        check_scene_unit(source, blocks=config.blocks)
    created = ctx.is_main and not out.exists()
    if ctx.is_main:
        prepare_output_folder(out, names=RUN_OUTPUTS, made_by=is_earlier_run)
        claim_output(out, "tile-cache/")
    if ctx.world > 1:
        dist.barrier()  # the folder and its record are made before any process writes its tile cache there
    try:
        val_tiles, train_tiles, target_tiles = _read_tiles(config, val_sources, train_sources, target_sources,
                                                           cache_dir=out / "tile-cache", ctx=ctx, terms=terms)
    except Exception:
        if created:  # this run made OUT and it holds only tile caches: a bad input leaves nothing behind
            remove_path(out)
        raise
    return RunInputs(out=out, train_sets=train_sets, val_tiles=val_tiles, train_tiles=train_tiles,
                     target_tiles=target_tiles, state=state, parent=parent)


def _set_up(config: TrainRunConfig, *, ctx: DistributedContext, base_dir: Path, out_dir: Path | None, resume: bool,
            init: Path | None, emit: Callable[[str], None], terms: RunTerms = TRAIN_TERMS) -> _Run:
    """Every input checked (before the output folder appears), the tiles read, the network, its
    optimizer and schedule built, and with ``resume`` restored from ``last.pt``."""
    settings = config.train
    inputs = prepare_run_inputs(config, ctx=ctx, base_dir=base_dir, out_dir=out_dir, resume=resume, init=init,
                                terms=terms)
    out, train_sets, state, parent = inputs.out, inputs.train_sets, inputs.state, inputs.parent
    val_tiles, train_tiles, target_tiles = inputs.val_tiles, inputs.train_tiles, inputs.target_tiles
    classes = len(config.data.class_names)
    train_set = TileDataset(train_tiles, points=config.blocks.points, seed=settings.seed, inputs=config.input,
                            augment=config.augment)
    val_set = None if val_tiles is None else TileDataset(
        val_tiles, points=config.blocks.points, seed=settings.seed, inputs=config.input,
    )
    draws = tile_draws(train_tiles, [len(sources) for sources in train_sets],
                       [scenes.weight for scenes in config.data.train])
    sampler = GlobalBatchSampler(
        len(train_set), batch_size=settings.batch_size, accumulation=settings.accumulation_steps,
        world=ctx.world, rank=ctx.rank, seed=settings.seed, draws=draws,
    )
    check_global_batch(sampler, terms=terms)
    weights = class_weights_from_labels(train_tiles.label, classes=classes, mode=settings.class_weights)
    weight = None if weights is None else torch.from_numpy(weights).to(ctx.device)

    torch.manual_seed(settings.seed)  # the same initial weights in every process
    model: PCTSegmentation = build_model(
        classes, config.model, in_dim=input_channels(config.input.features),
    ).to(ctx.device)
    started_from = None if parent is None else start_from(model, init, parent)  # before the EMA copies the weights
    frozen = freeze(model, settings.freeze)
    ema = WeightEMA(model, alpha=settings.ema_alpha)
    optimizer = torch.optim.Adam([p for p in model.parameters() if p.requires_grad], lr=settings.max_lr,
                                 weight_decay=settings.weight_decay)
    scheduler = torch.optim.lr_scheduler.OneCycleLR(
        optimizer, max_lr=settings.max_lr, total_steps=settings.epochs * sampler.steps_per_epoch,
        pct_start=settings.pct_start, anneal_strategy="cos", div_factor=settings.div_factor,
        final_div_factor=settings.final_div_factor, cycle_momentum=settings.cycle_momentum,
    )
    use_scaler = ctx.device.type == "cuda" and settings.amp == "float16"
    scaler = torch.amp.GradScaler(ctx.device.type, enabled=use_scaler)
    adapted = None if target_tiles is None else AdaptedBlocks(
        target_tiles, train_tiles, points=config.blocks.points, size_m=config.blocks.size_m, seed=settings.seed,
        inputs=config.input, augment=config.augment, config=config.adapt)
    run = _Run(config=config, ctx=ctx, out=out, base_dir=base_dir.resolve(), emit=emit, model=model, ddp_model=model, ema=ema, optimizer=optimizer,
               scheduler=scheduler, scaler=scaler, sampler=sampler, loader=None,  # type: ignore[arg-type]
               val_set=val_set, weight=weight, frozen=frozen,
               frozen_parameters=sum(p.numel() for module in frozen for p in module.parameters()),
               parameters=count_parameters(model), adapted=adapted, target_tiles=target_tiles,
               started_from=started_from, history=[], terms=terms)
    if state is not None:
        _restore(run, state)
    elif ctx.is_main:
        emit(
            f"training PCT ({run.parameters:,} parameters) on {len(train_set)} blocks from "
            f"{len(set(train_tiles.scene_names))} scenes, validating on "
            f"{0 if val_set is None else len(val_set)} blocks"
            + ("" if target_tiles is None else f", adapting to {len(target_tiles)} unlabelled blocks from "
               f"{len(set(target_tiles.scene_names))} scenes") + "; "
            f"global batch {sampler.global_batch} = {settings.batch_size} x {ctx.world} process(es) x "
            f"{settings.accumulation_steps} accumulation, {sampler.steps_per_epoch} steps/epoch "
            f"({sampler.steps_per_epoch * sampler.global_batch} blocks drawn), device {ctx.device}"
        )
        if weights is not None:
            emit("class weights (" + settings.class_weights + "): " + ", ".join(
                f"{name} {w:.2f}" for name, w in zip(config.data.class_names, weights.tolist(), strict=True)))
    if ctx.world > 1:
        # buffers stay identical in every process by construction (see MaskedBatchNorm1d):
        # no need to broadcast them before every forward
        run.ddp_model = nn.parallel.DistributedDataParallel(
            model, device_ids=[ctx.local_rank] if ctx.device.type == "cuda" else None, forward_sync_buffers=False,
        )
    # the sampler runs in this process (keys carry the epoch), so workers can persist across epochs
    run.loader = torch.utils.data.DataLoader(
        train_set, batch_sampler=sampler, num_workers=settings.num_workers,
        pin_memory=ctx.device.type == "cuda", persistent_workers=settings.num_workers > 0,
        worker_init_fn=die_with_parent if settings.num_workers > 0 else None,
    )
    return run


def _restore(run: _Run, state: dict[str, Any]) -> None:
    """Continue from ``last.pt`` (``state``): every weight, optimizer, schedule and generator state
    as it was."""
    ctx, last_path = run.ctx, run.last_path  # (what may continue was checked by check_resumable)
    load_state(run.model, state["model"], what="model weights", path=last_path)
    load_state(run.ema.module, state["ema"], what="EMA weights", path=last_path)
    run.ema.steps = state["ema_steps"]
    load_state(run.optimizer, state["optimizer"], what="optimizer state", path=last_path)
    load_state(run.scheduler, state["scheduler"], what="scheduler state", path=last_path)
    load_state(run.scaler, state["scaler"], what="gradient scaler state", path=last_path)
    restore_rng_state(state["rng"])
    run.started_from = state.get("init")
    run.history = list(state["history"])
    run.start_epoch = int(state["epoch"])
    run.best_miou = float(state.get("best_val_miou", -math.inf))
    if ctx.is_main:
        run.emit(f"resuming {run.out} after epoch {run.start_epoch}/{run.settings.epochs}")


def _train_epoch(run: _Run, epoch: int, on_step_end: Callable[[int, int], None] | None) -> dict[str, float]:
    """One epoch: its optimizer steps (with adapted blocks beside the synthetic ones when the run
    adapts), then validation; returns its metrics row."""
    ctx, settings, config = run.ctx, run.settings, run.config
    classes = len(config.data.class_names)
    accumulation = settings.accumulation_steps
    started = time.perf_counter()
    if run.adapted is not None and run.target_tiles is not None:
        start = run.started_from if epoch == 0 else None  # the teacher still holds the weights started from
        pseudo = pseudo_label_tiles(run.ema.module, run.target_tiles, points=config.blocks.points, inputs=config.input,
                                    config=config.adapt, classes=classes, device=ctx.device,
                                    batch_size=config.eval.batch_size, amp=settings.amp, seed=settings.seed,
                                    epoch=epoch,
                                    name=f"the averaged weights at epoch {epoch + 1}" if start is None
                                    else start["checkpoint"],
                                    advice=run.terms.when_diverged(settings.max_lr) if start is None
                                    else "start from another checkpoint")
        run.adapted.set_pseudo_labels(pseudo)
        if ctx.is_main:
            run.emit(f"epoch {epoch + 1}: " + pseudo.describe(tuple(config.data.class_names)))
    run.sampler.set_epoch(epoch)
    train_mode(run.model, run.frozen)
    confusion = torch.zeros(classes, classes, dtype=torch.int64, device=ctx.device)
    sums = torch.zeros(2, dtype=torch.float64, device=ctx.device)
    last_lr = math.nan
    # the step's losses and outputs finite so far: checked once per step (no sync per micro-batch)
    finite = torch.ones((), dtype=torch.bool, device=ctx.device)
    with progress_bar(total=run.sampler.steps_per_epoch, desc=f"epoch {epoch + 1}/{settings.epochs}", unit="step",
                      enabled=ctx.is_main) as bar:
        for index, batch in enumerate(run.loader):
            step, k = divmod(index, accumulation)
            torch.manual_seed(_seed_int(settings.seed, 11, epoch, step, ctx.rank * accumulation + k))
            xyz = batch["xyz"].to(ctx.device, non_blocking=True)
            label = batch["label"].to(ctx.device, non_blocking=True)
            mask = batch["mask"].to(ctx.device, non_blocking=True)
            own = len(xyz)
            adapted = 0
            if run.adapted is not None:
                slot = ((step * ctx.world + ctx.rank) * accumulation + k) * settings.batch_size
                extra = run.adapted.batch(epoch, slot, settings.batch_size)
                adapted = len(extra["xyz"])
                xyz = torch.cat([xyz, extra["xyz"].to(ctx.device)])
                label = torch.cat([label, extra["label"].to(ctx.device)])
                mask = torch.cat([mask, extra["mask"].to(ctx.device)])
            last_micro = k == accumulation - 1
            sync = contextlib.nullcontext() if (last_micro or ctx.world == 1) else run.ddp_model.no_sync()
            with sync:
                logits, loss, count, objective = run_micro_batch(
                    run.ddp_model, xyz, label, mask, scaler=run.scaler, amp=settings.amp, accumulation=accumulation,
                    weight=run.weight, adapted=adapted, adapted_weight=config.adapt.weight,
                )
            with torch.no_grad():
                finite &= torch.isfinite(objective.detach()) & outputs_finite(logits, mask)
                sums += torch.stack([loss.detach().double() * count, count.double()])
                _update_confusion(confusion, logits[:own].detach(), label[:own])
            if not last_micro:
                continue
            last_lr = run.optimizer.param_groups[0]["lr"]  # the LR this step applies; finish_step moves on
            finish_step(run.model, optimizer=run.optimizer, scaler=run.scaler, scheduler=run.scheduler, ema=run.ema)
            check_diverged(run.model, loss=loss, finite_loss=_all_finite(finite, ctx), epoch=epoch, step=step,
                           checkpoint=run.last_path, settings=settings, started_from=run.started_from, terms=run.terms)
            finite.fill_(True)
            bar.update(1)
            if on_step_end is not None:
                on_step_end(epoch, step)
    _all_reduce(confusion, ctx)
    _all_reduce(sums, ctx)
    row: dict[str, float] = {"epoch": epoch + 1, "lr": float(last_lr)}
    row.update(metric_row("train", confusion, float(sums[0]), float(sums[1])))
    if run.val_set is not None:
        val_confusion, val_loss, val_points = validate(
            run.ema.module, run.val_set, ctx=ctx, batch_size=config.eval.batch_size, amp=settings.amp, classes=classes,
            name=f"the averaged weights at epoch {epoch + 1}", advice=run.terms.when_diverged(settings.max_lr),
        )
        row.update(metric_row("val", val_confusion, val_loss, val_points))
    else:
        row.update(metric_row("val", None, 0.0, 0.0))
    row["seconds"] = time.perf_counter() - started
    return row


def _save_epoch(run: _Run, epoch: int, row: dict[str, float]) -> None:
    """Record the epoch: its row in the history, and on the main process last.pt (best.pt when the
    validation mIoU is the best yet), metrics.csv and curves.png."""
    run.history.append(row)
    if run.ctx.is_main:
        settings = run.settings
        payload = {
            "config": dump_config(run.config), "class_names": list(run.config.data.class_names), "epoch": epoch + 1,
            "model": run.model.state_dict(), "ema": run.ema.state_dict(), "ema_steps": run.ema.steps,
            "optimizer": run.optimizer.state_dict(),
            "scheduler": run.scheduler.state_dict(), "scaler": run.scaler.state_dict(), "rng": capture_rng_state(),
            "history": run.history, "world_size": run.ctx.world, "accumulation_steps": settings.accumulation_steps,
            "device": run.ctx.device.type,
            "global_batch": run.sampler.global_batch, "parameters": run.parameters,
            "best_val_miou": max(run.best_miou, row["val_miou"]) if not math.isnan(row["val_miou"]) else run.best_miou,
            "init": run.started_from, "frozen_parameters": run.frozen_parameters, "base_dir": str(run.base_dir),
        }
        save_checkpoint(run.last_path, payload)
        if not math.isnan(row["val_miou"]) and row["val_miou"] > run.best_miou:
            save_checkpoint(run.best_path, payload)
        write_history_csv(run.history, run.out / "metrics.csv")
        plot_training_curves(run.history, run.out / "curves.png", title=f"PCT on {run.out.name}")
        run.emit(_describe_epoch(row, settings.epochs))
    if not math.isnan(row["val_miou"]):
        run.best_miou = max(run.best_miou, row["val_miou"])


def _describe_epoch(row: dict[str, float], epochs: int) -> str:
    def part(prefix: str) -> str:
        if math.isnan(row[f"{prefix}_oa"]):
            return f"{prefix} -"
        return (f"{prefix} loss {row[f'{prefix}_loss']:.3f} OA {row[f'{prefix}_oa']:.3f} "
                f"mIoU {row[f'{prefix}_miou']:.3f} mAcc {row[f'{prefix}_macc']:.3f} "
                f"FWIoU {row[f'{prefix}_fwiou']:.3f} kappa {row[f'{prefix}_kappa']:.3f}")

    return f"epoch {int(row['epoch'])}/{epochs} ({row['seconds']:.1f} s): {part('train')} | {part('val')}"

"""Checkpoints: one ``torch.save`` file per run state, written atomically.

A checkpoint holds everything to resume training exactly (model, EMA, optimizer, scheduler,
gradient scaler, epoch, RNG states, metric history) and everything evaluation and prediction
need (class names, block and model configuration). Loading uses ``weights_only=True``: the
file holds tensors and plain data only, never pickled code.
"""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from torch import nn

from bimscan.errors import InputFileError, LearnError
from bimscan.files import atomic_output
from bimscan.learn.train_config import EvalConfig, TrainRunConfig, merge_inputs, parse_config
from bimscan.learn.features import input_channels
from bimscan.learn.model import build_model

CHECKPOINT_FORMAT = "bimscan-pct-checkpoint"
CHECKPOINT_VERSION = 1
# what evaluation and prediction read; training adds RESUME_KEYS (train.py)
MODEL_KEYS = ("config", "class_names", "epoch", "model", "ema")
_KINDS: dict[str, type | tuple[type, ...]] = {
    "config": dict, "class_names": (list, tuple), "epoch": int, "model": dict, "ema": dict, "optimizer": dict,
    "scheduler": dict, "scaler": dict, "rng": dict, "history": list, "ema_steps": int, "world_size": int,
    "accumulation_steps": int, "global_batch": int, "device": str,
}


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` to ``path`` atomically (temporary file in the same folder, then a rename)."""
    payload = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, **payload}
    with atomic_output(path) as temp:
        torch.save(payload, temp)


def _first_line(exc: BaseException, *, limit: int = 160) -> str:
    """The first sentence of an exception's message, at most ``limit`` characters."""
    line = next((line.strip() for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
    line = line.split(". ")[0]
    return line if len(line) <= limit else line[:limit - 3] + "..."


def read_checkpoint(path: str | Path, *, require: tuple[str, ...] = MODEL_KEYS) -> dict[str, Any]:
    """Load a checkpoint onto the CPU; one-line errors for missing, damaged, foreign or incomplete
    files (``require``: the keys the caller reads)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such checkpoint; pass the last.pt or best.pt of a training run")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # deliberately broad, at this one boundary:
        # a damaged or foreign file makes torch.load raise almost anything (UnpicklingError,
        # RuntimeError for a broken zip, KeyError, IndexError, struct.error, EOFError, ...);
        # every one of them means the same to the user
        raise InputFileError(f"{path}: not a readable checkpoint ({type(exc).__name__}: {_first_line(exc)}); "
                             "pass the last.pt or best.pt of a training run") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise InputFileError(f"{path}: not a bimscan PCT checkpoint; pass the last.pt or best.pt of 'bimscan train'")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise InputFileError(f"{path}: checkpoint version {payload.get('version')!r} is not supported ({CHECKPOINT_VERSION} is)")
    missing = [key for key in require if key not in payload]
    if missing:
        raise InputFileError(f"{path}: incomplete checkpoint, no {', '.join(repr(k) for k in missing)} (damaged, or "
                             "written by another bimscan version); pass a last.pt or best.pt of this version")
    for key in require:
        value = payload[key]
        kind = _KINDS.get(key)
        if kind is not None and (not isinstance(value, kind) or isinstance(value, bool)
                                 or (key == "class_names" and not all(isinstance(n, str) for n in value))):
            raise InputFileError(f"{path}: damaged checkpoint, {key!r} is a {type(value).__name__}; "
                                 "pass a bimscan checkpoint")
        if key in ("model", "ema"):
            check_finite_weights(value, what=f"{key} weights", path=path)
    return payload


def check_finite_weights(state: Mapping[str, Any], *, what: str, path: str | Path) -> None:
    """InputFileError when a floating-point tensor of ``state`` holds NaN or infinity: a model whose
    training diverged labels every point alike, and a run started from it learns nothing."""
    for name, tensor in state.items():
        if isinstance(tensor, torch.Tensor) and tensor.is_floating_point():
            bad = int((~torch.isfinite(tensor)).sum())
            if bad:
                raise InputFileError(f"{path}: its {what} hold {bad:,} non-finite value(s) ({name}): the training that "
                                     "wrote it diverged; train again with a lower [train] max_lr")


def load_state(module: nn.Module | Any, state: Mapping[str, Any], *, what: str, path: str | Path) -> None:
    """``module.load_state_dict(state)`` with a one-line LearnError when they do not fit.

    torch lists every mismatching tensor on its own line; the message keeps the first and counts the rest.
    """
    try:
        module.load_state_dict(state)
    except (KeyError, RuntimeError, ValueError, TypeError, IndexError) as exc:
        details = [line.strip() for line in str(exc).splitlines()[1:] if line.strip()] or [_first_line(exc)]
        more = f" and {len(details) - 1} more" if len(details) > 1 else ""
        raise LearnError(
            f"{path}: the stored {what} do not fit ({details[0].rstrip('.')}{more}); pass a checkpoint of this "
            "bimscan version and configuration"
        ) from exc


def capture_rng_state() -> dict[str, Any]:
    """The states of Python's, NumPy's legacy and torch's (CPU, CUDA) generators."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    state: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": {"kind": kind, "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached": float(cached)},
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng_state(state: dict[str, Any]) -> None:
    """Undo :func:`capture_rng_state`."""
    random.setstate(state["python"])
    numpy_state = state["numpy"]
    np.random.set_state((
        numpy_state["kind"], numpy_state["keys"].numpy().astype(np.uint32), numpy_state["pos"],
        numpy_state["has_gauss"], numpy_state["cached"],
    ))
    torch.set_rng_state(state["torch"])
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def stored_eval_config(path: str | Path) -> EvalConfig:
    """The ``[eval]`` a checkpoint's training run stored: how its model labels scenes by default."""
    payload = read_checkpoint(path, require=("config",))
    return parse_config(payload["config"], where=f"{path} [config]").eval


@dataclass
class TrainedModel:
    """A model restored from a checkpoint (a PCT, gradient-boosted trees or an ``Ensemble``), in
    eval mode, with what inference needs."""

    model: nn.Module
    config: TrainRunConfig
    class_names: tuple[str, ...]
    epoch: int
    weights: str


def load_trained_model(
    path: str | Path, *, device: torch.device | str = "cpu", weights: Literal["ema", "live"] | None = None,
) -> TrainedModel:
    """Rebuild the network of a checkpoint with its "ema" weights (as Table 2) or its "live" ones
    (None: those its ``[eval] weights`` names, the EMA unless changed)."""
    payload = read_checkpoint(path)
    config = parse_config(payload["config"], where=f"{path} [config]")
    weights = weights or config.eval.weights
    class_names = tuple(payload["class_names"])
    if len(class_names) < 2:
        raise InputFileError(f"{path}: damaged checkpoint, {len(class_names)} class name(s); pass a bimscan checkpoint")
    model: nn.Module
    if config.model.kind == "gbm":  # trees have no averaged weights: "ema" and "live" are the same trees
        from bimscan.learn.boosted import boosted_trees_from

        model = boosted_trees_from(payload, config, path=path)
    else:
        model = build_model(len(class_names), config.model, in_dim=input_channels(config.input.features))
        key = "ema" if weights == "ema" else "model"
        load_state(model, payload[key], what=f"{key} weights", path=path)
    model.to(device).eval()
    return TrainedModel(model=model, config=config, class_names=class_names, epoch=int(payload["epoch"]), weights=weights)


class Ensemble(nn.Module):
    """Models whose class probabilities are averaged (seeds, recipes or families of one set of
    classes and blocks): the output is the log of the members' mean softmax, so that a softmax of
    it, as inference takes, is that mean. Each member reads its own ``channels`` of the ensemble's
    input (``merge_inputs``; None: all, in order). Each member's outputs are checked for overflow
    first, named by its checkpoint."""

    def __init__(self, members: list[nn.Module], names: list[str],
                 channels: list[list[int] | None] | None = None) -> None:
        super().__init__()
        self.members = nn.ModuleList(members)
        self.names = names
        # each member's input channels among the ensemble's, as index tensors made once (None: all, in order)
        self.channels = [None if c is None else torch.as_tensor(c, dtype=torch.long)
                         for c in (channels if channels is not None else [None] * len(members))]

    def forward(self, xyz: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        from bimscan.learn.model import check_finite_outputs

        total: torch.Tensor | None = None
        for member, name, channels in zip(self.members, self.names, self.channels, strict=True):
            own = xyz if channels is None else xyz.index_select(-1, channels.to(xyz.device))
            logits = member(own, mask)
            check_finite_outputs(logits, mask, model=name, where="the ensemble's blocks")
            probabilities = torch.softmax(logits.float(), dim=-1)
            total = probabilities if total is None else total + probabilities
        assert total is not None
        # float32's smallest normal is 1e-38: a class no member gives any chance stays finite
        return torch.log((total / len(self.members)).clamp_min(1e-30))


def load_trained_models(
    paths: list[str | Path], *, device: torch.device | str = "cpu", weights: Literal["ema", "live"] | None = None,
) -> TrainedModel:
    """``load_trained_model`` of one checkpoint; of several, their ``Ensemble`` with the first's
    configuration. Checkpoints that differ in classes, inputs or blocks are refused: their
    probabilities are not of the same points or the same classes."""
    if len(paths) == 1:
        return load_trained_model(paths[0], device=device, weights=weights)
    loaded = [load_trained_model(path, device=device, weights=weights) for path in paths]
    first = loaded[0]
    for number, (path, other) in enumerate(zip(paths[1:], loaded[1:], strict=True), start=2):
        for what, mine, theirs in (("classes", first.class_names, other.class_names),
                                   ("[blocks] size_m and points", (first.config.blocks.size_m, first.config.blocks.points),
                                    (other.config.blocks.size_m, other.config.blocks.points))):
            if mine != theirs:
                raise LearnError(f"{path}: its {what} differ from those of {paths[0]}; an ensemble averages "
                                 "checkpoints trained on the same classes and blocks")
        try:
            merge_inputs([t.config.input for t in loaded[:number]])
        except ValueError as exc:
            raise LearnError(f"{path}: its {exc} differs from an earlier member's; an ensemble averages models that "
                             "read the same points and features computed alike (their feature lists may differ)") from None
    inputs, channels = merge_inputs([t.config.input for t in loaded])
    every = list(range(input_channels(inputs.features)))  # a member that reads them all, in order, takes xyz as it is
    ensemble = Ensemble([t.model for t in loaded], [str(p) for p in paths],
                        [None if c == every else c for c in channels]).to(device).eval()
    config = dataclasses.replace(first.config, input=inputs)  # the features every member reads, computed once
    return TrainedModel(model=ensemble, config=config, class_names=first.class_names,
                        epoch=first.epoch, weights=first.weights)

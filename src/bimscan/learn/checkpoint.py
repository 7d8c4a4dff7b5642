"""Checkpoints: one ``torch.save`` file per run state, written atomically.

A checkpoint holds everything to resume training exactly (model, EMA, optimizer, scheduler,
gradient scaler, epoch, RNG states, metric history) and everything evaluation and prediction
need (class names, block and model configuration). Loading uses ``weights_only=True``: the
file holds tensors and plain data only, never pickled code.
"""

from __future__ import annotations

import os
import pickle
import random
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from bimscan.errors import InputFileError, LearnError
from bimscan.learn.config import TrainRunConfig, parse_config
from bimscan.learn.model import PCTSegmentation, build_model

CHECKPOINT_FORMAT = "bimscan-pct-checkpoint"
CHECKPOINT_VERSION = 1


def save_checkpoint(path: Path, payload: dict[str, Any]) -> None:
    """Write ``payload`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    payload = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, **payload}
    handle, temp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    finished = False
    try:
        with os.fdopen(handle, "wb") as out:
            torch.save(payload, out)
        os.replace(temp, path)
        finished = True
    finally:
        if not finished:  # an interrupted save must not leave a torn file behind
            Path(temp).unlink(missing_ok=True)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load a checkpoint onto the CPU; one-line errors for missing or foreign files."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such checkpoint; pass the last.pt or best.pt of a training run")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError, ValueError) as exc:
        # torch reports a broken zip container as RuntimeError, foreign pickles as UnpicklingError
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise InputFileError(f"{path}: not a readable checkpoint ({first}); pass a bimscan checkpoint") from exc
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise InputFileError(f"{path}: not a bimscan PCT checkpoint; pass the last.pt or best.pt of 'bimscan train'")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise InputFileError(f"{path}: checkpoint version {payload.get('version')!r} is not supported ({CHECKPOINT_VERSION} is)")
    return payload


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


@dataclass
class TrainedModel:
    """A network restored from a checkpoint, in eval mode, with what inference needs."""

    model: PCTSegmentation
    config: TrainRunConfig
    class_names: tuple[str, ...]
    epoch: int
    weights: str


def load_trained_model(
    path: str | Path, *, device: torch.device | str = "cpu", weights: Literal["ema", "live"] = "ema",
) -> TrainedModel:
    """Rebuild the network of a checkpoint; ``weights="ema"`` (default, as Table 2) or "live"."""
    payload = read_checkpoint(path)
    config = parse_config(payload["config"], where=f"{path} [config]")
    class_names = tuple(payload["class_names"])
    model = build_model(len(class_names), config.model)
    key = "ema" if weights == "ema" else "model"
    try:
        model.load_state_dict(payload[key])
    except (KeyError, RuntimeError) as exc:
        raise LearnError(f"{path}: the {key} weights do not fit the stored model configuration ({exc})") from exc
    model.to(device).eval()
    return TrainedModel(model=model, config=config, class_names=class_names, epoch=int(payload["epoch"]), weights=weights)

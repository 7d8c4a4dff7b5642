"""Where a checkpoint's predictions go, per original S3DIS class (13 rows, not the 5 mapped ones).

The five-class confusion of ``bimscan evaluate`` says *that* Others is taken for Wall&Column; this
table says *which* Others (windows, boards, doors, clutter...). Rows: S3DIS classes of the rooms'
annotation files; columns: the checkpoint's classes; cells: percent of the row's points.

    .venv/bin/python scripts/s3dis_breakdown.py runs/sim2real-cpu/variants/sim2real-recipe/train/last.pt \
        ../shared/data/real/s3dis_area6
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from bimscan.errors import BimscanError
from bimscan.io.s3dis import S3DIS_CLASSES, list_s3dis_rooms, read_s3dis_room
from bimscan.learn.checkpoint import load_trained_model
from bimscan.learn.data import list_scenes
from bimscan.learn.infer import label_scene


def main(checkpoint: str, rooms_path: str) -> None:
    trained = load_trained_model(checkpoint, device=torch.device("cpu"), weights="ema")
    counts = np.zeros((len(S3DIS_CLASSES), len(trained.class_names)), dtype=np.int64)
    rooms = list_s3dis_rooms(rooms_path)
    if not rooms:
        sys.exit(f"error: {rooms_path}: no S3DIS room folder (with Annotations/) found; pass a room or an area")
    for room in rooms:
        source_class = read_s3dis_room(room).label  # index into S3DIS_CLASSES, in the reader's point order
        predicted = np.full(len(source_class), 255, dtype=np.uint8)  # 255: not labelled (yet)

        def keep(index: np.ndarray, prediction: np.ndarray) -> None:
            predicted[index] = prediction

        label_scene(trained.model, list_scenes([room])[0], class_names=trained.class_names,
                    blocks=trained.config.blocks, inputs=trained.config.input, on_labels=keep)
        if (predicted == 255).any():  # the reader and the labeller must agree on the points' order
            sys.exit(f"error: {room}: {int((predicted == 255).sum())} points got no prediction; report this as a bug")
        np.add.at(counts, (source_class, predicted), 1)
    print(f"{'S3DIS class':12s}" + "".join(f"{name[:11]:>12s}" for name in trained.class_names) + f"{'points':>10s}")
    for name, row in zip(S3DIS_CLASSES, counts, strict=True):
        if row.sum():
            print(f"{name:12s}" + "".join(f"{100 * v / row.sum():12.1f}" for v in row) + f"{row.sum():10d}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(f"usage: {Path(sys.argv[0]).name} CHECKPOINT S3DIS_ROOMS")
    try:
        main(sys.argv[1], sys.argv[2])
    except BimscanError as exc:
        sys.exit(f"error: {exc}")

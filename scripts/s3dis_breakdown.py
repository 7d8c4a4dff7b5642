"""Where a checkpoint's predictions go, per original S3DIS class (13 rows, not the 5 mapped ones).

The five-class confusion of ``bimscan evaluate`` says *that* Others is taken for Wall&Column; this
table says *which* Others (windows, boards, doors, clutter...). Rows: S3DIS classes of the rooms'
annotation files; columns: the checkpoint's classes; cells: percent of the row's points.

A second table asks whether the walls' errors follow their surroundings: wall points binned by
their distance to the nearest point of a class the shipped S3DIS mapping sends to Others and that
stands in the room (furniture and clutter: not windows, doors and boards, which lie in the wall
plane next to every wall point around them), and where each bin's points go. A model that reads
a wall's own geometry calls a wall a wall whatever stands in front of it; one that leans on
context calls the wall behind a desk part of the desk.

    .venv/bin/python scripts/s3dis_breakdown.py runs/sim2real-cpu/variants/sim2real-recipe/train/last.pt \
        ../shared/data/real/s3dis_area6
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from bimscan.errors import BimscanError
from bimscan.io.s3dis import S3DIS_CLASSES, list_s3dis_rooms, read_s3dis_room
from bimscan.learn.checkpoint import load_trained_model
from bimscan.learn.data import list_scenes
from bimscan.learn.infer import label_scene
from bimscan.learn.mapping import load_s3dis_mapping

CONTEXT_BINS_M = (0.0, 0.1, 0.2, 0.4, 0.8, 1.6, np.inf)
IN_WALL_PLANE = ("window", "door", "board")  # next to every wall point around them: not context


def main(checkpoint: str, rooms_path: str) -> None:
    trained = load_trained_model(checkpoint, device=torch.device("cpu"), weights="ema")
    counts = np.zeros((len(S3DIS_CLASSES), len(trained.class_names)), dtype=np.int64)
    mapping = load_s3dis_mapping()
    wall = S3DIS_CLASSES.index("wall")
    nearby = [i for i, name in enumerate(S3DIS_CLASSES)
              if mapping.classes.get(name, mapping.default) == "Others" and name not in IN_WALL_PLANE]
    context = np.zeros((len(CONTEXT_BINS_M) - 1, len(trained.class_names)), dtype=np.int64)
    rooms = list_s3dis_rooms(rooms_path)
    if not rooms:
        sys.exit(f"error: {rooms_path}: no S3DIS room folder (with Annotations/) found; pass a room or an area")
    for room in rooms:
        cloud = read_s3dis_room(room)
        source_class = cloud.label  # index into S3DIS_CLASSES, in the reader's point order
        predicted = np.full(len(source_class), 255, dtype=np.uint8)  # 255: not labelled (yet)

        def keep(index: np.ndarray, prediction: np.ndarray) -> None:
            predicted[index] = prediction

        label_scene(trained.model, list_scenes([room])[0], class_names=trained.class_names,
                    blocks=trained.config.blocks, inputs=trained.config.input, on_labels=keep)
        if (predicted == 255).any():  # the reader and the labeller must agree on the points' order
            sys.exit(f"error: {room}: {int((predicted == 255).sum())} points got no prediction; report this as a bug")
        np.add.at(counts, (source_class, predicted), 1)
        is_wall, is_near = source_class == wall, np.isin(source_class, nearby)
        if is_wall.any() and is_near.any():
            distance, _ = cKDTree(cloud.xyz[is_near]).query(cloud.xyz[is_wall])
            np.add.at(context, (np.digitize(distance, CONTEXT_BINS_M) - 1, predicted[is_wall]), 1)
    print(f"{'S3DIS class':12s}" + "".join(f"{name[:11]:>12s}" for name in trained.class_names) + f"{'points':>10s}")
    for name, row in zip(S3DIS_CLASSES, counts, strict=True):
        if row.sum():
            print(f"{name:12s}" + "".join(f"{100 * v / row.sum():12.1f}" for v in row) + f"{row.sum():10d}")
    print("\nS3DIS wall points by distance to the nearest furniture or clutter point (classes mapped to Others "
          "but " + ", ".join(IN_WALL_PLANE) + ")")
    print(f"{'metres':12s}" + "".join(f"{name[:11]:>12s}" for name in trained.class_names) + f"{'points':>10s}")
    for low, high, row in zip(CONTEXT_BINS_M[:-1], CONTEXT_BINS_M[1:], context, strict=True):
        if row.sum():
            print(f"{f'{low:.1f}-{high:.1f}':12s}" + "".join(f"{100 * v / row.sum():12.1f}" for v in row)
                  + f"{row.sum():10d}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(f"usage: {Path(sys.argv[0]).name} CHECKPOINT S3DIS_ROOMS")
    try:
        main(sys.argv[1], sys.argv[2])
    except BimscanError as exc:
        sys.exit(f"error: {exc}")

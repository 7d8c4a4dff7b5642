"""Training curves (the paper's Figs. 7 and 8): loss, OA, mIoU, mAcc, FWIoU and kappa per epoch,
for the synthetic training set and the real validation set, as one PNG (matplotlib, Agg)."""

from __future__ import annotations

import csv
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path

PANELS = (("loss", "Loss"), ("oa", "OA"), ("miou", "mIoU"), ("macc", "mAcc"), ("fwiou", "FWIoU"), ("kappa", "Cohen's kappa"))
CSV_COLUMNS = (
    "epoch", "lr", "seconds",
    *(f"train_{name}" for name, _ in PANELS),
    *(f"val_{name}" for name, _ in PANELS),
)


def _atomic_target(path: Path) -> tuple[int, str]:
    return tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)


def write_history_csv(history: Sequence[Mapping[str, float]], path: Path) -> None:
    """One row per epoch, columns ``CSV_COLUMNS``; NaN (no validation set) written empty."""
    handle, temp = _atomic_target(path)
    finished = False
    try:
        with os.fdopen(handle, "w", encoding="utf-8", newline="") as out:
            writer = csv.writer(out, lineterminator="\n")
            writer.writerow(CSV_COLUMNS)
            for row in history:
                cells = []
                for column in CSV_COLUMNS:
                    value = row.get(column, math.nan)
                    if column == "epoch":
                        cells.append(str(int(value)))
                    else:
                        cells.append("" if value is None or math.isnan(float(value)) else f"{float(value):.6g}")
                writer.writerow(cells)
        os.replace(temp, path)
        finished = True
    finally:
        if not finished:
            Path(temp).unlink(missing_ok=True)


def plot_training_curves(history: Sequence[Mapping[str, float]], path: Path, *, title: str = "") -> None:
    """Draw the six metric panels, train and validation lines, into a PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [int(row["epoch"]) for row in history]
    figure, axes = plt.subplots(2, 3, figsize=(12, 6.5), constrained_layout=True)
    for axis, (name, label) in zip(axes.flat, PANELS, strict=True):
        for split, style in (("train", "-"), ("val", "--")):
            values = [float(row.get(f"{split}_{name}", math.nan)) for row in history]
            if all(math.isnan(v) for v in values):
                continue
            axis.plot(epochs, values, style, marker="o", markersize=3,
                      label="training (synthetic)" if split == "train" else "validation (real)")
        axis.set_title(label)
        axis.set_xlabel("epoch")
        axis.grid(True, alpha=0.3)
        if name != "loss":
            axis.set_ylim(min(0.0, axis.get_ylim()[0]), 1.0)
    axes.flat[0].legend(loc="best", fontsize="small")
    if title:
        figure.suptitle(title)
    handle, temp = _atomic_target(path)
    os.close(handle)
    finished = False
    try:
        figure.savefig(temp, format="png", dpi=110, metadata={"Software": None})
        os.replace(temp, path)
        finished = True
    finally:
        plt.close(figure)
        if not finished:
            Path(temp).unlink(missing_ok=True)

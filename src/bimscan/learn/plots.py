"""Training curves (the paper's Figs. 7 and 8): loss, OA, mIoU, mAcc, FWIoU and kappa per epoch,
for the synthetic training set and the real validation set, as one PNG; and a confusion matrix,
row-normalised, as a PNG (matplotlib, Agg)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bimscan.files import save_png, write_atomic

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PANELS = (("loss", "Loss"), ("oa", "OA"), ("miou", "mIoU"), ("macc", "mAcc"), ("fwiou", "FWIoU"), ("kappa", "Cohen's kappa"))
CSV_COLUMNS = (
    "epoch", "lr", "seconds",
    *(f"train_{name}" for name, _ in PANELS),
    *(f"val_{name}" for name, _ in PANELS),
)


def write_history_csv(history: Sequence[Mapping[str, float]], path: Path) -> None:
    """One row per epoch, columns ``CSV_COLUMNS``; NaN (no validation set) written empty."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
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
    write_atomic(path, buffer.getvalue().encode("utf-8"))


def plot_training_curves(history: Sequence[Mapping[str, float]], path: Path, *, title: str = "") -> None:
    """Draw the six metric panels, train and validation lines, into a PNG at ``path``."""
    epochs = [int(row["epoch"]) for row in history]
    figure = _figure((12, 6.5), layout="constrained")
    axes = figure.subplots(2, 3)
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
    save_figure(figure, path)


def plot_confusion(confusion: np.ndarray, class_names: Sequence[str], path: Path, *, title: str) -> None:
    """Draw a (C, C) confusion matrix of counts (rows = ground truth, columns = prediction, in
    ``class_names`` order) into a PNG at ``path``: each row normalised to its ground-truth points,
    the share in percent in every cell; a row without ground truth stays blank."""
    counts = np.asarray(confusion, dtype=np.float64)
    if counts.ndim != 2 or counts.shape[0] != counts.shape[1] or counts.shape[0] != len(class_names):
        raise ValueError(f"confusion matrix must be (C, C) with C = {len(class_names)} class names, "
                         f"got shape {counts.shape}")
    support = counts.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        shares = np.where(support > 0, counts / np.where(support > 0, support, 1.0), np.nan)
    size = len(class_names)
    figure = _figure((max(4.5, 0.9 * size + 2.8), max(3.8, 0.8 * size + 1.8)), layout="constrained")
    axis = figure.subplots()
    image = axis.imshow(100.0 * shares, cmap="Blues", vmin=0.0, vmax=100.0)
    figure.colorbar(image, ax=axis, label="share of the ground truth (%)")
    for row in range(size):
        for column in range(size):
            share = shares[row, column]
            if not math.isnan(share):
                axis.text(column, row, f"{100.0 * share:.1f}%", ha="center", va="center", fontsize="small",
                          color="white" if share > 0.6 else "black")
    axis.set_xticks(range(size), labels=list(class_names), rotation=45, ha="right")
    axis.set_yticks(range(size), labels=list(class_names))
    axis.set_xlabel("prediction")
    axis.set_ylabel("ground truth")
    axis.set_title(title)
    save_figure(figure, path)


def plot_variant_curves(curves: Mapping[str, Sequence[float]], path: Path, *, title: str) -> None:
    """Real-validation mIoU per epoch of several training runs (sim2real variants) in one PNG."""
    figure = _figure((7, 4.5), layout="tight")
    axis = figure.subplots()
    for name, values in curves.items():
        axis.plot(range(1, len(values) + 1), values, marker="o", markersize=3, label=name)
    axis.set_xlabel("epoch")
    axis.set_ylabel("mIoU on real validation blocks")
    axis.set_title(title)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    save_figure(figure, path)


def plot_label_efficiency(series: Mapping[str, Sequence[tuple[float, float, str]]], path: Path, *, title: str) -> None:
    """mIoU against the number of real rooms trained on: points (rooms, mIoU, variant name) per
    series (with and without synthetic pretraining), each series joined in order of rooms."""
    figure = _figure((7, 4.5), layout="tight")
    axis = figure.subplots()
    for name, points in series.items():
        if not points:
            continue
        ordered = sorted(points)
        axis.plot([p[0] for p in ordered], [p[1] for p in ordered], marker="o", label=name)
        for rooms, miou, variant in ordered:
            axis.annotate(variant, (rooms, miou), textcoords="offset points", xytext=(4, 4), fontsize=7)
    axis.set_xlabel("real rooms trained on")
    axis.set_ylabel("mIoU on real rooms not trained on")
    axis.set_title(title)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=8)
    save_figure(figure, path)


def _figure(size_in: tuple[float, float], *, layout: str) -> Figure:
    """A matplotlib Figure of its own (no pyplot state: nothing to close, safe in threads)."""
    from matplotlib.figure import Figure

    return Figure(figsize=size_in, layout=layout)


def save_figure(figure: Figure, path: Path) -> None:
    """Write a figure as PNG (``bimscan.files.save_png``) at the learning pictures' resolution."""
    save_png(figure, path, dpi=110)

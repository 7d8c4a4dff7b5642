"""Sim-to-real evaluation: every point of every scene labelled, one metrics row per scene.

The table follows the paper's Table 3 (OA, mIoU, mAcc, FWIoU, kappa per scene, in percent),
with two summary rows: ``mean`` (the average of the per-scene values, as the paper's scene
means) and ``all points`` (the metrics of the pooled confusion matrix). Written as Markdown and
CSV; the CSV adds point counts, per-class IoU and the classes present in each scene.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import LearnError
from bimscan.files import write_atomic
from bimscan.learn.checkpoint import load_trained_model
from bimscan.learn.data import list_scenes
from bimscan.learn.infer import SceneLabels, label_scene
from bimscan.learn.mapping import LabelMapping
from bimscan.learn.metrics import METRIC_NAMES, SegmentationMetrics, compute_metrics
from bimscan.learn.model import pick_device

HEADINGS = {"oa": "OA", "miou": "mIoU", "macc": "mAcc", "fwiou": "FWIoU", "kappa": "κ"}


@dataclass(frozen=True)
class SceneEvaluation:
    """One scene's result: its labelling summary and the metrics of its confusion matrix, whose
    rows and columns are ``class_names`` (the checkpoint's classes)."""

    scene: str
    path: Path
    labels: SceneLabels
    metrics: SegmentationMetrics
    class_names: tuple[str, ...]


def evaluate_checkpoint(
    checkpoint: str | Path, scenes: Sequence[str | Path], *, label_field: str | None = None,
    mapping: LabelMapping | None = None, device: str = "auto", batch_size: int = 8, max_passes: int = 0,
    weights: str = "ema", seed: int = 0, work_dir: Path | None = None,
) -> list[SceneEvaluation]:
    """Label every point of each scene with the checkpoint's network and score it.

    Scenes must carry ground truth (after the mapping); class names come from the checkpoint.
    """
    torch_device = pick_device(device)
    trained = load_trained_model(checkpoint, device=torch_device, weights="ema" if weights == "ema" else "live")
    sources = list_scenes(scenes, label_field=label_field, mapping=mapping)
    results = []
    for source in sources:
        labels = label_scene(
            trained.model, source, class_names=trained.class_names, blocks=trained.config.blocks,
            device=torch_device, batch_size=batch_size, amp=trained.config.train.amp, seed=seed,
            max_passes=max_passes, work_dir=work_dir, inputs=trained.config.input,
        )
        if labels.labelled == 0:
            raise LearnError(
                f"{source.path}: no point has a ground-truth class among {', '.join(trained.class_names)}; "
                "evaluation needs labels (check --label-field/--mapping, or use 'bimscan predict')"
            )
        results.append(SceneEvaluation(
            source.name, source.path, labels, compute_metrics(labels.confusion), trained.class_names,
        ))
    return results


def _percent(value: float) -> str:
    return "-" if math.isnan(value) else f"{100.0 * value:.1f}"


def summarize_results(results: Sequence[SceneEvaluation]) -> list[tuple[str, dict[str, float]]]:
    """(name, metrics) rows: one per scene, then ``mean`` and ``all points``."""
    rows = [(r.scene, r.metrics.scalars()) for r in results]
    if results:
        mean = {name: float(np.nanmean([r.metrics.scalars()[name] for r in results])) for name in METRIC_NAMES}
        pooled = compute_metrics(np.sum([r.labels.confusion for r in results], axis=0)).scalars()
        rows += [("mean", mean), ("all points", pooled)]
    return rows


def format_markdown(results: Sequence[SceneEvaluation]) -> str:
    """The per-scene table (percent, one decimal) as Markdown."""
    lines = ["| Scene | " + " | ".join(HEADINGS[n] for n in METRIC_NAMES) + " |",
             "|---|" + "---:|" * len(METRIC_NAMES)]
    for i, (name, values) in enumerate(summarize_results(results)):
        label = name if i < len(results) else f"**{name}**"  # summary rows in bold
        lines.append(f"| {label} | " + " | ".join(_percent(values[n]) for n in METRIC_NAMES) + " |")
    return "\n".join(lines) + "\n"


def format_csv(results: Sequence[SceneEvaluation], class_names: Sequence[str]) -> str:
    """Per-scene rows with fractions (0..1), counts, per-class IoU and present classes."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["scene", *METRIC_NAMES, "points", "labelled_points", "nearest_filled",
                     *(f"iou_{c}" for c in class_names), "present_classes"])
    for i, (name, values) in enumerate(summarize_results(results)):
        result = results[i] if i < len(results) else None
        cells = [name, *("" if math.isnan(values[n]) else f"{values[n]:.6f}" for n in METRIC_NAMES)]
        if result is not None:
            m = result.metrics
            cells += [result.labels.points, result.labels.labelled, result.labels.nearest_filled]
            cells += ["" if math.isnan(v) else f"{v:.6f}" for v in m.iou]
            cells.append(";".join(c for c, p in zip(class_names, m.present, strict=True) if p))
        else:
            cells += [""] * (3 + len(class_names) + 1)
        writer.writerow(cells)
    return buffer.getvalue()


def write_evaluation(results: Sequence[SceneEvaluation], out_dir: Path, class_names: Sequence[str]) -> tuple[Path, Path]:
    """Write ``evaluation.md`` and ``evaluation.csv`` into ``out_dir`` (created if missing)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    markdown, table = out_dir / "evaluation.md", out_dir / "evaluation.csv"
    write_atomic(markdown, format_markdown(results).encode("utf-8"))
    write_atomic(table, format_csv(results, class_names).encode("utf-8"))
    return markdown, table

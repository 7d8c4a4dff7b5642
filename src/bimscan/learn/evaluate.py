"""Sim-to-real evaluation: every point of every scene labelled, one metrics row per scene.

The table follows the paper's Table 3 (OA, mIoU, mAcc, FWIoU, kappa per scene, in percent),
with two summary rows: ``mean`` (the average of the per-scene values, as the paper's scene
means) and ``all points`` (the metrics of the pooled confusion matrix), followed by the IoU of
each class per scene and over all points. Files written by ``write_evaluation``:

- ``evaluation.md``: both tables; ``evaluation.csv``: fractions, point counts, per-class IoU and
  the classes present in each scene;
- ``evaluation.json``: per scene and for ``mean`` and ``all points``, the five metrics, IoU,
  accuracy (recall) and support per class name, and the confusion matrix (rows = ground truth,
  columns = prediction, counts); NaN (an absent class) is written as null;
- ``confusion.csv`` (counts) and ``confusion.png`` (row-normalised): the pooled matrix;
- for bimscan clouds (whose points carry the component they lie on) and S3DIS rooms (whose points
  carry their annotation class): ``elements.csv``, where the points of each source class went (an
  IFC class; wall, board, door, ...), per scene and over all points, and the same over all points
  as a last table in ``evaluation.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import LearnError
from bimscan.files import (
    check_output_folder, dump_json, json_marker, prepare_output_folder, read_marker, write_atomic,
)
from bimscan.learn.checkpoint import load_trained_models
from bimscan.io.s3dis import S3DIS_CLASSES
from bimscan.learn.data import build_scene_label_table, check_scene_unit, list_scenes, stored_header
from bimscan.learn.infer import SceneLabels, label_scene
from bimscan.learn.mapping import LabelMapping
from bimscan.learn.metrics import METRIC_NAMES, SegmentationMetrics, compute_metrics
from bimscan.learn.model import pick_device
from bimscan.learn.plots import plot_confusion
from bimscan.learn.train_config import IGNORE_LABEL, EvalConfig
from bimscan.types import CloudHeader

HEADINGS = {"oa": "OA", "miou": "mIoU", "macc": "mAcc", "fwiou": "FWIoU", "kappa": "κ"}
CONFUSION_AXES = "rows: ground truth, columns: prediction"
NO_COMPONENT = "(no component)"
ELEMENT_TABLE_MIN_SHARE = 0.005  # evaluation.md lists the IFC classes holding at least this share of the points


@dataclass(frozen=True)
class ElementBreakdown:
    """Where the points of each source class went: the IFC classes of a bimscan cloud (its points
    carry component ids), the annotation classes of an S3DIS room (wall, board, door, ...).

    One row per (source class, the class it carries in the scene's labels): ``ifc_class`` and
    ``truth`` name it, ``counts`` (R, C) int64 holds its points per predicted class (the
    checkpoint's classes). Points on no component are the row (``NO_COMPONENT``, "").
    """

    ifc_class: tuple[str, ...]
    truth: tuple[str, ...]
    counts: np.ndarray

    @staticmethod
    def of(element_counts: np.ndarray, header: CloudHeader) -> ElementBreakdown:
        """Group a scene's per-component counts ((E + 1, C), last row: no component) by IFC class."""
        components = header.components
        assert components is not None
        names = header.scheme.names
        keys = [(str(c), names.get(int(label), str(int(label))))
                for c, label in zip(components.ifc_class, components.label, strict=True)] + [(NO_COMPONENT, "")]
        return _grouped(keys, element_counts)

    @staticmethod
    def of_s3dis(class_counts: np.ndarray, truth: Sequence[str]) -> ElementBreakdown:
        """Group an S3DIS room's per-class counts ((K + 1, C), rows in ``S3DIS_CLASSES`` order, the
        last for none) by class; ``truth``: each S3DIS class's training class (or "" for none)."""
        keys = [(name, truth[k]) for k, name in enumerate(S3DIS_CLASSES)] + [(NO_COMPONENT, "")]
        return _grouped(keys, class_counts)

    @property
    def points(self) -> np.ndarray:
        return self.counts.sum(axis=1)


def _grouped(keys: Sequence[tuple[str, str]], counts: np.ndarray) -> ElementBreakdown:
    """Rows of ``counts`` summed by key, sorted by key; keys without points are dropped."""
    rows: dict[tuple[str, str], np.ndarray] = {}
    for key, row in zip(keys, np.asarray(counts, dtype=np.int64), strict=True):
        rows[key] = rows[key] + row if key in rows else row.copy()
    kept = sorted(k for k, row in rows.items() if row.sum() > 0)
    width = counts.shape[1]
    return ElementBreakdown(tuple(k[0] for k in kept), tuple(k[1] for k in kept),
                            np.array([rows[k] for k in kept], dtype=np.int64).reshape(len(kept), width))


def pool_elements(results: Sequence[SceneEvaluation]) -> ElementBreakdown | None:
    """The scenes' breakdowns summed row by row (None when no scene has one)."""
    found = [r.elements for r in results if r.elements is not None]
    if not found:
        return None
    keys = [key for b in found for key in zip(b.ifc_class, b.truth, strict=True)]
    return _grouped(keys, np.concatenate([b.counts for b in found]))


@dataclass(frozen=True)
class SceneEvaluation:
    """One scene's result: its labelling summary and the metrics of its confusion matrix, whose
    rows and columns are ``class_names`` (the checkpoint's classes), and how it was labelled."""

    scene: str
    path: Path
    labels: SceneLabels
    metrics: SegmentationMetrics
    class_names: tuple[str, ...]
    evaluation: EvalConfig  # how the scene was labelled
    elements: ElementBreakdown | None = None  # bimscan clouds, S3DIS rooms: where each source class's points went


def evaluate_checkpoint(
    checkpoint: str | Path, scenes: Sequence[str | Path], *, label_field: str | None = None,
    mapping: LabelMapping | None = None, device: str = "auto", evaluation: EvalConfig | None = None,
    work_dir: Path | None = None, warn: Callable[[str], None] | None = None, ensemble: Sequence[str | Path] = (),
) -> list[SceneEvaluation]:
    """Label every point of each scene with the checkpoint's network and score it.

    Scenes must carry ground truth (after the mapping); class names come from the checkpoint.
    ``evaluation``: how to label (default: the checkpoint's own ``[eval]``). ``ensemble``: more
    checkpoints whose class probabilities are averaged with the checkpoint's
    (``bimscan.learn.checkpoint.Ensemble``).
    """
    torch_device = pick_device(device)
    trained = load_trained_models([checkpoint, *ensemble], device=torch_device,
                                  weights=None if evaluation is None else evaluation.weights)
    evaluation = (evaluation or trained.config.eval).with_seed(trained.config.train.seed)
    trained.config.eval.stride_for(trained.config.blocks.size_m)
    evaluation.stride_for(trained.config.blocks.size_m)  # a stride that does not divide the blocks: one line now
    sources = list_scenes(scenes, label_field=label_field, mapping=mapping)
    for source in sources:  # every scene in metres before the first is labelled
        check_scene_unit(source, blocks=trained.config.blocks)
    results = []
    for source in sources:
        header = stored_header(source)
        components = header.components if header is not None else None
        kinds = len(S3DIS_CLASSES) if source.kind == "s3dis" else 0  # S3DIS rooms: a breakdown by their classes
        labels = label_scene(
            trained.model, source, class_names=trained.class_names, blocks=trained.config.blocks,
            evaluation=evaluation, device=torch_device, amp=trained.config.train.amp, work_dir=work_dir,
            inputs=trained.config.input, warn=warn, checkpoint=checkpoint,
            elements=kinds if components is None else len(components.ifc_class),
        )
        if labels.labelled == 0:
            raise LearnError(
                f"{source.path}: no point has a ground-truth class among {', '.join(trained.class_names)}; "
                "evaluation needs labels (check --label-field/--mapping, or use 'bimscan predict')"
            )
        elements = None
        if header is not None and labels.element_counts is not None:
            elements = ElementBreakdown.of(labels.element_counts, header)
        elif kinds and labels.element_counts is not None:
            table = build_scene_label_table(source, class_names=trained.class_names)
            truth = [trained.class_names[t] if t != IGNORE_LABEL else "" for t in table[:len(S3DIS_CLASSES)].tolist()]
            elements = ElementBreakdown.of_s3dis(labels.element_counts, truth)
        results.append(SceneEvaluation(
            source.name, source.path, labels, compute_metrics(labels.confusion), trained.class_names, evaluation,
            elements,
        ))
    return results


def _percent(value: float) -> str:
    return "-" if math.isnan(value) else f"{100.0 * value:.1f}"


def pool_confusion(results: Sequence[SceneEvaluation]) -> np.ndarray:
    """The (C, C) int64 sum of the scenes' confusion matrices (the ``all points`` row)."""
    return np.sum([r.labels.confusion for r in results], axis=0).astype(np.int64)


def summarize_results(results: Sequence[SceneEvaluation]) -> list[tuple[str, dict[str, float]]]:
    """(name, metrics) rows: one per scene, then ``mean`` and ``all points``."""
    rows = [(r.scene, r.metrics.scalars()) for r in results]
    if results:
        mean = {name: float(np.nanmean([r.metrics.scalars()[name] for r in results])) for name in METRIC_NAMES}
        pooled = compute_metrics(pool_confusion(results)).scalars()
        rows += [("mean", mean), ("all points", pooled)]
    return rows


def format_markdown(results: Sequence[SceneEvaluation], *, class_iou: bool = True) -> str:
    """The per-scene table (percent, one decimal) as Markdown, followed by the per-class IoU
    table (``format_class_iou_markdown``) unless ``class_iou`` is False."""
    lines = ["| Scene | " + " | ".join(HEADINGS[n] for n in METRIC_NAMES) + " |",
             "|---|" + "---:|" * len(METRIC_NAMES)]
    for i, (name, values) in enumerate(summarize_results(results)):
        label = name if i < len(results) else f"**{name}**"  # summary rows in bold
        lines.append(f"| {label} | " + " | ".join(_percent(values[n]) for n in METRIC_NAMES) + " |")
    text = "\n".join(lines) + "\n"
    if class_iou and results:
        text += "\nIoU per class (%):\n\n" + format_class_iou_markdown(results)
    return text


def format_class_iou_markdown(results: Sequence[SceneEvaluation]) -> str:
    """IoU per class in percent (one decimal) as Markdown: a row per scene and the ``all points``
    row, a column per class of the checkpoint; ``-`` where the class is absent (neither in the
    ground truth nor predicted). Empty without results."""
    if not results:
        return ""
    class_names = results[0].class_names
    lines = ["| Scene | " + " | ".join(c.replace("|", "\\|") for c in class_names) + " |",
             "|---|" + "---:|" * len(class_names)]
    rows = [(r.scene, r.metrics.iou) for r in results]
    rows.append(("**all points**", compute_metrics(pool_confusion(results)).iou))
    for name, iou in rows:
        lines.append(f"| {name} | " + " | ".join(_percent(float(v)) for v in iou) + " |")
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


def _number(value: float) -> float | None:
    return None if math.isnan(value) else float(value)


def _per_class(values: np.ndarray, class_names: Sequence[str]) -> dict[str, float | None]:
    return {name: _number(float(v)) for name, v in zip(class_names, values, strict=True)}


def _confusion_document(confusion: np.ndarray, class_names: Sequence[str]) -> dict[str, object]:
    return {"axes": CONFUSION_AXES, "class_names": list(class_names),
            "matrix": np.asarray(confusion, dtype=np.int64).tolist()}


def _metrics_document(name: str, metrics: SegmentationMetrics, confusion: np.ndarray,
                      class_names: Sequence[str]) -> dict[str, object]:
    return {
        "name": name,
        "metrics": {key: _number(value) for key, value in metrics.scalars().items()},
        "iou": _per_class(metrics.iou, class_names),
        "acc": _per_class(metrics.acc, class_names),
        "support": {c: int(v) for c, v in zip(class_names, metrics.support, strict=True)},
        "confusion": _confusion_document(confusion, class_names),
    }


def evaluation_document(results: Sequence[SceneEvaluation], class_names: Sequence[str]) -> dict[str, object]:
    """The content of ``evaluation.json``: fractions 0..1 (kappa -1..1), NaN as None.

    ``scenes`` (one entry each, with point counts), ``all points`` (the pooled confusion matrix,
    the sum of the scenes') and ``mean``: the per-scene metrics and per-class IoU/accuracy
    averaged over the scenes where defined; its support and confusion are the summed ones.
    """
    scenes = []
    for result in results:
        entry = _metrics_document(result.scene, result.metrics, result.labels.confusion, class_names)
        entry.update(path=str(result.path), points=result.labels.points, labelled_points=result.labels.labelled,
                     nearest_filled=result.labels.nearest_filled, network_points=result.labels.network_points,
                     seconds=round(result.labels.seconds, 3))
        scenes.append(entry)
    pooled_confusion = pool_confusion(results) if results else np.zeros((len(class_names),) * 2, np.int64)
    pooled = compute_metrics(pooled_confusion)
    document: dict[str, object] = {
        "class_names": list(class_names),
        "evaluation": dataclasses.asdict(results[0].evaluation) if results else None,  # how every point was labelled
        "scenes": scenes,
        "all points": _metrics_document("all points", pooled, pooled_confusion, class_names),
        "mean": None,
    }
    if results:
        rows = dict(summarize_results(results))
        mean = _metrics_document("mean", pooled, pooled_confusion, class_names)
        mean["metrics"] = {key: _number(value) for key, value in rows["mean"].items()}
        mean["iou"] = _per_class(_scene_mean([r.metrics.iou for r in results]), class_names)
        mean["acc"] = _per_class(_scene_mean([r.metrics.acc for r in results]), class_names)
        document["mean"] = mean
    return document


def _scene_mean(values: Sequence[np.ndarray]) -> np.ndarray:
    """Per-class mean over the scenes where the value is defined; NaN where it never is."""
    stacked = np.asarray(values, dtype=np.float64)
    defined = ~np.isnan(stacked)
    count = defined.sum(axis=0)
    total = np.where(defined, stacked, 0.0).sum(axis=0)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def format_elements_markdown(breakdown: ElementBreakdown, class_names: Sequence[str], *,
                             min_share: float = ELEMENT_TABLE_MIN_SHARE) -> str:
    """Where each source class's points went, as Markdown (percent of the row's points, one decimal),
    largest first; rows under ``min_share`` of all points are left out (and counted below)."""
    points = breakdown.points
    total = max(int(points.sum()), 1)
    lines = ["| source class | labelled | points | share | " + " | ".join(c.replace("|", "\\|") for c in class_names)
             + " | right |", "|---|---|---:|---:|" + "---:|" * (len(class_names) + 1)]
    order = np.argsort(-points, kind="stable")
    shown = [int(i) for i in order if points[i] >= min_share * total]
    for i in shown:
        row = breakdown.counts[i] / max(int(points[i]), 1)
        truth = breakdown.truth[i]
        right = _percent(float(row[list(class_names).index(truth)])) if truth in class_names else "-"
        lines.append(f"| {breakdown.ifc_class[i]} | {truth or '-'} | {int(points[i]):,} | "
                     f"{100 * points[i] / total:.1f} | " + " | ".join(_percent(float(v)) for v in row)
                     + f" | {right} |")
    text = "\n".join(lines) + "\n"
    left = len(points) - len(shown)
    if left:
        text += (f"\n{left} more row(s) under {100 * min_share:g} % of the points each "
                 f"({int(points.sum() - points[shown].sum()):,} points; all in elements.csv).\n")
    return text


def format_elements_csv(results: Sequence[SceneEvaluation], pooled: ElementBreakdown,
                        class_names: Sequence[str]) -> str:
    """Per scene with a breakdown, then over all points (``pooled``, :func:`pool_elements`): IFC
    class, its labelled class, points and the points per predicted class."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["scene", "source_class", "labelled", "points", *(f"predicted_{c}" for c in class_names)])
    rows = [(r.scene, r.elements) for r in results if r.elements is not None]
    for scene, breakdown in rows + [("all points", pooled)]:
        for ifc_class, truth, counts in zip(breakdown.ifc_class, breakdown.truth, breakdown.counts, strict=True):
            writer.writerow([scene, ifc_class, truth, int(counts.sum()), *(int(v) for v in counts)])
    return buffer.getvalue()


def format_confusion_csv(confusion: np.ndarray, class_names: Sequence[str]) -> str:
    """A (C, C) confusion matrix of counts as CSV: the header names the predicted classes, the
    first column the ground-truth classes."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["truth \\ prediction", *class_names])
    for name, row in zip(class_names, np.asarray(confusion, dtype=np.int64), strict=True):
        writer.writerow([name, *(int(v) for v in row)])
    return buffer.getvalue()


@dataclass(frozen=True)
class EvaluationFiles:
    """The files ``write_evaluation`` wrote."""

    markdown: Path
    table: Path
    json: Path
    confusion_table: Path
    confusion_plot: Path
    elements: Path | None = None  # bimscan clouds only

    def paths(self) -> tuple[Path, ...]:
        """Every file written, in the order of the fields."""
        files = (self.markdown, self.table, self.json, self.confusion_table, self.confusion_plot, self.elements)
        return tuple(p for p in files if p is not None)


EVALUATION_FILES = ("evaluation.md", "evaluation.csv", "evaluation.json", "confusion.csv", "confusion.png",
                    "elements.csv")


def is_earlier_evaluation(folder: Path) -> bool:
    """Whether ``folder`` holds an evaluation written before output folders had records."""
    return json_marker(read_marker(folder / "evaluation.json"), "all points")


def check_evaluation_output(out_dir: Path) -> None:
    """OutputError, before any scene is read, when ``write_evaluation`` may not write into
    ``out_dir`` (``bimscan.files.check_output_folder``): a user's folder, or a user's file at one
    of its names (a ``metrics.csv`` beside them is left alone)."""
    check_output_folder(out_dir, names=EVALUATION_FILES, made_by=is_earlier_evaluation)


def write_evaluation(results: Sequence[SceneEvaluation], out_dir: Path, class_names: Sequence[str], *,
                     title: str = "") -> EvaluationFiles:
    """Write ``evaluation.md``, ``evaluation.csv``, ``evaluation.json``, ``confusion.csv`` and
    ``confusion.png`` (titled ``title``, default "Confusion, all points") into ``out_dir``
    (created if missing; an output folder, see ``check_evaluation_output``), and ``elements.csv``
    when a scene is a bimscan cloud."""
    prepare_output_folder(out_dir, names=EVALUATION_FILES, made_by=is_earlier_evaluation)
    elements = pool_elements(results)
    files = EvaluationFiles(out_dir / "evaluation.md", out_dir / "evaluation.csv", out_dir / "evaluation.json",
                            out_dir / "confusion.csv", out_dir / "confusion.png",
                            out_dir / "elements.csv" if elements is not None else None)
    pooled = pool_confusion(results) if results else np.zeros((len(class_names),) * 2, np.int64)
    markdown = format_markdown(results)
    if elements is not None and files.elements is not None:  # the one implies the other; the type checker needs both
        markdown += ("\nWhere each source class's points went (the IFC classes of bimscan clouds, the annotation "
                     "classes of S3DIS rooms), all points (percent of its points; 'right': the class it is "
                     "labelled):\n\n" + format_elements_markdown(elements, class_names))
        write_atomic(files.elements, format_elements_csv(results, elements, class_names).encode("utf-8"))
    write_atomic(files.markdown, markdown.encode("utf-8"))
    write_atomic(files.table, format_csv(results, class_names).encode("utf-8"))
    write_atomic(files.json, dump_json(evaluation_document(results, class_names)))
    write_atomic(files.confusion_table, format_confusion_csv(pooled, class_names).encode("utf-8"))
    plot_confusion(pooled, class_names, files.confusion_plot, title=title or "Confusion, all points")
    return files

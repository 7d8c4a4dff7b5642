"""The report of an experiment (:mod:`bimscan.learn.experiment`): ``report.md``, ``results.csv``,
``results.json``, the real-validation curves of every variant (``val_miou.png``) and, when
variants train on real rooms, the label-efficiency plot (``label_efficiency.png``: real-room mIoU
against the number of real rooms trained on, with and without synthetic pretraining)."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bimscan.files import write_atomic
from bimscan.learn.metrics import METRIC_NAMES

if TYPE_CHECKING:
    from bimscan.learn.experiment import Experiment, VariantResult


def _pct(value: float | None) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{100.0 * value:.1f}"


def _rooms_trained(result: VariantResult) -> float:
    """Real rooms a variant's models trained on (the mean over its folds)."""
    counts = [len(rooms) for rooms in result.train_rooms]
    return sum(counts) / len(counts) if counts else 0.0


def format_report(experiment: Experiment, results: Sequence[VariantResult]) -> str:
    """The comparison as Markdown: one row per variant (its scored real points pooled), per-class
    IoU, the mean over scenes, the holdout buildings, how each variant was trained and scored."""
    if not results:
        return "# experiment\n\nNo variant.\n"
    classes = results[0].class_names
    lines = [f"# {experiment.name}", "",
             f"Scored on the real scenes of {', '.join(experiment.real.scenes)}, every point, never on a room the "
             "model trained on (see 'scored on' below). Percent over the scored points pooled; 'scene mean' "
             "averages the per-scene values (the paper's Table 3 mean).", "",
             "| Variant | OA | mIoU | mAcc | FWIoU | κ | " + " | ".join(f"IoU {c}" for c in classes)
             + " | scene mean mIoU | scene mean κ |",
             "|---|" + "---:|" * (5 + len(classes) + 2)]
    for r in results:
        p = r.pooled
        lines.append(f"| {r.variant} | " + " | ".join(_pct(p[m]) for m in METRIC_NAMES) + " | "
                     + " | ".join(_pct(p["iou"][c]) for c in classes)
                     + f" | {_pct(r.scene_mean['miou'])} | {_pct(r.scene_mean['kappa'])} |")
    holdouts = [r for r in results if r.holdout is not None]
    if holdouts:
        buildings = list(holdouts[0].holdout["buildings"])  # type: ignore[index]
        lines += ["", f"Holdout buildings, scanned by bimscan and never trained on ({', '.join(buildings)}); "
                  "percent over all their points pooled:", "",
                  "| Variant | OA | mIoU | mAcc | FWIoU | κ | " + " | ".join(f"IoU {c}" for c in classes) + " |",
                  "|---|" + "---:|" * (5 + len(classes))]
        for r in holdouts:
            p = r.holdout["pooled"]  # type: ignore[index]
            lines.append(f"| {r.variant} | " + " | ".join(_pct(p[m]) for m in METRIC_NAMES) + " | "
                         + " | ".join(_pct(p["iou"][c]) for c in classes) + " |")
        lines += ["", "Per holdout building (OA / mIoU, percent):", "",
                  "| Building | " + " | ".join(r.variant for r in holdouts) + " |", "|---|" + "---:|" * len(holdouts)]
        for name in buildings:
            cells = []
            for r in holdouts:
                row = r.holdout["buildings"].get(name)  # type: ignore[index]
                cells.append("-" if row is None else f"{_pct(row['oa'])} / {_pct(row['miou'])}")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines += ["", "Where each IFC class's points went (per building and pooled): "
                  "`variants/<variant>/.../holdout/elements.csv`, pooled in its `evaluation.md`."]
    lines += ["", "Variants:", ""]
    for r in results:
        how = []
        if r.synthetic:
            how.append("synthetic data")
        rooms = _rooms_trained(r)
        if rooms:
            how.append(f"{rooms:g} real room(s)" + (f" per fold, {r.folds} folds" if r.folds else ""))
        if r.init:
            how.append(f"starting from {r.init}")
        adapted = max((len(names) for names in r.adapted), default=0)
        if adapted:
            how.append(f"adapted to {adapted} unlabelled scene(s)" + (" per fold" if r.folds else "")
                       + " (their labels never read)")
        scored = len(r.scenes)
        excluded = f"; its training rooms ({', '.join(r.excluded)}) are not scored" if r.excluded and not r.folds else ""
        folds = "; each fold's model scored on its held-out rooms" if r.folds else ""
        text = f" {r.description}" if r.description else ""
        trained = (f"The mean class probabilities of {', '.join(r.ensemble)} (trains nothing)" if r.ensemble
                   else f"Trained on {', '.join(how)}")
        cost = "Its members' training" if r.ensemble else "Training"
        lines.append(f"- **{r.variant}**:{text} {trained}; scored on {scored} real scene(s)"
                     f"{excluded}{folds}. {cost} {r.train_seconds / 60:.1f} min. Evaluation: columns every "
                     f"{r.evaluation['stride_m']} m, {r.evaluation['votes']} vote(s), label neighbours "
                     f"{r.evaluation['label_neighbours']}{', plane votes' if r.evaluation.get('plane_votes') else ''}. "
                     f"Confusion: `variants/{r.variant}/.../eval/confusion.png`.")
    scenes = sorted({s for r in results for s in r.scenes})
    lines += ["", "Per real scene (mIoU / κ, percent; - where a variant trained on it):", "",
              "| Scene | " + " | ".join(r.variant for r in results) + " |", "|---|" + "---:|" * len(results)]
    for scene in scenes:
        cells = []
        for r in results:
            row = r.scenes.get(scene)
            cells.append("-" if row is None else f"{_pct(row['miou'])} / {_pct(row['kappa'])}")
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def format_results_csv(results: Sequence[VariantResult]) -> str:
    """One row per variant and scope (pooled, scene mean, each scene, holdout): metrics and per-class IoU."""
    classes = results[0].class_names if results else ()
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["variant", "scope", *METRIC_NAMES, *(f"iou_{c}" for c in classes)])
    for r in results:
        rows: list[tuple[str, dict[str, Any]]] = [("all points", r.pooled), ("scene mean", r.scene_mean),
                                                  *r.scenes.items()]
        if r.holdout is not None:
            rows += [("holdout all points", r.holdout["pooled"]),
                     *((f"holdout {name}", row) for name, row in r.holdout["buildings"].items())]
        for scope, row in rows:
            ious = [row["iou"][c] for c in classes] if "iou" in row else [math.nan] * len(classes)
            writer.writerow([r.variant, scope, *(f"{row[m]:.6f}" for m in METRIC_NAMES),
                             *("" if math.isnan(x) else f"{x:.6f}" for x in ious)])
    return buffer.getvalue()


def write_report(experiment: Experiment, results: Sequence[VariantResult], out: Path) -> None:
    """Write report.md, results.csv, results.json, val_miou.png and label_efficiency.png."""
    from bimscan.learn.plots import plot_label_efficiency, plot_variant_curves

    write_atomic(out / "report.md", format_report(experiment, results).encode("utf-8"))
    write_atomic(out / "results.csv", format_results_csv(results).encode("utf-8"))
    document = {"experiment": experiment.name, "file": str(experiment.path), "real": list(experiment.real.scenes),
                "variants": [r.to_json() for r in results]}
    write_atomic(out / "results.json", (json.dumps(document, indent=2) + "\n").encode("utf-8"))
    curves = {f"{r.variant}" + (f" fold {k + 1}" if len(r.val_miou_per_epoch) > 1 else ""): values
              for r in results for k, values in enumerate(r.val_miou_per_epoch)}
    plot_variant_curves(curves, out / "val_miou.png", title=f"{experiment.name}: real-room mIoU per epoch")
    if any(r.train_rooms and any(r.train_rooms) for r in results):
        points = {"with synthetic pretraining": [], "real rooms only": []}
        for r in results:
            series = "real rooms only" if not r.synthetic and not r.init else "with synthetic pretraining"
            points[series].append((_rooms_trained(r), r.pooled["miou"], r.variant))
        plot_label_efficiency(points, out / "label_efficiency.png",
                              title=f"{experiment.name}: mIoU on real rooms not trained on")

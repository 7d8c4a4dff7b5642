"""Sim-to-real experiments: train on synthetic variants only, score every model on real scans.

One TOML file names the synthetic *variants* (each a dataset spec that is built, or existing
dataset folders / clouds), the training sections shared by all variants (``[blocks]``,
``[input]``, ``[augment]``, ``[model]``, ``[train]``, as in a training TOML, see
:mod:`bimscan.learn.train_config`), per-variant overrides of those sections, and the real
scenes (``[real]``); ``[experiment] base`` takes those sections from another experiment file
(see :func:`_with_base`). :func:`run_experiment` builds what is missing (the dataset builder,
resumable), trains one model per variant with the same seed and schedule (the real scenes are
the validation set, so ``curves.png`` shows synthetic train against real validation per epoch,
as the paper's Figs. 7-8), evaluates each last checkpoint on every real scene and writes one
comparison. Every step is kept on disk and skipped when found finished: a killed run continues.

Layout of ``OUT_DIR``::

    experiment.json              the resolved experiment (what was run)
    datasets/<spec name>/        datasets built from the variants' specs
    variants/<name>/train/       checkpoints, metrics.csv, curves.png
    variants/<name>/eval/        evaluation.md/.csv/.json, confusion.png/.csv
    variants/<name>/result.json  the variant's scores (the marker that it is finished)
    report.md, results.csv, results.json, val_miou.png
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.errors import ConfigError, InputFileError, LearnError
from bimscan.files import write_atomic
from bimscan.learn.metrics import METRIC_NAMES, compute_metrics
from bimscan.learn.train_config import TrainRunConfig
from bimscan.toml_files import base_file, build_dataclass, load_toml, resolve_path

TRAINING_SECTIONS = ("blocks", "input", "augment", "model", "train")
VARIANT_KEYS = {"name", "data", "description", *TRAINING_SECTIONS}
TOP_KEYS = {"experiment", "real", "variants", *TRAINING_SECTIONS}
DATA_RECORD = "synthetic_data.digest"  # in a variant's folder: the data its model was trained on
REAL_KEYS = {"scenes", "label_field", "mapping"}
EXPERIMENT_KEYS = {"name", "class_names", "workers", "base"}
NAME_PATTERN = re.compile(r"^[A-Za-z0-9+][A-Za-z0-9._+-]{0,63}$")
RESULT_VERSION = 1


@dataclass(frozen=True)
class Variant:
    """One synthetic training set and its training configuration.

    ``specs``: dataset spec files to build (absolute); ``folders``: existing dataset folders or
    clouds (absolute); ``config``: the whole training run (its ``data.train`` is filled in
    once the specs are built, see :func:`training_config`).
    """

    name: str
    description: str
    specs: tuple[Path, ...]
    folders: tuple[Path, ...]
    config: TrainRunConfig


@dataclass(frozen=True)
class Experiment:
    """A parsed and checked experiment file."""

    name: str
    path: Path
    real: tuple[Path, ...]
    real_label_field: str | None
    real_mapping: Path | None
    variants: tuple[Variant, ...]
    workers: int | None


def _check_keys(table: Any, allowed: set[str], *, where: str) -> dict[str, Any]:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table, got {type(table).__name__}")
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(allowed))}")
    return table


def _paths(value: Any, *, base: Path, where: str) -> tuple[Path, ...]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not items or not all(isinstance(v, str) and v for v in items):
        raise ConfigError(f"{where}: expected a path or a non-empty list of paths")
    return tuple(resolve_path(base, v).resolve() for v in items)


def load_experiment(
    path: str | Path, *, real: Sequence[str | Path] | None = None, device: str | None = None,
) -> Experiment:
    """Parse and check an experiment TOML before any work (one-line ConfigError/InputFileError).

    ``real`` replaces the ``[real] scenes`` of the file; ``device`` its ``[train] device``.
    """
    path = Path(path)
    own = _check_keys(load_toml(path), TOP_KEYS, where=str(path))
    data = _with_base(own, path)
    # the file to fix when the real scenes are missing: the base's when they come from there
    real_from = path if "scenes" in own.get("real", {}) or data is own else resolve_path(path.parent, own["experiment"]["base"]).resolve()
    base = path.resolve().parent
    head = _check_keys(data.get("experiment", {}), EXPERIMENT_KEYS, where=f"{path} [experiment]")
    name = head.get("name", path.stem)
    if not isinstance(name, str) or not NAME_PATTERN.match(name):
        raise ConfigError(f"{path} [experiment] name: {name!r} is not a usable name (letters, digits, . _ -)")
    workers = head.get("workers")
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 1):
        raise ConfigError(f"{path} [experiment] workers: expected a whole number >= 1, got {workers!r}")
    real_table = _check_keys(data.get("real", {}), REAL_KEYS, where=f"{path} [real]")
    if real:
        real_paths = tuple(Path(p).expanduser().resolve() for p in real)
    elif "scenes" in real_table:
        real_paths = _paths(real_table["scenes"], base=base, where=f"{path} [real] scenes")
    else:
        raise ConfigError(f"{path} [real] scenes: no real scenes named; add them or pass --real PATH")
    for scene in real_paths:
        if not scene.exists():
            raise InputFileError(f"{scene}: real scenes not found; fix [real] scenes in {real_from} or pass --real PATH")
    mapping = real_table.get("mapping")
    real_mapping = None if mapping is None else resolve_path(base, str(mapping)).resolve()
    if real_mapping is not None and not real_mapping.is_file():
        raise InputFileError(f"{real_mapping}: [real] mapping not found; fix the path in {path}")
    label_field = real_table.get("label_field")
    if label_field is not None and not isinstance(label_field, str):
        raise ConfigError(f"{path} [real] label_field: expected a field name")

    raw_variants = data.get("variants")
    if not isinstance(raw_variants, list) or not raw_variants:
        raise ConfigError(f"{path}: no [[variants]]; name at least one synthetic training set")
    shared = {section: data.get(section, {}) for section in TRAINING_SECTIONS}
    for section, table in shared.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{path} [{section}]: expected a table")
    class_names = head.get("class_names")
    variants: list[Variant] = []
    for i, raw in enumerate(raw_variants):
        where = f"{path} [[variants]] #{i + 1}"
        raw = _check_keys(raw, VARIANT_KEYS, where=where)
        vname = raw.get("name")
        if not isinstance(vname, str) or not NAME_PATTERN.match(vname):
            raise ConfigError(f"{where} name: {vname!r} is not a usable name (letters, digits, . _ -, at most 64)")
        if any(v.name == vname for v in variants):
            raise ConfigError(f"{where} name: {vname!r} is used twice; give every variant its own name")
        if "data" not in raw:
            raise ConfigError(f"{where}: no 'data'; name a dataset spec (.toml) or dataset folders")
        data_paths = _paths(raw["data"], base=base, where=f"{where} data")
        specs, folders = [], []
        for item in data_paths:
            if not item.exists():
                raise InputFileError(f"{item}: variant {vname!r} data not found; fix the path in {path}")
            (specs if item.is_file() and item.suffix.lower() == ".toml" else folders).append(item)
        for spec in specs:
            from bimscan.dataset.spec import load_spec

            load_spec(spec)  # every spec error before any work
        sections: dict[str, Any] = {}
        for section in TRAINING_SECTIONS:
            override = raw.get(section, {})
            if not isinstance(override, dict):
                raise ConfigError(f"{where} {section}: expected a table of overrides")
            sections[section] = {**shared[section], **override}
        train = dict(sections["train"])
        if device is not None:
            train["device"] = device
        run = {
            "data": {
                "train": ["<built by the experiment>"], "val": [str(p) for p in real_paths],
                "val_label_field": label_field, "val_mapping": None if real_mapping is None else str(real_mapping),
                **({"class_names": class_names} if class_names is not None else {}),
            },
            **{s: sections[s] for s in ("blocks", "input", "augment", "model")},
            "train": train,
        }
        config = build_dataclass(TrainRunConfig, run, where=where)
        description = raw.get("description", "")
        if not isinstance(description, str):
            raise ConfigError(f"{where} description: expected text")
        variants.append(Variant(vname, description, tuple(specs), tuple(folders), config))
    return Experiment(name, path.resolve(), real_paths, label_field, real_mapping, tuple(variants), workers)


def _with_base(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` on top of its ``[experiment] base`` file: the base's ``[real]`` and training
    sections are the defaults, this file's keys replace them key by key (its variants are not
    taken). Companion experiments so share one model and schedule instead of copying it."""
    head = data.get("experiment", {})
    if not isinstance(head, dict) or "base" not in head:
        return data
    base_path = base_file(head["base"], path, where="[experiment] base", kind="experiment file")
    base = _check_keys(load_toml(base_path), TOP_KEYS, where=str(base_path))
    if "base" in base.get("experiment", {}):
        raise ConfigError(f"{path} [experiment] base: {base_path.name} has a base of its own; name the file at the root")
    merged = dict(data)
    real = dict(_check_keys(base.get("real", {}), REAL_KEYS, where=f"{base_path} [real]"))

    def from_base(value: Any) -> Any:  # the base's relative paths are relative to the base file
        return str(resolve_path(base_path.parent, value).resolve()) if isinstance(value, str) else value

    for key in ("scenes", "mapping"):
        if key in real:
            real[key] = [from_base(v) for v in real[key]] if isinstance(real[key], list) else from_base(real[key])
    for section, defaults in (("real", real), *((s, base.get(s, {})) for s in TRAINING_SECTIONS)):
        own = data.get(section, {})
        if not isinstance(defaults, dict) or not isinstance(own, dict):
            raise ConfigError(f"{path} [{section}] (or its base's): expected a table")
        merged[section] = {**defaults, **own}
    return merged


def _dataset_dir(out: Path, spec: Path) -> Path:
    return out / "datasets" / spec.stem


def training_config(variant: Variant, out: Path) -> TrainRunConfig:
    """The variant's training run with its synthetic data filled in."""
    from dataclasses import replace

    train = [str(_dataset_dir(out, s)) for s in variant.specs] + [str(f) for f in variant.folders]
    return replace(variant.config, data=replace(variant.config.data, train=tuple(train)))


def _fingerprint(variant: Variant, out: Path) -> str:
    from bimscan.learn.train_config import dump_config

    config = dump_config(training_config(variant, out))
    config["train"] = {k: v for k, v in config["train"].items() if k not in ("device", "num_workers", "out_dir")}
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_experiment(
    experiment: Experiment, out_dir: str | Path, *, log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Build, train, evaluate every variant (skipping finished steps) and write the report.

    Returns the results as written to ``results.json``.
    """
    emit = log or (lambda text: print(text, file=sys.stderr, flush=True))
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    _check_same_experiment(experiment, out)
    _build_datasets(experiment, out, emit)
    _check_same_data(experiment, out)
    results = []
    for variant in experiment.variants:
        results.append(_run_variant(experiment, variant, out, emit))
    summary = _summarize(experiment, results)
    _write_report(experiment, summary, out)
    emit(f"report: {out / 'report.md'}")
    return summary


def _check_same_experiment(experiment: Experiment, out: Path) -> None:
    """A folder holds one experiment: variants of the same name must have the same recipe."""
    record = out / "experiment.json"
    current = {
        "format": "bimscan-sim2real", "version": RESULT_VERSION, "name": experiment.name,
        "file": str(experiment.path), "real": [str(p) for p in experiment.real],
        "variants": {v.name: _fingerprint(v, out) for v in experiment.variants},
    }
    if record.is_file():
        try:
            stored = json.loads(record.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LearnError(f"{record}: unreadable ({exc}); delete it or use another OUT_DIR") from exc
        for name, digest in current["variants"].items():
            old = stored.get("variants", {}).get(name)
            # a variant whose folder was deleted starts afresh (what the message below offers)
            if old is not None and old != digest and (out / "variants" / name).exists():
                raise LearnError(
                    f"{out}: variant {name!r} was run with another recipe; use another OUT_DIR or delete "
                    f"{out / 'variants' / name} to rerun it"
                )
        current["variants"] = {**stored.get("variants", {}), **current["variants"]}
    write_atomic(record, (json.dumps(current, indent=2) + "\n").encode("utf-8"))


def _data_digest(variant: Variant, out: Path) -> str:
    """What a variant trains on: every finished unit of its datasets with its fingerprint (the
    recipe, scene, scheme and software its bytes came from)."""
    from bimscan.dataset.layout import DatasetFolder

    digest = hashlib.sha256()
    for root in training_config(variant, out).data.train:
        folder = DatasetFolder(root)
        digest.update(f"{root}\n".encode())
        if folder.is_dataset():
            for unit in folder.read_manifest().done():
                digest.update(f"{unit.id}:{folder.read_unit(unit.id).fingerprint}\n".encode())
    return digest.hexdigest()[:16]


def _check_same_data(experiment: Experiment, out: Path) -> None:
    """A variant's model and scores stand for the data it was trained on: once its datasets change
    (another spec, scheme or software), its folder must go before it is run again."""
    for variant in experiment.variants:
        folder = out / "variants" / variant.name
        record = folder / DATA_RECORD
        digest = _data_digest(variant, out)
        if record.is_file():
            if record.read_text(encoding="utf-8").strip() != digest:
                raise LearnError(f"{folder}: variant {variant.name!r} was trained on other synthetic data (its dataset "
                                 f"changed since); delete {folder} to rerun it, or use another OUT_DIR")
        else:  # a new variant, or one run before this record existed
            folder.mkdir(parents=True, exist_ok=True)
            write_atomic(record, (digest + "\n").encode("utf-8"))


def _build_datasets(experiment: Experiment, out: Path, emit: Callable[[str], None]) -> None:
    specs = sorted({s for v in experiment.variants for s in v.specs})
    if not specs:  # dataset folders only: the IFC and scanning stack is not needed (nor imported)
        return
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import load_spec

    stems = [s.stem for s in specs]
    if len(set(stems)) != len(stems):
        raise ConfigError(f"{experiment.path}: two variant specs share a file name ({stems}); rename one")
    for spec_path in specs:
        target = _dataset_dir(out, spec_path)
        emit(f"dataset {spec_path.name} -> {target}")
        report = build_dataset(load_spec(spec_path), target, workers=experiment.workers)
        emit(report.summary())
        if not report.ok:
            raise LearnError(
                f"{target}: {report.failed} unit(s) failed to build (see manifest.json); fix them and run again"
            )


def _run_variant(experiment: Experiment, variant: Variant, out: Path, emit: Callable[[str], None]) -> dict[str, Any]:
    from bimscan.learn.checkpoint import read_checkpoint
    from bimscan.learn.evaluate import evaluate_checkpoint, pool_confusion, write_evaluation
    from bimscan.learn.mapping import load_label_mapping
    from bimscan.learn.train import train_model, use_cpu_threads

    folder = out / "variants" / variant.name
    result_path = folder / "result.json"
    if result_path.is_file():
        emit(f"variant {variant.name}: finished earlier, scores read from {result_path}")
        return json.loads(result_path.read_text(encoding="utf-8"))
    config = training_config(variant, out)
    train_dir = folder / "train"
    last = train_dir / "last.pt"
    epochs = config.train.epochs
    done = int(read_checkpoint(last)["epoch"]) if last.is_file() else 0
    if done < epochs:
        emit(f"variant {variant.name}: training{' (resuming after epoch ' + str(done) + ')' if done else ''}")
        train_model(config, base_dir=experiment.path.parent, out_dir=train_dir, resume=last.is_file(), log=emit)
    emit(f"variant {variant.name}: evaluating on {len(experiment.real)} real path(s)")
    use_cpu_threads(config.train.cpu_threads)  # the scores, too, are sums in thread order
    mapping = None if experiment.real_mapping is None else load_label_mapping(experiment.real_mapping)
    evaluations = evaluate_checkpoint(
        last, experiment.real, label_field=experiment.real_label_field, mapping=mapping,
        device=config.train.device, batch_size=config.train.eval_batch_size, seed=config.train.seed,
        work_dir=folder,
    )
    class_names = list(config.data.class_names)
    write_evaluation(evaluations, folder / "eval", class_names,
                     title=f"{variant.name}: confusion on {len(evaluations)} real scene(s), all points")
    confusion = pool_confusion(evaluations)
    pooled = compute_metrics(confusion)
    history = read_checkpoint(last)["history"]
    result = {
        "variant": variant.name, "description": variant.description, "class_names": class_names,
        "pooled": _metrics_json(pooled, class_names),
        "scene_mean": {m: float(np.nanmean([e.metrics.scalars()[m] for e in evaluations])) for m in METRIC_NAMES},
        "scenes": {e.scene: _metrics_json(e.metrics, class_names) for e in evaluations},
        "confusion": confusion.tolist(),
        "val_miou_per_epoch": [float(row.get("val_miou", math.nan)) for row in history],
        "train_miou_per_epoch": [float(row.get("train_miou", math.nan)) for row in history],
        "train_seconds": float(sum(row.get("seconds", 0.0) for row in history)),
        "synthetic": [str(p) for p in config.data.train],
    }
    write_atomic(result_path, (json.dumps(result, indent=2, allow_nan=True) + "\n").encode("utf-8"))
    p = result["pooled"]
    emit(f"variant {variant.name}: mIoU {p['miou']:.3f} kappa {p['kappa']:.3f} OA {p['oa']:.3f} (all real points)")
    return result


def _metrics_json(metrics: Any, class_names: Sequence[str]) -> dict[str, Any]:
    row: dict[str, Any] = metrics.scalars()
    row["iou"] = {c: float(v) for c, v in zip(class_names, metrics.iou.tolist(), strict=True)}
    row["points"] = int(metrics.total)
    return row


def _summarize(experiment: Experiment, results: list[dict[str, Any]]) -> dict[str, Any]:
    return {"experiment": experiment.name, "file": str(experiment.path), "real": [str(p) for p in experiment.real],
            "variants": results}


def _pct(value: float) -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{100.0 * value:.1f}"


def format_report(summary: dict[str, Any]) -> str:
    """The comparison as Markdown: one row per variant (all real points pooled), per-class IoU,
    the mean over scenes, and per real scene mIoU / kappa."""
    variants = summary["variants"]
    if not variants:
        return "# sim2real\n\nNo variant.\n"
    classes = variants[0]["class_names"]
    lines = [f"# sim2real: {summary['experiment']}", "",
             f"Trained on synthetic data only; scored on {len(variants[0]['scenes'])} real scene(s) "
             f"({', '.join(summary['real'])}). Metrics in percent over all real points pooled; "
             "'scene mean' averages the per-scene values (the paper's Table 3 mean).", "",
             "| Variant | OA | mIoU | mAcc | FWIoU | κ | " + " | ".join(f"IoU {c}" for c in classes)
             + " | scene mean mIoU | scene mean κ |",
             "|---|" + "---:|" * (5 + len(classes) + 2)]
    for v in variants:
        p = v["pooled"]
        lines.append(
            f"| {v['variant']} | " + " | ".join(_pct(p[m]) for m in METRIC_NAMES) + " | "
            + " | ".join(_pct(p["iou"][c]) for c in classes)
            + f" | {_pct(v['scene_mean']['miou'])} | {_pct(v['scene_mean']['kappa'])} |"
        )
    lines += ["", "Variants:", ""]
    for v in variants:
        text = f" {v['description']}" if v["description"] else ""
        lines.append(f"- **{v['variant']}**:{text} Confusion: `variants/{v['variant']}/eval/confusion.png`; "
                     f"curves: `variants/{v['variant']}/train/curves.png`; training {v['train_seconds'] / 60:.1f} min.")
    scenes = list(variants[0]["scenes"])
    lines += ["", "Per real scene (mIoU / κ, percent):", "",
              "| Scene | " + " | ".join(v["variant"] for v in variants) + " |", "|---|" + "---:|" * len(variants)]
    for scene in scenes:
        cells = []
        for v in variants:
            row = v["scenes"].get(scene)
            cells.append("-" if row is None else f"{_pct(row['miou'])} / {_pct(row['kappa'])}")
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def format_results_csv(summary: dict[str, Any]) -> str:
    """One row per variant and scope (pooled, scene mean, each scene): metrics and per-class IoU."""
    variants = summary["variants"]
    classes = variants[0]["class_names"] if variants else []
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["variant", "scope", *METRIC_NAMES, *(f"iou_{c}" for c in classes)])
    for v in variants:
        rows = [("all points", v["pooled"]), ("scene mean", v["scene_mean"]), *v["scenes"].items()]
        for scope, row in rows:
            ious = [row["iou"][c] for c in classes] if "iou" in row else [math.nan] * len(classes)
            writer.writerow([v["variant"], scope, *(f"{row[m]:.6f}" for m in METRIC_NAMES),
                             *("" if math.isnan(x) else f"{x:.6f}" for x in ious)])
    return buffer.getvalue()


def _write_report(experiment: Experiment, summary: dict[str, Any], out: Path) -> None:
    write_atomic(out / "report.md", format_report(summary).encode("utf-8"))
    write_atomic(out / "results.csv", format_results_csv(summary).encode("utf-8"))
    write_atomic(out / "results.json", (json.dumps(summary, indent=2) + "\n").encode("utf-8"))
    _plot_val_curves(summary, out / "val_miou.png")


def _plot_val_curves(summary: dict[str, Any], path: Path) -> None:
    """Real-validation mIoU per epoch of every variant in one figure."""
    from bimscan.learn.plots import plot_variant_curves

    plot_variant_curves({v["variant"]: v["val_miou_per_epoch"] for v in summary["variants"]}, path,
                        title=f"sim2real {summary['experiment']}: trained on synthetic only")

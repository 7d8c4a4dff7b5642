"""Experiments run: the synthetic datasets built, the holdout models scanned, every variant's
models trained (in folds where they train on, or adapt to, the scored rooms), scored on the real
scenes they never trained on and on the holdout buildings, and the report written
(``bimscan sim2real``).

The file format and its parse are :mod:`bimscan.learn.experiment`'s; this composes the stages
(``bimscan.dataset`` builds, ``bimscan.learn`` trains and scores), as :mod:`bimscan.pipeline`
composes a scan. Every step is kept on disk and skipped when found finished: a killed run continues.
OUT_DIR is an output folder (``bimscan.files.prepare_output_folder``): a new or empty one, or one
bimscan made; a user's file at a name the experiment writes there is refused before any work.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bimscan.errors import ConfigError, LearnError
from bimscan.files import claim_output, json_marker, prepare_output_folder, read_marker, write_atomic
from bimscan.learn.data import SceneSource
from bimscan.learn.experiment import (
    DATA_RECORD, Experiment, ExperimentRecord, Variant, VariantResult, parse_experiment, room_sources,
    training_sections,
)
from bimscan.learn.metrics import METRIC_NAMES, compute_metrics
from bimscan.learn.train_config import DataConfig, SceneSet, TrainRunConfig, setting_effect
from bimscan.toml_files import resolve_path

if TYPE_CHECKING:
    from bimscan.dataset.spec import DatasetSpec


def load_experiment(path: str | Path, *, real: Sequence[str | Path] | None = None,
                    device: str | None = None, seed: int | None = None) -> Experiment:
    """Parse and check an experiment TOML before any work (one-line ConfigError/InputFileError):
    the file (:func:`bimscan.learn.experiment.parse_experiment`), its variants' dataset specs and
    its holdout models and their scan settings. ``real`` replaces the ``[real] scenes`` of the
    file; ``device`` and ``seed`` the ``[train] device`` and ``[train] seed`` of every variant."""
    from bimscan.dataset.spec import load_spec

    experiment = parse_experiment(path, real=real, device=device, seed=seed)
    for spec in sorted({s for v in experiment.variants for s in v.specs}):
        load_spec(spec)
    _holdout_spec(experiment)
    return experiment


@dataclass(frozen=True)
class Run:
    """One model of a variant: the rooms it trains on and the real scenes it is scored on."""

    variant: Variant
    fold: int | None
    train_rooms: tuple[SceneSource, ...]
    scored: tuple[SceneSource, ...]
    adapt: tuple[SceneSource, ...] = ()  # unlabelled scans it adapts to (labels never read)

    def folder(self, out: Path) -> Path:
        base = out / "variants" / self.variant.name
        return base if self.fold is None else base / f"fold-{self.fold + 1}"


def run_experiment(experiment: Experiment, out_dir: str | Path, *,
                   log: Callable[[str], None] | None = None) -> list[VariantResult]:
    """Build, train, evaluate every variant (skipping finished steps) and write the report."""
    from bimscan.learn.report import write_report

    emit = log or (lambda text: print(text, file=sys.stderr, flush=True))
    out = Path(out_dir).resolve()
    scored = _scored_scenes(experiment)
    # every variant's models planned before any work: one that cannot run (too few scored rooms
    # for its folds) stops the experiment now, not after the variants before it have trained
    runs_of: dict[str, list[Run]] = {}
    for variant in experiment.variants:
        runs_of[variant.name] = _runs(experiment, variant, scored, runs_of)
    _check_holdout_unseen(experiment, out)
    _check_real_labelled(experiment)
    prepare_output_folder(out, names=EXPERIMENT_OUTPUTS, made_by=is_earlier_experiment)  # a user's folder: refused
    claim_output(out, "variants/")
    _check_same_experiment(experiment, out)
    _build_datasets(experiment, out, emit)
    holdout = _build_holdout(experiment, out, emit)
    _check_same_data(experiment, out)
    results = [_run_variant(experiment, variant, runs_of, out, holdout, emit) for variant in experiment.variants]
    write_report(experiment, results, out)
    emit(f"report: {out / 'report.md'}")
    return results


# What an experiment writes into OUT_DIR (``bimscan.files`` output folder names).
EXPERIMENT_OUTPUTS = ("experiment.json", "datasets/", "holdout/", "variants/", "report.md", "results.csv",
                      "results.json", "val_miou.png", "label_efficiency.png")


def is_earlier_experiment(folder: Path) -> bool:
    """Whether ``folder`` holds an experiment run before output folders had records (its experiment.json)."""
    return json_marker(read_marker(folder / "experiment.json"), "variants")


def _check_real_labelled(experiment: Experiment) -> None:
    """Every scored scene carries labels of the experiment's classes and is in metres (for every
    variant's blocks): a cloud without them, or one in millimetres, is refused in seconds, naming
    where it came from, before the datasets are built."""
    from bimscan.learn.data import check_scene_unit, require_labels
    from bimscan.learn.train_config import DEFAULT_CLASS_NAMES

    scored = _scored_scenes(experiment)
    require_labels(scored, class_names=experiment.class_names or DEFAULT_CLASS_NAMES, where="[real] scenes or --real")
    for blocks in {training_sections(variant)["blocks"] for variant in experiment.variants}:
        for source in scored:
            check_scene_unit(source, blocks=blocks)


def _scored_scenes(experiment: Experiment) -> list[SceneSource]:
    from bimscan.learn.train import resolve_scene_set

    return resolve_scene_set(experiment.real, base=Path("/"))


def _runs(experiment: Experiment, variant: Variant, scored: list[SceneSource],
          earlier: dict[str, list[Run]] | None = None) -> list[Run]:
    """The models of a variant (see the module docs: never scored on a room it trained on); an
    ensemble's are its members' runs, which must be alike (the same folds and scored scenes)."""
    if variant.ensemble:
        members = [(earlier or {})[name] for name in variant.ensemble]
        plan = [[(r.fold, r.scored) for r in runs] for runs in members]
        if any(other != plan[0] for other in plan[1:]):
            raise ConfigError(f"variant {variant.name!r} ensemble: its members are scored on other scenes or folds; "
                              "average variants trained on the same rooms")
        return [Run(variant, r.fold, r.train_rooms, r.scored, adapt=r.adapt) for r in members[0]]
    if variant.adapt_to == "scored":  # transductive: adapted to the very scenes it is scored on, unlabelled
        return [Run(variant, None, (), tuple(scored), adapt=tuple(scored))]
    if variant.adapt_to == "others":  # inductive: each fold adapted to the scored scenes outside it
        folds = min(experiment.folds, len(scored))
        if folds < 2:
            raise ConfigError(f"variant {variant.name!r} adapt_to = \"others\" needs two scored scenes or more; "
                              "score it on more (--real) or adapt_to = \"scored\"")
        runs = []
        for k in range(folds):
            held = tuple(s for i, s in enumerate(scored) if i % folds == k)
            runs.append(Run(variant, k, (), held, adapt=tuple(s for s in scored if s not in held)))
        return runs
    if variant.adapt_to:
        return [Run(variant, None, (), tuple(scored), adapt=tuple(variant.adapt_to))]
    all_rooms = () if experiment.rooms is None else tuple(room_sources(experiment.rooms, where="[rooms]"))
    rooms = all_rooms if variant.rooms == "all" else variant.rooms
    trained = {s.path.resolve() for s in rooms}
    others = tuple(s for s in scored if s.path.resolve() not in trained)
    if len(others) == len(scored) or (others and variant.rooms != "all"):
        return [Run(variant, None, tuple(rooms), others)]
    if variant.rooms != "all":
        raise ConfigError(f"variant {variant.name!r} trains on every scored scene; score it on others (--real) or "
                          "train on rooms = \"all\" (then in folds)")
    if others:
        return [Run(variant, None, tuple(rooms), others)]
    folds = min(experiment.folds, len(scored))
    runs = []
    for k in range(folds):
        held = tuple(s for i, s in enumerate(scored) if i % folds == k)
        out_of_fold = {s.path.resolve() for s in held}
        runs.append(Run(variant, k, tuple(s for s in rooms if s.path.resolve() not in out_of_fold), held))
    return runs


def _dataset_dir(out: Path, spec: Path) -> Path:
    return out / "datasets" / spec.stem


def _synthetic(variant: Variant, out: Path) -> tuple[str, ...]:
    return tuple(str(_dataset_dir(out, s)) for s in variant.specs) + tuple(str(f) for f in variant.folders)


def training_config(experiment: Experiment, run: Run, out: Path, runs_of: dict[str, list[Run]] | None = None,
                    number: int = 0) -> TrainRunConfig:
    """A run's whole training configuration: its synthetic data and rooms, its scored scenes as
    validation, the variant's sections; an ensemble's (run ``number`` of ``runs_of``): its first
    member's run's, with the ensemble's ``[eval]``."""
    if run.variant.ensemble:
        first = (runs_of or {})[run.variant.ensemble[0]][number]
        return dataclasses.replace(training_config(experiment, first, out),
                                   eval=training_sections(run.variant)["eval"])
    train: list[SceneSet] = []
    synthetic = _synthetic(run.variant, out)
    if synthetic:
        train.append(SceneSet(scenes=synthetic))
    if run.train_rooms:
        rooms = experiment.rooms
        if rooms is None:
            raise LearnError(f"variant {run.variant.name!r} names rooms but the experiment has no [rooms]")
        train.append(SceneSet(scenes=tuple(str(s.path) for s in run.train_rooms), label_field=rooms.label_field,
                              mapping=rooms.mapping, weight=run.variant.room_weight))
    val = SceneSet(scenes=tuple(str(s.path) for s in run.scored), label_field=experiment.real.label_field,
                   mapping=experiment.real.mapping) if run.scored else None
    adapt = (SceneSet(scenes=tuple(str(s.path) for s in run.adapt)),) if run.adapt else ()
    data = DataConfig(train=tuple(train), val=val, adapt=adapt, **({"class_names": experiment.class_names}
                                                                  if experiment.class_names else {}))
    return TrainRunConfig(data=data, **training_sections(run.variant))


def _fingerprint(experiment: Experiment, variant: Variant, out: Path) -> str:
    """What decides a variant's models: its sections, data, rooms and parent."""
    document = {"sections": variant.sections, "synthetic": _synthetic(variant, out), "init": variant.init,
                "rooms": "all" if variant.rooms == "all" else [str(s.path) for s in variant.rooms],
                "room_weight": variant.room_weight, "folds": experiment.folds, "class_names": experiment.class_names}
    if variant.ensemble:  # (absent otherwise, as adapt_to)
        document["ensemble"] = list(variant.ensemble)
    if variant.adapt_to:  # (absent otherwise: the fingerprints of variants without it stay what they were)
        # "scored" and "others" adapt to the scored scenes: other real scenes (--real), another model
        document["adapt_to"] = [variant.adapt_to, *experiment.real.scenes] if isinstance(variant.adapt_to, str) \
            else [str(s.path) for s in variant.adapt_to]
    document["sections"] = {k: {kk: vv for kk, vv in v.items() if setting_effect(k, kk) != "runtime"}
                            for k, v in variant.sections.items()}
    return hashlib.sha256(json.dumps(document, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _check_same_experiment(experiment: Experiment, out: Path) -> None:
    """A folder holds one experiment: variants of the same name must have the same recipe."""
    path = out / "experiment.json"
    current = {v.name: _fingerprint(experiment, v, out) for v in experiment.variants}
    stored = ExperimentRecord.read(path) if path.is_file() else None
    if stored is not None:
        for name, digest in current.items():
            old = stored.variants.get(name)
            # a variant whose folder was deleted starts afresh (what the message below offers)
            if old is not None and old != digest and (out / "variants" / name).exists():
                raise LearnError(f"{out}: variant {name!r} was run with another recipe; use another OUT_DIR or delete "
                                 f"{out / 'variants' / name} to rerun it")
        current = {**stored.variants, **current}
    record = ExperimentRecord(name=experiment.name, file=str(experiment.path), real=list(experiment.real.scenes),
                              variants=current)
    write_atomic(path, (json.dumps(dataclasses.asdict(record), indent=2) + "\n").encode("utf-8"))


def _data_digest(variant: Variant, out: Path) -> str:
    """What a variant trains on: every finished unit of its datasets with its fingerprint."""
    from bimscan.dataset.layout import DatasetFolder

    digest = hashlib.sha256()
    for root in _synthetic(variant, out):
        folder = DatasetFolder(root)
        digest.update(f"{root}\n".encode())
        if folder.is_dataset():
            for unit in folder.read_manifest().done():
                digest.update(f"{unit.id}:{folder.read_unit(unit.id).fingerprint}\n".encode())
    return digest.hexdigest()[:16]


def _check_same_data(experiment: Experiment, out: Path) -> None:
    """A variant's models and scores stand for the data they were trained on: once its datasets
    change (another spec, scheme or software), its folder must go before it is run again."""
    for variant in experiment.variants:
        folder = out / "variants" / variant.name
        record = folder / DATA_RECORD
        digest = _data_digest(variant, out)
        if record.is_file():
            if record.read_text(encoding="utf-8").strip() != digest:
                raise LearnError(f"{folder}: variant {variant.name!r} was trained on other synthetic data (its dataset "
                                 f"changed since); delete {folder} to rerun it, or use another OUT_DIR")
        else:
            folder.mkdir(parents=True, exist_ok=True)
            write_atomic(record, (digest + "\n").encode("utf-8"))


def _check_holdout_unseen(experiment: Experiment, out: Path) -> None:
    """Refuse a variant that trains on a holdout model: OUT/holdout's scans, or the same IFC file
    in one of its dataset specs or built dataset folders (another scan of the same building)."""
    if not experiment.holdout.ifc:
        return
    holdout_models = {(experiment.path.parent / p).resolve() for p in experiment.holdout.ifc}  # as _holdout_spec
    holdout_scans = (out / "holdout").resolve()
    for variant in experiment.variants:
        for folder in variant.folders:
            resolved = Path(folder).resolve()
            if resolved == holdout_scans or holdout_scans in resolved.parents:
                raise ConfigError(f"variant {variant.name!r} trains on the holdout scans ({folder}); the holdout is "
                                  "never trained on: take them out of its data, or drop [holdout]")
        for source, scene, ifc in _trained_models(variant):
            if Path(ifc).resolve() in holdout_models:
                raise ConfigError(f"variant {variant.name!r} trains on holdout model {ifc} (scene {scene!r} of "
                                  f"{source}); the holdout is never trained on: take it out of the data or of "
                                  "[holdout] ifc")


def _trained_models(variant: Variant) -> Iterator[tuple[str, str, str]]:
    """(where, scene name, IFC path) of every IFC scene in a variant's dataset specs and built
    dataset folders (their dataset.json); generated buildings and clouds name no IFC file."""
    from bimscan.dataset.layout import DatasetFolder, read_json
    from bimscan.dataset.spec import load_spec

    for spec_path in variant.specs:
        for scene in load_spec(spec_path).scenes:
            if scene.ifc is not None:
                yield spec_path.name, scene.name, scene.ifc
    for folder in variant.folders:
        info = DatasetFolder(folder).info_path
        if info.is_file():
            spec = read_json(info).get("spec")
            scenes = spec.get("scenes") if isinstance(spec, dict) else None
            for scene in scenes if isinstance(scenes, list) else []:
                if isinstance(scene, dict) and isinstance(scene.get("ifc"), str):
                    yield str(folder), str(scene.get("name")), scene["ifc"]


def _build_datasets(experiment: Experiment, out: Path, emit: Callable[[str], None]) -> None:
    specs = sorted({s for v in experiment.variants for s in v.specs})
    if not specs:  # dataset folders only: the IFC and scanning stack is not needed (nor imported)
        return
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import load_spec

    stems = [s.stem for s in specs]
    if len(set(stems)) != len(stems):
        raise ConfigError(f"{experiment.path}: two variant specs share a file name ({stems}); rename one")
    claim_output(out, "datasets/")
    for spec_path in specs:
        target = _dataset_dir(out, spec_path)
        emit(f"dataset {spec_path.name} -> {target}")
        report = build_dataset(load_spec(spec_path), target, workers=experiment.workers)
        emit(report.summary())
        if not report.ok:
            raise LearnError(f"{target}: {report.failed} unit(s) failed to build (see manifest.json); fix them and run again")


def _holdout_spec(experiment: Experiment) -> DatasetSpec | None:
    """The holdout models as a dataset spec of one configuration (None without holdout models)."""
    holdout = experiment.holdout
    if not holdout.ifc:
        return None
    from bimscan.dataset.spec import parse_spec

    folder = experiment.path.parent
    names = [Path(p).stem for p in holdout.ifc]
    config = holdout.scan_config()
    return parse_spec({"name": f"{experiment.name}-holdout", "seed": holdout.seed, "formats": ["npy"],
                       "scenes": [{"name": n, "ifc": str(resolve_path(folder, p).resolve())}
                                  for n, p in zip(names, holdout.ifc, strict=True)],
                       "configs": [config]}, base=folder, where=f"{experiment.path} [holdout]")


def _build_holdout(experiment: Experiment, out: Path, emit: Callable[[str], None]) -> Path | None:
    """Scan the holdout models once (a dataset of one configuration) into OUT/holdout."""
    spec = _holdout_spec(experiment)
    if spec is None:
        return None
    from bimscan.dataset.build import build_dataset

    target = out / "holdout"
    emit(f"holdout: {len(spec.scenes)} model(s) -> {target}")
    report = build_dataset(spec, target, workers=experiment.workers)
    emit(report.summary())
    if not report.ok:
        raise LearnError(f"{target}: {report.failed} holdout unit(s) failed to build (see manifest.json)")
    return target


def _run_variant(experiment: Experiment, variant: Variant, runs_of: dict[str, list[Run]], out: Path,
                 holdout: Path | None, emit: Callable[[str], None]) -> VariantResult:
    from bimscan.learn.checkpoint import read_checkpoint
    from bimscan.learn.evaluate import evaluate_checkpoint, pool_confusion, write_evaluation
    from bimscan.learn.mapping import load_label_mapping
    from bimscan.learn.train import train_model, use_cpu_threads

    folder = out / "variants" / variant.name
    result_path = folder / "result.json"
    if result_path.is_file():
        emit(f"variant {variant.name}: finished earlier, scores read from {result_path}")
        return VariantResult.from_json(json.loads(result_path.read_text(encoding="utf-8")))
    runs = runs_of[variant.name]
    evaluations, holdouts, histories, seconds = [], [], [], 0.0
    config = training_config(experiment, runs[0], out, runs_of)
    class_names = tuple(config.data.class_names)
    for number, run in enumerate(runs):
        config = training_config(experiment, run, out, runs_of, number)
        where = run.folder(out)
        last = where / "train" / "last.pt"
        members: list[Path] = []
        if variant.ensemble:  # its members' models of this run, trained by their own variants above
            members = [runs_of[name][number].folder(out) / "train" / "last.pt" for name in variant.ensemble]
            last = members[0]
            for path in members:
                if not path.is_file():
                    raise LearnError(f"{path}: a member of ensemble {variant.name!r} has no model; run the experiment "
                                     "from its start")
        init = None if variant.init is None else _parent_checkpoint(runs_of[variant.init], run, out)
        done = int(read_checkpoint(last)["epoch"]) if last.is_file() else 0
        label = variant.name + ("" if run.fold is None else f" fold {run.fold + 1}/{len(runs)}")
        if done < config.train.epochs and not members:
            emit(f"variant {label}: training{' (resuming after epoch ' + str(done) + ')' if done else ''} on "
                 f"{len(run.train_rooms)} real room(s){' and synthetic data' if variant.specs or variant.folders else ''}"
                 + (f", adapting to {len(run.adapt)} unlabelled scene(s)" if run.adapt else "")
                 + (f", from {variant.init}" if init else ""))
            train_model(config, base_dir=experiment.path.parent, out_dir=where / "train", resume=last.is_file(),
                        init=init, log=emit)
        use_cpu_threads(config.train.cpu_threads)  # the scores, too, are sums in thread order
        history = [] if members else read_checkpoint(last)["history"]  # an ensemble has no epochs of its own
        histories.append(history)
        for path in members or [last]:  # an ensemble cost its members' training
            seconds += float(sum(row.get("seconds", 0.0) for row in read_checkpoint(path)["history"]))
        if run.scored:
            emit(f"variant {label}: evaluating on {len(run.scored)} real scene(s)")
            mapping = None if experiment.real.mapping is None else load_label_mapping(experiment.real.mapping)
            found = evaluate_checkpoint(last, [s.path for s in run.scored], label_field=experiment.real.label_field,
                                        mapping=mapping, device=config.train.device, evaluation=config.eval,
                                        work_dir=where, ensemble=members[1:])
            write_evaluation(found, where / "eval", class_names,
                             title=f"{label}: confusion on {len(found)} real scene(s), all points")
            evaluations += found
        if holdout is not None:
            found = evaluate_checkpoint(last, [holdout], device=config.train.device, evaluation=config.eval,
                                        work_dir=where, ensemble=members[1:])
            write_evaluation(found, where / "holdout", class_names,
                             title=f"{label}: confusion on {len(found)} holdout building(s), all points")
            holdouts.append(found)
    if not evaluations:
        raise LearnError(f"variant {variant.name!r}: no real scene left to score it on")
    confusion = pool_confusion(evaluations)
    result = VariantResult(
        variant=variant.name, description=variant.description, class_names=class_names,
        pooled=_metrics_json(compute_metrics(confusion), class_names),
        scene_mean={m: float(np.nanmean([e.metrics.scalars()[m] for e in evaluations])) for m in METRIC_NAMES},
        scenes={e.scene: _metrics_json(e.metrics, class_names) for e in evaluations},
        confusion=confusion.tolist(), holdout=_holdout_json(holdouts, class_names),
        val_miou_per_epoch=[[float(r.get("val_miou", math.nan)) for r in h] for h in histories],
        train_miou_per_epoch=[[float(r.get("train_miou", math.nan)) for r in h] for h in histories],
        train_seconds=seconds, synthetic=list(_synthetic(variant, out)),
        train_rooms=[[s.name for s in run.train_rooms] for run in runs],
        adapted=[[s.name for s in run.adapt] for run in runs],
        excluded=sorted({s.name for run in runs for s in run.train_rooms} & {s.name for s in _scored_scenes(experiment)}),
        folds=len(runs) if runs[0].fold is not None else 0, evaluation=dataclasses.asdict(config.eval),
        init=variant.init, ensemble=list(variant.ensemble))
    write_atomic(result_path, (json.dumps(result.to_json(), indent=2, allow_nan=True) + "\n").encode("utf-8"))
    p = result.pooled
    emit(f"variant {variant.name}: mIoU {p['miou']:.3f} kappa {p['kappa']:.3f} OA {p['oa']:.3f} (real points it never "
         "trained on)")
    return result


def _parent_checkpoint(parent_runs: list[Run], run: Run, out: Path) -> Path:
    """The checkpoint a fine-tuned run starts from: its parent's run of the same fold, else the
    parent's only run."""
    same = [r for r in parent_runs if r.fold == run.fold] or parent_runs[:1]
    path = same[0].folder(out) / "train" / "last.pt"
    if not path.is_file():
        raise LearnError(f"{path}: the parent variant's model is missing; run the experiment from its start")
    return path


def _holdout_json(found: list[list[Any]], class_names: Sequence[str]) -> dict[str, Any] | None:
    """The holdout buildings' scores of a variant's runs: per building and pooled, each the sum of
    its runs' confusion matrices (folds of one variant all score every building)."""
    if not found:
        return None
    per_building: dict[str, np.ndarray] = {}
    for run in found:
        for e in run:
            per_building[e.scene] = per_building.get(e.scene, 0) + e.labels.confusion
    pooled = np.sum(list(per_building.values()), axis=0)
    return {"pooled": _metrics_json(compute_metrics(pooled), class_names),
            "buildings": {name: _metrics_json(compute_metrics(c), class_names) for name, c in per_building.items()}}


def _metrics_json(metrics: Any, class_names: Sequence[str]) -> dict[str, Any]:
    row: dict[str, Any] = metrics.scalars()
    row["iou"] = {c: float(v) for c, v in zip(class_names, metrics.iou.tolist(), strict=True)}
    row["points"] = int(metrics.total)
    return row


def format_report(results: Sequence[VariantResult], experiment: Experiment) -> str:
    """The report as Markdown (see :mod:`bimscan.learn.report`)."""
    from bimscan.learn.report import format_report as markdown

    return markdown(experiment, results)



__all__ = ["Run", "format_report", "load_experiment", "run_experiment", "training_config"]

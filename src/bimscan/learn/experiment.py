"""Experiments: train variants on synthetic scans (and real rooms), score every model on real scans
it never saw and on whole synthetic buildings, in one report.

One TOML file (loaded like every config, :func:`bimscan.toml_files.build_dataclass`) holds:

- ``[experiment]``: ``name``, ``class_names``, ``workers`` (dataset builds), ``folds`` (see
  below), ``base`` (another experiment file whose ``[real]``, ``[rooms]``, ``[holdout]`` and
  training sections are this file's defaults, key by key; its variants are not taken);
- ``[real]``: the real scenes every variant is scored on (a scene set: ``scenes``,
  ``label_field``, ``mapping``; ``--real`` replaces its scenes);
- ``[rooms]``: real labelled scenes variants may train on (a scene set; the variants name them);
- ``[holdout]``: IFC models scanned once with the given settings (``ifc``, ``preset``,
  ``head_deg_per_s``, ``clutter``, ``stage``, ``seed``, ``realism``, ``sensor``: a dataset
  configuration's), never trained on (a variant whose data holds one is refused): every
  variant is also scored on them, whole buildings beside the real rooms;
- the training sections shared by all variants (``[blocks]``, ``[input]``, ``[augment]``,
  ``[model]``, ``[train]``, ``[eval]``, as in a training TOML, :mod:`bimscan.learn.train_config`);
- ``[[variants]]``: ``name``, ``description``, ``data`` (synthetic: dataset specs to build, or
  dataset folders and clouds), ``rooms`` (names of ``[rooms]`` scenes to train on, or ``"all"``),
  ``room_weight`` (how often each block of those rooms is drawn per epoch), ``init`` (an earlier
  variant whose trained weights this one starts from: fine-tuning), ``adapt_to`` (unlabelled
  scans to adapt to, their labels never read, :mod:`bimscan.learn.adapt`: ``"scored"``, the
  scored real scenes themselves, the transductive protocol of unsupervised domain adaptation;
  ``"others"``, in folds, each fold's model adapted to the scored scenes outside its fold and
  scored on its own, the inductive one; or a list of scans) and overrides of the training
  sections (``[adapt]`` among them).

Scoring never counts a room a model trained on. A variant whose rooms are not among the scored
scenes is trained once and scored on all of them; one whose rooms are, on the others; one
training on ``"all"`` rooms when every scored scene is among them is run in ``folds`` folds
(the scored rooms, in their order, dealt into ``folds`` groups): each fold's model trains on the
other rooms and is scored on its own, and the variant's score pools the folds (so is one adapted
to ``"others"``). A fine-tuned or adapted variant starts each run from its parent's run of the
same fold (or its parent's only run).

Every run's real scored scenes are its validation set (``curves.png`` per epoch, as the paper's
Figs. 7-8). Every step is kept on disk and skipped when found finished: a killed run continues.

Layout of ``OUT_DIR``::

    experiment.json                      what was run (``ExperimentRecord``)
    datasets/<spec name>/                datasets built from the variants' specs
    holdout/                             the holdout models' scans (a dataset)
    variants/<name>/[fold-<k>/]train/    checkpoints, metrics.csv, curves.png
    variants/<name>/[fold-<k>/]eval/     evaluation.md/.csv/.json, confusion.png/.csv (real scenes)
    variants/<name>/[fold-<k>/]holdout/  the same on the holdout buildings
    variants/<name>/result.json          the variant's scores (``VariantResult``; the marker that it is finished)
    report.md, results.csv, results.json, val_miou.png, label_efficiency.png
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError, InputFileError, LearnError
from bimscan.files import write_atomic
from bimscan.learn.data import SceneSource
from bimscan.learn.metrics import METRIC_NAMES, compute_metrics
from bimscan.learn.train_config import (
    TRAINING_SECTIONS, DataConfig, SceneSet, TrainRunConfig, check_moved_keys, scene_sets, setting_effect,
)
from bimscan.toml_files import base_file, build_dataclass, load_toml, resolve_path

if TYPE_CHECKING:
    from bimscan.dataset.spec import DatasetSpec

DATA_RECORD = "synthetic_data.digest"  # in a variant's folder: the data its models were trained on
NAME_PATTERN = re.compile(r"^[A-Za-z0-9+][A-Za-z0-9._+-]{0,63}$")
RECORD_FORMAT = "bimscan-experiment"
RECORD_VERSION = 2


@dataclass(frozen=True)
class ExperimentTable(Checked):
    """``[experiment]``: the experiment's name (default: the file's stem), its classes, the dataset
    builds' worker processes, the folds of variants training on every scored room, a base file."""

    name: str | None = None
    class_names: tuple[str, ...] | None = None
    workers: int | None = setting(None, within=Range(1, 1024), effect="runtime")
    folds: int = setting(3, within=Range(2, 64))
    base: str | None = None

    def check(self) -> None:
        if self.name is not None and not NAME_PATTERN.match(self.name):
            raise ConfigError(f"name {self.name!r} is not a usable name (letters, digits, . _ -)")


@dataclass(frozen=True)
class HoldoutTable:
    """``[holdout]``: IFC models scanned once (auto stations) and scored, never trained on."""

    ifc: tuple[str, ...] = ()
    preset: str = "exp3"
    head_deg_per_s: float | None = None
    clutter: float = 0.0
    stage: str = "finished"
    seed: int = 0
    realism: str | None = None  # the scans' sensor realism and settings, as a dataset configuration's
    sensor: dict[str, Any] | None = None


@dataclass(frozen=True, kw_only=True)
class TrainingTables(Checked):
    """The training sections as written (``TRAINING_SECTIONS``, tables checked once merged): the
    experiment's shared ones and a variant's overrides."""

    blocks: dict[str, Any] = field(default_factory=dict)
    input: dict[str, Any] = field(default_factory=dict)
    augment: dict[str, Any] = field(default_factory=dict)
    model: dict[str, Any] = field(default_factory=dict)
    train: dict[str, Any] = field(default_factory=dict)
    eval: dict[str, Any] = field(default_factory=dict)
    adapt: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class VariantTable(TrainingTables):
    """``[[variants]]``: one model (or one per fold) to train and score (see the module docs)."""

    name: str
    description: str = ""
    data: tuple[str, ...] = ()
    rooms: tuple[str, ...] | Literal["all"] = ()
    room_weight: float = setting(1.0, within=Range(0, 100, low_open=True))
    init: str | None = None
    adapt_to: tuple[str, ...] | Literal["scored", "others"] = ()

    def check(self) -> None:
        if not NAME_PATTERN.match(self.name):
            raise ConfigError(f"name {self.name!r} is not a usable name (letters, digits, . _ -, at most 64)")
        if not self.data and not self.rooms:
            raise ConfigError(f"variant {self.name!r} trains on nothing; give 'data' (synthetic) and/or 'rooms' (real)")
        if self.adapt_to and self.init is None:
            raise ConfigError(f"variant {self.name!r} adapt_to: adapting starts from a trained model (its pseudo-labels "
                              "are that model's); name the variant to start from in 'init'")
        if self.adapt_to and self.rooms:
            raise ConfigError(f"variant {self.name!r}: give 'rooms' (labelled real rooms) or 'adapt_to' (unlabelled "
                              "scans), not both")


@dataclass(frozen=True)
class ExperimentFile(TrainingTables):
    """An experiment TOML file as written (before paths are resolved)."""

    experiment: ExperimentTable = field(default_factory=ExperimentTable)
    real: SceneSet | None = None
    rooms: SceneSet | None = None
    holdout: HoldoutTable = field(default_factory=HoldoutTable)
    variants: tuple[VariantTable, ...] = ()


@dataclass(frozen=True)
class Variant:
    """A variant resolved: its synthetic data (spec files to build, dataset folders or clouds,
    absolute), its training rooms (resolved scenes, or "all"), and its training sections (checked)."""

    name: str
    description: str
    specs: tuple[Path, ...]
    folders: tuple[Path, ...]
    rooms: tuple[SceneSource, ...] | Literal["all"]
    room_weight: float
    init: str | None
    sections: dict[str, Any]
    adapt_to: tuple[SceneSource, ...] | Literal["scored", "others"] = ()


@dataclass(frozen=True)
class Experiment:
    """A parsed and checked experiment file."""

    name: str
    path: Path
    real: SceneSet
    rooms: SceneSet | None
    holdout: HoldoutTable
    variants: tuple[Variant, ...]
    class_names: tuple[str, ...] | None
    workers: int | None
    folds: int


def load_experiment(path: str | Path, *, real: Sequence[str | Path] | None = None,
                    device: str | None = None) -> Experiment:
    """Parse and check an experiment TOML before any work (one-line ConfigError/InputFileError).

    ``real`` replaces the ``[real] scenes`` of the file; ``device`` its ``[train] device``.
    """
    path = Path(path).resolve()
    own = load_toml(path)
    data = _with_base(own, path)
    real_file = path  # the file whose [real] scenes are used (the base's when this one names none)
    head = own.get("experiment")
    if isinstance(head, dict) and "base" in head and data.get("real") and "scenes" not in (
            _one_set(own["real"], where=f"{path} [real]") if own.get("real") else {}):
        real_file = base_file(head["base"], path, where="[experiment] base", kind="experiment file")
    for section in ("real", "rooms"):
        if section in data:
            data[section] = _one_set(data[section], where=f"{path} [{section}]")
    if isinstance(data.get("variants"), list):  # one path or room may be given as a string
        data["variants"] = [_listed(v) for v in data["variants"]]
    if isinstance(data.get("holdout"), dict) and isinstance(data["holdout"].get("ifc"), str):
        data["holdout"] = {**data["holdout"], "ifc": [data["holdout"]["ifc"]]}
    parsed = build_dataclass(ExperimentFile, data, where=str(path))
    folder = path.parent
    if real:
        real_set = SceneSet(scenes=tuple(str(Path(p).expanduser().resolve()) for p in real),
                            label_field=None if parsed.real is None else parsed.real.label_field,
                            mapping=None if parsed.real is None else parsed.real.mapping)
    elif parsed.real is not None:
        real_set = _absolute(parsed.real, folder)
    else:
        raise ConfigError(f"{path} [real] scenes: no real scenes named; add them or pass --real PATH")
    for scene in real_set.scenes:
        if not Path(scene).exists():
            raise InputFileError(f"{scene}: real scenes not found; fix [real] scenes in {real_file} or pass --real PATH")
    rooms_set = None if parsed.rooms is None else _absolute(parsed.rooms, folder)
    if not parsed.variants:
        raise ConfigError(f"{path}: no [[variants]]; name at least one training set")
    shared = {name: getattr(parsed, name) for name in TRAINING_SECTIONS}
    room_sources = _room_sources(rooms_set, where=f"{path} [rooms]") if rooms_set is not None else []
    variants: list[Variant] = []
    for number, table in enumerate(parsed.variants, start=1):
        where = f"{path} [[variants]] #{number} ({table.name})"
        if any(v.name == table.name for v in variants):
            raise ConfigError(f"{where}: the name is used twice; give every variant its own name")
        if table.init is not None and all(v.name != table.init for v in variants):
            raise ConfigError(f"{where} init: {table.init!r} is not an earlier variant; name one defined above it")
        specs, folders = [], []
        for item in (resolve_path(folder, value).resolve() for value in table.data):
            if not item.exists():
                raise InputFileError(f"{item}: variant {table.name!r} data not found; fix the path in {path}")
            (specs if item.is_file() and item.suffix.lower() == ".toml" else folders).append(item)
        for spec in specs:
            from bimscan.dataset.spec import load_spec

            load_spec(spec)  # every spec error before any work
        sections = {name: {**shared[name], **getattr(table, name)} for name in TRAINING_SECTIONS}
        if device is not None:
            sections["train"] = {**sections["train"], "device": device}
        check_moved_keys(sections, where=where)
        built = {name: build_dataclass(kind, sections[name], where=f"{where} [{name}]")
                 for name, kind in TRAINING_SECTIONS.items()}
        _check_start(table, built, variants, parsed, where=where)
        try:  # what TrainRunConfig checks across sections, before any work
            built["eval"].stride_for(built["blocks"].size_m)
        except ConfigError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        variants.append(Variant(
            name=table.name, description=table.description, specs=tuple(specs), folders=tuple(folders),
            rooms=_variant_rooms(table.rooms, room_sources, where=where), room_weight=table.room_weight,
            init=table.init, sections=sections, adapt_to=_adapt_scenes(table.adapt_to, folder, where=where)))
    head = parsed.experiment
    experiment = Experiment(name=head.name or path.stem, path=path, real=real_set, rooms=rooms_set,
                            holdout=parsed.holdout, variants=tuple(variants), class_names=head.class_names,
                            workers=head.workers, folds=head.folds)
    _holdout_spec(experiment)  # its models and settings checked before any work
    return experiment


def _check_start(table: VariantTable, built: dict[str, Any], earlier: list[Variant], parsed: ExperimentFile, *,
                 where: str) -> None:
    """ConfigError before any work for a variant that cannot start as it says: one that freezes
    parts of a network it does not take from a parent (they would stay random), or one whose
    network does not fit its parent's (``init``), which would be refused only after the parent trained."""
    if table.init is None:
        if built["train"].freeze:
            raise ConfigError(f"{where} [train] freeze = {list(built['train'].freeze)}: without 'init' those parts of "
                              "the network stay random; name the variant to start from in 'init' or leave freeze out")
        return
    parent = next(v for v in earlier if v.name == table.init)
    theirs = training_sections(parent)
    for what, mine, other in (("[model]", built["model"], theirs["model"]),
                              ("[input] features", built["input"].features, theirs["input"].features)):
        if mine != other:
            raise ConfigError(f"{where}: init {table.init!r} trains another {what} ({other}) than this variant "
                              f"({mine}); fine-tuning starts from the same network: give both the same {what}")


def _adapt_scenes(value: tuple[str, ...] | str, folder: Path, *,
                  where: str) -> tuple[SceneSource, ...] | Literal["scored", "others"]:
    """A variant's ``adapt_to``: "scored", "others", or its scans resolved (their labels never read)."""
    if value in ("scored", "others"):
        return value  # type: ignore[return-value]
    from bimscan.learn.data import list_scenes

    paths = [resolve_path(folder, p).resolve() for p in value]
    for path in paths:
        if not path.exists():
            raise InputFileError(f"{path}: {where} adapt_to: scans not found; fix the path")
    return tuple(list_scenes(paths))


def _listed(table: Any) -> Any:
    """A variant table with ``data = "x"`` as ``["x"]`` and ``rooms = "r"`` (not ``"all"``) as ``["r"]``."""
    if not isinstance(table, dict):
        return table
    table = dict(table)
    if isinstance(table.get("data"), str):
        table["data"] = [table["data"]]
    if isinstance(table.get("rooms"), str) and table["rooms"] != "all":
        table["rooms"] = [table["rooms"]]
    if isinstance(table.get("adapt_to"), str) and table["adapt_to"] not in ("scored", "others"):
        table["adapt_to"] = [table["adapt_to"]]
    return table


def _one_set(value: Any, *, where: str) -> Any:
    """``[real]``/``[rooms]`` as one scene-set table (a list of paths or a table)."""
    sets = scene_sets(value)
    if isinstance(sets, list) and len(sets) == 1:
        return sets[0]
    raise ConfigError(f"{where}: expected a table with scenes (and label_field, mapping) or a list of paths")


def _absolute(scenes: SceneSet, folder: Path) -> SceneSet:
    return dataclasses.replace(
        scenes, scenes=tuple(str(resolve_path(folder, s).resolve()) for s in scenes.scenes),
        mapping=None if scenes.mapping is None else str(resolve_path(folder, scenes.mapping).resolve()))


def _room_sources(rooms: SceneSet, *, where: str) -> list[SceneSource]:
    from bimscan.learn.train import resolve_scene_set

    for scene in rooms.scenes:
        if not Path(scene).exists():
            raise InputFileError(f"{scene}: training rooms not found; fix {where} scenes")
    return resolve_scene_set(rooms, base=Path("/"))


def _variant_rooms(names: tuple[str, ...] | str, sources: list[SceneSource], *,
                   where: str) -> tuple[SceneSource, ...] | Literal["all"]:
    if names == "all":
        if not sources:
            raise ConfigError(f"{where} rooms: 'all' of no rooms; name the real rooms to train on in [rooms]")
        return "all"
    chosen = []
    repeated = sorted({name for name in names if list(names).count(name) > 1})
    if repeated:
        raise ConfigError(f"{where} rooms: {repeated[0]!r} is listed twice; name each room once (room_weight draws "
                          "them more often)")
    for name in names:
        found = [s for s in sources if s.name == name or s.name.endswith("/" + name) or s.path.name == name]
        if len(found) != 1:
            known = ", ".join(s.name.rsplit("/", 1)[-1] for s in sources) or "none in [rooms]"
            raise ConfigError(f"{where} rooms: {name!r} is {'not' if not found else 'more than one'} of the "
                              f"[rooms] scenes ({known})")
        chosen.append(found[0])
    return tuple(chosen)


def _with_base(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` on top of its ``[experiment] base`` file: the base's ``[real]``, ``[rooms]``,
    ``[holdout]`` and training sections are the defaults, this file's keys replace them key by
    key (its variants are not taken). Companion experiments so share one model and schedule."""
    head = data.get("experiment", {})
    if not isinstance(head, dict) or "base" not in head:
        return dict(data)
    base_path = base_file(head["base"], path, where="[experiment] base", kind="experiment file")
    base = load_toml(base_path)
    if isinstance(base.get("experiment"), dict) and "base" in base["experiment"]:
        raise ConfigError(f"{path} [experiment] base: {base_path.name} has a base of its own; name the file at the root")
    merged = dict(data)

    def from_base(value: Any) -> Any:  # the base's relative paths are relative to the base file
        return str(resolve_path(base_path.parent, value).resolve()) if isinstance(value, str) else value

    for section in ("real", "rooms"):
        if section in base:
            table = _one_set(base[section], where=f"{base_path} [{section}]")
            table = {**table, "scenes": [from_base(v) for v in table.get("scenes", [])]}
            if "mapping" in table:
                table["mapping"] = from_base(table["mapping"])
            own = data.get(section, {})
            own = _one_set(own, where=f"{path} [{section}]") if own else {}
            merged[section] = {**table, **own}
    holdout = base.get("holdout")
    if isinstance(holdout, dict):
        holdout = {**holdout, "ifc": [from_base(v) for v in holdout.get("ifc", [])]}
        merged["holdout"] = {**holdout, **data.get("holdout", {})}
    for section in TRAINING_SECTIONS:
        defaults, own = base.get(section, {}), data.get(section, {})
        if not isinstance(defaults, dict) or not isinstance(own, dict):
            raise ConfigError(f"{path} [{section}] (or its base's): expected a table")
        merged[section] = {**defaults, **own}
    return merged


# -- running --------------------------------------------------------------------------------------

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


@dataclass(frozen=True)
class VariantResult:
    """What ``result.json`` of a variant holds (its scores, pooled over its runs' scored scenes)."""

    variant: str
    description: str
    class_names: tuple[str, ...]
    pooled: dict[str, Any]
    scene_mean: dict[str, float]
    scenes: dict[str, dict[str, Any]]
    confusion: list[list[int]]
    holdout: dict[str, Any] | None
    val_miou_per_epoch: list[list[float]]
    train_miou_per_epoch: list[list[float]]
    train_seconds: float
    synthetic: list[str]
    train_rooms: list[list[str]]
    excluded: list[str]
    folds: int
    evaluation: dict[str, Any]
    init: str | None
    adapted: list[list[str]] = field(default_factory=list)  # per run, the unlabelled scenes it adapted to

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @staticmethod
    def from_json(data: dict[str, Any]) -> VariantResult:
        fields = {f.name for f in dataclasses.fields(VariantResult)}
        if set(data) != fields and set(data) != fields - {"adapted"}:  # results from before adaptation read too
            raise LearnError("a variant result of another bimscan version; delete the variant's folder to rerun it")
        return VariantResult(**{**data, "class_names": tuple(data["class_names"])})


@dataclass(frozen=True)
class ExperimentRecord:
    """What ``experiment.json`` holds: what was run (the variants' fingerprints)."""

    name: str
    file: str
    real: list[str]
    variants: dict[str, str]
    format: str = RECORD_FORMAT
    version: int = RECORD_VERSION

    @staticmethod
    def read(path: Path) -> ExperimentRecord | None:
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise LearnError(f"{path}: unreadable ({exc}); delete it or use another OUT_DIR") from exc
        if data.get("format") != RECORD_FORMAT or data.get("version") != RECORD_VERSION:
            return None  # another version's record: its variants are checked by their own digests
        return ExperimentRecord(**data)


def run_experiment(experiment: Experiment, out_dir: str | Path, *,
                   log: Callable[[str], None] | None = None) -> list[VariantResult]:
    """Build, train, evaluate every variant (skipping finished steps) and write the report."""
    from bimscan.learn.report import write_report

    emit = log or (lambda text: print(text, file=sys.stderr, flush=True))
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    _check_holdout_unseen(experiment, out)
    _check_real_labelled(experiment)
    _check_same_experiment(experiment, out)
    _build_datasets(experiment, out, emit)
    holdout = _build_holdout(experiment, out, emit)
    _check_same_data(experiment, out)
    scored = _scored_scenes(experiment)
    runs_of: dict[str, list[Run]] = {}
    results = []
    for variant in experiment.variants:
        runs_of[variant.name] = _runs(experiment, variant, scored)
        results.append(_run_variant(experiment, variant, runs_of, out, holdout, emit))
    write_report(experiment, results, out)
    emit(f"report: {out / 'report.md'}")
    return results


def _check_real_labelled(experiment: Experiment) -> None:
    """Every scored scene carries labels of the experiment's classes: a cloud without them is
    refused in seconds, naming where it came from, before the datasets are built."""
    from bimscan.learn.data import require_labels
    from bimscan.learn.train_config import DEFAULT_CLASS_NAMES

    require_labels(_scored_scenes(experiment), class_names=experiment.class_names or DEFAULT_CLASS_NAMES,
                   where="[real] scenes or --real")


def _scored_scenes(experiment: Experiment) -> list[SceneSource]:
    from bimscan.learn.train import resolve_scene_set

    return resolve_scene_set(experiment.real, base=Path("/"))


def _runs(experiment: Experiment, variant: Variant, scored: list[SceneSource]) -> list[Run]:
    """The models of a variant (see the module docs: never scored on a room it trained on)."""
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
    all_rooms = () if experiment.rooms is None else tuple(_room_sources(experiment.rooms, where="[rooms]"))
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


def training_config(experiment: Experiment, run: Run, out: Path) -> TrainRunConfig:
    """A run's whole training configuration: its synthetic data and rooms, its scored scenes as
    validation, the variant's sections."""
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


def training_sections(variant: Variant) -> dict[str, Any]:
    """A variant's training sections as their dataclasses (``blocks``, ``input``, ... ``eval``)."""
    return {name: build_dataclass(kind, variant.sections[name], where=f"variant {variant.name} [{name}]")
            for name, kind in TRAINING_SECTIONS.items()}


def _fingerprint(experiment: Experiment, variant: Variant, out: Path) -> str:
    """What decides a variant's models: its sections, data, rooms and parent."""
    document = {"sections": variant.sections, "synthetic": _synthetic(variant, out), "init": variant.init,
                "rooms": "all" if variant.rooms == "all" else [str(s.path) for s in variant.rooms],
                "room_weight": variant.room_weight, "folds": experiment.folds, "class_names": experiment.class_names}
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
    config: dict[str, Any] = {"name": "holdout", "preset": holdout.preset, "stage": holdout.stage}
    if holdout.head_deg_per_s is not None:
        config["head_deg_per_s"] = holdout.head_deg_per_s
    if holdout.clutter:
        config["clutter"] = {"density": holdout.clutter}
    if holdout.realism is not None:
        config["realism"] = holdout.realism
    if holdout.sensor:
        config["sensor"] = dict(holdout.sensor)
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
    config = training_config(experiment, runs[0], out)
    class_names = tuple(config.data.class_names)
    for run in runs:
        config = training_config(experiment, run, out)
        where = run.folder(out)
        last = where / "train" / "last.pt"
        init = None if variant.init is None else _parent_checkpoint(runs_of[variant.init], run, out)
        done = int(read_checkpoint(last)["epoch"]) if last.is_file() else 0
        label = variant.name + ("" if run.fold is None else f" fold {run.fold + 1}/{len(runs)}")
        if done < config.train.epochs:
            emit(f"variant {label}: training{' (resuming after epoch ' + str(done) + ')' if done else ''} on "
                 f"{len(run.train_rooms)} real room(s){' and synthetic data' if variant.specs or variant.folders else ''}"
                 + (f", adapting to {len(run.adapt)} unlabelled scene(s)" if run.adapt else "")
                 + (f", from {variant.init}" if init else ""))
            train_model(config, base_dir=experiment.path.parent, out_dir=where / "train", resume=last.is_file(),
                        init=init, log=emit)
        use_cpu_threads(config.train.cpu_threads)  # the scores, too, are sums in thread order
        history = read_checkpoint(last)["history"]
        histories.append(history)
        seconds += float(sum(row.get("seconds", 0.0) for row in history))
        if run.scored:
            emit(f"variant {label}: evaluating on {len(run.scored)} real scene(s)")
            mapping = None if experiment.real.mapping is None else load_label_mapping(experiment.real.mapping)
            found = evaluate_checkpoint(last, [s.path for s in run.scored], label_field=experiment.real.label_field,
                                        mapping=mapping, device=config.train.device, evaluation=config.eval,
                                        work_dir=where)
            write_evaluation(found, where / "eval", class_names,
                             title=f"{label}: confusion on {len(found)} real scene(s), all points")
            evaluations += found
        if holdout is not None:
            found = evaluate_checkpoint(last, [holdout], device=config.train.device, evaluation=config.eval,
                                        work_dir=where)
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
        init=variant.init)
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


__all__ = ["Experiment", "ExperimentRecord", "Run", "Variant", "VariantResult", "format_report", "load_experiment",
           "run_experiment", "training_config",
           "training_sections"]

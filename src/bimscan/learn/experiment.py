"""Experiments as data: the file that says which variants to train on synthetic scans (and real
rooms, or adapted to unlabelled scans) and where to score them; :mod:`bimscan.sim2real` runs one.

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
  sections (``[adapt]`` among them); or ``ensemble``: earlier variants whose models' class
  probabilities are averaged run by run (fold by fold), a variant that trains nothing and is
  scored as the others are (its members must read the same ``[blocks]`` and points, their features
  computed alike, :func:`bimscan.learn.train_config.merge_inputs`; its own ``[eval]`` may differ).

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
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError, InputFileError, LearnError
from bimscan.learn.data import SceneSource
from bimscan.learn.train_config import (
    TRAINING_SECTIONS, AdaptationSchedule, SceneSet, TrainConfig, check_moved_keys, merge_inputs, scene_sets,
)
from bimscan.toml_files import base_file, build_dataclass, load_toml, over_base, resolve_path

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
    """``[holdout]``: IFC models (``ifc``) scanned once with auto stations, seeded by ``seed``, with
    the scan settings of ``config``: a dataset spec's ``[[configs]]`` table (preset, head speed,
    clutter, stage, realism, sensor, ...; its name is "holdout"), read by the dataset spec's own
    loader. Scored, never trained on."""

    ifc: tuple[str, ...] = ()
    seed: int = 0
    config: dict[str, Any] = field(default_factory=dict)

    def scan_config(self) -> dict[str, Any]:
        """The configuration table the holdout is scanned with: ``config`` over a default preset
        (exp3, unless ``config`` gives explicit ``settings``)."""
        default = {} if "settings" in self.config else {"preset": HOLDOUT_PRESET}
        return {**default, **self.config, "name": "holdout"}


HOLDOUT_PRESET = "exp3"
# [holdout] keys of earlier versions, now keys of its dataset configuration table
HOLDOUT_MOVED = ("preset", "head_deg_per_s", "clutter", "stage", "realism", "sensor")


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
    ensemble: tuple[str, ...] = ()

    def check(self) -> None:
        if not NAME_PATTERN.match(self.name):
            raise ConfigError(f"name {self.name!r} is not a usable name (letters, digits, . _ -, at most 64)")
        if self.ensemble:
            if len(self.ensemble) < 2 or len(set(self.ensemble)) != len(self.ensemble):
                raise ConfigError(f"variant {self.name!r} ensemble: name two earlier variants or more, each once")
            given = [key for key in ("data", "rooms", "init", "adapt_to") if getattr(self, key)]
            if given:
                raise ConfigError(f"variant {self.name!r}: an ensemble trains nothing, it averages its members' "
                                  f"models; remove {', '.join(given)}")
            return
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
    ensemble: tuple[str, ...] = ()  # earlier variants whose models it averages (it trains nothing)


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


def parse_experiment(path: str | Path, *, real: Sequence[str | Path] | None = None,
                     device: str | None = None, seed: int | None = None) -> Experiment:
    """Parse and check an experiment TOML (one-line ConfigError/InputFileError); its dataset specs
    and holdout models are checked by :func:`bimscan.sim2real.load_experiment`, which runs it.

    ``real`` replaces the ``[real] scenes`` of the file; ``device`` and ``seed`` the ``[train]
    device`` and ``[train] seed`` of every variant (a repeat of the experiment with other network
    weights and block order, on the same scans).
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
    moved = [key for key in HOLDOUT_MOVED if isinstance(data.get("holdout"), dict) and key in data["holdout"]]
    if moved:
        raise ConfigError(f"{path} [holdout] {moved[0]}: the holdout's scan settings are a dataset configuration "
                          f"table now; write [holdout] config = {{ {moved[0]} = ... }} (clutter as "
                          "{ density = 0.3 }, as in a dataset spec's [[configs]])")
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
    known_rooms = room_sources(rooms_set, where=f"{path} [rooms]") if rooms_set is not None else []
    variants: list[Variant] = []
    for number, table in enumerate(parsed.variants, start=1):
        where = f"{path} [[variants]] #{number} ({table.name})"
        if any(v.name == table.name for v in variants):
            raise ConfigError(f"{where}: the name is used twice; give every variant its own name")
        if table.init is not None and all(v.name != table.init for v in variants):
            raise ConfigError(f"{where} init: {table.init!r} is not an earlier variant; name one defined above it")
        if table.ensemble:
            variants.append(_ensemble_variant(table, variants, where=where))
            continue
        specs, folders = [], []
        for item in (resolve_path(folder, value).resolve() for value in table.data):
            if not item.exists():
                raise InputFileError(f"{item}: variant {table.name!r} data not found; fix the path in {path}")
            (specs if item.is_file() and item.suffix.lower() == ".toml" else folders).append(item)
        sections = {name: {**shared[name], **getattr(table, name)} for name in TRAINING_SECTIONS}
        if table.adapt_to:  # bimscan adapt's schedule, from the parent's [train], unless the variant sets its own
            sections["train"] = {**sections["train"],
                                 **_adaptation_schedule(table, sections["train"], variants, where=where)}
        replaced = {key: value for key, value in (("device", device), ("seed", seed)) if value is not None}
        sections["train"] = {**sections["train"], **replaced}
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
            rooms=_variant_rooms(table.rooms, known_rooms, where=where), room_weight=table.room_weight,
            init=table.init, sections=sections, adapt_to=_adapt_scenes(table.adapt_to, folder, where=where)))
    head = parsed.experiment
    experiment = Experiment(name=head.name or path.stem, path=path, real=real_set, rooms=rooms_set,
                            holdout=parsed.holdout, variants=tuple(variants), class_names=head.class_names,
                            workers=head.workers, folds=head.folds)
    return experiment


def _ensemble_variant(table: VariantTable, earlier: list[Variant], *, where: str) -> Variant:
    """An ensemble variant: its members earlier variants of the same inputs and blocks; its
    training sections its first member's, with its own ``[eval]`` over them."""
    members = []
    for name in table.ensemble:
        member = next((v for v in earlier if v.name == name), None)
        if member is None:
            raise ConfigError(f"{where} ensemble: {name!r} is not an earlier variant; name variants defined above it")
        members.append(member)
    first = members[0]
    def built(variant: Variant, section: str) -> Any:
        return build_dataclass(TRAINING_SECTIONS[section], variant.sections[section], where=where)

    for number, member in enumerate(members[1:], start=2):
        blocks = [(b.size_m, b.points) for b in (built(first, "blocks"), built(member, "blocks"))]
        if blocks[0] != blocks[1]:
            raise ConfigError(f"{where} ensemble: {member.name!r} reads other [blocks] than {first.name!r}; an "
                              "ensemble averages models of the same blocks")
        try:
            merge_inputs([built(v, "input") for v in members[:number]])
        except ValueError as exc:
            raise ConfigError(f"{where} ensemble: {member.name!r} has another {exc} than an earlier member; an "
                              "ensemble averages models that read the same points and features computed alike") from None
    for key in ("blocks", "input", "augment", "model", "train", "adapt"):
        if getattr(table, key):
            raise ConfigError(f"{where} [{key}]: an ensemble trains nothing; only its [eval] may be set")
    sections = {**first.sections, "eval": {**first.sections["eval"], **table.eval}}
    build_dataclass(TRAINING_SECTIONS["eval"], sections["eval"], where=f"{where} [eval]")
    return Variant(name=table.name, description=table.description, specs=(), folders=(), rooms=(), room_weight=1.0,
                   init=None, sections=sections, ensemble=table.ensemble)


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


def _adaptation_schedule(table: VariantTable, train: dict[str, Any], earlier: list[Variant], *,
                         where: str) -> dict[str, Any]:
    """The ``[train]`` settings of an adapting variant that ``AdaptationSchedule`` decides, as for
    ``bimscan adapt``: its epochs, a share of its parent's ``max_lr`` and no ``freeze`` (``train``:
    the variant's section so far), less those the variant sets itself. ``freeze`` is written only
    when the section freezes something, so that the variants' recorded sections (and fingerprints)
    stay as the experiment files wrote them."""
    parent = next(v for v in earlier if v.name == table.init)
    trained = build_dataclass(TrainConfig, parent.sections["train"], where=f"{where} init {table.init!r} [train]")
    changes = AdaptationSchedule().changes(trained)
    if not train.get("freeze"):
        changes.pop("freeze")
    return {key: value for key, value in changes.items() if key not in table.train}


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


def room_sources(rooms: SceneSet, *, where: str) -> list[SceneSource]:
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
    """``data`` on top of its ``[experiment] base`` file (``toml_files.over_base``, as a dataset
    spec over its base): the base's ``[real]``, ``[rooms]``, ``[holdout]`` and training sections,
    merged key by key with this file's (its ``[experiment]`` and variants are not taken).
    Companion experiments so share one model and schedule."""
    head = data.get("experiment", {})
    if not isinstance(head, dict) or "base" not in head:
        return dict(data)
    base_path = base_file(head["base"], path, where="[experiment] base", kind="experiment file")
    base = load_toml(base_path)
    if isinstance(base.get("experiment"), dict) and "base" in base["experiment"]:
        raise ConfigError(f"{path} [experiment] base: {base_path.name} has a base of its own; name the file at the root")

    def from_base(value: Any) -> Any:  # the base's relative paths are relative to the base file
        return str(resolve_path(base_path.parent, value).resolve()) if isinstance(value, str) else value

    inherited, own = dict(base), dict(data)
    for section in ("real", "rooms"):  # scene sets, as tables on both sides
        if section in base:
            table = _one_set(base[section], where=f"{base_path} [{section}]")
            table = {**table, "scenes": [from_base(v) for v in table.get("scenes", [])]}
            if "mapping" in table:
                table["mapping"] = from_base(table["mapping"])
            inherited[section] = table
        if own.get(section):
            own[section] = _one_set(own[section], where=f"{path} [{section}]")
    if isinstance(base.get("holdout"), dict):
        inherited["holdout"] = {**base["holdout"], "ifc": [from_base(v) for v in base["holdout"].get("ifc", [])]}
    for section in TRAINING_SECTIONS:
        for where, table in ((base_path, base.get(section, {})), (path, own.get(section, {}))):
            if not isinstance(table, dict):
                raise ConfigError(f"{where} [{section}]: expected a table")
    return over_base(own, inherited, keys=("real", "rooms", "holdout", *TRAINING_SECTIONS))


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
    ensemble: list[str] = field(default_factory=list)  # the variants it averages (it trained nothing)

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @staticmethod
    def from_json(data: dict[str, Any]) -> VariantResult:
        fields = {f.name for f in dataclasses.fields(VariantResult)}
        if not fields - {"adapted", "ensemble"} <= set(data) <= fields:  # results from before these read too
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


def training_sections(variant: Variant) -> dict[str, Any]:
    """A variant's training sections as their dataclasses (``blocks``, ``input``, ... ``eval``)."""
    return {name: build_dataclass(kind, variant.sections[name], where=f"variant {variant.name} [{name}]")
            for name, kind in TRAINING_SECTIONS.items()}


__all__ = ["Experiment", "ExperimentRecord", "Variant", "VariantResult", "parse_experiment", "room_sources",
           "training_sections"]

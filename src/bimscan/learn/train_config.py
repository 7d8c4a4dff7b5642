"""Training configuration: one TOML file per experiment -> frozen dataclasses.

Sections ``[data]``, ``[blocks]``, ``[input]``, ``[augment]``, ``[model]``, ``[train]`` and
``[eval]``; unknown keys are errors. Keys Table 2 gives default to its value; the sim-to-real
recipe (``[input]``, ``[augment]``, ``[train] class_weights``) defaults to what the ablation in
docs/results/sim2real.md measured best, and ``configs/training/table2.toml`` switches it off to stay
the paper's baseline. Relative paths in the file are relative to the file's folder. See
``configs/training/table2.toml`` for a commented example.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

from bimscan.constraints import Checked, Effect, Range, effect_of, setting
from bimscan.errors import ConfigError
from bimscan.learn.features import FEATURE_CHANNELS
from bimscan.semantics import DEFAULT_SCHEME, load_scheme
from bimscan.toml_files import build_dataclass, load_toml
from bimscan.types import UNLABELLED

# The default classes are the default label scheme's (spc5: the paper's five), in id order.
DEFAULT_CLASS_NAMES = tuple(c.name for c in sorted(load_scheme(DEFAULT_SCHEME).classes, key=lambda c: c.id))
IGNORE_LABEL = UNLABELLED  # skipped by the loss and the metrics


@dataclass(frozen=True)
class SceneSet(Checked):
    """Scenes whose labels read alike.

    ``scenes``: bimscan dataset folders (``manifest.json``; the units with status "done"), cloud
    files (``.las .laz .ply .e57``, text ``.txt .xyz .pts .csv .asc``), NumPy cloud folders, S3DIS
    room or area folders; relative paths are relative to the file that names them.
    ``label_field``: the LAS/PLY dimension, NumPy file or text column that holds the labels (None:
    ``classification``/``label``; S3DIS rooms: their annotation names). ``mapping``: a mapping TOML
    (source class name or id -> one of the class names; S3DIS rooms use the shipped
    S3DIS->5-class mapping when none is given). ``weight`` (training only): how often each training
    block of these scenes is drawn per epoch (1 = once; 4: four times, a few real rooms among many
    synthetic buildings; 0.5: half of them, at random each epoch).

    In TOML a list of paths is a scene set with the defaults (``train = ["a", "b"]``); a table, or
    a list of tables, gives the other keys (``[[data.train]]`` ... ``scenes = [...]``, ``weight = 4``).
    """

    scenes: tuple[str, ...]
    label_field: str | None = None
    mapping: str | None = None
    weight: float = setting(1.0, within=Range(0, 100, low_open=True))

    def check(self) -> None:
        if not self.scenes:
            raise ConfigError("a scene set names no scenes; give at least one path in 'scenes'")


def scene_sets(value: object) -> object:
    """A TOML value naming scenes as a list of scene-set tables (see ``SceneSet``): a list of paths is
    one set, a table one set; anything else is left for the loader to refuse."""
    if isinstance(value, list | tuple) and value and all(isinstance(v, str) for v in value):
        return [{"scenes": list(value)}]
    if isinstance(value, dict):
        return [value]
    return value


@dataclass(frozen=True)
class DataConfig(Checked):
    """Where the scenes are and how their labels read (``SceneSet``): ``train``, one or more sets
    (synthetic datasets, and real labelled scans to train on); ``val``, the set validated on every
    epoch (real scans; none: no validation); ``adapt``, unlabelled scans the model adapts to
    (``[adapt]``; their labels, if any, are never read: a user's own scans of the building).
    ``class_names``: the training classes, in id order.
    """

    train: tuple[SceneSet, ...]
    val: SceneSet | None = None
    adapt: tuple[SceneSet, ...] = ()
    class_names: tuple[str, ...] = DEFAULT_CLASS_NAMES

    def check(self) -> None:
        if not self.train:
            raise ConfigError("'train' lists no scenes; name at least one dataset folder or cloud")
        if not 2 <= len(self.class_names) <= 255:
            raise ConfigError(f"'class_names' needs 2..255 names, got {len(self.class_names)}")
        if len(set(self.class_names)) != len(self.class_names):
            raise ConfigError(f"'class_names' repeats a name: {list(self.class_names)}")


@dataclass(frozen=True)
class BlockConfig(Checked):
    """How scenes are cut into network inputs (Table 2: N = 8192 points per block).

    A block is a vertical column ``size_m`` x ``size_m`` over the scene's full height. Training
    tiles are the non-overlapping columns of a grid anchored at multiples of ``size_m``; each
    keeps a uniform random subset of at most ``cache_points`` points in memory, from which
    every epoch draws ``points`` without replacement (zero padding with a validity mask when
    the tile has fewer). Tiles with fewer than ``min_points`` points are skipped for training
    and validation. Evaluation and prediction slide the same column (``EvalConfig``).
    """

    size_m: float = setting(4.0, within=Range(0, 100, low_open=True))
    points: int = setting(8192, within=Range(16, 1 << 20))
    min_points: int = setting(1024, within=Range(1, 1 << 24))
    cache_points: int = setting(16384, within=Range(16, 1 << 24))
    # training columns of scenes that record stations: "station" (each station's points apart: what
    # one tripod saw, one face of each wall, like a real scan of one room, not both faces of a wall
    # and the room behind it; part of the sim-to-real recipe), "scene" (all stations merged, the
    # paper) or "both" (every column both ways: single-room scans and merged whole buildings);
    # evaluation always reads whole scenes
    train_columns: Literal["scene", "station", "both"] = "station"

    def check(self) -> None:
        if self.cache_points < self.points:
            raise ConfigError(f"cache_points ({self.cache_points}) must be >= points ({self.points})")
        if self.min_points > self.cache_points:
            raise ConfigError(f"min_points must be in 1..cache_points ({self.cache_points}), got {self.min_points}")


FEATURE_NAMES = tuple(FEATURE_CHANNELS)  # the features bimscan.learn.features computes


@dataclass(frozen=True)
class InputConfig(Checked):
    """What the network sees of a block, identically for synthetic and real scenes.

    ``grid_m``: density normalisation, one point per voxel of this size before blocking
    (:mod:`bimscan.learn.density`); 0 = off (the paper: raw points). ``features``: ``xyz``
    first, optionally ``height`` (above the floor under the point, :mod:`bimscan.learn.floors`,
    / ``height_scale_m``), ``normals`` (PCA of ``normal_neighbours`` neighbours among the
    block's points), ``shape`` (linearity, planarity, scattering of the same neighbourhood) and
    ``shape_wide`` (the same over ``wide_neighbours`` neighbours) (:mod:`bimscan.learn.features`).
    Defaults: the sim-to-real recipe measured in docs/results/sim2real.md; the paper's baseline
    is ``grid_m = 0.0``, ``features = ["xyz"]``.
    """

    grid_m: float = setting(0.05, within=Range(0.0, 1.0))
    features: tuple[str, ...] = ("xyz", "height", "normals", "shape")
    height_scale_m: float = setting(3.0, within=Range(0, 100, low_open=True))
    normal_neighbours: int = setting(32, within=Range(3, 128))
    wide_neighbours: int = setting(128, within=Range(3, 512))

    def check(self) -> None:
        if not self.features or self.features[0] != "xyz":
            raise ConfigError(f"features must start with 'xyz', got {list(self.features)}")
        unknown = [f for f in self.features if f not in FEATURE_NAMES]
        if unknown or len(set(self.features)) != len(self.features):
            raise ConfigError(f"features take each of {', '.join(FEATURE_NAMES)} at most once, got {list(self.features)}")


# What models averaged point by point must share: the same points (grid) and, for the features
# both read, the settings those features are computed with; their feature lists may differ.
SHARED_INPUT_SETTINGS: dict[str, tuple[str, ...]] = {
    "grid_m": (), "height_scale_m": ("height",), "normal_neighbours": ("normals", "shape"),
    "wide_neighbours": ("shape_wide",),
}


def merge_inputs(inputs: list[InputConfig]) -> tuple[InputConfig, list[list[int]]]:
    """The inputs several models read together (an ensemble): the first's features, then those
    only others read, each setting of ``SHARED_INPUT_SETTINGS`` taken from a model that reads the
    features it shapes; and for each model the union's channels it reads, in its own order.
    ValueError naming the setting when two models read a feature computed with other settings."""
    first = inputs[0]
    settings: dict[str, object] = {}
    for key, shaped in SHARED_INPUT_SETTINGS.items():
        readers = [i for i in inputs if not shaped or any(name in i.features for name in shaped)]
        for other in readers[1:]:
            if getattr(other, key) != getattr(readers[0], key):
                raise ValueError(f"[input] {key} ({getattr(other, key)} against {getattr(readers[0], key)})")
        if readers:
            settings[key] = getattr(readers[0], key)
    features = list(first.features)
    for other in inputs[1:]:
        features += [name for name in other.features if name not in features]
    start, offset = {}, 0
    for name in features:
        start[name], offset = offset, offset + FEATURE_CHANNELS[name]
    channels = [[start[name] + c for name in own.features for c in range(FEATURE_CHANNELS[name])] for own in inputs]
    return replace(first, features=tuple(features), **settings), channels


@dataclass(frozen=True)
class AugmentConfig(Checked):
    """Training augmentations (:mod:`bimscan.learn.augment`); ``enabled = false`` is the paper's
    baseline. Each effect is off at its neutral value (rotate_z false, scale_range [1, 1],
    flip_probability 0, jitter_sigma_m 0, dropout_max 0, elastic [], the colour ones 0). The colour
    randomisation acts on blocks read with colour (``[input] features`` with ``rgb``):
    ``colour_gain_sigma`` (each channel scaled by a gain ~ N(1, sigma) and shifted by ~ N(0,
    sigma / 2) of full scale, per block: white balance, exposure), ``colour_noise`` (per point
    sigma, of full scale), ``colour_grey`` (the chance a block's colour becomes its grey value)
    and ``colour_drop`` (the chance it becomes mid grey: a scan without colour)."""

    enabled: bool = True
    rotate_z: bool = True
    scale_range: tuple[float, float] = setting((0.9, 1.1), each=Range(0, 10, low_open=True))
    anisotropic: bool = True
    flip_probability: float = setting(0.5, within=Range(0.0, 1.0))
    jitter_sigma_m: float = setting(0.01, within=Range(0.0, 1.0))
    jitter_clip_m: float = setting(0.05, within=Range(0.0, 1.0))
    dropout_max: float = setting(0.2, within=Range(0.0, 1.0, high_open=True))
    elastic: tuple[tuple[float, float], ...] = setting(((0.2, 0.4), (0.8, 1.6)), each=Range(0, 100))
    colour_gain_sigma: float = setting(0.0, within=Range(0.0, 1.0))
    colour_noise: float = setting(0.0, within=Range(0.0, 1.0))
    colour_grey: float = setting(0.0, within=Range(0.0, 1.0))
    colour_drop: float = setting(0.0, within=Range(0.0, 1.0))

    def check(self) -> None:
        low, high = self.scale_range
        if not low <= high:
            raise ConfigError(f"scale_range must be [low, high] with 0 < low <= high, got {list(self.scale_range)}")
        for pair in self.elastic:
            if len(pair) != 2 or not pair[0] > 0:
                raise ConfigError(f"elastic takes [granularity_m > 0, magnitude >= 0] pairs, got {list(pair)}")


@dataclass(frozen=True)
class ModelConfig(Checked):
    """The model: ``kind`` "pct", the PCT segmentation network (its size: defaults of Guo et al.
    2021, about 2.4M parameters at C=5), or "gbm", gradient-boosted trees (LightGBM) on per-point
    geometric features of the same blocks (:mod:`bimscan.learn.boosted`; the ``gbm_`` keys):
    ``gbm_rounds`` boosting rounds of one tree per class with at most ``gbm_leaves`` leaves and
    ``gbm_min_leaf_points`` points per leaf, shrunk by ``gbm_learning_rate``, trained on at most
    ``gbm_points`` points drawn evenly from the ``[train] epochs`` augmented draws of every block."""

    kind: Literal["pct", "gbm"] = "pct"
    gbm_rounds: int = setting(300, within=Range(1, 100_000))
    gbm_leaves: int = setting(63, within=Range(2, 131_072))
    gbm_learning_rate: float = setting(0.05, within=Range(0.0, 1.0, low_open=True))
    gbm_min_leaf_points: int = setting(200, within=Range(1, 1 << 30))
    gbm_points: int = setting(1_500_000, within=Range(1000, 1 << 31))
    embed_dim: int = setting(128, within=Range(4, 4096))
    attention_layers: int = setting(4, within=Range(1, 64))
    fuse_dim: int = setting(1024, within=Range(1, 1 << 16))
    head_dims: tuple[int, ...] = setting((512, 256), each=Range(1, 1 << 16))
    dropout: float = setting(0.5, within=Range(0.0, 1.0, high_open=True))

    def check(self) -> None:
        if self.embed_dim % 4:
            raise ConfigError(f"embed_dim must be a multiple of 4 (q/k project to embed_dim/4), got {self.embed_dim}")


@dataclass(frozen=True)
class TrainConfig(Checked):
    """Optimisation (Table 2): Adam, OneCycleLR (cosine), EMA, AMP, accumulation, DDP.

    The global batch is ``batch_size`` (per process) x processes x ``accumulation_steps``.
    OneCycleLR runs from ``max_lr / div_factor`` up to ``max_lr`` over the first ``pct_start``
    of the steps and down to ``max_lr / div_factor / final_div_factor``. ``cycle_momentum``
    (true: PyTorch's default, kept) makes it also cycle Adam's beta1 inversely to the LR,
    from 0.95 down to 0.85 at the peak and back to 0.95; false leaves beta1 at Adam's 0.9.
    ``amp``: "float16" (Table 2's AMP with GradScaler; the default), "bfloat16" (no scaler
    needed: bf16 has float32's range) or "off". AMP applies on CUDA only; CPU runs use float32.
    ``device``: "auto" (CUDA when present), "cpu", "cuda". ``out_dir`` holds the checkpoints,
    ``metrics.csv`` and ``curves.png``. ``cpu_threads``: PyTorch's threads for the CPU's work
    (0: PyTorch's default, one per core). A CPU run's float sums are ordered by its thread count, so
    the same seed gives the same model only at the same count (and PyTorch build): set it where
    results are to be compared across machines.
    """

    epochs: int = setting(100, within=Range(1, 100_000))
    batch_size: int = setting(2, within=Range(1, 4096))
    accumulation_steps: int = setting(4, within=Range(1, 4096))
    # above 1 Adam's steps are larger than any weight of the network: a typo, not a schedule
    max_lr: float = setting(2e-3, within=Range(0.0, 1.0, low_open=True))
    weight_decay: float = setting(5e-4, within=Range(0.0, 1.0))
    pct_start: float = setting(0.3, within=Range(0.0, 1.0, low_open=True, high_open=True))
    div_factor: float = setting(25.0, within=Range(1.0, 1e6))
    final_div_factor: float = setting(1e4, within=Range(1.0, 1e9))
    cycle_momentum: bool = True
    ema_alpha: float = setting(0.99, within=Range(0.0, 1.0, high_open=True))
    amp: Literal["float16", "bfloat16", "off"] = "float16"
    num_workers: int = setting(4, within=Range(0, 256), effect="runtime")
    seed: int = setting(0, within=Range(0, 2**63 - 1))
    device: Literal["auto", "cpu", "cuda"] = setting("auto", effect="runtime")
    cpu_threads: int = setting(0, within=Range(0, 1024))
    out_dir: str = setting("runs/train", effect="runtime")
    # class-balanced loss: per-class weights from the training points' class frequencies f_c,
    # "inverse" 1/f_c, "inverse_sqrt" 1/sqrt(f_c) (milder), normalised to mean 1; "none": the paper
    class_weights: Literal["none", "inverse", "inverse_sqrt"] = "inverse_sqrt"
    # parts of the network kept as they are while training (fine-tuning): "embedding" (the
    # point-wise layers before attention), "attention"
    freeze: tuple[Literal["embedding", "attention"], ...] = ()


@dataclass(frozen=True)
class EvalConfig(Checked):
    """How evaluation and prediction label every point of a scene (:mod:`bimscan.learn.infer`).

    Columns of the training block's size slide every ``stride_m`` (the block size must be a whole
    multiple of it; None: half the block) and vote with their summed softmax; each column's points
    (its voxel representatives, with a grid) are shuffled and cut into groups of the block's
    points ``votes`` times, so every point is voted on that many times per column, each time
    among another random sample of it (test-time voting over random subsamples, as RandLA-Net and
    KPConv vote). With a density grid a point that is not its voxel's representative takes the
    inverse-square-distance mean of the votes of its ``label_neighbours`` nearest representatives
    (PointNet++'s interpolation, Qi et al. 2017; 0: its own voxel's representative's).
    ``batch_size``: blocks per forward pass (speed and memory only). ``max_passes`` > 0 caps the
    groups per block (points left out take their nearest voted neighbour's class; 0: every point
    seen). ``weights``: the EMA weights (Table 2) or the live ones. ``seed``: the shuffles'
    (None: the training run's ``[train] seed``, the one ``sim2real`` scores with). ``plane_votes``:
    before a stripe's labels are final, each vertical planar region of the scene (its voxel
    representatives grown through neighbours within ``PLANE_REACH_M`` whose normals differ by at
    most ``PLANE_ANGLE_DEG``, the stripes in memory around it included) gives all its Wall&Column and
    Others representatives the one of the two most of them got: a wall behind furniture takes the
    class of the wall above it (:func:`bimscan.learn.regions.plane_votes`).

    A training run stores its ``[eval]`` with its checkpoint as that model's evaluation; commands
    that evaluate or predict use it unless told otherwise, and record what they used.
    """

    stride_m: float | None = setting(None, within=Range(0, 100, low_open=True), effect="scores")
    votes: int = setting(1, within=Range(1, 64), effect="scores")
    label_neighbours: int = setting(3, within=Range(0, 64), effect="scores")
    batch_size: int = setting(8, within=Range(1, 4096), effect="runtime")
    max_passes: int = setting(0, within=Range(0, 1 << 20), effect="scores")
    weights: Literal["ema", "live"] = setting("ema", effect="scores")
    seed: int | None = setting(None, within=Range(0, 2**63 - 1), effect="scores")
    plane_votes: bool = setting(False, effect="scores")

    def with_seed(self, training_seed: int) -> EvalConfig:
        """This evaluation with its seed decided: its own, else the training run's."""
        return self if self.seed is not None else replace(self, seed=training_seed)

    def stride_for(self, size_m: float) -> float:
        """The stride for columns of ``size_m``; ConfigError unless it divides ``size_m`` whole."""
        stride = size_m / 2 if self.stride_m is None else self.stride_m
        ratio = size_m / stride
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(f"[eval] stride_m = {stride:g} does not divide the {size_m:g} m blocks whole; "
                              f"give one like {size_m / 2:g} or {size_m / 3:g}")
        return stride


@dataclass(frozen=True)
class AdaptConfig(Checked):
    """Adaptation to unlabelled scans (``[data] adapt``): self-training on pseudo-labels of the
    averaged (EMA, mean-teacher) weights, with class-balanced thresholds, on blocks that mix the
    unlabelled scans with the synthetic ones (:mod:`bimscan.learn.adapt`).

    Every epoch is a round (Zou et al. 2018, CBST): the teacher labels every kept point of the
    unlabelled columns once, and of the points it calls class c the ``pseudo_share`` most
    confident keep their label (the threshold at most ``max_threshold``: a class it is sure of
    is not cut), so rare classes keep labels too. Beside each micro-batch of synthetic blocks
    train as many adapted blocks: an unlabelled column with its pseudo-labels, its footprint cut
    into ``mix_cells`` x ``mix_cells`` cells of which a random half (at least one, not all) take
    a synthetic column's points and labels instead (column mixing, after DODA's cuboid mixing,
    Ding et al. 2022), the whole augmented as a synthetic block; ``mix_cells`` 1: the
    unlabelled column alone. Its loss counts ``weight`` times the synthetic blocks'.
    """

    pseudo_share: float = setting(0.5, within=Range(0.0, 1.0, low_open=True))
    max_threshold: float = setting(0.9, within=Range(0.0, 1.0))
    mix_cells: int = setting(2, within=Range(1, 8))
    weight: float = setting(1.0, within=Range(0.0, 10.0, low_open=True))


@dataclass(frozen=True)
class AdaptationSchedule(Checked):
    """How ``bimscan adapt`` fine-tunes a checkpoint to a user's unlabelled scans: ``epochs`` over
    the checkpoint's synthetic training data (its scene sets as it trained on them), each with the
    adapted blocks beside (``[adapt]``), at ``lr_factor`` times the checkpoint's ``max_lr`` (a
    fine-tune, not a new training); the rest of its configuration as it was. An experiment's
    variant that adapts (``adapt_to``) takes the same from its parent's ``[train]`` unless it sets
    its own (``bimscan.learn.experiment``; ``configs/experiments/sim2real_adapt_cpu.toml``)."""

    epochs: int = setting(1, within=Range(1, 1000))
    lr_factor: float = setting(0.2, within=Range(0.0, 1.0, low_open=True))

    def changes(self, trained: TrainConfig) -> dict[str, object]:
        """The ``[train]`` settings an adaptation of a model trained with ``trained`` replaces:
        ``epochs``, ``max_lr`` (``lr_factor`` times its own, to 12 significant digits: a fifth of
        5e-3 is 1e-3, not 1.0000000000000002e-3) and ``freeze`` (none: adaptation trains every part)."""
        return {"epochs": self.epochs, "max_lr": float(f"{trained.max_lr * self.lr_factor:.12g}"), "freeze": ()}


@dataclass(frozen=True)
class TrainRunConfig(Checked):
    """A whole training experiment: the sections of the TOML file."""

    data: DataConfig
    blocks: BlockConfig = field(default_factory=BlockConfig)
    input: InputConfig = field(default_factory=InputConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    adapt: AdaptConfig = field(default_factory=AdaptConfig)

    def check(self) -> None:
        self.eval.stride_for(self.blocks.size_m)  # a stride that does not divide the blocks fails now


# The training sections of a run (and of an experiment's variants) and their settings classes.
TRAINING_SECTIONS: dict[str, type] = {"blocks": BlockConfig, "input": InputConfig, "augment": AugmentConfig,
                                      "model": ModelConfig, "train": TrainConfig, "eval": EvalConfig,
                                      "adapt": AdaptConfig}


def setting_effect(section: str, key: str) -> Effect:
    """What changing ``[section] key`` touches: "model", "scores" or "runtime" (``bimscan.constraints``)."""
    kind = {"data": DataConfig, **TRAINING_SECTIONS}.get(section)
    try:
        return "model" if kind is None else effect_of(kind, key)
    except KeyError:
        return "model"


# Keys that moved, with where they live now (a one-line error names the new home).
MOVED_KEYS = {
    ("blocks", "eval_stride_m"): "[eval] stride_m", ("blocks", "eval_votes"): "[eval] votes",
    ("input", "label_neighbours"): "[eval] label_neighbours", ("train", "eval_batch_size"): "[eval] batch_size",
    ("data", "train_label_field"): "[[data.train]] label_field", ("data", "train_mapping"): "[[data.train]] mapping",
    ("data", "val_label_field"): "[data.val] label_field", ("data", "val_mapping"): "[data.val] mapping",
}


def load_train_config(path: str | Path) -> tuple[TrainRunConfig, Path]:
    """Load a training TOML file; returns the config and the folder relative paths start from."""
    path = Path(path)
    data = load_toml(path)
    check_moved_keys(data, where=str(path))
    table = data.get("data")
    if "adapt" in data and not (isinstance(table, dict) and table.get("adapt")):
        raise ConfigError(f"{path} [adapt]: its settings act only on unlabelled scans, and [data] adapt names none; "
                          "add [data] adapt = [\"SCANS\"] or remove [adapt]")
    return build_dataclass(TrainRunConfig, with_scene_sets(data), where=str(path)), path.resolve().parent


def check_moved_keys(data: dict[str, object], *, where: str) -> None:
    """ConfigError naming the new home of a key that moved (see ``MOVED_KEYS``)."""
    for (section, key), home in MOVED_KEYS.items():
        table = data.get(section)
        if isinstance(table, dict) and key in table:
            raise ConfigError(f"{where}: [{section}] {key} is now {home}; move it there")


def with_scene_sets(data: dict[str, object]) -> dict[str, object]:
    """``data`` with its ``[data]`` train and val in scene-set form (``SceneSet``)."""
    table = data.get("data")
    if not isinstance(table, dict):
        return data
    table = dict(table)
    if "train" in table:
        table["train"] = scene_sets(table["train"])
    if "adapt" in table:
        table["adapt"] = scene_sets(table["adapt"])
    if "val" in table:
        val = scene_sets(table["val"])
        if isinstance(val, list) and not val:
            table["val"] = None
        elif isinstance(val, list) and len(val) == 1:
            table["val"] = val[0]
        else:
            table["val"] = val
    return {**data, "data": table}


def dump_config(config: TrainRunConfig) -> dict[str, object]:
    """The config as plain data (for the checkpoint and the run log)."""
    from dataclasses import asdict

    return asdict(config)


def parse_config(data: dict[str, object], *, where: str) -> TrainRunConfig:
    """Rebuild a config stored by :func:`dump_config` (tuples come back as lists).

    A config stored before the sim-to-real recipe existed (no ``input`` section) was trained
    as the paper's baseline: it reads back as such, not with today's recipe defaults. One stored
    before ``[eval]`` existed reads its evaluation from where it was kept then.
    """
    if "input" not in data:
        data = _as_paper_baseline(data)
    if "eval" not in data:
        data = _with_eval_section(data)
    try:
        return build_dataclass(TrainRunConfig, with_scene_sets(data), where=where)
    except ConfigError as exc:
        raise ConfigError(f"{where}: stored configuration is not readable by this version ({exc})") from exc


def _with_eval_section(data: dict[str, object]) -> dict[str, object]:
    """A stored config from before ``[eval]``: its evaluation settings and scene sets moved to
    where they live now, with the values that run had (then-defaults included)."""
    sections = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    blocks, inputs, train = (sections.setdefault(k, {}) for k in ("blocks", "input", "train"))
    stride = blocks.pop("eval_stride_m", 2.0)  # type: ignore[union-attr]
    sections["eval"] = {
        "stride_m": stride, "votes": blocks.pop("eval_votes", 1),  # type: ignore[union-attr]
        "label_neighbours": inputs.pop("label_neighbours", 0),  # type: ignore[union-attr]
        "batch_size": train.pop("eval_batch_size", 8),  # type: ignore[union-attr]
    }
    table = dict(sections.get("data", {}))  # type: ignore[arg-type]
    for name in ("train", "val"):
        field_name, mapping_name = f"{name}_label_field", f"{name}_mapping"
        extras = {"label_field": table.pop(field_name, None), "mapping": table.pop(mapping_name, None)}
        value = table.get(name)
        if isinstance(value, list | tuple) and value and all(isinstance(v, str) for v in value):
            table[name] = {"scenes": list(value), **extras} if name == "val" else [{"scenes": list(value), **extras}]
        elif name == "val" and not value:
            table[name] = None
    sections["data"] = table
    return sections


def _as_paper_baseline(data: dict[str, object]) -> dict[str, object]:
    """A pre-recipe stored config with the recipe switched off (what that run trained with)."""
    upgraded: dict[str, object] = {**data, "input": {"grid_m": 0.0, "features": ["xyz"]}, "augment": {"enabled": False}}
    for section, key, value in (("blocks", "train_columns", "scene"), ("train", "class_weights", "none")):
        table = data.get(section)
        if isinstance(table, dict) and key not in table:
            upgraded[section] = {**table, key: value}
    return upgraded

"""Dataset specifications: which scenes, scanned with which configurations, written how.

A spec is one TOML file (paths inside it are relative to the file)::

    name = "my-dataset"
    seed = 0                      # noise seed of every unit
    scheme = "spc5"               # built-in label scheme or a scheme TOML file
    scanner = "riegl_vz400"       # built-in scanner or a scanner TOML file
    formats = ["laz", "npy"]      # one or several of las, laz, ply, e57, npy per unit
    voxel_size_m = 0.02           # optional: voxel subsampling of every unit (an edge > 0 in metres)
    engine = "open3d"             # ray engine: open3d, embreex, warp or auto (warp on a CUDA GPU)
    strict = false                # settings outside the device's limits are errors
    max_station_pulses = 500000000  # refuse settings that would fire more per station (tripod)
    max_walk_pulses = 2000000000  # refuse a walk that would fire more in all (mobile)
    realism = "paper"             # optional: "paper" (default) or "full" sensor effects

    [noise]                       # optional; default: the scanner's accuracies
    range_sigma_m = 0.005
    angle_sigma_deg = 0.03

    [sensor]                      # optional: sensor settings (bimscan.scan.sensor.SensorModel keys;
    color = true                  # a setting whose effect is off in a configuration is refused)
    color_noise = 0.05

    [[scenes]]
    name = "duplex"
    ifc = "models/duplex.ifc"
    stations = "auto"             # or a station CSV file
    trajectory = "auto"           # mobile configurations: a walk planned through the stations, or a CSV file
    length_unit = "mm"            # optional: the IFC's lengths in this unit, whatever it says (m, cm, mm, ft, in)

    [[scenes]]
    name = "demo1"
    generate = { seed = 1, storeys = 2, style = "office" }   # a generated building (style optional)

    [[configs]]
    name = "exp1"
    preset = "exp1"               # exp1..exp6 (the paper's Table 1)
    head_deg_per_s = 60.0         # optional head speed override

    [[configs]]
    name = "custom"
    settings = { pulse_freq_hz = 300000, scan_freq_hz = 100, head_deg_per_s = 20 }
    realism = "full"              # optional: this configuration's realism and sensor settings,
    sensor = { glass = false }    # key by key over the spec's
    stage = "enclosed"            # optional: the construction stage (bimscan.site), a name or a table
    clutter = { density = 0.2, kinds = ["site", "people"] }   # optional: clutter on the floors

    [[configs]]
    name = "handheld"
    platform = "handheld"         # a mobile scan (handheld, backpack or a platform file): no preset
    lidar = "velodyne_vlp16"      # optional: the multi-beam lidar (default: the platform's)
    rotation_hz = 10.0            # optional: its rotation rate
    drift_m = 0.01                # optional: SLAM drift, metres per 10 m walked (bimscan.survey.drift)
    # platform = "drone" flies instead (a Risley lidar); gnss_m = 0.01: its GNSS/INS error (as --gnss)

A spec can start from another: ``base = "other.toml"`` (relative to this file) takes every
top-level key of that spec (its scenes and configurations too) that this file does not set; a
key this file sets replaces the base's whole (``clutter = { density = 0.0 }`` takes clutter out,
``[[scenes]]`` here replace the base's scenes). Paths the base holds stay relative to the base
file. A base cannot have a base of its own. Companion datasets (the same buildings without
clutter, or scanned with other sensor settings) so name their scenes once.

A top-level ``stage`` and ``clutter`` are the defaults of every configuration. A top-level
``stages = ["structure", "enclosed", "finished"]`` (names or tables) sweeps the stages: every
configuration becomes one per stage, named ``<config>.<stage>`` (unit ``<scene>__<config>.<stage>``).

``load_spec`` checks everything a build needs before any work starts: unknown keys, bad
values, names, missing IFC or station files, unknown presets, schemes (and the IFC classes their
rules name), scanners and engines, impossible settings, unknown stages and clutter kinds,
trajectory files (read, and their walks held to ``max_walk_pulses``), and settings that would
change nothing (as ``bimscan scan`` refuses them: ``ScanRecipe.resolve``). Each
(scene, configuration) pair is one data unit ``<scene>__<config>``, scanned with the
``ScanRecipe`` that ``DatasetSpec.recipe`` resolves for it. A mobile configuration walks each
scene along its ``trajectory``: planned through the scene's stations (the tripod plan every
configuration of the scene shares), or the scene's CSV file; the unit keeps it as
``trajectory.csv``.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bimscan.constraints import Checked, setting
from bimscan.dataset.layout import FORMAT_FILES, UNIT_SEPARATOR, unit_id
from bimscan.errors import BimscanError, ConfigError, InputFileError
from bimscan.ifc.generate.styles import DEFAULT_STYLE
from bimscan.ifc.load import check_ifc_file
from bimscan.ifc.units import LENGTH_UNITS
from bimscan.process.subsample import VOXEL_SIZE_HINT, VOXEL_SIZE_M
from bimscan.scan.device import DEFAULT_SCANNER, ScanSettings
from bimscan.scan.engine import DEFAULT_ENGINE
from bimscan.scan.noise import NoiseModel
from bimscan.survey.drift import registration_drift
from bimscan.survey.mobile import AUTO_TRAJECTORY
from bimscan.survey.platform import TRIPOD
from bimscan.survey.recipe import AUTO_STATIONS, DEFAULT_MAX_STATION_PULSES, DEFAULT_MAX_WALK_PULSES, ScanRecipe
from bimscan.scan.sensor import merge_sensor_tables
from bimscan.site.model import ClutterSettings, SiteModel, StageSettings, stage_table
from bimscan.toml_files import base_file, build_dataclass, load_toml, over_base
from bimscan.types import LabelScheme

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class GeneratedScene:
    """A seeded demo building (``bimscan.ifc.generate.make_building``)."""

    seed: int
    storeys: int = 2
    style: str = DEFAULT_STYLE  # office, residential or site (bimscan.ifc.generate.styles.STYLES)


@dataclass(frozen=True)
class SceneSpec(Checked):
    """One BIM scene: an IFC file (``ifc``, absolute once loaded) or a generated building."""

    name: str
    ifc: str | None = None
    generate: GeneratedScene | None = None
    stations: str = AUTO_STATIONS  # "auto" or a station CSV file (absolute once loaded)
    length_unit: str | None = setting(None, among=LENGTH_UNITS)  # read the IFC's lengths in this unit
    trajectory: str = AUTO_TRAJECTORY  # mobile configurations: "auto" or a trajectory CSV (absolute once loaded)


@dataclass(frozen=True)
class ConfigSpec:
    """One scanner configuration: a preset or an explicit settings table, optional head speed,
    optional sensor realism and settings (over the spec's), and optionally the site as scanned
    (construction stage, clutter; default: the spec's)."""

    name: str
    preset: str | None = None
    settings: ScanSettings | None = None
    head_deg_per_s: float | None = None
    realism: str | None = None
    sensor: dict[str, Any] | None = None
    stage: StageSettings | None = None
    clutter: ClutterSettings | None = None
    platform: str = TRIPOD
    lidar: str | None = None
    rotation_hz: float | None = None
    drift_m: float | None = None
    gnss_m: float | None = None

    @property
    def is_mobile(self) -> bool:
        return self.platform != TRIPOD


@dataclass(frozen=True)
class DatasetSpec(Checked):
    """A validated dataset specification (see the module docs); paths are absolute. Its own numbers
    are checked on construction; what the configurations resolve to (``ScanRecipe``: the seed,
    the scan settings, the budgets) is checked where they are declared, by ``check_spec``."""

    name: str = "dataset"
    seed: int = 0
    scheme: str = "spc5"
    scanner: str = DEFAULT_SCANNER
    formats: tuple[str, ...] = ("laz",)
    voxel_size_m: float | None = setting(None, within=VOXEL_SIZE_M,
                                         hint=f"{VOXEL_SIZE_HINT}; leave it out for no subsampling")
    engine: str = DEFAULT_ENGINE
    strict: bool = False
    max_station_pulses: int = DEFAULT_MAX_STATION_PULSES  # the tripod configurations' budget per station
    max_walk_pulses: int = DEFAULT_MAX_WALK_PULSES  # the mobile configurations' budget per walk
    noise: NoiseModel = field(default_factory=NoiseModel)
    realism: str | None = None
    sensor: dict[str, Any] | None = None
    stage: StageSettings | None = None  # default stage of the configurations
    clutter: ClutterSettings | None = None  # default clutter of the configurations
    stages: tuple[StageSettings, ...] = ()  # a sweep: every configuration once per stage
    scenes: tuple[SceneSpec, ...] = ()
    configs: tuple[ConfigSpec, ...] = ()

    def check(self) -> None:
        if not self.formats:
            raise ConfigError(f"'formats' is empty; give one or more of {', '.join(FORMAT_FILES)}")
        for fmt in self.formats:
            if fmt not in FORMAT_FILES:
                raise ConfigError(f"unknown output format {fmt!r}; use one or more of {', '.join(FORMAT_FILES)}")
        if len(set(self.formats)) != len(self.formats):
            raise ConfigError(f"'formats' lists a format twice ({list(self.formats)}); list each once")

    def unit_ids(self) -> list[str]:
        """Every unit id, scene by scene, configurations in spec order."""
        return [unit_id(s.name, c.name) for s in self.scenes for c in self.configs]

    def scene(self, name: str) -> SceneSpec:
        return next(s for s in self.scenes if s.name == name)

    def config(self, name: str) -> ConfigSpec:
        return next(c for c in self.configs if c.name == name)

    def site(self, config: ConfigSpec) -> SiteModel:
        """The site model of a configuration: its own stage and clutter, else the spec's."""
        return SiteModel(stage=config.stage or self.stage or StageSettings(),
                         clutter=config.clutter or self.clutter or ClutterSettings())

    def recipe(self, scene: SceneSpec, config: ConfigSpec) -> ScanRecipe:
        """The scan recipe of the unit (scene, config): its own noise stream (the unit id), so no
        two units share a noise sequence. Raises ConfigError/ScannerSettingsError when impossible."""
        stations_from = scene.stations
        if config.is_mobile:  # a preset, settings or head speed is refused by ScanRecipe.resolve, as on the CLI
            mobile = {"platform": config.platform, "lidar": config.lidar, "rotation_hz": config.rotation_hz,
                      "trajectory": scene.trajectory, "max_walk_pulses": self.max_walk_pulses,
                      "drift": registration_drift(config.drift_m, config.gnss_m)}
            if scene.trajectory != AUTO_TRAJECTORY:  # the scene's stations serve its tripod configurations
                stations_from = AUTO_STATIONS
        else:
            if (config.preset is None) == (config.settings is None):
                raise ConfigError(f"give exactly one of 'preset' (exp1..exp6 or a settings file) or 'settings' (a "
                                  f"table), not {'both' if config.preset else 'neither'}")
            if config.lidar is not None or config.rotation_hz is not None or config.drift_m is not None or \
                    config.gnss_m is not None:
                raise ConfigError("'lidar', 'rotation_hz', 'drift_m' and 'gnss_m' are for mobile configurations; give "
                                  "platform = \"handheld\", \"backpack\" or \"drone\", or leave them out")
            mobile = {"max_station_pulses": self.max_station_pulses}
        return ScanRecipe.resolve(preset=config.preset, settings=config.settings, scanner=self.scanner, **mobile,
                                  head_deg_per_s=config.head_deg_per_s, noise=self.noise, seed=self.seed,
                                  noise_stream=unit_id(scene.name, config.name), engine=self.engine,
                                  stations_from=stations_from, strict=self.strict, site=self.site(config),
                                  realism=config.realism or self.realism,
                                  sensor=merge_sensor_tables(self.sensor, config.sensor))


def load_spec(path: str | Path) -> DatasetSpec:
    """Read and validate a dataset spec file; relative paths resolve against its folder.

    Raises ConfigError (unknown keys, bad values, unknown presets, impossible settings, ...) or
    InputFileError (the spec, an IFC or a station file is missing), naming the place in the file.
    """
    path = Path(path)
    data = _with_base(load_toml(path), path)
    return parse_spec(data, base=path.resolve().parent, where=str(path))


def _with_base(data: dict[str, Any], path: Path) -> dict[str, Any]:
    """``data`` over its ``base`` spec (see the module docs), the base's relative paths made absolute."""
    if "base" not in data:
        return data
    base_path = base_file(data["base"], path, where="base", kind="dataset spec (.toml)")
    base = load_toml(base_path)
    if "base" in base:
        raise ConfigError(f"{path} base: {base_path.name} has a base of its own; name the spec at the root")
    folder = base_path.parent

    def local(value: Any) -> Any:  # a file next to the base (a registry name stays as it is)
        return _local_path(value, folder) if isinstance(value, str) else value

    inherited = dict(base)
    for key in ("scheme", "scanner"):
        if key in inherited:
            inherited[key] = local(inherited[key])
    if isinstance(inherited.get("sensor"), dict):
        inherited["sensor"] = _local_sensor(inherited["sensor"], folder)
    if isinstance(inherited.get("scenes"), list):
        inherited["scenes"] = [_scene_paths(raw, folder) for raw in inherited["scenes"]]
    if isinstance(inherited.get("configs"), list):
        inherited["configs"] = [_config_paths(raw, folder) for raw in inherited["configs"]]
    return over_base({k: v for k, v in data.items() if k != "base"}, inherited)


def _config_paths(raw: Any, folder: Path) -> Any:
    """A base's ``[[configs]]`` table with its preset and material table files absolute."""
    if not isinstance(raw, dict):
        return raw
    out = dict(raw)
    for key in ("preset", "platform", "lidar"):
        if isinstance(out.get(key), str):
            out[key] = _local_path(out[key], folder)
    if isinstance(out.get("sensor"), dict):
        out["sensor"] = _local_sensor(out["sensor"], folder)
    return out


def _scene_paths(raw: Any, folder: Path) -> Any:
    """A base's ``[[scenes]]`` table with its IFC and station files absolute (relative to ``folder``)."""
    if not isinstance(raw, dict):
        return raw
    out = dict(raw)
    if isinstance(out.get("ifc"), str):
        out["ifc"] = str((folder / out["ifc"]).resolve())
    if isinstance(out.get("stations"), str) and out["stations"] != AUTO_STATIONS:
        out["stations"] = str((folder / out["stations"]).resolve())
    if isinstance(out.get("trajectory"), str) and out["trajectory"] != AUTO_TRAJECTORY:
        out["trajectory"] = str((folder / out["trajectory"]).resolve())
    return out


def parse_spec(data: dict[str, Any], *, base: Path, where: str) -> DatasetSpec:
    """Validate a spec mapping (as read from TOML); ``base`` resolves relative paths."""
    data = dict(data)
    scenes_raw = data.pop("scenes", None)
    configs_raw = data.pop("configs", None)
    if "stage" in data:
        data["stage"] = stage_table(data["stage"])
    if isinstance(data.get("stages"), list):
        data["stages"] = [stage_table(s) for s in data["stages"]]
    try:
        spec = build_dataclass(DatasetSpec, data, where=where)
    except BimscanError as exc:  # nested tables (noise) validate themselves without knowing the file
        raise exc if str(exc).startswith(where) else type(exc)(f"{where}: {exc}") from exc
    if not isinstance(scenes_raw, list) or not scenes_raw:
        raise ConfigError(f"{where}: no scenes; add at least one [[scenes]] table with a name and an ifc file")
    if not isinstance(configs_raw, list) or not configs_raw:
        raise ConfigError(f"{where}: no configurations; add at least one [[configs]] table with a name and a preset")
    scenes = tuple(_scene(raw, base=base, where=f"{where} [[scenes]] #{i + 1}") for i, raw in enumerate(scenes_raw))
    configs = _expand_stages(spec, tuple(_config(raw, where=f"{where} [[configs]] #{i + 1}")
                                         for i, raw in enumerate(configs_raw)), where=where)
    spec = _absolute(dataclasses.replace(spec, scenes=scenes, configs=configs), base=base)
    check_spec(spec, where=where)
    return spec


def _config(raw: Any, *, where: str) -> ConfigSpec:
    if isinstance(raw, dict) and "stage" in raw:
        raw = {**raw, "stage": stage_table(raw["stage"])}
    try:
        return build_dataclass(ConfigSpec, raw, where=where)
    except BimscanError as exc:  # stage and clutter validate themselves without knowing the file
        raise exc if str(exc).startswith(where) else type(exc)(f"{where}: {exc}") from exc


def _expand_stages(spec: DatasetSpec, configs: tuple[ConfigSpec, ...], *, where: str) -> tuple[ConfigSpec, ...]:
    """Every configuration once per stage of a ``stages`` sweep, named ``<config>.<stage>``."""
    if not spec.stages:
        return configs
    if spec.stage is not None:
        raise ConfigError(f"{where}: give 'stage' (one stage for all) or 'stages' (a sweep), not both")
    names = [s.name for s in spec.stages]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ConfigError(f"{where}: 'stages' names {', '.join(map(repr, repeated))} more than once; sweep each stage "
                          "once (put other partial states in configurations of their own)")
    expanded = []
    for config in configs:
        if config.stage is not None:
            raise ConfigError(f"{where} [[configs]] {config.name!r}: sets its own 'stage' while the spec sweeps "
                              "'stages'; drop one of them")
        expanded += [dataclasses.replace(config, name=f"{config.name}.{stage.name}", stage=stage)
                     for stage in spec.stages]
    return tuple(expanded)


def _scene(raw: Any, *, base: Path, where: str) -> SceneSpec:
    scene = build_dataclass(SceneSpec, raw, where=where)
    where = f"{where} ({scene.name!r})"
    if (scene.ifc is None) == (scene.generate is None):
        raise ConfigError(f"{where}: give exactly one of 'ifc' (a file) or 'generate' (a demo building), not "
                          f"{'both' if scene.ifc else 'neither'}")
    ifc = None
    if scene.ifc is not None:
        ifc_path = (base / scene.ifc).resolve()
        if not ifc_path.is_file():
            raise InputFileError(f"{where}: IFC file {scene.ifc!r} not found (looked at {ifc_path}); fix the path, "
                                 "which is relative to the spec file")
        try:
            check_ifc_file(ifc_path)  # not an IFC file: refused now, not inside the build
        except BimscanError as exc:
            raise type(exc)(f"{where}: {exc}") from exc
        ifc = str(ifc_path)
    stations = scene.stations
    if stations != "auto":
        station_path = (base / stations).resolve()
        if not station_path.is_file():
            raise InputFileError(f"{where}: station file {stations!r} not found (looked at {station_path}); give "
                                 "'auto' or a CSV file relative to the spec file")
        stations = str(station_path)
    trajectory = scene.trajectory
    if trajectory != AUTO_TRAJECTORY:
        trajectory_file = (base / trajectory).resolve()
        if not trajectory_file.is_file():
            raise InputFileError(f"{where}: trajectory file {trajectory!r} not found (looked at {trajectory_file}); "
                                 "give 'auto' or a CSV file relative to the spec file")
        trajectory = str(trajectory_file)
    return dataclasses.replace(scene, ifc=ifc, stations=stations, trajectory=trajectory)


def check_spec(spec: DatasetSpec, *, where: str) -> None:
    """Raise a BimscanError for the first thing in ``spec`` a build could not do."""
    for kind, names in (("scene", [s.name for s in spec.scenes]), ("configuration", [c.name for c in spec.configs])):
        for name in names:
            if not _NAME.match(name) or UNIT_SEPARATOR in name:
                raise ConfigError(f"{where}: {kind} name {name!r} is not usable as a folder name; use letters, digits, "
                                  f"'-', '_' and '.', starting with a letter or digit, without {UNIT_SEPARATOR!r}")
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ConfigError(f"{where}: {kind} name(s) {', '.join(map(repr, duplicates))} used more than once; "
                              "give every one a unique name")
    try:
        resolve_scheme(spec)
    except BimscanError as exc:
        raise type(exc)(f"{where}: {exc}") from exc
    for config in spec.configs:
        try:
            spec.recipe(spec.scenes[0], config)  # settings, scanner, noise, seed, engine: the same for every scene
        except BimscanError as exc:
            raise type(exc)(f"{where} [[configs]] {config.name!r}: {exc}") from exc
    for scene in spec.scenes:
        check_scene_walks(spec, scene, where=f"{where} [[scenes]] {scene.name!r}")
        if scene.generate is not None:
            from bimscan.ifc.generate import check_building_options

            try:
                check_building_options(seed=scene.generate.seed, storeys=scene.generate.storeys,
                                       style=scene.generate.style)
            except BimscanError as exc:
                raise type(exc)(f"{where} [[scenes]] {scene.name!r} generate: {exc}") from exc


def check_scene_walks(spec: DatasetSpec, scene: SceneSpec, *, where: str) -> None:
    """Raise a BimscanError, in one line naming the scene, when its trajectory file cannot be walked:
    unreadable or malformed, over a mobile configuration's pulse budget, or given where it would
    change nothing (no mobile configuration; a station file only mobile configurations walking the
    file would ignore)."""
    if scene.trajectory == AUTO_TRAJECTORY:
        return
    from bimscan.survey.trajectory import read_trajectory

    mobile = [config for config in spec.configs if config.is_mobile]
    if not mobile:
        raise ConfigError(f"{where}: trajectory {Path(scene.trajectory).name!r} would change nothing: no configuration "
                          "is mobile; leave it out or add a configuration with platform = \"handheld\" or \"backpack\"")
    if scene.stations != AUTO_STATIONS and len(mobile) == len(spec.configs):
        raise ConfigError(f"{where}: stations {Path(scene.stations).name!r} would change nothing: every configuration "
                          f"is mobile and walks the trajectory file {Path(scene.trajectory).name!r}; leave the "
                          "stations out, or give trajectory = \"auto\" to walk through them")
    try:
        trajectory = read_trajectory(scene.trajectory)
    except BimscanError as exc:
        raise type(exc)(f"{where}: trajectory {exc}") from exc
    for config in mobile:
        try:
            spec.recipe(scene, config).check_walk(trajectory, source=Path(scene.trajectory).name)
        except BimscanError as exc:
            raise type(exc)(f"{where} with [[configs]] {config.name!r}: {exc}") from exc


def _local_path(value: str, base: Path) -> str:
    """A registry name stays as is; anything else is a file relative to the spec's folder."""
    candidate = base / value
    return str(candidate.resolve()) if candidate.is_file() else value


def _absolute(spec: DatasetSpec, *, base: Path) -> DatasetSpec:
    """The spec with its scheme, scanner and preset files made absolute (workers run anywhere)."""
    configs = tuple(dataclasses.replace(c, preset=_local_path(c.preset, base) if c.preset else None,
                                        sensor=_local_sensor(c.sensor, base),
                                        platform=_local_path(c.platform, base),
                                        lidar=_local_path(c.lidar, base) if c.lidar else None) for c in spec.configs)
    return dataclasses.replace(spec, scheme=_local_path(spec.scheme, base), scanner=_local_path(spec.scanner, base),
                               sensor=_local_sensor(spec.sensor, base), configs=configs)


def _local_sensor(table: dict[str, Any] | None, base: Path) -> dict[str, Any] | None:
    """A sensor table with its material table file made absolute."""
    if not table or not isinstance(table.get("material_table"), str):
        return table
    return table | {"material_table": str((base / table["material_table"]).resolve())}


def resolve_scheme(spec: DatasetSpec) -> LabelScheme:
    """The spec's label scheme (a built-in name or a scheme file), its rules' IFC classes checked."""
    from bimscan.pipeline import load_label_scheme

    return load_label_scheme(spec.scheme)


def device_warnings(spec: DatasetSpec) -> list[str]:
    """One line per configuration setting outside the scanner's limits (allowed unless ``strict``)."""
    return [f"configuration {config.name!r}: {warning}" for config in spec.configs
            for warning in spec.recipe(spec.scenes[0], config).warnings]

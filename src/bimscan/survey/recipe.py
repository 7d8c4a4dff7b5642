"""The scan recipe: everything that decides a scan besides the scene, in one typed value.

A ``ScanRecipe`` is resolved once from what a user wrote (a preset or settings file name, a
scanner name or file, a head speed override, noise overrides; on the command line or in a
dataset spec) into objects, and then travels unchanged: the CLI builds one from its flags, a
dataset spec resolves one per (scene, configuration), a unit job carries one, a survey holds the
one it was prepared with, and the cloud's metadata is ``to_json()`` of it, so settings and
recorded metadata cannot disagree. Every default lives here (or in the types it holds) once.

Construction validates: impossible settings raise ``ScannerSettingsError``; settings outside the
device's limits are ``warnings`` (errors under ``strict``). Unset noise sigmas are resolved from
the scanner's accuracies (``NoiseModel.resolved``).
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from bimscan.constraints import Checked, Range, effect_of, setting
from bimscan.files import dump_json, file_sha256
from bimscan.scan.device import (
    DEFAULT_PRESET, DEFAULT_SCANNER, PRESETS, SCANNERS, SENSOR_DEVICE_FIELDS, ScannerModel, ScanSettings,
    check_settings, load_scanner, load_settings, with_overrides,
)
from bimscan.errors import BimscanError, ConfigError, ScannerSettingsError
from bimscan.scan.engine import DEFAULT_ENGINE, resolve_engine
from bimscan.scan.noise import NoiseModel
from bimscan.scan.sensor import SensorModel
from bimscan.site.model import SiteModel
from bimscan.scan.lidars import load_lidar
from bimscan.survey.drift import DriftModel
from bimscan.survey.mobile import AUTO_TRAJECTORY, MobileScan
from bimscan.survey.platform import TRIPOD, load_platform
from bimscan.survey.trajectory import Trajectory
from bimscan.toml_files import build_dataclass, load_toml

DEFAULT_CHUNK_PULSES = 1 << 20  # ~70 MB of working arrays per chunk
# The most pulses one station may fire unless the user raises it: the paper's densest preset fires
# 7.5M per station; 500M points are about 15 GB uncompressed, so more is most likely a typo.
DEFAULT_MAX_STATION_PULSES = 500_000_000
# The most pulses a mobile scan's whole walk may fire unless the user raises it: about two hours of
# one VLP-16 (289,352 pulses/s), one hour of the backpack's two; a walk of 2e9 pulses is some 60 GB
# of points uncompressed, so more is most likely a unit mistake in a trajectory's time column.
DEFAULT_MAX_WALK_PULSES = 2_000_000_000
AUTO_STATIONS = "auto"


def _json_value(value: Any) -> Any:
    """A recipe field as JSON-able data: nested settings through their ``to_json`` when they have
    one, else as dicts."""
    if hasattr(value, "to_json"):
        return value.to_json()
    return dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value


@dataclass(frozen=True)
class ScanRecipe(Checked):
    """How to scan a scene: the device, what each station does, noise, seed, engine, stations.

    scanner: the device model. settings: what one station does; ``preset`` names where they came
    from (a preset name or a settings file's name; None for settings given as a table).
    noise: resolved against the scanner on construction (None sigmas -> its accuracies).
    seed, noise_stream: the noise generator's key is (seed, noise_stream, station); a dataset gives
    every unit its own stream (its id) so that no two units share a noise sequence; "" for a
    single scan. engine: a ``scan.engine.ENGINES`` name, or "auto" (resolved on construction: Warp
    on a CUDA GPU, Open3D otherwise; see ``scan.engine.resolve_engine``). stations_from: "auto"
    (planned) or a station CSV file. strict: settings outside the device's limits are errors.
    sensor: which effects beyond the paper's thin ray are simulated (``SensorModel``; the default is
    the paper's scanner). site: what the site looks like when scanned (construction stage, clutter;
    ``bimscan.site``), dressed with ``seed``. threads (0 = all cores) and chunk_pulses change speed
    and memory only, never the output. max_station_pulses: a station that would fire more pulses is
    refused before any work (with the number it would fire). mobile: a mobile scan (a platform
    walking a trajectory with multi-beam lidars, ``survey.mobile``) instead of tripod stations;
    ``scanner`` and ``stations_from`` are then the tripod plan's, which decides where a planned
    walk goes (``survey.walk``), ``settings`` and ``preset`` are unused, and none of them is
    recorded. max_walk_pulses: a walk whose lidars would fire more pulses in all is refused before
    the scan (``check_walk``). The "runtime" settings (``RUNTIME_FIELDS``: threads, chunk_pulses
    and the budgets) change how a scan runs or what it refuses, never its output bytes, and are left
    out of the fingerprint.
    """

    scanner: ScannerModel = field(default_factory=lambda: SCANNERS[DEFAULT_SCANNER])
    settings: ScanSettings = field(default_factory=lambda: PRESETS[DEFAULT_PRESET])
    preset: str | None = DEFAULT_PRESET
    noise: NoiseModel = field(default_factory=NoiseModel)
    seed: int = setting(0, within=Range(0, 2**64 - 1))
    noise_stream: str = ""
    engine: str = DEFAULT_ENGINE
    stations_from: str = AUTO_STATIONS
    strict: bool = False
    sensor: SensorModel = field(default_factory=SensorModel)
    site: SiteModel = field(default_factory=SiteModel)
    threads: int = setting(0, within=Range(0, None), hint="0: all cores", effect="runtime")
    chunk_pulses: int = setting(DEFAULT_CHUNK_PULSES, within=Range(1, None), effect="runtime")
    max_station_pulses: int = setting(DEFAULT_MAX_STATION_PULSES, effect="runtime")
    mobile: MobileScan | None = None
    max_walk_pulses: int = setting(DEFAULT_MAX_WALK_PULSES, within=Range(1, None), effect="runtime")

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise", self.noise.resolved(self.mobile.lidar if self.mobile else self.scanner))
        if self.mobile is not None and isinstance(self.sensor, SensorModel):
            object.__setattr__(self, "sensor", self.sensor.for_mobile())
        super().__post_init__()  # the declared ranges, then ``check``
        # "auto" becomes the engine this machine runs, so the metadata records the one used
        object.__setattr__(self, "engine", resolve_engine(self.engine))

    def check(self) -> None:
        if self.site.yard_density > 0 and self.site.ground_margin_m == 0:
            raise ConfigError("yard objects (--yard) stand on the ground around the building, and this scan has "
                              "none: fly a drone whose platform keeps its ground (ground_margin_m > 0; --platform "
                              "drone does) or leave --yard out")
        if self.mobile is not None:
            if self.noise.registers_with_error:
                raise ConfigError("a mobile scan has no stations to register: give its registration error as --drift "
                                  "(metres per 10 m walked), not as a station registration sigma")
            self.mobile.warnings(strict=self.strict)  # raises under strict
        if not isinstance(self.sensor, SensorModel):
            raise ConfigError(f"sensor must be a SensorModel, got {type(self.sensor).__name__}")
        self.sensor.check_settings_act(mobile=self.mobile is not None)  # an option acts or is refused
        if self.sensor.needs_surfaces:
            from bimscan.scan.surfaces import load_material_table

            load_material_table(self.sensor.material_table)  # a bad table fails now, before any work
        check_settings(self.settings, self.scanner, strict=self.strict)  # raises for impossible settings
        lines = self.settings.scan_freq_hz * self.settings.duration_s()
        pulses = self.settings.expected_pulses(self.scanner)
        if not lines >= 1:
            raise ScannerSettingsError(
                f"a station would sweep {lines:.3g} mirror lines (scan_freq_hz = {self.settings.scan_freq_hz:g} over "
                f"{self.settings.duration_s():.3g} s of head rotation); raise scan_freq_hz or turn the head further")
        if not pulses <= self.max_station_pulses:
            raise ScannerSettingsError(
                f"a station would fire {pulses:.3g} pulses, more than the budget of {self.max_station_pulses:,}; "
                "lower pulse_freq_hz, turn the head faster, or raise the budget (--max-station-pulses)")

    @staticmethod
    def resolve(*, preset: str | Path | None = None, settings: ScanSettings | None = None,
                scanner: str | Path | ScannerModel | None = None, head_deg_per_s: float | None = None,
                realism: str | None = None, sensor: SensorModel | Mapping[str, Any] | str | Path | None = None,
                platform: str | Path | None = None, lidar: str | Path | None = None, trajectory: str | None = None,
                drift: DriftModel | None = None, rotation_hz: float | None = None,
                max_station_pulses: int | None = None, max_walk_pulses: int | None = None,
                **fields: Any) -> ScanRecipe:
        """A recipe from what a user wrote: a preset name or settings TOML (or a settings table),
        a scanner name or TOML, a head speed override, the sensor realism (``realism`` "paper" or
        "full", and ``sensor``: a SensorModel, a table of its keys or a TOML file of them; an
        explicit ``realism`` wins over the table's); ``fields`` are the other ScanRecipe fields.
        A mobile ``platform`` (a ``survey.platform.PLATFORMS`` name or file; None or "tripod": TLS
        stations) makes a mobile scan: its ``lidar`` (a ``scan.lidars.MOBILE_LIDARS`` name or file,
        multi-beam or Risley; default: the platform's) along ``trajectory`` ("auto": a planned walk or,
        for a drone, flight; or a CSV file) with ``drift`` (SLAM drift, or a drone's GNSS/INS error) at
        ``rotation_hz`` (default: the lidar's; none for a Risley lidar). A drone adds the ground
        around the building to the site (its flight's ``ground_margin_m``). ``scanner`` stays the TLS whose
        tripod plan the walk visits. ``max_station_pulses`` budgets a tripod station,
        ``max_walk_pulses`` a mobile walk (None: the default).

        Without ``preset`` and ``settings``: the default preset. What would do nothing is refused,
        whether it comes from the command line or a dataset spec: a preset, settings, head speed or
        station budget on a mobile platform, stations beside a trajectory file, a walk budget or any
        mobile option on a tripod (and, on construction, sensor settings whose effect is off).
        Raises ConfigError for these, unknown names, keys and missing files, ScannerSettingsError
        for impossible settings.
        """
        if preset is not None and settings is not None:
            raise ConfigError("give a preset or explicit settings, not both")
        fields["sensor"] = resolve_sensor(sensor, realism=realism)
        if platform is not None and platform != TRIPOD:
            chosen = load_platform(platform)
            idle = [name for name, value in (("'preset' (--preset)", preset), ("'settings'", settings),
                                             ("'head_deg_per_s' (--head-speed)", head_deg_per_s),
                                             ("'max_station_pulses' (--max-station-pulses)", max_station_pulses))
                    if value is not None]
            if idle:
                budget = "; a walk's budget is max_walk_pulses (--max-walk-pulses)" if max_station_pulses is not None else ""
                raise ConfigError(f"a mobile platform ({chosen.name!r}) has no TLS {', '.join(idle)}: its lidars fire "
                                  f"their own pattern along the walk; leave {'it' if len(idle) == 1 else 'them'} "
                                  f"out{budget}")
            walk_file = trajectory not in (None, AUTO_TRAJECTORY)
            stations_from = fields.get("stations_from", AUTO_STATIONS)
            if walk_file and stations_from != AUTO_STATIONS:
                raise ConfigError(f"stations from {Path(stations_from).name!r} (--stations) would change nothing: they "
                                  f"are the waypoints of a planned walk, and the walk comes from the trajectory file "
                                  f"{Path(trajectory).name!r}; leave the stations out, or give --trajectory auto to "
                                  "walk through them")
            fields["mobile"] = MobileScan(platform=chosen, lidar=load_lidar(lidar or chosen.default_scanner),
                                          rotation_hz=rotation_hz, trajectory_from=trajectory or AUTO_TRAJECTORY,
                                          drift=drift or DriftModel())
            if chosen.flies:
                if stations_from != AUTO_STATIONS:
                    raise ConfigError(f"stations from {Path(stations_from).name!r} (--stations): a drone has none; it "
                                      "flies the flight planned around the model, or a trajectory file (--trajectory)")
                site = fields.get("site") or SiteModel()
                if site.ground_margin_m == 0.0 and chosen.flight.ground_margin_m > 0.0:  # a site, not a floating building
                    fields["site"] = dataclasses.replace(site, ground_margin_m=chosen.flight.ground_margin_m)
            if max_walk_pulses is not None:
                fields["max_walk_pulses"] = max_walk_pulses
        else:
            if trajectory not in (None, AUTO_TRAJECTORY) or (drift is not None and not drift.is_off) or \
                    rotation_hz is not None or lidar is not None:
                raise ConfigError("a lidar, trajectory, drift, GNSS/INS error or rotation rate needs a mobile platform "
                                  "(--platform handheld, backpack or drone); a tripod scan has stations")
            if max_walk_pulses is not None:
                raise ConfigError("'max_walk_pulses' (--max-walk-pulses) budgets a mobile platform's walk; a tripod "
                                  "scan's budget is per station (--max-station-pulses): leave it out")
            if max_station_pulses is not None:
                fields["max_station_pulses"] = max_station_pulses
        model = scanner if isinstance(scanner, ScannerModel) else load_scanner(scanner)
        if settings is None:
            preset = DEFAULT_PRESET if preset is None else preset
            settings = load_settings(preset)
            name: str | None = preset if isinstance(preset, str) and preset in PRESETS else Path(preset).name
        else:
            name = None
        settings = with_overrides(settings, head_deg_per_s=head_deg_per_s)
        return ScanRecipe(scanner=model, settings=settings, preset=name, **fields)

    def check_walk(self, trajectory: Trajectory, *, source: str | Path | None = None) -> int:
        """The pulses a mobile scan fires along ``trajectory`` (every pass, every lidar); raises
        ScannerSettingsError, in one line with the estimate, when they are more than
        ``max_walk_pulses`` or none. ``source`` names the trajectory in the message (its file)."""
        mobile = self.mobile
        if mobile is None:
            raise ValueError("a tripod recipe walks no trajectory; check_walk needs a mobile recipe")
        pulses = mobile.walk_pulses(trajectory)
        duration, lidars = trajectory.duration_s(), len(mobile.platform.mounts)
        walk = f"the trajectory {source}" if source is not None else "the walk"
        if pulses == 0:
            raise ScannerSettingsError(
                f"{walk} lasts {duration:.3g} s, less than one firing sequence of the {mobile.lidar.name} "
                f"({mobile.lidar.firing_cycle_us:g} us): it fires no pulse; give a longer trajectory")
        if pulses > self.max_walk_pulses:
            raise ScannerSettingsError(
                f"{walk} would fire {pulses:.3g} pulses ({duration:,.0f} s x {lidars} x {mobile.lidar.name} at "
                f"{mobile.lidar.pulse_rate_hz:,.0f} pulses/s), more than the budget of {self.max_walk_pulses:,}; "
                f"check the trajectory's time column (seconds), shorten the walk, or raise the budget "
                f"(--max-walk-pulses; max_walk_pulses in a dataset spec)")
        return pulses

    @cached_property
    def warnings(self) -> tuple[str, ...]:
        """Settings outside the device's limits (allowed unless ``strict``), one line each."""
        if self.mobile is not None:
            return tuple(self.mobile.warnings())
        return tuple(check_settings(self.settings, self.scanner))

    def to_json(self) -> dict[str, Any]:
        """The recipe as JSON-able data (what clouds and units record; the fingerprint's input).

        Every field but ``RUNTIME_FIELDS``, nested settings through their ``to_json`` or as dicts.
        A station file (and a material table) is recorded by its name (a dataset adds its
        checksum), so moving a dataset's folder changes neither fingerprints nor bytes. The sensor
        settings (and the device facts only they use) are recorded when an effect beyond the paper
        is on: a paper scan records exactly what it did before those effects existed.
        """
        document = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name not in RUNTIME_FIELDS:
                document[f.name] = _json_value(value)
        if self.stations_from != AUTO_STATIONS:
            document["stations_from"] = Path(self.stations_from).name
        if self.mobile is None:
            del document["mobile"]  # a tripod recipe records what it did before mobile scans existed
        else:
            for name in ("scanner", "settings", "preset", "stations_from"):
                del document[name]
        if self.sensor.is_paper:
            del document["sensor"]  # paper scans record what they did before the sensor effects existed
            if self.mobile is None:
                document["scanner"] = {k: v for k, v in document["scanner"].items() if k not in SENSOR_DEVICE_FIELDS}
        elif self.sensor.material_table is not None:  # by name and content, as station files
            table = Path(self.sensor.material_table)
            document["sensor"]["material_table"] = {"file": table.name, "sha256": file_sha256(table)}
        return document

    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of ``to_json()``: equal output-deciding settings, equal value."""
        return hashlib.sha256(dump_json(self.to_json())).hexdigest()

    def with_fields(self, **changes: Any) -> ScanRecipe:
        """A copy with fields replaced (validated again)."""
        return dataclasses.replace(self, **changes)


# Fields that change how a scan runs or what it refuses, not its output bytes (left out of the fingerprint).
RUNTIME_FIELDS = tuple(f.name for f in dataclasses.fields(ScanRecipe) if effect_of(ScanRecipe, f.name) == "runtime")


def resolve_sensor(sensor: SensorModel | Mapping[str, Any] | str | Path | None = None, *,
                   realism: str | None = None, where: str = "sensor settings") -> SensorModel:
    """A SensorModel from a model, a table of its keys or a TOML file of them; ``realism`` overrides.
    ``where`` names a table's origin in error messages (a file names itself)."""
    if isinstance(sensor, SensorModel):
        return sensor if realism is None else dataclasses.replace(sensor, realism=realism)
    if isinstance(sensor, str | Path):
        where = str(sensor)
        table: dict[str, Any] = dict(load_toml(sensor))
    else:
        table = dict(sensor or {})
    if realism is not None:
        table["realism"] = realism
    try:
        return build_dataclass(SensorModel, table, where=where)
    except BimscanError as exc:
        raise exc if str(exc).startswith(where) else type(exc)(f"{where}: {exc}") from exc

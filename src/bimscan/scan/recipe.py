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
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from bimscan.files import dump_json
from bimscan.scan.device import (
    DEFAULT_PRESET, DEFAULT_SCANNER, PRESETS, SCANNERS, ScannerModel, ScanSettings, check_settings, load_scanner,
    load_settings, with_overrides,
)
from bimscan.scan.engine import DEFAULT_ENGINE, resolve_engine
from bimscan.scan.noise import NoiseModel
from bimscan.errors import ConfigError, ScannerSettingsError

DEFAULT_CHUNK_PULSES = 1 << 20  # ~70 MB of working arrays per chunk
# The most pulses one station may fire unless the user raises it: the paper's densest preset fires
# 7.5M per station; 500M points are about 15 GB uncompressed, so more is most likely a typo.
DEFAULT_MAX_STATION_PULSES = 500_000_000
AUTO_STATIONS = "auto"
# Fields that change how a scan runs or what it refuses, not its output bytes (left out of the
# fingerprint).
RUNTIME_FIELDS = ("threads", "chunk_pulses", "max_station_pulses")


@dataclass(frozen=True)
class ScanRecipe:
    """How to scan a scene: the device, what each station does, noise, seed, engine, stations.

    scanner: the device model. settings: what one station does; ``preset`` names where they came
    from (a preset name or a settings file's name; None for settings given as a table).
    noise: resolved against the scanner on construction (None sigmas -> its accuracies).
    seed, noise_stream: the noise generator's key is (seed, noise_stream, station); a dataset gives
    every unit its own stream (its id) so that no two units share a noise sequence; "" for a
    single scan. engine: a ``scan.engine.ENGINES`` name, or "auto" (resolved on construction: Warp
    on a CUDA GPU, Open3D otherwise; see ``scan.engine.resolve_engine``). stations_from: "auto" (planned) or a
    station CSV file. strict: settings outside the device's limits are errors. threads (0 = all
    cores) and chunk_pulses change speed and memory only, never the output. max_station_pulses: a
    station that would fire more pulses is refused before any work (with the number it would fire).
    """

    scanner: ScannerModel = field(default_factory=lambda: SCANNERS[DEFAULT_SCANNER])
    settings: ScanSettings = field(default_factory=lambda: PRESETS[DEFAULT_PRESET])
    preset: str | None = DEFAULT_PRESET
    noise: NoiseModel = field(default_factory=NoiseModel)
    seed: int = 0
    noise_stream: str = ""
    engine: str = DEFAULT_ENGINE
    stations_from: str = AUTO_STATIONS
    strict: bool = False
    threads: int = 0
    chunk_pulses: int = DEFAULT_CHUNK_PULSES
    max_station_pulses: int = DEFAULT_MAX_STATION_PULSES

    def __post_init__(self) -> None:
        object.__setattr__(self, "noise", self.noise.resolved(self.scanner))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**64:
            raise ConfigError(f"seed = {self.seed!r} is impossible; give an integer in 0..2^64-1")
        # "auto" becomes the engine this machine runs, so the metadata records the one used
        object.__setattr__(self, "engine", resolve_engine(self.engine))
        if self.threads < 0:
            raise ConfigError(f"threads = {self.threads} is impossible; give 0 (all cores) or more")
        if self.chunk_pulses < 1:
            raise ConfigError(f"chunk_pulses = {self.chunk_pulses} is impossible; give 1 or more")
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
                **fields: Any) -> ScanRecipe:
        """A recipe from what a user wrote: a preset name or settings TOML (or a settings table),
        a scanner name or TOML, a head speed override; ``fields`` are the other ScanRecipe fields.

        Without ``preset`` and ``settings``: the default preset. Raises ConfigError for unknown
        names and missing files, ScannerSettingsError for impossible settings.
        """
        if preset is not None and settings is not None:
            raise ConfigError("give a preset or explicit settings, not both")
        model = scanner if isinstance(scanner, ScannerModel) else load_scanner(scanner)
        if settings is None:
            preset = DEFAULT_PRESET if preset is None else preset
            settings = load_settings(preset)
            name: str | None = preset if isinstance(preset, str) and preset in PRESETS else Path(preset).name
        else:
            name = None
        settings = with_overrides(settings, head_deg_per_s=head_deg_per_s)
        return ScanRecipe(scanner=model, settings=settings, preset=name, **fields)

    @cached_property
    def warnings(self) -> tuple[str, ...]:
        """Settings outside the device's limits (allowed unless ``strict``), one line each."""
        return tuple(check_settings(self.settings, self.scanner))

    def to_json(self) -> dict[str, Any]:
        """The recipe as JSON-able data (what clouds and units record; the fingerprint's input).

        Every field but ``RUNTIME_FIELDS``, nested settings as dicts. A station file is recorded
        by its name (a dataset adds its checksum), so moving a dataset's folder changes neither
        fingerprints nor bytes.
        """
        document = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name not in RUNTIME_FIELDS:
                document[f.name] = dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
        if self.stations_from != AUTO_STATIONS:
            document["stations_from"] = Path(self.stations_from).name
        return document

    def fingerprint(self) -> str:
        """SHA-256 of the canonical JSON of ``to_json()``: equal output-deciding settings, equal value."""
        return hashlib.sha256(dump_json(self.to_json())).hexdigest()

    def with_fields(self, **changes: Any) -> ScanRecipe:
        """A copy with fields replaced (validated again)."""
        return dataclasses.replace(self, **changes)

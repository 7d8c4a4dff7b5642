"""Scanner models (device definitions as data) and scan settings (what one station does).

``SCANNER_TABLES`` holds the TOML files of ``scan/scanners``, read once: the rotating-mirror TLS
among them are ``SCANNERS`` (a name -> ``ScannerModel``), those of ``kind = "multibeam"`` the
multi-beam lidars of ``bimscan.scan.multibeam.LIDARS``. Users pass their own file with
``load_scanner(path)``. ``PRESETS`` are the paper's six configurations (``presets.toml``). ``check_settings`` separates nonsense (an error naming the
parameter and its allowed range) from settings outside the device's limits (a warning, or an
error under ``strict``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from bimscan.toml_files import build_dataclass, load_named, read_package_tables
from bimscan.errors import ConfigError, ScannerSettingsError
from bimscan.constraints import Checked, Range, setting
from bimscan.scan.noise import MAX_ANGLE_SIGMA_DEG, MAX_RANGE_SIGMA_M


# What a number of a device or of a station's settings can be at all (beyond: nonsense, refused);
# a device's own limits (its pulse rates, line rates, head speed) only warn (``check_settings``).
PULSE_RATE_HZ = Range(0.0, 1e8, low_open=True)
LINE_RATE_HZ = Range(0.0, 1e5, low_open=True)
MAX_HEAD_DEG_PER_S = 3600.0  # ten turns a second: no tripod head turns faster
HEAD_SPEED_DEG_PER_S = Range(0.0, MAX_HEAD_DEG_PER_S, low_open=True)
ELEVATION_DEG = Range(-90.0, 90.0)


@dataclass(frozen=True)
class ScannerModel(Checked):
    """A rotating-mirror terrestrial laser scanner.

    The polygon mirror sweeps ``mirror_sweep_deg`` per line (centred on the horizon) at the line
    rate; pulses are emitted only while the beam is inside [elevation_min_deg, elevation_max_deg).
    The head turns about the vertical axis. The beam leaves ``tripod_height_m +
    beam_origin_height_m`` above the floor.

    Facts the sensor effects use (``bimscan.scan.sensor``; a paper scan ignores them):
    ``beam_divergence_rad`` is the full angle (footprint diameter = range x divergence);
    ``pulse_length_ns`` sets the range resolution (c * pulse length / 2: echoes closer than that
    merge); ``wavelength_nm`` says which reflectance the material table must hold; the datasheet's
    maximum range ``reach_range_m[i]`` for flat targets of reflectance ``reach_reflectance[i]``
    at normal incidence and pulse rate ``reach_pulse_freq_hz`` calibrates the detection model.
    """

    name: str
    description: str = ""
    range_accuracy_m: float = setting(0.005, within=Range(0.0, MAX_RANGE_SIGMA_M))
    angle_accuracy_deg: float = setting(0.03, within=Range(0.0, MAX_ANGLE_SIGMA_DEG))
    beam_divergence_rad: float = setting(0.0003, within=Range(0.0, 0.1))
    pulse_freqs_hz: tuple[float, ...] = setting((), each=PULSE_RATE_HZ)
    min_range_m: float = setting(1.5, within=Range(0.0, 1e5))
    max_range_m: float = setting(600.0, within=Range(0.0, 1e5, low_open=True))
    mirror_sweep_deg: float = setting(240.0, within=Range(0.0, 360.0, low_open=True))
    elevation_min_deg: float = setting(-40.0, within=Range(-180.0, 180.0))
    elevation_max_deg: float = setting(60.0, within=Range(-180.0, 180.0))
    scan_freq_min_hz: float = setting(3.0, within=LINE_RATE_HZ)
    scan_freq_max_hz: float = setting(120.0, within=LINE_RATE_HZ)
    head_deg_per_s_max: float = setting(60.0, within=HEAD_SPEED_DEG_PER_S)
    tripod_height_m: float = setting(1.5, within=Range(0.0, 100.0))
    beam_origin_height_m: float = setting(0.2, within=Range(0.0, 10.0))
    wavelength_nm: float = setting(1550.0, within=Range(0.0, 1e5, low_open=True))
    pulse_length_ns: float = setting(5.0, within=Range(0.0, 1e6, low_open=True))
    reach_reflectance: tuple[float, ...] = setting((0.9, 0.2), each=Range(0.0, 1.0, low_open=True))
    reach_range_m: tuple[float, ...] = setting((600.0, 280.0), each=Range(0.0, 1e5, low_open=True))
    reach_pulse_freq_hz: float = setting(100000.0, within=PULSE_RATE_HZ)

    def check(self) -> None:
        if not self.reach_reflectance or len(self.reach_reflectance) != len(self.reach_range_m):
            raise self.refusal(f"reach_reflectance and reach_range_m must be lists of the same length >= 1, got "
                               f"{list(self.reach_reflectance)} and {list(self.reach_range_m)}")
        if self.scan_freq_min_hz > self.scan_freq_max_hz:
            raise self.refusal(f"need scan_freq_min_hz <= scan_freq_max_hz, got {self.scan_freq_min_hz} and "
                               f"{self.scan_freq_max_hz}")
        half = self.mirror_sweep_deg / 2
        if not -half <= self.elevation_min_deg < self.elevation_max_deg <= half:
            raise self.refusal(
                f"the elevation window [{self.elevation_min_deg}, {self.elevation_max_deg}) must be non-empty "
                f"and inside the mirror sweep [-{half}, {half}]")
        if not self.min_range_m < self.max_range_m:
            raise self.refusal(f"need min_range_m < max_range_m, got {self.min_range_m} and {self.max_range_m}")

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(f"scanner {self.name!r}: {problem}; fix the scanner file")

    @property
    def instrument_height_m(self) -> float:
        """Height of the beam origin above the floor the tripod stands on."""
        return self.tripod_height_m + self.beam_origin_height_m

    @property
    def range_resolution_m(self) -> float:
        """Echoes closer than this along the beam merge into one return: c * pulse length / 2."""
        return SPEED_OF_LIGHT_M_PER_NS * self.pulse_length_ns / 2.0

    def reach_constant(self) -> float:
        """K in the datasheet's reach law rho / R_max^2 = K (at ``reach_pulse_freq_hz``): the geometric
        mean of rho_i / R_i^2 over the datasheet's points (per square metre)."""
        logs = [math.log(r / m**2) for r, m in zip(self.reach_reflectance, self.reach_range_m, strict=True)]
        return math.exp(sum(logs) / len(logs))


SPEED_OF_LIGHT_M_PER_NS = 0.299792458
# Facts only the sensor effects use: a paper scan's recorded recipe leaves them out, so its
# metadata (and the fingerprints of datasets built before they existed) stay as they were.
SENSOR_DEVICE_FIELDS = ("wavelength_nm", "pulse_length_ns", "reach_reflectance", "reach_range_m", "reach_pulse_freq_hz")


@dataclass(frozen=True)
class ScanSettings(Checked):
    """What one station does: pulse rate, line rate, head rotation, elevation window.

    ``elevation_min_deg``/``elevation_max_deg`` default to the scanner's window. ``head_start_deg``
    and ``head_stop_deg`` bound the head rotation (a full 360 degree station by default). Each
    number is checked on construction, wherever it comes from (a preset, a settings file or table,
    ``--head-speed``, ``bimscan demo``); what depends on the scanner (the window inside its mirror
    sweep, at least one pulse per line, its limits) is ``check_settings``'.
    """

    pulse_freq_hz: float = setting(within=PULSE_RATE_HZ, hint="pulses per second")
    scan_freq_hz: float = setting(within=LINE_RATE_HZ, hint="mirror lines per second")
    head_deg_per_s: float = setting(within=HEAD_SPEED_DEG_PER_S, hint="degrees per second")
    head_start_deg: float = setting(0.0, within=Range())
    head_stop_deg: float = setting(360.0, within=Range())
    elevation_min_deg: float | None = setting(None, within=ELEVATION_DEG)
    elevation_max_deg: float | None = setting(None, within=ELEVATION_DEG)

    def check(self) -> None:
        if not 0 < self.head_stop_deg - self.head_start_deg <= 360:
            raise self.refusal(f"head_start_deg = {self.head_start_deg:g} and head_stop_deg = {self.head_stop_deg:g} "
                               "are impossible; allowed: head_start_deg < head_stop_deg <= head_start_deg + 360")
        low, high = self.elevation_min_deg, self.elevation_max_deg
        if low is not None and high is not None and not low < high:
            raise self.refusal(f"elevation window [{low:g}, {high:g}) is empty; allowed: elevation_min_deg < "
                               "elevation_max_deg")

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(problem)

    @staticmethod
    def from_resolution(*, pulse_freq_hz: float, vertical_resolution_deg: float,
                        horizontal_resolution_deg: float, scanner: ScannerModel) -> ScanSettings:
        """Settings from angular resolutions, converted as HELIOS++ does.

        line rate = pulse rate * vertical resolution / mirror sweep;
        head speed = horizontal resolution * line rate.
        """
        if not (vertical_resolution_deg > 0 and horizontal_resolution_deg > 0):  # (the rates: the settings' own)
            raise ScannerSettingsError(
                "vertical_resolution_deg and horizontal_resolution_deg must be > 0, got "
                f"{vertical_resolution_deg}, {horizontal_resolution_deg}")
        scan_freq = pulse_freq_hz * vertical_resolution_deg / scanner.mirror_sweep_deg
        return ScanSettings(pulse_freq_hz=pulse_freq_hz, scan_freq_hz=scan_freq,
                            head_deg_per_s=horizontal_resolution_deg * scan_freq)

    def window(self, scanner: ScannerModel) -> tuple[float, float]:
        """The emitting elevation window in degrees."""
        low = scanner.elevation_min_deg if self.elevation_min_deg is None else self.elevation_min_deg
        high = scanner.elevation_max_deg if self.elevation_max_deg is None else self.elevation_max_deg
        return low, high

    def vertical_step_deg(self, scanner: ScannerModel) -> float:
        """Elevation step between consecutive pulses of one line."""
        return scanner.mirror_sweep_deg * self.scan_freq_hz / self.pulse_freq_hz

    def horizontal_step_deg(self) -> float:
        """Azimuth step between consecutive lines."""
        return self.head_deg_per_s / self.scan_freq_hz

    def duration_s(self) -> float:
        """Seconds one station takes."""
        return (self.head_stop_deg - self.head_start_deg) / self.head_deg_per_s

    def expected_pulses(self, scanner: ScannerModel) -> float:
        """pulse_freq * duration * window / sweep: the emitted pulse count of one station."""
        low, high = self.window(scanner)
        return self.pulse_freq_hz * self.duration_s() * (high - low) / scanner.mirror_sweep_deg


MULTIBEAM_KIND = "multibeam"  # the ``kind`` of a scanner file that describes a multi-beam lidar
RISLEY_KIND = "risley"  # ... and of one that describes a Risley-prism lidar (``bimscan.scan.risley``)
MOBILE_KINDS = (MULTIBEAM_KIND, RISLEY_KIND)  # the lidars a mobile platform carries
SCANNER_TABLES: dict[str, dict[str, Any]] = read_package_tables("bimscan.scan", "scanners")
SCANNERS: dict[str, ScannerModel] = {
    name: build_dataclass(ScannerModel, table, where=f"built-in scanner {name}")
    for name, table in SCANNER_TABLES.items() if table.get("kind") not in MOBILE_KINDS
}

DEFAULT_SCANNER = "riegl_vz400"
_LIDAR_KINDS = {MULTIBEAM_KIND: "multi-beam lidar", RISLEY_KIND: "Risley-prism lidar"}
_PLATFORMS_OF = {MULTIBEAM_KIND: "handheld or backpack", RISLEY_KIND: "drone, handheld or backpack"}
DEFAULT_PRESET = "exp3"


def load_scanner(source: str | Path | None = None) -> ScannerModel:
    """A scanner by registry name, or from a TOML file (same keys as scanners/riegl_vz400.toml)."""
    if source is None:
        return SCANNERS[DEFAULT_SCANNER]
    kind = SCANNER_TABLES.get(source, {}).get("kind") if isinstance(source, str) and source not in SCANNERS else None
    if kind in MOBILE_KINDS:
        raise ConfigError(f"scanner {source!r} is a {_LIDAR_KINDS[kind]} for mobile scanning; use it with --platform "
                          f"{_PLATFORMS_OF[kind]}, or pick a TLS scanner for the tripod: " + ", ".join(SCANNERS))
    return load_named(source, SCANNERS, kind="scanner", read=_read_scanner_file)


def _read_scanner_file(table: dict[str, Any], path: Path) -> ScannerModel:
    kind = table.get("kind")
    if kind in MOBILE_KINDS:
        raise ConfigError(f"{path}: a {_LIDAR_KINDS[kind]} for mobile scanning; use it with --platform "
                          f"{_PLATFORMS_OF[kind]}, or pass a TLS scanner file for the tripod")
    return build_dataclass(ScannerModel, table, where=str(path))


PRESETS: dict[str, ScanSettings] = {
    name: build_dataclass(ScanSettings, table, where=f"presets.toml [{name}]")
    for name, table in read_package_tables("bimscan.scan", "presets.toml").items()
}


def load_settings(preset: str | Path) -> ScanSettings:
    """Settings by preset name (exp1..exp6) or from a TOML file with the ScanSettings keys."""
    return load_named(preset, PRESETS, kind="preset", file="a settings TOML file (pulse_freq_hz, scan_freq_hz, "
                                                           "head_deg_per_s)",
                      read=lambda table, path: build_dataclass(ScanSettings, table, where=str(path)))


def check_settings(settings: ScanSettings, scanner: ScannerModel, *, strict: bool = False) -> list[str]:
    """Validate settings against physics and the device.

    Raises ScannerSettingsError for values impossible with this scanner (naming the parameter and
    its allowed range; each number alone was checked when ``settings`` was made). Returns warnings
    for values outside the device's limits; under ``strict`` those raise instead.
    """
    low, high = settings.window(scanner)
    half = scanner.mirror_sweep_deg / 2
    if not max(-half, -90.0) <= low < high <= min(half, 90.0):
        raise ScannerSettingsError(
            f"elevation window [{low:g}, {high:g}) is impossible; allowed: a non-empty window inside the mirror sweep "
            f"[-{half:g}, {half:g}] of {scanner.name} and within -90..90 degrees")
    pulses_per_line = settings.pulse_freq_hz / settings.scan_freq_hz * (high - low) / scanner.mirror_sweep_deg
    if pulses_per_line < 1:
        raise ScannerSettingsError(
            f"scan_freq_hz = {settings.scan_freq_hz:g} with pulse_freq_hz = {settings.pulse_freq_hz:g} leaves "
            f"{pulses_per_line:.2f} pulses per line; allowed: scan_freq_hz <= "
            f"{settings.pulse_freq_hz * (high - low) / scanner.mirror_sweep_deg:g}")
    warnings = []
    if scanner.pulse_freqs_hz and settings.pulse_freq_hz not in scanner.pulse_freqs_hz:
        warnings.append(f"pulse_freq_hz = {settings.pulse_freq_hz:g} is not a pulse rate of {scanner.name} "
                        f"({', '.join(f'{f:g}' for f in scanner.pulse_freqs_hz)} Hz)")
    if not scanner.scan_freq_min_hz <= settings.scan_freq_hz <= scanner.scan_freq_max_hz:
        warnings.append(f"scan_freq_hz = {settings.scan_freq_hz:g} is outside {scanner.name}'s line rates "
                        f"{scanner.scan_freq_min_hz:g}..{scanner.scan_freq_max_hz:g} Hz")
    if settings.head_deg_per_s > scanner.head_deg_per_s_max:
        warnings.append(f"head_deg_per_s = {settings.head_deg_per_s:g} exceeds {scanner.name}'s "
                        f"{scanner.head_deg_per_s_max:g} deg/s")
    if (settings.elevation_min_deg is not None and settings.elevation_min_deg < scanner.elevation_min_deg) or (
            settings.elevation_max_deg is not None and settings.elevation_max_deg > scanner.elevation_max_deg):
        warnings.append(f"elevation window [{low:g}, {high:g}) exceeds {scanner.name}'s "
                        f"[{scanner.elevation_min_deg:g}, {scanner.elevation_max_deg:g})")
    if warnings and strict:
        raise ScannerSettingsError("outside the device's limits (--strict): " + "; ".join(warnings))
    return warnings


def with_overrides(settings: ScanSettings, **overrides: float | None) -> ScanSettings:
    """A copy with the given fields replaced (None values ignored)."""
    return replace(settings, **{k: v for k, v in overrides.items() if v is not None})

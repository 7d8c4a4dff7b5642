"""Scanner definitions, presets and the validation of scan settings."""

from __future__ import annotations

import re
from dataclasses import replace

import pytest

from bimscan.errors import ConfigError, ScannerSettingsError
from bimscan.scan.device import PRESETS, SCANNERS, ScanSettings, check_settings, load_scanner, load_settings

VZ400 = SCANNERS["riegl_vz400"]


def test_the_vz400_has_the_helios_figures():
    assert VZ400.range_accuracy_m == 0.005
    assert VZ400.beam_divergence_rad == 0.0003
    assert VZ400.pulse_freqs_hz == (100000.0, 300000.0)
    assert VZ400.min_range_m == 1.5
    assert (VZ400.mirror_sweep_deg, VZ400.elevation_min_deg, VZ400.elevation_max_deg) == (240.0, -40.0, 60.0)
    assert (VZ400.scan_freq_min_hz, VZ400.scan_freq_max_hz, VZ400.head_deg_per_s_max) == (3.0, 120.0, 60.0)
    assert VZ400.instrument_height_m == pytest.approx(1.7)


def test_presets_are_the_papers_table_1():
    table = {name: (p.pulse_freq_hz, p.scan_freq_hz) for name, p in PRESETS.items()}
    assert table == {
        "exp1": (50000, 240), "exp2": (50000, 360), "exp3": (100000, 240),
        "exp4": (100000, 360), "exp5": (500000, 240), "exp6": (500000, 360),
    }
    assert len({p.head_deg_per_s for p in PRESETS.values()}) == 1, "one documented head speed for all presets"


def test_every_preset_runs_with_warnings_and_fails_under_strict():
    for name, preset in PRESETS.items():
        warnings = check_settings(preset, VZ400)
        assert any("line rates" in w for w in warnings), name
        with pytest.raises(ScannerSettingsError, match="outside the device's limits"):
            check_settings(preset, VZ400, strict=True)


def test_settings_within_the_device_give_no_warning():
    assert check_settings(ScanSettings(pulse_freq_hz=300000, scan_freq_hz=120, head_deg_per_s=60), VZ400, strict=True) == []


@pytest.mark.parametrize("changes, message", [
    ({"pulse_freq_hz": 0}, "pulse_freq_hz must be a number in (0, 1e+08] (pulses per second), got 0"),
    ({"pulse_freq_hz": -5}, "pulse_freq_hz must be a number in (0, 1e+08] (pulses per second), got -5"),
    ({"scan_freq_hz": 0}, "scan_freq_hz must be a number in (0, 100000] (mirror lines per second), got 0"),
    ({"head_deg_per_s": 0}, "head_deg_per_s must be a number in (0, 3600] (degrees per second), got 0"),
    ({"head_deg_per_s": float("nan")}, "head_deg_per_s must be a number in (0, 3600] (degrees per second), got nan"),
    ({"head_deg_per_s": 1e9}, "head_deg_per_s must be a number in (0, 3600] (degrees per second), got 1e+09"),
    ({"elevation_min_deg": 10, "elevation_max_deg": 10}, "elevation window [10, 10) is empty; allowed: "),
    ({"elevation_min_deg": -130}, "elevation_min_deg must be a number in [-90, 90], got -130"),
    ({"head_start_deg": 90, "head_stop_deg": 45}, "head_start_deg = 90 and head_stop_deg = 45 are impossible; allowed"),
])
def test_nonsense_settings_are_refused_on_construction_naming_the_parameter_and_the_allowed_range(changes, message):
    base = dict(pulse_freq_hz=100000, scan_freq_hz=100, head_deg_per_s=30)
    with pytest.raises(ScannerSettingsError) as info:
        ScanSettings(**(base | changes))
    assert str(info.value) == message or str(info.value).startswith(message)


NARROW = replace(VZ400, mirror_sweep_deg=90.0, elevation_min_deg=-40.0, elevation_max_deg=40.0)


@pytest.mark.parametrize("changes, message", [
    ({"scan_freq_hz": 90000}, "pulses per line; allowed"),
    ({"elevation_min_deg": -50}, "elevation window [-50, 40) is impossible; allowed: a non-empty window inside the "
                                 "mirror sweep [-45, 45]"),
])
def test_settings_impossible_with_the_scanner_name_the_parameter_and_the_allowed_range(changes, message):
    base = dict(pulse_freq_hz=100000, scan_freq_hz=100, head_deg_per_s=30)
    with pytest.raises(ScannerSettingsError, match=re.escape(message)):
        check_settings(ScanSettings(**(base | changes)), NARROW)


def test_angular_resolutions_convert_as_helios_does():
    settings = ScanSettings.from_resolution(pulse_freq_hz=300000, vertical_resolution_deg=0.04,
                                            horizontal_resolution_deg=0.04, scanner=VZ400)
    # HELIOS++: scan_freq = pulse_freq * vres / (2 * scanAngleMax) with scanAngleMax = 120 deg
    assert settings.scan_freq_hz == pytest.approx(300000 * 0.04 / 240)
    assert settings.head_deg_per_s == pytest.approx(0.04 * 50)
    assert settings.vertical_step_deg(VZ400) == pytest.approx(0.04)
    assert settings.horizontal_step_deg() == pytest.approx(0.04)


def test_user_scanner_and_settings_files(tmp_path):
    scanner_file = tmp_path / "my.toml"
    scanner_file.write_text('name = "mine"\npulse_freqs_hz = [200000]\nmirror_sweep_deg = 360\n'
                            'elevation_min_deg = -60\nelevation_max_deg = 90\n')
    mine = load_scanner(scanner_file)
    assert (mine.name, mine.mirror_sweep_deg, mine.elevation_max_deg) == ("mine", 360.0, 90.0)
    settings_file = tmp_path / "s.toml"
    settings_file.write_text("pulse_freq_hz = 200000\nscan_freq_hz = 50\nhead_deg_per_s = 20\n")
    assert load_settings(settings_file).pulse_freq_hz == 200000
    bad = tmp_path / "bad.toml"
    bad.write_text("pulse_freq_hz = 1\nscan_freq_hz = 1\nhead_deg_per_s = 1\nspeed = 3\n")
    with pytest.raises(ConfigError, match="unknown key"):
        load_settings(bad)
    with pytest.raises(ConfigError, match="neither a file nor a known preset"):
        load_settings("exp9")
    with pytest.raises(ConfigError, match="neither a file nor a known scanner"):
        load_scanner("riegl_vz9000")

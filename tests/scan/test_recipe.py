"""The scan recipe: one typed value resolved once; the scanner file drives the noise; units get
their own noise streams; the fingerprint follows what decides the output."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.errors import ConfigError, ScannerSettingsError
from bimscan.files import dump_json
from bimscan.io import read_cloud, read_cloud_header
from bimscan.pipeline import load_scene, scan_model
from bimscan.scan.device import PRESETS, SCANNERS, ScanSettings, load_scanner
from bimscan.scan.kernels import noise_key
from bimscan.scan.noise import NoiseModel
from bimscan.survey.recipe import ScanRecipe
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.types import PointCloud, Station

VZ400 = SCANNERS["riegl_vz400"]
SETTINGS = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36)
CENTRE = Station(id=0, position=(4.0, 3.0, 1.7))


def scanner_file(folder, **accuracies) -> str:
    lines = ['name = "custom"'] + [f"{key} = {value!r}" for key, value in accuracies.items()]
    path = folder / "custom.toml"
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def test_resolving_names_gives_the_objects_and_records_where_the_settings_came_from(tmp_path):
    recipe = ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, seed=3)
    assert recipe.scanner == VZ400 and recipe.preset == "exp1"
    assert recipe.settings == dataclasses.replace(PRESETS["exp1"], head_deg_per_s=60.0)
    assert ScanRecipe.resolve().preset == "exp3" and ScanRecipe().settings == PRESETS["exp3"]
    settings_file = tmp_path / "mine.toml"
    settings_file.write_text("pulse_freq_hz = 100000\nscan_freq_hz = 50\nhead_deg_per_s = 20\n")
    assert ScanRecipe.resolve(preset=str(settings_file)).preset == "mine.toml"
    assert ScanRecipe.resolve(settings=SETTINGS).preset is None
    with pytest.raises(ConfigError, match="not both"):
        ScanRecipe.resolve(preset="exp1", settings=SETTINGS)
    with pytest.raises(ScannerSettingsError, match="outside the device's limits"):
        ScanRecipe.resolve(preset="exp1", strict=True)
    assert any("scan_freq_hz = 240" in w for w in ScanRecipe.resolve(preset="exp1").warnings)
    with pytest.raises(ConfigError, match="unknown ray engine"):
        ScanRecipe(engine="optix")


def test_unset_noise_sigmas_are_the_scanner_files_accuracies(tmp_path):
    custom = load_scanner(scanner_file(tmp_path, range_accuracy_m=0.02, angle_accuracy_deg=0.1))
    recipe = ScanRecipe.resolve(scanner=custom)
    assert recipe.noise.range_sigma_m == 0.02 and recipe.noise.angle_sigma_deg == 0.1
    assert ScanRecipe.resolve(scanner=custom, noise=NoiseModel(range_sigma_m=0.001)).noise.range_sigma_m == 0.001
    assert ScanRecipe.resolve().noise == NoiseModel(range_sigma_m=0.005, angle_sigma_deg=0.03)
    for bad in ({"range_accuracy_m": -0.01}, {"angle_accuracy_deg": float("nan")}, {"angle_accuracy_deg": 30.0}):
        with pytest.raises(ScannerSettingsError, match=next(iter(bad))):
            load_scanner(scanner_file(tmp_path, **bad))


def test_a_custom_scanner_file_changes_the_range_noise_of_a_scan(box_room_ifc, tmp_path):
    scene = load_scene(box_room_ifc)
    custom = load_scanner(scanner_file(tmp_path, range_accuracy_m=0.02, angle_accuracy_deg=0.0))
    scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=custom)

    def scan(recipe: ScanRecipe) -> PointCloud:
        return PointCloud.concatenate(list(scanner.scan_station(CENTRE, recipe)))

    exact = scan(ScanRecipe(scanner=custom, settings=SETTINGS, preset=None, noise=NoiseModel.off()))
    noisy = scan(ScanRecipe(scanner=custom, settings=SETTINGS, preset=None, seed=2))
    origin = np.array(CENTRE.position)
    error = np.linalg.norm(noisy.xyz - origin, axis=1) - np.linalg.norm(exact.xyz - origin, axis=1)
    assert error.std() == pytest.approx(0.02, rel=0.02)


def test_noise_streams_separate_units_and_a_single_scan_keeps_its_key(box_room_ifc):
    assert noise_key(5, 2, "") == noise_key(5, 2) != noise_key(5, 2, "room__exp1") != noise_key(5, 2, "room__exp2")
    scene = load_scene(box_room_ifc)
    scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=VZ400)
    base = ScanRecipe(settings=SETTINGS, preset=None, seed=1)
    clouds = [PointCloud.concatenate(list(scanner.scan_station(CENTRE, base.with_fields(noise_stream=stream))))
              for stream in ("a__x", "a__y", "a__x")]
    assert np.array_equal(clouds[0].xyz, clouds[2].xyz) and not np.allclose(clouds[0].xyz, clouds[1].xyz)
    assert np.array_equal(clouds[0].time, clouds[1].time)  # same pulses, other noise


def test_the_fingerprint_follows_what_decides_the_output_only(tmp_path):
    recipe = ScanRecipe.resolve(preset="exp2", seed=4)
    assert recipe.fingerprint() == recipe.with_fields(threads=1, chunk_pulses=1000).fingerprint()
    for change in ({"seed": 5}, {"noise_stream": "u"}, {"noise": NoiseModel.off()}, {"engine": "embreex"},
                   {"settings": PRESETS["exp3"]}):
        assert recipe.with_fields(**change).fingerprint() != recipe.fingerprint(), change
    stations = tmp_path / "deep" / "st.csv"
    assert recipe.with_fields(stations_from=str(stations)).to_json()["stations_from"] == "st.csv"


def test_a_scan_records_exactly_the_recipe_it_was_made_with(box_room_ifc, tmp_path):
    recipe = ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, seed=9, noise=NoiseModel(range_sigma_m=0.001))
    out = scan_model(box_room_ifc, tmp_path / "room.laz", recipe, progress=False).path
    metadata = read_cloud_header(out).metadata
    recorded = json.loads(dump_json(recipe.to_json()))  # as JSON stores it (tuples become lists)
    assert {key: metadata[key] for key in recorded} == recorded
    assert metadata["device_warnings"] == list(recipe.warnings)


def test_the_scan_command_takes_its_noise_from_a_scanner_file(box_room_ifc, tmp_path):
    path = scanner_file(tmp_path, range_accuracy_m=0.0, angle_accuracy_deg=0.0)
    out = tmp_path / "exact.laz"
    assert main(["scan", str(box_room_ifc), str(out), "--preset", "exp1", "--head-speed", "60", "--scanner", path]) == 0
    header = read_cloud_header(out)
    assert header.metadata["noise"]["range_sigma_m"] == 0.0 and header.metadata["scanner"]["name"] == "custom"
    cloud = read_cloud(out)
    # noise-free: every point on a face of the 8 x 6 x 3.5 m box room (to the LAS 0.1 mm step)
    x, y, z = cloud.xyz.T
    on_face = np.minimum.reduce([np.abs(x - 0.0), np.abs(x - 8.0), np.abs(y - 0.0), np.abs(y - 6.0),
                                 np.abs(z - 0.0), np.abs(z - 3.5)])
    assert on_face.max() < 1e-3


@pytest.mark.parametrize("fields, message", [
    ({"head_deg_per_s": 1e-300}, "would fire inf pulses"),
    ({"head_deg_per_s": 1e-3}, "would fire 1.5e\\+10 pulses, more than the budget"),
    ({"settings": ScanSettings(pulse_freq_hz=1e5, scan_freq_hz=1e-9, head_deg_per_s=10)}, "would sweep 3.6e-08 mirror lines"),
    ({"settings": ScanSettings(pulse_freq_hz=1e5, scan_freq_hz=100, head_deg_per_s=10, head_stop_deg=1e-9)},
     "mirror lines"),
    ({"seed": 2**70}, r"seed must be an integer in 0\.\.18446744073709551615, got 1.18e\+21"),
    ({"seed": -1}, r"seed must be an integer in 0\.\.18446744073709551615, got -1"),
    ({"threads": -1}, r"threads must be an integer >= 0 \(0: all cores\), got -1"),
    ({"chunk_pulses": 0}, "chunk_pulses must be an integer >= 1, got 0"),
])
def test_settings_that_cannot_make_a_sensible_scan_are_refused_before_any_work(fields, message):
    with pytest.raises((ConfigError, ScannerSettingsError), match=message):
        ScanRecipe.resolve(**fields)


def test_a_range_sigma_in_millimetres_by_mistake_is_refused():
    with pytest.raises(ScannerSettingsError, match=r"range_sigma_m must be a number in \[0, 1\], got 5 .*not millimetres"):
        NoiseModel(range_sigma_m=5.0)


def test_a_larger_pulse_budget_admits_a_slow_head():
    recipe = ScanRecipe.resolve(head_deg_per_s=1e-3, max_station_pulses=20_000_000_000)
    assert recipe.settings.expected_pulses(recipe.scanner) == pytest.approx(1.5e10)
    assert recipe.fingerprint() == recipe.with_fields(max_station_pulses=10**11).fingerprint()


@pytest.mark.parametrize("keys, message", [
    ({"scan_freq_min_hz": 200.0}, "scan_freq_min_hz <= scan_freq_max_hz"),
    ({"head_deg_per_s_max": -60.0}, r"head_deg_per_s_max must be a number in \(0, 3600\], got -60"),
    ({"pulse_freqs_hz": [100000, -5]}, r"pulse_freqs_hz takes numbers in \(0, 1e\+08\], got -5"),
    ({"tripod_height_m": -1.5}, r"tripod_height_m must be a number in \[0, 100\], got -1.5"),
])
def test_nonsense_scanner_files_are_refused(tmp_path, keys, message):
    with pytest.raises(ScannerSettingsError, match=message):
        load_scanner(scanner_file(tmp_path, **keys))


def test_an_option_a_scan_would_ignore_is_refused_by_the_rule_the_cli_and_dataset_specs_share(tmp_path):
    walk = tmp_path / "walk.csv"
    walk.write_text("t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n3,5,3,0,0,0,0\n")
    stations = tmp_path / "st.csv"
    stations.write_text("x,y,height\n4,3,1.7\n")
    for fields, named in (({"preset": "exp1"}, "no TLS 'preset'"), ({"settings": SETTINGS}, "'settings'"),
                          ({"head_deg_per_s": 60.0}, r"'head_deg_per_s' \(--head-speed\)"),
                          ({"max_station_pulses": 10**6}, "'max_station_pulses'"),
                          ({"stations_from": str(stations), "trajectory": str(walk)}, "stations from 'st.csv'"),
                          ({"realism": "full", "sensor": {"returns": "all"}}, "returns = 'all'.*mobile scan")):
        with pytest.raises(ConfigError, match=named):
            ScanRecipe.resolve(platform="handheld", **fields)
    with pytest.raises(ConfigError, match="'max_walk_pulses'"):
        ScanRecipe.resolve(max_walk_pulses=10**6)
    with pytest.raises(ConfigError, match="returns = 'all' .acts only with footprint or glass"):
        ScanRecipe.resolve(sensor={"returns": "all"})
    # where they act, they are taken
    assert ScanRecipe.resolve(platform="handheld", stations_from=str(stations)).stations_from == str(stations)
    assert ScanRecipe.resolve(platform="backpack", trajectory=str(walk), max_walk_pulses=10**6).max_walk_pulses == 10**6
    assert ScanRecipe.resolve(max_station_pulses=10**9).max_station_pulses == 10**9
    assert ScanRecipe.resolve(sensor={"returns": "all", "glass": True}).sensor.returns == "all"
    assert ScanRecipe.resolve(realism="full", sensor={"beam_sample_quality": 4}).sensor.beam_sample_quality == 4

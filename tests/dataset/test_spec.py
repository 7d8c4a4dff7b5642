"""Dataset specs: what loads, and one clear error before any work for what does not."""

from __future__ import annotations

from pathlib import Path

import pytest

from bimscan.cli.main import main
from bimscan.dataset.spec import load_spec
from bimscan.errors import ConfigError, InputFileError, ScannerSettingsError

GOOD = """\
name = "two"
seed = 7
formats = ["laz", "ply"]
voxel_size_m = 0.02
[noise]
range_sigma_m = 0.002
[[scenes]]
name = "room"
ifc = "models/room.ifc"
stations = "stations.csv"
[[scenes]]
name = "generated"
generate = { seed = 4, storeys = 3 }
[[configs]]
name = "paper-exp2"
preset = "exp2"
[[configs]]
name = "mine"
settings = { pulse_freq_hz = 300000, scan_freq_hz = 100, head_deg_per_s = 20 }
"""


@pytest.fixture
def spec_folder(tmp_path: Path, box_room_ifc: Path) -> Path:
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "room.ifc").write_bytes(box_room_ifc.read_bytes())
    (tmp_path / "stations.csv").write_text("x,y,height\n4,3,1.7\n")
    return tmp_path


def _write(folder: Path, text: str) -> Path:
    path = folder / "spec.toml"
    path.write_text(text)
    return path


def test_a_spec_loads_with_paths_made_absolute_and_settings_resolved(spec_folder: Path) -> None:
    spec = load_spec(_write(spec_folder, GOOD))
    assert spec.unit_ids() == ["room__paper-exp2", "room__mine", "generated__paper-exp2", "generated__mine"]
    room, generated = spec.scenes
    assert room.ifc == str((spec_folder / "models" / "room.ifc").resolve())
    assert room.stations == str((spec_folder / "stations.csv").resolve())
    assert generated.ifc is None and generated.generate.seed == 4 and generated.generate.storeys == 3
    assert spec.noise.range_sigma_m == 0.002 and spec.noise.angle_sigma_deg is None  # None: the scanner's accuracy
    assert spec.formats == ("laz", "ply") and spec.voxel_size_m == 0.02 and spec.seed == 7
    room_exp2, room_mine = (spec.recipe(room, config) for config in spec.configs)
    assert room_exp2.settings.scan_freq_hz == 360 and room_exp2.preset == "exp2"
    assert room_mine.settings.head_deg_per_s == 20 and room_mine.preset is None
    assert room_exp2.noise.range_sigma_m == 0.002 and room_exp2.noise.angle_sigma_deg == 0.03 and room_exp2.seed == 7
    assert room_exp2.stations_from == room.stations and spec.recipe(generated, spec.configs[0]).stations_from == "auto"


def test_sensor_realism_and_settings_apply_per_configuration_over_the_spec(spec_folder: Path) -> None:
    (spec_folder / "materials.toml").write_text(
        (Path(__import__("bimscan.scan", fromlist=["x"]).__file__).parent / "materials.toml").read_text())
    text = GOOD.replace("voxel_size_m = 0.02", 'voxel_size_m = 0.02\nrealism = "full"')
    text = text.replace("[[scenes]]", '[sensor]\nreturns = "first"\nmaterial_table = "materials.toml"\n[[scenes]]', 1)
    text += 'realism = "paper"\nsensor = { footprint = true, color = true }\n'  # colour reads the material table
    spec = load_spec(_write(spec_folder, text))
    room = spec.scenes[0]
    full, mine = (spec.recipe(room, config).sensor for config in spec.configs)
    assert full.realism == "full" and full.returns == "first" and full.on("glass")
    assert full.material_table == str((spec_folder / "materials.toml").resolve())
    assert mine.realism == "paper" and mine.on("footprint") and not mine.on("glass") and mine.returns == "first"
    assert mine.material_table == full.material_table
    assert spec.recipe(room, spec.configs[0]).to_json()["sensor"]["material_table"]["file"] == "materials.toml"


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t + 'sensor = { footprnt = true }\n', "unknown key(s) 'footprnt'"),
    (lambda t: t + 'realism = "photo"\n', "key 'realism': expected one of 'paper', 'full', got 'photo'"),
    (lambda t: t + 'sensor = { material_table = "nowhere.toml" }\nrealism = "full"\n', "material table"),
])
def test_bad_sensor_settings_are_refused_before_any_work_naming_the_configuration(spec_folder: Path, edit,
                                                                                  message: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_spec(_write(spec_folder, edit(GOOD)))
    assert message in str(caught.value) and "[[configs]] 'mine'" in str(caught.value)


def test_every_unit_of_a_spec_draws_its_own_noise_stream(spec_folder: Path) -> None:
    spec = load_spec(_write(spec_folder, GOOD))
    recipes = [spec.recipe(scene, config) for scene in spec.scenes for config in spec.configs]
    assert [r.noise_stream for r in recipes] == spec.unit_ids()
    assert len({r.fingerprint() for r in recipes}) == len(recipes)


def test_a_scheme_with_a_misspelt_ifc_class_is_refused_before_any_work(spec_folder: Path) -> None:
    from bimscan.errors import SchemeError

    scheme = spec_folder / "scheme.toml"
    scheme.write_text('name = "typo"\ndefault = "b"\n[[classes]]\nid = 0\nname = "a"\n[[classes]]\nid = 1\nname = "b"\n'
                      '[[rules]]\nifc_class = "IfcWal"\nlabel = "a"\n')
    with pytest.raises(SchemeError, match="unknown IFC class 'IfcWal'"):
        load_spec(_write(spec_folder, GOOD.replace('name = "two"', 'name = "two"\nscheme = "scheme.toml"')))


@pytest.mark.parametrize(("edit", "error", "message"), [
    (lambda t: t.replace('name = "two"', 'name = "two"\ncolour = "red"'), ConfigError, "unknown key(s) 'colour'"),
    (lambda t: t.replace('stations = "stations.csv"', 'station = "auto"'), ConfigError, "unknown key(s) 'station'"),
    (lambda t: t.replace("models/room.ifc", "models/missing.ifc"), InputFileError, "IFC file 'models/missing.ifc' not found"),
    (lambda t: t.replace('"exp2"', '"exp9"'), ConfigError, "preset 'exp9' is neither a file nor a known preset"),
    (lambda t: t.replace("head_deg_per_s = 20", "head_deg_per_s = -1"), ScannerSettingsError,
     "[[configs]] #2 key 'settings': head_deg_per_s must be a number in (0, 3600] (degrees per second), got -1"),
    (lambda t: t.replace('preset = "exp2"', 'preset = "exp2"\nhead_deg_per_s = 0.0'), ScannerSettingsError,
     "[[configs]] 'paper-exp2': head_deg_per_s must be a number in (0, 3600] (degrees per second), got 0"),
    (lambda t: t.replace('"laz", "ply"', '"laz", "pcd"'), ConfigError, "unknown output format 'pcd'"),
    (lambda t: t.replace("0.02", "-0.5"), ConfigError,
     "voxel_size_m must be a number > 0 (metres, a voxel's edge; leave it out for no subsampling), got -0.5"),
    (lambda t: t.replace("0.02", "0.0"), ConfigError, "voxel_size_m must be a number > 0"),
    (lambda t: t.replace("0.02", "nan"), ConfigError, "voxel_size_m must be a number > 0"),
    (lambda t: t.replace('name = "mine"', 'name = "paper-exp2"'), ConfigError, "'paper-exp2' used more than once"),
    (lambda t: t.replace('name = "room"', 'name = "my__room"'), ConfigError, "is not usable as a folder name"),
    (lambda t: t.replace('ifc = "models/room.ifc"', 'ifc = "models/room.ifc"\ngenerate = { seed = 1 }'), ConfigError,
     "exactly one of 'ifc'"),
    (lambda t: t.replace("storeys = 3", "storeys = 40"), ConfigError, "storeys must be an integer in"),
    (lambda t: t.replace("storeys = 3", 'storeys = 3, style = "castle"'), ConfigError, "castle"),
    (lambda t: t.replace('stations = "stations.csv"', 'stations = "stations.csv"\nlength_unit = "furlong"'), ConfigError,
     "length_unit takes 'm', 'cm', 'mm', 'ft', 'in', got 'furlong'"),
    (lambda t: t.replace('stations = "stations.csv"', 'stations = "nowhere.csv"'), InputFileError, "station file"),
    (lambda t: t.replace("range_sigma_m = 0.002", "range_sigma_m = -2"), ScannerSettingsError, "range_sigma_m"),
    (lambda t: t.replace('name = "two"', 'name = "two"\nstrict = true'), ScannerSettingsError, "outside the device's limits"),
    (lambda t: t.split("[[configs]]")[0], ConfigError, "no configurations"),
    (lambda t: t.replace('preset = "exp2"', 'preset = "exp2"\nstage = { name = "enclosed", exclude = ["IfcDoors"] }'),
     ConfigError, "unknown IFC class 'IfcDoors' (no IfcProduct class of IFC2X3, IFC4 or IFC4X3); did you mean 'IfcDoor'?"),
    (lambda t: t.replace('name = "two"', 'name = "two"\nstage = { name = "structure", include = ["IfcWall", "IfcFoo"] }'),
     ConfigError, "unknown IFC class 'IfcFoo'"),
])
def test_a_bad_spec_raises_one_clear_error_naming_the_file(spec_folder: Path, edit, error: type, message: str) -> None:
    path = _write(spec_folder, edit(GOOD))
    with pytest.raises(error) as caught:
        load_spec(path)
    assert message in str(caught.value)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_settings_outside_the_device_limits_are_listed_per_configuration(spec_folder: Path) -> None:
    from bimscan.dataset.spec import device_warnings

    warnings = device_warnings(load_spec(_write(spec_folder, GOOD)))
    assert len(warnings) == 2 and all(w.startswith("configuration 'paper-exp2': ") for w in warnings)
    assert any("scan_freq_hz = 360" in w for w in warnings) and any("pulse_freq_hz = 50000" in w for w in warnings)


def test_build_refuses_a_bad_spec_before_any_work(spec_folder: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(spec_folder, GOOD.replace('"exp2"', '"exp9"'))
    out = spec_folder / "out"
    assert main(["build", str(path), str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "exp9" in err[0]
    assert not out.exists()  # nothing was created, let alone parsed or scanned


def test_build_refuses_a_spec_that_is_not_toml(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "spec.toml"
    path.write_text("[[scenes]\nname = ")
    assert main(["build", str(path), str(tmp_path / "out")]) == 1
    assert "not valid TOML" in capsys.readouterr().err


def test_the_shipped_example_specs_load(tmp_path: Path) -> None:
    from bimscan.demo import demo_spec

    root = Path(__file__).resolve().parents[2]
    demo = load_spec(root / "configs" / "datasets" / "demo.toml")
    assert (root / "configs" / "datasets" / "demo.toml").read_text() == demo_spec()  # the demo builds this very file
    assert len(demo.unit_ids()) == 12 and [c.preset for c in demo.configs] == [f"exp{i}" for i in range(1, 7)]
    spc = root / "configs" / "datasets" / "spc.toml"
    if not (root.parent / "shared" / "data" / "ifc" / "duplex.ifc").is_file():
        pytest.skip("the SPC-scale example uses the shared sample models, absent here")
    spec = load_spec(spc)
    assert len(spec.scenes) == 22 and len(spec.unit_ids()) == 132


def test_the_spec_in_the_datasets_guide_loads_as_shown(tmp_path: Path, box_room_ifc: Path) -> None:
    # it showed voxel_size_m = 0.0, which the spec refuses (issue 50): every key and value there must load
    import re

    guide = (Path(__file__).parents[2] / "docs" / "guide" / "datasets.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```toml\n(.*?)```", guide, flags=re.S)
    assert blocks, "the guide shows a spec"
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "duplex.ifc").write_bytes(box_room_ifc.read_bytes())
    for block in blocks:
        spec = load_spec(_write(tmp_path, block))
        assert spec.voxel_size_m is None or spec.voxel_size_m > 0


def test_a_spec_takes_what_it_does_not_set_from_its_base_with_the_base_s_paths(spec_folder: Path) -> None:
    base = _write(spec_folder, GOOD.replace('formats = ["laz", "ply"]', 'formats = ["laz", "ply"]\nclutter = { density = 0.3 }'))
    other = spec_folder / "companions"
    other.mkdir()
    (other / "empty.toml").write_text('base = "../spec.toml"\nname = "empty"\nclutter = { density = 0.0 }\n')
    parent, child = load_spec(base), load_spec(other / "empty.toml")
    assert child.name == "empty" and child.seed == 7 and child.formats == ("laz", "ply")
    assert child.scenes == parent.scenes  # the base's IFC and station files, relative to the base
    assert child.scenes[0].ifc == str((spec_folder / "models" / "room.ifc").resolve())
    assert parent.site(parent.configs[0]).clutter.density == 0.3
    assert child.site(child.configs[0]).clutter.density == 0.0  # a key set here replaces the base's
    (other / "one.toml").write_text('base = "../spec.toml"\n[[scenes]]\nname = "g"\ngenerate = { seed = 1 }\n')
    assert [s.name for s in load_spec(other / "one.toml").scenes] == ["g"]


@pytest.mark.parametrize("text, error, message", [
    ('base = "spec.toml"\n', ConfigError, "names this file itself"),
    ('base = "nowhere.toml"\n', InputFileError, "base not found"),
    ('base = 3\n', ConfigError, "expected the path of another dataset spec"),
    ('base = "middle.toml"\n', ConfigError, "has a base of its own"),
])
def test_a_bad_base_is_one_clear_error(spec_folder: Path, text: str, error: type, message: str) -> None:
    (spec_folder / "root.toml").write_text(GOOD)
    (spec_folder / "middle.toml").write_text('base = "root.toml"\n')
    with pytest.raises(error, match=message):
        load_spec(_write(spec_folder, text))


MOBILE = """\
[[scenes]]
name = "room"
ifc = "models/room.ifc"
trajectory = "walk.csv"
[[configs]]
name = "hh"
platform = "handheld"
"""
WALK = "t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n3,5,3,0,0,0,0\n"


@pytest.mark.parametrize(("walk", "spec_edit", "error", "message"), [
    ("t,x,y,z\n0,2,3,0\n3,5,3,0\n", None, InputFileError, "the header lacks column(s) roll, pitch, yaw"),
    ("t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n3,five,3,0,0,0,0\n", None, InputFileError, "data line 3"),
    ("t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n0,5,3,0,0,0,0\n", None, InputFileError, "time must increase"),
    ("t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n20000,5,3,0,0,0,0\n", None, ScannerSettingsError,
     "with [[configs]] 'hh': the trajectory walk.csv would fire 5.79e+09 pulses"),
    (WALK, lambda t: t.replace('platform = "handheld"', 'preset = "exp1"'), ConfigError,
     "trajectory 'walk.csv' would change nothing: no configuration is mobile"),
    (WALK, lambda t: t.replace('trajectory = "walk.csv"', 'trajectory = "walk.csv"\nstations = "stations.csv"'),
     ConfigError, "stations 'stations.csv' would change nothing: every configuration is mobile"),
])
def test_a_scene_s_trajectory_file_is_checked_when_the_spec_is_read(spec_folder: Path, walk: str, spec_edit, error,
                                                                    message: str) -> None:
    (spec_folder / "walk.csv").write_text(walk)
    path = _write(spec_folder, (spec_edit or (lambda t: t))(MOBILE))
    with pytest.raises(error) as caught:
        load_spec(path)
    assert message in str(caught.value), str(caught.value)
    assert f"{path} [[scenes]] 'room'" in str(caught.value) and "\n" not in str(caught.value)
    assert "walk.csv" in str(caught.value)


def test_a_scene_s_trajectory_and_stations_serve_a_spec_with_tripod_and_mobile_configurations(
        spec_folder: Path) -> None:
    (spec_folder / "walk.csv").write_text("\ufeff" + WALK)  # a byte order mark is no part of the header
    text = MOBILE.replace('trajectory = "walk.csv"', 'trajectory = "walk.csv"\nstations = "stations.csv"')
    text += '[[configs]]\nname = "tls"\npreset = "exp1"\n'  # the stations serve it
    spec = load_spec(_write(spec_folder, text))
    room = spec.scenes[0]
    hh, tls = (spec.recipe(room, config) for config in spec.configs)
    assert tls.stations_from == str(spec_folder / "stations.csv") and hh.mobile.trajectory_from == room.trajectory
    assert hh.max_walk_pulses == spec.max_walk_pulses and tls.max_station_pulses == spec.max_station_pulses
    with pytest.raises(ScannerSettingsError, match=r"'room' with \[\[configs\]\] 'hh'.*budget of 100,000"):
        load_spec(_write(spec_folder, "max_walk_pulses = 100000\n" + text))

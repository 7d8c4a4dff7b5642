"""``bimscan scan`` end to end: IFC in, labelled cloud file out; errors leave nothing behind."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.io import read_cloud, read_cloud_header
from bimscan.pipeline import scan_model
from bimscan.survey.recipe import ScanRecipe

FAST = ["--preset", "exp1", "--head-speed", "60"]


def sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_scan_writes_a_labelled_laz_that_explains_itself(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "room.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--seed", "1"]) == 0
    report = capsys.readouterr()
    assert "points from 1 stations" in report.out
    assert "warning: pulse_freq_hz = 50000 is not a pulse rate" in report.err
    cloud = read_cloud(out)
    header = read_cloud_header(out)
    assert len(cloud) > 50_000
    assert [c.name for c in header.scheme.classes] == ["Wall&Column", "Beam", "Covering", "Slab", "Others"]
    assert np.array_equal(cloud.label, header.components.label[cloud.component])
    assert set(np.unique(cloud.label)) == {0, 3}  # walls and slabs only in the box room
    assert len(header.stations) == 1 and header.metadata["seed"] == 1
    assert header.metadata["settings"]["pulse_freq_hz"] == 50000
    assert not list(tmp_path.glob(".*tmp*"))


def test_same_seed_same_bytes_different_seed_different_bytes(box_room_ifc, tmp_path):
    paths = []
    for name, seed in (("a", 1), ("b", 1), ("c", 2)):
        paths.append(tmp_path / f"{name}.laz")
        assert main(["scan", str(box_room_ifc), str(paths[-1]), *FAST, "--seed", str(seed)]) == 0
    assert sha(paths[0]) == sha(paths[1]) != sha(paths[2])


@pytest.mark.parametrize("suffix", [".laz", ".ply", ""])
def test_output_bytes_do_not_depend_on_chunk_size(box_room_ifc, tmp_path, suffix):
    recipe = ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, seed=4)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = scan_model(box_room_ifc, tmp_path / "a" / f"cloud{suffix}", recipe, progress=False).path
    b = scan_model(box_room_ifc, tmp_path / "b" / f"cloud{suffix}", recipe.with_fields(chunk_pulses=20_000),
                   progress=False).path
    files_a = sorted(p.relative_to(a.parent) for p in a.parent.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b.parent) for p in b.parent.rglob("*") if p.is_file())
    assert files_a == files_b and files_a
    for name in files_a:
        assert sha(a.parent / name) == sha(b.parent / name), name


def test_a_station_file_drives_the_survey(box_room_ifc, tmp_path):
    stations = tmp_path / "st.csv"
    stations.write_text("x,y,height\n2,2,1.7\n6,4,1.7\n")
    out = tmp_path / "two.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--stations", str(stations), "--no-noise"]) == 0
    cloud = read_cloud(out)
    assert set(np.unique(cloud.station)) == {0, 1}


@pytest.mark.parametrize("args, message", [
    (["--preset", "exp9"], "neither a file nor a known preset"),
    (["--strict"], "outside the device's limits"),
    (["--head-speed", "0"], "head_deg_per_s must be a number in (0, 3600] (degrees per second), got 0"),
    (["--range-sigma", "-1"], "range_sigma_m must be a number in [0, 1], got -1"),
    (["--scanner", "nope"], "neither a file nor a known scanner"),
])
def test_bad_settings_fail_with_one_line_and_no_output(box_room_ifc, tmp_path, capsys, args, message):
    out = tmp_path / "x.laz"
    assert main(["scan", str(box_room_ifc), str(out), *args]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ") and message in err[-1]
    assert not out.exists() and list(tmp_path.iterdir()) == []


HEAD_SPEED_SPEC = """\
[[scenes]]
name = "room"
generate = { seed = 1, storeys = 1 }
[[configs]]
name = "fast"
preset = "exp1"
head_deg_per_s = SPEED
"""


@pytest.mark.parametrize("speed", ["0", "-3", "5000", "nan"])
def test_a_head_speed_is_refused_alike_by_scan_plan_export_demo_and_build(speed, tmp_path, capsys):
    # it was checked in three places: ranged for demo only (5000 deg/s scanned, planned and built), with
    # three messages (click's range for demo, 'is impossible' for scan, the spec's own)
    (tmp_path / "spec.toml").write_text(HEAD_SPEED_SPEC.replace("SPEED", speed))
    model, out = tmp_path / "missing.ifc", tmp_path / "out"
    runs = [["scan", str(model), str(tmp_path / "x.laz")], ["plan", str(model), str(out)],
            ["export-obj", str(model), str(out), "--helios"], ["demo", str(out)]]
    expected = f"head_deg_per_s must be a number in (0, 3600] (degrees per second), got {float(speed):g}"
    for args in runs:
        assert main([*args, "--head-speed", speed]) == 1, args
        assert capsys.readouterr().err.splitlines() == [f"error: {expected}"], args
    assert main(["build", str(tmp_path / "spec.toml"), str(out)]) == 1
    assert capsys.readouterr().err.splitlines()[-1].endswith(f"[[configs]] 'fast': {expected}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.toml"]  # refused before anything was made


def test_a_station_inside_a_wall_fails_clearly(box_room_ifc, tmp_path, capsys):
    stations = tmp_path / "st.csv"
    stations.write_text("x,y,z\n8.1,3,1.7\n")
    assert main(["scan", str(box_room_ifc), str(tmp_path / "x.laz"), *FAST, "--stations", str(stations)]) == 1
    assert "inside a solid (IfcWall" in capsys.readouterr().err
    assert not (tmp_path / "x.laz").exists()


def test_an_interrupted_scan_leaves_no_file(box_room_ifc, tmp_path, monkeypatch):
    import bimscan.pipeline as pipeline

    real = pipeline.run_survey

    def interrupted(*args, **kwargs):
        for i, chunk in enumerate(real(*args, **kwargs)):
            if i == 1:
                raise KeyboardInterrupt
            yield chunk

    monkeypatch.setattr(pipeline, "run_survey", interrupted)
    out = tmp_path / "cut.laz"
    with pytest.raises(KeyboardInterrupt):
        scan_model(box_room_ifc, out, ScanRecipe.resolve(head_deg_per_s=60.0, chunk_pulses=20_000), progress=False)
    assert list(tmp_path.iterdir()) == []


def test_an_existing_output_is_kept_unless_overwrite(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "keep.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--seed", "1"]) == 0
    first = out.read_bytes()
    capsys.readouterr()
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--seed", "2"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {out} already exists; pass --overwrite to replace it or choose another path"]
    assert "overwrite=True" not in err[0]
    assert out.read_bytes() == first
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--seed", "2", "--overwrite"]) == 0
    assert out.read_bytes() != first and len(read_cloud(out)) > 50_000


def test_overwrite_never_replaces_a_file_that_is_not_a_cloud_of_its_suffix(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "keep.laz"
    out.write_bytes(b"precious")  # a user's file that happens to be named like a cloud
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--overwrite"]) == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        f"error: {out} is a file not in the format of a .laz file; bimscan replaces only what it wrote: choose another "
        "output or remove it yourself"]
    assert out.read_bytes() == b"precious" and sorted(p.name for p in tmp_path.iterdir()) == ["keep.laz"]


@pytest.mark.parametrize("name", ["mydata", "x.laz"])
def test_overwrite_refuses_a_users_folder_before_the_scan_and_keeps_all_of_it(box_room_ifc, tmp_path, capsys,
                                                                              monkeypatch, name):
    import bimscan.pipeline

    def no_scan(*args, **kwargs):
        raise AssertionError("the model was loaded: the output should have been refused first")

    monkeypatch.setattr(bimscan.pipeline, "load_scene", no_scan)
    folder = tmp_path / name
    (folder / "sub").mkdir(parents=True)
    (folder / "sub" / "data.csv").write_text("1,2,3\n")
    (folder / "thesis.txt").write_text("three years of work")
    assert main(["scan", str(box_room_ifc), str(folder), *FAST, "--overwrite"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {folder} is a folder") and "(it holds sub/, thesis.txt)" in err[0]
    assert err[0].endswith("bimscan replaces only what it wrote: choose another output or remove it yourself")
    assert (folder / "thesis.txt").read_text() == "three years of work"
    assert (folder / "sub" / "data.csv").read_text() == "1,2,3\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]


@pytest.mark.parametrize("out", [".", "..", "/", "./"])
def test_an_output_that_names_a_folder_is_refused_before_the_scan(box_room_ifc, tmp_path, capsys, monkeypatch, out):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["scan", str(box_room_ifc), out, *FAST, "--overwrite"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "names a folder" in err[0] and "give the output a name of its own" in err[0]
    assert list(work.iterdir()) == []


def test_a_mobile_scan_refuses_a_folder_where_its_trajectory_goes(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "walk.laz"
    beside = tmp_path / "walk.laz.trajectory.csv"
    beside.mkdir()
    (beside / "mine.txt").write_text("x")
    assert main(["scan", str(box_room_ifc), str(out), "--platform", "handheld", "--overwrite"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {beside} is a folder, not a .csv file (it holds mine.txt); bimscan replaces only what it "
                   "wrote: choose another output or remove it yourself"]
    assert (beside / "mine.txt").read_text() == "x" and sorted(p.name for p in tmp_path.iterdir()) == [beside.name]


def test_a_tripod_scan_over_a_handheld_one_leaves_no_stale_trajectory(box_room_ifc, tmp_path, capsys):
    """render draws OUT.trajectory.csv over OUT: after a tripod scan replaces a handheld one there,
    the handheld walk must be gone with the cloud it belonged to (and only a walk bimscan wrote)."""
    walk = tmp_path / "walk.csv"
    walk.write_text("t,x,y,z,roll,pitch,yaw,pass\n0,2,2,1.5,0,0,0,0\n0.3,2.5,2,1.5,0,0,0,0\n")
    out, beside = tmp_path / "scan.laz", tmp_path / "scan.laz.trajectory.csv"
    assert main(["scan", str(box_room_ifc), str(out), "--platform", "handheld", "--trajectory", str(walk)]) == 0
    assert beside.is_file()
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--overwrite"]) == 0
    assert out.is_file() and not beside.exists()
    assert len(read_cloud_header(out).stations) == 1  # the tripod's cloud, with no walk beside it
    capsys.readouterr()

    # the cloud gone, its walk left: a new scan there is refused before any work, unless asked
    out.unlink()
    beside.write_text("t,x,y,z,roll,pitch,yaw,pass\n0,2,2,1.5,0,0,0,0\n")
    assert main(["scan", str(box_room_ifc), str(out), *FAST]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{beside} exists (the trajectory of a mobile scan at {out}); pass --overwrite" in err[0]
    assert not out.exists()
    # a user's file of that name is never removed, even when asked
    beside.write_text("time;x;y;z\n0;1;2;3\n")
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--overwrite"]) == 1
    assert "not in the format of a .trajectory.csv file" in capsys.readouterr().err
    assert beside.read_text() == "time;x;y;z\n0;1;2;3\n" and not out.exists()


@pytest.mark.parametrize("args, message", [
    (["--seed", str(2**70)], "seed must be an integer in 0..18446744073709551615, got 1.18e+21"),
    (["--threads", "-1"], "threads must be an integer >= 0 (0: all cores), got -1"),
    (["--head-speed", "1e-300"], "would fire inf pulses"),
    (["--range-sigma", "nan"], "range_sigma_m must be a number in [0, 1], got nan"),
])
def test_settings_that_would_crash_or_run_forever_are_one_line_errors(box_room_ifc, tmp_path, capsys, args, message):
    out = tmp_path / "x.laz"
    assert main(["scan", str(box_room_ifc), str(out), *args]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0]
    assert list(tmp_path.iterdir()) == []


def test_a_scan_that_sees_nothing_is_an_error_not_an_empty_file(box_room_ifc, tmp_path, capsys):
    blind = tmp_path / "blind.toml"  # nothing in the 8 x 6 m room lies within 0.5 m of the centre
    blind.write_text('name = "blind"\nmin_range_m = 0.0\nmax_range_m = 0.5\n')
    out = tmp_path / "none.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--scanner", str(blind)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: the scan of ") and "has no point" in err[-1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blind.toml"]


def test_an_unwritable_output_folder_fails_before_the_scan(box_room_ifc, tmp_path, capsys, monkeypatch):
    import bimscan.io._writer as writer_module

    # the tests may run as root, who can write anywhere: make the permission check see a read-only folder
    monkeypatch.setattr(writer_module, "folder_writable", lambda folder: False)
    assert main(["scan", str(box_room_ifc), str(tmp_path / "x.laz"), *FAST]) == 1
    assert "is not writable; check its permissions" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_file_name_that_is_not_utf8_is_reported_in_one_printable_line(tmp_path, capfdbinary):
    import os
    import subprocess
    import sys

    name = os.fsdecode(b"model-\xff.ifc")
    result = subprocess.run([sys.executable, "-m", "bimscan.cli.main", "info", str(tmp_path / name)],
                            capture_output=True, env=os.environ | {"BIMSCAN_PROGRESS": "0"})
    assert result.returncode == 1
    lines = result.stderr.decode("utf-8").strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "model-\\udcff.ifc" in lines[0]


def test_full_realism_from_the_command_line_writes_returns_colour_and_the_as_built_transforms(box_room_ifc, tmp_path):
    import laspy

    out = tmp_path / "full.laz"
    assert main(["scan", str(box_room_ifc), str(out), *FAST, "--seed", "1", "--realism", "full",
                 "--returns", "first", "--no-glass"]) == 0
    header = read_cloud_header(out)
    sensor = header.metadata["sensor"]
    assert sensor["realism"] == "full" and sensor["returns"] == "first" and sensor["glass"] is False
    assert sensor["footprint"] is True and len(header.metadata["as_built"]["components"]["global_id"]) == 6
    las = laspy.read(out)
    assert las.header.point_format.id == 7 and np.asarray(las.red).max() > 0
    cloud = read_cloud(out)
    assert cloud.rgb is not None and (cloud.return_number == 1).all()
    assert np.array_equal(cloud.label, header.components.label[cloud.component])
    plain = tmp_path / "plain.laz"
    assert main(["scan", str(box_room_ifc), str(plain), *FAST, "--seed", "1", "--realism", "paper"]) == 0
    assert "sensor" not in read_cloud_header(plain).metadata and read_cloud(plain).rgb is None


@pytest.mark.parametrize(("args", "named"), [
    (["--platform", "handheld", "--preset", "exp1"], "no TLS 'preset' (--preset)"),
    (["--platform", "handheld", "--head-speed", "60"], "'head_deg_per_s' (--head-speed)"),
    (["--platform", "backpack", "--returns", "all"], "returns = 'all' (acts only with footprint or glass)"),
    (["--platform", "handheld", "--beam-sample-quality", "4"], "beam_sample_quality = 4 (acts only with footprint)"),
    (["--platform", "handheld", "--max-station-pulses", "1000"], "'max_station_pulses' (--max-station-pulses)"),
    (["--platform", "handheld", "--stations", "{stations}", "--trajectory", "{walk}"], "stations from 'st.csv'"),
    (["--platform", "{no_mounts}"], "the platform has no [[mounts]]"),
    (["--returns", "all"], "returns = 'all' (acts only with footprint or glass)"),
    (["--beam-sample-quality", "4", "--glass"], "beam_sample_quality = 4 (acts only with footprint)"),
    (["--material-table", "{materials}"], "material_table = 'materials.toml' (acts only with materials"),
    (["--max-walk-pulses", "1000"], "'max_walk_pulses' (--max-walk-pulses)"),
])
def test_an_option_that_would_change_nothing_is_refused_in_one_line_before_the_model_is_read(tmp_path, capsys,
                                                                                              args, named):
    files = {"stations": tmp_path / "st.csv", "walk": tmp_path / "walk.csv", "no_mounts": tmp_path / "pole.toml",
             "materials": tmp_path / "materials.toml"}
    files["stations"].write_text("x,y,height\n4,3,1.7\n")
    files["walk"].write_text("t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n3,5,3,0,0,0,0\n")
    files["no_mounts"].write_text('description = "a lidar on a pole, not placed"\nwalking_speed_m_s = 0.8\n')
    files["materials"].write_text("")
    inputs = sorted(p.name for p in tmp_path.iterdir())
    args = [a.format(**files) for a in args]
    # the model does not exist: the option is refused before anything reads it
    assert main(["scan", str(tmp_path / "unread.ifc"), str(tmp_path / "x.laz"), *args]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and named in err[0], err
    assert "unread.ifc" not in err[0] and sorted(p.name for p in tmp_path.iterdir()) == inputs


def test_a_walk_over_its_pulse_budget_is_refused_with_the_estimate_before_the_model_is_read(tmp_path, capsys):
    import math

    from bimscan.survey.trajectory import read_trajectory

    walk = tmp_path / "long.csv"  # two rows, 20,000 s apart: 5.8e9 pulses of one VLP-16
    walk.write_text("t,x,y,z,roll,pitch,yaw\n0,2,3,0,0,0,0\n20000,5,3,0,0,0,0\n")
    args = ["scan", str(tmp_path / "unread.ifc"), str(tmp_path / "x.laz"), "--platform", "handheld",
            "--trajectory", str(walk)]
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: the trajectory {walk} would fire 5.79e+09 pulses "
                                               "(20,000 s x 1 x velodyne_vlp16 at 289,352 pulses/s)")
    assert "budget of 2,000,000,000" in err[0] and "--max-walk-pulses" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["long.csv"]
    # the estimate is what the scan would fire: whole firing sequences of 16 pulses, on every lidar
    sequences = math.floor(20000 / 55.296e-6 + 1e-9)
    for platform, lidars in (("handheld", 1), ("backpack", 2)):
        recipe = ScanRecipe.resolve(platform=platform, trajectory=str(walk), max_walk_pulses=2 * 10**10)
        assert recipe.check_walk(read_trajectory(walk)) == sequences * 16 * lidars
    # a raised budget lets the walk through to the model, which is read next
    assert main([*args, "--max-walk-pulses", str(6 * 10**9)]) == 1
    assert "unread.ifc" in capsys.readouterr().err

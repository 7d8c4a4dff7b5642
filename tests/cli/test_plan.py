"""``bimscan plan`` end to end: a plan folder a scan takes as it is, checks of given plans and of
their scans, and refusals that leave nothing behind."""

from __future__ import annotations

import csv
import hashlib
import json

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.io import read_cloud_header

FAST = ["--preset", "exp1", "--head-speed", "60"]  # 1/12 of the default preset's points per station
PLAN = [*FAST, "--density", "100"]


def rows(path):
    return list(csv.DictReader(line for line in path.read_text("utf-8").splitlines() if not line.startswith("#")))


def test_a_plan_folder_holds_stations_coverage_graph_summary_and_pictures(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(out), *PLAN]) == 0
    printed = capsys.readouterr().out
    assert "stations planned" in printed and "Wall&Column" in printed and "registration graph" in printed
    names = sorted(p.name for p in out.iterdir())
    assert names == ["coverage.csv", "plan.json", "plan_1_L0.png", "registration.csv", "stations.csv"]
    summary = json.loads((out / "plan.json").read_text("utf-8"))
    assert summary["kind"] == "bimscan plan" and summary["mode"] == "plan" and summary["met"] is True
    assert summary["config"]["density_pts_m2"] == 100.0 and summary["preset"] == "exp1"
    coverage = rows(out / "coverage.csv")
    assert {r["class"] for r in coverage} == {"Wall&Column", "Slab"}  # the box room has no beams or coverings
    assert all(r["global_id"] and r["status"] in ("covered", "short", "never seen", "seen only edge-on")
               for r in coverage)
    assert len(rows(out / "stations.csv")) == len(summary["stations"]) >= 1
    assert not list(tmp_path.glob(".*tmp*"))


def test_the_plans_stations_scan_as_they_are(box_room_ifc, tmp_path):
    out = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(out), *PLAN]) == 0
    cloud = tmp_path / "scan.laz"
    assert main(["scan", str(box_room_ifc), str(cloud), *FAST, "--stations", str(out / "stations.csv")]) == 0
    planned = json.loads((out / "plan.json").read_text("utf-8"))["stations"]
    scanned = read_cloud_header(cloud).stations
    assert len(scanned) == len(planned)
    for a, b in zip(planned, scanned):
        assert np.allclose(a["position"], b.position, atol=1e-4) and b.floor_z == pytest.approx(a["floor_z"], abs=1e-4)


@pytest.mark.slow
def test_checking_a_scan_reports_the_coverage_measured_on_it(box_room_ifc, tmp_path, capsys):
    plan = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(plan), *PLAN]) == 0
    cloud = tmp_path / "scan"
    assert main(["scan", str(box_room_ifc), str(cloud), *FAST, "--stations", str(plan / "stations.csv")]) == 0
    capsys.readouterr()
    check = tmp_path / "check"
    assert main(["plan", str(box_room_ifc), str(check), *PLAN, "--check", str(plan / "stations.csv"),
                 "--cloud", str(cloud)]) == 0
    assert "on the scan" in capsys.readouterr().out
    summary = json.loads((check / "plan.json").read_text("utf-8"))
    assert summary["mode"] == "check" and summary["solver"] is None and summary["scan_met"] is True
    q1, median, q3 = summary["scan_density_over_estimate_quartiles"]
    assert 0.85 <= median <= 1.15 and q1 <= median <= q3
    for name, figures in summary["classes"].items():
        if figures["visible_m2"]:
            assert abs(figures["scan_covered_fraction"] - figures["covered_fraction"]) <= 0.05, name
    assert "scan_covered_fraction" in rows(check / "coverage.csv")[0]


def test_check_auto_reports_the_per_room_plan(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "auto"
    assert main(["plan", str(box_room_ifc), str(out), *PLAN, "--check", "auto"]) == 0
    assert "1 stations checked" in capsys.readouterr().out
    assert json.loads((out / "plan.json").read_text("utf-8"))["mode"] == "check"


def test_same_inputs_same_bytes(box_room_ifc, tmp_path):
    digests = []
    for name in ("a", "b"):
        out = tmp_path / name
        assert main(["plan", str(box_room_ifc), str(out), *PLAN]) == 0
        digests.append({p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.iterdir())})
    assert digests[0] == digests[1]


def test_an_impossible_ask_is_one_error_line_and_writes_nothing(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(out), *FAST, "--density", "1e9"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len([line for line in err if line.startswith("error:")]) == 1
    assert "no plan reaches the coverage asked" in err[-1] and "--density" in err[-1]
    assert not out.exists() and not list(tmp_path.glob(".*tmp*"))


def test_an_existing_folder_bimscan_did_not_write_is_never_replaced(box_room_ifc, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    assert main(["plan", str(box_room_ifc), str(mine), *PLAN, "--overwrite"]) == 1
    assert "is a folder that is not a bimscan plan folder (it holds notes.txt)" in capsys.readouterr().err
    assert (mine / "notes.txt").read_text() == "keep me"
    plan = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(plan), *PLAN]) == 0
    assert main(["plan", str(box_room_ifc), str(plan), *PLAN]) == 1  # exists: --overwrite needed
    assert main(["plan", str(box_room_ifc), str(plan), *PLAN, "--classes", "Slab", "--overwrite"]) == 0
    assert {r["class"] for r in rows(plan / "coverage.csv")} == {"Slab"}


def test_overwriting_a_plan_keeps_a_picture_the_user_put_beside_it(box_room_ifc, tmp_path, capsys):
    plan = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(plan), *PLAN]) == 0
    signed = plan / "plan_signed_by_client.png"  # named like the plan's pictures, but the plan.json lists its own
    signed.write_bytes(b"\x89PNG\r\n\x1a\n signed by the client")
    before = {p.name: p.read_bytes() for p in plan.iterdir()}
    capsys.readouterr()
    assert main(["plan", str(box_room_ifc), str(plan), *PLAN, "--overwrite"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "plan_signed_by_client.png, which bimscan did not write" in err
    assert {p.name: p.read_bytes() for p in plan.iterdir()} == before
    assert not list(tmp_path.glob(".*tmp*"))


def test_a_config_file_sets_the_planner_and_the_flags_override_it(box_room_ifc, tmp_path, capsys):
    config = tmp_path / "plan.toml"
    config.write_text('classes = ["Wall&Column"]\ndensity_pts_m2 = 150.0\nsearch_rounds = 5\n')
    out = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(out), *FAST, "--config", str(config), "--density", "120"]) == 0
    summary = json.loads((out / "plan.json").read_text("utf-8"))
    assert summary["config"]["classes"] == ["Wall&Column"] and summary["config"]["density_pts_m2"] == 120.0
    assert summary["config"]["search_rounds"] == 5
    config.write_text("densty = 3\n")
    assert main(["plan", str(box_room_ifc), str(tmp_path / "other"), *FAST, "--config", str(config)]) == 1
    assert "unknown key(s) 'densty'" in capsys.readouterr().err


@pytest.mark.parametrize(("args", "message"), [
    (["--classes", "Walls"], "unknown class 'Walls'"),
    (["--coverage", "0.9,0.8"], "error: --coverage 0.9,0.8 must be one fraction, or one per class (4: Wall&Column,"),
    (["--coverage", "0.9,1.5"],
     "error: --coverage takes numbers in (0, 1] (fractions, e.g. 0.95), got 1.5 in 0.9,1.5\n"),
    (["--coverage", "0.9;0.8"], "error: Invalid value for --coverage: '0.9;0.8' is not a list of numbers"),
    (["--density", "-1"], "error: --density must be a number > 0, got -1\n"),
    (["--classes", "Slab,Slab"], "error: --classes Slab,Slab must name at least one class, each once"),
    (["--ladder", "0.8,2"], "error: --ladder takes numbers in (0, 1]"),
    (["--solver", "greedy", "--time-limit", "5"],
     "error: --time-limit 5 would change nothing: --solver greedy runs no MILP; leave it out"),
    (["--check", "auto", "--solver", "milp"], "error: --solver milp would change nothing: a given plan is checked"),
    (["--cloud", "scan.laz"], "--cloud needs --check"),
    (["--check", "missing.csv"], "missing.csv"),
])
def test_bad_asks_are_one_line_in_the_words_typed(box_room_ifc, tmp_path, capsys, args, message):
    assert main(["plan", str(box_room_ifc), str(tmp_path / "out"), *PLAN, *args]) != 0
    err = capsys.readouterr().err
    assert message in err and err.count("error:") == 1
    assert "density_pts_m2" not in err and "milp_time_limit_s" not in err and "[" not in err
    assert not (tmp_path / "out").exists()


def test_a_config_files_own_keys_are_named_as_the_file_has_them(box_room_ifc, tmp_path, capsys):
    config = tmp_path / "plan.toml"
    config.write_text('solver = "greedy"\nmilp_time_limit_s = 5.0\n')
    assert main(["plan", str(box_room_ifc), str(tmp_path / "out"), *PLAN, "--config", str(config)]) == 1
    assert "plan.toml with the flags: milp_time_limit_s = 5 would change nothing: solver = 'greedy'" in \
        capsys.readouterr().err


@pytest.mark.parametrize(("rows", "message"), [
    ("x,y,z\n2,2,1.7\n6,4,1.7\n2,2,1.7\n", "stations 1 and 3 stand at the same spot (2, 2, 1.7)"),
    ("x,y,z,storey\n2,2,1.7,Roof 99\n", "station 1: unknown storey 'Roof 99'; use one of L0"),
])
def test_a_checked_plan_with_a_station_twice_or_an_unknown_storey_is_refused(box_room_ifc, tmp_path, capsys, rows,
                                                                              message):
    stations = tmp_path / "stations.csv"
    stations.write_text(rows, "utf-8")
    for command in (["plan", str(box_room_ifc), str(tmp_path / "check"), *PLAN, "--check", str(stations)],
                    ["scan", str(box_room_ifc), str(tmp_path / "scan.laz"), *FAST, "--stations", str(stations)]):
        assert main(command) == 1
        err = capsys.readouterr().err
        assert message in err and err.count("error:") == 1
    assert not (tmp_path / "check").exists() and not (tmp_path / "scan.laz").exists()


def test_the_plan_says_how_many_stations_each_coverage_needs(box_room_ifc, tmp_path, capsys):
    out = tmp_path / "plan"
    assert main(["plan", str(box_room_ifc), str(out), *FAST, "--density", "300", "--classes", "Slab",
                 "--ladder", "0.3,0.6"]) == 0  # and the asked 95 %
    printed = capsys.readouterr().out
    summary = json.loads((out / "plan.json").read_text("utf-8"))
    ladder = summary["coverage_ladder"]
    assert [rung["coverage"] for rung in ladder] == [0.3, 0.6, 0.95]
    counts = [rung["stations"] for rung in ladder]
    assert counts[-1] == len(summary["stations"]) >= 2 and counts == sorted(counts) and counts[0] == 1
    assert f"stations by coverage: 30 % 1, 60 % {counts[1]}, 95 % {counts[2]}" in printed

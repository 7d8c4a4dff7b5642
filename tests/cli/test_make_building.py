"""bimscan make-building: writes a seeded IFC4 building, one summary line, one-line errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import ifcopenshell
import pytest

from bimscan.cli.main import main


def test_make_building_writes_the_file_and_prints_a_one_line_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo.ifc"
    assert main(["make-building", str(out), "--seed", "7", "--storeys", "2"]) == 0
    stdout = capsys.readouterr().out
    assert stdout.count("\n") == 1 and str(out) in stdout
    model = ifcopenshell.open(str(out))
    spaces = len(model.by_type("IfcSpace"))
    assert f"{spaces} rooms" in stdout
    assert f"IfcWall {len(model.by_type('IfcWall'))}" in stdout
    assert len(model.by_type("IfcBuildingStorey")) == 2


def test_make_building_with_the_same_seed_twice_gives_the_same_bytes(tmp_path: Path) -> None:
    for name in ("a.ifc", "b.ifc"):
        assert main(["make-building", str(tmp_path / name), "--seed", "11", "--storeys", "1"]) == 0
    assert (tmp_path / "a.ifc").read_bytes() == (tmp_path / "b.ifc").read_bytes()


def test_make_building_replaces_a_building_it_wrote_only_when_asked_and_leaves_no_temporary_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo.ifc"
    assert main(["make-building", str(out), "--storeys", "1", "--seed", "1"]) == 0
    first = out.read_bytes()
    assert main(["make-building", str(out), "--storeys", "1", "--seed", "2"]) == 1
    assert capsys.readouterr().err.endswith("demo.ifc already exists; pass --overwrite to replace it or choose "
                                            "another path\n")
    assert out.read_bytes() == first
    assert main(["make-building", str(out), "--storeys", "1", "--seed", "2", "--overwrite"]) == 0
    assert out.read_text().startswith("ISO-10303-21;") and out.read_bytes() != first
    assert [p.name for p in tmp_path.iterdir()] == ["demo.ifc"]


def test_make_building_never_replaces_a_model_bimscan_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "theirs.ifc"
    assert main(["make-building", str(out), "--storeys", "1", "--seed", "1"]) == 0
    theirs = out.read_text().replace("('bimscan make-building')", "('Architect')")  # another tool's header
    out.write_text(theirs)
    assert main(["make-building", str(out), "--storeys", "1", "--seed", "2", "--overwrite"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "theirs.ifc is an IFC model bimscan did not write" in err
    assert out.read_text() == theirs and [p.name for p in tmp_path.iterdir()] == ["theirs.ifc"]


def test_make_building_never_replaces_a_file_that_is_not_ifc(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo.ifc"
    out.write_text("old content")  # a user's file that happens to end in .ifc
    assert main(["make-building", str(out), "--storeys", "1", "--overwrite"]) == 1
    assert "demo.ifc is a file not in the format of a .ifc file; bimscan replaces only" in capsys.readouterr().err
    assert out.read_text() == "old content" and [p.name for p in tmp_path.iterdir()] == ["demo.ifc"]


def test_make_building_help_names_its_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["make-building", "--help"]) == 0
    text = capsys.readouterr().out
    assert "--seed" in text and "--storeys" in text and "1..10" in text
    assert "--style" in text and "office|residential|site" in text
    assert "--schedule START" in text and "YYYY-MM-DD" in text


@pytest.mark.parametrize("style", ["office", "residential", "site"])
def test_make_building_writes_the_chosen_style_and_says_so(
    style: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / f"{style}.ifc"
    assert main(["make-building", str(out), "--seed", "3", "--storeys", "1", "--style", style]) == 0
    assert f": {style} seed 3," in capsys.readouterr().out
    model = ifcopenshell.open(str(out))
    assert model.by_type("IfcProject")[0].Name == f"bimscan {style} building"
    assert bool(model.by_type("IfcColumn")) == (style != "residential")


def test_the_summary_says_which_roof_the_building_has(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bimscan.ifc.generate.floor_plan import plan_building

    home = next(seed for seed in range(50) if plan_building(seed=seed, storeys=1, style="residential").roof)
    assert main(["make-building", str(tmp_path / "home.ifc"), "--seed", str(home), "--storeys", "1",
                 "--style", "residential"]) == 0
    assert main(["make-building", str(tmp_path / "office.ifc"), "--seed", "3", "--storeys", "1"]) == 0
    home_line, office_line = capsys.readouterr().out.splitlines()
    assert "attic under a" in home_line and "deg gable roof" in home_line
    assert "flat roof" in office_line
    storeys = ifcopenshell.open(str(tmp_path / "home.ifc")).by_type("IfcBuildingStorey")
    assert sorted(s.LongName or "" for s in storeys) == ["", "Attic"]


def test_the_command_line_loads_without_ifcopenshell() -> None:
    # Every command's --help and argument errors come before any IFC work: starting the CLI must
    # not pay for IfcOpenShell (the style table is plain data).
    code = "import sys, bimscan.cli.commands; sys.exit(int('ifcopenshell' in sys.modules))"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_an_unknown_style_gives_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo.ifc"
    assert main(["make-building", str(out), "--style", "castle"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "castle" in err and "office" in err
    assert not out.exists()


@pytest.mark.parametrize("storeys", ["0", "50"])
def test_bad_storeys_give_a_one_line_error_and_a_non_zero_exit(
    storeys: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo.ifc"
    assert main(["make-building", str(out), "--storeys", storeys]) != 0
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    assert "1..10" in err and storeys in err
    assert not out.exists()


def test_missing_output_folder_gives_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "missing" / "demo.ifc"
    assert main(["make-building", str(out)]) != 0
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "does not exist" in err
    assert not out.parent.exists()


def test_make_building_with_a_schedule_says_when_the_works_begin_and_end(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "works.ifc"
    assert main(["make-building", str(out), "--storeys", "1", "--seed", "2", "--schedule", "2024-03-02"]) == 0
    line = capsys.readouterr().out
    model = ifcopenshell.open(str(out))
    tasks = [t for t in model.by_type("IfcTask") if not t.IsNestedBy]  # those that build, not their summaries
    last = max(t.TaskTime.ScheduleFinish for t in tasks)[:10]
    assert line.count("\n") == 1 and line.rstrip().endswith(
        f"; work schedule of {len(tasks)} tasks from 2024-03-04 to {last}")  # Saturday: works begin on Monday
    assert len(model.by_type("IfcWorkSchedule")) == 1


def test_make_building_refuses_a_schedule_start_that_is_not_a_date(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["make-building", str(tmp_path / "b.ifc"), "--storeys", "1", "--schedule", "2024-02-30"]) == 1
    err = capsys.readouterr().err
    assert err == "error: schedule start = '2024-02-30' is not a date; give the first day of works as YYYY-MM-DD " \
                  "(e.g. 2024-03-04)\n"
    assert list(tmp_path.iterdir()) == []

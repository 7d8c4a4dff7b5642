"""``bimscan demo``: dataset, statistics and pictures of the generated buildings; re-running resumes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bimscan.cli.main import main
from bimscan.demo import demo_spec


@pytest.mark.slow
def test_the_demo_builds_the_dataset_statistics_and_pictures_and_resumes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    # the demo at six times its head speed: the same twelve units with a sixth of the points
    assert main(["demo", str(out), "--head-speed", "360"]) == 0
    printed = capsys.readouterr().out
    assert (out / "dataset.toml").read_text() == demo_spec(head_deg_per_s=360.0)
    manifest = json.loads((out / "dataset" / "manifest.json").read_text())
    units = manifest["units"]
    assert len(units) == 12 and all(u["status"] == "done" for u in units)
    assert {u["config"] for u in units} == {f"exp{i}" for i in range(1, 7)}
    points = {u["id"]: u["points"] for u in units}
    for scene in ("office-1f", "office-2f"):
        # pulse rate 500 kHz vs 50 kHz at the same line rate: about ten times the points
        assert 8 < points[f"{scene}__exp5"] / points[f"{scene}__exp1"] < 11
    report = (out / "stats" / "report.md").read_text()
    assert "so extents stay stable" in report and "so proportions stay stable" in report
    pictures = sorted(p.name for p in (out / "pictures").iterdir())
    assert pictures == [".bimscan.json", "office-1f_exp3.png", "office-1f_model_and_scan.png", "office-2f_exp3.png",
                        "office-2f_model_and_scan.png"]  # the record lists what bimscan wrote in the folder
    assert json.loads((out / ".bimscan.json").read_text())["files"] == ["dataset.toml", "dataset/", "pictures/",
                                                                        "stats/"]
    assert str(out / "stats" / "report.md") in printed and str(out / "dataset" / "manifest.json") in printed

    mtimes = {p: p.stat().st_mtime_ns for p in (out / "dataset" / "units").rglob("*")}
    (out / "notes.md").write_text("what I saw")  # a user's file beside the demo's is left alone
    assert main(["demo", str(out), "--head-speed", "360"]) == 0
    assert (out / "notes.md").read_text() == "what I saw"
    assert "12 units: 0 built, 12 already done, 0 failed" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in (out / "dataset" / "units").rglob("*")} == mtimes


def test_the_demo_refuses_a_users_folder_and_a_users_file_at_its_names_before_any_work(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.txt").write_text("three years")
    assert main(["demo", str(mine)]) == 1
    assert "mine is a folder bimscan did not make (it holds thesis.txt)" in capsys.readouterr().err
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.txt"]

    out = tmp_path / "demo"
    (out / "pictures").mkdir(parents=True)
    (out / "dataset.toml").write_text("# the demo's spec, as the demo wrote it\n")
    (out / ".bimscan.json").write_text(json.dumps({"format": "bimscan-output-folder", "version": 1,
                                                    "files": ["dataset.toml"]}))
    (out / "pictures" / "office-1f_exp3.png").write_bytes(b"\x89PNG\r\n\x1a\n mine")  # a folder it did not make
    assert main(["demo", str(out)]) == 1
    err = capsys.readouterr().err
    assert f"{out / 'pictures'} was not written by bimscan" in err and err.count("\n") == 1
    assert not (out / "dataset").exists()  # refused before the build
    assert (out / "pictures" / "office-1f_exp3.png").read_bytes() == b"\x89PNG\r\n\x1a\n mine"

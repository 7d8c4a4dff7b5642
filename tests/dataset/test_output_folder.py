"""A dataset folder is bimscan's: a build writes into a new or empty folder or one it made, replaces
only what it wrote there, and finds a clash (a user's manifest.json, a user's folder where a unit
goes) before anything is generated or scanned (issue 50)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from bimscan.cli.main import main
from bimscan.dataset.build import build_dataset
from bimscan.dataset.layout import DATASET_OUTPUTS
from bimscan.dataset.spec import load_spec
from bimscan.errors import OutputError
from bimscan.files import OUTPUT_RECORD, read_output_record

from .conftest import BuiltDataset, reproducible_files, write_tiny_spec


def _snapshot(root: Path) -> dict[str, bytes | None]:
    found: dict[str, bytes | None] = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(folder, name)
            found[path.relative_to(root).as_posix()] = None if path.is_dir() else path.read_bytes()
    return found


@pytest.fixture
def no_work(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The scene and unit tasks (run in this process by the serial executor) replaced by ones that
    only note that they ran."""
    ran: list[str] = []

    def scene_task(job):
        ran.append(f"scene {job.scene}")
        raise AssertionError("a scene task ran")

    def unit_task(job):
        ran.append(f"unit {job.unit}")
        raise AssertionError("a unit task ran")

    monkeypatch.setattr("bimscan.dataset.build.run_scene_job", scene_task)
    monkeypatch.setattr("bimscan.dataset.build.run_unit_job", unit_task)
    return ran


@pytest.mark.parametrize("name", ["manifest.json", "dataset.json"])
def test_a_users_manifest_or_dataset_json_in_out_is_refused_and_kept_byte_identical(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str) -> None:
    spec = write_tiny_spec(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / name).write_text('{"format": "my-lab-inventory", "rooms": 12}\n')
    before = _snapshot(tmp_path)
    assert main(["build", str(spec), str(out)]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning: ")]
    assert err == [f"error: {out} is a folder bimscan did not make (it holds {name}); bimscan writes only into a new "
                   "or empty folder, or one it made: choose another"]
    assert _snapshot(tmp_path) == before  # nothing written, nothing generated, nothing replaced


def test_a_users_folder_where_a_unit_goes_is_refused_before_anything_is_generated_or_scanned(
        tmp_path: Path, no_work: list[str]) -> None:
    spec = load_spec(write_tiny_spec(tmp_path))
    out = tmp_path / "out"
    out.mkdir()
    (out / OUTPUT_RECORD).write_text(json.dumps({"format": "bimscan-output-folder", "version": 1,
                                                 "files": ["units/"]}))  # a folder bimscan made
    mine = out / "units" / "north__sparse"
    mine.mkdir(parents=True)
    (mine / "thesis.txt").write_text("three years")
    with pytest.raises(OutputError) as caught:
        build_dataset(spec, out, executor="serial", progress=False)
    assert str(caught.value) == (f"{mine} is a folder that is not a bimscan data unit (it holds thesis.txt); bimscan "
                                 "replaces only what it wrote: choose another output or remove it yourself")
    assert no_work == [] and not (out / "scenes" / "north.ifc").exists()
    assert (mine / "thesis.txt").read_text() == "three years"


def test_a_unit_with_a_users_file_added_is_kept_when_finished_and_refused_before_scanning_when_stale(
        reference_dataset: BuiltDataset, tmp_path: Path, no_work: list[str]) -> None:
    out = tmp_path / "copy"
    shutil.copytree(reference_dataset.out, out)
    unit = out / "units" / "north__sparse"
    (unit / "notes.txt").write_text("checked on site")
    report = build_dataset(load_spec(reference_dataset.spec), out, executor="serial", progress=False)
    assert (report.built, report.reused) == (0, 4) and (unit / "notes.txt").read_text() == "checked on site"

    (unit / "cloud.laz").unlink()  # stale: it is to be rebuilt, over the user's file
    with pytest.raises(OutputError, match="north__sparse is a bimscan data unit that also holds notes.txt, which "
                                          "bimscan did not write"):
        build_dataset(load_spec(reference_dataset.spec), out, executor="serial", progress=False)
    assert no_work == [] and (unit / "notes.txt").read_text() == "checked on site"


def test_a_rerun_into_its_own_folder_resumes_and_leaves_a_users_files_alone(
        reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    out = tmp_path / "copy"
    shutil.copytree(reference_dataset.out, out)
    assert read_output_record(out) == set(DATASET_OUTPUTS)
    (out / "notes.md").write_text("my notes")
    (out / "units" / "north__dense").rename(tmp_path / "gone")  # a unit to build again
    report = build_dataset(load_spec(reference_dataset.spec), out, executor="serial", progress=False)
    assert (report.built, report.reused) == (1, 3)
    assert (out / "notes.md").read_text() == "my notes" and "notes.md" not in read_output_record(out)
    assert {k: v for k, v in reproducible_files(out).items() if k != "notes.md"} == reproducible_files(
        reference_dataset.out)


def test_a_dataset_built_before_folders_had_records_is_taken_by_its_manifest(
        reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    out = tmp_path / "copy"
    shutil.copytree(reference_dataset.out, out)
    (out / OUTPUT_RECORD).unlink()
    (out / "notes.md").write_text("my notes")
    report = build_dataset(load_spec(reference_dataset.spec), out, executor="serial", progress=False)
    assert (report.built, report.reused) == (0, 4)
    assert read_output_record(out) == set(DATASET_OUTPUTS)  # bimscan's names, not the user's notes
    assert (out / "notes.md").read_text() == "my notes"

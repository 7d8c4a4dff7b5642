"""The folders train, adapt and evaluate write into (--out) are bimscan's: a new or empty folder or
one it made; a user's metrics.csv, curves.png, evaluation.md or confusion.csv is refused before any
scene is read and kept byte for byte, a user's notes beside bimscan's files are left alone, and a
run resumes in its own folder (issue 50)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from bimscan.cli.main import main
from bimscan.files import OUTPUT_RECORD, read_output_record

PNG = b"\x89PNG\r\n\x1a\n"


def _snapshot(root: Path) -> dict[str, bytes | None]:
    found: dict[str, bytes | None] = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(folder, name)
            found[path.relative_to(root).as_posix()] = None if path.is_dir() else path.read_bytes()
    return found


@pytest.fixture
def users_results(tmp_path: Path) -> Path:
    """A folder of the user's own results, named as bimscan names its outputs."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "metrics.csv").write_text("epoch,my_metric\n1,0.9\n")
    (mine / "curves.png").write_bytes(PNG + b"my curves")
    (mine / "evaluation.md").write_text("# my evaluation\n")
    (mine / "confusion.csv").write_text("my,confusion\n")
    return mine


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The scenes a run starts reading (none, when it is refused first)."""
    read: list[str] = []

    def read_tiles(*args, **kwargs):
        read.append("tiles")
        raise AssertionError("scenes read")

    monkeypatch.setattr("bimscan.learn.train._read_tiles", read_tiles)
    return read


def test_train_into_a_users_folder_is_refused_before_reading_a_scene_and_keeps_it_whole(
    tmp_path: Path, users_results: Path, room_files: dict[str, list[str]], tiny_config, reads: list[str],
    capsys: pytest.CaptureFixture[str],
) -> None:
    config = tiny_config(tmp_path, train=room_files["train"], val=room_files["val"])
    before = _snapshot(users_results)
    assert main(["train", str(config), "--out", str(users_results)]) == 1
    err = capsys.readouterr().err
    assert err == (f"error: {users_results} is a folder bimscan did not make (it holds confusion.csv, curves.png, "
                   "evaluation.md, metrics.csv); bimscan writes only into a new or empty folder, or one it made: "
                   "choose another\n")
    assert reads == [] and _snapshot(users_results) == before


def test_adapt_into_a_users_folder_is_refused_before_reading_a_scan(
    trained_run: Path, users_results: Path, reads: list[str], capsys: pytest.CaptureFixture[str],
) -> None:
    before = _snapshot(users_results)
    assert main(["adapt", str(trained_run / "run" / "last.pt"), str(trained_run / "real.txt"),
                 str(users_results)]) == 1
    assert "is a folder bimscan did not make" in capsys.readouterr().err
    assert reads == [] and _snapshot(users_results) == before


def test_evaluate_into_a_users_folder_is_refused_before_the_checkpoint_is_read(
    tmp_path: Path, users_results: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    before = _snapshot(users_results)
    assert main(["evaluate", str(tmp_path / "nowhere.pt"), str(tmp_path / "nowhere.las"),
                 "--out", str(users_results)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {users_results} is a folder bimscan did not make") and err.count("\n") == 1
    assert _snapshot(users_results) == before


def test_evaluate_writes_beside_a_run_in_its_folder_and_refuses_a_users_file_at_its_names(
    trained_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    run = tmp_path / "run"
    shutil.copytree(trained_run / "run", run)
    (run / "confusion.csv").write_text("my,confusion\n")  # the user's, in a folder bimscan made
    checkpoint = run / "last.pt"
    args = ["evaluate", str(checkpoint), str(trained_run / "real.txt"), "--out", str(run), "--device", "cpu"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"error: {run / 'confusion.csv'} was not written by bimscan") and "move it away" in err
    assert (run / "confusion.csv").read_text() == "my,confusion\n"

    (run / "confusion.csv").rename(tmp_path / "kept.csv")
    training = {name: (run / name).read_bytes() for name in ("last.pt", "metrics.csv", "curves.png")}
    assert main(args) == 0
    assert {name: (run / name).read_bytes() for name in training} == training
    assert {"evaluation.md", "evaluation.json", "confusion.csv", "confusion.png", "last.pt"} <= read_output_record(run)


def test_a_run_folder_made_before_records_resumes_and_its_users_notes_stay_out_of_the_record(
    trained_run: Path, tmp_path: Path,
) -> None:
    from bimscan.learn.train import train_model
    from bimscan.learn.train_config import load_train_config

    shutil.copytree(trained_run, tmp_path / "project")
    run = tmp_path / "project" / "run"
    (run / OUTPUT_RECORD).unlink()  # as an earlier version left it
    (run / "notes.md").write_text("lr too high?")
    config, base = load_train_config(tmp_path / "project" / "train.toml")
    result = train_model(config, base_dir=base, resume=True, log=lambda text: None)  # taken by its last.pt
    assert result.epochs_done == 3
    assert (run / "notes.md").read_text() == "lr too high?"
    assert {"last.pt", "metrics.csv", "curves.png", "tile-cache/"} <= read_output_record(run)
    assert "notes.md" not in read_output_record(run)


def test_a_run_folder_an_earlier_version_left_in_its_first_epoch_is_taken_and_a_users_is_not(tmp_path: Path) -> None:
    from bimscan.errors import OutputError
    from bimscan.files import check_output_folder
    from bimscan.learn.train import RUN_OUTPUTS, is_earlier_run

    killed = tmp_path / "killed"
    (killed / "tile-cache").mkdir(parents=True)  # killed before its first checkpoint, by an earlier version
    (killed / "tile-cache" / "tiles-0123.npz").write_bytes(b"PK")
    check_output_folder(killed, names=RUN_OUTPUTS, made_by=is_earlier_run)
    (killed / "metrics.csv").write_text("mine\n")
    with pytest.raises(OutputError, match="is a folder bimscan did not make"):
        check_output_folder(killed, names=RUN_OUTPUTS, made_by=is_earlier_run)

"""The train / evaluate / predict commands end to end on a tiny generated dataset: a bimscan
dataset folder of LAZ and NumPy units for training, a foreign LAS with labels in an extra
dimension and an S3DIS room as the "real" scans; bad input gives one line and exit 1."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path

import laspy
import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.dataset.layout import DatasetFolder, Manifest, ManifestEntry
from bimscan.io import open_cloud_writer
from bimscan.semantics.scheme import load_scheme
from bimscan.types import CloudHeader, PointCloud


def _write_dataset(folder: Path, room: Callable[..., PointCloud]) -> None:
    header = CloudHeader(scheme=load_scheme(), origin=(0.0, 0.0, 0.0), metadata={"test": True})
    units = []
    for i, (unit, file) in enumerate((("u0", "cloud.laz"), ("u1", "cloud"), ("u2", "cloud.laz"))):
        (folder / "units" / unit).mkdir(parents=True)
        cloud = room(i, size_m=(4.0 + i, 3.0), points_per_m2=40)
        with open_cloud_writer(folder / "units" / unit / file, header=header) as writer:
            for start in range(0, len(cloud), 1000):  # streamed, as the scanner writes
                writer.write(cloud.take(slice(start, start + 1000)))
        key = "laz" if file.endswith(".laz") else "npy"
        units.append(ManifestEntry(id=unit, scene=f"room{i}", config="tls", status="done", points=len(cloud),
                                   files={key: f"units/{unit}/{file}"}))
    units.append(ManifestEntry(id="u3", scene="room3", config="tls", status="failed", error="test"))
    DatasetFolder(folder).write_manifest(Manifest(units=tuple(units)))


def _write_foreign_las(path: Path, cloud: PointCloud) -> None:
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.floor(cloud.xyz.min(axis=0))
    header.scales = np.array([0.001, 0.001, 0.001])
    header.add_extra_dim(laspy.ExtraBytesParams(name="gt", type=np.uint8))
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.gt = cloud.label
    las.write(path)


def _write_s3dis_room(folder: Path, cloud: PointCloud) -> None:
    names = {0: "wall", 1: "beam", 2: "ceiling", 3: "floor", 4: "table"}
    (folder / "Annotations").mkdir(parents=True)
    for label, name in names.items():
        xyz = cloud.xyz[cloud.label == label]
        table = np.column_stack([xyz, np.full((len(xyz), 3), 128.0)])
        np.savetxt(folder / "Annotations" / f"{name}_1.txt", table, fmt="%.4f %.4f %.4f %d %d %d")


@pytest.fixture
def project(tmp_path: Path, room: Callable[..., PointCloud]) -> Path:
    _write_dataset(tmp_path / "spc", room)
    _write_foreign_las(tmp_path / "site.las", room(50, size_m=(5.0, 4.0), points_per_m2=40))
    _write_s3dis_room(tmp_path / "Area_1" / "office_1", room(51, size_m=(4.0, 4.0), points_per_m2=40))
    (tmp_path / "train.toml").write_text("""\
[data]
train = ["spc"]
val = { scenes = ["site.las"], label_field = "gt" }

[eval]
stride_m = 1.0

[blocks]
size_m = 2.0
points = 128
min_points = 32
cache_points = 256

[model]
embed_dim = 16
attention_layers = 2
fuse_dim = 32
head_dims = [32, 16]
dropout = 0.1

[train]
epochs = 3
batch_size = 2
accumulation_steps = 2
max_lr = 0.01
num_workers = 0
out_dir = "runs/tiny"
""")
    return tmp_path


def test_train_evaluate_and_predict_from_the_command_line(
    project: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(project)

    assert main(["train", "train.toml"]) == 0
    trained = capsys.readouterr()
    checkpoint = project / "runs" / "tiny" / "last.pt"
    assert "trained 3 epoch(s)" in trained.out and checkpoint.is_file()
    assert trained.err.count("epoch ") >= 3  # one summary line per epoch

    status = main(["evaluate", str(checkpoint), "site.las", "Area_1", "--label-field", "gt", "--out", "eval",
                   "--device", "cpu"])
    evaluated = capsys.readouterr()
    assert status == 0, evaluated.err
    lines = evaluated.out.splitlines()
    assert lines[0] == "| Scene | OA | mIoU | mAcc | FWIoU | κ |"
    assert [line.split("|")[1].strip() for line in lines[2:6]] == ["site", "Area_1/office_1", "**mean**", "**all points**"]
    with (project / "eval" / "evaluation.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [r["scene"] for r in rows] == ["site", "Area_1/office_1", "mean", "all points"]
    assert int(rows[0]["points"]) == len(laspy.read(project / "site.las").points)
    for row in rows:
        assert 0.0 <= float(row["oa"]) <= 1.0 and -1.0 <= float(row["kappa"]) <= 1.0
    mean_oa = (float(rows[0]["oa"]) + float(rows[1]["oa"])) / 2
    assert float(rows[2]["oa"]) == pytest.approx(mean_oa, abs=2e-6)
    assert "| Scene | Wall&Column | Beam | Covering | Slab | Others |" in lines  # IoU per class
    for name in ("evaluation.json", "confusion.csv", "confusion.png"):
        assert (project / "eval" / name).stat().st_size > 0 and name in evaluated.out

    assert main(["predict", str(checkpoint), "site.las", "site-labelled.laz", "--device", "cpu"]) == 0
    predicted = capsys.readouterr()
    assert "wrote site-labelled.laz" in predicted.out
    written = laspy.read(project / "site-labelled.laz")
    assert len(written.points) == len(laspy.read(project / "site.las").points)
    assert set(np.unique(written.classification)) <= set(range(5))

    # a room with a class the S3DIS mapping does not know: prediction reads its points only
    room = project / "Area_1" / "office_1"
    np.savetxt(room / "Annotations" / "radiator_1.txt", np.array([[1.0, 1.0, 0.5, 9, 9, 9], [1.1, 1.0, 0.5, 9, 9, 9]]),
               fmt="%.4f %.4f %.4f %d %d %d")
    assert main(["predict", str(checkpoint), str(room), "room-labelled.laz", "--device", "cpu"]) == 0
    capsys.readouterr()
    assert len(laspy.read(project / "room-labelled.laz").points) == sum(
        len(np.loadtxt(f, ndmin=2)) for f in (room / "Annotations").glob("*.txt"))
    assert main(["evaluate", str(checkpoint), str(room), "--device", "cpu"]) == 1  # scoring needs the class
    assert "unknown S3DIS class 'radiator'" in capsys.readouterr().err


def test_training_resumes_from_the_command_line(project: Path, capsys: pytest.CaptureFixture[str],
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(project)
    config = project / "train.toml"
    config.write_text(config.read_text().replace("epochs = 3", "epochs = 1"))
    assert main(["train", "train.toml", "--out", "one"]) == 0

    assert main(["train", "train.toml", "--out", "one"]) == 1
    assert "pass --resume" in capsys.readouterr().err
    assert main(["train", "train.toml", "--out", "one", "--resume"]) == 0  # nothing left to do, no error


def test_fine_tuning_from_the_command_line_checks_its_start_before_any_work(
    project: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    from bimscan.learn.checkpoint import read_checkpoint

    monkeypatch.chdir(project)
    config = project / "train.toml"
    config.write_text(config.read_text().replace("epochs = 3", "epochs = 1"))
    assert main(["train", "train.toml", "--out", "parent"]) == 0
    parent = project / "parent" / "last.pt"

    assert main(["train", "train.toml", "--out", "missing", "--init", "nowhere.pt"]) == 1
    assert "nowhere.pt" in capsys.readouterr().err and not (project / "missing").exists()
    other = project / "other.toml"
    other.write_text(config.read_text().replace("embed_dim = 16", "embed_dim = 8"))
    assert main(["train", "other.toml", "--out", "other", "--init", str(parent)]) == 1
    error = capsys.readouterr().err
    assert "other [model]" in error and error.count("\n") == 1 and not (project / "other").exists()

    assert main(["train", "train.toml", "--out", "child", "--init", str(parent)]) == 0
    assert read_checkpoint(project / "child" / "last.pt")["init"]["checkpoint"] == str(parent)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("epochs = 3", "epochs = 3\nepoch = 4"), "unknown key(s) 'epoch'"),
        (("epochs = 3", "epochs = 0"), "epochs must be an integer in 1..100000"),
        (("max_lr = 0.01", 'max_lr = "fast"'), "expected a number"),
        (('train = ["spc"]', 'train = ["nowhere"]'), "nowhere: no such file or folder"),
    ],
)
def test_bad_training_input_is_one_error_line_and_exit_1(
    project: Path, capsys: pytest.CaptureFixture[str], edit: tuple[str, str], message: str,
) -> None:
    config = project / "train.toml"
    config.write_text(config.read_text().replace(*edit))

    status = main(["train", str(config)])

    err = capsys.readouterr().err
    assert status == 1
    assert err.startswith("error: ") and err.count("\n") == 1
    assert message in err
    assert not (project / "runs").exists()


def test_evaluate_with_a_missing_checkpoint_is_one_error_line(project: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status = main(["evaluate", str(project / "nope.pt"), str(project / "site.las")])

    err = capsys.readouterr().err
    assert status == 1 and err.startswith("error: ") and err.count("\n") == 1
    assert "no such checkpoint" in err


def test_predict_checks_its_output_before_any_work(project: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (project / "taken.laz").write_bytes(b"keep me")

    for out, message in (("taken.laz", "already exists"), ("out.dwg", "unknown cloud format"),
                         ("out.xyz", "bimscan writes text clouds only as labelled copies of text clouds"),
                         ("missing/out.laz", "does not exist"),
                         ("site.las", "already exists; pass --overwrite")):  # IN itself
        # the checkpoint does not exist either: the output is checked first
        status = main(["predict", str(project / "nope.pt"), str(project / "site.las"), str(project / out)])

        err = capsys.readouterr().err
        assert status == 1 and err.startswith("error: ") and err.count("\n") == 1, err
        assert message in err
    assert (project / "taken.laz").read_bytes() == b"keep me"


def test_evaluation_inputs_without_ground_truth_or_readable_weights_are_one_error_line(
    project: Path, trained_run: Path, capsys: pytest.CaptureFixture[str], foreign_las: Callable[..., Path],
    room: Callable[..., PointCloud],
) -> None:
    checkpoint = str(trained_run / "run" / "last.pt")
    foreign_las(project / "bare.las", room(52, points_per_m2=10), classification=0)
    (project / "bad.pt").write_bytes(b"\x80\x02junk" * 50)

    for argv, message in (
        ([checkpoint, str(project / "bare.las")], "no ground-truth labels"),
        ([str(project / "bad.pt"), str(project / "site.las")], "not a readable checkpoint"),
        ([checkpoint, str(project / "Area_1"), "--label-field", "gt"], "cannot apply to S3DIS rooms"),
    ):
        status = main(["evaluate", *argv, "--device", "cpu"])

        err = capsys.readouterr().err
        assert status == 1 and err.startswith("error: ") and err.count("\n") == 1, err
        assert message in err


def test_training_with_an_unlabelled_validation_set_is_one_error_line(
    project: Path, capsys: pytest.CaptureFixture[str], foreign_las: Callable[..., Path],
    room: Callable[..., PointCloud],
) -> None:
    foreign_las(project / "bare.las", room(53, points_per_m2=40), classification=1)
    config = project / "train.toml"
    config.write_text(config.read_text().replace('val = { scenes = ["site.las"], label_field = "gt" }', 'val = ["bare.las"]'))

    status = main(["train", str(config)])

    err = capsys.readouterr().err
    assert status == 1 and err.startswith("error: ") and err.count("\n") == 1, err
    assert "no ground-truth labels" in err


@pytest.mark.slow
def test_a_trained_model_adapts_to_unlabelled_scans_from_the_command_line(
    project: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, room: Callable[..., PointCloud],
) -> None:
    """train, then adapt to two unlabelled scans (one with labels in its file: never read), then
    predict with the adapted model; the same command again continues or finds it finished."""
    from bimscan.io.text import write_text_cloud

    monkeypatch.chdir(project)
    config = project / "train.toml"
    config.write_text(config.read_text().replace("epochs = 3", "epochs = 1"))
    assert main(["train", "train.toml"]) == 0
    checkpoint = project / "runs" / "tiny" / "last.pt"
    write_text_cloud(project / "mine1.xyz", PointCloud(xyz=room(60, size_m=(5.0, 4.0), points_per_m2=40).xyz))
    capsys.readouterr()

    elsewhere = project / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the checkpoint's data is found where its configuration was
    assert main(["adapt", str(checkpoint), "../mine1.xyz", "../site.las", "adapted", "--device", "cpu"]) == 0
    adapted = capsys.readouterr()
    assert "pseudo-labels kept per class: Wall&Column" in adapted.err
    assert "label a scan with 'bimscan predict adapted/last.pt SCAN OUT.laz'" in adapted.out
    assert main(["adapt", str(checkpoint), "../mine1.xyz", "../site.las", "adapted", "--device", "cpu"]) == 0
    assert "in 1 epoch(s)" in capsys.readouterr().out  # finished: nothing left to do
    assert main(["predict", "adapted/last.pt", "../mine1.xyz", "mine1.laz", "--device", "cpu"]) == 0

    assert main(["adapt", str(checkpoint), "../mine1.xyz", "other", "--synthetic", "../missing"]) == 1
    assert "missing: no such file or folder" in capsys.readouterr().err
    (project / "spc").rename(project / "spc-moved")
    assert main(["adapt", str(checkpoint), "../mine1.xyz", "other"]) == 1
    err = capsys.readouterr().err
    assert "the synthetic data it trained on is not here" in err and "--synthetic PATH" in err
    assert not (elsewhere / "other").exists()

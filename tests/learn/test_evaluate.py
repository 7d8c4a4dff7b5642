"""Evaluation: one row per scene from every point, the mean and pooled rows, per-class IoU and
confusion matrices equal to scikit-learn's in every file written, and scenes without ground
truth refused."""

from __future__ import annotations

import csv
import json
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from sklearn.metrics import confusion_matrix, jaccard_score

from bimscan.errors import LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.evaluate import (
    SceneEvaluation, evaluate_checkpoint, format_class_iou_markdown, format_csv, format_markdown, summarize_results,
    write_evaluation,
)
from bimscan.learn.infer import SceneLabels
from bimscan.learn.train_config import EvalConfig
from bimscan.learn.metrics import compute_confusion, compute_metrics
from bimscan.types import PointCloud


def test_each_scene_is_scored_on_every_point_with_mean_and_pooled_rows(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud],
) -> None:
    scenes = []
    for seed in (30, 31):
        cloud = room(seed, size_m=(4.0, 3.5), points_per_m2=30)
        write_text_cloud(tmp_path / f"real{seed}.txt", cloud)
        scenes.append((tmp_path / f"real{seed}.txt", cloud))

    results = evaluate_checkpoint(trained_run / "run" / "last.pt", [p for p, _ in scenes], device="cpu")

    assert [r.scene for r in results] == ["real30", "real31"]
    for result, (_, cloud) in zip(results, scenes, strict=True):
        assert result.labels.points == result.labels.labelled == len(cloud)
        assert result.labels.confusion.sum() == len(cloud)
        np.testing.assert_array_equal(result.labels.confusion.sum(axis=1), np.bincount(cloud.label, minlength=5))
        assert result.metrics.oa > 0.4  # trained three epochs on rooms like these
    rows = dict(summarize_results(results))
    assert rows["mean"]["miou"] == pytest.approx((results[0].metrics.miou + results[1].metrics.miou) / 2)
    pooled = compute_metrics(results[0].labels.confusion + results[1].labels.confusion)
    assert rows["all points"]["kappa"] == pytest.approx(pooled.kappa)
    markdown = format_markdown(results)
    assert f"| real30 | {100 * results[0].metrics.oa:.1f} |" in markdown
    table = format_csv(results, ["Wall&Column", "Beam", "Covering", "Slab", "Others"]).splitlines()
    assert table[0].startswith("scene,oa,miou,macc,fwiou,kappa,points")
    assert table[1].endswith("Wall&Column;Beam;Covering;Slab;Others")

    files = write_evaluation(results, tmp_path / "eval", results[0].class_names, title="tiny")
    document = json.loads(files.json.read_text(encoding="utf-8"))
    assert document["all points"]["confusion"]["matrix"] == pooled_confusion(results).tolist()
    assert "IoU per class" in files.markdown.read_text(encoding="utf-8")


def _components(ifc_classes: list[str], labels: list[int]):
    from bimscan.types import ComponentTable

    n = len(ifc_classes)

    def text(values: list[str]) -> np.ndarray:
        return np.array(values, dtype=str)

    return ComponentTable(global_id=text([f"g{i}" for i in range(n)]), ifc_class=text(ifc_classes),
                          predefined_type=text([""] * n), name=text([f"c{i}" for i in range(n)]),
                          storey=text([""] * n), parent_class=text([""] * n), label=np.array(labels, dtype=np.uint8))


@pytest.mark.parametrize("name", ["scene.laz", "scene"])  # LAZ, NumPy folder
def test_a_bimscan_cloud_is_also_scored_per_ifc_class(tmp_path: Path, trained_run: Path,
                                                      room: Callable[..., PointCloud], name: str) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.semantics.scheme import load_scheme
    from bimscan.types import CloudHeader

    cloud = room(42, points_per_m2=30)
    rng = np.random.default_rng(0)
    # components 0-4 carry the points of their own class; some wall points lie on a column (5);
    # some Others points on no component (-1: as a scan's clutter outside the model)
    component = cloud.label.astype(np.int32)
    component[(cloud.label == 0) & (rng.random(len(cloud)) < 0.3)] = 5
    component[(cloud.label == 4) & (rng.random(len(cloud)) < 0.3)] = -1
    components = _components(["IfcWall", "IfcBeam", "IfcCovering", "IfcSlab", "IfcFurniture", "IfcColumn"],
                             [0, 1, 2, 3, 4, 0])
    with open_cloud_writer(tmp_path / name, header=CloudHeader(scheme=load_scheme(), components=components)) as out:
        out.write(PointCloud(xyz=cloud.xyz, label=cloud.label, component=component))

    (result,) = evaluate_checkpoint(trained_run / "run" / "last.pt", [tmp_path / name], device="cpu")

    elements = result.elements
    assert elements is not None
    rows = {(c, t): counts for c, t, counts in zip(elements.ifc_class, elements.truth, elements.counts, strict=True)}
    assert set(rows) == {("IfcWall", "Wall&Column"), ("IfcColumn", "Wall&Column"), ("IfcBeam", "Beam"),
                         ("IfcCovering", "Covering"), ("IfcSlab", "Slab"), ("IfcFurniture", "Others"),
                         ("(no component)", "")}
    index = {"IfcWall": 0, "IfcBeam": 1, "IfcCovering": 2, "IfcSlab": 3, "IfcFurniture": 4, "IfcColumn": 5}
    for (ifc_class, _), counts in rows.items():  # every point counted once, on its own component
        assert counts.sum() == (component == index.get(ifc_class, -1)).sum()
    # the rows of one labelled class add up to that class's row of the confusion matrix
    confusion = result.labels.confusion
    np.testing.assert_array_equal(rows[("IfcWall", "Wall&Column")] + rows[("IfcColumn", "Wall&Column")], confusion[0])
    np.testing.assert_array_equal(rows[("IfcFurniture", "Others")] + rows[("(no component)", "")], confusion[4])
    np.testing.assert_array_equal(rows[("IfcSlab", "Slab")], confusion[3])
    files = write_evaluation([result], tmp_path / "eval", result.class_names)
    assert files.elements is not None and files.elements in files.paths()
    table = list(csv.reader(files.elements.read_text(encoding="utf-8").splitlines()))
    assert table[0][:4] == ["scene", "source_class", "labelled", "points"] and len(table) == 1 + 2 * len(rows)
    markdown = files.markdown.read_text(encoding="utf-8")
    assert "Where each source class's points went" in markdown and "| IfcColumn | Wall&Column |" in markdown


def test_a_scene_without_ground_truth_is_refused(tmp_path: Path, trained_run: Path,
                                                 room: Callable[..., PointCloud]) -> None:
    cloud = room(40, points_per_m2=10)
    write_text_cloud(tmp_path / "bare.xyz", PointCloud(xyz=cloud.xyz))

    with pytest.raises(LearnError, match="no point has a ground-truth class"):
        evaluate_checkpoint(trained_run / "run" / "last.pt", [tmp_path / "bare.xyz"], device="cpu")


def test_evaluation_leaves_denormal_floats_working(tmp_path: Path, trained_run: Path,
                                                   room: Callable[..., PointCloud]) -> None:
    write_text_cloud(tmp_path / "scene.txt", room(41, points_per_m2=10))

    evaluate_checkpoint(trained_run / "run" / "last.pt", [tmp_path / "scene.txt"], device="cpu")

    # inference flushes denormals to zero for speed; that must not outlive it
    assert np.nextafter(0.0, 1.0) > 0.0
    assert np.float32(1e-40) != 0.0


def test_an_unclassified_foreign_las_is_refused_for_evaluation_but_predicted(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud], foreign_las: Callable[..., Path],
) -> None:
    from bimscan.learn.predict import predict_cloud

    scan = foreign_las(tmp_path / "site.las", room(42, points_per_m2=10), classification=1)

    with pytest.raises(LearnError, match="no ground-truth labels: its LAS classification is only 0/1"):
        evaluate_checkpoint(trained_run / "run" / "last.pt", [scan], device="cpu")
    result = predict_cloud(trained_run / "run" / "last.pt", scan, tmp_path / "labelled.laz", device="cpu")

    assert result.points > 0
    (scored,) = evaluate_checkpoint(trained_run / "run" / "last.pt", [scan], label_field="gt", device="cpu")
    assert scored.labels.labelled == scored.labels.points  # with the right field it scores


CLASS_NAMES = ("Wall&Column", "Beam", "Covering", "Slab", "Others")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def pooled_confusion(results: list[SceneEvaluation]) -> np.ndarray:
    return np.sum([r.labels.confusion for r in results], axis=0)


def scored_scene(name: str, truth: np.ndarray, prediction: np.ndarray) -> SceneEvaluation:
    """A scene's evaluation from given labels, as ``evaluate_checkpoint`` returns it."""
    confusion = compute_confusion(truth, prediction, num_classes=len(CLASS_NAMES))
    labels = SceneLabels(name=name, points=len(truth), labelled=len(truth), confusion=confusion, blocks=1, passes=1,
                         nearest_filled=0, lower=np.zeros(3), upper=np.ones(3), seconds=0.0)
    return SceneEvaluation(name, Path(f"{name}.txt"), labels, compute_metrics(confusion), CLASS_NAMES, EvalConfig())


def random_scenes(seed: int) -> tuple[list[SceneEvaluation], list[tuple[np.ndarray, np.ndarray]]]:
    """Three scenes of random labels: in the second, Beam (1) never occurs; Others (4) is
    absent from every scene's ground truth and predicted only in the first."""
    rng = np.random.default_rng(seed)
    labels = []
    for i, size in enumerate(rng.integers(50, 400, size=3)):
        occurring = [0, 2, 3] if i == 1 else [0, 1, 2, 3]
        truth = rng.choice(occurring, size=size)
        guesses = rng.choice(occurring + [4] if i == 0 else occurring, size=size)
        prediction = np.where(rng.random(size) < 0.3, guesses, truth)
        labels.append((truth, prediction))
    return [scored_scene(f"scene{i}", t, p) for i, (t, p) in enumerate(labels)], labels


def expected_iou(truth: np.ndarray, prediction: np.ndarray) -> list[float | None]:
    """scikit-learn's IoU per class, None for a class neither true nor predicted."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # classes without ground truth
        iou = jaccard_score(truth, prediction, labels=range(len(CLASS_NAMES)), average=None, zero_division=0)
    present = np.isin(range(len(CLASS_NAMES)), np.union1d(truth, prediction))
    return [float(v) if p else None for v, p in zip(iou, present, strict=True)]


@pytest.mark.parametrize("seed", range(5))
def test_the_json_and_confusion_files_hold_scikit_learns_matrices_and_iou(tmp_path: Path, seed: int) -> None:
    results, labels = random_scenes(seed)

    files = write_evaluation(results, tmp_path / "eval", CLASS_NAMES, title=f"seed {seed}")

    assert [p.name for p in files.paths()] == [
        "evaluation.md", "evaluation.csv", "evaluation.json", "confusion.csv", "confusion.png"]
    document = json.loads(files.json.read_text(encoding="utf-8"))
    assert document["class_names"] == list(CLASS_NAMES)
    for entry, (truth, prediction) in zip(document["scenes"], labels, strict=True):
        assert entry["confusion"]["class_names"] == list(CLASS_NAMES)
        assert entry["confusion"]["matrix"] == confusion_matrix(truth, prediction, labels=range(5)).tolist()
        iou = [entry["iou"][c] for c in CLASS_NAMES]
        assert iou == pytest.approx(expected_iou(truth, prediction))
        assert [entry["support"][c] for c in CLASS_NAMES] == np.bincount(truth, minlength=5).tolist()
        assert entry["points"] == len(truth)
    truth, prediction = (np.concatenate(part) for part in zip(*labels, strict=True))
    pooled = document["all points"]
    scene_sum = np.sum([e["confusion"]["matrix"] for e in document["scenes"]], axis=0)
    assert pooled["confusion"]["matrix"] == scene_sum.tolist()
    assert pooled["confusion"]["matrix"] == confusion_matrix(truth, prediction, labels=range(5)).tolist()
    assert [pooled["iou"][c] for c in CLASS_NAMES] == pytest.approx(expected_iou(truth, prediction))
    assert pooled["acc"]["Others"] is None  # no ground truth anywhere: no recall
    assert pooled["metrics"]["kappa"] == pytest.approx(compute_metrics(pooled_confusion(results)).kappa)
    assert document["mean"]["metrics"]["miou"] == pytest.approx(np.mean([r.metrics.miou for r in results]))
    assert document["mean"]["iou"]["Beam"] == pytest.approx((results[0].metrics.iou[1] + results[2].metrics.iou[1]) / 2)

    with files.confusion_table.open(newline="", encoding="utf-8") as handle:
        rows = list(csv.reader(handle))
    assert rows[0][1:] == list(CLASS_NAMES) and [r[0] for r in rows[1:]] == list(CLASS_NAMES)
    assert [[int(v) for v in r[1:]] for r in rows[1:]] == pooled["confusion"]["matrix"]
    png = files.confusion_plot.read_bytes()
    assert png.startswith(PNG_SIGNATURE) and len(png) > 1000


def test_the_per_class_table_shows_a_dash_for_an_absent_class() -> None:
    results, _ = random_scenes(7)

    table = format_class_iou_markdown(results).splitlines()

    assert table[0] == "| Scene | Wall&Column | Beam | Covering | Slab | Others |"
    assert [row.split("|")[1].strip() for row in table[2:]] == ["scene0", "scene1", "scene2", "**all points**"]
    scene1 = [cell.strip() for cell in table[3].split("|")[2:-1]]
    assert scene1[1] == "-" and scene1[4] == "-"  # Beam and Others neither true nor predicted there
    assert scene1[0] == f"{100 * results[1].metrics.iou[0]:.1f}"
    pooled = [cell.strip() for cell in table[5].split("|")[2:-1]]
    assert pooled[4] == "0.0"  # predicted in scene0, never true: a false alarm, IoU 0
    assert format_class_iou_markdown(results) in format_markdown(results)
    assert format_class_iou_markdown(results) not in format_markdown(results, class_iou=False)


# An evaluation that stops for good once its stripe files are written: killed there, it leaves them.
STALLED_EVALUATION = """
import sys, time
from pathlib import Path
from bimscan.learn import infer
from bimscan.learn.evaluate import evaluate_checkpoint

def stalled(self, counts):
    Path(sys.argv[3]).write_text("bucketed")
    time.sleep(600)

infer._Labeller._label_stripes = stalled
evaluate_checkpoint(sys.argv[1], [sys.argv[2]], device="cpu")
"""


@pytest.mark.slow
def test_the_stripes_of_a_killed_evaluation_are_removed_from_tmpdir_by_the_next_one(
    tmp_path: Path, trained_run: Path, room: Callable[[int], PointCloud], monkeypatch: pytest.MonkeyPatch,
) -> None:
    import os
    import subprocess
    import sys
    import tempfile
    import time

    scratch, ready = tmp_path / "tmpdir", tmp_path / "ready"
    scratch.mkdir()
    write_text_cloud(tmp_path / "scene.txt", room(7))
    checkpoint = trained_run / "run" / "last.pt"
    process = subprocess.Popen([sys.executable, "-c", STALLED_EVALUATION, str(checkpoint), str(tmp_path / "scene.txt"),
                                str(ready)], env={**os.environ, "TMPDIR": str(scratch)})
    start = time.monotonic()
    while not ready.exists():
        assert process.poll() is None and time.monotonic() - start < 120
        time.sleep(0.05)
    process.kill()
    process.wait()
    left = [p.name for p in scratch.iterdir()]
    assert len(left) == 1 and left[0].startswith(f".bimscan-stripes.{process.pid}-")

    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # $TMPDIR, as tempfile.gettempdir() read it
    evaluate_checkpoint(checkpoint, [tmp_path / "scene.txt"], device="cpu")

    assert list(scratch.iterdir()) == []


def test_an_s3dis_room_is_also_scored_per_annotation_class(tmp_path: Path, trained_run: Path) -> None:
    """Where a real room's boards, doors and walls went: one row per S3DIS class, each point once,
    labelled with the class the shipped mapping gives it."""
    rng = np.random.default_rng(0)
    notes = tmp_path / "Area_9" / "office_1" / "Annotations"
    notes.mkdir(parents=True)
    grid = np.stack(np.meshgrid(np.arange(0.0, 4.0, 0.1), np.arange(0.0, 3.0, 0.1)), -1).reshape(-1, 2)
    parts = {"floor": np.c_[grid, np.zeros(len(grid))], "ceiling": np.c_[grid, np.full(len(grid), 2.8)],
             "wall": np.c_[rng.uniform(0, 4, 300), np.zeros(300), rng.uniform(0, 2.8, 300)],
             "board": np.c_[rng.uniform(1, 2, 40), np.full(40, 0.02), rng.uniform(1, 2, 40)],
             "chair": np.c_[rng.uniform(1, 1.5, 50), rng.uniform(1, 1.5, 50), rng.uniform(0, 0.9, 50)]}
    for name, xyz in parts.items():
        np.savetxt(notes / f"{name}_1.txt", np.c_[xyz, np.full((len(xyz), 3), 128)], fmt="%.4f")

    (result,) = evaluate_checkpoint(trained_run / "run" / "last.pt", [tmp_path / "Area_9" / "office_1"], device="cpu")

    breakdown = result.elements
    assert breakdown is not None
    rows = {name: (truth, int(points)) for name, truth, points in
            zip(breakdown.ifc_class, breakdown.truth, breakdown.points, strict=True)}
    assert rows == {"board": ("Others", 40), "ceiling": ("Covering", len(grid)), "chair": ("Others", 50),
                    "floor": ("Slab", len(grid)), "wall": ("Wall&Column", 300)}
    assert int(breakdown.counts.sum()) == result.labels.points
    files = write_evaluation([result], tmp_path / "eval", result.class_names)
    assert "| board | Others | 40 |" in files.markdown.read_text()

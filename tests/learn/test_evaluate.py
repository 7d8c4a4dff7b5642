"""Evaluation: one row per scene from every point, the mean and pooled rows, and scenes
without ground truth refused."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.evaluate import evaluate_checkpoint, format_csv, format_markdown, summarize_results
from bimscan.learn.metrics import compute_metrics
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

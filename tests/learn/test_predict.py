"""Prediction: every point of a scan labelled and written with bimscan.io (class in
classification), the other columns kept, reproducible bytes, atomic on failure."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import laspy
import numpy as np
import pytest

from bimscan.errors import InputFileError, OutputError
from bimscan.io import read_cloud, read_cloud_header
from bimscan.io.text import write_text_cloud
from bimscan.learn.predict import predict_cloud
from bimscan.learn.train_config import EvalConfig
from bimscan.types import PointCloud


@pytest.fixture
def scan(tmp_path: Path, room: Callable[..., PointCloud]) -> Path:
    """A foreign LAS scan, as another tool writes it: labels in an extra dimension 'gt'."""
    cloud = room(21, size_m=(4.0, 3.0), points_per_m2=30, origin=(512_000.0, 5_400_000.0))
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.floor(cloud.xyz.min(axis=0))
    header.scales = np.array([0.001, 0.001, 0.001])
    header.add_extra_dim(laspy.ExtraBytesParams(name="gt", type=np.uint8))
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.intensity = np.arange(len(cloud), dtype=np.uint16)
    las.gt = cloud.label
    las.classification = np.full(len(cloud), 1, dtype=np.uint8)
    path = tmp_path / "site.las"
    las.write(path)
    return path


def test_prediction_labels_every_point_and_keeps_the_other_columns(
    tmp_path: Path, trained_run: Path, scan: Path,
) -> None:
    out = tmp_path / "labelled.laz"

    result = predict_cloud(trained_run / "run" / "last.pt", scan, out, device="cpu")

    source = laspy.read(scan)
    written = laspy.read(out)
    assert len(written.points) == len(source.points) == result.points
    assert written.classification.max() < 5
    np.testing.assert_array_equal(np.bincount(written.classification, minlength=5), result.class_counts)
    np.testing.assert_array_equal(np.asarray(written.intensity), np.asarray(source.intensity))
    np.testing.assert_allclose(written.x, source.x, atol=1e-4)
    header = read_cloud_header(out)
    assert header is not None
    assert [c.name for c in header.scheme.classes] == ["Wall&Column", "Beam", "Covering", "Slab", "Others"]
    # a trained model, not noise: most points agree with the scan's own ground truth
    agreement = float(np.mean(np.asarray(written.classification) == np.asarray(source.gt)))
    assert agreement > 0.5


def test_prediction_is_reproducible_to_the_byte(tmp_path: Path, trained_run: Path, scan: Path) -> None:
    checkpoint = trained_run / "run" / "last.pt"

    once = EvalConfig(max_passes=1)
    predict_cloud(checkpoint, scan, tmp_path / "a.laz", device="cpu", evaluation=once)
    predict_cloud(checkpoint, scan, tmp_path / "b.laz", device="cpu", evaluation=once)

    assert (tmp_path / "a.laz").read_bytes() == (tmp_path / "b.laz").read_bytes()


def test_prediction_of_a_text_scan_into_a_numpy_folder(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud],
) -> None:
    write_text_cloud(tmp_path / "scan.txt", room(5, points_per_m2=20))

    result = predict_cloud(trained_run / "run" / "last.pt", tmp_path / "scan.txt", tmp_path / "out", device="cpu")

    cloud = read_cloud(tmp_path / "out")
    assert len(cloud) == result.points and cloud.label is not None


def test_prediction_refuses_to_overwrite_and_leaves_nothing_on_failure(
    tmp_path: Path, trained_run: Path, scan: Path,
) -> None:
    out = tmp_path / "labelled.laz"
    out.write_bytes(b"keep me")

    with pytest.raises(OutputError, match="already exists"):
        predict_cloud(trained_run / "run" / "last.pt", scan, out, device="cpu")
    with pytest.raises(InputFileError, match="not a bimscan PCT checkpoint|not a readable checkpoint"):
        predict_cloud(scan, scan, tmp_path / "other.laz", device="cpu")

    assert out.read_bytes() == b"keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labelled.laz", "site.las"]

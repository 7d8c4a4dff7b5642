"""A unit's post-checks read back what was written: a damaged or short output is caught."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.dataset.tasks import check_written
from bimscan.io import open_cloud_writer
from bimscan.errors import SemanticError
from bimscan.process.summary import CloudSummary
from bimscan.semantics import load_scheme
from bimscan.types import CloudHeader, PointCloud

N = 5000


def _write(path: Path):
    rng = np.random.default_rng(1)
    cloud = PointCloud(xyz=rng.uniform(0, 10, (N, 3)), label=rng.integers(0, 5, N).astype(np.uint8))
    summary = CloudSummary()
    summary.add(cloud)
    with open_cloud_writer(path, header=CloudHeader(scheme=load_scheme())) as writer:
        writer.write(cloud)
    return summary, writer.close()


@pytest.mark.parametrize("name", ["cloud.las", "cloud.laz", "cloud.ply", "cloud"])
def test_an_intact_output_passes_and_a_count_the_stream_did_not_have_fails(tmp_path: Path, name: str) -> None:
    summary, written = _write(tmp_path / name)
    check_written(summary, {"x": written})
    summary.points += 1  # as if a chunk had been dropped on the way to the file
    with pytest.raises(SemanticError, match=f"holds {N} points, the stream had {N + 1}"):
        check_written(summary, {"x": written})


@pytest.mark.parametrize("name, file", [("cloud.las", "cloud.las"), ("cloud.laz", "cloud.laz"), ("cloud.ply", "cloud.ply"),
                                        ("cloud", "cloud/coord.npy")])
def test_a_truncated_output_is_caught(tmp_path: Path, name: str, file: str) -> None:
    summary, written = _write(tmp_path / name)
    target = tmp_path / file
    target.write_bytes(target.read_bytes()[:-1000])
    with pytest.raises(SemanticError, match="cannot be read back"):
        check_written(summary, {"x": written})


def test_an_empty_scan_fails_the_unit(tmp_path: Path) -> None:
    with pytest.raises(SemanticError, match="no point"):
        check_written(CloudSummary(), {})

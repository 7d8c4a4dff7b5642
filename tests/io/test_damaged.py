"""Damaged clouds are refused in one line: degenerate LAS scales, disagreeing point counts,
non-finite coordinates; FIFOs and link loops are named for what they are (issue 13); labelled copies of
damaged clouds likewise, leaving nothing at the output (issue 50)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import laspy
import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.errors import InputFileError
from bimscan.io import read_cloud

# Byte offsets in a LAS 1.4 header (ASPRS LAS 1.4 R15, Table 3).
LEGACY_COUNT, X_SCALE, X_OFFSET, POINT_COUNT = 107, 131, 155, 247


@pytest.fixture
def las_file(tmp_path: Path) -> Path:
    header = laspy.LasHeader(version="1.4", point_format=6)
    header.scales, header.offsets = [0.001] * 3, [100.0, 200.0, 0.0]
    data = laspy.LasData(header)
    rng = np.random.default_rng(5)
    data.x, data.y, data.z = 100 + 10 * rng.random(500), 200 + 10 * rng.random(500), 3 * rng.random(500)
    path = tmp_path / "ok.las"
    data.write(path)
    return path


def _patched(path: Path, offset: int, fmt: str, value: float | int, *more: tuple[int, str, float | int]) -> Path:
    data = bytearray(path.read_bytes())
    for at, kind, number in ((offset, fmt, value), *more):
        struct.pack_into(kind, data, at, number)
    out = path.with_name(f"damaged-{offset}-{value}.las")
    out.write_bytes(bytes(data))
    return out


def test_an_undamaged_file_reads(las_file):
    cloud = read_cloud(las_file)
    assert len(cloud) == 500 and np.isfinite(cloud.xyz).all()


@pytest.mark.parametrize("offset, fmt, value, words", [
    (X_SCALE, "<d", 0.0, "x scale 0.0"),
    (X_SCALE, "<d", float("nan"), "x scale nan"),
    (X_SCALE, "<d", -0.001, "x scale -0.001"),
    (X_OFFSET, "<d", float("inf"), "offset inf"),
    (POINT_COUNT, "<Q", 5000, "says 5,000 points, the file holds 500"),
    (LEGACY_COUNT, "<I", 7, "two point counts"),
])
def test_a_damaged_las_header_is_refused_in_one_line(las_file, offset, fmt, value, words):
    damaged = _patched(las_file, offset, fmt, value)
    with pytest.raises(InputFileError, match=words) as error:
        read_cloud(damaged)
    assert "\n" not in str(error.value)


def test_a_point_count_too_small_for_the_data_is_refused(las_file):
    damaged = _patched(las_file, POINT_COUNT, "<Q", 10, (LEGACY_COUNT, "<I", 10))
    with pytest.raises(InputFileError, match="says 10 points, the file holds 500"):
        read_cloud(damaged)


def test_non_finite_points_are_refused_naming_the_first(tmp_path):
    path = tmp_path / "nan.ply"
    rows = ["0 0 0", "1 2 3", "nan 2 3", "4 inf 6"]
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\n"
                    "property double z\nend_header\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputFileError, match=r"point 2 has coordinates \[nan, 2.0, 3.0\] \(2 non-finite"):
        read_cloud(path)


def test_the_cli_refuses_a_damaged_cloud_with_one_error_line(las_file, tmp_path, capsys):
    damaged = _patched(las_file, X_SCALE, "<d", 0.0)
    assert main(["render", str(damaged), str(tmp_path / "out.png")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "scale" in err
    assert not (tmp_path / "out.png").exists()


def test_a_fifo_and_a_link_loop_are_named_not_read(tmp_path):
    fifo = tmp_path / "cloud.laz"
    os.mkfifo(fifo)  # reading it would wait for a writer forever
    with pytest.raises(InputFileError, match="FIFO"):
        read_cloud(fifo)
    loop = tmp_path / "loop.las"
    loop.symlink_to(loop)
    with pytest.raises(InputFileError, match="symbolic link loop"):
        read_cloud(loop)


# -- labelled copies of damaged clouds (issue 50): one line, nothing left at the output -------------

def _labelled_copy(source: Path, target: Path, n: int) -> None:
    from bimscan.io import plan_labelled_copy, write_labelled_copy
    from bimscan.semantics import DEFAULT_SCHEME, load_scheme
    from bimscan.types import CloudHeader

    plan = plan_labelled_copy(source, target)
    write_labelled_copy(plan, np.zeros(n, np.uint8), header=CloudHeader(scheme=load_scheme(DEFAULT_SCHEME)))


def test_a_las_cut_short_is_refused_by_its_labelled_copy(las_file, tmp_path):
    cut = tmp_path / "cut.las"
    cut.write_bytes(las_file.read_bytes()[:-200])

    with pytest.raises(InputFileError, match="cut.las: the LAS header says 500 points, the file holds 493"):
        _labelled_copy(cut, tmp_path / "out.las", 500)
    assert not any(p.name.startswith((".out", "out")) for p in tmp_path.iterdir())


def test_a_ply_cut_short_is_refused_by_its_labelled_copy(tmp_path):
    vertices = np.zeros(10, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4")])
    (tmp_path / "cut.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\n"
                                       b"property float y\nproperty float z\nproperty float nx\nend_header\n"
                                       + vertices.tobytes()[:-20])

    with pytest.raises(InputFileError, match="cut.ply: PLY body ends after 8 of 10 vertices; the file is truncated"):
        _labelled_copy(tmp_path / "cut.ply", tmp_path / "out.ply", 10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.ply"]


def test_a_text_line_short_of_columns_is_refused_by_its_labelled_copy(tmp_path):
    (tmp_path / "ragged.txt").write_text("x y z label\n1 2 3 0\n4 5 6\n")

    with pytest.raises(InputFileError, match=r"ragged.txt: point line 2 '4 5 6' has fewer columns than the first"):
        _labelled_copy(tmp_path / "ragged.txt", tmp_path / "out.txt", 2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ragged.txt"]

"""Plain-text clouds: labels round-trip, every documented layout reads, errors are one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import InputFileError, OutputError
from bimscan.io import count_points, iter_cloud_chunks, read_cloud
from bimscan.io.text import iter_text_chunks, write_text_cloud
from bimscan.types import PointCloud


def _cloud(n: int, seed: int = 0, labels: bool = True) -> PointCloud:
    rng = np.random.default_rng(seed)
    xyz = rng.normal(scale=20.0, size=(n, 3)) + [512_000.0, 5_400_000.0, 300.0]  # real-world offsets
    return PointCloud(xyz=xyz, label=rng.integers(0, 256, n).astype(np.uint8) if labels else None)


def test_text_cloud_round_trips_labels_and_coordinates(tmp_path: Path) -> None:
    cloud = _cloud(2000)

    write_text_cloud(tmp_path / "scan.txt", cloud)
    back = read_cloud(tmp_path / "scan.txt")

    np.testing.assert_array_equal(back.label, cloud.label)
    np.testing.assert_allclose(back.xyz, cloud.xyz, atol=5.1e-7, rtol=0)


def test_text_cloud_without_labels_reads_back_without_labels(tmp_path: Path) -> None:
    cloud = _cloud(10, labels=False)

    write_text_cloud(tmp_path / "scan.xyz", cloud)
    back = read_cloud(tmp_path / "scan.xyz")

    assert back.label is None and len(back) == 10


@pytest.mark.parametrize(
    ("text", "labels"),
    [
        ("1 2 3\n4 5 6\n", None),
        ("1 2 3 7\n4 5 6 9\n", [7, 9]),
        ("1 2 3 10 20 30\n4 5 6 10 20 30\n", None),
        ("1 2 3 10 20 30 4\n4 5 6 10 20 30 0\n", [4, 0]),
        ("x,y,z,red,green,blue,classification\n1,2,3,9,9,9,5\n4,5,6,9,9,9,6\n", [5, 6]),
        ("// exported\n2\n1 2 3 1\n4 5 6 2\n", [1, 2]),  # .pts count line and a comment
        ("label x y z\n3 1 2 3\n4 4 5 6\n", [3, 4]),  # named columns in any order
    ],
)
def test_every_documented_text_layout_reads(tmp_path: Path, text: str, labels: list[int] | None) -> None:
    path = tmp_path / "cloud.txt"
    path.write_text(text)

    cloud = read_cloud(path)

    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [4, 5, 6]])
    if labels is None:
        assert cloud.label is None
    else:
        assert cloud.label.tolist() == labels


def test_chunks_join_to_the_whole_cloud(tmp_path: Path) -> None:
    cloud = _cloud(1234, seed=5)
    write_text_cloud(tmp_path / "scan.txt", cloud)

    chunks = list(iter_text_chunks(tmp_path / "scan.txt", chunk_points=100))

    assert [len(c) for c in chunks] == [100] * 12 + [34]
    joined = PointCloud.concatenate(chunks)
    np.testing.assert_array_equal(joined.label, read_cloud(tmp_path / "scan.txt").label)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1 2 3 4.5\n", "not an integer in 0..255"),
        ("1 2 3 300\n", "not an integer in 0..255"),
        ("1 2 3 4\n1 2 3 x\n", "unreadable point line near line 2"),
        ("1 2 3 4 5\n", "has 5 columns"),
        ("# only a comment\n", "holds no points"),
        ("a,b,c\n1,2,3\n", "names no column 'x'"),
    ],
)
def test_bad_text_clouds_fail_with_a_one_line_error(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.txt"
    path.write_text(text)

    with pytest.raises(InputFileError, match=message) as caught:
        read_cloud(path)
    assert "\n" not in str(caught.value)


def test_writing_over_an_existing_file_needs_overwrite_and_leaves_no_temporary(tmp_path: Path) -> None:
    path = tmp_path / "scan.txt"
    write_text_cloud(path, _cloud(5))
    before = path.read_bytes()

    with pytest.raises(OutputError, match="already exists"):
        write_text_cloud(path, _cloud(7, seed=1))
    write_text_cloud(path, _cloud(7, seed=1), overwrite=True)

    assert path.read_bytes() != before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan.txt"]


def test_same_cloud_gives_the_same_bytes(tmp_path: Path) -> None:
    write_text_cloud(tmp_path / "a.txt", _cloud(300, seed=9))
    write_text_cloud(tmp_path / "b.txt", _cloud(300, seed=9))

    assert (tmp_path / "a.txt").read_bytes() == (tmp_path / "b.txt").read_bytes()


@pytest.mark.parametrize(
    "lines",
    [
        "1 2 3 -1200\n4 5 6 300\n",  # x y z intensity
        "1 2 3 -1200 10 20 30\n4 5 6 300 10 20 30\n",  # x y z intensity r g b
    ],
)
def test_leica_pts_columns_after_xyz_are_intensity_and_colour_never_a_label(tmp_path: Path, lines: str) -> None:
    path = tmp_path / "scan.pts"
    path.write_text("2\n" + lines)

    cloud = read_cloud(path)

    np.testing.assert_array_equal(cloud.xyz, [[1, 2, 3], [4, 5, 6]])
    assert cloud.label is None


def test_a_label_field_names_a_header_column_and_needs_a_header(tmp_path: Path) -> None:
    named = tmp_path / "named.txt"
    named.write_text("x y z label gt\n1 2 3 9 1\n4 5 6 9 2\n")
    bare = tmp_path / "bare.txt"
    bare.write_text("1 2 3 4\n")

    (chunk,) = iter_text_chunks(named, label_field="GT")

    assert chunk.label.tolist() == [1, 2]
    with pytest.raises(InputFileError, match="no column 'truth' to read labels from"):
        list(iter_text_chunks(named, label_field="truth"))
    with pytest.raises(InputFileError, match="no header line naming its columns, so label field 'gt' cannot apply"):
        list(iter_text_chunks(bare, label_field="gt"))


def test_labels_that_are_not_wanted_are_neither_read_nor_checked(tmp_path: Path) -> None:
    path = tmp_path / "scan.txt"
    path.write_text("1 2 3 4.5\n4 5 6 300\n")  # a scalar field where a label would be

    (chunk,) = iter_text_chunks(path, labels=False)

    assert chunk.label is None and len(chunk) == 2
    with pytest.raises(InputFileError, match="not an integer in 0..255"):
        read_cloud(path)


def test_writing_into_a_missing_folder_is_refused(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="does not exist"):
        write_text_cloud(tmp_path / "missing" / "scan.txt", _cloud(3))


def test_colours_round_trip_and_name_their_columns_in_a_header_or_by_count(tmp_path: Path) -> None:
    from bimscan.io.text import iter_text_chunks, write_text_cloud

    rng = np.random.default_rng(0)
    cloud = PointCloud(xyz=rng.random((50, 3)), label=rng.integers(0, 5, 50).astype(np.uint8),
                       rgb=rng.integers(0, 256, (50, 3)).astype(np.uint8))
    write_text_cloud(tmp_path / "c.txt", cloud)
    (back,) = iter_text_chunks(tmp_path / "c.txt")
    assert np.array_equal(back.rgb, cloud.rgb) and np.array_equal(back.label, cloud.label)
    (tmp_path / "named.csv").write_text("x,y,z,red,green,blue\n1,2,3,10,20,30\n")
    (named,) = iter_text_chunks(tmp_path / "named.csv")
    assert named.rgb.tolist() == [[10, 20, 30]] and named.label is None
    (tmp_path / "scan.pts").write_text("1\n1 2 3 -100 10 20 30\n")  # Leica: intensity before the colour
    (pts,) = iter_text_chunks(tmp_path / "scan.pts")
    assert pts.rgb.tolist() == [[10, 20, 30]]
    (tmp_path / "plain.xyz").write_text("1 2 3\n")
    (plain,) = iter_text_chunks(tmp_path / "plain.xyz")
    assert plain.rgb is None

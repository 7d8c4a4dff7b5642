"""One vocabulary of cloud formats: every registry is keyed by it, the dataset layout takes its
names from it, and text clouds and S3DIS rooms are read through the same dispatch as the rest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.dataset.layout import FORMAT_FILES, READ_ORDER
from bimscan.errors import InputFileError
from bimscan.io import (
    BYTES_PER_POINT,
    CHUNK_READERS,
    CLOUD_FORMATS,
    HEADER_READERS,
    LIKELY_BYTES_PER_POINT,
    POINT_COUNTERS,
    WRITABLE_FORMATS,
    WRITERS,
    count_points,
    input_format,
    iter_cloud_chunks,
    open_cloud_writer,
    output_format,
    read_cloud,
    read_cloud_header,
)
from bimscan.io.s3dis import S3DIS_CLASSES


@pytest.mark.parametrize("registry", [CHUNK_READERS, HEADER_READERS, POINT_COUNTERS])
def test_every_reader_registry_has_exactly_the_formats_of_the_vocabulary(registry: dict[str, object]) -> None:
    assert list(registry) == list(CLOUD_FORMATS)


@pytest.mark.parametrize("registry", [WRITERS, BYTES_PER_POINT, LIKELY_BYTES_PER_POINT])
def test_every_writer_registry_has_exactly_the_writable_formats(registry: dict[str, object]) -> None:
    assert list(registry) == list(WRITABLE_FORMATS)
    assert set(WRITABLE_FORMATS) <= set(CLOUD_FORMATS)


def test_the_dataset_layout_uses_the_writable_formats_and_their_suffixes() -> None:
    assert list(FORMAT_FILES) == list(WRITABLE_FORMATS)
    assert sorted(READ_ORDER) == sorted(WRITABLE_FORMATS)
    assert {name: output_format(file) for name, file in FORMAT_FILES.items()} == {n: n for n in WRITABLE_FORMATS}


def test_no_suffix_names_two_formats() -> None:
    suffixes = [suffix for name in CLOUD_FORMATS for suffix in CLOUD_FORMATS[name]]
    assert len(suffixes) == len(set(suffixes))


@pytest.mark.parametrize("name", WRITABLE_FORMATS)
def test_every_reader_leaves_labels_out_when_they_are_not_wanted(name, tmp_path, header, cloud_factory) -> None:
    path = tmp_path / FORMAT_FILES[name]
    with open_cloud_writer(path, header=header) as writer:
        writer.write(cloud_factory(50, seed=3))

    assert input_format(path) == name
    assert read_cloud(path).label is not None
    cloud = read_cloud(path, labels=False)
    assert cloud.label is None and len(cloud) == 50


def test_a_text_cloud_reads_counts_and_streams_through_the_registries(tmp_path: Path) -> None:
    path = tmp_path / "scan.xyz"
    rows = "\n".join(f"{i} {2 * i} {3 * i} {i % 4}" for i in range(25))
    path.write_text(f"# exported\n{rows}\n\n// done\n")

    cloud = read_cloud(path)
    chunks = list(iter_cloud_chunks(path, chunk_points=10))

    assert input_format(path) == "text"
    assert count_points(path) == len(cloud) == 25
    assert read_cloud_header(path) is None
    assert cloud.label.tolist() == [i % 4 for i in range(25)]
    np.testing.assert_array_equal(cloud.xyz[:, 2], 3.0 * np.arange(25))
    assert [len(c) for c in chunks] == [10, 10, 5]
    assert read_cloud(path, labels=False).label is None


def _tiny_room(folder: Path) -> Path:
    (folder / "Annotations").mkdir(parents=True)
    (folder / "Annotations" / "wall_1.txt").write_text("0 0 0 1 2 3\n0 0 1 1 2 3\n0 1 1 1 2 3\n")
    (folder / "Annotations" / "floor_1.txt").write_text("0 0 0 9 9 9\n1 0 0 9 9 9\n")
    return folder


def test_an_s3dis_room_reads_counts_and_streams_through_the_registries(tmp_path: Path) -> None:
    room = _tiny_room(tmp_path / "Area_1" / "office_1")

    cloud = read_cloud(room)
    chunks = list(iter_cloud_chunks(room, chunk_points=2))

    assert input_format(room) == "s3dis"
    assert count_points(room) == len(cloud) == 5
    assert read_cloud_header(room) is None
    # files in sorted order: floor_1 (instance 0) then wall_1 (instance 1)
    floor, wall = S3DIS_CLASSES.index("floor"), S3DIS_CLASSES.index("wall")
    assert cloud.label.tolist() == [floor] * 2 + [wall] * 3
    assert cloud.component.tolist() == [0, 0, 1, 1, 1]
    assert [len(c) for c in chunks] == [2, 2, 1]
    assert read_cloud(room, labels=False).label is None


def test_an_s3dis_room_refuses_a_label_field_in_one_line(tmp_path: Path) -> None:
    room = _tiny_room(tmp_path / "office_1")

    with pytest.raises(InputFileError, match="takes no label field") as caught:
        read_cloud(room, label_field="gt")
    assert "\n" not in str(caught.value)


def test_an_unknown_suffix_is_one_line_naming_what_is_readable(tmp_path: Path) -> None:
    path = tmp_path / "scan.pcd"
    path.write_text("x")

    readable = r"unknown cloud format '\.pcd'; bimscan reads .*\.laz.*\.xyz.*S3DIS room"
    for call in (read_cloud, count_points, read_cloud_header, input_format):
        with pytest.raises(InputFileError, match=readable) as caught:
            call(path)
        assert "\n" not in str(caught.value)


def test_a_folder_that_is_no_cloud_is_one_line_naming_what_is_readable(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()

    with pytest.raises(InputFileError, match="neither a NumPy cloud .* nor an S3DIS room") as caught:
        read_cloud(tmp_path / "empty")
    assert "\n" not in str(caught.value)

"""NumPy folder specifics: plain np.load works, coord is relative to the stored origin."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bimscan.errors import InputFileError
from bimscan.io import open_cloud_writer, read_cloud, read_cloud_header
from bimscan.io.npdir import NPY_HEADER_BYTES, npy_header


def write(path, header, chunks):
    with open_cloud_writer(path, header=header) as writer:
        for chunk in chunks:
            writer.write(chunk)
    return writer.close()


def test_every_file_loads_with_plain_numpy_in_the_pointcept_layout(tmp_path, header, cloud_factory):
    cloud = cloud_factory(7_000, seed=1)
    write(tmp_path / "scan", header, [cloud.take(slice(0, 2_500)), cloud.take(slice(2_500, None))])
    expected = {"coord": ((7_000, 3), "float32"), "segment": ((7_000,), "int32"), "instance": ((7_000,), "int32"),
                "station": ((7_000,), "uint16"), "intensity": ((7_000,), "uint16"), "time": ((7_000,), "float64")}
    for stem, (shape, dtype) in expected.items():
        for mmap_mode in (None, "r"):
            array = np.load(tmp_path / "scan" / f"{stem}.npy", mmap_mode=mmap_mode)
            assert array.shape == shape and array.dtype == np.dtype(dtype), stem
    assert np.array_equal(np.load(tmp_path / "scan" / "segment.npy"), cloud.label)
    assert np.array_equal(np.load(tmp_path / "scan" / "instance.npy"), cloud.component)
    assert sorted(p.name for p in (tmp_path / "scan").iterdir()) == sorted(
        [f"{s}.npy" for s in expected] + ["origin.npy", "meta.json"]
    )


def test_coord_is_float32_relative_to_the_origin_stored_twice(tmp_path, header, cloud_factory):
    cloud = cloud_factory(1_000, seed=2)
    write(tmp_path / "scan", header, [cloud])
    origin = np.load(tmp_path / "scan" / "origin.npy")
    assert origin.dtype == np.float64 and tuple(origin) == header.origin
    assert json.loads((tmp_path / "scan" / "meta.json").read_text())["origin_m"] == list(header.origin)
    coord = np.load(tmp_path / "scan" / "coord.npy")
    assert np.abs(coord - (cloud.xyz - origin)).max() < 1e-5  # metres; the room spans +-10 m


def test_npy_headers_have_a_fixed_size_whatever_the_row_count():
    sizes = {len(npy_header("<f4", (n, 3))) for n in (0, 7, 10**12, 10**19)}
    assert sizes == {NPY_HEADER_BYTES}


def test_a_foreign_pointcept_folder_reads_with_a_named_label_file(tmp_path):
    folder = tmp_path / "scene0000_00"
    folder.mkdir()
    rng = np.random.default_rng(3)
    coord = rng.uniform(0, 5, (400, 3)).astype(np.float32)
    np.save(folder / "coord.npy", coord)
    np.save(folder / "color.npy", rng.integers(0, 255, (400, 3)).astype(np.uint8))
    np.save(folder / "segment20.npy", rng.integers(0, 20, 400).astype(np.int16))
    cloud = read_cloud(folder, label_field="segment20")
    assert np.array_equal(cloud.label, np.load(folder / "segment20.npy"))
    assert np.array_equal(cloud.xyz, coord.astype(np.float64))
    assert cloud.component is None and read_cloud_header(folder) is None


def test_pointcept_ignore_labels_read_as_unlabelled_and_other_negatives_are_refused(tmp_path):
    folder = tmp_path / "scene"
    folder.mkdir()
    np.save(folder / "coord.npy", np.zeros((3, 3), np.float32))
    np.save(folder / "segment.npy", np.array([0, -1, 2], np.int32))
    assert read_cloud(folder).label.tolist() == [0, 255, 2]
    np.save(folder / "segment.npy", np.array([0, -2, 2], np.int32))
    with pytest.raises(InputFileError, match="found -2"):
        read_cloud(folder)


def test_a_folder_without_coord_is_an_input_error(tmp_path):
    with pytest.raises(InputFileError, match="no coord.npy"):
        read_cloud(tmp_path)


def test_columns_of_different_lengths_are_an_input_error(tmp_path):
    np.save(tmp_path / "coord.npy", np.zeros((3, 3), np.float32))
    np.save(tmp_path / "segment.npy", np.zeros(4, np.int32))
    with pytest.raises(InputFileError, match="4 rows but coord.npy has 3"):
        read_cloud(tmp_path)


def test_colour_and_returns_are_plain_uint8_files_with_pointcepts_colour_name(tmp_path, header, cloud_factory):
    from bimscan.types import PointCloud

    cloud = cloud_factory(2_000, seed=13, columns=PointCloud.COLUMNS)
    write(tmp_path / "scan", header, [cloud])
    color = np.load(tmp_path / "scan" / "color.npy")
    assert color.dtype == np.uint8 and color.shape == (2_000, 3) and np.array_equal(color, cloud.rgb)
    assert np.array_equal(np.load(tmp_path / "scan" / "return_number.npy"), cloud.return_number)
    assert np.array_equal(np.load(tmp_path / "scan" / "number_of_returns.npy"), cloud.number_of_returns)

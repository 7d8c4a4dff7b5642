"""LAS/LAZ specifics: what laspy sees, reproducible headers, foreign files, bad input."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bimscan.errors import InputFileError, OutputError
from bimscan.io import open_cloud_writer, read_cloud, read_cloud_header
from bimscan.io.las import LAS_SCALE_M, lookup_name, quantise_xyz
from bimscan.types import PointCloud


def write(path, header, cloud):
    with open_cloud_writer(path, header=header) as writer:
        writer.write(cloud)
    return writer.close()


@pytest.mark.parametrize("name", ["cloud.las", "cloud.laz"])
def test_laspy_reads_classification_extra_dimensions_and_the_class_lookup(name, tmp_path, header, cloud_factory):
    cloud = cloud_factory(20_000, seed=1)
    write(tmp_path / name, header, cloud)
    las = laspy.read(tmp_path / name)
    assert str(las.header.version) == "1.4" and las.header.point_format.id == 6
    assert las.header.are_points_compressed == name.endswith(".laz")
    assert np.allclose(las.header.scales, LAS_SCALE_M) and np.allclose(las.header.offsets, header.origin)
    assert np.array_equal(np.asarray(las.classification), cloud.label)
    assert np.array_equal(np.asarray(las.component), cloud.component)
    assert np.array_equal(np.asarray(las.station), cloud.station)
    assert np.array_equal(np.asarray(las.point_source_id), cloud.station)
    assert np.array_equal(np.asarray(las.intensity), cloud.intensity)
    assert np.array_equal(np.asarray(las.gps_time), cloud.time)
    assert np.all(np.asarray(las.return_number) == 1) and np.all(np.asarray(las.number_of_returns) == 1)
    assert np.abs(np.stack([las.x, las.y, las.z], 1) - cloud.xyz).max() <= LAS_SCALE_M / 2 + 1e-9
    lookup = next(v for v in las.header.vlrs if isinstance(v, laspy.vlrs.known.ClassificationLookupVlr))
    assert len(lookup.record_data_bytes()) == 256 * 16  # the LAS 1.4 record: 256 entries of 16 bytes
    for cls in header.scheme.classes:
        # laspy keeps only letters, digits and spaces of each stored name
        assert lookup.lookups[cls.id] == "".join(ch for ch in lookup_name(cls.name) if ch.isalnum() or ch == " ")
    evlr = next(v for v in las.header.evlrs if v.user_id == "bimscan")
    assert json.loads(evlr.record_data)["n_points"] == len(cloud)


def test_header_bounds_and_count_match_the_points(tmp_path, header, cloud_factory):
    cloud = cloud_factory(30_000, seed=2)
    write(tmp_path / "cloud.laz", header, cloud)
    las_header = laspy.read(tmp_path / "cloud.laz").header
    assert las_header.point_count == len(cloud)
    assert np.abs(las_header.mins - cloud.xyz.min(axis=0)).max() <= LAS_SCALE_M
    assert np.abs(las_header.maxs - cloud.xyz.max(axis=0)).max() <= LAS_SCALE_M
    assert las_header.number_of_points_by_return[0] == len(cloud)


def test_the_header_is_dated_from_source_date_epoch_and_never_today(tmp_path, header, cloud_factory, monkeypatch):
    cloud = cloud_factory(100, seed=3)
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    write(tmp_path / "a.las", header, cloud)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")  # 2023-11-14
    write(tmp_path / "b.las", header, cloud)
    assert str(laspy.read(tmp_path / "a.las").header.creation_date) == "1970-01-01"
    assert str(laspy.read(tmp_path / "b.las").header.creation_date) == "2023-11-14"


def test_the_project_guid_follows_the_header_so_equal_inputs_give_equal_files(tmp_path, header, cloud_factory):
    cloud = cloud_factory(100, seed=4)
    write(tmp_path / "a.las", header, cloud)
    write(tmp_path / "b.las", header, cloud)
    other = type(header)(scheme=header.scheme, origin=header.origin, metadata={"seed": 8})
    write(tmp_path / "c.las", other, cloud)
    guid = [laspy.read(tmp_path / n).header.uuid for n in ("a.las", "b.las", "c.las")]
    assert guid[0] == guid[1] != guid[2]
    assert (tmp_path / "a.las").read_bytes() == (tmp_path / "b.las").read_bytes()


def test_points_beyond_the_int32_range_around_the_origin_are_refused(tmp_path, header, cloud_factory):
    cloud = cloud_factory(100, seed=5)
    cloud.xyz[7, 0] = header.origin[0] + 300_000.0  # 300 km: more than 2^31 steps of 0.1 mm
    with pytest.raises(OutputError, match="does not fit LAS 0.1 mm steps"):
        write(tmp_path / "cloud.laz", header, cloud)
    assert list(tmp_path.iterdir()) == []


@given(st.integers(min_value=0, max_value=10_000))
def test_the_one_pass_quantiser_gives_numpys_steps_bounds_and_first_bad_coordinate(seed):
    rng = np.random.default_rng(seed)
    n = 2000
    origin = rng.uniform(-1e3, 1e3, 3)
    xyz = origin + rng.uniform(-500, 500, (n, 3))
    xyz[: n // 4] = origin + (np.round(rng.uniform(-1e6, 1e6, (n // 4, 3))) + 0.5) * LAS_SCALE_M  # ties to even
    expected = np.rint(np.divide(np.subtract(xyz, origin), LAS_SCALE_M))
    steps = np.zeros((3, n), dtype=np.int32)
    low, high = np.full(3, np.inf), np.full(3, -np.inf)
    assert quantise_xyz(xyz, origin, LAS_SCALE_M, steps[0], steps[1], steps[2], low, high) == -1
    assert np.array_equal(steps, expected.T.astype(np.int32))
    assert np.array_equal(low, expected.min(axis=0)) and np.array_equal(high, expected.max(axis=0))
    row, axis = int(rng.integers(n)), int(rng.integers(3))
    xyz[row, axis] = [np.nan, np.inf, origin[axis] + 3e5][seed % 3]  # 300 km: beyond 2^31 steps
    assert quantise_xyz(xyz, origin, LAS_SCALE_M, steps[0], steps[1], steps[2], low, high) == 3 * row + axis


def test_nan_coordinates_are_refused(tmp_path, header, cloud_factory):
    cloud = cloud_factory(100, seed=6)
    cloud.xyz[3, 2] = np.nan
    with pytest.raises(OutputError, match="use finite coordinates"):
        write(tmp_path / "cloud.las", header, cloud)


def make_foreign_las(path, *, gt: np.ndarray, gt_type: type = np.uint8) -> np.ndarray:
    """A LAS written by laspy alone (point format 3, no bimscan EVLR), labels in extra dim 'gt'."""
    rng = np.random.default_rng(9)
    las = laspy.create(point_format=3, file_version="1.2")
    las.add_extra_dim(laspy.ExtraBytesParams(name="gt", type=gt_type))
    xyz = rng.uniform([100.0, 200.0, 0.0], [150.0, 260.0, 12.0], (len(gt), 3))
    las.header.scales = np.array([0.001, 0.001, 0.001])
    las.header.offsets = np.array([100.0, 200.0, 0.0])
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = np.full(len(gt), 6, dtype=np.uint8)  # ASPRS "building"
    las.intensity = rng.integers(0, 4000, len(gt)).astype(np.uint16)
    las.gps_time = np.arange(len(gt), dtype=np.float64)
    las.gt = gt.astype(gt_type)
    las.write(path)
    return xyz


def test_a_foreign_las_reads_labels_from_a_named_extra_dimension(tmp_path):
    gt = np.random.default_rng(1).integers(0, 5, 1_000)
    xyz = make_foreign_las(tmp_path / "real.las", gt=gt)
    cloud = read_cloud(tmp_path / "real.las", label_field="gt")
    assert np.array_equal(cloud.label, gt)
    assert np.abs(cloud.xyz - xyz).max() <= 0.0005 + 1e-9
    assert np.array_equal(cloud.time, np.arange(1_000))
    assert cloud.component is None and cloud.station is None
    assert read_cloud_header(tmp_path / "real.las") is None


def test_a_foreign_las_reads_classification_by_default(tmp_path):
    make_foreign_las(tmp_path / "real.las", gt=np.zeros(50))
    assert np.all(read_cloud(tmp_path / "real.las").label == 6)


def test_whole_number_float_labels_are_accepted_and_others_refused(tmp_path):
    make_foreign_las(tmp_path / "good.las", gt=np.array([0.0, 4.0, 255.0]), gt_type=np.float32)
    assert read_cloud(tmp_path / "good.las", label_field="gt").label.tolist() == [0, 4, 255]
    make_foreign_las(tmp_path / "bad.las", gt=np.array([0.0, 2.5]), gt_type=np.float32)
    with pytest.raises(InputFileError, match=r"labels in 'gt' must be integers in 0\.\.255, found 2\.5"):
        read_cloud(tmp_path / "bad.las", label_field="gt")
    make_foreign_las(tmp_path / "big.las", gt=np.array([1, 300]), gt_type=np.int16)
    with pytest.raises(InputFileError, match="found 300"):
        read_cloud(tmp_path / "big.las", label_field="gt")


def test_an_unknown_label_field_names_the_dimensions_the_file_has(tmp_path):
    make_foreign_las(tmp_path / "real.las", gt=np.zeros(5))
    with pytest.raises(InputFileError, match="no dimension 'truth'.*classification.*gt"):
        read_cloud(tmp_path / "real.las", label_field="truth")


def test_a_file_that_is_not_las_is_an_input_error(tmp_path):
    (tmp_path / "fake.laz").write_bytes(b"this is not a point cloud")
    with pytest.raises(InputFileError, match="not a readable LAS/LAZ file"):
        read_cloud(tmp_path / "fake.laz")


@pytest.mark.parametrize("name", ["cloud.las", "cloud.laz"])
def test_returns_and_colour_go_to_point_format_7_fields_that_laspy_reads(name, tmp_path, header, cloud_factory):
    cloud = cloud_factory(20_000, seed=11, columns=PointCloud.COLUMNS)
    write(tmp_path / name, header, cloud)
    las = laspy.read(tmp_path / name)
    assert las.header.point_format.id == 7
    assert np.array_equal(np.asarray(las.return_number), cloud.return_number)
    assert np.array_equal(np.asarray(las.number_of_returns), cloud.number_of_returns)
    for channel, field in enumerate(("red", "green", "blue")):
        assert np.array_equal(np.asarray(getattr(las, field)), cloud.rgb[:, channel].astype(np.uint16) * 257)
    by_return = np.bincount(cloud.return_number, minlength=16)[1:]
    assert list(las.header.number_of_points_by_return) == list(by_return[: len(las.header.number_of_points_by_return)])


def test_a_foreign_las_gives_its_return_numbers_and_colour(tmp_path):
    las = laspy.create(point_format=3, file_version="1.2")
    las.x, las.y, las.z = np.arange(4.0), np.zeros(4), np.zeros(4)
    las.return_number, las.number_of_returns = np.array([1, 2, 1, 1]), np.array([2, 2, 1, 1])
    las.red, las.green, las.blue = np.array([0, 65535, 256 * 7, 512]), np.zeros(4), np.full(4, 65535)
    las.write(tmp_path / "foreign.las")
    cloud = read_cloud(tmp_path / "foreign.las")
    assert cloud.return_number.tolist() == [1, 2, 1, 1] and cloud.number_of_returns.tolist() == [2, 2, 1, 1]
    assert cloud.rgb[:, 0].tolist() == [0, 255, 7, 2] and (cloud.rgb[:, 2] == 255).all()


@pytest.fixture
def ctrl_c_raises():
    """SIGINT raising KeyboardInterrupt in the main thread (Python's own handler), restored after."""
    import signal

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupt_after(seconds: float):
    import os
    import signal
    import threading

    timer = threading.Timer(seconds, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    return timer


@pytest.mark.slow
def test_ctrl_c_while_lazrs_writes_stops_the_writer_as_an_interrupt_not_a_write_error(
    tmp_path, header, cloud_factory, ctrl_c_raises,
):
    # lazrs calls back into Python to write and turned a KeyboardInterrupt raised there into "IoError: Failed
    # to call write"; a mobile scan, which spends most of its time compressing, met it 5 times in 8
    rng = np.random.default_rng(41)
    chunk = cloud_factory(400_000, seed=3)
    for attempt in range(6):
        path = tmp_path / f"scan{attempt}.laz"
        written = 0
        timer = _interrupt_after(float(rng.uniform(0.05, 0.6)))
        with pytest.raises(KeyboardInterrupt):
            with open_cloud_writer(path, header=header) as writer:
                for _ in range(200):
                    writer.write(chunk)
                    written += 1
        timer.join()
        assert written < 200  # the signal came while the cloud was being written
        assert list(tmp_path.iterdir()) == []  # no output, no temporary


def test_the_parallel_laz_compressor_writes_the_single_threaded_ones_bytes(tmp_path, header, cloud_factory, monkeypatch):
    import bimscan.io.las as las

    cloud = cloud_factory(180_000, seed=9)  # 4 LAZ chunks, the last one partial
    write(tmp_path / "parallel.laz", header, cloud)
    monkeypatch.setattr(las, "LAZ_BACKENDS", (laspy.LazBackend.Lazrs,))
    write(tmp_path / "single.laz", header, cloud)
    assert (tmp_path / "parallel.laz").read_bytes() == (tmp_path / "single.laz").read_bytes()
    assert laspy.LazBackend.LazrsParallel.is_available()  # else both ran single-threaded and proved nothing

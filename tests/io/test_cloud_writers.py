"""Contract tests over every entry of WRITERS: round trip, header, bytes, streaming, atomicity."""

from __future__ import annotations

import errno
import hashlib
import subprocess
import sys
import tempfile
import textwrap
import tracemalloc
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bimscan.errors import InputFileError, OutputError
from bimscan.io import (
    CLOUD_FORMATS,
    WRITABLE_FORMATS,
    WRITERS,
    iter_cloud_chunks,
    open_cloud_writer,
    output_format,
    read_cloud,
    read_cloud_header,
)
from bimscan.io._writer import BLOCK_POINTS, WatchedFile
from bimscan.types import CloudHeader, PointCloud

SCAN_COLUMNS = ("xyz", "label", "component", "station", "intensity", "time")
MOBILE_COLUMNS = ("ring", "channel", "sensor_xyz")  # what E57 (one pose per scan) cannot hold
NAMES = {name: "cloud" + CLOUD_FORMATS[name][0] for name in WRITABLE_FORMATS}
FORMATS = sorted(WRITERS)


def xyz_tolerance(key: str, xyz: np.ndarray, origin: tuple[float, float, float]) -> float:
    """How far a coordinate may move through the format: LAS 0.1 mm steps, float32 offsets,
    E57's 0.1 mm steps in a station frame turned back to world axes (per axis at most the
    length of the half-step diagonal)."""
    if key in ("las", "laz"):
        return 0.5e-4 + 1e-9
    if key == "npy":
        return float(np.abs(xyz - np.asarray(origin)).max()) * np.finfo(np.float32).eps
    if key == "e57":
        return 0.5e-4 * np.sqrt(3) + 1e-9
    return 0.0


def write_chunks(path: Path, header: CloudHeader, chunks: list[PointCloud], **options: object):
    with open_cloud_writer(path, header=header, **options) as writer:
        for chunk in chunks:
            writer.write(chunk)
    return writer.close()


def folder_listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def output_bytes(path: Path) -> dict[str, bytes]:
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    if path.suffix == ".ply":
        files.append(path.with_name(path.name + ".json"))
    return {f.relative_to(path.parent).as_posix(): f.read_bytes() for f in files}


@pytest.mark.parametrize("key", FORMATS)
def test_every_writer_round_trips_every_column_through_its_reader(key, tmp_path, header, cloud_factory, chunk_splitter):
    columns = tuple(c for c in PointCloud.COLUMNS if key != "e57" or c not in MOBILE_COLUMNS)
    cloud = cloud_factory(25_013, seed=1, columns=columns)
    path = tmp_path / NAMES[key]
    written = write_chunks(path, header, chunk_splitter(cloud, seed=2, low=1, high=4_000))
    back = read_cloud(path)
    assert written.n_points == len(back) == len(cloud)
    assert np.abs(back.xyz - cloud.xyz).max() <= xyz_tolerance(key, cloud.xyz, header.origin)
    for column in columns[1:]:
        if column == "sensor_xyz":  # LAS keeps beam origins in the 0.1 mm steps of its coordinates
            assert np.abs(back.sensor_xyz - cloud.sensor_xyz).max() <= xyz_tolerance(key, cloud.sensor_xyz,
                                                                                     header.origin)
            continue
        assert np.array_equal(getattr(back, column), getattr(cloud, column)), column
        assert getattr(back, column).dtype == getattr(cloud, column).dtype
    assert read_cloud_header(path) is not None


def test_e57_refuses_a_mobile_scan_in_one_line_and_leaves_no_file(tmp_path, header, cloud_factory):
    path = tmp_path / "mobile.e57"
    with pytest.raises(OutputError, match="one pose per scan"):
        write_chunks(path, header, [cloud_factory(100, seed=1, columns=(*SCAN_COLUMNS, "ring", "sensor_xyz"))])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("key", FORMATS)
def test_returns_and_colour_are_left_out_of_files_of_clouds_without_them(key, tmp_path, header, cloud_factory):
    path = tmp_path / NAMES[key]
    write_chunks(path, header, [cloud_factory(500, seed=8)])
    back = read_cloud(path)
    assert back.return_number is None and back.number_of_returns is None and back.rgb is None


@pytest.mark.parametrize("key", FORMATS)
def test_every_writer_stores_scheme_components_stations_and_metadata(key, tmp_path, header, cloud_factory):
    path = tmp_path / NAMES[key]
    write_chunks(path, header, [cloud_factory(1_000, seed=3)])
    stored = read_cloud_header(path)
    assert stored is not None
    assert stored.scheme == header.scheme
    assert stored.stations == header.stations
    assert stored.origin == header.origin
    assert dict(stored.metadata) == dict(header.metadata)
    assert stored.components is not None
    assert stored.components.rows() == header.components.rows()
    assert dict(stored.components.class_ancestry) == dict(header.components.class_ancestry)


@pytest.mark.parametrize("key", FORMATS)
def test_every_writer_gives_identical_bytes_however_the_stream_is_chunked(key, tmp_path, header, cloud_factory, chunk_splitter):
    # More than one re-blocking unit, so LAS/LAZ block boundaries fall inside caller chunks.
    cloud = cloud_factory(BLOCK_POINTS + 150_007, seed=4)
    one, many = tmp_path / "one", tmp_path / "many"
    one.mkdir()
    many.mkdir()
    first = write_chunks(one / NAMES[key], header, [cloud])
    second = write_chunks(many / NAMES[key], header, chunk_splitter(cloud, seed=5, low=1, high=300_000))
    assert output_bytes(one / NAMES[key]) == output_bytes(many / NAMES[key])
    assert first.sha256 == second.sha256 and first.sha256


@pytest.mark.parametrize("key", FORMATS)
def test_checksums_are_the_sha256_of_the_files_written(key, tmp_path, header, cloud_factory):
    path = tmp_path / NAMES[key]
    written = write_chunks(path, header, [cloud_factory(2_000, seed=6)])
    on_disk = {name: hashlib.sha256(data).hexdigest() for name, data in output_bytes(path).items()}
    assert dict(written.sha256) == on_disk
    assert written.n_bytes == sum(len(d) for d in output_bytes(path).values())
    assert not write_chunks(tmp_path / ("x" + NAMES[key]), header, [cloud_factory(10, seed=6)], checksum=False).sha256


@pytest.mark.parametrize("key", FORMATS)
def test_columns_the_cloud_lacks_read_back_as_none(key, tmp_path, header, cloud_factory):
    cloud = cloud_factory(3_000, seed=7, columns=("xyz", "label"))
    path = tmp_path / NAMES[key]
    write_chunks(path, header, [cloud])
    back = read_cloud(path)
    assert np.array_equal(back.label, cloud.label)
    assert back.component is None and back.station is None and back.intensity is None and back.time is None


@pytest.mark.parametrize("key", FORMATS)
def test_a_writer_given_no_chunk_writes_an_empty_readable_cloud(key, tmp_path, header):
    path = tmp_path / NAMES[key]
    with open_cloud_writer(path, header=header) as writer:
        pass
    assert writer.close().n_points == 0
    assert len(read_cloud(path)) == 0
    assert read_cloud_header(path).scheme == header.scheme


@pytest.mark.parametrize("key", FORMATS)
def test_chunked_reading_gives_the_same_points_in_bounded_chunks(key, tmp_path, header, cloud_factory):
    cloud = cloud_factory(10_001, seed=8)
    path = tmp_path / NAMES[key]
    write_chunks(path, header, [cloud])
    chunks = list(iter_cloud_chunks(path, chunk_points=3_000))
    assert [len(c) for c in chunks] == [3_000, 3_000, 3_000, 1_001]
    assert np.array_equal(PointCloud.concatenate(chunks).label, cloud.label)


@pytest.mark.parametrize("key", FORMATS)
def test_chunks_with_other_columns_than_the_first_are_refused_and_nothing_is_left(key, tmp_path, header, cloud_factory):
    path = tmp_path / NAMES[key]
    with pytest.raises(OutputError, match="same columns"):
        with open_cloud_writer(path, header=header) as writer:
            writer.write(cloud_factory(100, seed=9))
            writer.write(cloud_factory(100, seed=9, columns=("xyz",)))
    assert folder_listing(tmp_path) == []


@pytest.mark.parametrize("key", FORMATS)
def test_an_exception_inside_the_with_block_leaves_no_output_and_no_temporary(key, tmp_path, header, cloud_factory):
    path = tmp_path / NAMES[key]
    with pytest.raises(KeyboardInterrupt):
        with open_cloud_writer(path, header=header) as writer:
            writer.write(cloud_factory(5_000, seed=10))
            raise KeyboardInterrupt
    assert folder_listing(tmp_path) == []


@pytest.mark.parametrize("key", FORMATS)
def test_an_existing_output_is_kept_without_overwrite_and_replaced_with_it(key, tmp_path, header, cloud_factory):
    path = tmp_path / NAMES[key]
    write_chunks(path, header, [cloud_factory(100, seed=11)])
    before = output_bytes(path)
    with pytest.raises(OutputError, match="already exists"):
        open_cloud_writer(path, header=header)
    assert output_bytes(path) == before
    write_chunks(path, header, [cloud_factory(200, seed=12)], overwrite=True)
    assert len(read_cloud(path)) == 200
    assert [p for p in folder_listing(tmp_path) if p.startswith(".")] == []


# libE57Format writes through its own C++ file handle, which no Python patch reaches: the E57
# writer's disk-full path is tested with a real file-size limit in test_e57.py.
@pytest.mark.parametrize("key", [k for k in FORMATS if k != "e57"])
def test_disk_full_while_writing_is_an_output_error_and_removes_the_temporary(key, tmp_path, header, cloud_factory, monkeypatch):
    budget = {"bytes": 200_000}
    real_write = WatchedFile.write

    def write_until_full(self: WatchedFile, data: bytes | memoryview) -> int:
        size = memoryview(data).nbytes
        if size > budget["bytes"]:
            self.error = OSError(errno.ENOSPC, "No space left on device")
            raise self.error
        budget["bytes"] -= size
        return real_write(self, data)

    monkeypatch.setattr(WatchedFile, "write", write_until_full)
    path = tmp_path / NAMES[key]
    with pytest.raises(OutputError, match="disk full while writing .*; free space and run again"):
        write_chunks(path, header, [cloud_factory(BLOCK_POINTS // 4, seed=13)] * 5)
    assert folder_listing(tmp_path) == []


def test_a_real_write_error_inside_lazrs_becomes_an_output_error(tmp_path, header):
    # A file-size limit makes the kernel fail the writes (EFBIG) deep inside the LAZ compressor.
    script = textwrap.dedent(
        f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2_000_000, 2_000_000))
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from conftest import ORIGIN, make_cloud
        from bimscan.errors import OutputError
        from bimscan.io import open_cloud_writer
        from bimscan.types import CloudHeader, LabelScheme
        header = CloudHeader(scheme=LabelScheme("s", (), (), "x"), origin=ORIGIN)
        try:
            with open_cloud_writer({str(tmp_path / 'big.laz')!r}, header=header) as writer:
                writer.write(make_cloud(2_000_000, seed=1))
        except OutputError as exc:
            print("OutputError:", exc)
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert "OutputError: could not write" in done.stdout, done.stderr
    assert "File too large" in done.stdout
    assert folder_listing(tmp_path) == []


@pytest.mark.parametrize("key", FORMATS)
def test_writer_memory_does_not_grow_with_the_number_of_chunks(key, tmp_path, header, cloud_factory):
    chunk = cloud_factory(50_000, seed=14)

    def peak_bytes(n_chunks: int, name: str) -> int:
        tracemalloc.start()
        try:
            with open_cloud_writer(tmp_path / name, header=header, checksum=False) as writer:
                for _ in range(n_chunks):
                    writer.write(chunk)
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    few = peak_bytes(4, "few" + NAMES[key])  # 0.2 M points
    many = peak_bytes(48, "many" + NAMES[key])  # 2.4 M points, past two LAS re-blocking flushes
    assert many <= few * 1.2 + 2_000_000, (few, many)
    assert many < 64 * 2**20  # the LAS block (1 M rows) dominates; the whole cloud would be 98 MB


def test_unknown_suffix_is_an_output_error_naming_the_supported_formats(tmp_path, header):
    with pytest.raises(OutputError, match=r"\.las, \.laz, \.ply"):
        open_cloud_writer(tmp_path / "cloud.xyz", header=header)


def test_missing_parent_folder_is_an_output_error(tmp_path, header):
    with pytest.raises(OutputError, match="does not exist"):
        open_cloud_writer(tmp_path / "missing" / "cloud.laz", header=header)


def test_paths_without_suffix_or_with_a_trailing_slash_are_numpy_folders():
    assert output_format("out/scan") == "npy"
    assert output_format("out/scene.exp1/") == "npy"
    assert output_format("out/scan.LAZ") == "laz"
    assert output_format("out/scene.exp1") is None
    assert output_format("out/scan.txt") is None  # text is read, not written, through the registries


def test_metadata_that_is_not_json_is_refused_before_any_point_is_written(tmp_path, header):
    bad = CloudHeader(scheme=header.scheme, metadata={"when": object()})
    with pytest.raises(OutputError, match="not JSON-able"):
        open_cloud_writer(tmp_path / "cloud.laz", header=bad)
    assert folder_listing(tmp_path) == []


def test_a_closed_writer_refuses_more_chunks_and_keeps_its_output(tmp_path, header, cloud_factory):
    path = tmp_path / "cloud.laz"
    with open_cloud_writer(path, header=header) as writer:
        writer.write(cloud_factory(10, seed=15))
    with pytest.raises(OutputError, match="already closed"):
        writer.write(cloud_factory(10, seed=15))
    writer.abort()  # a no-op once closed
    assert len(read_cloud(path)) == 10


def test_reading_an_unknown_format_or_a_missing_path_is_an_input_error(tmp_path):
    (tmp_path / "cloud.pcd").write_bytes(b"")
    (tmp_path / "README").write_text("not a cloud")
    with pytest.raises(InputFileError, match="unknown cloud format '.pcd'"):
        read_cloud(tmp_path / "cloud.pcd")
    with pytest.raises(InputFileError, match="unknown cloud format"):
        read_cloud(tmp_path / "README")
    with pytest.raises(InputFileError, match="no such file"):
        read_cloud(tmp_path / "missing.laz")


@pytest.mark.parametrize("key", ["las", "ply", "e57", "npy"])
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.integers(min_value=0, max_value=3_500), max_size=12))
def test_any_chunking_gives_the_bytes_of_the_unchunked_stream(key, cuts, header, cloud_factory):
    # Small re-blocking units, so hypothesis' cuts land on, before and after block boundaries
    # (the fixtures are immutable, so sharing them between examples is safe).
    cloud = cloud_factory(3_500, seed=16, columns=tuple(c for c in PointCloud.COLUMNS
                                                        if key != "e57" or c not in MOBILE_COLUMNS))
    bounds = [0, *sorted(cuts), len(cloud)]
    chunks = [cloud.take(slice(a, b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    with tempfile.TemporaryDirectory() as scratch, \
            mock.patch("bimscan.io._writer.BLOCK_POINTS", 1_000), mock.patch("bimscan.io.las.BLOCK_POINTS", 1_000), \
            mock.patch("bimscan.io.e57.E57_BLOCK_POINTS", 1_000):
        one, many = Path(scratch, "one"), Path(scratch, "many")
        one.mkdir()
        many.mkdir()
        write_chunks(one / NAMES[key], header, [cloud])
        write_chunks(many / NAMES[key], header, chunks)
        assert output_bytes(one / NAMES[key]) == output_bytes(many / NAMES[key])

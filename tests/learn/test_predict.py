"""Prediction: every point of a scan labelled and written with bimscan.io (class in
classification), the other columns kept, reproducible bytes, atomic on failure."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bimscan.errors import InputFileError, OutputError
from bimscan.io import read_cloud, read_cloud_header
from bimscan.io.text import write_text_cloud
from bimscan.learn.predict import predict_cloud
from bimscan.learn.train_config import EvalConfig
from bimscan.types import PointCloud

from .conftest import make_room


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


def test_overwrite_refuses_a_users_folder_before_reading_the_checkpoint(tmp_path: Path, scan: Path) -> None:
    userdir = tmp_path / "userdir"
    (userdir / "sub").mkdir(parents=True)
    (userdir / "results.txt").write_text("mine")

    with pytest.raises(OutputError, match=r"userdir is a folder that is not a bimscan NumPy cloud \(it holds "
                                          r"results.txt, sub/\)"):
        predict_cloud(tmp_path / "nope.pt", scan, userdir, device="cpu", overwrite=True)

    assert (userdir / "results.txt").read_text() == "mine" and (userdir / "sub").is_dir()


# A predict that stops for good once its labels are on disk: the work folder is there when it is killed.
STALLED_PREDICT = """
import sys, time
from pathlib import Path
import bimscan.learn.predict as predict

def stalled(*args, **kwargs):
    result = real(*args, **kwargs)
    Path(sys.argv[4]).write_text("labelled")
    time.sleep(600)

real, predict.label_scene = predict.label_scene, stalled
predict.predict_cloud(sys.argv[1], sys.argv[2], sys.argv[3], device="cpu")
"""


@pytest.mark.slow
def test_the_work_folder_of_a_killed_prediction_is_removed_by_the_next_run_to_the_same_output(
    tmp_path: Path, trained_run: Path, scan: Path,
) -> None:
    import subprocess
    import sys
    import time

    out, ready = tmp_path / "out" / "labelled.laz", tmp_path / "ready"
    out.parent.mkdir()
    checkpoint = trained_run / "run" / "last.pt"
    process = subprocess.Popen([sys.executable, "-c", STALLED_PREDICT, str(checkpoint), str(scan), str(out), str(ready)])
    start = time.monotonic()
    while not ready.exists():
        assert process.poll() is None and time.monotonic() - start < 120
        time.sleep(0.05)
    process.kill()  # kill -9: no clean-up of its own runs
    process.wait()
    left = [p.name for p in out.parent.iterdir()]
    assert len(left) == 1 and left[0].startswith(f".labelled.laz.{process.pid}-")  # its work folder, named with its pid

    predict_cloud(checkpoint, scan, out, device="cpu")

    assert sorted(p.name for p in out.parent.iterdir()) == ["labelled.laz"]


def test_a_mobile_cloud_to_e57_is_refused_before_any_labelling(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud], monkeypatch: pytest.MonkeyPatch,
) -> None:
    import bimscan.learn.predict as predict
    from bimscan.io import open_cloud_writer
    from bimscan.learn.predict import build_prediction_scheme
    from bimscan.types import CloudHeader

    cloud = room(31, points_per_m2=10)
    n = len(cloud)
    walk = PointCloud(xyz=cloud.xyz, label=cloud.label, ring=np.arange(n, dtype=np.uint8) % 16,
                      sensor_xyz=np.tile([1.0, 1.0, 1.6], (n, 1)), time=np.linspace(0.0, 10.0, n))
    with open_cloud_writer(tmp_path / "walk.laz", header=CloudHeader(scheme=build_prediction_scheme(("a", "b")))) as w:
        w.write(walk)

    def no_labelling(*args: object, **kwargs: object) -> None:
        raise AssertionError("labelling started: the output should have been refused first")

    monkeypatch.setattr(predict, "label_scene", no_labelling)
    with pytest.raises(OutputError, match="walk.e57: E57 stores one pose per scan and has no field for a mobile "
                                          "scan's beam origins, rings"):
        predict_cloud(trained_run / "run" / "last.pt", tmp_path / "walk.laz", tmp_path / "walk.e57", device="cpu")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.laz"]


def test_a_foreign_las_without_return_numbers_is_predicted_to_e57(tmp_path: Path, trained_run: Path, scan: Path) -> None:
    # laspy leaves return numbers 0 (LAS 1.4 counts from 1): E57's returnIndex is the number - 1
    assert int(laspy.read(scan).return_number.max()) == 0
    checkpoint = trained_run / "run" / "last.pt"

    result = predict_cloud(checkpoint, scan, tmp_path / "labelled.e57", device="cpu", evaluation=EvalConfig(max_passes=1))
    predict_cloud(checkpoint, scan, tmp_path / "labelled.laz", device="cpu", evaluation=EvalConfig(max_passes=1))

    e57, laz = read_cloud(tmp_path / "labelled.e57"), read_cloud(tmp_path / "labelled.laz")
    assert len(e57) == len(laz) == result.points
    np.testing.assert_array_equal(e57.label, laz.label)
    np.testing.assert_allclose(e57.xyz, laz.xyz, atol=2e-4)
    assert set(np.unique(e57.return_number)) == {1} and set(np.unique(e57.number_of_returns)) == {1}


# -- a user's scan kept whole (issue 50) ---------------------------------------------------------------

WKT = ('PROJCS["ETRS89 / UTM zone 32N",GEOGCS["ETRS89",DATUM["ETRS89",SPHEROID["GRS 1980",6378137,298.257222101]],'
       'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
       'PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],'
       'UNIT["metre",1],AUTHORITY["EPSG","25832"]]')


@pytest.fixture
def georeferenced(tmp_path: Path, room: Callable[..., PointCloud]) -> Path:
    """The issue's scan: LAS 1.4 with a WKT CRS, a UTM offset, 10 micrometre steps, an extra
    dimension and another tool's EVLR."""
    from laspy.vlrs.known import WktCoordinateSystemVlr
    from laspy.vlrs.vlrlist import VLRList

    cloud = room(22, size_m=(4.0, 3.0), points_per_m2=30, origin=(512_003.0, 5_401_002.0))
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.array([512_000.0, 5_401_000.0, 300.0])
    header.scales = np.array([1e-5, 1e-5, 1e-5])
    header.add_extra_dim(laspy.ExtraBytesParams(name="deviation", type=np.float32, description="distance to model"))
    header.vlrs.append(WktCoordinateSystemVlr(WKT))
    header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2] + 300.0
    las.deviation = np.linspace(-0.01, 0.01, len(cloud)).astype(np.float32)
    las.classification = np.full(len(cloud), 1, np.uint8)
    las.evlrs = VLRList([laspy.VLR("Leica", 42, "registration report", b"RMS 1.2 mm " * 30)])
    path = tmp_path / "g.las"
    las.write(path)
    return path


def las_parts(path: Path) -> tuple[bytes, list[bytes], np.ndarray]:
    """What a labelled copy must keep of a LAS: its header block without the fields a copy rewrites
    (point data offset, VLR count, EVLR position and count), its VLRs and EVLRs but bimscan's own and
    the class lookup, and its point records without the class byte."""
    from bimscan.io.las import read_las_layout

    layout = read_las_layout(path)
    head = bytearray(layout.header)
    for offset, size in ((96, 8), (235, 12)):
        head[offset:offset + size] = b"\0" * size
    records = [r.raw for r in (*layout.vlrs, *layout.evlrs) if (r.user_id, r.record_id) not in
               {("LASF_Spec", 0), ("bimscan", 1)}]
    las = laspy.read(path)
    rows = np.asarray(las.points.array).view(np.uint8).reshape(len(las.points), -1).copy()
    rows[:, 16] = 0
    return bytes(head), records, rows


def test_the_issues_georeferenced_scan_keeps_its_crs_steps_offset_extra_dimension_and_evlr(
    tmp_path: Path, trained_run: Path, georeferenced: Path,
) -> None:
    checkpoint, once = trained_run / "run" / "last.pt", EvalConfig(max_passes=1)
    original = las_parts(georeferenced)
    lines: list[str] = []

    result = predict_cloud(checkpoint, georeferenced, tmp_path / "labelled.las", device="cpu", evaluation=once,
                           warn=lines.append)
    # writing over the input, spelled another way: the same bytes, only the classes changed
    (tmp_path / "sub").mkdir()
    predict_cloud(checkpoint, georeferenced, tmp_path / "sub" / ".." / "g.las", device="cpu", evaluation=once,
                  overwrite=True, warn=lines.append)

    assert lines == []  # nothing to warn about: everything kept
    for written in (tmp_path / "labelled.las", georeferenced):
        head, records, rows = las_parts(written)
        assert head == original[0] and records == original[1]  # CRS, extra-bytes VLR, the EVLR as they were
        np.testing.assert_array_equal(rows, original[2])  # X/Y/Z integers, extra dimension: never re-quantised
        np.testing.assert_array_equal(np.bincount(laspy.read(written).classification, minlength=5), result.class_counts)
    assert (tmp_path / "labelled.las").read_bytes() == georeferenced.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.las", "labelled.las", "sub"]


def test_writing_over_the_input_that_a_copy_would_change_is_refused_before_the_checkpoint_is_read(
    tmp_path: Path, room: Callable[..., PointCloud],
) -> None:
    cloud = room(6, points_per_m2=10)
    (tmp_path / "scan.pts").write_text(f"{len(cloud)}\n" + "".join(f"{x} {y} {z} 5\n" for x, y, z in cloud.xyz))
    before = (tmp_path / "scan.pts").read_bytes()

    with pytest.raises(OutputError, match=r"scan.pts is the input .*scan.pts and its labelled copy would not keep all "
                                          r"of it \(a header line 'x y z intensity label' is added"):
        predict_cloud(tmp_path / "nope.pt", tmp_path / "scan.pts", tmp_path / "scan.pts", device="cpu", overwrite=True)

    assert (tmp_path / "scan.pts").read_bytes() == before


def test_another_tools_ply_and_text_keep_their_normals_scalar_fields_and_colour(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud],
) -> None:
    cloud = room(7, size_m=(4.0, 3.0), points_per_m2=20)
    n = len(cloud)
    dtype = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                      ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("scalar_Roughness", "<f4")])
    vertices = np.zeros(n, dtype)
    vertices["x"], vertices["y"], vertices["z"] = cloud.xyz.T
    vertices["nz"] = 1.0
    vertices["red"] = np.arange(n) % 256
    vertices["scalar_Roughness"] = np.linspace(0.0, 1.0, n)
    header = "".join(f"property {'double' if t == '<f8' else 'float' if t == '<f4' else 'uchar'} {name}\n"
                     for name, (t, _) in ((k, (dtype[k].str, 0)) for k in dtype.names or ()))
    (tmp_path / "cc.ply").write_bytes(f"ply\nformat binary_little_endian 1.0\ncomment CloudCompare\nelement vertex {n}\n"
                                      f"{header}end_header\n".encode() + vertices.tobytes())
    (tmp_path / "cc.txt").write_text("x y z nx ny nz roughness\n" + "".join(
        f"{x:.4f} {y:.4f} {z:.4f} 0 0 1 {r:.3f}\n" for (x, y, z), r in zip(cloud.xyz, vertices["scalar_Roughness"])))
    checkpoint, once = trained_run / "run" / "last.pt", EvalConfig(max_passes=1)

    ply = predict_cloud(checkpoint, tmp_path / "cc.ply", tmp_path / "out.ply", device="cpu", evaluation=once)
    text = predict_cloud(checkpoint, tmp_path / "cc.txt", tmp_path / "out.txt", device="cpu", evaluation=once)

    body = (tmp_path / "out.ply").read_bytes().partition(b"end_header\n")[2]
    written = np.frombuffer(body, dtype=dtype.descr + [("label", "u1")])
    for name in dtype.names or ():
        np.testing.assert_array_equal(written[name], vertices[name])
    np.testing.assert_array_equal(np.bincount(written["label"], minlength=5), ply.class_counts)
    lines = (tmp_path / "out.txt").read_text().splitlines()
    assert lines[0] == "x y z nx ny nz roughness label"
    assert [line.rsplit(" ", 1)[0] for line in lines[1:]] == (tmp_path / "cc.txt").read_text().splitlines()[1:]
    np.testing.assert_array_equal(np.bincount(read_cloud(tmp_path / "out.txt").label, minlength=5), text.class_counts)


def test_another_format_warns_in_one_line_naming_what_it_cannot_hold(
    tmp_path: Path, trained_run: Path, georeferenced: Path,
) -> None:
    lines: list[str] = []

    predict_cloud(trained_run / "run" / "last.pt", georeferenced, tmp_path / "out.ply", device="cpu",
                  evaluation=EvalConfig(max_passes=1), warn=lines.append)

    (line,) = lines
    assert line == (f"{tmp_path / 'out.ply'} will not hold what PLY has no place for: the CRS (WKT); VLR/EVLR "
                    f"Leica/42 of {georeferenced}")
    assert b"property float deviation\n" in (tmp_path / "out.ply").read_bytes()  # the extra dimension goes along


@st.composite
def georeferenced_las(draw: st.DrawFn) -> dict:
    version, point_format = draw(st.sampled_from([("1.2", 1), ("1.2", 3), ("1.3", 0), ("1.4", 2), ("1.4", 6),
                                                   ("1.4", 7), ("1.4", 8)]))
    users = st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ_", min_size=1, max_size=15)
    return {
        "version": version, "point_format": point_format,
        "scale": draw(st.sampled_from([1e-5, 2.5e-5, 1e-4, 5e-4, 1e-3])),
        "shift": draw(st.lists(st.floats(-500.0, 500.0, allow_nan=False), min_size=3, max_size=3)),
        "vlrs": draw(st.lists(st.tuples(users, st.integers(0, 65535), st.binary(max_size=80)), max_size=2)),
        "evlrs": draw(st.lists(st.tuples(users, st.integers(0, 65535), st.binary(max_size=200)), max_size=2))
        if version == "1.4" else [],
        "extra": draw(st.lists(st.sampled_from(["u1", "i2", "u4", "i8", "f4", "f8"]), max_size=2)),
        "compress": draw(st.booleans()), "target": draw(st.sampled_from([".las", ".laz"])),
    }


@pytest.mark.slow
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(spec=georeferenced_las())
def test_predict_keeps_random_header_scales_offsets_vlrs_and_extra_dimensions(trained_run: Path, spec: dict) -> None:
    import tempfile

    from bimscan.io.las import read_las_layout

    cloud = make_room(9, size_m=(3.0, 2.0), points_per_m2=15, origin=(512_000.0, 5_401_000.0))
    rng = np.random.default_rng(len(cloud))
    header = laspy.LasHeader(point_format=spec["point_format"], version=spec["version"])
    header.scales = np.full(3, spec["scale"])
    header.offsets = np.floor(cloud.xyz.min(axis=0)) + np.array(spec["shift"])
    for i, kind in enumerate(spec["extra"]):
        header.add_extra_dim(laspy.ExtraBytesParams(name=f"extra_{i}", type=np.dtype(kind)))
    for user, record, data in spec["vlrs"]:
        header.vlrs.append(laspy.VLR(f"u{user}", record, "a record", data))
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(len(cloud), header=header))
    records = np.asarray(las.points.array).view(np.uint8)
    records[:] = rng.integers(0, 256, records.shape)  # every field random ...
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]  # ... but the coordinates: a room
    if spec["evlrs"]:
        from laspy.vlrs.vlrlist import VLRList

        las.evlrs = VLRList([laspy.VLR(f"u{u}", r, "an EVLR", d) for u, r, d in spec["evlrs"]])
    with tempfile.TemporaryDirectory() as folder:
        source = Path(folder) / ("in.laz" if spec["compress"] else "in.las")
        las.write(source, do_compress=spec["compress"])
        target = Path(folder) / f"out{spec['target']}"

        result = predict_cloud(trained_run / "run" / "last.pt", source, target, device="cpu",
                               evaluation=EvalConfig(max_passes=1))

        before, after = laspy.read(source), laspy.read(target)
        assert after.header.point_format.id == spec["point_format"] and after.header.version == before.header.version
        assert list(after.header.scales) == list(before.header.scales)
        assert list(after.header.offsets) == list(before.header.offsets)
        anew = {("LASF_Spec", 0), ("laszip encoded", 22204), ("bimscan", 1)}
        kept = [[r.raw for r in (*layout.vlrs, *layout.evlrs) if (r.user_id, r.record_id) not in anew]
                for layout in (read_las_layout(source), read_las_layout(target))]
        assert kept[0] == kept[1]
        class_byte = 16 if spec["point_format"] >= 6 else 15
        rows = [np.asarray(x.points.array).view(np.uint8).reshape(len(cloud), -1).copy() for x in (before, after)]
        if class_byte == 15:  # legacy formats: the class is bits 0-4, the flags bits 5-7 stay
            np.testing.assert_array_equal(rows[1][:, 15] >> 5, rows[0][:, 15] >> 5)
        for row in rows:
            row[:, class_byte] = 0
        np.testing.assert_array_equal(rows[1], rows[0])
        np.testing.assert_array_equal(np.bincount(after.classification, minlength=5), result.class_counts)

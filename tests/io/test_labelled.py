"""Labelled copies: a user's cloud written again with new classes keeps everything else it held
(issue 50): a LAS's header, scales, offsets, CRS, VLRs, EVLRs, extra dimensions and raw point
records; another tool's PLY with every property and element; every column of a text cloud; every
array of a NumPy folder; an E57's scans, poses, point fields and images."""

from __future__ import annotations

import os
import struct
import tempfile
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from laspy.vlrs.known import WktCoordinateSystemVlr
from laspy.vlrs.vlrlist import VLRList

from bimscan.errors import InputFileError, OutputError
from bimscan.io import (
    plan_labelled_copy,
    read_cloud,
    read_cloud_header,
    write_labelled_copy,
)
from bimscan.io.las import read_las_layout
from bimscan.types import CloudHeader, LabelClass, LabelScheme

UTM_OFFSET = (512_000.0, 5_401_000.0, 300.0)
ETRS89_UTM32N = (
    'PROJCS["ETRS89 / UTM zone 32N",GEOGCS["ETRS89",DATUM["European_Terrestrial_Reference_System_1989",'
    'SPHEROID["GRS 1980",6378137,298.257222101]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],'
    'PROJECTION["Transverse_Mercator"],PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],'
    'PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],PARAMETER["false_northing",0],'
    'UNIT["metre",1],AUTHORITY["EPSG","25832"]]'
)
# The public header fields a copy rewrites: where the point data starts, how many VLRs it has, the
# point format byte (compression bit), where the EVLRs start and how many there are.
PATCHED = {96: 4, 100: 4, 104: 1, 235: 8, 243: 4}


def scheme_of(n_classes: int) -> LabelScheme:
    classes = tuple(LabelClass(id=i, name=f"class {i}", color="#4e79a7") for i in range(n_classes))
    return LabelScheme(name="predicted", classes=classes, rules=(), default_label=classes[-1].name)


def site_las(path: Path, *, n: int = 400, compress: bool = False, seed: int = 0) -> Path:
    """The issue's scan: LAS 1.4 in UTM with a WKT CRS, 10 micrometre steps, an extra dimension
    and another tool's EVLR."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.offsets = np.array(UTM_OFFSET)
    header.scales = np.array([1e-5, 1e-5, 1e-5])
    header.add_extra_dim(laspy.ExtraBytesParams(name="reflectance", type=np.float32, description="reflectance dB"))
    header.vlrs.append(WktCoordinateSystemVlr(ETRS89_UTM32N))
    header.global_encoding.wkt = True
    header.system_identifier = "RIEGL VZ-400i"
    header.generating_software = "RiSCAN PRO 2.15"
    las = laspy.LasData(header)
    las.X = rng.integers(0, 2_000_000, n)  # 20 m at 10 micrometres
    las.Y = rng.integers(0, 1_500_000, n)
    las.Z = rng.integers(0, 300_000, n)
    las.intensity = rng.integers(0, 65535, n).astype(np.uint16)
    las.classification = rng.integers(0, 20, n).astype(np.uint8)
    las.return_number, las.number_of_returns = np.ones(n, np.uint8), np.ones(n, np.uint8)
    las.gps_time = np.sort(rng.random(n)) * 100.0
    las.red, las.green, las.blue = (rng.integers(0, 65535, n).astype(np.uint16) for _ in range(3))
    las.point_source_id = np.full(n, 7, np.uint16)
    las.reflectance = rng.normal(-5.0, 2.0, n).astype(np.float32)
    las.evlrs = VLRList([laspy.VLR("RIEGL", 1, "scan position", b"SOP matrix " * 40)])
    las.write(path, do_compress=compress)
    return path


def copy(source: Path, target: Path, labels: np.ndarray, *, n_classes: int = 5, overwrite: bool = False) -> Path:
    plan = plan_labelled_copy(source, target, overwrite=overwrite, top_class=n_classes - 1)
    write_labelled_copy(plan, labels, header=CloudHeader(scheme=scheme_of(n_classes)))
    return target


def header_without_patched_fields(raw: bytes) -> bytes:
    masked = bytearray(raw)
    for offset, size in PATCHED.items():
        masked[offset:offset + size] = b"\0" * size
    return bytes(masked)


def records_except_class(path: Path) -> np.ndarray:
    """The point records of a LAS/LAZ (N, record length) uint8, the class byte zeroed."""
    las = laspy.read(path)
    rows = np.asarray(las.points.array).view(np.uint8).reshape(len(las.points), -1).copy()
    rows[:, 16 if las.header.point_format.id >= 6 else 15] = 0
    return rows


def kept_records(path: Path) -> tuple[list[bytes], list[bytes]]:
    """The raw VLRs and EVLRs of a file other than the classification lookup, the LASzip record and
    bimscan's header document (what a copy writes anew)."""
    layout = read_las_layout(path)
    anew = {("LASF_Spec", 0), ("laszip encoded", 22204), ("bimscan", 1)}
    return ([r.raw for r in layout.vlrs if (r.user_id, r.record_id) not in anew],
            [r.raw for r in layout.evlrs if (r.user_id, r.record_id) not in anew])


# -- LAS / LAZ ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("source_suffix", "target_suffix"), [(".las", ".las"), (".las", ".laz"), (".laz", ".las")])
def test_a_labelled_las_keeps_its_header_crs_records_and_extra_dimension_byte_for_byte(
    tmp_path: Path, source_suffix: str, target_suffix: str,
) -> None:
    source = site_las(tmp_path / f"site{source_suffix}", compress=source_suffix == ".laz")
    labels = (np.arange(400) % 5).astype(np.uint8)

    target = copy(source, tmp_path / f"labelled{target_suffix}", labels)

    before, after = read_las_layout(source), read_las_layout(target)
    assert header_without_patched_fields(after.header) == header_without_patched_fields(before.header)
    assert after.compressed == (target_suffix == ".laz")
    assert kept_records(target) == kept_records(source)  # the WKT CRS, the extra-bytes VLR, RIEGL's EVLR
    original, labelled = laspy.read(source), laspy.read(target)
    np.testing.assert_array_equal(records_except_class(target), records_except_class(source))
    np.testing.assert_array_equal(labelled.X, original.X)  # integer steps copied, never re-quantised
    np.testing.assert_array_equal(labelled.reflectance, original.reflectance)
    np.testing.assert_array_equal(labelled.classification, labels)
    assert list(labelled.header.scales) == [1e-5] * 3 and list(labelled.header.offsets) == list(UTM_OFFSET)
    assert "UTM zone 32N" in labelled.header.vlrs.get("WktCoordinateSystemVlr")[0].string
    stored = read_cloud_header(target)
    assert stored is not None and stored.scheme == scheme_of(5) and stored.origin == UTM_OFFSET
    cloud = read_cloud(target)
    np.testing.assert_array_equal(cloud.label, labels)
    np.testing.assert_array_equal(cloud.rgb, (np.stack([original.red, original.green, original.blue], 1) >> 8).astype(np.uint8))


def test_a_copy_of_a_copy_replaces_bimscans_records_instead_of_adding_more(tmp_path: Path) -> None:
    once = copy(site_las(tmp_path / "site.las"), tmp_path / "once.laz", np.zeros(400, np.uint8))

    twice = copy(once, tmp_path / "twice.las", np.ones(400, np.uint8), n_classes=3)

    layout = read_las_layout(twice)
    ids = [(r.user_id, r.record_id) for r in (*layout.vlrs, *layout.evlrs)]
    assert ids.count(("LASF_Spec", 0)) == 1 and ids.count(("bimscan", 1)) == 1
    assert ("laszip encoded", 22204) not in ids
    stored = read_cloud_header(twice)
    assert stored is not None and stored.scheme == scheme_of(3)
    assert laspy.read(twice).header.vlrs.get("ClassificationLookupVlr")[0][2] == "class 2"


def test_a_legacy_point_format_becomes_its_las_14_equivalent_when_the_classes_do_not_fit_5_bits(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = np.array(UTM_OFFSET), np.array([1e-3] * 3)
    header.add_extra_dim(laspy.ExtraBytesParams(name="deviation", type=np.uint16))
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = np.arange(50), np.arange(50) * 2, np.arange(50) * 3
    las.scan_angle_rank = np.arange(-25, 25).astype(np.int8)
    las.withheld = np.arange(50) % 2
    las.return_number, las.number_of_returns = np.full(50, 2), np.full(50, 3)
    las.red = np.arange(50, dtype=np.uint16) * 1000
    las.deviation = np.arange(50, dtype=np.uint16)
    las.write(tmp_path / "old.las")
    labels = (np.arange(50) % 40).astype(np.uint8)

    plan = plan_labelled_copy(tmp_path / "old.las", tmp_path / "new.las", top_class=39)
    write_labelled_copy(plan, labels, header=CloudHeader(scheme=scheme_of(40)))

    assert "point format 3 (LAS 1.2) becomes 7 (LAS 1.4)" in plan.check.changed[0]
    new = laspy.read(tmp_path / "new.las")
    assert new.header.point_format.id == 7 and str(new.header.version) == "1.4"
    np.testing.assert_array_equal(new.classification, labels)
    np.testing.assert_array_equal(new.X, las.X)
    np.testing.assert_array_equal(new.withheld, las.withheld)
    np.testing.assert_array_equal(new.red, las.red)
    np.testing.assert_array_equal(new.deviation, las.deviation)
    np.testing.assert_allclose(np.asarray(new.scan_angle) * 0.006, las.scan_angle_rank, atol=0.003)
    assert list(new.header.number_of_points_by_return[:3]) == [0, 50, 0]
    assert int.from_bytes(read_las_layout(tmp_path / "new.las").header[107:111], "little") == 0  # legacy count: 0


def test_a_las_12_copy_keeps_bimscans_header_in_a_vlr(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=1, version="1.2")
    las = laspy.LasData(header)
    las.X = np.arange(20)
    las.classification = np.full(20, 2)
    las.write(tmp_path / "old.las")

    copy(tmp_path / "old.las", tmp_path / "new.las", np.full(20, 4, np.uint8))

    assert str(laspy.read(tmp_path / "new.las").header.version) == "1.2"
    stored = read_cloud_header(tmp_path / "new.las")
    assert stored is not None and stored.scheme == scheme_of(5)
    np.testing.assert_array_equal(read_cloud(tmp_path / "new.las").label, np.full(20, 4))


VLR_USERS = st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz_0123456789", min_size=1, max_size=16)
EXTRA_TYPES = ("u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f4", "f8")
FORMATS = [("1.2", f) for f in range(4)] + [("1.3", f) for f in range(6)] + [("1.4", f) for f in range(11)]


@st.composite
def las_files(draw: st.DrawFn) -> dict:
    version, point_format = draw(st.sampled_from(FORMATS))
    n_extra = draw(st.integers(0, 3))
    return {
        "version": version, "point_format": point_format,
        "scales": draw(st.lists(st.sampled_from([1e-6, 1e-5, 2.5e-5, 1e-4, 1e-3, 0.01, 0.25]), min_size=3, max_size=3)),
        "offsets": draw(st.lists(st.floats(-1e7, 1e7, allow_nan=False), min_size=3, max_size=3)),
        "vlrs": draw(st.lists(st.tuples(VLR_USERS, st.integers(0, 65535), st.binary(max_size=120)), max_size=3)),
        "evlrs": draw(st.lists(st.tuples(VLR_USERS, st.integers(0, 65535), st.binary(max_size=300)), max_size=2))
        if version == "1.4" else [],
        "extra": [(f"field_{i}", draw(st.sampled_from(EXTRA_TYPES))) for i in range(n_extra)],
        "n": draw(st.integers(1, 60)),
        "compress": draw(st.booleans()),
        "target": draw(st.sampled_from([".las", ".laz"])),
        "classes": draw(st.integers(1, 48)),
        "seed": draw(st.integers(0, 2**16)),
    }


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(las_files())
def test_every_header_scale_offset_vlr_evlr_and_extra_dimension_survives_a_labelled_copy(spec: dict) -> None:
    rng = np.random.default_rng(spec["seed"])
    header = laspy.LasHeader(point_format=spec["point_format"], version=spec["version"])
    header.scales, header.offsets = np.array(spec["scales"]), np.array(spec["offsets"])
    for name, kind in spec["extra"]:
        header.add_extra_dim(laspy.ExtraBytesParams(name=name, type=np.dtype(kind)))
    for user, record, data in spec["vlrs"]:
        header.vlrs.append(laspy.VLR(f"x{user}"[:16], record, "another tool's record", data))
    n = spec["n"]
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(n, header=header))
    records = np.asarray(las.points.array).view(np.uint8)
    records[:] = rng.integers(0, 256, records.shape)  # every bit of every field, extra bytes included
    if spec["point_format"] in (4, 5, 9, 10) and (spec["compress"] or spec["target"] == ".laz"):
        # LASzip's wave packet codec of formats 9 and 10 does not give every random bit pattern back
        # (laspy alone loses them too); real wave packets (an index, growing offsets) survive
        for name in ("wavepacket_index", "wavepacket_offset", "wavepacket_size"):
            las[name] = np.zeros(n, dtype=np.asarray(las[name]).dtype)
    if spec["evlrs"]:
        las.evlrs = VLRList([laspy.VLR(f"x{u}"[:16], r, "an EVLR", d) for u, r, d in spec["evlrs"]])
    with tempfile.TemporaryDirectory() as folder:
        source = Path(folder) / ("in.laz" if spec["compress"] else "in.las")
        las.write(source, do_compress=spec["compress"])
        original = laspy.read(source)
        labels = rng.integers(0, spec["classes"], n).astype(np.uint8)
        target = copy(source, Path(folder) / f"out{spec['target']}", labels, n_classes=spec["classes"])

        labelled = laspy.read(target)
        upgraded = spec["point_format"] < 6 and spec["classes"] > 32
        assert labelled.header.point_format.id == (
            {0: 6, 1: 6, 2: 7, 3: 7, 4: 9, 5: 10}[spec["point_format"]] if upgraded else spec["point_format"])
        assert list(labelled.header.scales) == list(original.header.scales)
        assert list(labelled.header.offsets) == list(original.header.offsets)
        assert kept_records(target) == kept_records(source)
        np.testing.assert_array_equal(labelled.classification, labels)
        for name in original.point_format.dimension_names:
            if name in ("classification", "scan_angle_rank") or (upgraded and name == "return_number"):
                continue
            np.testing.assert_array_equal(np.asarray(labelled[name]), np.asarray(original[name]), err_msg=name)
        if not upgraded:
            np.testing.assert_array_equal(records_except_class(target), records_except_class(source))
            assert header_without_patched_fields(read_las_layout(target).header) == \
                header_without_patched_fields(read_las_layout(source).header)
        stored = read_cloud_header(target)
        assert stored is not None and stored.scheme == scheme_of(spec["classes"])


# -- the plan: what an output keeps, and writing over the input ---------------------------------------

def test_writing_over_the_input_by_another_spelling_keeps_everything_and_needs_overwrite(tmp_path: Path) -> None:
    source = site_las(tmp_path / "site.las")
    before = source.read_bytes()
    spelled = tmp_path / "sub" / ".." / "site.las"
    (tmp_path / "sub").mkdir()

    with pytest.raises(OutputError, match="already exists; pass --overwrite"):
        plan_labelled_copy(source, spelled, top_class=4)
    plan = plan_labelled_copy(source, spelled, overwrite=True, top_class=4)
    write_labelled_copy(plan, np.full(400, 3, np.uint8), header=CloudHeader(scheme=scheme_of(5)))

    assert plan.same_file and plan.notices() == ()
    after = source.read_bytes()
    assert header_without_patched_fields(after[:375]) == header_without_patched_fields(before[:375])
    np.testing.assert_array_equal(laspy.read(source).classification, np.full(400, 3))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site.las", "sub"]  # no temporary left


def test_writing_over_the_input_through_a_link_to_it_is_refused_as_every_link_is(tmp_path: Path) -> None:
    source = site_las(tmp_path / "site.las")
    os.symlink(source, tmp_path / "link.las")

    with pytest.raises(OutputError, match="link.las is a symbolic link"):
        plan_labelled_copy(source, tmp_path / "link.las", overwrite=True)


def test_a_link_to_the_output_as_input_is_the_same_file(tmp_path: Path) -> None:
    source = site_las(tmp_path / "site.las")
    os.symlink(source, tmp_path / "link.las")

    plan = plan_labelled_copy(tmp_path / "link.las", source, overwrite=True)

    assert plan.same_file and plan.copied


def test_writing_over_the_input_is_refused_before_any_work_when_the_copy_would_change_it(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=1, version="1.2")
    laspy.LasData(header).write(tmp_path / "old.las")
    before = (tmp_path / "old.las").read_bytes()

    with pytest.raises(OutputError, match=r"old.las is the input .*old.las and its labelled copy would not keep all "
                                          r"of it \(point format 1 \(LAS 1.2\) becomes 6 \(LAS 1.4\)"):
        plan_labelled_copy(tmp_path / "old.las", tmp_path / "old.las", overwrite=True, top_class=40)
    assert (tmp_path / "old.las").read_bytes() == before


def test_another_format_carries_every_field_it_can_hold_and_names_the_rest_in_one_line(tmp_path: Path) -> None:
    source = site_las(tmp_path / "site.las")
    labels = (np.arange(400) % 5).astype(np.uint8)
    header = CloudHeader(scheme=scheme_of(5), origin=UTM_OFFSET)

    to_ply = plan_labelled_copy(source, tmp_path / "out.ply", top_class=4)
    to_npy = plan_labelled_copy(source, tmp_path / "out", top_class=4)
    to_e57 = plan_labelled_copy(source, tmp_path / "out.e57", top_class=4)
    for plan in (to_ply, to_npy):
        write_labelled_copy(plan, labels, header=header)

    (ply_line,) = to_ply.notices()
    assert ply_line == (f"{tmp_path / 'out.ply'} will not hold what PLY has no place for: the CRS (WKT); VLR/EVLR "
                        f"RIEGL/1 of {source}")
    (e57_line,) = to_e57.notices()  # E57 has no field for another format's: named, with the rest
    assert e57_line.startswith(f"{tmp_path / 'out.e57'} will not hold what E57 has no place for: fields 'synthetic', ")
    assert "'reflectance'" in e57_line
    assert "the CRS (WKT)" in e57_line and "\n" not in e57_line
    original = laspy.read(source)
    body = (tmp_path / "out.ply").read_bytes().partition(b"end_header\n")[2]
    head = (tmp_path / "out.ply").read_bytes().partition(b"end_header\n")[0].decode().splitlines()
    assert head[-4:] == ["property uchar user_data", "property short scan_angle", "property ushort point_source_id",
                         "property float reflectance"]
    names = [line.split()[-1] for line in head if line.startswith("property")]
    kinds = {"double": "<f8", "uchar": "u1", "ushort": "<u2", "short": "<i2", "float": "<f4"}
    rows = np.frombuffer(body, dtype=[(n, kinds[line.split()[1]]) for n, line in
                                      zip(names, [l for l in head if l.startswith("property")], strict=True)])
    for name in ("reflectance", "point_source_id", "scan_angle", "user_data", "synthetic"):
        np.testing.assert_array_equal(rows[name], np.asarray(original[name]), err_msg=name)
        np.testing.assert_array_equal(np.load(tmp_path / "out" / f"{name}.npy"), np.asarray(original[name]))
    np.testing.assert_array_equal(rows["label"], labels)
    assert (tmp_path / "out" / "reflectance.npy").is_file()
    copy(source, tmp_path / "out", labels, overwrite=True)  # the folder with the fields stays bimscan's to replace


def test_another_tools_ply_normals_and_scalar_fields_become_extra_dimensions_of_a_laz(tmp_path: Path) -> None:
    vertices = foreign_ply(tmp_path / "scan.ply", fmt="ascii")
    labels = (np.arange(30) % 5).astype(np.uint8)

    plan = plan_labelled_copy(tmp_path / "scan.ply", tmp_path / "out.laz", top_class=4)
    write_labelled_copy(plan, labels, header=CloudHeader(scheme=scheme_of(5)))

    assert [f.name for f in plan.fields] == ["nx", "ny", "nz", "scalar_Deviation"]
    assert plan.notices() == (f"{tmp_path / 'out.laz'} will not hold what LAZ has no place for: element face (2); "
                              f"its header comments of {tmp_path / 'scan.ply'}",)
    las = laspy.read(tmp_path / "out.laz")
    for name in ("nx", "ny", "nz", "scalar_Deviation"):
        np.testing.assert_array_equal(np.asarray(las[name]), vertices[name])
    np.testing.assert_array_equal(las.classification, labels)


def test_an_e57s_scan_grid_and_extension_fields_go_to_another_format_with_its_valid_points(tmp_path: Path) -> None:
    foreign_e57(tmp_path / "site.e57")
    cloud = read_cloud(tmp_path / "site.e57")

    plan = plan_labelled_copy(tmp_path / "site.e57", tmp_path / "out", top_class=4)
    write_labelled_copy(plan, np.zeros(len(cloud), np.uint8), header=CloudHeader(scheme=scheme_of(5), origin=UTM_OFFSET))

    valid = np.concatenate([e57_points(tmp_path / "site.e57", i)["cartesianInvalidState"] == 0 for i in range(2)])
    rows = np.concatenate([e57_points(tmp_path / "site.e57", i)["rowIndex"] for i in range(2)])
    np.testing.assert_array_equal(np.load(tmp_path / "out" / "rowIndex.npy"), rows[valid])
    assert [f.name for f in plan.fields] == ["rowIndex"]
    (line,) = plan.notices()
    assert "field 'nor:normalX' (not a plain file name)" in line and "1 image (images2D)" in line


def test_a_text_output_is_written_only_from_a_text_input(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match="bimscan writes text clouds only as labelled copies of text clouds"):
        plan_labelled_copy(site_las(tmp_path / "site.las"), tmp_path / "out.txt")


def test_a_failed_copy_leaves_nothing_behind(tmp_path: Path) -> None:
    source = site_las(tmp_path / "site.las")
    plan = plan_labelled_copy(source, tmp_path / "out.laz", top_class=4)

    with pytest.raises(ValueError, match="399 labels for 400 points"):
        write_labelled_copy(plan, np.zeros(399, np.uint8), header=CloudHeader(scheme=scheme_of(5)))

    assert sorted(p.name for p in tmp_path.iterdir()) == ["site.las"]


# -- PLY ------------------------------------------------------------------------------------------

FOREIGN_PROPERTIES = (("x", "float"), ("y", "float"), ("z", "float"), ("nx", "float"), ("ny", "float"),
                      ("nz", "float"), ("red", "uchar"), ("green", "uchar"), ("blue", "uchar"),
                      ("scalar_Deviation", "float"))
PLY_NUMPY = {"float": "f4", "uchar": "u1", "int": "i4", "char": "i1", "double": "f8"}


def foreign_ply(path: Path, *, fmt: str, n: int = 30, label: tuple[str, str] | None = None) -> np.ndarray:
    """A CloudCompare-style PLY: normals, colour, a scalar field (and a label-like one), faces."""
    properties = FOREIGN_PROPERTIES + ((label,) if label is not None else ())
    order = ">" if fmt == "binary_big_endian" else "<"
    dtype = np.dtype([(name, order + PLY_NUMPY[kind]) for name, kind in properties])
    rng = np.random.default_rng(3)
    vertices = np.zeros(n, dtype)
    for name in dtype.names or ():
        vertices[name] = rng.integers(0, 200, n) if dtype[name].kind in "iu" else rng.random(n) * 10
    lines = ["ply", f"format {fmt} 1.0", "comment Created by CloudCompare v2.13.1", "obj_info scanned 2024-05-02",
             f"element vertex {n}", *(f"property {kind} {name}" for name, kind in properties),
             "element face 2", "property list uchar int vertex_indices", "end_header"]
    with path.open("wb") as out:
        out.write(("\n".join(lines) + "\n").encode("ascii"))
        if fmt == "ascii":
            for row in vertices:
                out.write((" ".join(repr(v.item()) for v in row) + "\n").encode("ascii"))
            out.write(b"3 0 1 2\n3 2 3 4\n")
        else:
            out.write(vertices.tobytes())
            face = np.dtype([("n", "u1"), ("i", order + "i4", (3,))])
            out.write(np.array([(3, (0, 1, 2)), (3, (2, 3, 4))], dtype=face).tobytes())
    return vertices


def ply_parts(path: Path) -> tuple[list[bytes], bytes]:
    data = path.read_bytes()
    head, _, body = data.partition(b"end_header\n")
    return head.split(b"\n"), body


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian", "ascii"])
def test_another_tools_ply_keeps_every_property_element_and_header_line(tmp_path: Path, fmt: str) -> None:
    vertices = foreign_ply(tmp_path / "scan.ply", fmt=fmt)
    labels = (np.arange(30) % 5).astype(np.uint8)

    target = copy(tmp_path / "scan.ply", tmp_path / "labelled.ply", labels)

    head_in, body_in = ply_parts(tmp_path / "scan.ply")
    head_out, body_out = ply_parts(target)
    assert head_out == head_in[:15] + [b"property uchar label"] + head_in[15:]  # after the last vertex property
    cloud = read_cloud(target)
    np.testing.assert_array_equal(cloud.label, labels)
    np.testing.assert_allclose(cloud.xyz[:, 0], vertices["x"], rtol=1e-6)
    if fmt == "ascii":
        lines_in, lines_out = body_in.split(b"\n"), body_out.split(b"\n")
        assert [line.rsplit(b" ", 1)[0] for line in lines_out[:30]] == lines_in[:30]
        assert lines_out[30:] == lines_in[30:]  # the faces
    else:
        order = ">" if fmt == "binary_big_endian" else "<"
        written = np.frombuffer(body_out[: 30 * (vertices.itemsize + 1)],
                                dtype=vertices.dtype.descr + [("label", order + "u1")])
        for name in vertices.dtype.names or ():
            np.testing.assert_array_equal(written[name], vertices[name])
        assert body_out[30 * (vertices.itemsize + 1):] == body_in[30 * vertices.itemsize:]  # the faces
    stored = read_cloud_header(target)
    assert stored is not None and stored.scheme == scheme_of(5)


def test_a_ply_label_scalar_field_gets_the_classes_in_its_place_and_type(tmp_path: Path) -> None:
    vertices = foreign_ply(tmp_path / "scan.ply", fmt="binary_little_endian", label=("scalar_Classification", "float"))
    labels = (np.arange(30) % 5).astype(np.uint8)

    target = copy(tmp_path / "scan.ply", tmp_path / "labelled.ply", labels)

    head_in, body_in = ply_parts(tmp_path / "scan.ply")
    head_out, body_out = ply_parts(target)
    assert head_out == head_in and len(body_out) == len(body_in)
    written = np.frombuffer(body_out[: vertices.nbytes], dtype=vertices.dtype)
    np.testing.assert_array_equal(written["scalar_Classification"], labels.astype(np.float32))
    np.testing.assert_array_equal(written["scalar_Deviation"], vertices["scalar_Deviation"])
    np.testing.assert_array_equal(read_cloud(target).label, labels)


def test_a_char_label_property_becomes_uchar_for_class_ids_above_127(tmp_path: Path) -> None:
    foreign_ply(tmp_path / "scan.ply", fmt="binary_little_endian", label=("label", "char"))
    labels = (np.arange(30) * 7).astype(np.uint8)

    plan = plan_labelled_copy(tmp_path / "scan.ply", tmp_path / "labelled.ply", top_class=250)
    write_labelled_copy(plan, labels, header=CloudHeader(scheme=scheme_of(251)))

    assert plan.check.changed == ("vertex property 'label' becomes uchar: its type (i1) cannot hold class id 250",)
    assert b"property uchar label" in ply_parts(tmp_path / "labelled.ply")[0]
    np.testing.assert_array_equal(read_cloud(tmp_path / "labelled.ply").label, labels)


def test_bimscans_own_ply_gets_the_new_scheme_in_its_comments_and_sidecar(tmp_path: Path, header: CloudHeader) -> None:
    from bimscan.io import open_cloud_writer

    from .conftest import make_cloud

    cloud = make_cloud(50, seed=2)
    with open_cloud_writer(tmp_path / "scan.ply", header=header) as writer:
        writer.write(cloud)
    labels = np.full(50, 2, np.uint8)

    target = copy(tmp_path / "scan.ply", tmp_path / "labelled.ply", labels, n_classes=3)

    head = ply_parts(target)[0]
    assert head.count(b"comment bimscan cloud 1") == 1
    assert [line for line in head if line.startswith(b"comment class")] == [
        f'comment class {i} #4e79a7 "class {i}"'.encode() for i in range(3)]
    again = read_cloud(target)
    np.testing.assert_array_equal(again.label, labels)
    np.testing.assert_array_equal(again.component, cloud.component)
    stored = read_cloud_header(target)
    assert stored is not None and stored.scheme == scheme_of(3) and stored.origin == header.origin


# -- text -----------------------------------------------------------------------------------------

TEXT_CASES = {
    # CloudCompare ASCII with a header line, comments, a blank line, CRLF and an inline comment
    "named.txt": ("// exported\r\nX,Y,Z,Nx,Ny,Nz,Intensity\r\n1.5,2,3,0,0,1,55\r\n\r\n4,5,6.25,0,1,0,7 # note\r\n"
                  "7,8,9,1,0,0,9\r\n", "// exported\r\nX,Y,Z,Nx,Ny,Nz,Intensity,label\r\n1.5,2,3,0,0,1,55,1\r\n\r\n"
                  "4,5,6.25,0,1,0,7,2 # note\r\n7,8,9,1,0,0,9,3\r\n"),
    "labelled.txt": ("x y z r g b classification\n1 2 3 10 20 30 7\n4 5 6 10 20 30 7\n7 8 9 1 1 1 7\n",
                     "x y z r g b classification\n1 2 3 10 20 30 1\n4 5 6 10 20 30 2\n7 8 9 1 1 1 3\n"),
    "plain.xyz": ("1 2 3\n4 5 6\n7 8 9", "1 2 3 1\n4 5 6 2\n7 8 9 3"),
    "coloured.txt": ("1 2 3 10 20 30\n4 5 6 1 2 3\n7 8 9 4 5 6\n",
                     "1 2 3 10 20 30 1\n4 5 6 1 2 3 2\n7 8 9 4 5 6 3\n"),
    "scan.pts": ("3\n1 2 3 -100 10 20 30\n4 5 6 -50 1 2 3\n7 8 9 0 4 5 6\n",
                 "3\nx y z intensity r g b label\n1 2 3 -100 10 20 30 1\n4 5 6 -50 1 2 3 2\n7 8 9 0 4 5 6 3\n"),
}


@pytest.mark.parametrize("name", sorted(TEXT_CASES))
def test_a_text_cloud_keeps_every_line_and_column_and_gets_its_label_column(tmp_path: Path, name: str) -> None:
    text, expected = TEXT_CASES[name]
    source = tmp_path / name
    source.write_bytes(text.encode())
    labels = np.array([1, 2, 3], np.uint8)

    target = copy(source, tmp_path / f"out{source.suffix}", labels)

    assert target.read_bytes() == expected.encode()
    np.testing.assert_array_equal(read_cloud(target).label, labels)


def test_a_pts_file_cannot_be_labelled_in_place_as_it_gains_a_header_line(tmp_path: Path) -> None:
    (tmp_path / "scan.pts").write_text(TEXT_CASES["scan.pts"][0])

    with pytest.raises(OutputError, match="its labelled copy would not keep all of it \\(a header line 'x y z "
                                          "intensity r g b label' is added"):
        plan_labelled_copy(tmp_path / "scan.pts", tmp_path / "scan.pts", overwrite=True)


# -- NumPy folders ---------------------------------------------------------------------------------

def test_a_numpy_folder_keeps_every_array_and_can_be_replaced_by_a_later_run(tmp_path: Path) -> None:
    folder = tmp_path / "scene"
    folder.mkdir()
    coord = np.random.default_rng(0).random((40, 3)).astype(np.float32)
    np.save(folder / "coord.npy", coord)
    np.save(folder / "normal.npy", np.ones((40, 3), np.float32))
    np.save(folder / "segment.npy", np.full(40, -1, np.int64))  # Pointcept's "ignore"
    (folder / "notes.txt").write_text("scanned twice")
    labels = (np.arange(40) % 5).astype(np.uint8)

    target = copy(folder, tmp_path / "labelled", labels)
    copy(folder, target, labels[::-1].copy(), overwrite=True)  # its own output: replaced whole

    assert sorted(p.name for p in target.iterdir()) == ["coord.npy", "meta.json", "normal.npy", "notes.txt", "segment.npy"]
    np.testing.assert_array_equal(np.load(target / "coord.npy"), coord)
    np.testing.assert_array_equal(np.load(target / "normal.npy"), np.ones((40, 3), np.float32))
    assert (target / "notes.txt").read_text() == "scanned twice"
    segment = np.load(target / "segment.npy")
    assert segment.dtype == np.int64
    np.testing.assert_array_equal(segment, labels[::-1])
    stored = read_cloud_header(target)
    assert stored is not None and stored.scheme == scheme_of(5)
    np.testing.assert_array_equal(np.load(folder / "segment.npy"), np.full(40, -1))  # the input as it was


# -- E57 ------------------------------------------------------------------------------------------

def foreign_e57(path: Path, n: int = 300) -> None:
    """Two posed scans as a scanner's software exports them: scaled-integer cartesian coordinates,
    float intensity, colour, the scan grid, points flagged invalid, and an image with its blob."""
    from pye57 import libe57

    rng = np.random.default_rng(5)
    image = libe57.ImageFile(str(path), "w")
    image.extensionsAdd("nor", "http://www.example.com/normals")
    root = image.root()
    root.set("formatName", libe57.StringNode(image, "ASTM E57 3D Imaging Data File"))
    root.set("guid", libe57.StringNode(image, "{e57-guid-of-the-site}"))
    root.set("coordinateMetadata", libe57.StringNode(image, ETRS89_UTM32N))
    data3d = libe57.VectorNode(image, True)
    root.set("data3D", data3d)
    for index in range(2):
        scan = libe57.StructureNode(image)
        data3d.append(scan)
        scan.set("guid", libe57.StringNode(image, f"{{scan-{index}}}"))
        scan.set("name", libe57.StringNode(image, f"Station {index + 1}"))
        pose = libe57.StructureNode(image)
        rotation, translation = libe57.StructureNode(image), libe57.StructureNode(image)
        for key, value in zip("wxyz", (0.9238795325, 0.0, 0.0, 0.3826834324), strict=True):
            rotation.set(key, libe57.FloatNode(image, value))
        for key, value in zip("xyz", (UTM_OFFSET[0] + 10 * index, UTM_OFFSET[1], UTM_OFFSET[2]), strict=True):
            translation.set(key, libe57.FloatNode(image, value))
        pose.set("rotation", rotation)
        pose.set("translation", translation)
        scan.set("pose", pose)
        prototype = libe57.StructureNode(image)
        for axis in "XYZ":
            prototype.set(f"cartesian{axis}", libe57.ScaledIntegerNode(image, 0, -2**31, 2**31 - 1, 1e-5, 0.0))
        prototype.set("cartesianInvalidState", libe57.IntegerNode(image, 0, 0, 2))
        prototype.set("intensity", libe57.FloatNode(image, 0.0, libe57.E57_SINGLE, 0.0, 1.0))
        for channel in ("Red", "Green", "Blue"):
            prototype.set(f"color{channel}", libe57.IntegerNode(image, 0, 0, 255))
        prototype.set("rowIndex", libe57.IntegerNode(image, 0, 0, 10_000))
        prototype.set("nor:normalX", libe57.FloatNode(image, 0.0, libe57.E57_SINGLE))
        points = libe57.CompressedVectorNode(image, prototype, libe57.VectorNode(image, True))
        scan.set("points", points)
        columns = {f"cartesian{a}": rng.integers(-1_000_000, 1_000_000, n).astype(np.longlong) for a in "XYZ"}
        columns["cartesianInvalidState"] = (rng.random(n) < 0.1).astype(np.longlong) * 2
        columns["intensity"] = rng.random(n).astype(np.float32).astype(np.float64)
        for channel in ("Red", "Green", "Blue"):
            columns[f"color{channel}"] = rng.integers(0, 256, n).astype(np.longlong)
        columns["rowIndex"] = np.arange(n, dtype=np.longlong)
        columns["nor:normalX"] = rng.random(n).astype(np.float32).astype(np.float64)
        buffers = libe57.VectorSourceDestBuffer()
        for name, values in columns.items():
            buffers.append(libe57.SourceDestBuffer(image, name, values, n, True, name.startswith("cartesian") is False))
        writer = points.writer(buffers)
        writer.write(n)
        writer.close()
    images = libe57.VectorNode(image, True)
    root.set("images2D", images)
    picture = libe57.StructureNode(image)
    images.append(picture)
    picture.set("name", libe57.StringNode(image, "panorama"))
    blob = libe57.BlobNode(image, 1000)
    jpeg = libe57.StructureNode(image)
    picture.set("pinholeRepresentation", jpeg)
    jpeg.set("jpegImage", blob)
    blob.write((np.arange(1000) % 251).astype(np.uint8), 0, 1000)
    image.close()


def e57_points(path: Path, scan_index: int) -> dict[str, np.ndarray]:
    """Every point field of a scan as stored (scaled integers as their raw integers)."""
    from pye57 import libe57

    image = libe57.ImageFile(str(path), "r")
    try:
        scan = libe57.StructureNode(image.root()["data3D"].get(scan_index))
        vector = libe57.CompressedVectorNode(scan.get("points"))
        prototype = libe57.StructureNode(vector.prototype())
        n = vector.childCount()
        columns = {}
        buffers = libe57.VectorSourceDestBuffer()
        for i in range(prototype.childCount()):
            name = prototype.get(i).elementName()
            columns[name] = np.zeros(n, np.float64 if "intensity" in name or "normal" in name else np.longlong)
            buffers.append(libe57.SourceDestBuffer(image, name, columns[name], n, True, False))
        reader = vector.reader(buffers)
        reader.read()
        reader.close()
        return columns
    finally:
        image.close()


def test_an_e57_keeps_its_scans_poses_raw_point_fields_and_images(tmp_path: Path) -> None:
    from pye57 import libe57

    from bimscan.io.e57 import LABEL_FIELD, read_e57_scans

    foreign_e57(tmp_path / "site.e57")
    before = read_cloud(tmp_path / "site.e57")
    labels = (np.arange(len(before)) % 5).astype(np.uint8)

    target = copy(tmp_path / "site.e57", tmp_path / "labelled.e57", labels)

    assert read_e57_scans(target) == read_e57_scans(tmp_path / "site.e57")
    for index in range(2):
        old, new = e57_points(tmp_path / "site.e57", index), e57_points(target, index)
        assert list(new) == [*old, LABEL_FIELD]
        for name, values in old.items():
            np.testing.assert_array_equal(new[name], values, err_msg=name)
        valid = old["cartesianInvalidState"] == 0
        assert set(new[LABEL_FIELD][~valid]) <= {255}
    after = read_cloud(target)
    np.testing.assert_array_equal(after.label, labels)
    np.testing.assert_array_equal(after.xyz, before.xyz)
    image = libe57.ImageFile(str(target), "r")
    try:
        root = image.root()
        assert root["guid"].value() == "{e57-guid-of-the-site}" and "UTM zone 32N" in root["coordinateMetadata"].value()
        blob = libe57.BlobNode(libe57.StructureNode(libe57.StructureNode(root["images2D"].get(0)).get(
            "pinholeRepresentation")).get("jpegImage"))
        data = np.zeros(1000, np.uint8)
        blob.read(data, 0, 1000)
        np.testing.assert_array_equal(data, np.arange(1000) % 251)
    finally:
        image.close()
    stored = read_cloud_header(target)
    assert stored is not None and stored.scheme == scheme_of(5)


def test_a_damaged_input_is_refused_in_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    source = site_las(tmp_path / "site.las")
    data = bytearray(source.read_bytes())
    struct.pack_into("<I", data, 100, 90)  # 90 VLRs: more than the file holds
    source.write_bytes(bytes(data))

    with pytest.raises(InputFileError, match="site.las"):
        plan_labelled_copy(source, tmp_path / "out.las")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site.las"]


def test_the_same_input_and_labels_give_the_same_bytes_in_every_format(tmp_path: Path) -> None:
    sources = [site_las(tmp_path / "site.laz", compress=True), tmp_path / "scan.ply", tmp_path / "site.e57",
               tmp_path / "scan.txt"]
    foreign_ply(sources[1], fmt="binary_big_endian")
    foreign_e57(sources[2])
    sources[3].write_text(TEXT_CASES["named.txt"][0])
    for source in sources:
        labels = (np.arange(len(read_cloud(source))) % 5).astype(np.uint8)
        targets = [tmp_path / f"{name}{source.suffix}" for name in ("a", "b")]

        for target in targets:
            copy(source, target, labels)

        assert targets[0].read_bytes() == targets[1].read_bytes(), source.name


# -- every copier, every pair ----------------------------------------------------------------------

SOURCE_SUFFIXES = {"las": ".las", "laz": ".laz", "ply": ".ply", "e57": ".e57", "npy": "", "text": ".txt"}


def bimscan_cloud(tmp_path: Path, fmt: str, header: CloudHeader) -> Path:
    """A small bimscan cloud in ``fmt`` (text: as write_text_cloud writes it)."""
    from bimscan.io import open_cloud_writer
    from bimscan.io.text import write_text_cloud

    from .conftest import make_cloud

    cloud = make_cloud(120, seed=4, columns=("xyz", "label", "intensity", "station", "rgb"))
    path = tmp_path / f"in{SOURCE_SUFFIXES[fmt]}" if fmt != "npy" else tmp_path / "in"
    if fmt == "text":
        write_text_cloud(path, cloud)
    else:
        with open_cloud_writer(path, header=header) as writer:
            writer.write(cloud)
    return path


@pytest.mark.parametrize("target_format", ["las", "laz", "ply", "e57", "npy"])
@pytest.mark.parametrize("source_format", sorted(SOURCE_SUFFIXES))
def test_every_copier_and_every_writer_give_the_labels_back(
    tmp_path: Path, header: CloudHeader, source_format: str, target_format: str,
) -> None:
    from bimscan.io import LABELLED_COPIERS

    source = bimscan_cloud(tmp_path, source_format, header)
    before = read_cloud(source)
    labels = (np.arange(len(before)) % 3).astype(np.uint8)
    target = tmp_path / ("out" + SOURCE_SUFFIXES[target_format])

    plan = plan_labelled_copy(source, target, top_class=2)
    write_labelled_copy(plan, labels, header=CloudHeader(scheme=scheme_of(3), origin=header.origin,
                                                          stations=header.stations))

    assert plan.copied == (target_format in LABELLED_COPIERS[source_format].targets)
    after = read_cloud(target)
    np.testing.assert_array_equal(after.label, labels)
    np.testing.assert_allclose(after.xyz, before.xyz, atol=2e-4)
    stored = read_cloud_header(target)
    assert stored is not None and stored.scheme == scheme_of(3)
    fields = LABELLED_COPIERS[source_format].fields(source)
    rows = sum(len(block) for block in LABELLED_COPIERS[source_format].iter_fields(source, fields))
    assert rows == (len(before) if fields else rows)


def test_bytes_other_software_adds_to_the_header_and_after_the_vlrs_and_geotiff_keys_are_kept(tmp_path: Path) -> None:
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = np.array(UTM_OFFSET), np.array([0.001] * 3)
    keys = struct.pack("<8H", 1, 1, 0, 1, 3072, 0, 1, 25832)  # one GeoTIFF key: ProjectedCSTypeGeoKey = EPSG 25832
    header.vlrs.extend([laspy.VLR("LASF_Projection", 34735, "GeoTIFF GeoKeyDirectoryTag", keys),
                        laspy.VLR("LASF_Projection", 34737, "GeoTIFF GeoAsciiParamsTag", b"ETRS89 / UTM zone 32N|\0")])
    header.extra_header_bytes = b"TerraScan header extension"
    header.extra_vlr_bytes = b"\xde\xad\xbe\xef" * 8
    las = laspy.LasData(header)
    las.X, las.Y, las.Z = np.arange(30), np.arange(30), np.arange(30)
    las.write(tmp_path / "tscan.las")

    target = copy(tmp_path / "tscan.las", tmp_path / "out.laz", np.full(30, 2, np.uint8))

    before, after = read_las_layout(tmp_path / "tscan.las"), read_las_layout(target)
    assert after.header.endswith(b"TerraScan header extension") and after.vlr_tail == before.vlr_tail
    assert kept_records(target) == kept_records(tmp_path / "tscan.las")  # the GeoTIFF keys and their ASCII params
    assert header_without_patched_fields(after.header) == header_without_patched_fields(before.header)

"""E57: real scans through the writer and back, poses and scan grid, foreign files, failures."""

from __future__ import annotations

import dataclasses
import hashlib
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.errors import InputFileError, OutputError
from bimscan.io import iter_cloud_chunks, open_cloud_writer, read_cloud, read_cloud_header
from bimscan.io.e57 import (
    COMPONENT_FIELD,
    LABEL_FIELD,
    gps_seconds,
    heading_quaternion,
    read_e57_scans,
)
from bimscan.pipeline import scan_model
from bimscan.scan.device import SCANNERS, ScanSettings
from bimscan.scan.noise import NoiseModel
from bimscan.survey.recipe import ScanRecipe
from bimscan.scan.pattern import PulsePattern
from bimscan.types import CloudHeader, Station

pye57 = pytest.importorskip("pye57")
libe57 = pytest.importorskip("pye57.libe57")

FAST = ["--preset", "exp1", "--head-speed", "60"]
STATIONS = "x,y,height,heading_deg\n2.5,2,1.7,0\n5.5,4,1.7,90\n"  # inside the 8 x 6 m box room


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def scanned(box_room_ifc: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The box room scanned from two headed stations by ``bimscan scan``, as E57 and as LAZ, noise off."""
    folder = tmp_path_factory.mktemp("e57scan")
    stations = folder / "stations.csv"
    stations.write_text(STATIONS)
    paths = {}
    for suffix in (".e57", ".laz"):
        paths[suffix] = folder / f"room{suffix}"
        assert main(["scan", str(box_room_ifc), str(paths[suffix]), *FAST, "--stations", str(stations),
                     "--no-noise", "--seed", "5"]) == 0
    return paths


def test_bimscan_scan_writes_an_e57_holding_the_same_labelled_points_as_its_laz(scanned):
    e57, laz = read_cloud(scanned[".e57"]), read_cloud(scanned[".laz"])
    assert len(e57) == len(laz) > 100_000
    assert np.abs(e57.xyz - laz.xyz).max() <= 0.5e-4 + 0.5e-4 * np.sqrt(3) + 1e-9  # both formats' 0.1 mm steps
    for column in ("label", "component", "station", "intensity", "time"):
        assert np.array_equal(getattr(e57, column), getattr(laz, column)), column
    assert set(np.unique(e57.station)) == {0, 1}
    header = read_cloud_header(scanned[".e57"])
    assert [c.name for c in header.scheme.classes] == ["Wall&Column", "Beam", "Covering", "Slab", "Others"]
    assert header.components.rows() == read_cloud_header(scanned[".laz"]).components.rows()


def test_every_station_is_one_data3d_posed_at_its_beam_origin_and_heading(scanned):
    header = read_cloud_header(scanned[".e57"])
    cloud = read_cloud(scanned[".e57"])
    scans = read_e57_scans(scanned[".e57"])
    assert [s.station_id for s in scans] == [s.id for s in header.stations] == [0, 1]
    for scan, station in zip(scans, header.stations, strict=True):
        assert scan.translation == station.position
        assert np.allclose(scan.rotation, heading_quaternion(station.heading_deg), atol=1e-15)
        assert scan.n_points == int((cloud.station == station.id).sum())
    assert np.allclose(scans[1].rotation, (np.sqrt(0.5), 0, 0, np.sqrt(0.5)))  # 90 degrees about +Z


def test_another_e57_reader_sees_the_same_world_points_and_the_scan_grid_of_each_pulse(scanned):
    # pye57's own reader (pose applied with pyquaternion) is an independent second opinion.
    header = read_cloud_header(scanned[".e57"])
    ours = read_cloud(scanned[".e57"])
    settings = ScanSettings(**{k: v for k, v in header.metadata["settings"].items()})
    pattern = PulsePattern.of(settings, SCANNERS["riegl_vz400"])
    with pye57.E57(str(scanned[".e57"])) as e57:
        assert e57.scan_count == 2
        for index, station in enumerate(header.stations):
            theirs = e57.read_scan(index, intensity=True, row_column=True, ignore_missing_fields=True)
            mine = ours.take(ours.station == station.id)
            xyz = np.stack([theirs["cartesianX"], theirs["cartesianY"], theirs["cartesianZ"]], axis=1)
            assert np.abs(xyz - mine.xyz).max() < 1e-9
            raw = e57.read_scan_raw(index, ignore_unsupported_fields=True)
            row, column = raw["rowIndex"].astype(np.int64), raw["columnIndex"].astype(np.int64)
            assert len(np.unique(column * 100_000 + row)) == len(row)  # one point per pulse: grid cells unique
            start, stop = pattern.line_pulses(0, pattern.n_lines)
            assert (row < (stop - start)[column]).all()
            pulse = start[column] + row
            # the pulse the grid names fired in the direction the point was measured (no noise)
            elevation = np.degrees(raw["sphericalElevation"])
            azimuth = np.degrees(raw["sphericalAzimuth"])
            assert np.abs(elevation - pattern.elevation_deg(pulse)).max() < 1e-3
            expected = settings.head_start_deg + pulse * pattern.head_deg_per_pulse
            assert np.abs((azimuth - expected + 180.0) % 360.0 - 180.0).max() < 1e-3
            assert np.allclose(mine.time, index * settings.duration_s() + pulse / settings.pulse_freq_hz)


def test_e57_bytes_repeat_for_the_same_seed_whatever_the_chunk_size(box_room_ifc, tmp_path):
    recipe = ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, seed=4, noise=NoiseModel())
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = scan_model(box_room_ifc, tmp_path / "a" / "cloud.e57", recipe, progress=False).path
    b = scan_model(box_room_ifc, tmp_path / "b" / "cloud.e57", recipe.with_fields(chunk_pulses=20_000),
                   progress=False).path
    assert sha(a) == sha(b)
    assert not list(tmp_path.rglob(".*tmp"))


def test_creation_date_comes_from_source_date_epoch_as_gps_time(tmp_path, header, cloud_factory, monkeypatch):
    assert gps_seconds(1483228800) == 1167264018  # 2017-01-01 UTC: GPS runs 18 leap seconds ahead
    assert gps_seconds(315964800) == 0
    cloud = cloud_factory(500, seed=1)
    for name, epoch in (("a.e57", None), ("b.e57", "1483228800")):
        if epoch is not None:
            monkeypatch.setenv("SOURCE_DATE_EPOCH", epoch)
        with open_cloud_writer(tmp_path / name, header=header) as writer:
            writer.write(cloud)
    image = libe57.ImageFile(str(tmp_path / "b.e57"), "r")
    assert image.root()["creationDateTime"]["dateTimeValue"].value() == 1167264018.0
    image.close()
    image = libe57.ImageFile(str(tmp_path / "a.e57"), "r")
    assert not image.root().isDefined("creationDateTime")
    image.close()


def test_labels_and_components_are_extension_fields_other_readers_can_find(tmp_path, header, cloud_factory):
    cloud = cloud_factory(2_000, seed=2)
    path = tmp_path / "cloud.e57"
    with open_cloud_writer(path, header=header) as writer:
        writer.write(cloud)
    image = libe57.ImageFile(str(path), "r")
    try:
        assert image.extensionsPrefix(1) == "bimscan" and image.extensionsUri(1) == "urn:bimscan:e57:1"
        prototype = libe57.StructureNode(image.root()["data3D"][0]["points"].prototype())
        assert prototype[LABEL_FIELD].maximum() == 255
        assert (prototype[COMPONENT_FIELD].minimum(), prototype[COMPONENT_FIELD].maximum()) == (-1, 2)
    finally:
        image.close()
    # the extension field is an ordinary label field for the reader
    assert np.array_equal(read_cloud(path, label_field=LABEL_FIELD).label, cloud.label)


def test_a_station_that_comes_back_gets_another_entry_and_the_point_order_is_kept(tmp_path, header, cloud_factory):
    station = np.repeat(np.array([0, 1, 0], dtype=np.uint16), 1_000)
    cloud = dataclasses.replace(cloud_factory(3_000, seed=3), station=station)
    path = tmp_path / "cloud.e57"
    with open_cloud_writer(path, header=header) as writer:
        writer.write(cloud)
    assert [(s.station_id, s.n_points) for s in read_e57_scans(path)] == [(0, 1_000), (1, 1_000), (0, 1_000)]
    back = read_cloud(path)
    assert np.array_equal(back.station, station) and np.array_equal(back.label, cloud.label)
    assert np.abs(back.xyz - cloud.xyz).max() <= 0.5e-4 * np.sqrt(3) + 1e-9


def test_points_of_a_station_the_header_does_not_pose_are_refused_and_nothing_is_left(tmp_path, header, cloud_factory):
    bad = dataclasses.replace(cloud_factory(100, seed=4), station=np.full(100, 7, np.uint16))
    with pytest.raises(OutputError, match="points of station 7 but the header has no station 7"):
        with open_cloud_writer(tmp_path / "cloud.e57", header=header) as writer:
            writer.write(bad)
    assert list(tmp_path.iterdir()) == []


def test_times_that_are_not_the_surveys_pulse_times_are_refused(tmp_path, header, cloud_factory):
    settings = ScanSettings(pulse_freq_hz=50_000.0, scan_freq_hz=240.0, head_deg_per_s=60.0)
    surveyed = CloudHeader(scheme=header.scheme, components=header.components, stations=header.stations,
                           origin=header.origin, metadata={"settings": dataclasses.asdict(settings),
                                                           "scanner": dataclasses.asdict(SCANNERS["riegl_vz400"])})
    cloud = cloud_factory(1_000, seed=5)  # random times, not multiples of the pulse period
    with pytest.raises(OutputError, match="not pulse times of the scan settings"):
        with open_cloud_writer(tmp_path / "cloud.e57", header=surveyed) as writer:
            writer.write(cloud)
    assert list(tmp_path.iterdir()) == []


def _quaternion(angle_deg: float, axis: tuple[float, float, float]) -> tuple[float, float, float, float]:
    half = np.radians(angle_deg) / 2
    unit = np.asarray(axis) / np.linalg.norm(axis)
    return (float(np.cos(half)), *(float(v) for v in np.sin(half) * unit))


def test_a_foreign_e57_from_pye57_reads_in_world_coordinates_one_station_per_scan(tmp_path):
    from pyquaternion import Quaternion

    rng = np.random.default_rng(6)
    path = tmp_path / "foreign.e57"
    poses = [(_quaternion(30.0, (0, 0, 1)), np.array([512_000.0, 5_400_000.0, 40.0])),
             (_quaternion(-75.0, (0.2, 0.1, 1.0)), np.array([512_010.0, 5_400_004.0, 41.5]))]
    written = []
    with pye57.E57(str(path), mode="w") as e57:
        for rotation, translation in poses:
            n = int(rng.integers(500, 900))
            data = {"cartesianX": rng.uniform(-20, 20, n), "cartesianY": rng.uniform(-20, 20, n),
                    "cartesianZ": rng.uniform(-2, 5, n), "intensity": rng.uniform(0.1, 0.9, n).astype(np.float32),
                    "colorRed": rng.integers(0, 256, n).astype(np.uint8),
                    "colorGreen": rng.integers(0, 256, n).astype(np.uint8),
                    "colorBlue": rng.integers(0, 256, n).astype(np.uint8)}
            e57.write_scan_raw(data, rotation=np.array(rotation), translation=translation)
            written.append(data)
    assert read_cloud_header(path) is None
    cloud = read_cloud(path)
    assert cloud.label is None and cloud.component is None and cloud.time is None
    assert np.array_equal(cloud.station, np.repeat([0, 1], [len(d["cartesianX"]) for d in written]).astype(np.uint16))
    for index, (data, (rotation, translation)) in enumerate(zip(written, poses, strict=True)):
        local = np.stack([data[k].astype(np.float32).astype(np.float64) for k in ("cartesianX", "cartesianY", "cartesianZ")], 1)
        expected = local @ Quaternion(rotation).rotation_matrix.T + translation  # pye57 stores float32
        mine = cloud.take(cloud.station == index)
        assert np.abs(mine.xyz - expected).max() < 1e-6
        # pye57 writes float intensities with the scan's min..max as intensityLimits: they span 0..65535
        assert mine.intensity.min() == 0 and mine.intensity.max() == 65535
        order = np.argsort(data["intensity"], kind="stable")
        assert (np.diff(mine.intensity[order].astype(np.int64)) >= 0).all()
    with pytest.raises(InputFileError, match="no point field 'classification' to read labels from; it has"):
        read_cloud(path, label_field="classification")


def test_a_spherical_scan_with_invalid_points_and_a_foreign_label_field(tmp_path):
    path = tmp_path / "spherical.e57"
    n = 1_000
    rng = np.random.default_rng(7)
    data = {"sphericalRange": rng.uniform(1, 30, n), "sphericalAzimuth": rng.uniform(-np.pi, np.pi, n),
            "sphericalElevation": rng.uniform(-0.7, 1.0, n),
            "sphericalInvalidState": np.where(np.arange(n) % 10 == 0, 2, 0).astype(np.int8),
            "other:classification": rng.integers(0, 6, n).astype(np.float64)}
    image = libe57.ImageFile(str(path), "w")
    image.extensionsAdd("", libe57.E57_V1_0_URI)
    image.extensionsAdd("other", "http://example.org/other-tool/1")
    root = image.root()
    root.set("formatName", libe57.StringNode(image, "ASTM E57 3D Imaging Data File"))
    root.set("guid", libe57.StringNode(image, "{test}"))
    root.set("versionMajor", libe57.IntegerNode(image, 1))
    root.set("versionMinor", libe57.IntegerNode(image, 0))
    root.set("data3D", libe57.VectorNode(image, True))
    scan = libe57.StructureNode(image)
    root["data3D"].append(scan)
    scan.set("guid", libe57.StringNode(image, "{scan}"))
    prototype = libe57.StructureNode(image)
    for name in ("sphericalRange", "sphericalAzimuth", "sphericalElevation", "other:classification"):
        prototype.set(name, libe57.FloatNode(image, 0.0, libe57.E57_DOUBLE))
    prototype.set("sphericalInvalidState", libe57.IntegerNode(image, 0, 0, 2))
    points = libe57.CompressedVectorNode(image, prototype, libe57.VectorNode(image, True))
    scan.set("points", points)
    buffers = libe57.VectorSourceDestBuffer()
    for name, values in data.items():
        buffers.append(libe57.SourceDestBuffer(image, name, values, n, True, True))
    writer = points.writer(buffers)
    writer.write(n)
    writer.close()
    image.close()
    cloud = read_cloud(path, label_field="other:classification")
    valid = data["sphericalInvalidState"] == 0
    r, a, e = (data[k][valid] for k in ("sphericalRange", "sphericalAzimuth", "sphericalElevation"))
    expected = np.stack([r * np.cos(e) * np.cos(a), r * np.cos(e) * np.sin(a), r * np.sin(e)], 1)
    assert len(cloud) == int(valid.sum()) == 900
    assert np.abs(cloud.xyz - expected).max() < 1e-12
    assert np.array_equal(cloud.label, data["other:classification"][valid].astype(np.uint8))
    assert read_cloud(path).label is None


def test_files_that_are_not_e57_or_are_damaged_are_one_line_input_errors(tmp_path, header, cloud_factory, capfd):
    (tmp_path / "text.e57").write_text("x y z\n1 2 3\n")
    with pytest.raises(InputFileError, match="not an E57 file"):
        read_cloud(tmp_path / "text.e57")
    good = tmp_path / "good.e57"
    with open_cloud_writer(good, header=header) as writer:
        writer.write(cloud_factory(20_000, seed=8))
    damaged = tmp_path / "damaged.e57"
    data = bytearray(good.read_bytes())
    data[5_000:5_010] = b"\xff" * 10  # page checksums no longer match
    damaged.write_bytes(bytes(data))
    capfd.readouterr()
    with pytest.raises(InputFileError, match=r"damaged.e57: the E57 point data is damaged \(checksum mismatch") as caught:
        list(iter_cloud_chunks(damaged))
    assert "\n" not in str(caught.value)  # libE57Format's debug report is not part of the message
    assert "e57 exception" not in capfd.readouterr().err
    truncated = tmp_path / "truncated.e57"
    truncated.write_bytes(good.read_bytes()[:3_000])
    with pytest.raises(InputFileError, match="not a readable E57 file"):
        read_cloud(truncated)


@pytest.mark.parametrize("free, message", [(None, "could not write .*libE57Format"), (0, "disk full while writing")])
def test_a_write_failure_inside_libe57format_is_an_output_error_and_leaves_nothing(tmp_path, free, message):
    # A file-size limit makes the kernel fail libE57Format's writes (EFBIG); with no space
    # reported free, the writer names a full disk.
    patch = "" if free is None else f"e57._free_bytes = lambda folder: {free}"
    script = textwrap.dedent(
        f"""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (2_000_000, 2_000_000))
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from conftest import ORIGIN, make_cloud
        from bimscan.errors import OutputError
        from bimscan.io import e57, open_cloud_writer
        from bimscan.types import CloudHeader, LabelScheme
        {patch}
        header = CloudHeader(scheme=LabelScheme("s", (), (), "x"), origin=ORIGIN)
        try:
            with open_cloud_writer({str(tmp_path / 'big.e57')!r}, header=header) as writer:
                writer.write(make_cloud(200_000, seed=1))
        except OutputError as exc:
            print("OutputError:", exc)
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert "OutputError:" in done.stdout, done.stderr
    assert len(done.stdout.strip().splitlines()) == 1
    assert re.search(message, done.stdout), done.stdout
    assert "e57 exception" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_dataset_spec_can_ask_for_e57_units(tmp_path):
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import load_spec

    spec = tmp_path / "spec.toml"
    spec.write_text('formats = ["e57"]\n[[scenes]]\nname = "room"\ngenerate = { seed = 1, storeys = 1 }\n'
                    '[[configs]]\nname = "fast"\npreset = "exp1"\nhead_deg_per_s = 360.0\n')
    report = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    assert report.ok and report.built == 1
    unit = tmp_path / "out" / "units" / "room__fast"
    cloud = read_cloud(unit / "cloud.e57")
    scans = read_e57_scans(unit / "cloud.e57")
    header = read_cloud_header(unit / "cloud.e57")
    assert len(cloud) > 0 and sum(s.n_points for s in scans) == len(cloud)
    assert [s.station_id for s in scans] == [s.id for s in header.stations]
    assert [s.translation for s in scans] == [s.position for s in header.stations]


def test_learning_reads_an_e57_as_a_scene(tmp_path, header, cloud_factory):
    from bimscan.learn.data import iter_scene_chunks, list_scenes

    cloud = cloud_factory(4_000, seed=9)
    path = tmp_path / "real.e57"
    with open_cloud_writer(path, header=header) as writer:
        writer.write(cloud)
    (source,) = list_scenes([path])
    assert source.kind == "e57"
    chunks = list(iter_scene_chunks(source, class_names=[c.name for c in header.scheme.classes]))
    assert np.array_equal(np.concatenate([c.label for c in chunks]), cloud.label)


def test_station_frames_keep_coordinates_far_from_the_file_origin_to_a_tenth_of_a_millimetre(
        tmp_path, header, cloud_factory):
    # the file origin is 5 000 km away: coordinates are stored relative to the station, not the origin
    x, y, z = header.origin
    far = CloudHeader(scheme=header.scheme, stations=(Station(0, (x + 3.0, y - 4.0, z + 1.7), heading_deg=33.0),),
                      origin=(0.0, 0.0, 0.0))
    cloud = cloud_factory(1_000, seed=10, columns=("xyz", "station"))
    cloud = dataclasses.replace(cloud, station=np.zeros(1_000, np.uint16))
    with open_cloud_writer(tmp_path / "far.e57", header=far) as writer:
        writer.write(cloud)
    assert np.abs(read_cloud(tmp_path / "far.e57").xyz - cloud.xyz).max() <= 0.5e-4 * np.sqrt(3) + 1e-9
    posed_at_origin = CloudHeader(scheme=header.scheme, origin=(0.0, 0.0, 0.0))  # no stations: 5 000 km out
    with pytest.raises(OutputError, match="do not fit E57's 0.1 mm integer steps"):
        with open_cloud_writer(tmp_path / "origin.e57", header=posed_at_origin) as writer:
            writer.write(dataclasses.replace(cloud, station=None))
    assert not (tmp_path / "origin.e57").exists()


def test_return_numbers_a_las_file_left_unset_are_written_as_first_returns(tmp_path, header, cloud_factory):
    # laspy leaves return numbers 0 (LAS 1.4 counts from 1); E57's returnIndex 0..254 is the number - 1, which
    # libE57Format refused after the whole job as "value out of min/max bounds", blamed on the disk
    cloud = cloud_factory(2_000, seed=5, columns=("xyz", "label", "station", "intensity", "return_number",
                                                  "number_of_returns"))
    unset = dataclasses.replace(cloud, return_number=np.zeros(len(cloud), np.uint8),
                                number_of_returns=np.where(np.arange(len(cloud)) % 2, 0, 2).astype(np.uint8))
    path = tmp_path / "foreign.e57"
    with open_cloud_writer(path, header=header) as writer:
        writer.write(unset)
    back = read_cloud(path)
    assert set(np.unique(back.return_number)) == {1}
    np.testing.assert_array_equal(back.number_of_returns, np.maximum(unset.number_of_returns, 1))
    np.testing.assert_array_equal(back.label, cloud.label)

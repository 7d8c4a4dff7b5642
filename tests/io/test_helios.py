"""HELIOS++ scene export: one objloader part per component file, classes in the materials."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bimscan.io import export_obj
from bimscan.io.helios import helios_scene_xml
from bimscan.types import BimScene, SceneMesh


@pytest.fixture
def scene(scheme, components) -> BimScene:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3]], dtype=np.int32)
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=np.array([0, 2, 2], dtype=np.int32))
    return BimScene(source="house & garden.ifc", file_sha256="", schema="IFC2X3", mesh=mesh, components=components,
                    scheme=scheme, storeys=(), spaces=(), failed=(), unmapped_classes={})


def test_the_scene_xml_has_one_objloader_part_per_component_file(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj", helios=True)
    root = ET.parse(export.helios_scene).getroot()
    assert root.tag == "document"
    (scene_element,) = root.findall("scene")
    assert scene_element.get("name") == "house & garden.ifc"
    parts = scene_element.findall("part")
    assert sorted(int(p.get("id")) for p in parts) == sorted(export.component_files) == [0, 2]
    for part in parts:
        (loader,) = part.findall("filter")
        assert loader.get("type") == "objloader"
        params = {p.get("key"): p.get("value") for p in loader.findall("param")}
        assert params["up"] == "z"
        # relative to the export folder (HELIOS++ --assets <folder>)
        assert (export.out_dir / params["filepath"]).resolve() == export.component_files[int(part.get("id"))].resolve()


def test_materials_carry_the_class_ids_as_helios_classification(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj")
    text = export.materials.read_text()
    for cls in scene.scheme.classes:
        assert f"newmtl class_{cls.id}\n" in text and f"helios_classification {cls.id}\n" in text
    assert "mtllib ../classes.mtl" in export.component_files[0].read_text()


def test_scene_xml_escapes_names_and_paths():
    document = helios_scene_xml([(3, 'odd "dir"/c3.obj')], scene_id="s", name="<model>")
    scene = ET.fromstring(document).find("scene")
    assert scene.get("name") == "<model>"
    assert scene.find("part/filter/param").get("value") == 'odd "dir"/c3.obj'


# -- the survey ---------------------------------------------------------------------------------

import dataclasses  # noqa: E402
import math  # noqa: E402

from bimscan.cli.main import main  # noqa: E402
from bimscan.errors import ConfigError  # noqa: E402
from bimscan.io.helios import HELIOS_SCANNERS, helios_near_limit_m, helios_survey_xml  # noqa: E402
from bimscan.scan.device import SCANNERS, ScanSettings  # noqa: E402
from bimscan.types import Station  # noqa: E402

VZ400 = SCANNERS["riegl_vz400"]
SETTINGS = ScanSettings(pulse_freq_hz=100_000.0, scan_freq_hz=100.0, head_deg_per_s=20.0, head_start_deg=10.0,
                        head_stop_deg=350.0, elevation_min_deg=-30.0, elevation_max_deg=55.0)
STATIONS = (Station(0, (512_301.25, 5_403_102.5, 42.7), floor_z=41.0, storey="EG", room="Küche & Bad"),
            Station(4, (512_309.0, 5_403_101.0, 45.9), heading_deg=37.5, room="hall -- north"))


def parse_survey(document: bytes) -> ET.Element:
    return ET.fromstring(document, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))


def helios_rotate(axis: tuple[float, float, float], angle: float, u: np.ndarray) -> np.ndarray:
    """HELIOS++'s Rotation(axis, angle).applyTo(u), transcribed from its maths/Rotation.cpp."""
    half = -0.5 * angle
    q0, (q1, q2, q3) = math.cos(half), (math.sin(half) * np.asarray(axis, dtype=float))
    x, y, z = u
    s = q1 * x + q2 * y + q3 * z
    return np.array([2 * (q0 * (x * q0 - (q2 * z - q3 * y)) + s * q1) - x,
                     2 * (q0 * (y * q0 - (q3 * x - q1 * z)) + s * q2) - y,
                     2 * (q0 * (z * q0 - (q1 * y - q2 * x)) + s * q3) - z])


def test_the_survey_is_well_formed_xml_naming_every_station_and_setting():
    root = parse_survey(helios_survey_xml(STATIONS, SETTINGS, VZ400, scene_id="house", name="house"))
    (survey,) = root.findall("survey")
    assert survey.get("scene") == "helios/scene.xml#house"
    assert survey.get("platform") == "data/platforms.xml#tripod"
    assert survey.get("scanner") == "data/scanners_tls.xml#riegl_vz400"
    legs = survey.findall("leg")
    comments = [c.text for c in survey if c.tag is ET.Comment]
    assert len(legs) == len(comments) == len(STATIONS)
    for leg, comment, station in zip(legs, comments, STATIONS, strict=True):
        assert f"bimscan station {station.id} (room {station.room.replace('--', '- -')}" in comment
        platform = leg.find("platformSettings").attrib
        assert platform["onGround"] == "false"
        assert (float(platform["x"]), float(platform["y"])) == station.position[:2]
        assert float(platform["z"]) + 1.5 + 0.2 == pytest.approx(station.position[2], abs=1e-12)
        settings = leg.find("scannerSettings").attrib
        assert settings["active"] == "true" and settings["pulseFreq_hz"] == "100000"
        assert float(settings["scanFreq_hz"]) == SETTINGS.scan_freq_hz
        assert float(settings["headRotatePerSec_deg"]) == SETTINGS.head_deg_per_s
        assert (float(settings["verticalAngleMin_deg"]), float(settings["verticalAngleMax_deg"])) == (-30.0, 55.0)
        assert float(settings["scanAngle_deg"]) >= 55.0
        start, stop = float(settings["headRotateStart_deg"]), float(settings["headRotateStop_deg"])
        assert stop - start == SETTINGS.head_stop_deg - SETTINGS.head_start_deg
        assert start == SETTINGS.head_start_deg + station.heading_deg - 90.0


def test_helios_fires_the_first_pulse_of_each_leg_where_bimscan_does():
    # Follow HELIOS++'s own rotation conventions: head about +Z by its angle, mirror about +X by
    # the elevation, applied to its forward direction +Y (ScanningDevice::calcAbsoluteBeamAttitude).
    survey = parse_survey(helios_survey_xml(STATIONS, SETTINGS, VZ400, scene_id="s", name="s")).find("survey")
    for leg, station in zip(survey.findall("leg"), STATIONS, strict=True):
        head = math.radians(float(leg.find("scannerSettings").get("headRotateStart_deg")))
        for elevation_deg in (-30.0, 0.0, 40.0):
            elevation = math.radians(elevation_deg)
            helios = helios_rotate((0, 0, 1), head, helios_rotate((1, 0, 0), elevation, np.array([0.0, 1.0, 0.0])))
            azimuth = math.radians(SETTINGS.head_start_deg + station.heading_deg)  # bimscan's generate_rays
            bimscan = np.array([math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth),
                                math.sin(elevation)])
            assert np.allclose(helios, bimscan, atol=1e-12)


def test_helios_near_limit_is_1_95_m_for_its_vz400_which_hides_a_low_ceiling_above_27_degrees():
    near = helios_near_limit_m(HELIOS_SCANNERS["riegl_vz400"])
    assert near == pytest.approx(1.5 + 0.299792458 * 1.5)  # the pulse peaks 1.5 ns after it starts
    assert round(near, 2) == 1.95
    # 2.6 m room, beam at 1.7 m: the ceiling is 0.9 m above it, closer than `near` above this elevation
    assert math.degrees(math.asin(0.9 / near)) == pytest.approx(27.5, abs=0.1)


@pytest.mark.parametrize("change, message", [
    ({"name": "faro_focus"}, "knows HELIOS\\+\\+'s definition of riegl_vz400 only, not of scanner 'faro_focus'"),
    ({"mirror_sweep_deg": 300.0}, "keep mirror_sweep_deg = 240"),
])
def test_scanners_helios_has_no_definition_of_are_refused(change, message):
    with pytest.raises(ConfigError, match=message):
        helios_survey_xml(STATIONS, SETTINGS, dataclasses.replace(VZ400, **change), scene_id="s", name="s")


def test_a_fractional_pulse_rate_is_refused_because_helios_reads_an_integer():
    with pytest.raises(ConfigError, match="integer pulse rate"):
        helios_survey_xml(STATIONS, dataclasses.replace(SETTINGS, pulse_freq_hz=99_999.5), VZ400, scene_id="s", name="s")


def test_matching_min_range_is_a_scanner_file_setting(tmp_path):
    from bimscan.scan.device import load_scanner

    text = (Path(__file__).parents[2] / "src/bimscan/scan/scanners/riegl_vz400.toml").read_text()
    matched = tmp_path / "vz400_as_helios.toml"
    matched.write_text(text.replace("min_range_m = 1.5", "min_range_m = 1.95"))
    scanner = load_scanner(str(matched))
    assert scanner.min_range_m == 1.95 and scanner.name == "riegl_vz400"
    document = helios_survey_xml(STATIONS, SETTINGS, scanner, scene_id="s", name="s").decode()
    assert "bimscan: min_range_m = 1.95 m" in document


def test_export_obj_with_helios_writes_the_survey_of_the_scan_it_would_make(box_room_ifc, tmp_path, capsys):
    stations = tmp_path / "stations.csv"
    stations.write_text("x,y,height,heading_deg\n2,2,1.7,0\n6,4,1.7,90\n")
    out = tmp_path / "my export"  # the printed command quotes a folder with a space for the shell
    assert main(["export-obj", str(box_room_ifc), str(out), "--helios", "--stations", str(stations),
                 "--preset", "exp1", "--head-speed", "60"]) == 0
    report = capsys.readouterr().out
    assert f"cd '{out}' && helios++ helios/survey.xml --assets ." in report
    scene = ET.parse(out / "helios" / "scene.xml").getroot().find("scene")
    survey = parse_survey((out / "helios" / "survey.xml").read_bytes()).find("survey")
    assert survey.get("scene") == f"helios/scene.xml#{scene.get('id')}"
    legs = survey.findall("leg")
    assert [(float(leg.find("platformSettings").get("x")), float(leg.find("platformSettings").get("y")))
            for leg in legs] == [(2.0, 2.0), (6.0, 4.0)]
    assert [float(leg.find("platformSettings").get("z")) for leg in legs] == pytest.approx([0.0, 0.0], abs=1e-6)  # floor
    assert {leg.find("scannerSettings").get("pulseFreq_hz") for leg in legs} == {"50000"}
    assert {leg.find("scannerSettings").get("headRotatePerSec_deg") for leg in legs} == {"60.0"}


def test_survey_options_without_helios_are_a_usage_error(box_room_ifc, tmp_path, capsys):
    assert main(["export-obj", str(box_room_ifc), str(tmp_path / "x"), "--stations", "auto"]) != 0
    assert "--stations describe the HELIOS++ survey; add --helios" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()

"""Stations: planning per storey and room, station files, and the checks on bad stations."""

from __future__ import annotations

import pytest

from bimscan.errors import InputFileError, StationError
from bimscan.pipeline import load_scene
from bimscan.scan.device import SCANNERS
from bimscan.scan.probe import Prober
from bimscan.survey.stations import check_station, plan_stations, read_stations
from bimscan.types import Station

VZ400 = SCANNERS["riegl_vz400"]


@pytest.fixture(scope="module")
def box(box_room_ifc):
    scene = load_scene(box_room_ifc)
    return scene, Prober(scene.mesh)


def test_a_single_room_gets_one_station_on_the_floor_at_instrument_height(box):
    scene, scanner = box
    stations, report = plan_stations(scene, scanner, VZ400)
    assert len(stations) == 1
    x, y, z = stations[0].position
    assert 0.4 <= x <= 7.6 and 0.4 <= y <= 5.6
    assert z == pytest.approx(VZ400.instrument_height_m, abs=1e-3)
    assert stations[0].floor_z == pytest.approx(0.0, abs=1e-3)


def test_planned_stations_on_a_real_house_reach_every_room_with_a_floor(shared_ifc):
    scene = load_scene(shared_ifc("duplex.ifc"))
    scanner = Prober(scene.mesh)
    stations, report = plan_stations(scene, scanner, VZ400)
    rooms = {s.name for s in scene.spaces}
    with_station = {s.room for s in stations if s.room}
    # every room is either scanned from inside or reported (utility closets are too small for a tripod)
    assert with_station | set(report.rooms_without_station) >= rooms - {"R301 Roof"}
    assert len(with_station) >= 15
    # the roof has a space of its own (R301 Roof): a tripod on the flat roof scans it from there
    assert set(report.stations_per_storey) == {"Level 1", "Level 2", "Roof"}
    for station in stations:
        check_station(station, scene, scanner)  # none inside a solid or outside


def test_a_station_inside_a_wall_is_refused_naming_the_wall(box):
    scene, scanner = box
    inside_wall = Station(id=3, position=(8.1, 3.0, 1.7))  # the east wall spans x = 8.0 .. 8.25
    with pytest.raises(StationError, match="station 3 .* inside a solid \\(IfcWall"):
        check_station(inside_wall, scene, scanner)


def test_a_station_outside_the_building_is_refused(box):
    scene, scanner = box
    with pytest.raises(StationError, match="outside the building"):
        check_station(Station(id=0, position=(40.0, 40.0, 1.7)), scene, scanner)


def test_a_station_file_with_absolute_and_floor_relative_rows(box, tmp_path):
    scene, scanner = box
    path = tmp_path / "stations.csv"
    path.write_text("# tripods\nx,y,z,height,heading_deg\n2,2,1.8,,0\n6,4,,1.7,90\n")
    stations = read_stations(path, scene, scanner, VZ400)
    assert [s.position for s in stations] == [(2.0, 2.0, 1.8), (6.0, 4.0, pytest.approx(1.7, abs=1e-4))]
    assert stations[1].heading_deg == 90.0 and stations[1].floor_z == pytest.approx(0.0, abs=1e-4)


def test_stations_without_heights_stand_on_a_standard_tripod(box, tmp_path):
    scene, scanner = box
    path = tmp_path / "xy.csv"
    path.write_text("x,y\n3,3\n")
    (station,) = read_stations(path, scene, scanner, VZ400)
    assert station.position[2] == pytest.approx(VZ400.instrument_height_m, abs=1e-4)


def test_whitespace_separated_station_files_are_read(box, tmp_path):
    scene, scanner = box
    path = tmp_path / "stations.txt"
    path.write_text("x y z\n3 3 1.7\n5 3 1.7\n")
    assert len(read_stations(path, scene, scanner, VZ400)) == 2


@pytest.mark.parametrize("text, message", [
    ("a,b,c\n1,2,3\n", "must name x and y"),
    ("x,y,z\n1,2\n", "has 2 values for 3 columns"),
    ("x,y,z\n1,two,3\n", "must be numbers"),
    ("x,y,height,storey\n2,2,1.7,Attic\n", "unknown storey 'Attic'"),
    ("x,y,z,storey\n2,2,1.7,Roof 99\n", r"station 1: unknown storey 'Roof 99'; use one of L0$"),  # z given too
    ("x,y,z\n2,2,1.7\n5,3,1.7\n2,2,1.7\n", r"stations 1 and 3 stand at the same spot \(2, 2, 1.7\)"),
    ("x,y,z,heading_deg\n2,2,1.7,0\n2.005,2,1.7,90\n", "stations 1 and 2 stand at the same spot"),  # a full turn
    ("x,y,z\n8.1,3,1.7\n", "inside a solid"),
    ("x,y,height\n50,50,1.7\n", "no floor under it"),
    ("# nothing\n", "no stations"),
])
def test_bad_station_files_give_clear_errors(box, tmp_path, text, message):
    scene, scanner = box
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(StationError, match=message):
        read_stations(path, scene, scanner, VZ400)


def test_a_missing_station_file_is_an_input_error(box, tmp_path):
    scene, scanner = box
    with pytest.raises(InputFileError):
        read_stations(tmp_path / "none.csv", scene, scanner, VZ400)


def test_a_model_with_no_room_for_a_tripod_is_refused(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(0, 0, -0.3), size=(1.0, 1.0, 0.3))  # a 1 m table of floor, no roof
    scene = load_scene(model.write(tmp_path / "tiny.ifc"))
    scanner = Prober(scene.mesh)
    with pytest.raises(StationError, match="no place for a station"):
        plan_stations(scene, scanner, VZ400)


@pytest.mark.parametrize("content, message", [
    (b"x,y,height\n", "no stations in the file"),
    (b"x,y,z\n4,3,1.7\n".replace(b"4", b"\xff\xfe"), "not a UTF-8 text file"),
    (b"x,y,z,heading_deg\n4,3,1.7,nan\n", "not a finite number"),
    (b"x,y,z\ninf,3,1.7\n", "not a finite number"),
    (b"x,y,z\n4,3,-5\n", "nothing under it to stand on"),  # 5 m under the floor slab
    (b"x,y,z\n4,3,0.0\n", "closer than a scanner head allows"),  # on the floor slab's top face
    (b"x,y,z\n4,3,0.05\n", "closer than a scanner head allows"),
])
def test_nonsense_station_files_are_refused_with_one_line(box, tmp_path, content, message):
    scene, scanner = box
    path = tmp_path / "stations.csv"
    path.write_bytes(content)
    with pytest.raises(StationError, match=message) as caught:
        read_stations(path, scene, scanner, VZ400)
    assert "\n" not in str(caught.value)


def test_with_a_partial_head_rotation_two_headings_at_one_spot_are_two_stations(box, tmp_path):
    scene, scanner = box
    path = tmp_path / "halves.csv"
    path.write_text("x,y,z,heading_deg\n2,2,1.7,0\n2,2,1.7,180\n")
    assert len(read_stations(path, scene, scanner, VZ400, head_span_deg=180.0)) == 2
    path.write_text("x,y,z,heading_deg\n2,2,1.7,0\n2,2,1.7,360\n")
    with pytest.raises(StationError, match="same spot"):
        read_stations(path, scene, scanner, VZ400, head_span_deg=180.0)

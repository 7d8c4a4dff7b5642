"""The station planner on models as real exports have them: whatever it plans, the checks accept.

Tiny models built in code cover what real IFC files do: no spaces, a storey without its floor
slab, a basement below zero, a pitched roof only, split levels, no storeys, nothing to stand on;
the generated styles and the shared models are the larger cases.
"""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.errors import StationError
from bimscan.pipeline import load_scene
from bimscan.scan.device import SCANNERS
from bimscan.scan.probe import Prober
from bimscan.survey.stations import check_station, plan_stations

VZ400 = SCANNERS["riegl_vz400"]
W = 0.25  # walls
S = 0.3  # slabs


def _walls(model, *, z0: float, height: float, size=(10.0, 8.0), storey=None) -> None:
    sx, sy = size
    for name, origin, extent in (("south", (-W, -W, z0), (sx + 2 * W, W, height)),
                                 ("north", (-W, sy, z0), (sx + 2 * W, W, height)),
                                 ("west", (-W, 0.0, z0), (W, sy, height)),
                                 ("east", (sx, 0.0, z0), (W, sy, height))):
        model.add_box("IfcWall", origin=origin, size=extent, name=f"{name} {z0:g}", storey=storey)


def _slab(model, *, top: float, size=(10.0, 8.0), x0: float = 0.0, storey=None, name: str = "slab", contain=True):
    sx, sy = size
    return model.add_box("IfcSlab", origin=(x0 - W, -W, top - S), size=(sx + 2 * W, sy + 2 * W, S),
                         predefined_type="FLOOR", name=name, storey=storey, contain=contain)


def _space(model, name: str, *, z0: float, height: float, size=(10.0, 8.0), storey=None):
    return model.add_box("IfcSpace", origin=(0.0, 0.0, z0), size=(*size, height), name=name, storey=storey)


def plan(path):
    scene = load_scene(path)
    prober = Prober(scene.mesh)
    stations, report = plan_stations(scene, prober, VZ400)
    for station in stations:  # the property: whatever the planner emits, the station check accepts
        check_station(station, scene, Prober(scene.mesh))
    return scene, stations, report


def test_a_model_without_spaces_gets_stations_on_every_storey(tiny_model, tmp_path):
    model = tiny_model("IFC2X3")
    upper = model.add_storey("L1", 3.3)
    _slab(model, top=0.0)
    _walls(model, z0=0.0, height=3.0)
    _slab(model, top=3.3, storey=upper, name="floor L1")
    _walls(model, z0=3.3, height=3.0, storey=upper)
    _slab(model, top=6.6, storey=upper, name="roof")
    _, stations, _ = plan(model.write(tmp_path / "nospaces.ifc"))
    floors = sorted({round(s.floor_z, 2) for s in stations})
    assert floors == [0.0, 3.3]
    assert {s.storey for s in stations} == {"L0", "L1"}


def test_a_storey_without_its_floor_slab_stands_on_its_rooms_floors(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    upper = model.add_storey("L1", 3.3)
    _walls(model, z0=0.0, height=3.0)  # no floor slab at 0 nor at 3.3: the export left them out
    _space(model, "ground room", z0=0.0, height=3.0)
    _walls(model, z0=3.3, height=3.0, storey=upper)
    _space(model, "upper room", z0=3.3, height=3.0, storey=upper)
    _slab(model, top=3.3 - 0.01, storey=upper, name="ceiling", size=(4.0, 8.0))  # a slab under part of the upper room
    _slab(model, top=6.6, storey=upper, name="roof")
    scene, stations, report = plan(model.write(tmp_path / "noslab.ifc"))
    by_room = {room: [s for s in stations if s.room == room] for room in ("ground room", "upper room")}
    assert all(by_room.values()) and not report.rooms_without_station
    assert all(s.floor_z == pytest.approx(0.0, abs=1e-6) for s in by_room["ground room"])
    assert all(s.floor_z == pytest.approx(3.3, abs=0.02) for s in by_room["upper room"])
    # the check knows the room's floor: the same place given without it has nothing to stand on
    ground = by_room["ground room"][0]
    with pytest.raises(StationError, match="nothing under it"):
        check_station(type(ground)(id=9, position=ground.position), scene, Prober(scene.mesh))


def test_a_basement_below_zero_gets_its_own_stations(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    basement = model.add_storey("B1", -3.0)
    _slab(model, top=-3.0, storey=basement, name="basement floor")
    _walls(model, z0=-3.0, height=2.95, storey=basement)
    _slab(model, top=0.0, name="ground floor")
    _walls(model, z0=0.0, height=3.0)
    _slab(model, top=3.3, name="roof")
    _, stations, _ = plan(model.write(tmp_path / "basement.ifc"))
    assert sorted({round(s.floor_z, 2) for s in stations}) == [-3.0, 0.0]
    assert {s.storey for s in stations if s.floor_z < -1} == {"B1"}


def test_a_pitched_roof_is_no_place_for_a_tripod(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    _slab(model, top=0.0)
    _walls(model, z0=0.0, height=2.6)
    for x, tilt in ((-W, -30.0), (5.0, 30.0)):  # two roof planes rising to a ridge at x = 5
        origin = (x, -W, 2.6) if tilt < 0 else (5.0, -W, 2.6 + 5.25 * np.tan(np.radians(30)))
        model.add_box("IfcSlab", origin=origin, size=(6.1, 8.5, 0.2), predefined_type="ROOF", tilt_deg=tilt)
    scene, stations, _ = plan(model.write(tmp_path / "pitched.ifc"))
    assert scene.mesh.bounds()[1][2] > 4.5  # the roof rises over the room
    assert stations and all(s.floor_z == pytest.approx(0.0, abs=1e-6) for s in stations)


def test_split_levels_get_a_station_each(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    _slab(model, top=0.0, size=(6.0, 8.0), name="low half")
    _slab(model, top=1.5, size=(6.0, 8.0), x0=6.25, name="raised half")
    _walls(model, z0=0.0, height=4.5, size=(12.5, 8.0))
    model.add_box("IfcSlab", origin=(-W, -W, 4.5), size=(13.0, 8.5, S), predefined_type="ROOF", name="roof")
    _, stations, _ = plan(model.write(tmp_path / "split.ifc"))
    assert sorted({round(s.floor_z, 2) for s in stations}) == [0.0, 1.5]


def test_elements_in_no_storey_still_get_stations(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    _slab(model, top=0.0, contain=False)
    for name, origin, extent in (("s", (-W, -W, 0.0), (10.5, W, 3.0)), ("n", (-W, 8.0, 0.0), (10.5, W, 3.0)),
                                 ("w", (-W, 0.0, 0.0), (W, 8.0, 3.0)), ("e", (10.0, 0.0, 0.0), (W, 8.0, 3.0))):
        model.add_box("IfcWall", origin=origin, size=extent, name=name, contain=False)
    model.add_box("IfcSlab", origin=(-W, -W, 3.0), size=(10.5, 8.5, S), predefined_type="ROOF", contain=False)
    _, stations, _ = plan(model.write(tmp_path / "nostorey.ifc"))
    assert stations and all(s.floor_z == pytest.approx(0.0, abs=1e-6) for s in stations)


def test_a_model_where_nothing_can_hold_a_tripod_is_one_line_naming_the_way_out(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    _walls(model, z0=0.0, height=3.0)  # walls only: no floor, no room
    scene = load_scene(model.write(tmp_path / "walls.ifc"))
    with pytest.raises(StationError, match="--stations FILE") as caught:
        plan_stations(scene, Prober(scene.mesh), VZ400)
    assert "\n" not in str(caught.value)


def test_a_room_too_small_for_a_tripod_is_reported_by_name(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    _slab(model, top=0.0)
    _walls(model, z0=0.0, height=3.0)
    _space(model, "hall", z0=0.0, height=3.0, size=(10.0, 7.2))
    model.add_box("IfcWall", origin=(0.0, 7.2, 0.0), size=(10.0, 0.1, 3.0), name="cupboard wall")
    _space(model, "cupboard", z0=0.0, height=3.0, size=(10.0, 0.7))  # 0.5 m deep behind the wall: no tripod fits
    model.file.by_type("IfcSpace")[-1].ObjectPlacement.RelativePlacement.Location.Coordinates = (0.0, 7.3, 0.0)
    _slab(model, top=3.3, name="roof")
    _, stations, report = plan(model.write(tmp_path / "cupboard.ifc"))
    assert report.rooms_without_station == ("cupboard",)
    assert {s.room for s in stations} == {"hall"}


@pytest.mark.slow
@pytest.mark.parametrize("style", ["office", "residential", "site"])
def test_generated_buildings_of_every_style_get_a_station_in_every_room_with_a_floor(style, tmp_path):
    from bimscan.ifc.generate import make_building

    built = make_building(tmp_path / f"{style}.ifc", seed=4, storeys=2, style=style)
    scene, stations, report = plan(built.path if hasattr(built, "path") else built)
    rooms = {s.name for s in scene.spaces}
    with_station = {s.room for s in stations if s.room}
    assert with_station | set(report.rooms_without_station) == rooms
    assert len(report.rooms_without_station) <= 0.1 * len(rooms)
    assert len({s.storey for s in stations}) == 2


@pytest.mark.parametrize("name", ["duplex.ifc", "AC20-FZK-Haus.ifc", "IfcOpenHouse_IFC4.ifc", "example.ifc"])
def test_every_shared_model_gets_stations_the_checks_accept(shared_ifc, name):
    _, stations, _ = plan(shared_ifc(name))
    assert stations

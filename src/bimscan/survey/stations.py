"""Scan stations: read from a file, planned automatically, and checked against the scene.

Stations stand on the floor: the beam origin is ``tripod_height + beam_origin_height`` above it.

Station files are CSV (comma or whitespace separated) with a header naming the columns:
``x, y`` (metres) and either ``z`` (absolute height of the beam origin) or ``height`` (beam
origin above the floor below; without z and height the scanner's tripod + beam offset), with
``storey`` naming the storey of floor-relative stations when the building has more than one;
``heading_deg`` is optional. With both ``z`` and ``height`` the floor is ``z - height`` (the file
``format_stations`` writes keeps it so). Lines starting with ``#`` are comments.

``plan_stations`` places stations on the floors the geometry has (``survey.spots``: level
surfaces a tripod can stand on, with headroom and a clear circle), level by level (floor heights
more than ``LEVEL_GAP_M`` apart): one station in every room (IfcSpace) that has a tripod spot,
then a greedy visibility cover so that every spot of the level is seen from a station within
``max_spacing_m``. Every station it returns passes ``check_station``. Rooms without a tripod
spot are reported; a model without any is a ``StationError``.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError, StationError, number
from bimscan.scan.device import ScannerModel
from bimscan.scan.probe import Prober, sphere_directions
from bimscan.survey.spots import (
    DOWN_CONE_Z, STATION_CHECK_RAYS, TripodSpots, find_tripod_spots, grid_columns, in_room, on_room_floor, rooms_of,
)
from bimscan.types import BimScene, Space, Station

HEAD_CLEARANCE_M = 0.1  # a TLS head is about 20-30 cm across: its beam origin needs this much free space around it
SAME_SPOT_M = 0.01  # two stations of a file whose beam origins lie this close are one spot scanned twice
LEVEL_GAP_M = 1.2  # floor heights further apart than this are separate levels (a storey is at least 2 m)
FINE_GRID_M = 0.25  # rooms the planner's grid misses are searched on this grid


@dataclass(frozen=True)
class PlanReport:
    """What the planner did: stations per storey and the rooms it could not place a station in."""

    stations_per_storey: dict[str, int] = field(default_factory=dict)
    rooms_without_station: tuple[str, ...] = ()  # rooms (IfcSpace) with no spot a tripod can stand on

    def rooms_without_station_line(self) -> str:
        """The one warning line naming the rooms the planner left without a station."""
        rooms = self.rooms_without_station
        shown = ", ".join(rooms[:20]) + (f" and {len(rooms) - 20} more" if len(rooms) > 20 else "")
        return (f"{len(rooms)} rooms without a station (no level floor with headroom and a clear tripod spot in "
                f"them): {shown}")


def read_stations(path: str | Path, scene: BimScene, prober: Prober, scanner: ScannerModel, *,
                  head_span_deg: float = 360.0, check: bool = True) -> tuple[Station, ...]:
    """Stations from a CSV file (see module docs); floor-relative rows are placed on the floor,
    the tripod's height being ``scanner``'s. A storey the model does not have is refused, and so
    are two rows at one spot (``SAME_SPOT_M``): a scan from both holds that spot's points twice
    (with a head rotation of less than a full turn, ``head_span_deg``, two headings at one spot
    scan different sectors and are kept). ``check``: each station is checked (``check_station``)
    on this scene; leave it to the caller when the stations are to be checked on the scene as it
    will be scanned (a site dressed from it)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such station file; check the path")
    try:
        text = path.read_text("utf-8")
    except UnicodeDecodeError as exc:
        raise StationError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start}); save the station "
                           "file as UTF-8 CSV") from exc
    lines = [line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    if len(lines) < 2:
        raise StationError(f"{path}: no stations in the file; give a header (x,y,z or x,y,height) and one row per station")
    delimiter = "," if "," in lines[0] else None
    rows = list(csv.reader(io.StringIO("\n".join(lines)), delimiter=",")) if delimiter else [line.split() for line in lines]
    header = [h.strip().lower() for h in rows[0]]
    allowed = {"x", "y", "z", "height", "storey", "heading_deg"}
    unknown = sorted(set(header) - allowed)
    if unknown or not {"x", "y"} <= set(header):
        raise StationError(f"{path}: header {','.join(header)!r} must name x and y (optional: z or height, "
                           f"storey, heading_deg); unknown: {', '.join(unknown) or 'none'}")
    storeys = {s.name: s.elevation_m for s in scene.storeys}
    stations = []
    instrument = scanner.instrument_height_m
    for number, row in enumerate(rows[1:], start=1):
        if len(row) != len(header):
            raise StationError(f"{path}: station {number} has {len(row)} values for {len(header)} columns; fix the row")
        values = dict(zip(header, (v.strip() for v in row)))
        try:
            x, y = float(values["x"]), float(values["y"])
            heading = float(values.get("heading_deg") or 0.0)
            z = float(values["z"]) if values.get("z") not in (None, "") else None
            height = float(values["height"]) if values.get("height") not in (None, "") else None
        except ValueError as exc:
            raise StationError(f"{path}: station {number}: {exc}; coordinates must be numbers in metres") from exc
        if not all(math.isfinite(v) for v in (x, y, heading, *(v for v in (z, height) if v is not None))):
            raise StationError(f"{path}: station {number} has a value that is not a finite number (nan or inf); "
                               "give coordinates in metres and the heading in degrees")
        storey_name = values.get("storey", "") or ""
        if storey_name and storey_name not in storeys:
            known = (f"use one of {', '.join(storeys)}" if storeys else
                     "the model has no storeys: leave the storey empty")
            raise StationError(f"{path}: station {number}: unknown storey {storey_name!r}; {known}")
        floor_z = None
        if z is None:
            if height is None:
                height = instrument  # a tripod of the scanner's standard height
            if not storey_name:
                if len(storeys) > 1:
                    raise StationError(f"{path}: station {number} is floor-relative but names no storey; "
                                       f"add a storey column ({', '.join(storeys)})")
                storey_name = next(iter(storeys), "")
            if storey_name not in storeys:
                raise StationError(f"{path}: station {number}: unknown storey {storey_name!r}; use one of {', '.join(storeys)}")
            floor_z = _floor_below(prober, x, y, storeys[storey_name] + 1.0)
            if floor_z is None:  # a room of the storey without a floor element: its own floor
                floor_z = next((float(r.vertices[:, 2].min()) for r in rooms_of(scene)
                                if r.storey == storey_name and r.contains(np.array([[x, y, float(r.vertices[:, 2].min()) + 0.05]]))[0]), None)
            if floor_z is None:
                raise StationError(f"{path}: station {number} at ({x:g}, {y:g}) has no floor under it on storey "
                                   f"{storey_name!r}; move it inside the building")
            z = floor_z + height
        elif height is not None:  # z and height: the station says where its floor is
            floor_z = z - height
        stations.append(Station(id=number - 1, position=(x, y, z), heading_deg=heading, floor_z=floor_z,
                                storey=storey_name))
    _refuse_same_spot(path, stations, head_span_deg)
    if check:
        for station in stations:
            check_station(station, scene, prober)
    return tuple(stations)


def _refuse_same_spot(path: Path, stations: list[Station], head_span_deg: float) -> None:
    """StationError naming the first two stations (1-based rows) whose beam origins lie within
    ``SAME_SPOT_M``, unless a partial head rotation turns them to different headings."""
    if len(stations) < 2:
        return
    xyz = np.array([s.position for s in stations])
    full_turn = head_span_deg >= 360.0 - 1e-9
    for a in range(len(stations) - 1):
        near = np.flatnonzero(np.linalg.norm(xyz[a + 1:] - xyz[a], axis=1) <= SAME_SPOT_M) + a + 1
        for b in near:
            turned = (stations[b].heading_deg - stations[a].heading_deg) % 360.0
            if full_turn or min(turned, 360.0 - turned) < 1e-6:
                raise StationError(
                    f"{path}: stations {a + 1} and {b + 1} stand at the same spot "
                    f"({', '.join(number(c) for c in stations[a].position)}); a scan from both holds that spot's "
                    "points twice: remove one of the rows")


def station_problem(station: Station, scene: BimScene, prober: Prober) -> str | None:
    """Why a station is unusable (one line: inside a solid, outside the building, nothing under it
    to stand on, a surface closer than a scanner head's size), or None. A station whose floor is
    a room's (``floor_z`` at the bottom of an IfcSpace it stands in) stands on that floor even
    where the model has no slab."""
    where = f"station {station.id} at ({', '.join(number(c) for c in station.position)})"
    inside = prober.solid_containing(np.asarray(station.position))
    if inside is not None:
        return (f"{where} is inside a solid ({scene.components.ifc_class[inside]} "
                f"{scene.components.global_id[inside]}); move it into a room")
    directions = sphere_directions(STATION_CHECK_RAYS)
    t_hit, component = prober.cast(np.asarray(station.position), directions)
    hit = np.isfinite(t_hit)
    down, up = directions[:, 2] < DOWN_CONE_Z, directions[:, 2] > -DOWN_CONE_Z
    on_room = station.floor_z is not None and bool(
        on_room_floor(scene, np.array([[station.position[0], station.position[1], station.floor_z]]))[0])
    if (~hit[down]).mean() > 0.5 and (~hit[up]).mean() > 0.5 and not on_room:
        return f"{where} is outside the building (nothing above or below it); move it inside"
    if (~hit[down]).mean() > 0.5 and not on_room:
        return (f"{where} has nothing under it to stand on (under the building?); give its z as the beam "
                "height above a floor, or use a height column")
    nearest = int(np.argmin(t_hit))
    if t_hit[nearest] < HEAD_CLEARANCE_M:
        c = int(component[nearest])
        return (f"{where} is {100 * t_hit[nearest]:.0f} cm from {scene.components.ifc_class[c]} "
                f"{scene.components.global_id[c]}, closer than a scanner head allows "
                f"({100 * HEAD_CLEARANCE_M:.0f} cm); move it into free space")
    return None


def check_station(station: Station, scene: BimScene, prober: Prober) -> None:
    """Raise StationError when a station is unusable (see ``station_problem``)."""
    problem = station_problem(station, scene, prober)
    if problem is not None:
        raise StationError(problem)


def _floor_below(prober: Prober, x: float, y: float, z_from: float) -> float | None:
    t, _ = prober.cast(np.array([x, y, z_from]), np.array([[0.0, 0.0, -1.0]], dtype=np.float32))
    return None if not np.isfinite(t[0]) else z_from - float(t[0])


def plan_stations(scene: BimScene, prober: Prober, scanner: ScannerModel, *, grid_m: float = 1.0,
                  clearance_m: float = 0.4, max_spacing_m: float = 12.0,
                  max_columns: int = 4000) -> tuple[tuple[Station, ...], PlanReport]:
    """Place stations on every level (see the module docs): ``grid_m`` apart (coarser on models over
    ``max_columns`` square grid cells), ``clearance_m`` clear around the tripod, every spot seen from a
    station within ``max_spacing_m``. Raises StationError when no tripod can stand anywhere."""
    instrument = scanner.instrument_height_m
    rooms = rooms_of(scene)
    spots = station_spots(scene, prober, scanner, grid_m=grid_m, clearance_m=clearance_m, max_columns=max_columns)
    levels = floor_levels(spots.floor[:, 2])
    room_spots = [in_room(room, spots.floor) for room in rooms]
    refused = np.zeros(len(spots), dtype=bool)
    stations: list[Station] = []
    per_storey: dict[str, int] = {}
    with_station = np.zeros(len(rooms), dtype=bool)
    for level in range(int(levels.max()) + 1):
        while True:  # a chosen spot the station check refuses is dropped and the level chosen again
            members = np.flatnonzero((levels == level) & ~refused)
            chosen = _choose(prober, scanner, spots, members, room_spots, with_station, max_spacing_m)
            trial = [_station(len(stations) + k, spots.floor[i], rooms, room_spots, i, scene, instrument)
                     for k, i in enumerate(chosen)]
            bad = [i for i, s in zip(chosen, trial) if station_problem(s, scene, prober) is not None]
            if not bad:
                break
            refused[bad] = True
        for i, station in zip(chosen, trial):
            stations.append(station)
            storey = station.storey or f"level at {spots.floor[i, 2]:.2f} m"
            per_storey[storey] = per_storey.get(storey, 0) + 1
            for k, members_of_room in enumerate(room_spots):
                with_station[k] |= bool(members_of_room[i])
    rooms_without = tuple(room.name for k, room in enumerate(rooms) if not with_station[k])
    return tuple(stations), PlanReport(per_storey, rooms_without)


def station_spots(scene: BimScene, prober: Prober, scanner: ScannerModel, *, grid_m: float = 1.0,
                  clearance_m: float = 0.4, max_columns: int = 4000) -> TripodSpots:
    """The tripod spots the planner chooses from (see ``plan_stations``): on the grid, on a finer
    grid in rooms the grid misses; indoors ones (covered, or in a room) only where the model has
    any. Raises StationError when there is none: no tripod can stand anywhere in the model."""
    instrument = scanner.instrument_height_m
    lo, hi = scene.mesh.bounds()
    columns = grid_columns(lo, hi, grid_m=grid_m, max_columns=max_columns)
    spots = find_tripod_spots(scene, prober, columns, instrument_m=instrument, clearance_m=clearance_m)
    if len(spots) == 0:  # no floor element gives a spot: whatever element is wide and level enough
        spots = find_tripod_spots(scene, prober, columns, instrument_m=instrument, clearance_m=clearance_m,
                                  any_element=True)
    found = [spots]
    for room in rooms_of(scene):  # small rooms can fall between grid points: search them on a fine grid of their own
        if in_room(room, spots.floor).any():
            continue
        r_lo, r_hi = room.vertices.min(axis=0), room.vertices.max(axis=0)
        columns = grid_columns(r_lo, r_hi, grid_m=FINE_GRID_M, max_columns=max_columns)
        columns = columns[room.contains(np.column_stack([columns, np.full(len(columns), r_lo[2] + 0.5)]))]
        fine = find_tripod_spots(scene, prober, columns, instrument_m=instrument, clearance_m=clearance_m)
        found.append(fine.take(in_room(room, fine.floor)))
    spots = TripodSpots.join(found)
    indoors = spots.covered.copy()  # under a slab or roof, or in a room (a model may have neither)
    for room in rooms_of(scene):
        indoors |= in_room(room, spots.floor)
    if indoors.any():  # indoors wherever the model has an indoors
        spots = spots.take(indoors)
    if len(spots) == 0:
        raise StationError(f"{scene.source}: no place for a station found (no level floor with "
                           f"{instrument + 0.3:.1f} m of headroom and {clearance_m:g} m clear around a tripod); "
                           "give stations in a file with --stations FILE")
    return spots


def floor_levels(z: np.ndarray) -> np.ndarray:
    """(M,) int level of each floor height (M,): heights sorted and split where they jump by more
    than ``LEVEL_GAP_M``; level 0 is the lowest."""
    if len(z) == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.argsort(z, kind="stable")
    jumps = np.concatenate([[0], np.diff(z[order]) > LEVEL_GAP_M]).astype(np.int64)
    levels = np.empty(len(z), dtype=np.int64)
    levels[order] = np.cumsum(jumps)
    return levels


def _station(number: int, floor: np.ndarray, rooms: list[Space], room_spots: list[np.ndarray], spot: int,
             scene: BimScene, instrument: float) -> Station:
    """The station standing at ``floor`` (x, y, floor z): its room (the first that holds the spot)
    and storey (the room's, else the highest storey at or below the floor)."""
    x, y, floor_z = (float(v) for v in floor)
    room = next((r for r, members in zip(rooms, room_spots) if members[spot]), None)
    storey = room.storey if room is not None and room.storey else storey_at(scene, floor_z)
    return Station(id=number, position=(x, y, floor_z + instrument), floor_z=floor_z, storey=storey,
                   room=room.name if room is not None else "")


def station_on_floor(number: int, floor: np.ndarray, scene: BimScene, instrument: float) -> Station:
    """The station ``number`` whose tripod stands at ``floor`` (3,) (x, y, floor z) metres, the beam
    origin ``instrument`` above it, with its room and storey as ``plan_stations`` gives them."""
    rooms = rooms_of(scene)
    point = np.asarray(floor, dtype=np.float64)[None, :]
    return _station(number, point[0], rooms, [in_room(room, point) for room in rooms], 0, scene, instrument)


def storey_at(scene: BimScene, floor_z: float) -> str:
    """The name of the highest storey at or below a floor height (0.5 m of slack; the lowest storey
    below all of them; "" for a model without storeys)."""
    below = [s for s in scene.storeys if s.elevation_m <= floor_z + 0.5]
    pick = max(below, key=lambda s: s.elevation_m) if below else min(scene.storeys, key=lambda s: s.elevation_m,
                                                                      default=None)
    return pick.name if pick is not None else ""


STATION_COLUMNS = ("x", "y", "z", "height", "storey", "heading_deg")


def station_rows(stations: tuple[Station, ...] | list[Station]) -> list[dict[str, str]]:
    """The stations as rows of a station file (``STATION_COLUMNS``): ``z`` the beam origin,
    ``height`` its height above the floor (so the file keeps the floor; empty when unknown)."""
    rows = []
    for s in stations:
        x, y, z = s.position
        height = "" if s.floor_z is None else f"{z - s.floor_z:.4f}"
        rows.append({"x": f"{x:.4f}", "y": f"{y:.4f}", "z": f"{z:.4f}", "height": height, "storey": s.storey,
                     "heading_deg": f"{s.heading_deg:g}"})
    return rows


def format_stations(stations: tuple[Station, ...] | list[Station], *, comments: tuple[str, ...] = ()) -> str:
    """A station file's text (see the module docs) that ``read_stations`` reads back to the same
    stations (positions to 0.1 mm): ``comments`` first, as ``#`` lines, then a header and one row
    per station in id order."""
    out = io.StringIO()
    for line in comments:
        out.write(f"# {line}\n")
    writer = csv.DictWriter(out, fieldnames=STATION_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(station_rows(sorted(stations, key=lambda s: s.id)))
    return out.getvalue()


def _choose(prober: Prober, scanner: ScannerModel, spots: TripodSpots, members: np.ndarray,
            room_spots: list[np.ndarray], with_station: np.ndarray, max_spacing: float) -> list[int]:
    """Indices of spots (among ``members``, one level's) to use: one per room that has none yet,
    then a greedy visibility cover of the level's spots."""
    if len(members) == 0:
        return []
    heads = spots.floor + [0.0, 0.0, scanner.instrument_height_m]
    chosen: list[int] = []
    for k, in_this_room in enumerate(room_spots):
        inside = members[in_this_room[members]]
        if len(inside) == 0 or with_station[k] or any(in_this_room[i] for i in chosen):
            continue
        # the spot that sees most of the room beyond the minimum range (narrow rooms and
        # corridors lose what is closer than that); ties go to the spot nearest the middle
        useful = useful_return_fraction(prober, scanner, heads[inside])
        centre = heads[inside, :2].mean(axis=0)
        distance = np.linalg.norm(heads[inside, :2] - centre, axis=1)
        chosen.append(int(inside[np.lexsort((distance, -np.round(useful, 2)))[0]]))
    level_heads = heads[members]
    seen = np.zeros(len(members), dtype=bool)
    position = {int(i): j for j, i in enumerate(members)}
    for i in chosen:
        seen |= _visible_from(prober, level_heads, position[i], max_spacing)
    while not seen.all():
        # the unseen spot seeing the most unseen spots becomes the next station
        unseen = np.flatnonzero(~seen)
        best, best_cover = -1, None
        for j in unseen[:: max(1, len(unseen) // 200)]:
            cover = _visible_from(prober, level_heads, int(j), max_spacing) & ~seen
            if best_cover is None or cover.sum() > best_cover.sum():
                best, best_cover = int(j), cover
        chosen.append(int(members[best]))
        seen |= best_cover
        seen[best] = True
    return chosen


def useful_return_fraction(prober: Prober, scanner: ScannerModel, heads: np.ndarray, n_rays: int = 256) -> np.ndarray:
    """Per instrument position (M, 3), the fraction of rays (in the scanner's window) that would give a point."""
    directions = sphere_directions(4 * n_rays)
    low, high = np.sin(np.radians([scanner.elevation_min_deg, scanner.elevation_max_deg]))
    directions = directions[(directions[:, 2] >= low) & (directions[:, 2] < high)][:n_rays]
    origins = np.repeat(heads, len(directions), axis=0)
    t, _ = prober.cast(origins, np.tile(directions, (len(heads), 1)))
    ok = (t >= scanner.min_range_m) & (t <= scanner.max_range_m)
    return ok.reshape(len(heads), len(directions)).mean(axis=1)


def _visible_from(prober: Prober, heads: np.ndarray, i: int, max_spacing: float) -> np.ndarray:
    """Spots whose instrument point is in line of sight of spot i's, within max_spacing."""
    delta = heads - heads[i]
    distance = np.linalg.norm(delta, axis=1)
    near = (distance <= max_spacing) & (distance > 1e-6)
    out = np.zeros(len(heads), dtype=bool)
    out[i] = True
    if near.any():
        directions = (delta[near] / distance[near, None]).astype(np.float32)
        t, _ = prober.cast(heads[i], directions)
        out[np.flatnonzero(near)] = t >= distance[near] - 0.05
    return out

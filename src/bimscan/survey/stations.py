"""Scan stations: read from a file, planned automatically, and checked against the scene.

Stations stand on the floor: the beam origin is ``tripod_height + beam_origin_height`` above it.

Station files are CSV (comma or whitespace separated) with a header naming the columns:
``x, y`` (metres) and either ``z`` (absolute height of the beam origin) or ``height`` (beam
origin above the floor below; without z and height the scanner's tripod + beam offset), with
``storey`` naming the storey of floor-relative stations when the building has more than one;
``heading_deg`` is optional. Lines starting with ``#`` are comments.

``plan_stations`` places stations per storey: a grid of candidate tripod spots on floors
(slab or floor covering under the spot, headroom, a clear circle around the tripod, not inside
any solid), one station in every room (IfcSpace) that has a usable spot, then a greedy visibility
cover so that every usable spot is seen from a station within ``max_spacing_m``. Rooms with a
floor but no usable spot are reported.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError, StationError
from bimscan.scan.virtual_scanner import VirtualScanner, sphere_directions
from bimscan.types import BimScene, Station

FLOOR_CLASSES = ("IfcSlab", "IfcCovering", "IfcRamp", "IfcRampFlight", "IfcPlate")
HEAD_CLEARANCE_M = 0.1  # a TLS head is about 20-30 cm across: its beam origin needs this much free space around it


@dataclass(frozen=True)
class PlanReport:
    """What the planner did: stations per storey and the rooms it could not place a station in."""

    stations_per_storey: dict[str, int] = field(default_factory=dict)
    rooms_without_station: tuple[str, ...] = ()


def read_stations(path: str | Path, scene: BimScene, scanner: VirtualScanner) -> tuple[Station, ...]:
    """Stations from a CSV file (see module docs); floor-relative rows are placed on the floor."""
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
    instrument = scanner.scanner.instrument_height_m
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
            floor_z = _floor_below(scanner, x, y, storeys[storey_name] + 1.0)
            if floor_z is None:
                raise StationError(f"{path}: station {number} at ({x:g}, {y:g}) has no floor under it on storey "
                                   f"{storey_name!r}; move it inside the building")
            z = floor_z + height
        stations.append(Station(id=number - 1, position=(x, y, z), heading_deg=heading, floor_z=floor_z,
                                storey=storey_name))
    for station in stations:
        check_station(station, scene, scanner)
    return tuple(stations)


def check_station(station: Station, scene: BimScene, scanner: VirtualScanner) -> None:
    """Raise StationError when a station is unusable: inside a solid, outside the building, with
    nothing under it to stand on, or with a surface closer than a scanner head's size."""
    where = f"station {station.id} at ({', '.join(f'{c:.2f}' for c in station.position)})"
    inside = scanner.solid_containing(np.asarray(station.position))
    if inside is not None:
        raise StationError(f"{where} is inside a solid ({scene.components.ifc_class[inside]} "
                           f"{scene.components.global_id[inside]}); move it into a room")
    directions = sphere_directions(2048)
    t_hit, component = scanner.cast(np.asarray(station.position), directions)
    hit = np.isfinite(t_hit)
    down, up = directions[:, 2] < -0.85, directions[:, 2] > 0.85
    if (~hit[down]).mean() > 0.5 and (~hit[up]).mean() > 0.5:
        raise StationError(f"{where} is outside the building (nothing above or below it); move it inside")
    if (~hit[down]).mean() > 0.5:
        raise StationError(f"{where} has nothing under it to stand on (under the building?); give its z as the beam "
                           "height above a floor, or use a height column")
    nearest = int(np.argmin(t_hit))
    if t_hit[nearest] < HEAD_CLEARANCE_M:
        c = int(component[nearest])
        raise StationError(f"{where} is {100 * t_hit[nearest]:.0f} cm from {scene.components.ifc_class[c]} "
                           f"{scene.components.global_id[c]}, closer than a scanner head allows "
                           f"({100 * HEAD_CLEARANCE_M:.0f} cm); move it into free space")


def _floor_below(scanner: VirtualScanner, x: float, y: float, z_from: float) -> float | None:
    t, _ = scanner.cast(np.array([x, y, z_from]), np.array([[0.0, 0.0, -1.0]], dtype=np.float32))
    return None if not np.isfinite(t[0]) else z_from - float(t[0])


def plan_stations(scene: BimScene, scanner: VirtualScanner, *, grid_m: float = 1.0, clearance_m: float = 0.4,
                  max_spacing_m: float = 12.0, max_candidates: int = 3000) -> tuple[tuple[Station, ...], PlanReport]:
    """Place stations on every storey (see module docs). Raises StationError if none can be placed."""
    instrument = scanner.scanner.instrument_height_m
    lo, hi = scene.mesh.bounds()
    area = max((hi[0] - lo[0]) * (hi[1] - lo[1]), 1e-6)
    grid = max(grid_m, math.sqrt(area / max_candidates))
    xs = np.arange(lo[0] + grid / 2, hi[0], grid)
    ys = np.arange(lo[1] + grid / 2, hi[1], grid)
    gx, gy = (a.ravel() for a in np.meshgrid(xs, ys, indexing="xy"))
    floor_components = _components_of(scene, FLOOR_CLASSES)
    levels = _levels(scene, lo[2], hi[2])
    stations: list[Station] = []
    per_storey: dict[str, int] = {}
    rooms_without: list[str] = []
    for index, (name, elevation, next_elevation) in enumerate(levels):
        spots = _tripod_spots(scanner, gx, gy, elevation, next_elevation, floor_components, instrument, clearance_m)
        rooms = [s for s in scene.spaces if s.storey == name] if name else list(scene.spaces)
        # small rooms can fall between grid points: search them on a fine grid of their own
        for room in rooms:
            if not _room_has_floor(room, elevation, next_elevation) or (len(spots) and _in_room(room, spots).any()):
                continue
            r_lo, r_hi = room.vertices.min(axis=0), room.vertices.max(axis=0)
            fx, fy = (a.ravel() for a in np.meshgrid(np.arange(r_lo[0] + 0.125, r_hi[0], 0.25),
                                                     np.arange(r_lo[1] + 0.125, r_hi[1], 0.25), indexing="xy"))
            if len(fx) == 0:
                continue
            fine = _tripod_spots(scanner, fx, fy, elevation, next_elevation, floor_components, instrument, clearance_m)
            fine = fine[_in_room(room, fine)] if len(fine) else fine
            if len(fine):
                spots = np.concatenate([spots, fine]) if len(spots) else fine
        if len(spots) == 0:
            rooms_without += [r.name for r in rooms if _room_has_floor(r, elevation, next_elevation)]
            continue
        chosen = _choose(scanner, spots, rooms, instrument, max_spacing_m, rooms_without, elevation, next_elevation)
        per_storey[name or f"level {index}"] = len(chosen)
        for i in chosen:
            x, y, floor_z = spots[i]
            stations.append(Station(id=len(stations), position=(float(x), float(y), float(floor_z + instrument)),
                                    floor_z=float(floor_z), storey=name, room=_room_name(rooms, x, y, floor_z)))
    if not stations:
        raise StationError(f"{scene.source}: no place for a station found (no floor with {instrument + 0.3:.1f} m of "
                           "headroom and a clear tripod spot); give stations in a file with --stations FILE")
    return tuple(stations), PlanReport(per_storey, tuple(rooms_without))


def _components_of(scene: BimScene, classes: tuple[str, ...]) -> np.ndarray:
    """Boolean mask (C,) of components whose class descends from one of ``classes``."""
    ancestry = scene.components.class_ancestry
    wanted = {c.lower() for c in classes}
    by_class = {cls: any(a.lower() in wanted for a in ancestry.get(cls, (cls,))) for cls in set(scene.components.ifc_class.tolist())}
    mask = np.array([by_class[c] for c in scene.components.ifc_class.tolist()], dtype=bool)
    return mask if mask.any() else np.ones(len(mask), dtype=bool)  # no slabs at all: any surface is a floor


def _levels(scene: BimScene, z_min: float, z_max: float) -> list[tuple[str, float, float]]:
    """(storey name, elevation, next elevation) from the storeys, or one level for the whole model."""
    storeys = sorted(scene.storeys, key=lambda s: s.elevation_m)
    if not storeys:
        return [("", float(z_min), float(z_max) + 1.0)]
    out = []
    for i, s in enumerate(storeys):
        nxt = storeys[i + 1].elevation_m if i + 1 < len(storeys) else float(z_max) + 1.0
        if nxt - s.elevation_m > 1.0:
            out.append((s.name, s.elevation_m, nxt))
    return out


def _tripod_spots(scanner: VirtualScanner, gx: np.ndarray, gy: np.ndarray, elevation: float, next_elevation: float,
                  floor_components: np.ndarray, instrument: float, clearance: float) -> np.ndarray:
    """(M, 3) candidate tripod spots (x, y, floor z) of one storey.

    A spot stands on a floor surface near the storey's elevation (or, where the model has no
    floor there, on a virtual floor at the elevation), under a ceiling or roof with headroom for
    the instrument, with a clear circle around the tripod. Spots on furniture are rejected: the
    first surface below must be a floor element or lie no higher than the elevation.
    """
    start_z = elevation + min(1.0, 0.5 * (next_elevation - elevation))
    origins = np.stack([gx, gy, np.full_like(gx, start_z)], axis=1)
    t, component = scanner.cast(origins, np.broadcast_to(np.array([0, 0, -1], np.float32), origins.shape))
    floor_z = start_z - t
    near_elevation = (floor_z > elevation - 0.6) & (floor_z < elevation + 0.6)
    on_floor = np.isfinite(t) & (component >= 0) & floor_components[np.maximum(component, 0)] & near_elevation
    # no floor element under the spot and nothing above the storey's elevation either (a model
    # without floor slabs, or a footing at ground level): stand on a virtual floor at the elevation
    floorless = ~on_floor & (~np.isfinite(t) | (floor_z <= elevation + 0.05))
    floor_z = np.where(on_floor, floor_z, elevation)
    spots = np.stack([gx, gy, floor_z], axis=1)[on_floor | floorless]
    if len(spots) == 0:
        return spots
    # something overhead (a ceiling or roof: inside the building), above the instrument
    up_origins = spots + [0.0, 0.0, 0.05]
    t_up, _ = scanner.cast(up_origins, np.broadcast_to(np.array([0, 0, 1], np.float32), up_origins.shape))
    spots = spots[np.isfinite(t_up) & (t_up >= instrument + 0.3)]
    if len(spots) == 0:
        return spots
    # a clear circle around the tripod at three heights (this also rejects spots inside solids)
    ring = np.array([[math.cos(a), math.sin(a), 0.0] for a in np.linspace(0, 2 * math.pi, 16, endpoint=False)], np.float32)
    clear = np.ones(len(spots), dtype=bool)
    for h in (0.3, 1.0, instrument):
        origins = np.repeat(spots + [0.0, 0.0, h], len(ring), axis=0)
        t_ring, _ = scanner.cast(origins, np.tile(ring, (len(spots), 1)))
        clear &= (t_ring.reshape(len(spots), len(ring)) >= clearance).all(axis=1)
    return spots[clear]


def _choose(scanner: VirtualScanner, spots: np.ndarray, rooms, instrument: float, max_spacing: float,
            rooms_without: list[str], elevation: float, next_elevation: float) -> list[int]:
    """Indices of spots to use: one per room, then a greedy visibility cover of all spots."""
    heads = spots + [0.0, 0.0, instrument]
    chosen: list[int] = []
    for room in rooms:
        if not _room_has_floor(room, elevation, next_elevation):
            continue
        inside = np.flatnonzero(_in_room(room, spots))
        if len(inside) == 0:
            rooms_without.append(room.name)
            continue
        # the spot that sees most of the room beyond the minimum range (narrow rooms and
        # corridors lose what is closer than that); ties go to the spot nearest the middle
        useful = useful_return_fraction(scanner, heads[inside])
        centre = heads[inside, :2].mean(axis=0)
        distance = np.linalg.norm(heads[inside, :2] - centre, axis=1)
        chosen.append(int(inside[np.lexsort((distance, -np.round(useful, 2)))[0]]))
    seen = np.zeros(len(spots), dtype=bool)
    for i in chosen:
        seen |= _visible_from(scanner, heads, i, max_spacing)
    while not seen.all():
        # the unseen spot seeing the most unseen spots becomes the next station
        unseen = np.flatnonzero(~seen)
        best, best_cover = -1, None
        for i in unseen[:: max(1, len(unseen) // 200)]:
            cover = _visible_from(scanner, heads, int(i), max_spacing) & ~seen
            if best_cover is None or cover.sum() > best_cover.sum():
                best, best_cover = int(i), cover
        chosen.append(best)
        seen |= best_cover
        seen[best] = True
    return chosen


def useful_return_fraction(scanner: VirtualScanner, heads: np.ndarray, n_rays: int = 256) -> np.ndarray:
    """Per instrument position, the fraction of rays (in the scanner's window) that would give a point."""
    model = scanner.scanner
    directions = sphere_directions(4 * n_rays)
    low, high = np.sin(np.radians([model.elevation_min_deg, model.elevation_max_deg]))
    directions = directions[(directions[:, 2] >= low) & (directions[:, 2] < high)][:n_rays]
    origins = np.repeat(heads, len(directions), axis=0)
    t, _ = scanner.cast(origins, np.tile(directions, (len(heads), 1)))
    ok = (t >= model.min_range_m) & (t <= model.max_range_m)
    return ok.reshape(len(heads), len(directions)).mean(axis=1)


def _visible_from(scanner: VirtualScanner, heads: np.ndarray, i: int, max_spacing: float) -> np.ndarray:
    """Spots whose instrument point is in line of sight of spot i's, within max_spacing."""
    delta = heads - heads[i]
    distance = np.linalg.norm(delta, axis=1)
    near = (distance <= max_spacing) & (distance > 1e-6)
    out = np.zeros(len(heads), dtype=bool)
    out[i] = True
    if near.any():
        directions = (delta[near] / distance[near, None]).astype(np.float32)
        t, _ = scanner.cast(heads[i], directions)
        out[np.flatnonzero(near)] = t >= distance[near] - 0.05
    return out


def _room_has_floor(room, elevation: float, next_elevation: float) -> bool:
    z0 = float(room.vertices[:, 2].min())
    return elevation - 0.6 < z0 < next_elevation - 1.0


def _in_room(room, points: np.ndarray) -> np.ndarray:
    """Points (x, y, z) whose xy falls inside the room's footprint and z inside its height."""
    return room.contains(points)


def _room_name(rooms, x: float, y: float, floor_z: float) -> str:
    point = np.array([[x, y, floor_z]])
    for room in rooms:
        if _in_room(room, point)[0]:
            return room.name
    return ""

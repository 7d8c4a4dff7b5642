"""Drone flights planned from the model: orbits around the building facing its facades, then a grid
over the site, taking off and landing outside the footprint.

A flying platform's trajectory is the pose of its gimbal-stabilised payload (the lidar's mount):
``xyz`` the payload, ``yaw`` where it faces, ``pitch`` how far the gimbal tilts it down (0:
level, 90: straight down; ``Trajectory``'s Ry(pitch) turns +x towards -z), roll 0. The lidar of
the drone platform is mounted looking along the payload's +x (``tilt_deg = 90``), so its sensor y
axis lies across the direction it faces.

The plan (``plan_flight``), every length from ``FlightSettings``:

- **Footprint**: the convex hull of the model's plan (every vertex, roof overhangs included); the
  ring the orbits fly is that hull grown by ``orbit_clearance_m`` (its corners rounded), so the
  drone keeps that distance from every part of the building's outline.
- **Orbits** at heights spread evenly over the building's height, each facing the building
  (each side of the ring flown along its inward normal, turning at its end; pitch
  ``orbit_pitch_deg``), flown counter-clockwise. How
  many: the facade band one orbit covers is ``2 d tan(h)`` at the clearance d for the lidar's
  half-extent h along its sensor x axis (vertical when facing a facade), overlapping by
  ``orbit_overlap``; heights below ``MIN_HEIGHT_M`` above the ground are raised to it.
- **Grid**: lines over the hull's minimum-area rectangle grown by the clearance, at
  ``grid_height_m`` above the building's highest point, the gimbal pointing down
  (``grid_pitch_deg``); the lines lie along the rectangle's long side, ``2 g tan(h) (1 -
  side_overlap)`` apart for the lidar's half-extent h across the track at g = ``grid_height_m``
  (the swath on the roof).
- **Take-off and landing** at one point ``takeoff_offset_m`` outside the ring, on the ground (the
  first around the ring clear of the yard's objects): a vertical climb to the first orbit, climbs
  between orbits at the ring's first point, a climb to the grid's height, the grid, then back over
  the take-off point and down. Orbits pass over the yard's objects near their ring.

Speeds: ``speed_m_s`` along the orbits and the grid, ``climb_speed_m_s`` up and down; the yaw
turns at most ``max_turn_deg_per_s`` (a leg that must turn further takes longer). The
trajectory is sampled every ``sample_m`` metres (and at every turn); poses between samples are
linear, as for any trajectory.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError, StationError
from bimscan.scan.lidars import Lidar
from bimscan.scan.risley import RisleyScanner
from bimscan.survey.trajectory import Trajectory

MIN_HEIGHT_M = 3.0  # no orbit flies lower above the ground
RING_ARC_STEPS = 12  # points per quarter turn of the ring's rounded corners
GROUND_BELOW_FLOOR_M = 0.05  # the ground lies this far below the ground floor (inside its slab)
TAKEOFF_HEIGHT_M = 0.3  # the payload's height above the ground when the drone stands
OBSTACLE_BAND_M = 3.0  # what stands this close to an orbit's ring (or the take-off point) is in the way
OBSTACLE_CLEARANCE_M = 1.5  # an orbit passes this far over what stands under it
GROUND_FLOOR_NEAR_ZERO_M = 1.5  # a storey this close to elevation 0 is the ground floor


@dataclass(frozen=True)
class FlightSettings(Checked):
    """How a drone's flight is planned (see the module docs). The defaults are a typical building
    survey with a DJI M350 and a Zenmuse L2 (DJI's guidance for the L2: flight heights of 50-150 m
    for mapping and about 5-10 m/s; closer and slower around a single building); they are
    assumptions of this planner, not a vendor's figures."""

    speed_m_s: float = setting(4.0, within=Range(0.1, 30.0), hint="metres per second")
    climb_speed_m_s: float = setting(2.0, within=Range(0.1, 10.0))
    max_turn_deg_per_s: float = setting(45.0, within=Range(1.0, 360.0))
    grid_height_m: float = setting(30.0, within=Range(2.0, 500.0), hint="metres above the building's top")
    side_overlap: float = setting(0.5, within=Range(0.0, 0.95))
    orbit_clearance_m: float = setting(10.0, within=Range(1.0, 200.0), hint="metres from the footprint")
    orbit_overlap: float = setting(0.3, within=Range(0.0, 0.95))
    orbit_pitch_deg: float = setting(0.0, within=Range(-30.0, 90.0))
    grid_pitch_deg: float = setting(90.0, within=Range(0.0, 90.0))
    takeoff_offset_m: float = setting(5.0, within=Range(0.0, 500.0))
    ground_margin_m: float = setting(30.0, within=Range(0.0, 1000.0), hint="metres of ground around the footprint")
    sample_m: float = setting(1.0, within=Range(0.05, 50.0))

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"flight {problem}")


@dataclass(frozen=True)
class FlightReport:
    """What a planned flight does: its orbits' heights (metres, world z), the grid's lines and their
    spacing, where it takes off, its length and duration."""

    orbit_heights: tuple[float, ...]
    grid_lines: int
    grid_spacing_m: float
    grid_z: float
    takeoff: tuple[float, float, float]
    length_m: float
    duration_s: float

    def to_json(self) -> dict[str, object]:
        return {"orbit_heights_m": [round(z, 6) for z in self.orbit_heights], "grid_lines": self.grid_lines,
                "grid_spacing_m": round(self.grid_spacing_m, 6), "grid_z_m": round(self.grid_z, 6),
                "takeoff": [round(c, 6) for c in self.takeoff]}

    def line(self) -> str:
        heights = ", ".join(f"{z:.1f}" for z in self.orbit_heights)
        return (f"flight: {len(self.orbit_heights)} orbit{'s' if len(self.orbit_heights) != 1 else ''} at z = "
                f"{heights} m, {self.grid_lines} grid lines {self.grid_spacing_m:.1f} m apart at z = "
                f"{self.grid_z:.1f} m; {self.length_m:,.0f} m in {self.duration_s:,.0f} s")


def ground_level(vertices_z_min: float, storey_elevations: tuple[float, ...]) -> float:
    """The ground's height, ``GROUND_BELOW_FLOOR_M`` below the ground floor so that the ground lies
    inside its slab: the ground floor is the storey nearest elevation 0 when one lies within
    ``GROUND_FLOOR_NEAR_ZERO_M`` of it (a basement's storey is below), else the lowest storey at or
    above the model's lowest point (a model placed at its absolute height), else that lowest point."""
    candidates = [e for e in storey_elevations if e >= vertices_z_min - 1e-6]
    near_zero = [e for e in candidates if abs(e) <= GROUND_FLOOR_NEAR_ZERO_M]
    floor = min(near_zero, key=abs) if near_zero else min(candidates) if candidates else vertices_z_min
    return floor - GROUND_BELOW_FLOOR_M


def footprint_hull(xy: np.ndarray) -> np.ndarray:
    """(H, 2) the convex hull of plan points, counter-clockwise."""
    points = np.unique(np.round(np.asarray(xy, dtype=np.float64), 6), axis=0)
    if len(points) < 3:
        raise StationError("the model has no footprint to fly around (fewer than three distinct plan points)")
    try:
        hull = ConvexHull(points)
    except QhullError as exc:  # all points on a line
        raise StationError("the model's plan is a line, not a footprint; a flight needs a building with an area") from exc
    return points[hull.vertices]  # qhull gives 2-D hulls counter-clockwise


def grown_ring(hull: np.ndarray, distance: float) -> np.ndarray:
    """(R, 2) the hull grown by ``distance`` (its corners rounded), counter-clockwise, not closed."""
    angles = np.linspace(0.0, 2 * math.pi, 4 * RING_ARC_STEPS, endpoint=False)
    circle = np.column_stack([np.cos(angles), np.sin(angles)]) * distance
    return footprint_hull((hull[:, None, :] + circle[None, :, :]).reshape(-1, 2))


def min_area_rectangle(hull: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The hull's minimum-area enclosing rectangle: its centre (2,), its long axis (2,) unit and its
    extents (length along the long axis, width)."""
    best = None
    edges = np.diff(np.vstack([hull, hull[:1]]), axis=0)
    for edge in edges:
        norm = float(np.hypot(*edge))
        if norm < 1e-9:
            continue
        u = edge / norm
        v = np.array([-u[1], u[0]])
        a, b = hull @ u, hull @ v
        area = (a.max() - a.min()) * (b.max() - b.min())
        if best is None or area < best[0]:
            centre = u * (a.max() + a.min()) / 2 + v * (b.max() + b.min()) / 2
            extents = np.array([a.max() - a.min(), b.max() - b.min()])
            best = (area, centre, u, extents)
    _, centre, u, extents = best
    if extents[1] > extents[0]:  # the long side first
        u, extents = np.array([-u[1], u[0]]), extents[::-1]
    return centre, u, extents


class _Path:
    """Waypoints of a flight with yaw and pitch, timed as they are appended."""

    def __init__(self, start: np.ndarray, yaw: float, pitch: float, settings: FlightSettings) -> None:
        self.settings = settings
        self.t, self.xyz, self.yaw, self.pitch = [0.0], [np.asarray(start, dtype=np.float64)], [yaw], [pitch]

    def _turned(self, yaw: float) -> float:
        """``yaw`` as the nearest equivalent to the current yaw (turning the short way)."""
        return self.yaw[-1] + (yaw - self.yaw[-1] + math.pi) % (2 * math.pi) - math.pi

    def turn(self, yaw: float, pitch: float) -> None:
        """Turn on the spot (yaw at the turn rate; the gimbal's pitch meanwhile)."""
        yaw = self._turned(yaw)
        swing = max(abs(yaw - self.yaw[-1]), abs(pitch - self.pitch[-1]))
        if swing < 1e-9:
            return
        self.t.append(self.t[-1] + swing / math.radians(self.settings.max_turn_deg_per_s))
        self.xyz.append(self.xyz[-1].copy())
        self.yaw.append(yaw)
        self.pitch.append(pitch)

    def go(self, target: np.ndarray, yaw: float, pitch: float, *, vertical: bool = False) -> None:
        """Fly straight to ``target`` (sampled every ``sample_m``), facing ``yaw`` and tilted
        ``pitch`` on arrival (turning on the way, no faster than the turn rate)."""
        target = np.asarray(target, dtype=np.float64)
        length = float(np.linalg.norm(target - self.xyz[-1]))
        if length < 1e-9:
            self.turn(yaw, pitch)
            return
        speed = self.settings.climb_speed_m_s if vertical else self.settings.speed_m_s
        yaw = self._turned(yaw)
        seconds = length / speed
        swing = max(abs(yaw - self.yaw[-1]), abs(pitch - self.pitch[-1]))
        seconds = max(seconds, swing / math.radians(self.settings.max_turn_deg_per_s))
        steps = max(1, int(math.ceil(length / self.settings.sample_m)))
        start, t0, yaw0, pitch0 = self.xyz[-1], self.t[-1], self.yaw[-1], self.pitch[-1]
        for k in range(1, steps + 1):
            f = k / steps
            self.t.append(t0 + f * seconds)
            self.xyz.append(start + f * (target - start))
            self.yaw.append(yaw0 + f * (yaw - yaw0))
            self.pitch.append(pitch0 + f * (pitch - pitch0))

    def trajectory(self) -> Trajectory:
        n = len(self.t)
        return Trajectory(t=np.asarray(self.t), xyz=np.asarray(self.xyz), roll=np.zeros(n),
                          pitch=np.asarray(self.pitch), yaw=np.asarray(self.yaw), pass_id=np.zeros(n, dtype=np.int32))


def plan_flight(plan_xy: np.ndarray, z_range: tuple[float, float], storey_elevations: tuple[float, ...],
                settings: FlightSettings, half_extent_deg: tuple[float, float],
                obstacles: np.ndarray | None = None) -> tuple[Trajectory, FlightReport]:
    """The flight over a building (see the module docs). plan_xy: (N, 2) the model's vertices in plan;
    z_range: its lowest and highest point; half_extent_deg: the lidar's half-extent along its sensor
    x and y axes (degrees; ``lidar_half_extent_deg``); obstacles: (M, 3) vertices of what stands
    around the building (the yard's objects): orbits pass ``OBSTACLE_CLEARANCE_M`` over those
    within ``OBSTACLE_BAND_M`` of their ring, and the take-off point is the first around the ring
    with none within ``OBSTACLE_BAND_M``."""
    ground = ground_level(z_range[0], storey_elevations)
    top = z_range[1]
    hull = footprint_hull(plan_xy)
    ring = grown_ring(hull, settings.orbit_clearance_m)
    half_x, half_y = (math.radians(min(a, 80.0)) for a in half_extent_deg)
    obstacles = np.zeros((0, 3)) if obstacles is None else np.asarray(obstacles, dtype=np.float64)
    # orbits: evenly over the facade's height, each covering its band with the overlap, none lower than
    # MIN_HEIGHT_M above the ground or OBSTACLE_CLEARANCE_M above what stands under the ring
    near_ring = _distance_to_ring(obstacles[:, :2], ring) <= OBSTACLE_BAND_M
    lowest = max(ground + MIN_HEIGHT_M, float(obstacles[near_ring, 2].max()) + OBSTACLE_CLEARANCE_M
                 if near_ring.any() else -math.inf)
    height = max(top - ground, 0.0)
    band = 2 * settings.orbit_clearance_m * math.tan(half_x) * (1 - settings.orbit_overlap)
    count = max(1, int(math.ceil(height / max(band, 1e-3))))
    heights = tuple(float(z) for z in np.unique(np.round(
        [max(ground + height * (k + 0.5) / count, lowest) for k in range(count)], 6)))
    # the ring's normals point in (the left normal of a counter-clockwise ring); it starts at the first
    # vertex whose take-off point, outside it, is clear of obstacles
    tangent = np.roll(ring, -1, axis=0) - ring
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    outward_all = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    start = 0
    for k in range(len(ring)):
        spot = ring[k] + outward_all[k] * settings.takeoff_offset_m
        if not len(obstacles) or np.hypot(*(obstacles[:, :2] - spot).T).min() > OBSTACLE_BAND_M:
            start = k
            break
    ring, tangent, outward_all = (np.roll(a, -start, axis=0) for a in (ring, tangent, outward_all))
    inward_yaw = np.arctan2(-outward_all[:, 1], -outward_all[:, 0])
    takeoff = np.array([*(ring[0] + outward_all[0] * settings.takeoff_offset_m), ground + TAKEOFF_HEIGHT_M])
    orbit_pitch, grid_pitch = math.radians(settings.orbit_pitch_deg), math.radians(settings.grid_pitch_deg)
    path = _Path(takeoff, float(inward_yaw[0]), orbit_pitch, settings)
    path.go(np.array([takeoff[0], takeoff[1], heights[0]]), float(inward_yaw[0]), orbit_pitch, vertical=True)
    for index, z in enumerate(heights):  # to the ring from the take-off point, then up the ring's first point
        path.go(np.array([ring[0, 0], ring[0, 1], z]), float(inward_yaw[0]), orbit_pitch, vertical=index > 0)
        for k in range(1, len(ring) + 1):  # each side flown facing its own normal, turning at its end
            i = k % len(ring)
            path.go(np.array([ring[i, 0], ring[i, 1], z]), float(inward_yaw[k - 1]), orbit_pitch)
            path.turn(float(inward_yaw[i]), orbit_pitch)
    # the grid, over the rectangle grown by the clearance
    grid_z = top + settings.grid_height_m
    centre, u, extents = min_area_rectangle(hull)
    v = np.array([-u[1], u[0]])
    length, width = extents + 2 * settings.orbit_clearance_m
    spacing = 2 * settings.grid_height_m * math.tan(half_y) * (1 - settings.side_overlap)
    lines = max(1, int(math.ceil(width / max(spacing, 1e-3))) + 1)
    offsets = (np.arange(lines) - (lines - 1) / 2) * (width / max(lines - 1, 1) if lines > 1 else 0.0)
    path.go(np.array([ring[0, 0], ring[0, 1], grid_z]), float(inward_yaw[0]), grid_pitch, vertical=True)
    for k, offset in enumerate(offsets):
        direction = u if k % 2 == 0 else -u
        start = centre + v * offset - direction * length / 2
        end = centre + v * offset + direction * length / 2
        heading = math.atan2(direction[1], direction[0])
        path.go(np.array([*start, grid_z]), heading, grid_pitch)
        path.go(np.array([*end, grid_z]), heading, grid_pitch)
    home_yaw = path.yaw[-1]
    path.go(np.array([takeoff[0], takeoff[1], grid_z]), home_yaw, grid_pitch)
    path.go(takeoff, home_yaw, grid_pitch, vertical=True)
    trajectory = path.trajectory()
    report = FlightReport(orbit_heights=heights, grid_lines=lines, grid_spacing_m=float(width / max(lines - 1, 1)),
                          grid_z=float(grid_z), takeoff=tuple(float(c) for c in takeoff),
                          length_m=trajectory.length_m(), duration_s=trajectory.duration_s())
    return trajectory, report


def _distance_to_ring(points: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """(N,) plan distance of each point to the closed polygon ``ring``'s edges."""
    if len(points) == 0:
        return np.zeros(0)
    a, b = ring, np.roll(ring, -1, axis=0)
    ab = b - a
    t = np.clip(((points[:, None, :] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points[:, None, :] - (a + t[..., None] * ab), axis=-1).min(axis=1)


def check_pointable(lidar: Lidar) -> RisleyScanner:
    """The lidar, when a flight can point it; ConfigError for a spinning multi-beam lidar (the drone's
    gimbal points an optical axis), or a Risley lidar on a spinning head (the Livox Mid-360's)."""
    if not isinstance(lidar, RisleyScanner) or lidar.spinning:
        what = "a spinning multi-beam lidar" if not isinstance(lidar, RisleyScanner) else "a Risley lidar on a spinning head"
        raise ConfigError(f"a drone flight points a Risley-prism lidar's optical axis; {getattr(lidar, 'name', lidar)} "
                          f"is {what}: give --scanner dji_zenmuse_l2, livox_avia, livox_mid70 or another Risley lidar")
    return lidar


@functools.lru_cache(maxsize=16)
def lidar_half_extent_deg(lidar: Lidar) -> tuple[float, float]:
    """A Risley lidar's pattern half-extents along its sensor x and y axes (degrees; measured once per
    lidar: a second of its pulses); ConfigError as ``check_pointable``."""
    x, y = check_pointable(lidar).pattern_extent_deg()
    return x / 2, y / 2

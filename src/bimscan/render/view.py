"""Orthographic cameras fitted to a box, and the section height that opens a building from above.

A ``Camera`` looks at the scene from ``azimuth_deg`` (in the XY plane, counter-clockwise from
+X) and ``elevation_deg`` above the horizon (90: straight down, X to the right and Y up on the
screen) and maps world points to pixels so that a given box fills the image.

A terrestrial scan of a building is taken from inside: seen from above, its ceilings hide
everything. ``find_section`` finds, from the heights of a cloud's points, the top storey's
floor and ceiling, so a top view can show a floor plan (a band up to 1.5 m above the floor)
and an oblique view the rooms opened from above (everything under the ceiling).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TOP = (-90.0, 90.0)  # (azimuth, elevation) of the plan view
OBLIQUE = (-60.0, 38.0)  # from the south-south-east, looking down


@dataclass(frozen=True)
class Camera:
    """An orthographic camera; ``project`` maps (N, 3) world metres to pixels and depth."""

    azimuth_deg: float
    elevation_deg: float
    width: int
    height: int
    scale: float  # pixels per metre
    centre_screen: tuple[float, float]  # screen coordinates (metres) of the image centre

    @staticmethod
    def basis(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
        """(3, 3) rows: screen right, screen up, towards the camera (all unit vectors)."""
        a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
        towards = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        right = np.array([-math.sin(a), math.cos(a), 0.0])
        up = np.cross(towards, right)
        return np.stack([right, up, towards])

    @staticmethod
    def fit(low: np.ndarray, high: np.ndarray, *, azimuth_deg: float, elevation_deg: float, width: int, height: int,
            margin: float = 0.04) -> Camera:
        """A camera whose image (width x height pixels) holds the box [low, high] (metres) with a margin."""
        corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])
        screen = corners @ Camera.basis(azimuth_deg, elevation_deg)[:2].T
        span = np.maximum(screen.max(axis=0) - screen.min(axis=0), 1e-6)
        usable = np.array([width, height], dtype=np.float64) * (1 - 2 * margin)
        scale = float(np.min(usable / span))
        centre = (screen.max(axis=0) + screen.min(axis=0)) / 2
        return Camera(azimuth_deg, elevation_deg, int(width), int(height), scale, (float(centre[0]), float(centre[1])))

    def project(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel x (N,), pixel y (N,) (down) and depth (N,) (smaller = nearer) of world points (N, 3)."""
        basis = self.basis(self.azimuth_deg, self.elevation_deg)
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        # column by column: a (N, 3) @ (3, 3) product is far slower for millions of rows
        right, up, towards = ((x * b[0] + y * b[1] + z * b[2]) for b in basis)
        sx = (right - self.centre_screen[0]) * self.scale + self.width / 2
        sy = self.height / 2 - (up - self.centre_screen[1]) * self.scale
        return sx, sy, -towards

    @property
    def towards(self) -> np.ndarray:
        """(3,) unit vector from the scene towards the camera."""
        return self.basis(self.azimuth_deg, self.elevation_deg)[2]


@dataclass(frozen=True)
class Section:
    """Where to cut a building cloud to look into its top storey (world heights in metres).

    floor_z: the top storey's floor. plan_z: the plan cut, 1.5 m above it (top views show the
    band from just under the floor up to here, as a floor plan does). ceiling_z: just under the
    storey's ceiling (oblique views show everything below it: whole walls, rooms open from above).
    """

    floor_z: float
    plan_z: float
    ceiling_z: float


def find_section(z: np.ndarray, *, bin_m: float = 0.05, plan_above_floor_m: float = 1.5) -> Section | None:
    """The top storey's section of a cloud from its point heights, or None when it has no storeys.

    Horizontal surfaces (floors, ceilings) are heights where points pile up (at least three
    times the median count of a 5 cm height bin). The top storey's floor is the highest such
    layer at least 2 m below the highest one that holds at least 30 % of the points of the
    fullest of them (table tops are layers too, but small ones); its ceiling is the lowest layer
    at least 2 m above the floor.
    """
    z = np.asarray(z, dtype=np.float64)
    z = z[np.isfinite(z)]
    if len(z) < 100:
        return None
    low, high = float(z.min()), float(z.max())
    if high - low < 2.5:
        return None
    counts, edges = np.histogram(z, bins=max(1, int(math.ceil((high - low) / bin_m))), range=(low, high))
    dense = np.flatnonzero(counts >= 3 * np.median(counts[counts > 0]))
    if len(dense) == 0:
        return None
    layers = ((edges[:-1] + edges[1:]) / 2)[dense]
    weights = counts[dense]
    low_enough = layers <= layers[-1] - 2.0
    if not low_enough.any():
        return None
    # a floor spans a storey: furniture tops pile up points too, but far fewer
    floors = layers[low_enough & (weights >= 0.3 * weights[low_enough].max())]
    floor = float(floors.max())
    ceiling = float(layers[layers >= floor + 2.0].min())
    return Section(floor_z=floor, plan_z=min(floor + plan_above_floor_m, ceiling - 0.3), ceiling_z=ceiling - 2 * bin_m)

"""The ground around a building: a flat terrain patch, so that a scan from outside (a drone's) sees a
site, not a building floating in the air.

The patch is a grid of square cells (``GROUND_CELL_M``; small triangles keep the ray engine's
bounds tight and renders even) covering the model's minimum-area plan rectangle grown by the
margin, at ``survey.flight.ground_level``: the ground floor's elevation less 5 cm, so that the
patch runs inside the ground floor's slab and no scan from indoors sees it. It is one component
of class ``Terrain.Ground`` (an IfcBuildingElementProxy by its IFC class; labelled Others by the
SPC scheme).

The yard (``yard_objects``): site objects standing on that ground around the building, as a
contractor's yard has them: site containers (ISO 668, 10 and 20 ft), material stacks, pallets,
waste bins, cable drums and scaffold towers (the clutter library's objects and sizes), drawn by
the weights of ``YARD_KINDS``, ``density`` objects per 100 m2 of ground outside the building's
footprint grown by ``YARD_CLEARANCE_M``, each at a random spot and heading where it overlaps no
other (a spot tried ``YARD_TRIES`` times at most), seeded by the scene and the seed.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
from matplotlib.path import Path as PolygonPath
from scipy.spatial import ConvexHull

from bimscan.site.placement import PlacedObject
from bimscan.types import BimScene

GROUND_CELL_M = 5.0
YARD_CLEARANCE_M = 2.0  # objects keep this far from the footprint (a path around the building)
YARD_TRIES = 30
# kind -> weight among the yard's objects (the library's kinds, and the site container)
YARD_KINDS = {"container": 0.4, "material_stack": 2.0, "pallet": 1.0, "waste_bin": 0.7, "cable_drum": 0.5,
              "scaffold_tower": 0.5}


def _site_plan(scene: BimScene) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The ground's height, the footprint's hull and its minimum-area rectangle (centre, long axis,
    extents) of the (undressed) building ``scene``."""
    from bimscan.survey.flight import footprint_hull, ground_level, min_area_rectangle

    vertices = scene.mesh.vertices
    z = ground_level(float(vertices[:, 2].min()), tuple(s.elevation_m for s in scene.storeys))
    hull = footprint_hull(vertices[:, :2])
    return (z, hull, *min_area_rectangle(hull))


def ground_patch(scene: BimScene, margin_m: float) -> PlacedObject:
    """The terrain patch of ``scene`` reaching ``margin_m`` beyond its footprint (see the module docs)."""
    z, _, centre, u, extents = _site_plan(scene)
    v = np.array([-u[1], u[0]])
    length, width = extents + 2 * margin_m
    nu, nv = max(1, math.ceil(length / GROUND_CELL_M)), max(1, math.ceil(width / GROUND_CELL_M))
    a = np.linspace(-length / 2, length / 2, nu + 1)
    b = np.linspace(-width / 2, width / 2, nv + 1)
    aa, bb = np.meshgrid(a, b, indexing="ij")
    xy = centre + aa.reshape(-1, 1) * u + bb.reshape(-1, 1) * v
    grid = np.column_stack([xy, np.full(len(xy), z)])
    index = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    p00, p10, p01, p11 = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([p00, p10, p11]), np.column_stack([p00, p11, p01])]).astype(np.int32)
    corners = centre + np.array([[-length / 2, -width / 2], [length / 2, -width / 2], [length / 2, width / 2],
                                 [-length / 2, width / 2]]) @ np.vstack([u, v])
    return PlacedObject(kind="ground", class_name="Terrain.Ground", room="site", room_key="site", storey="",
                        vertices=grid, faces=faces, footprint=corners, base_z=float(z))


def yard_objects(scene: BimScene, margin_m: float, density: float, seed: int) -> list[PlacedObject]:
    """Site objects on the ground around the building (see the module docs), as placed objects."""
    from bimscan.site.library import CLUTTER_KINDS, make_site_container
    from bimscan.survey.flight import grown_ring

    z, hull, centre, u, extents = _site_plan(scene)
    ring = grown_ring(hull, YARD_CLEARANCE_M)
    keep_out = PolygonPath(ring)
    v = np.array([-u[1], u[0]])
    length, width = extents + 2 * margin_m
    area = length * width - ConvexHull(ring).volume  # a 2-D hull's volume is its area
    count = int(round(density * max(area, 0.0) / 100.0))
    rng = np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(scene.file_sha256.encode()), 0x79617264]))
    names = list(YARD_KINDS)
    weights = np.array([YARD_KINDS[name] for name in names])
    placed: list[PlacedObject] = []
    discs: list[tuple[float, float, float]] = []  # x, y, radius of what stands already
    for _ in range(count):
        name = names[int(rng.choice(len(names), p=weights / weights.sum()))]
        made = make_site_container(rng, 10.0, False) if name == "container" else CLUTTER_KINDS[name].make(rng, 10.0, False)
        if made is None:
            continue
        radius = math.hypot(made.size_m[0], made.size_m[1]) / 2
        for _try in range(YARD_TRIES):
            a = rng.uniform(-length / 2 + radius, length / 2 - radius)
            b = rng.uniform(-width / 2 + radius, width / 2 - radius)
            x, y = centre + a * u + b * v
            yaw = rng.uniform(0.0, 2 * math.pi)
            c, s_ = math.cos(yaw), math.sin(yaw)
            w, d = made.size_m[0] / 2, made.size_m[1] / 2
            corners = np.array([[x + c * px - s_ * py, y + s_ * px + c * py] for px, py in ((-w, -d), (w, -d), (w, d), (-w, d))])
            if keep_out.contains_points(corners).any() or keep_out.contains_point((x, y)):
                continue
            if any(math.hypot(x - ox, y - oy) < radius + orad for ox, oy, orad in discs):
                continue
            local = made.vertices
            world = np.column_stack([x + c * local[:, 0] - s_ * local[:, 1], y + s_ * local[:, 0] + c * local[:, 1],
                                     z + local[:, 2]])
            placed.append(PlacedObject(kind=name, class_name=made.class_name, room="yard", room_key="yard", storey="",
                                       vertices=world, faces=made.faces, footprint=corners, base_z=float(z)))
            discs.append((float(x), float(y), radius))
            break
    return placed

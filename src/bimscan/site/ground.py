"""The ground around a building: a flat terrain patch, so that a scan from outside (a drone's) sees a
site, not a building floating in the air.

The patch is a grid of square cells (``GROUND_CELL_M``; small triangles keep the ray engine's
bounds tight and renders even) covering the model's minimum-area plan rectangle grown by the
margin, at ``survey.flight.ground_level``: the ground floor's elevation less 5 cm, so that the
patch runs inside the ground floor's slab and no scan from indoors sees it. It is one component
of class ``Terrain.Ground`` (an IfcBuildingElementProxy by its IFC class; labelled Others by the
SPC scheme).
"""

from __future__ import annotations

import math

import numpy as np

from bimscan.site.placement import PlacedObject
from bimscan.types import BimScene

GROUND_CELL_M = 5.0


def ground_patch(scene: BimScene, margin_m: float) -> PlacedObject:
    """The terrain patch of ``scene`` reaching ``margin_m`` beyond its footprint (see the module docs)."""
    from bimscan.survey.flight import footprint_hull, ground_level, min_area_rectangle

    vertices = scene.mesh.vertices
    z = ground_level(float(vertices[:, 2].min()), tuple(s.elevation_m for s in scene.storeys))
    centre, u, extents = min_area_rectangle(footprint_hull(vertices[:, :2]))
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

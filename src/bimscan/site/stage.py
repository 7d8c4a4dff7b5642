"""Construction stages: which components are built, and partial states of the building.

An element is built at a stage when its class descends from one of the stage's classes; an
element that is part of an aggregate (a stair's flights and railings, a curtain wall's panels, a
door's lining) follows the aggregate's class. ``exclude`` takes classes out (own or aggregate).
With a work schedule (``types.BuildDates`` per GlobalId) and a date, an element whose
construction task finishes after the date, or whose demolition finished on or before it, is not
there; elements no task names are there.

Partial states, each seeded by the element's GlobalId (so the same element is chosen whatever
else the model holds, and a larger fraction removes a superset):

- walls not yet built: a fraction of the walls left out, with the doors and windows in them;
- ceilings open between grid lines: the ceiling coverings (PredefinedType CEILING) cut along
  the structural grid (the lines through the column centres; without columns the 0.6 m module
  of suspended ceiling tiles, EN 13964) and a fraction of the bays left without panels.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping

import numpy as np

from bimscan.site.floor import component_bounds, component_mask
from bimscan.site.model import StageSettings
from bimscan.types import BimScene, BuildDates, SceneMesh

CEILING_MODULE_M = 0.6  # suspended ceiling tiles, 600 x 600 mm (EN 13964)
GRID_TOLERANCE_M = 0.3  # column centres this close lie on one grid line
# aggregates whose parts are built with them (IFC2X3/IFC4 IfcBuildingElement, IFC4X3 IfcBuiltElement)
PART_OWNERS = ("IfcBuildingElement", "IfcBuiltElement", "IfcFurnishingElement")


def unit_draw(*parts: object) -> float:
    """A number in [0, 1) fixed by ``parts`` (SHA-256), the same on every machine."""
    digest = hashlib.sha256(":".join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def built_components(scene: BimScene, stage: StageSettings, *, seed: int,
                     schedule: Mapping[str, BuildDates] | None = None) -> np.ndarray:
    """(C,) bool: the components standing at ``stage`` (see the module docs)."""
    components = scene.components
    n = len(components)
    keep = np.ones(n, dtype=bool)
    classes = stage.kept_classes()
    if classes is not None:
        own = component_mask(scene, classes)
        parents = components.parent_class.tolist()
        # parts of a building element (a stair, a curtain wall, a door) follow it; members of a
        # mere assembly (IfcElementAssembly) go by their own class
        parent_decides = np.array([_descends(scene, p, PART_OWNERS) for p in parents], dtype=bool)
        parent_kept = np.array([_descends(scene, p, classes) for p in parents], dtype=bool)
        keep = np.where(parent_decides, parent_kept, own)
    if stage.exclude:
        keep &= ~component_mask(scene, stage.exclude, parents=True)
    if stage.at is not None and schedule:
        keep &= _standing_at(components.global_id.tolist(), schedule, stage.at)
    if stage.walls_missing_fraction > 0:
        keep &= ~_missing_walls(scene, keep, stage.walls_missing_fraction, seed)
    return keep


def _descends(scene: BimScene, cls: str, classes: tuple[str, ...]) -> bool:
    if not cls:
        return False
    wanted = {c.lower() for c in classes}
    return any(a.lower() in wanted for a in scene.components.class_ancestry.get(cls, (cls,)))


def _standing_at(global_ids: list[str], schedule: Mapping[str, BuildDates], at: str) -> np.ndarray:
    out = np.ones(len(global_ids), dtype=bool)
    for i, gid in enumerate(global_ids):
        dates = schedule.get(gid)
        if dates is None:
            continue
        if dates.built is not None and dates.built > at:
            out[i] = False
        if dates.removed is not None and dates.removed <= at:
            out[i] = False
    return out


def _missing_walls(scene: BimScene, keep: np.ndarray, fraction: float, seed: int) -> np.ndarray:
    """Walls not yet built (by GlobalId draw), and the doors and windows standing in them."""
    walls = component_mask(scene, ("IfcWall",)) & keep
    gids = scene.components.global_id
    missing = np.array([walls[i] and unit_draw(seed, "wall", gids[i]) < fraction for i in range(len(gids))],
                       dtype=bool)
    if not missing.any():
        return missing
    lo, hi = component_bounds(scene.mesh, len(gids))
    fillings = np.flatnonzero(component_mask(scene, ("IfcDoor", "IfcWindow"), parents=True) & keep)
    for wall in np.flatnonzero(missing):
        inside = ((lo[fillings] <= hi[wall] + 0.05) & (hi[fillings] >= lo[wall] - 0.05)).all(axis=1)
        missing[fillings[inside]] = True
    return missing


def open_ceilings(scene: BimScene, keep: np.ndarray, fraction: float, seed: int) -> SceneMesh:
    """The scene's mesh with the ceilings cut along the grid and a fraction of their bays removed."""
    components = scene.components
    ceilings = ceiling_coverings(scene) & keep
    mesh = scene.mesh
    if fraction <= 0 or not ceilings.any():
        return mesh
    xs, ys = _grid_lines(scene, keep, ceilings)
    is_ceiling = ceilings[mesh.face_component]
    pieces: list[tuple[np.ndarray, int]] = []
    for f in np.flatnonzero(is_ceiling):
        component = int(mesh.face_component[f])
        triangle = mesh.vertices[mesh.faces[f]]
        for bx0, bx1, ix in _bays(xs, triangle[:, 0]):
            for by0, by1, iy in _bays(ys, triangle[:, 1]):
                if unit_draw(seed, "bay", components.global_id[component], ix, iy) < fraction:
                    continue  # an open bay: no panel here
                polygon = _clip(triangle, bx0, bx1, by0, by1)
                if len(polygon) >= 3:
                    pieces.append((polygon, component))
    return _replace_faces(mesh, is_ceiling, pieces)


def _replace_faces(mesh: SceneMesh, removed: np.ndarray, pieces: list[tuple[np.ndarray, int]]) -> SceneMesh:
    """The mesh less the ``removed`` faces ((F,) bool), plus each piece (a convex polygon (k, 3) of
    its component) as a fan of triangles, in order."""
    new_faces: list[np.ndarray] = []
    new_component: list[int] = []
    count = len(mesh.vertices)
    for polygon, component in pieces:
        for k in range(1, len(polygon) - 1):
            new_faces.append(np.array([count, count + k, count + k + 1]))
            new_component.append(component)
        count += len(polygon)
    kept = ~removed
    faces = np.concatenate([mesh.faces[kept]] + ([np.array(new_faces, dtype=np.int32)] if new_faces else []))
    return SceneMesh(
        vertices=np.concatenate([mesh.vertices] + [p for p, _ in pieces]) if pieces else mesh.vertices,
        faces=faces.astype(np.int32),
        face_component=np.concatenate([mesh.face_component[kept], np.array(new_component, dtype=np.int32)]),
    )


def ceiling_coverings(scene: BimScene) -> np.ndarray:
    """(C,) bool: the ceiling coverings (IfcCovering, PredefinedType CEILING)."""
    return component_mask(scene, ("IfcCovering",)) & np.array(
        [t.upper() == "CEILING" for t in scene.components.predefined_type.tolist()], dtype=bool)


def cut_openings(mesh: SceneMesh, cut: np.ndarray, openings: list[np.ndarray]) -> SceneMesh:
    """The mesh with vertical rectangular openings cut through the components in ``cut`` ((C,) bool):
    every opening is a rectangle of 4 world xy corners (in order, any orientation), and each of
    those components' triangles that it meets is replaced by the parts of it outside the opening
    (a ceiling tile's underside and top alike, so a fitting set into it is seen through it)."""
    if not openings or not cut.any():
        return mesh
    rects = []
    for corners in openings:
        edge = corners[1] - corners[0]
        angle = float(np.arctan2(edge[1], edge[0]))
        c, s = np.cos(angle), np.sin(angle)
        to_local = np.array([[c, s], [-s, c]])  # world xy -> the rectangle's axes
        local = corners @ to_local.T
        rects.append((to_local, local.min(axis=0), local.max(axis=0), corners.min(axis=0), corners.max(axis=0)))
    candidates = np.flatnonzero(cut[mesh.face_component])
    corners3 = mesh.vertices[mesh.faces[candidates]]
    lo, hi = corners3[:, :, :2].min(axis=1), corners3[:, :, :2].max(axis=1)
    meets = np.zeros(len(candidates), dtype=bool)
    for _, _, _, rlo, rhi in rects:
        meets |= ((lo < rhi) & (hi > rlo)).all(axis=1)
    pieces: list[tuple[np.ndarray, int]] = []
    for j in np.flatnonzero(meets):
        parts = [corners3[j]]
        for to_local, (x0, y0), (x1, y1), rlo, rhi in rects:
            if (lo[j] >= rhi).any() or (hi[j] <= rlo).any():
                continue
            outside = []
            for part in parts:
                local = part.copy()
                local[:, :2] = part[:, :2] @ to_local.T
                for bounds in ((-np.inf, x0, -np.inf, np.inf), (x1, np.inf, -np.inf, np.inf),
                               (x0, x1, -np.inf, y0), (x0, x1, y1, np.inf)):
                    piece = _clip(local, *bounds)
                    if len(piece) >= 3:
                        piece[:, :2] = piece[:, :2] @ to_local  # back to world xy
                        outside.append(piece)
            parts = outside
        component = int(mesh.face_component[candidates[j]])
        pieces += [(part, component) for part in parts]
    removed = np.zeros(len(mesh.faces), dtype=bool)
    removed[candidates[meets]] = True
    return _replace_faces(mesh, removed, pieces)


def _grid_lines(scene: BimScene, keep: np.ndarray, ceilings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted x and y of the grid lines: through the column centres, else the ceiling tile module."""
    lo, hi = component_bounds(scene.mesh, len(scene.components))
    columns = np.flatnonzero(component_mask(scene, ("IfcColumn",)) & np.isfinite(lo).all(axis=1))
    lines = []
    for axis in (0, 1):
        centres = np.sort((lo[columns, axis] + hi[columns, axis]) / 2)
        merged: list[float] = []
        for c in centres:
            if not merged or c - merged[-1] > GRID_TOLERANCE_M:
                merged.append(float(c))
        if len(merged) < 2:
            start = float(lo[ceilings, axis].min())
            merged = list(np.arange(start, float(hi[ceilings, axis].max()) + CEILING_MODULE_M, CEILING_MODULE_M))
        lines.append(np.array(merged))
    return lines[0], lines[1]


def _bays(lines: np.ndarray, values: np.ndarray) -> list[tuple[float, float, int]]:
    """The bays (low, high, index) between grid lines that the span of ``values`` meets."""
    edges = np.concatenate([[-np.inf], lines, [np.inf]])
    first = int(np.searchsorted(edges, values.min(), side="right")) - 1
    last = int(np.searchsorted(edges, values.max(), side="left")) - 1
    return [(float(edges[k]), float(edges[k + 1]), k) for k in range(max(first, 0), min(last, len(edges) - 2) + 1)]


def _clip(polygon: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a 3-D polygon (k, 3) to the vertical prism x0..x1, y0..y1."""
    for axis, bound, keep_below in ((0, x0, False), (0, x1, True), (1, y0, False), (1, y1, True)):
        if not np.isfinite(bound) or len(polygon) == 0:
            continue
        out = []
        for k in range(len(polygon)):
            a, b = polygon[k], polygon[(k + 1) % len(polygon)]
            a_in = a[axis] <= bound if keep_below else a[axis] >= bound
            b_in = b[axis] <= bound if keep_below else b[axis] >= bound
            if a_in:
                out.append(a)
            if a_in != b_in:
                t = (bound - a[axis]) / (b[axis] - a[axis])
                out.append(a + t * (b - a))
        polygon = np.array(out) if out else np.zeros((0, 3))
    return polygon

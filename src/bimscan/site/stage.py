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
from bimscan.site.polygons import Polygons
from bimscan.types import BimScene, BuildDates, SceneMesh

CEILING_MODULE_M = 0.6  # suspended ceiling tiles, 600 x 600 mm (EN 13964)
GRID_TOLERANCE_M = 0.3  # column centres this close lie on one grid line
MIN_CUT_AREA_M2 = 1e-10  # a piece that reaches into an opening by less than this (it touches an edge) stays whole
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
    faces = np.flatnonzero(is_ceiling)
    triangles = mesh.vertices[mesh.faces[faces]]
    # every (triangle, bay) pair the triangle's span meets, triangle by triangle, x bays outer
    x_first, x_count = _bay_spans(xs, triangles[:, :, 0])
    y_first, y_count = _bay_spans(ys, triangles[:, :, 1])
    pair_face = np.repeat(np.arange(len(faces)), x_count * y_count)
    rank = np.arange(len(pair_face)) - np.repeat(np.cumsum(x_count * y_count) - x_count * y_count, x_count * y_count)
    ix = x_first[pair_face] + rank // y_count[pair_face]
    iy = y_first[pair_face] + rank % y_count[pair_face]
    component = mesh.face_component[faces[pair_face]]
    draws: dict[tuple[int, int, int], bool] = {}
    closed = np.ones(len(pair_face), dtype=bool)
    for k, key in enumerate(zip(component.tolist(), ix.tolist(), iy.tolist())):
        if key not in draws:  # an open bay: no panel here
            draws[key] = unit_draw(seed, "bay", components.global_id[key[0]], key[1], key[2]) >= fraction
        closed[k] = draws[key]
    x_edges, y_edges = np.concatenate([[-np.inf], xs, [np.inf]]), np.concatenate([[-np.inf], ys, [np.inf]])
    pair_face, ix, iy, component = pair_face[closed], ix[closed], iy[closed], component[closed]
    pieces = Polygons.of_triangles(triangles[pair_face]).clip_to_box(x_edges[ix], x_edges[ix + 1], y_edges[iy],
                                                                      y_edges[iy + 1])
    whole = pieces.count >= 3
    return _replace_faces(mesh, is_ceiling, pieces.take(whole), component[whole])


def _bay_spans(lines: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``values`` (N, k), the first bay between grid lines its span meets and how many
    (bays are numbered from 0, the one below the first line)."""
    edges = np.concatenate([[-np.inf], lines, [np.inf]])
    first = np.maximum(np.searchsorted(edges, values.min(axis=1), side="right") - 1, 0)
    last = np.minimum(np.searchsorted(edges, values.max(axis=1), side="left") - 1, len(edges) - 2)
    return first, np.maximum(last - first + 1, 0)


def _replace_faces(mesh: SceneMesh, removed: np.ndarray, pieces: Polygons, component: np.ndarray) -> SceneMesh:
    """The mesh less the ``removed`` faces ((F,) bool), plus each piece (a convex polygon of at least
    3 vertices, of ``component`` (P,)) as a fan of triangles, in order."""
    vertices, faces, polygon = pieces.fan_triangles(len(mesh.vertices))
    kept = ~removed
    return SceneMesh(vertices=np.concatenate([mesh.vertices, vertices]) if len(pieces) else mesh.vertices,
                     faces=np.concatenate([mesh.faces[kept], faces]).astype(np.int32),
                     face_component=np.concatenate([mesh.face_component[kept],
                                                    component[polygon].astype(np.int32)]),
                     face_transparency=mesh.face_transparency_for(kept, added=len(faces)))  # the pieces: no style


def ceiling_coverings(scene: BimScene) -> np.ndarray:
    """(C,) bool: the ceiling coverings (IfcCovering, PredefinedType CEILING)."""
    return component_mask(scene, ("IfcCovering",)) & np.array(
        [t.upper() == "CEILING" for t in scene.components.predefined_type.tolist()], dtype=bool)


def cut_openings(mesh: SceneMesh, cut: np.ndarray, openings: list[np.ndarray]) -> SceneMesh:
    """The mesh with vertical rectangular openings cut through the components in ``cut`` ((C,) bool):
    every opening is a rectangle of 4 world xy corners (in order, any orientation), and each of
    those components' triangles that it overlaps is replaced by the parts of it outside the opening
    (a ceiling tile's underside and top alike, so a fitting set into it is seen through it).

    Openings are cut one after another. An opening cuts only the pieces that reach into it (by
    more than ``MIN_CUT_AREA_M2``), each into at most four (the strips beside the opening and the
    parts before and after it); the other pieces keep their vertices. So a tile holding n fittings
    ends in about 4 n pieces, and the work follows the fittings: openings and triangles are cut in
    groups that share no triangle (a room's ceiling, usually), each group on its own pieces.
    Triangles no opening cuts keep their place; the pieces of the cut ones follow the mesh's faces,
    triangle by triangle in mesh order, each triangle's pieces in the order the cuts left them."""
    if not openings or not cut.any():
        return mesh
    candidates = np.flatnonzero(cut[mesh.face_component])
    corners3 = mesh.vertices[mesh.faces[candidates]]
    lo, hi = corners3[:, :, :2].min(axis=1), corners3[:, :, :2].max(axis=1)
    rects = [_rectangle(corners) for corners in openings]
    opening, triangle = _boxes_meeting(np.array([r[3] for r in rects]), np.array([r[4] for r in rects]), lo, hi)
    pieces: list[Polygons] = []
    owners: list[np.ndarray] = []
    changed = np.zeros(len(candidates), dtype=bool)  # triangles some opening cut
    for group_openings, group_triangles in _linked_groups(opening, triangle, len(rects), len(candidates)):
        parts, owner = Polygons.of_triangles(corners3[group_triangles]), group_triangles
        for o in group_openings:
            parts, source, fresh = _cut_one(parts, rects[o])
            owner = owner[source]
            changed[owner[fresh]] = True
        pieces.append(parts)
        owners.append(owner)
    if not changed.any():
        return mesh
    parts, owner = Polygons.concatenate(pieces), np.concatenate(owners)
    keep = np.flatnonzero(changed[owner])
    keep = keep[np.argsort(owner[keep], kind="stable")]  # by triangle, each one's pieces in their order
    removed = np.zeros(len(mesh.faces), dtype=bool)
    removed[candidates[changed]] = True
    return _replace_faces(mesh, removed, parts.take(keep), mesh.face_component[candidates[owner[keep]]])


def _cut_one(parts: Polygons, rect: tuple[np.ndarray, ...]) -> tuple[Polygons, np.ndarray, np.ndarray]:
    """``parts`` with one opening cut (``_rectangle``'s tuple): every part that reaches into it
    replaced in place by its pieces outside it. Returns the new parts, the part each came from
    (index into ``parts``) and whether it is a new piece."""
    to_local, (x0, y0), (x1, y1), rlo, rhi = rect
    same = (parts, np.arange(len(parts)), np.zeros(len(parts), dtype=bool))
    plo, phi = parts.bounds_xy()
    near = np.flatnonzero(((plo < rhi) & (phi > rlo)).all(axis=1))
    if len(near) == 0:
        return same
    local = parts.take(near).rotated_xy(to_local.T)
    reaches = local.clip_to_box(x0, x1, y0, y1).areas() > MIN_CUT_AREA_M2
    if not reaches.any():
        return same
    hit, local = near[reaches], local.take(reaches)
    inf = np.inf
    regions = [local.clip_to_box(*bounds) for bounds in
               ((-inf, x0, -inf, inf), (x1, inf, -inf, inf), (x0, x1, -inf, y0), (x0, x1, y1, inf))]
    untouched = np.ones(len(parts), dtype=bool)
    untouched[hit] = False
    kept = np.flatnonzero(untouched)
    keys, pieces, sources, fresh = [4 * kept], [parts.take(kept)], [kept], [np.zeros(len(kept), dtype=bool)]
    for r, region in enumerate(regions):
        whole = region.count >= 3
        keys.append(4 * hit[whole] + r)
        pieces.append(region.take(whole).rotated_xy(to_local))
        sources.append(hit[whole])
        fresh.append(np.ones(int(whole.sum()), dtype=bool))
    order = np.argsort(np.concatenate(keys), kind="stable")  # each cut part's pieces take its place
    return Polygons.concatenate(pieces).take(order), np.concatenate(sources)[order], np.concatenate(fresh)[order]


def _boxes_meeting(a_lo: np.ndarray, a_hi: np.ndarray, b_lo: np.ndarray,
                   b_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (a, b) index pairs of xy boxes (rows of (N, 2) low and high corners) that overlap with
    positive area, ordered by a. One comparison per pair, in blocks of rows (bounded memory)."""
    rows: list[np.ndarray] = []
    columns: list[np.ndarray] = []
    block = max(1, 4_000_000 // max(len(b_lo), 1))
    for start in range(0, len(a_lo), block):
        lo, hi = a_lo[start:start + block, None, :], a_hi[start:start + block, None, :]
        meet = ((b_lo[None] < hi) & (b_hi[None] > lo)).all(axis=2)
        r, c = np.nonzero(meet)
        rows.append(r + start)
        columns.append(c)
    return np.concatenate(rows), np.concatenate(columns)


def _linked_groups(a: np.ndarray, b: np.ndarray, n_a: int, n_b: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The connected groups of the pairs (a[k], b[k]) as (sorted a's, sorted b's), items in no pair left out."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(a) == 0:
        return []
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, n_a + b)), shape=(n_a + n_b, n_a + n_b))
    _, label = connected_components(graph, directed=False)
    used = np.zeros(n_a + n_b, dtype=bool)
    used[a] = True
    used[n_a + b] = True
    nodes = np.flatnonzero(used)
    order = nodes[np.argsort(label[nodes], kind="stable")]
    bounds = np.flatnonzero(np.diff(label[order])) + 1
    groups = []
    for members in np.split(order, bounds):  # each group's members in increasing order
        groups.append((members[members < n_a], members[members >= n_a] - n_a))
    return groups


def _rectangle(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """An opening's rectangle of 4 world xy corners as (world -> its axes (2, 2), its low and high
    corners in its axes, its world bounding box low and high)."""
    edge = corners[1] - corners[0]
    angle = float(np.arctan2(edge[1], edge[0]))
    c, s = np.cos(angle), np.sin(angle)
    to_local = np.array([[c, s], [-s, c]])  # world xy -> the rectangle's axes
    local = corners @ to_local.T
    return to_local, local.min(axis=0), local.max(axis=0), corners.min(axis=0), corners.max(axis=0)


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

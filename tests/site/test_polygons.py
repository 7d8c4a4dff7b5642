"""Polygons clipped in bulk give what the one-polygon loop gives: the same pieces, the same area."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from bimscan.site.polygons import Polygons
from bimscan.site.stage import MIN_CUT_AREA_M2, cut_openings
from bimscan.types import SceneMesh


def clip_loop(polygon: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    """The textbook Sutherland-Hodgman clip of one 3-D polygon (k, 3) to a vertical prism: the
    reference the array version must equal."""
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


def polygon_area(polygon: np.ndarray) -> float:
    """The area of one 3-D polygon (k, 3): half the norm of its fan's summed cross products."""
    if len(polygon) < 3:
        return 0.0
    spokes = polygon[1:] - polygon[0]
    return float(np.linalg.norm(np.cross(spokes[:-1], spokes[1:]).sum(axis=0)) / 2)


def cut_loop(mesh: SceneMesh, cut: np.ndarray,
             openings: list[np.ndarray]) -> tuple[list[tuple[np.ndarray, int]], list[int]]:
    """The reference, one triangle, one piece and one opening at a time: an opening cuts a piece
    that reaches into it (the piece clipped to the opening has an area) into its parts outside it,
    and leaves the other pieces as they are. Returns the pieces of the triangles some opening cut,
    triangle by triangle, and those triangles."""
    candidates = np.flatnonzero(cut[mesh.face_component])
    pieces, cut_triangles = [], []
    for f in candidates:
        parts = [mesh.vertices[mesh.faces[f]]]
        was_cut = False
        for corners in openings:
            edge = corners[1] - corners[0]
            angle = float(np.arctan2(edge[1], edge[0]))
            c, s = np.cos(angle), np.sin(angle)
            to_local = np.array([[c, s], [-s, c]])
            local_corners = corners @ to_local.T
            (x0, y0), (x1, y1) = local_corners.min(axis=0), local_corners.max(axis=0)
            outside = []
            for part in parts:
                lo, hi = part[:, :2].min(axis=0), part[:, :2].max(axis=0)
                if (lo >= corners.max(axis=0)).any() or (hi <= corners.min(axis=0)).any():
                    outside.append(part)
                    continue
                local = part.copy()
                local[:, :2] = part[:, :2] @ to_local.T
                if polygon_area(clip_loop(local, x0, x1, y0, y1)) <= MIN_CUT_AREA_M2:
                    outside.append(part)
                    continue
                was_cut = True
                for bounds in ((-np.inf, x0, -np.inf, np.inf), (x1, np.inf, -np.inf, np.inf), (x0, x1, -np.inf, y0),
                               (x0, x1, y1, np.inf)):
                    piece = clip_loop(local, *bounds)
                    if len(piece) >= 3:
                        piece[:, :2] = piece[:, :2] @ to_local
                        outside.append(piece)
            parts = outside
        if was_cut:
            pieces += [(p, int(mesh.face_component[f])) for p in parts]
            cut_triangles.append(int(f))
    return pieces, cut_triangles


def area(vertices: np.ndarray, faces: np.ndarray) -> float:
    tri = vertices[faces]
    return float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum() / 2)


@given(st.integers(min_value=0, max_value=10_000))
def test_clipping_many_polygons_at_once_equals_the_one_polygon_loop(seed):
    rng = np.random.default_rng(seed)
    triangles = rng.uniform(-2, 2, size=(40, 3, 3))
    bounds = np.sort(rng.uniform(-2.5, 2.5, size=(40, 4)).reshape(40, 2, 2), axis=2).reshape(40, 4)
    bounds[rng.random(40) < 0.2, 0] = -np.inf  # some sides open
    x0, x1, y0, y1 = bounds[:, 0], bounds[:, 1], bounds[:, 2], bounds[:, 3]
    clipped = Polygons.of_triangles(triangles).clip_to_box(x0, x1, y0, y1)
    for k in range(len(triangles)):
        expected = clip_loop(triangles[k], x0[k], x1[k], y0[k], y1[k])
        assert clipped.count[k] == len(expected)
        assert np.array_equal(clipped.vertices[k, :clipped.count[k]], expected)


@given(st.integers(min_value=0, max_value=10_000))
def test_cutting_openings_keeps_the_area_and_the_pieces_of_the_one_triangle_loop(seed):
    rng = np.random.default_rng(seed)
    n = 30
    vertices = np.column_stack([rng.uniform(0, 10, size=(3 * n, 2)), rng.uniform(2.6, 2.8, size=3 * n)])
    faces = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    component = (np.arange(n) % 3).astype(np.int32)
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=component)
    openings = []
    for _ in range(rng.integers(1, 12)):
        centre, half, angle = rng.uniform(1, 9, 2), rng.uniform(0.1, 1.5, 2), rng.uniform(0, np.pi)
        c, s = np.cos(angle), np.sin(angle)
        local = np.array([[-half[0], -half[1]], [half[0], -half[1]], [half[0], half[1]], [-half[0], half[1]]])
        openings.append(centre + local @ np.array([[c, s], [-s, c]]))
    cut = np.array([True, True, False])
    result = cut_openings(mesh, cut, openings)
    reference, cut_triangles = cut_loop(mesh, cut, openings)
    added = result.faces[result.faces.max(axis=1) >= len(vertices)]
    untouched = np.delete(np.arange(n), cut_triangles)
    assert np.array_equal(result.faces[:len(untouched)], faces[untouched])  # the others keep their place and bytes
    expected_vertices = np.concatenate([p for p, _ in reference]) if reference else np.zeros((0, 3))
    assert np.array_equal(result.vertices[len(vertices):], expected_vertices)  # the same pieces, in order
    kept_area = area(result.vertices, added)
    assert kept_area == pytest.approx(sum(area(p, np.array([[0, k, k + 1] for k in range(1, len(p) - 1)]))
                                          for p, _ in reference), abs=1e-9)
    assert area(result.vertices, result.faces[result.face_component == 2]) == pytest.approx(
        area(vertices, faces[component == 2]), abs=1e-12)  # a component not cut keeps its triangles


def test_many_openings_in_one_board_cut_it_into_a_few_pieces_each():
    # a 6 x 4 m ceiling board's underside (two triangles) with a 5 x 4 grid of 0.6 x 0.6 m openings:
    # each opening cuts only the pieces under it, so the board ends in a few pieces per opening
    # (cutting every piece of a triangle along every opening's edge lines gave thousands)
    vertices = np.array([[0, 0, 2.7], [6, 0, 2.7], [6, 4, 2.7], [0, 4, 2.7]], dtype=float)
    faces = np.array([[0, 2, 1], [0, 3, 2]], dtype=np.int32)
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=np.zeros(2, dtype=np.int32))
    square = np.array([[-0.3, -0.3], [0.3, -0.3], [0.3, 0.3], [-0.3, 0.3]])
    openings = [np.array([x, y]) + square for x in np.linspace(0.7, 5.3, 5) for y in np.linspace(0.6, 3.4, 4)]
    result = cut_openings(mesh, np.array([True]), openings)
    assert len(result.faces) <= 8 * len(openings)
    assert area(result.vertices, result.faces) == pytest.approx(24.0 - 0.36 * len(openings), abs=1e-9)


def test_polygon_areas_are_three_dimensional():
    polygons = Polygons(vertices=np.array([[[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]],  # upright, 1 m2
                                           [[0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 0]],  # a triangle, 2 m2
                                           [[0, 0, 0], [1, 1, 1], [0, 0, 0], [0, 0, 0]]], dtype=float),
                        count=np.array([4, 3, 2]))
    assert polygons.areas() == pytest.approx([1.0, 2.0, 0.0])
    lo, hi = polygons.bounds_xy()
    assert lo.tolist() == [[0, 0], [0, 0], [0, 0]] and hi.tolist() == [[1, 0], [2, 2], [1, 1]]


def test_polygons_fan_into_triangles_numbered_after_the_mesh():
    square = Polygons(vertices=np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]],
                                         [[0, 0, 1], [1, 0, 1], [0, 1, 1], [9, 9, 9]]], dtype=float),
                      count=np.array([4, 3]))
    vertices, faces, polygon = square.fan_triangles(10)
    assert len(vertices) == 7
    assert faces.tolist() == [[10, 11, 12], [10, 12, 13], [14, 15, 16]] and polygon.tolist() == [0, 0, 1]

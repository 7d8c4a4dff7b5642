"""Cloud-to-mesh distances within a band: the same answers as Embree's closest-point query."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bimscan.compare.distance import BandDistances
from bimscan.compare.surfaces import ModelSurfaces, outward_normals
from bimscan.types import SceneMesh


def _random_mesh(seed: int, triangles: int) -> SceneMesh:
    rng = np.random.default_rng(seed)
    vertices = rng.uniform(-2.0, 2.0, size=(3 * triangles, 3))
    faces = np.arange(3 * triangles, dtype=np.int32).reshape(-1, 3)
    component = (np.arange(triangles) % 4).astype(np.int32)
    return SceneMesh(vertices=vertices, faces=faces, face_component=component)


@settings(max_examples=15)
@given(seed=st.integers(0, 10_000), band=st.floats(0.05, 1.0))
def test_distances_within_the_band_match_embrees_closest_points(seed: int, band: float) -> None:
    mesh = _random_mesh(seed, 20)
    points = np.random.default_rng(seed + 1).uniform(-2.5, 2.5, size=(3000, 3))
    answer = BandDistances(mesh, band_m=band).query(points)
    truth = ModelSurfaces(mesh).closest(points)
    near = truth.distance < band - 1e-4
    assert np.all(answer.triangle[near] >= 0)
    assert np.allclose(answer.distance[near], truth.distance[near], atol=1e-5)  # Embree answers in float32
    far = truth.distance > band + 1e-4
    assert np.all(np.isinf(answer.distance[far])) and np.all(answer.triangle[far] == -1)


def test_the_second_distance_is_to_the_nearest_surface_of_another_element() -> None:
    # two parallel squares 2 cm apart, elements 0 and 1
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    vertices = np.vstack([square, square + [0, 0, 0.02]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], dtype=np.int32)
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=np.array([0, 0, 1, 1], dtype=np.int32))
    answer = BandDistances(mesh, band_m=0.1).query(np.array([[0.5, 0.5, 0.005], [0.5, 0.5, 0.5]]))
    assert answer.triangle[0] in (0, 1) and abs(answer.distance[0] - 0.005) < 1e-12
    assert abs(answer.second[0] - 0.015) < 1e-12
    assert np.isinf(answer.distance[1]) and np.isinf(answer.second[1])
    other = BandDistances(mesh, band_m=0.1).query(np.array([[0.5, 0.5, 0.005]]), other_than=np.array([0]))
    assert abs(other.distance[0] - 0.015) < 1e-12 and other.triangle[0] in (2, 3)


def test_outward_normals_do_not_depend_on_the_winding() -> None:
    # a unit cube, then the same cube with every triangle wound the other way
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int32)
    component = np.zeros(len(faces), dtype=np.int32)
    wound = outward_normals(SceneMesh(vertices=corners, faces=faces, face_component=component))
    flipped = outward_normals(SceneMesh(vertices=corners, faces=faces[:, ::-1].copy(), face_component=component))
    assert np.allclose(wound, flipped)
    centroids = corners[faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", wound, centroids - 0.5) > 0)  # every normal points out of the cube

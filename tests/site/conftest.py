"""Fixtures for site tests: one generated office (parsed once) and an exact mesh-crossing check."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="session")
def office_ifc(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A generated one-storey office (rooms, corridor, doors, windows, columns, beams, ceilings, furniture)."""
    from bimscan.ifc.generate import make_building

    return make_building(tmp_path_factory.mktemp("office") / "office.ifc", seed=1, storeys=1).path


@pytest.fixture(scope="session")
def office_scene(office_ifc: Path):
    """The generated office, labelled with spc5 (parsed without the cache: session-wide)."""
    from bimscan.pipeline import load_scene

    return load_scene(office_ifc, use_cache=False)


@pytest.fixture(scope="session")
def dressed_office(office_scene):
    """The office with office clutter and people at 0.3 objects per square metre."""
    from bimscan.site import ClutterSettings, SiteModel, dress_scene

    return dress_scene(office_scene, SiteModel(clutter=ClutterSettings(density=0.3)), seed=5)


def raycasting_scene(vertices: np.ndarray, faces: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)))
    return scene


def edges_cross(vertices: np.ndarray, faces: np.ndarray, scene) -> bool:
    """True when an edge of the mesh (vertices, faces) crosses a triangle of ``scene`` (two closed
    meshes intersect exactly when an edge of one crosses a face of the other)."""
    import open3d as o3d

    if len(faces) == 0:
        return False
    edges = np.unique(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1), axis=0)
    start, end = vertices[edges[:, 0]], vertices[edges[:, 1]]
    length = np.linalg.norm(end - start, axis=1)
    rays = np.concatenate([start, (end - start) / length[:, None]], axis=1).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    return bool((t < length - 1e-6).any())


def component_meshes(scene, components: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Vertices and faces (renumbered) of each given component of a scene's mesh."""
    out = {}
    for c in components:
        faces = scene.mesh.faces[scene.mesh.face_component == c]
        used, inverse = np.unique(faces, return_inverse=True)
        out[int(c)] = (scene.mesh.vertices[used], inverse.reshape(-1, 3))
    return out

"""Pictures of BIM models: the scene mesh flat-shaded by class, z-buffered (Numba rasteriser)."""

from __future__ import annotations

import numpy as np

from bimscan.render.compose import class_color_table
from bimscan.render.raster import fill_triangles, new_canvas
from bimscan.render.view import Camera
from bimscan.types import LabelScheme, SceneMesh


def face_colors(mesh: SceneMesh, component_label: np.ndarray, scheme: LabelScheme, *,
                light_towards: np.ndarray) -> np.ndarray:
    """(F, 3) uint8 colour of each triangle: its class colour, flat-shaded (two-sided Lambert).

    component_label: (C,) uint8 class id per component. light_towards: (3,) direction from the
    scene to the light (a light near the camera keeps faces that face the viewer bright).
    """
    base = class_color_table(scheme).astype(np.float64)[component_label[mesh.face_component]]
    light = np.array(light_towards, dtype=np.float64)  # a copy: the caller's vector stays as it is
    light /= np.linalg.norm(light)
    shade = 0.45 + 0.55 * np.abs(mesh.face_normals() @ light)  # triangle winding is not trusted: two-sided
    return np.clip(base * shade[:, None], 0, 255).round().astype(np.uint8)


def draw_mesh(mesh: SceneMesh, colors: np.ndarray, camera: Camera, *, cut_z: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 image of the mesh with per-triangle colours (F, 3), everything above ``cut_z`` removed."""
    image, zbuffer = new_canvas(camera.width, camera.height)
    if mesh.n_triangles == 0:
        return image
    sx, sy, depth = camera.project(mesh.vertices)
    fill_triangles(sx, sy, depth, np.ascontiguousarray(mesh.vertices[:, 2]), mesh.faces,
                   np.ascontiguousarray(colors), np.inf if cut_z is None else float(cut_z), zbuffer, image)
    return image

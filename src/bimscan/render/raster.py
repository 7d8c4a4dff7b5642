"""Z-buffered drawing into RGB images: point splats and flat-shaded triangles (Numba).

Both kernels take screen coordinates (pixels, x right, y down, float64) and a depth per point or
vertex (smaller = nearer the viewer), keep a float64 z-buffer (H, W) initialised to +inf, and
write uint8 RGB colours into an image (H, W, 3). Points are drawn as ``radius``-pixel squares
(radius 0: one pixel). Triangles are filled when their pixel centres fall inside, with depth
interpolated linearly; a world height per vertex lets both clip everything above a section
height (``cut_z``), so building interiors can be seen from above.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def splat_points(x: np.ndarray, y: np.ndarray, depth: np.ndarray, color: np.ndarray, radius: int,
                 zbuffer: np.ndarray, image: np.ndarray) -> int:
    """Draw points (N,) with colours (N, 3) uint8 nearest-first; returns how many pixels were written."""
    height, width = zbuffer.shape
    written = 0
    for i in range(x.shape[0]):
        cx = int(np.floor(x[i]))
        cy = int(np.floor(y[i]))
        d = depth[i]
        for py in range(max(cy - radius, 0), min(cy + radius + 1, height)):
            for px in range(max(cx - radius, 0), min(cx + radius + 1, width)):
                if d < zbuffer[py, px]:
                    zbuffer[py, px] = d
                    image[py, px, 0] = color[i, 0]
                    image[py, px, 1] = color[i, 1]
                    image[py, px, 2] = color[i, 2]
                    written += 1
    return written


@nb.njit(cache=True)
def fill_triangles(sx: np.ndarray, sy: np.ndarray, depth: np.ndarray, world_z: np.ndarray, faces: np.ndarray,
                   face_color: np.ndarray, cut_z: float, zbuffer: np.ndarray, image: np.ndarray) -> int:
    """Fill triangles ``faces`` (F, 3) of vertices (sx, sy, depth, world_z: (V,)) with colours (F, 3) uint8.

    Pixels whose interpolated world height exceeds ``cut_z`` are skipped (a horizontal section).
    Returns the number of pixels written.
    """
    height, width = zbuffer.shape
    written = 0
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, bx, by, cx, cy = sx[a], sy[a], sx[b], sy[b], sx[c], sy[c]
        area = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if abs(area) < 1e-12:
            continue
        x0 = max(int(np.floor(min(ax, bx, cx))), 0)
        x1 = min(int(np.ceil(max(ax, bx, cx))), width - 1)
        y0 = max(int(np.floor(min(ay, by, cy))), 0)
        y1 = min(int(np.ceil(max(ay, by, cy))), height - 1)
        if min(world_z[a], world_z[b], world_z[c]) > cut_z:
            continue
        for py in range(y0, y1 + 1):
            qy = py + 0.5
            for px in range(x0, x1 + 1):
                qx = px + 0.5
                w0 = ((bx - qx) * (cy - qy) - (cx - qx) * (by - qy)) / area
                w1 = ((cx - qx) * (ay - qy) - (ax - qx) * (cy - qy)) / area
                w2 = 1.0 - w0 - w1
                if w0 < 0 or w1 < 0 or w2 < 0:
                    continue
                z_world = w0 * world_z[a] + w1 * world_z[b] + w2 * world_z[c]
                if z_world > cut_z:
                    continue
                d = w0 * depth[a] + w1 * depth[b] + w2 * depth[c]
                if d < zbuffer[py, px]:
                    zbuffer[py, px] = d
                    image[py, px, 0] = face_color[f, 0]
                    image[py, px, 1] = face_color[f, 1]
                    image[py, px, 2] = face_color[f, 2]
                    written += 1
    return written


def new_canvas(width: int, height: int, background: tuple[int, int, int] = (255, 255, 255)) -> tuple[np.ndarray, np.ndarray]:
    """(image (H, W, 3) uint8 filled with ``background``, z-buffer (H, W) float64 of +inf)."""
    image = np.empty((height, width, 3), dtype=np.uint8)
    image[:] = background
    return image, np.full((height, width), np.inf)

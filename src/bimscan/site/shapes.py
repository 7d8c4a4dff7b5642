"""Closed triangle meshes from simple solids: boxes, members between two points, prisms.

Every solid is a closed shell with outward winding (each edge used once in each direction), so
an object made of several solids is a set of closed shells: the scanner sees their outer
surfaces and the inside-a-solid tests work on them. Coordinates are metres.
"""

from __future__ import annotations

import math

import numpy as np

# Corner i of a box is (i & 1, (i >> 1) & 1, (i >> 2) & 1) in its frame; two outward triangles per side.
_BOX_FACES = np.array([
    [0, 2, 3], [0, 3, 1],  # -z
    [4, 5, 7], [4, 7, 6],  # +z
    [0, 1, 5], [0, 5, 4],  # -y
    [2, 6, 7], [2, 7, 3],  # +y
    [0, 4, 6], [0, 6, 2],  # -x
    [1, 3, 7], [1, 7, 5],  # +x
], dtype=np.int32)
_CORNERS = np.array([[(i & 1), (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)


class MeshBuilder:
    """Collects closed solids into one mesh (vertices (V, 3) float64, faces (F, 3) int32)."""

    def __init__(self) -> None:
        self._vertices: list[np.ndarray] = []
        self._faces: list[np.ndarray] = []
        self._count = 0

    def _add(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._vertices.append(vertices)
        self._faces.append(faces + self._count)
        self._count += len(vertices)

    def frame_box(self, origin: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> None:
        """The parallelepiped ``origin + x a + y b + z c`` (x, y, z in [0, 1]); (a, b, c) right-handed."""
        self._add(origin + _CORNERS @ np.stack([a, b, c]), _BOX_FACES)

    def box(self, lo: tuple[float, float, float], hi: tuple[float, float, float]) -> None:
        """An axis-aligned box from corner ``lo`` to corner ``hi``."""
        lo_, hi_ = np.asarray(lo, float), np.asarray(hi, float)
        size = hi_ - lo_
        if (size <= 0).any():
            raise ValueError(f"box with empty extent {size}")
        self.frame_box(lo_, np.array([size[0], 0, 0]), np.array([0, size[1], 0]), np.array([0, 0, size[2]]))

    def member(self, p0: tuple[float, float, float], p1: tuple[float, float, float], width: float,
               depth: float) -> None:
        """A straight member of ``width`` x ``depth`` section from ``p0`` to ``p1`` (width horizontal
        when the member is not vertical)."""
        u, e1, e2, length = _axes(p0, p1)
        origin = np.asarray(p0, float) - e1 * width / 2 - e2 * depth / 2
        self.frame_box(origin, e1 * width, e2 * depth, u * length)

    def prism(self, p0: tuple[float, float, float], p1: tuple[float, float, float], radius: float,
              sides: int = 12) -> None:
        """A regular ``sides``-gon prism (a cylinder) of circumradius ``radius`` from ``p0`` to ``p1``."""
        u, e1, e2, length = _axes(p0, p1)
        angles = np.arange(sides) * (2 * math.pi / sides)
        ring = radius * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
        base = np.asarray(p0, float)
        vertices = np.concatenate([base + ring, base + u * length + ring, [base, base + u * length]])
        i = np.arange(sides)
        j = (i + 1) % sides
        c0, c1 = 2 * sides, 2 * sides + 1
        faces = np.concatenate([
            np.stack([np.full(sides, c0), j, i], axis=1),  # bottom cap, facing -u
            np.stack([np.full(sides, c1), sides + i, sides + j], axis=1),  # top cap, facing +u
            np.stack([i, j, sides + j], axis=1), np.stack([i, sides + j, sides + i], axis=1),  # sides
        ]).astype(np.int32)
        self._add(vertices, faces)

    def build(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (V, 3) float64, faces (F, 3) int32) of everything added."""
        if not self._faces:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
        return np.concatenate(self._vertices).astype(np.float64), np.concatenate(self._faces).astype(np.int32)


def _axes(p0: tuple[float, float, float],
          p1: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Unit axis from p0 to p1, two unit vectors across it with (e1, e2, u) right-handed, and the length."""
    d = np.asarray(p1, float) - np.asarray(p0, float)
    length = float(np.linalg.norm(d))
    if length <= 0:
        raise ValueError("a member needs two distinct end points")
    u = d / length
    reference = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(reference, u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return u, e1, e2, length


def yaw_matrix(yaw_rad: float) -> np.ndarray:
    """(3, 3) rotation about +z by ``yaw_rad``."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def is_closed(faces: np.ndarray) -> bool:
    """True when every directed edge appears exactly once and its reverse exactly once (closed,
    consistently oriented shells)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    n = int(faces.max()) + 1 if len(faces) else 0
    directed = edges[:, 0] * n + edges[:, 1]
    reverse = edges[:, 1] * n + edges[:, 0]
    unique, counts = np.unique(directed, return_counts=True)
    return bool((counts == 1).all() and np.isin(reverse, unique).all())

"""Convex polygons in bulk: many 3-D polygons clipped by vertical planes at once, and fanned back
into triangles.

Site dressing cuts ceiling tiles along grid lines and around lay-in fittings; real models have
thousands of tiles and hundreds of fittings, so the cuts run on arrays: ``Polygons`` holds P
polygons of at most K vertices as one (P, K, 3) array and a count per polygon, and every clip is a
Sutherland-Hodgman step over all of them. Each vertex is computed with the same floating-point
operations, in the same order, as the textbook one-polygon loop, so the results are the same
bytes as that loop's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Polygons:
    """P convex polygons: vertices (P, K, 3) float64 (rows past ``count`` are padding), count (P,)
    int64 vertices of each (0: empty), in order around the polygon."""

    vertices: np.ndarray
    count: np.ndarray

    def __len__(self) -> int:
        return int(len(self.count))

    @staticmethod
    def of_triangles(triangles: np.ndarray) -> Polygons:
        """Triangles (P, 3, 3) as polygons."""
        return Polygons(vertices=np.array(triangles, dtype=np.float64), count=np.full(len(triangles), 3, np.int64))

    def take(self, index: np.ndarray) -> Polygons:
        return Polygons(vertices=self.vertices[index], count=self.count[index])

    @staticmethod
    def concatenate(parts: list[Polygons]) -> Polygons:
        """The polygons of ``parts`` one after another (padded to the widest)."""
        width = max((p.vertices.shape[1] for p in parts), default=0)
        vertices = [np.pad(p.vertices, ((0, 0), (0, width - p.vertices.shape[1]), (0, 0))) for p in parts]
        return Polygons(vertices=np.concatenate(vertices) if vertices else np.zeros((0, 0, 3)),
                        count=np.concatenate([p.count for p in parts]) if parts else np.zeros(0, np.int64))

    def rotated_xy(self, matrix: np.ndarray) -> Polygons:
        """x, y of every vertex multiplied by ``matrix`` (2, 2) as row vectors (xy @ matrix); z kept."""
        vertices = self.vertices.copy()
        vertices[:, :, :2] = np.matmul(self.vertices[:, :, :2], matrix)
        return Polygons(vertices=vertices, count=self.count)

    def clip(self, axis: int, bound: np.ndarray | float, *, keep_below: bool) -> Polygons:
        """Each polygon clipped to the half-space ``coordinate[axis] <= bound`` (``keep_below``) or
        ``>= bound``; ``bound`` (P,) or one for all; a polygon whose bound is not finite is kept whole."""
        vertices, count = self.vertices, self.count
        n, k = count.shape[0], vertices.shape[1]
        bound = np.broadcast_to(np.asarray(bound, dtype=np.float64), (n,))
        if n == 0 or k == 0:
            return self
        slot = np.arange(k)
        valid = slot[None, :] < count[:, None]
        following = np.where(slot[None, :] + 1 < count[:, None], slot[None, :] + 1, 0)
        a = vertices
        b = np.take_along_axis(vertices, following[:, :, None], axis=1)
        av, bv, limit = a[:, :, axis], b[:, :, axis], bound[:, None]
        a_in = av <= limit if keep_below else av >= limit
        b_in = bv <= limit if keep_below else bv >= limit
        crossing = valid & (a_in != b_in)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (limit - av) / (bv - av)
            cut = a + t[:, :, None] * (b - a)
        # each edge gives its start (when inside) and then its crossing point: compact them in order
        emitted = np.stack([valid & a_in, crossing], axis=2).reshape(n, 2 * k)
        points = np.stack([a, cut], axis=2).reshape(n, 2 * k, 3)
        whole = ~np.isfinite(bound)
        if whole.any():  # an infinite bound clips nothing: the polygon stays as it was
            emitted[whole] = np.stack([valid[whole], np.zeros_like(valid[whole])], axis=2).reshape(-1, 2 * k)
        new_count = emitted.sum(axis=1)
        width = int(new_count.max(initial=0))
        out = np.zeros((n, width, 3))
        rows, columns = np.nonzero(emitted)
        position = np.cumsum(emitted, axis=1)[rows, columns] - 1
        out[rows, position] = points[rows, columns]
        return Polygons(vertices=out, count=new_count.astype(np.int64))

    def clip_to_box(self, x0: np.ndarray | float, x1: np.ndarray | float, y0: np.ndarray | float,
                    y1: np.ndarray | float) -> Polygons:
        """Each polygon clipped to the vertical prism x0..x1, y0..y1 (bounds (P,) or one for all;
        an infinite bound does not clip)."""
        out = self
        for axis, bound, keep_below in ((0, x0, False), (0, x1, True), (1, y0, False), (1, y1, True)):
            out = out.clip(axis, bound, keep_below=keep_below)
        return out

    def bounds_xy(self) -> tuple[np.ndarray, np.ndarray]:
        """(P, 2) lowest and highest x, y of each polygon's vertices (inf / -inf for an empty one)."""
        valid = (np.arange(self.vertices.shape[1])[None, :] < self.count[:, None])[:, :, None]
        xy = self.vertices[:, :, :2]
        return np.where(valid, xy, np.inf).min(axis=1, initial=np.inf), np.where(valid, xy, -np.inf).max(
            axis=1, initial=-np.inf)

    def areas(self) -> np.ndarray:
        """(P,) area of each polygon in square metres (in 3-D: a vertical polygon has its own area,
        not its footprint's); 0 for fewer than 3 vertices."""
        if self.vertices.shape[1] < 3:
            return np.zeros(len(self.count))
        spokes = self.vertices[:, 1:] - self.vertices[:, :1]  # from the first vertex to the others
        fans = np.cross(spokes[:, :-1], spokes[:, 1:])  # (P, K - 2, 3): twice each fan triangle's area vector
        used = np.arange(fans.shape[1])[None, :] < (self.count[:, None] - 2)
        return np.linalg.norm(np.where(used[:, :, None], fans, 0.0).sum(axis=1), axis=1) / 2

    def fan_triangles(self, first_vertex: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The polygons as triangle fans: (vertices (V, 3) float64 in polygon order, faces (T, 3)
        int32 numbered from ``first_vertex``, polygon (T,) int64 each triangle's polygon).
        Polygons of fewer than 3 vertices give none."""
        count = self.count
        slot = np.arange(self.vertices.shape[1])
        vertices = self.vertices[slot[None, :] < count[:, None]]
        start = first_vertex + np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
        fans = np.maximum(count - 2, 0)
        polygon = np.repeat(np.arange(len(count)), fans)
        k = np.arange(int(fans.sum())) - np.repeat(np.cumsum(fans) - fans, fans) + 1
        base = start[polygon]
        faces = np.stack([base, base + k, base + k + 1], axis=1).astype(np.int32)
        return vertices, faces, polygon

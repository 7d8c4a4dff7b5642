"""The registration graph: which stations share enough surface to be registered to each other.

Cloud-to-cloud registration (ICP and its kin) aligns two scans on the surface both hold. Two
stations are joined by an edge when

- the surface both see at ``overlap_density_pts_m2`` or more (each on its own, within the
  incidence limit) is at least ``overlap`` of what the smaller of the two sees at that density,
- and that shared surface pins every direction: the smallest eigenvalue of ``sum(area * n n^T)``
  over it is at least ``min_direction_share`` of its trace. This is the translational part of the
  point-to-plane ICP covariance (Gelfand et al. 2003, "Geometrically stable sampling for the ICP
  algorithm"): a corridor's two walls and floor leave the corridor's axis free, and ICP slides.

The shared areas come from a stratified sample of the surface (``OVERLAP_SAMPLES``); the normal
tensor of a pair sums, over 13 normal directions (level; upright and steep, each in six 30 degree
azimuth bins), the shared area in that bin times the bin's mean n n^T.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import connected_components

from bimscan.survey.planning.surface import SurfaceSamples
from bimscan.survey.planning.visibility import Visibility

OVERLAP_SAMPLES = 40_000  # surface samples the overlap areas are computed on (dense products: K x S x K)


@dataclass(frozen=True)
class Overlaps:
    """shared_m2 (K, K) float64: the surface both stations see at the overlap density (the diagonal:
    what each sees); weakest_share (K, K) float64: the share of the shared surface facing its
    weakest direction (0 where nothing is shared)."""

    shared_m2: np.ndarray
    weakest_share: np.ndarray

    def edges(self, *, overlap: float, min_direction_share: float) -> np.ndarray:
        """(K, K) bool: the pairs that register (see the module docs); no self-loops."""
        seen = np.diag(self.shared_m2)
        smaller = np.minimum(seen[:, None], seen[None, :])
        joined = (self.shared_m2 >= overlap * smaller) & (self.shared_m2 > 0) & \
            (self.weakest_share >= min_direction_share)
        np.fill_diagonal(joined, False)
        return joined


def normal_bins(normal: np.ndarray) -> np.ndarray:
    """(S,) int bin of each unit normal (S, 3), the sign ignored: 0 level (|nz| >= 0.9), then
    1 + 6 * steep + azimuth bin (30 degrees, modulo 180), steep meaning |nz| >= 0.5."""
    nz = np.abs(normal[:, 2])
    azimuth = np.degrees(np.arctan2(normal[:, 1], normal[:, 0])) % 180.0
    bins = 1 + 6 * (nz >= 0.5) + np.minimum((azimuth // 30.0).astype(np.int64), 5)
    return np.where(nz >= 0.9, 0, bins)


def compute_overlaps(visibility: Visibility, samples: SurfaceSamples, *, density_pts_m2: float,
                     seed: int = 0) -> Overlaps:
    """The overlaps of every pair of ``visibility``'s stations (see the module docs)."""
    k = visibility.n_stations
    strong = visibility.density_pts_m2 >= density_pts_m2
    rows, cols = visibility.sample[strong], visibility.station[strong]
    used = np.unique(rows)
    weight_scale = 1.0
    if len(used) > OVERLAP_SAMPLES:
        rng = np.random.default_rng(seed)
        keep = np.sort(rng.choice(used, size=OVERLAP_SAMPLES, replace=False))
        weight_scale = float(samples.area_m2[used].sum() / samples.area_m2[keep].sum())
        used = keep
    position = np.full(len(samples), -1, dtype=np.int64)
    position[used] = np.arange(len(used))
    inside = position[rows] >= 0
    rows, cols = position[rows[inside]], cols[inside]
    area = samples.area_m2[used] * weight_scale
    normal = samples.normal[used]
    bins = normal_bins(normal)
    shared = np.zeros((k, k))
    tensor = np.zeros((k, k, 3, 3))
    for b in np.unique(bins):
        in_bin = bins == b
        local = np.full(len(used), -1, dtype=np.int64)
        local[in_bin] = np.arange(int(in_bin.sum()))
        pick = local[rows] >= 0
        seen = np.zeros((int(in_bin.sum()), k), dtype=np.float32)
        seen[local[rows[pick]], cols[pick]] = 1.0
        part = (seen * area[in_bin, None].astype(np.float32)).T @ seen  # (K, K): area both see in this bin
        part = part.astype(np.float64)
        shared += part
        n = normal[in_bin]
        mean_tensor = np.einsum("s,si,sj->ij", area[in_bin], n, n) / max(float(area[in_bin].sum()), 1e-12)
        tensor += part[:, :, None, None] * mean_tensor
    weakest = np.zeros((k, k))
    trace = np.einsum("abii->ab", tensor)
    some = trace > 0
    if some.any():
        weakest[some] = np.linalg.eigvalsh(tensor[some])[:, 0] / trace[some]
    return Overlaps(shared_m2=shared, weakest_share=np.clip(weakest, 0.0, 1.0))


def graph_parts(edges: np.ndarray, members: np.ndarray | None = None) -> np.ndarray:
    """(M,) int: the connected part of each of ``members`` (indices; all when None) in the graph
    of ``edges`` restricted to them, numbered from 0 in order of first appearance."""
    members = np.arange(len(edges)) if members is None else np.asarray(members, dtype=np.int64)
    if len(members) == 0:
        return np.zeros(0, dtype=np.int64)
    _, labels = connected_components(edges[np.ix_(members, members)], directed=False)
    _, first = np.unique(labels, return_index=True)
    renumber = np.empty(labels.max() + 1, dtype=np.int64)
    renumber[labels[np.sort(first)]] = np.arange(len(first))
    return renumber[labels]


def scan_order(chosen: np.ndarray, heads: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The chosen stations (indices) in the order to scan them: from the lowest (then the one
    furthest to the south-west), each next one the nearest of those that register to one already
    scanned, so each scan can be registered as it comes; a part the graph does not reach starts
    at its station nearest the last one."""
    chosen = np.asarray(chosen, dtype=np.int64)
    if len(chosen) == 0:
        return chosen
    p = heads[chosen]
    first = int(np.lexsort((p[:, 1], p[:, 0], np.round(p[:, 2], 1)))[0])
    order = [first]
    left = set(range(len(chosen))) - {first}
    while left:
        rest = np.array(sorted(left))
        linked = edges[np.ix_(chosen[order], chosen[rest])].any(axis=0)
        pool = rest[linked] if linked.any() else rest
        distance = np.linalg.norm(p[pool] - p[order[-1]], axis=1)
        pick = int(pool[np.argmin(distance)])
        order.append(pick)
        left.remove(pick)
    return chosen[np.array(order)]

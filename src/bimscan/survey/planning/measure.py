"""Coverage measured on a scan: the points per square metre a labelled cloud holds on each sample.

Every point of a bimscan cloud carries its component and its station. A point is given to the
nearest surface sample of its own component that lies in the point's plane (within
``PLANE_TOLERANCE_M`` along the sample's normal, among the ``NEIGHBOURS`` nearest, at most
``ASSIGN_RADIUS_M`` away); it counts only when its station's beam met that surface within the
incidence limit (the same rule the plan's estimate follows). A sample's measured density is the
points given to it and to its coplanar neighbours on the same element within ``SMOOTH_RADIUS_M``,
over the area those samples stand for: a ratio of two sums over the same patch, so a patch cut by
an element's edge is neither diluted nor inflated.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from bimscan.survey.planning.surface import SurfaceSamples
from bimscan.types import PointCloud

PLANE_TOLERANCE_M = 0.03  # range noise (5 mm sigma) and float32 storage stay well inside this
ASSIGN_RADIUS_M = 0.3
NEIGHBOURS = 6
SMOOTH_RADIUS_M = 0.3
_COMPONENT_SPACING = 1.0e4  # a fourth coordinate: samples of other components are 10 km away


def _keyed(xyz: np.ndarray, component: np.ndarray) -> np.ndarray:
    return np.column_stack([xyz, component.astype(np.float64) * _COMPONENT_SPACING])


def count_points(chunks: Iterable[PointCloud], samples: SurfaceSamples, stations: Mapping[int, np.ndarray], *,
                 max_incidence_deg: float, threads: int = -1) -> np.ndarray:
    """(S,) int64 points of the cloud ``chunks`` given to each sample (see the module docs).
    ``stations``: beam origin (3,) of each station id the cloud's points carry; points of other
    components than the samples', or of unknown stations, are skipped."""
    counts = np.zeros(len(samples), dtype=np.int64)
    if len(samples) == 0:
        return counts
    tree = cKDTree(_keyed(samples.xyz, samples.component))
    sampled = np.zeros(int(samples.component.max()) + 1, dtype=bool)
    sampled[samples.component] = True
    ids = np.array(sorted(stations), dtype=np.int64)
    origin = np.full((int(ids.max()) + 1 if len(ids) else 1, 3), np.nan)
    for i in ids:
        origin[i] = stations[int(i)]
    cos_limit = math.cos(math.radians(max_incidence_deg))
    for chunk in chunks:
        if chunk.component is None or chunk.station is None:
            raise ValueError("a cloud measured for coverage needs its points' component and station")
        component = chunk.component.astype(np.int64)
        station = chunk.station.astype(np.int64)
        keep = (component >= 0) & (component < len(sampled)) & (station < len(origin))
        keep[keep] &= sampled[component[keep]]
        if not keep.any():
            continue
        xyz, component, station = chunk.xyz[keep], component[keep], station[keep]
        distance, neighbour = tree.query(_keyed(xyz, component), k=NEIGHBOURS, distance_upper_bound=ASSIGN_RADIUS_M,
                                         workers=threads)
        valid = np.isfinite(distance)
        safe = np.where(valid, neighbour, 0)
        offset = np.abs(np.einsum("nkj,nkj->nk", xyz[:, None, :] - samples.xyz[safe], samples.normal[safe]))
        ok = valid & (offset <= PLANE_TOLERANCE_M)
        first = np.argmax(ok, axis=1)
        found = ok[np.arange(len(ok)), first]
        target = safe[np.arange(len(ok)), first]
        beam = xyz - origin[station]
        length = np.linalg.norm(beam, axis=1)
        cos_incidence = np.abs(np.einsum("nj,nj->n", beam, samples.normal[target])) / np.maximum(length, 1e-12)
        counted = found & np.isfinite(length) & (cos_incidence >= cos_limit)
        counts += np.bincount(target[counted], minlength=len(samples))
    return counts


def patch_matrix(samples: SurfaceSamples) -> sparse.csr_matrix:
    """(S, S) 0/1 sparse: each sample with its coplanar neighbours on its element within
    ``SMOOTH_RADIUS_M`` (itself included)."""
    n = len(samples)
    tree = cKDTree(_keyed(samples.xyz, samples.component))
    pairs = tree.query_pairs(SMOOTH_RADIUS_M, output_type="ndarray")
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        same_plane = (np.abs(np.einsum("nj,nj->n", samples.normal[a], samples.normal[b])) >= 0.95) & \
                     (np.abs(np.einsum("nj,nj->n", samples.xyz[b] - samples.xyz[a], samples.normal[a])) <= PLANE_TOLERANCE_M)
        a, b = a[same_plane], b[same_plane]
    else:
        a = b = np.zeros(0, dtype=np.int64)
    rows = np.concatenate([np.arange(n), a, b])
    cols = np.concatenate([np.arange(n), b, a])
    return sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))


def patch_density(values: np.ndarray, samples: SurfaceSamples, *, per_area: bool,
                  patches: sparse.csr_matrix | None = None) -> np.ndarray:
    """(S,) the density on each sample's patch: with ``per_area`` (counts of points) the patch's
    points over its area; otherwise (densities) their area-weighted mean over the patch."""
    patches = patch_matrix(samples) if patches is None else patches
    area = samples.area_m2
    total_area = patches @ area
    if per_area:
        return (patches @ values.astype(np.float64)) / np.maximum(total_area, 1e-12)
    return (patches @ (values * area)) / np.maximum(total_area, 1e-12)

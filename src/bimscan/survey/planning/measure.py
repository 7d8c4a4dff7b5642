"""Coverage measured on a scan: the points per square metre a labelled cloud holds on each sample.

Every point of a bimscan cloud carries its component and its station. A point is given to the
nearest surface sample of its own component (among the nearest few, then up to 16; at most
``ASSIGN_RADIUS_M`` away) that lies in the point's plane (within ``PLANE_TOLERANCE_M`` along the
sample's normal) and that its station sees within the incidence limit (the plan's own visibility:
the two faces of a thin steel section lie millimetres apart, and only the station tells which one
a point is on). A point no such sample takes is not counted. A sample's measured density is the
points given to it and to its neighbours on the same face of the same element (normals within 18
degrees, the same plane) within ``SMOOTH_RADIUS_M``, over the area those samples stand for: a ratio
of two sums over the same patch, so a patch cut by an element's edge is neither diluted nor
inflated.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
from scipy import sparse
from scipy.spatial import cKDTree

from bimscan.survey.planning.surface import SurfaceSamples
from bimscan.survey.planning.visibility import Visibility
from bimscan.types import PointCloud

PLANE_TOLERANCE_M = 0.03  # range noise (5 mm sigma) and float32 storage stay well inside this
ASSIGN_RADIUS_M = 0.3
NEIGHBOURS = (4, 16)  # the nearest samples tried: a few first, more for the points none of those takes
SMOOTH_RADIUS_M = 0.2  # the samples' own spacing at 25 per square metre
SAME_FACE_COS = 0.95
_COMPONENT_SPACING = 1.0e4  # a fourth coordinate: samples of other components are 10 km away


def _keyed(xyz: np.ndarray, component: np.ndarray) -> np.ndarray:
    return np.column_stack([xyz, component.astype(np.float64) * _COMPONENT_SPACING])


def points_per_sample(chunks: Iterable[PointCloud], samples: SurfaceSamples, visibility: Visibility,
                      columns: Mapping[int, int], *, counted: np.ndarray | None = None,
                      threads: int = -1) -> np.ndarray:
    """(S,) int64 points of the cloud ``chunks`` given to each sample (see the module docs).
    ``columns``: the visibility column (candidate) of each station id the cloud's points carry;
    ``counted`` (S,) bool: the samples to count on (None: all); points of unknown stations, or of
    components without such samples, are skipped."""
    all_counts = np.zeros(len(samples), dtype=np.int64)
    index = np.arange(len(samples)) if counted is None else np.flatnonzero(counted)
    if len(index) == 0 or not columns:
        return all_counts
    subset = samples.take(index)
    counts = _count(chunks, subset, index, visibility, columns, threads)
    all_counts[index] = counts
    return all_counts


def _count(chunks: Iterable[PointCloud], samples: SurfaceSamples, index: np.ndarray, visibility: Visibility,
           columns: Mapping[int, int], threads: int) -> np.ndarray:
    """``points_per_sample`` on the samples ``index`` of the visibility's (``samples`` holds just those)."""
    counts = np.zeros(len(samples), dtype=np.int64)
    tree = cKDTree(_keyed(samples.xyz, samples.component))
    sampled = np.zeros(int(samples.component.max()) + 1, dtype=bool)
    sampled[samples.component] = True
    position = np.full(visibility.n_samples, -1, dtype=np.int64)
    position[index] = np.arange(len(index))
    column_of = np.full(max(columns) + 1, -1, dtype=np.int64)
    for station, column in columns.items():
        column_of[station] = column
    within = (visibility.density_pts_m2 > 0) & (position[visibility.sample] >= 0)  # seen within the incidence limit
    pair_keys = np.sort(position[visibility.sample[within]] * visibility.n_stations + visibility.station[within])
    for chunk in chunks:
        if chunk.component is None or chunk.station is None:
            raise ValueError("a cloud measured for coverage needs its points' component and station")
        component = chunk.component.astype(np.int64)
        station = chunk.station.astype(np.int64)
        keep = (component >= 0) & (component < len(sampled)) & (station < len(column_of))
        keep[keep] &= sampled[component[keep]] & (column_of[station[keep]] >= 0)
        if not keep.any():
            continue
        xyz, component, column = chunk.xyz[keep], component[keep], column_of[station[keep]]
        keyed = _keyed(xyz, component)
        target = np.full(len(xyz), -1, dtype=np.int64)
        left = np.arange(len(xyz))
        for k in NEIGHBOURS:  # narrow faces (a 100 mm steel tube) have few samples of their own near a point
            target[left] = _assign(tree, keyed[left], xyz[left], column[left], samples, pair_keys,
                                   visibility.n_stations, k, threads)
            left = left[target[left] < 0]
            if len(left) == 0:
                break
        found = target >= 0
        counts += np.bincount(target[found], minlength=len(samples))
    return counts


def _assign(tree: cKDTree, keyed: np.ndarray, xyz: np.ndarray, column: np.ndarray, samples: SurfaceSamples,
            pair_keys: np.ndarray, n_stations: int, k: int, threads: int) -> np.ndarray:
    """(N,) the sample each point goes to among its ``k`` nearest (-1: none takes it)."""
    distance, neighbour = tree.query(keyed, k=k, distance_upper_bound=ASSIGN_RADIUS_M, workers=threads)
    valid = np.isfinite(distance)
    safe = np.where(valid, neighbour, 0)
    offset = np.abs(np.einsum("nkj,nkj->nk", xyz[:, None, :] - samples.xyz[safe], samples.normal[safe]))
    key = safe * n_stations + column[:, None]
    if len(pair_keys):
        where = np.minimum(np.searchsorted(pair_keys, key), len(pair_keys) - 1)
        seen = pair_keys[where] == key
    else:
        seen = np.zeros_like(valid)
    ok = valid & (offset <= PLANE_TOLERANCE_M) & seen
    first = np.argmax(ok, axis=1)
    rows = np.arange(len(ok))
    return np.where(ok[rows, first], safe[rows, first], -1)


def patch_matrix(samples: SurfaceSamples) -> sparse.csr_matrix:
    """(S, S) 0/1 sparse: each sample with its neighbours on the same face of its element within
    ``SMOOTH_RADIUS_M`` (itself included)."""
    n = len(samples)
    tree = cKDTree(_keyed(samples.xyz, samples.component))
    pairs = tree.query_pairs(SMOOTH_RADIUS_M, output_type="ndarray")
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        offset = np.abs(np.einsum("nj,nj->n", samples.xyz[b] - samples.xyz[a], samples.normal[a]))
        same_face = (np.einsum("nj,nj->n", samples.normal[a], samples.normal[b]) >= SAME_FACE_COS) & \
            (offset <= PLANE_TOLERANCE_M)
        a, b = a[same_face], b[same_face]
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

"""Scene-level regularisation at labelling time: vertical planar regions vote.

What geometry leaves to chance is where Wall&Column and Others meet: a wall behind a desk, a
bookcase's back in a wall's plane. A wall is one vertical plane; its points that the network
calls Others by their neighbourhood (furniture in front of it) are outvoted by the rest of the
plane. ``plane_votes`` grows vertical planar regions over voxel representatives (points whose
normal is within ``VERTICAL_DEG`` of horizontal, linked to neighbours within ``PLANE_REACH_M``
whose normals differ by at most ``PLANE_ANGLE_DEG``, as region growing of Rabbani et al. 2006
links smooth surfaces) and, in each region of at least ``MIN_REGION`` representatives, gives the
Wall&Column or Others representatives the class most of them have (their two votes summed on it).
Other classes are left as they are.

Streaming: labels are made stripe by stripe (:mod:`bimscan.learn.infer`); the regions of a stripe
are grown over the representatives in memory around it (the finished stripe before it and those
its later columns still hold), so a wall that crosses the stripe's edges votes with its parts
on either side, and memory stays what the labeller holds.
"""

from __future__ import annotations

import math

import numpy as np

PLANE_REACH_M = 0.2  # representatives this close are neighbours in a region (two voxels at 0.1 m)
PLANE_ANGLE_DEG = 15.0  # ... when their normals differ by at most this
VERTICAL_DEG = 15.0  # a representative of a vertical plane: its normal within this of horizontal
MIN_REGION = 30  # representatives in a region that votes (0.3 m2 at 0.1 m voxels)
NORMAL_NEIGHBOURS = 12  # representatives a normal is fitted to (learn.features.estimate_normals)


def plane_votes(xyz: np.ndarray, normal: np.ndarray, votes: np.ndarray, mine: np.ndarray, wall: int,
                others: int) -> np.ndarray:
    """The votes (M, C) of the representatives ``mine`` (M,) (indices into ``xyz``) after their
    vertical planar regions voted (module docs). xyz (N, 3), normal (N, 3) and votes (N, C) of every
    representative in memory; ``wall`` and ``others``: the two classes' columns."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    result = votes[mine].copy()
    decided = votes.sum(axis=1) > 0
    winner = votes.argmax(axis=1)
    vertical = np.abs(normal[:, 2]) < math.sin(math.radians(VERTICAL_DEG))
    candidates = np.flatnonzero(vertical & decided)
    if len(candidates) < MIN_REGION:
        return result
    pairs = cKDTree(xyz[candidates]).query_pairs(PLANE_REACH_M, output_type="ndarray")
    if not len(pairs):
        return result
    n = normal[candidates]
    alike = np.abs(np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]])) >= math.cos(math.radians(PLANE_ANGLE_DEG))
    pairs = pairs[alike]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(candidates),) * 2)
    _, region = connected_components(graph, directed=False)
    size = np.bincount(region)
    tallies = np.zeros((len(size), 2), dtype=np.int64)
    kind = winner[candidates]
    for column, cls in enumerate((wall, others)):
        tallies[:, column] = np.bincount(region[kind == cls], minlength=len(size))
    voting = (size >= MIN_REGION) & (tallies[:, 0] != tallies[:, 1])
    region_of = np.full(len(xyz), -1, dtype=np.int64)
    region_of[candidates] = region
    mine_region = region_of[mine]
    change = np.flatnonzero((mine_region >= 0) & np.isin(winner[mine], (wall, others)))
    change = change[voting[mine_region[change]]]
    if not len(change):
        return result
    majority = np.where(tallies[mine_region[change], 0] > tallies[mine_region[change], 1], wall, others)
    pair_total = result[change, wall] + result[change, others]
    result[change, wall] = np.where(majority == wall, pair_total, 0.0)
    result[change, others] = np.where(majority == others, pair_total, 0.0)
    return result

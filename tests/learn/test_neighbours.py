"""The cell search behind vote spreading: exact where it says so, and settling most points."""

from __future__ import annotations

import numpy as np

from bimscan.learn.density import voxel_representatives
from bimscan.learn.neighbours import cell_table, nearest_vote_means


def test_cells_find_the_nearest_candidates_where_they_say_they_did() -> None:
    rng = np.random.default_rng(11)
    xyz = rng.random((4000, 3)) * [2.0, 2.0, 0.5]
    xyz[:, 2] = np.round(xyz[:, 2] * 4) / 4  # three planes, as floors and ceilings lie
    reps, _ = voxel_representatives(xyz, 0.1)
    candidates = xyz[reps]
    votes = rng.random((len(reps), 4)).astype(np.float32)
    out = np.full((len(xyz), 4), np.nan, dtype=np.float32)
    exact = np.zeros(len(xyz), dtype=np.bool_)

    nearest_vote_means(xyz, candidates, votes, 3, 0.15, *cell_table(candidates, xyz.min(axis=0), xyz.max(axis=0), 0.15),
                       out, exact)

    distance = np.linalg.norm(xyz[:, None, :] - candidates[None, :, :], axis=2)  # brute force
    nearest = np.argsort(distance, axis=1, kind="stable")[:, :3]
    weight = 1.0 / np.maximum(np.take_along_axis(distance, nearest, axis=1), 1e-3) ** 2
    expected = (weight[..., None] * votes[nearest]).sum(axis=1) / weight.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(out[exact], expected[exact], rtol=1e-5)
    assert exact.mean() > 0.95  # cells of 1.5 voxels settle almost every point
    assert np.isnan(out[~exact]).all()  # the points it could not settle are left to the caller


def test_points_beyond_every_candidates_cells_are_left_to_the_caller() -> None:
    candidates = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    query = np.array([[0.05, 0.05, 0.0], [3.0, 3.0, 3.0]])
    out = np.zeros((2, 2), dtype=np.float32)
    exact = np.zeros(2, dtype=np.bool_)
    votes = np.eye(3, 2, dtype=np.float32)

    nearest_vote_means(query, candidates, votes, 3, 0.2, *cell_table(candidates, query.min(axis=0), query.max(axis=0), 0.2),
                       out, exact)

    assert exact.tolist() == [True, False]  # the far point has no candidate in its cells
    np.testing.assert_allclose(out[0], [1 / 3, 1 / 3], rtol=1e-6)  # three candidates at equal distance

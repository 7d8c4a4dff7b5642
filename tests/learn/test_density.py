"""Labelling's voxel representatives: the point nearest each voxel's centre, ties to the first."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.learn.density import QUANTUM_M, voxel_representatives


def _nearest_to_centre(xyz: np.ndarray, grid_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The rule written out point by point: lattice distance to the voxel's centre, ties to the first."""
    step = round(grid_m / QUANTUM_M)
    lattice = np.rint(xyz / QUANTUM_M).astype(np.int64)
    best: dict[tuple[int, ...], tuple[int, int]] = {}
    for i, point in enumerate(lattice):
        cell = tuple((point // step).tolist())
        offset = (point - np.asarray(cell) * step) * 2 - step
        distance = int(offset @ offset)
        if cell not in best or distance < best[cell][0]:
            best[cell] = (distance, i)
    rep_of = np.array([best[tuple((p // step).tolist())][1] for p in lattice])
    return np.sort([i for _, i in best.values()]), rep_of


@pytest.mark.parametrize("spread_m", [3.0, 5_000.0])  # a building; a site so wide that the packed sort key overflows
def test_each_voxel_keeps_the_point_nearest_its_centre_and_the_first_of_equals(spread_m: float) -> None:
    rng = np.random.default_rng(7)
    xyz = rng.random((2_000, 3)) * [3.0, 2.0, 1.0]
    xyz[::2, :2] += rng.integers(0, 2, (1_000, 1)) * spread_m  # two clusters spread_m apart in x and y
    xyz = np.concatenate([xyz, xyz[::5]])  # exact copies of earlier points: ties
    xyz[len(xyz) // 2] = np.floor(xyz[len(xyz) // 2] / 0.1) * 0.1 + 0.05  # a point on a voxel's centre

    representatives, rep_of = voxel_representatives(xyz, 0.1)

    expected, expected_of = _nearest_to_centre(xyz, 0.1)
    np.testing.assert_array_equal(representatives, expected)
    np.testing.assert_array_equal(rep_of, expected_of)
    assert len(xyz) // 2 in representatives

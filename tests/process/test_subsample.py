"""Streaming subsampling: the voxel grid of dataset units and the uniform sample of renders."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bimscan.errors import ConfigError
from bimscan.process.subsample import UniformSampler, VoxelSubsampler
from bimscan.types import PointCloud


def _cloud(n: int, *, seed: int, span_m: float = 4.0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(xyz=rng.uniform(0.0, span_m, (n, 3)), label=rng.integers(0, 5, n).astype(np.uint8),
                      station=np.arange(n, dtype=np.uint16))


def _voxel_first_points(xyz: np.ndarray, size: float) -> np.ndarray:
    """Reference: for every occupied voxel, the index of its first point (sorted)."""
    keys = [tuple(v) for v in np.floor(xyz / size).astype(np.int64)]
    first: dict[tuple, int] = {}
    for i, key in enumerate(keys):
        first.setdefault(key, i)
    return np.array(sorted(first.values()))


def _run(sampler: VoxelSubsampler, cloud: PointCloud, bounds: list[int]) -> PointCloud:
    parts = [sampler.filter(cloud.take(slice(a, b))) for a, b in zip(bounds[:-1], bounds[1:])]
    return PointCloud.concatenate(parts)


def test_voxel_subsampling_keeps_the_first_point_of_every_occupied_voxel() -> None:
    cloud = _cloud(5000, seed=1)
    kept = _run(VoxelSubsampler(0.5), cloud, [0, 1200, 1201, 3000, 5000])
    expected = _voxel_first_points(cloud.xyz, 0.5)
    np.testing.assert_array_equal(kept.station, expected.astype(np.uint16))  # station column = original index
    np.testing.assert_array_equal(kept.xyz, cloud.xyz[expected])


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(min_value=0, max_value=3000), max_size=8), size=st.sampled_from([0.1, 0.37, 1.0]))
def test_voxel_subsampling_does_not_depend_on_how_the_stream_is_chunked(cuts: list[int], size: float) -> None:
    cloud = _cloud(3000, seed=2)
    whole = VoxelSubsampler(size).filter(cloud)
    chunked = _run(VoxelSubsampler(size), cloud, sorted({0, 3000, *cuts}))
    np.testing.assert_array_equal(chunked.xyz, whole.xyz)
    np.testing.assert_array_equal(chunked.label, whole.label)


def test_voxel_grid_is_anchored_at_its_origin() -> None:
    xyz = np.array([[10.05, 0.0, 0.0], [10.15, 0.0, 0.0]])
    cloud = PointCloud(xyz=xyz)
    # Voxels of 0.2 m from x = 0 put both points in [10.0, 10.2); from x = 0.1, they straddle 10.1.
    assert len(VoxelSubsampler(0.2).filter(cloud)) == 1
    assert len(VoxelSubsampler(0.2, origin=(0.1, 0.0, 0.0)).filter(cloud)) == 2


def test_voxel_subsampler_keeps_one_point_per_voxel_and_remembers_few_keys_per_voxel() -> None:
    sampler = VoxelSubsampler(1.0)
    cloud = _cloud(20000, seed=3, span_m=3.0)  # 27 voxels
    kept = sum(len(sampler.filter(cloud.take(slice(start, start + 1000)))) for start in range(0, 20000, 1000))
    assert kept == 27
    assert len(sampler._seen) == 27  # memory follows the output, not the 20000 points read


def test_voxel_subsampler_refuses_a_bad_voxel_size_and_points_off_the_grid() -> None:
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(ConfigError, match="voxel_size_m"):
            VoxelSubsampler(bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="use a larger voxel"):
        VoxelSubsampler(0.001).filter(PointCloud(xyz=np.array([[5000.0, 0.0, 0.0]])))


def test_uniform_sampler_keeps_at_most_k_points_in_stream_order() -> None:
    cloud = _cloud(10_000, seed=4)
    sampler = UniformSampler(700, seed=9)
    for start in range(0, 10_000, 999):
        sampler.add(cloud.take(slice(start, start + 999)))
    sample = sampler.result()
    assert len(sample) == 700 and sampler.seen == 10_000
    index = sample.station.astype(np.int64)
    assert np.all(np.diff(index) > 0)  # stream order, no duplicates
    np.testing.assert_array_equal(sample.xyz, cloud.xyz[index])


def test_uniform_sampler_is_reproducible_by_seed_and_close_to_uniform() -> None:
    cloud = _cloud(20_000, seed=5)

    def sample(seed: int) -> np.ndarray:
        sampler = UniformSampler(4000, seed=seed)
        for start in range(0, 20_000, 3000):
            sampler.add(cloud.take(slice(start, start + 3000)))
        return sampler.result().station.astype(np.int64)

    first, again, other = sample(1), sample(1), sample(2)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, other)
    # every tenth of the stream holds about a tenth of the sample (binomial sd ~19 of 400)
    counts = np.bincount(first // 2000, minlength=10)
    assert counts.min() > 320 and counts.max() < 480


def test_uniform_sampler_keeps_everything_of_a_short_stream() -> None:
    cloud = _cloud(50, seed=6)
    sampler = UniformSampler(100)
    sampler.add(cloud)
    np.testing.assert_array_equal(sampler.result().xyz, cloud.xyz)
    assert len(UniformSampler(5).result()) == 0

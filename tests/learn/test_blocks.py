"""Blocks: normalisation, Table 2 sampling/padding, and passes that see every point."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bimscan.learn.blocks import (
    locate_columns, encode_column_key, normalize_block, pad_block, plan_passes, sample_block, decode_column_key,
)


def test_normalised_block_is_centred_on_its_box_and_fills_the_unit_cube() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.random((500, 3)) * [4.0, 2.0, 3.0] + [1000.0, -50.0, 7.0]

    out = normalize_block(xyz)

    assert out.dtype == np.float32
    np.testing.assert_allclose((out.min(axis=0) + out.max(axis=0)) / 2, 0.0, atol=1e-6)
    assert out.max() == pytest.approx(1.0) and out.min() == pytest.approx(-1.0)
    # isotropic scale: the aspect ratio survives
    extent = out.max(axis=0) - out.min(axis=0)
    source_extent = xyz.max(axis=0) - xyz.min(axis=0)
    np.testing.assert_allclose(extent / extent[0], source_extent / source_extent[0], rtol=1e-5)


def test_sample_block_draws_distinct_points_when_the_block_is_larger() -> None:
    rng = np.random.default_rng(1)
    xyz = rng.random((1000, 3))
    label = rng.integers(0, 5, 1000).astype(np.uint8)

    block = sample_block(xyz, label, points=256, rng=np.random.default_rng(2))

    assert block.mask.all()
    assert len(np.unique(block.index)) == 256
    np.testing.assert_array_equal(block.label, label[block.index])


def test_sample_block_pads_small_blocks_and_marks_the_padding() -> None:
    xyz = np.random.default_rng(3).random((40, 3))
    label = np.full(40, 2, dtype=np.uint8)

    block = sample_block(xyz, label, points=64, rng=np.random.default_rng(4))

    assert block.mask.sum() == 40 and not block.mask[40:].any()
    assert (block.xyz[40:] == 0).all()
    assert (block.label[40:] == 255).all() and (block.label[:40] == 2).all()
    assert (block.index[40:] == -1).all()


def test_pad_block_refuses_more_points_than_the_block_holds() -> None:
    with pytest.raises(ValueError, match="do not fit"):
        pad_block(np.zeros((10, 3)), None, np.arange(10), points=8)


@pytest.mark.parametrize("m", [1, 100, 256, 257, 1000, 2048])
def test_plan_passes_sees_every_point_with_full_groups(m: int) -> None:
    groups = plan_passes(m, points=256, rng=np.random.default_rng(m))

    seen = np.concatenate(groups)
    assert set(seen.tolist()) == set(range(m))
    assert all(len(np.unique(g)) == len(g) for g in groups)  # no point twice in one pass
    assert all(len(g) == min(m, 256) for g in groups)
    assert len(groups) == -(-m // 256)


def test_plan_passes_with_a_cap_returns_at_most_that_many_groups() -> None:
    groups = plan_passes(5000, points=256, rng=np.random.default_rng(0), max_passes=3)

    assert len(groups) == 3
    assert len(np.unique(np.concatenate(groups))) == 3 * 256


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.floats(-1e6, 1e6), st.floats(-1e6, 1e6)), min_size=1, max_size=30),
       st.sampled_from([0.5, 2.0, 4.0]))
def test_column_keys_round_trip_and_sort_by_x_then_y(points: list[tuple[float, float]], size: float) -> None:
    xy = np.array(points, dtype=np.float64)
    ix, iy = locate_columns(xy, size_m=size)

    key = encode_column_key(ix, iy)
    back_x, back_y = decode_column_key(key)

    np.testing.assert_array_equal(back_x, ix)
    np.testing.assert_array_equal(back_y, iy)
    order = np.argsort(key, kind="stable")
    assert list(zip(ix[order], iy[order])) == sorted(zip(ix, iy))

"""Labelling whole scenes: every point exactly once, overlapping blocks, a pass cap with
nearest-neighbour filling, and results independent of how the scene is streamed."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.errors import ConfigError
from bimscan.io.text import write_text_cloud
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES, BlockConfig, InputConfig, ModelConfig
from bimscan.learn.data import iter_raw_chunks, list_scenes
from bimscan.learn.density import grid_representatives
from bimscan.learn import infer
from bimscan.learn.infer import _spread_votes, label_scene
from bimscan.learn.metrics import compute_confusion
from bimscan.learn.model import build_model
from bimscan.types import PointCloud

from .conftest import denormals_kept

BLOCKS = BlockConfig(size_m=2.0, eval_stride_m=1.0, points=64, min_points=8, cache_points=128)


@pytest.fixture
def scene(tmp_path: Path, room: Callable[..., PointCloud]) -> tuple[Path, PointCloud]:
    cloud = room(7, size_m=(5.0, 3.0), points_per_m2=25, origin=(-3.3, 1.2))  # columns at negative x too
    write_text_cloud(tmp_path / "scene.txt", cloud)
    return tmp_path / "scene.txt", cloud


@pytest.fixture
def model() -> torch.nn.Module:
    torch.manual_seed(0)
    return build_model(5, ModelConfig(embed_dim=8, attention_layers=1, fuse_dim=16, head_dims=(16,), dropout=0.0)).eval()


def _label(model: torch.nn.Module, path: Path, **options: object) -> tuple[np.ndarray, np.ndarray, object]:
    indices, predictions = [], []

    def keep(index: np.ndarray, prediction: np.ndarray) -> None:
        indices.append(index.copy())
        predictions.append(prediction.copy())

    result = label_scene(model, list_scenes([path])[0], class_names=DEFAULT_CLASS_NAMES, blocks=BLOCKS,
                         on_labels=keep, **options)  # type: ignore[arg-type]
    return np.concatenate(indices), np.concatenate(predictions), result


def test_every_point_of_the_scene_gets_exactly_one_label(
    scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    path, cloud = scene

    index, prediction, result = _label(model, path)

    assert np.array_equal(np.sort(index), np.arange(len(cloud)))
    assert prediction.dtype == np.uint8 and prediction.max() < 5
    assert result.points == result.labelled == len(cloud)
    assert result.nearest_filled == 0
    # every point was seen in each of the blocks covering it: at least one pass per point
    assert result.passes * BLOCKS.points >= len(cloud)
    ordered = np.empty(len(cloud), np.uint8)
    ordered[index] = prediction
    np.testing.assert_array_equal(result.confusion, compute_confusion(cloud.label, ordered, num_classes=5))


@pytest.mark.parametrize("grid_m", [0.0, 0.25])
def test_labels_do_not_depend_on_how_the_scene_is_streamed(
    scene: tuple[Path, PointCloud], model: torch.nn.Module, grid_m: float,
) -> None:
    path, _ = scene
    inputs = InputConfig(grid_m=grid_m, features=("xyz",))

    index_a, prediction_a, _ = _label(model, path, chunk_points=777, inputs=inputs)
    index_b, prediction_b, _ = _label(model, path, chunk_points=10**6, inputs=inputs)

    np.testing.assert_array_equal(prediction_a[np.argsort(index_a)], prediction_b[np.argsort(index_b)])


def test_a_pass_cap_labels_the_unseen_points_from_their_nearest_neighbours(
    scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    path, cloud = scene

    index, _, result = _label(model, path, max_passes=1)

    assert result.nearest_filled > 0
    assert np.array_equal(np.sort(index), np.arange(len(cloud)))


@pytest.mark.parametrize("chunk", [100, 10**6])
def test_points_off_the_grid_take_the_distance_weighted_votes_of_the_nearest_representatives(
    chunk: int, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(infer, "SPREAD_CHUNK", chunk)
    rng = np.random.default_rng(5)
    xyz = rng.random((3000, 3)) * [2.0, 1.5, 1.0]
    representatives, rep_of = grid_representatives(xyz, 0.2)
    votes = np.zeros((len(xyz), 5), np.float32)
    votes[representatives] = rng.random((len(representatives), 5))
    votes[representatives[::7]] = 0.0  # representatives no pass saw lend no votes

    spread = _spread_votes(votes, xyz, representatives, rep_of, 3)

    np.testing.assert_array_equal(spread[representatives], votes[representatives])
    voted = representatives[votes[representatives].sum(axis=1) > 0]
    others = np.setdiff1d(np.arange(len(xyz)), representatives)
    distance = np.linalg.norm(xyz[others, None, :] - xyz[None, voted, :], axis=2)  # brute force
    nearest = np.argsort(distance, axis=1)[:, :3]
    weight = 1.0 / np.take_along_axis(distance, nearest, axis=1) ** 2
    expected = (weight[..., None] * votes[voted][nearest]).sum(axis=1) / weight.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(spread[others], expected, rtol=1e-5)
    # 0 neighbours: the votes of the voxel's own representative, as before
    np.testing.assert_array_equal(_spread_votes(votes, xyz, representatives, rep_of, 0), votes[rep_of])


def test_interpolated_labels_keep_the_representatives_and_change_only_other_points(
    scene: tuple[Path, PointCloud],
) -> None:
    path, _ = scene
    results = {}

    class ByPosition(torch.nn.Module):  # a class per part of the block: labels that vary in space
        def forward(self, xyz: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return torch.cat([4.0 * xyz[..., :3], torch.zeros_like(xyz[..., :2])], dim=-1)

    for neighbours in (0, 3):
        inputs = InputConfig(grid_m=0.5, features=("xyz",), label_neighbours=neighbours)
        index, prediction, _ = _label(ByPosition(), path, inputs=inputs)
        results[neighbours] = prediction[np.argsort(index)]
    xyz = np.concatenate([c.xyz for c in iter_raw_chunks(list_scenes([path])[0], labels=False)])  # as read
    representatives, rep_of = grid_representatives(xyz, 0.5)

    # 0.5 m voxels fall inside the 1 m stripes: one representative per voxel in every window
    np.testing.assert_array_equal(results[3][representatives], results[0][representatives])
    np.testing.assert_array_equal(results[0], results[0][rep_of])  # a voxel shares one label
    assert (results[3] != results[0]).any()  # points near other voxels' representatives move


def test_eval_votes_shuffle_every_column_again(scene: tuple[Path, PointCloud], model: torch.nn.Module) -> None:
    path, cloud = scene
    _, _, once = _label(model, path)
    labelled = []

    def keep(index: np.ndarray, prediction: np.ndarray) -> None:
        labelled.append(index)

    thrice = label_scene(model, list_scenes([path])[0], class_names=DEFAULT_CLASS_NAMES, on_labels=keep,
                         blocks=dataclasses.replace(BLOCKS, eval_votes=3))

    assert thrice.blocks == once.blocks
    assert thrice.passes == 3 * once.passes  # every block cut into groups three times
    assert np.array_equal(np.sort(np.concatenate(labelled)), np.arange(len(cloud)))  # each point once
    with pytest.raises(ConfigError, match="eval_votes must be in 1..64"):
        dataclasses.replace(BLOCKS, eval_votes=0)


def test_blocks_overlap_as_configured(scene: tuple[Path, PointCloud], model: torch.nn.Module) -> None:
    path, cloud = scene
    x_columns = np.unique(np.floor(cloud.xyz[:, 0] / 1.0)).size
    y_columns = np.unique(np.floor(cloud.xyz[:, 1] / 1.0)).size

    _, _, result = _label(model, path)

    # 2 m columns every 1 m: one block per pair of neighbouring 1 m cells, in x and in y
    assert result.blocks == (x_columns - 1) * (y_columns - 1)


def test_stripe_files_are_removed_afterwards(
    tmp_path: Path, scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    work = tmp_path / "work"
    work.mkdir()

    _label(model, scene[0], work_dir=work)

    assert list(work.iterdir()) == []


def test_labelling_memory_does_not_grow_with_the_scene_length(tmp_path: Path, model: torch.nn.Module) -> None:
    import tracemalloc

    rng = np.random.default_rng(0)
    peaks = {}
    for length in (10.0, 40.0, 160.0):  # a corridor 4x longer: 4x the points; the first warms up
        n = int(length * 2500)
        xyz = rng.random((n, 3)) * [length, 3.0, 3.0]
        write_text_cloud(tmp_path / f"corridor{length:.0f}.txt", PointCloud(xyz=xyz, label=rng.integers(0, 5, n).astype(np.uint8)))
        source = list_scenes([tmp_path / f"corridor{length:.0f}.txt"])[0]
        runs = []
        # twice, keeping the lower peak: a one-time growth of an interpreter-wide table (the
        # interned strings' dict, about 4 MB under pytest) can land in any single run
        for _ in range(2):
            tracemalloc.start()
            result = label_scene(model, source, class_names=DEFAULT_CLASS_NAMES, blocks=BLOCKS, max_passes=1,
                                 chunk_points=5000)
            runs.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
            assert result.points == n
        peaks[length] = min(runs)

    # only the stripes under the current column are in memory, not the scene (reading the
    # whole 160 m scene in one chunk instead peaks at about 4x the 40 m one)
    assert peaks[160.0] < 1.3 * peaks[40.0], peaks


def test_denormals_are_flushed_for_the_network_only(
    scene: tuple[Path, PointCloud], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Flush-to-zero speeds the network up but crashed SciPy's cKDTree (a segmentation fault on
    some blocks): the features' neighbour search must run with it off, the forward with it on."""
    import bimscan.learn.features as features
    from bimscan.learn.train_config import InputConfig

    torch.manual_seed(0)
    model = build_model(5, ModelConfig(embed_dim=8, attention_layers=1, fuse_dim=16, head_dims=(16,), dropout=0.0),
                        in_dim=6).eval()  # xyz and normals
    seen: dict[str, list[bool]] = {"features": [], "network": []}
    geometry, forward = features.local_geometry, model.forward

    def spy_geometry(xyz: np.ndarray, *, neighbours: int) -> tuple[np.ndarray, np.ndarray]:
        seen["features"].append(denormals_kept())
        return geometry(xyz, neighbours=neighbours)

    def spy_forward(xyz: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        seen["network"].append(denormals_kept())
        return forward(xyz, mask)

    monkeypatch.setattr(features, "local_geometry", spy_geometry)
    monkeypatch.setattr(model, "forward", spy_forward)
    label_scene(model, list_scenes([scene[0]])[0], class_names=DEFAULT_CLASS_NAMES, blocks=BLOCKS,
                inputs=InputConfig(grid_m=0.0, features=("xyz", "normals")))
    assert seen["features"] and all(seen["features"])
    assert seen["network"] and not any(seen["network"])
    assert denormals_kept()  # and never left on

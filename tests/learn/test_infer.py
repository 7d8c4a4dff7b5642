"""Labelling whole scenes: every point exactly once, overlapping blocks, a pass cap with
nearest-neighbour filling, and results independent of how the scene is streamed."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.io.text import write_text_cloud
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES, BlockConfig, ModelConfig
from bimscan.learn.data import list_scenes
from bimscan.learn.infer import label_scene
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


def test_labels_do_not_depend_on_how_the_scene_is_streamed(
    scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    path, _ = scene

    index_a, prediction_a, _ = _label(model, path, chunk_points=777)
    index_b, prediction_b, _ = _label(model, path, chunk_points=10**6)

    np.testing.assert_array_equal(prediction_a[np.argsort(index_a)], prediction_b[np.argsort(index_b)])


def test_a_pass_cap_labels_the_unseen_points_from_their_nearest_neighbours(
    scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    path, cloud = scene

    index, _, result = _label(model, path, max_passes=1)

    assert result.nearest_filled > 0
    assert np.array_equal(np.sort(index), np.arange(len(cloud)))


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

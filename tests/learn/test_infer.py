"""Labelling whole scenes: every point exactly once, overlapping blocks, a pass cap with
nearest-neighbour filling, and results independent of how the scene is streamed."""

from __future__ import annotations

import dataclasses

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.errors import ConfigError, LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES, BlockConfig, EvalConfig, InputConfig, ModelConfig
from bimscan.learn.data import iter_raw_chunks, list_scenes
from bimscan.learn.density import voxel_representatives
from bimscan.learn import infer
from bimscan.learn import neighbours as neighbour_cells
from bimscan.learn.infer import label_scene, spread_votes
from bimscan.learn.metrics import compute_confusion
from bimscan.learn.model import build_model
from bimscan.types import PointCloud

from .conftest import denormals_kept

BLOCKS = BlockConfig(size_m=2.0, points=64, min_points=8, cache_points=128)


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

    result = label_scene(model, list_scenes([path])[0], class_names=DEFAULT_CLASS_NAMES, on_labels=keep,
                         **{"blocks": BLOCKS, **options})  # type: ignore[arg-type]
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

    index, _, result = _label(model, path, evaluation=EvalConfig(max_passes=1))

    assert result.nearest_filled > 0
    assert np.array_equal(np.sort(index), np.arange(len(cloud)))


@pytest.mark.parametrize("chunk", [100, 10**6])
@pytest.mark.parametrize(("cell_m", "max_cells"), [
    (0.0, 1 << 23),  # a k-d tree for every point
    (0.3, 1 << 23),  # the cells around each point (1.5 voxels), the k-d tree for the few they do not settle
    (0.05, 1 << 23),  # cells too small to settle most points: the k-d tree for many
    (0.3, 1),  # a table over the limit: the k-d tree for all
])
def test_points_off_the_grid_take_the_distance_weighted_votes_of_the_nearest_representatives(
    chunk: int, cell_m: float, max_cells: int, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(infer, "SPREAD_CHUNK", chunk)
    monkeypatch.setattr(neighbour_cells, "MAX_CELLS", max_cells)
    rng = np.random.default_rng(5)
    xyz = rng.random((3000, 3)) * [2.0, 1.5, 1.0]
    representatives, rep_of = voxel_representatives(xyz, 0.2)
    rep_votes = rng.random((len(representatives), 5)).astype(np.float32)
    rep_votes[::7] = 0.0  # representatives no pass saw lend no votes
    votes = np.zeros((len(xyz), 5), np.float32)
    votes[representatives] = rep_votes

    spread = spread_votes(rep_votes, xyz, representatives, rep_of, 3, cell_m=cell_m)

    np.testing.assert_array_equal(spread[representatives], rep_votes)
    voted = representatives[rep_votes.sum(axis=1) > 0]
    others = np.setdiff1d(np.arange(len(xyz)), representatives)
    distance = np.linalg.norm(xyz[others, None, :] - xyz[None, voted, :], axis=2)  # brute force
    nearest = np.argsort(distance, axis=1)[:, :3]
    weight = 1.0 / np.take_along_axis(distance, nearest, axis=1) ** 2
    expected = (weight[..., None] * votes[voted][nearest]).sum(axis=1) / weight.sum(axis=1, keepdims=True)
    np.testing.assert_allclose(spread[others], expected, rtol=1e-5)
    # 0 neighbours: the votes of the voxel's own representative
    np.testing.assert_array_equal(spread_votes(rep_votes, xyz, representatives, rep_of, 0), votes[rep_of])
    # the representatives of the next stripe lend their votes too
    near = (xyz[rep_of != np.arange(len(xyz))][:1] + [0.001, 0.0, 0.0])
    lent = spread_votes(rep_votes, xyz, representatives, rep_of, 1, others=[(near, np.eye(5, dtype=np.float32)[:1])],
                        cell_m=cell_m)
    assert lent[np.flatnonzero(rep_of != np.arange(len(xyz)))[0]].argmax() == 0


def test_interpolated_labels_keep_the_representatives_and_change_only_other_points(
    scene: tuple[Path, PointCloud],
) -> None:
    path, _ = scene
    results = {}

    class ByPosition(torch.nn.Module):  # a class per part of the block: labels that vary in space
        def forward(self, xyz: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
            return torch.cat([4.0 * xyz[..., :3], torch.zeros_like(xyz[..., :2])], dim=-1)

    for neighbours in (0, 3):
        inputs = InputConfig(grid_m=0.5, features=("xyz",))
        index, prediction, _ = _label(ByPosition(), path, inputs=inputs, evaluation=EvalConfig(label_neighbours=neighbours))
        results[neighbours] = prediction[np.argsort(index)]
    xyz = np.concatenate([c.xyz for c in iter_raw_chunks(list_scenes([path])[0], labels=False)])  # as read
    representatives, rep_of = voxel_representatives(xyz - xyz.min(axis=0), 0.5)  # voxels from the scene's corner

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
                         blocks=BLOCKS, evaluation=EvalConfig(votes=3))

    assert thrice.blocks == once.blocks
    # every block of more than N points cut into groups three times; a smaller one passes whole once
    assert once.passes < thrice.passes <= 3 * once.passes
    assert np.array_equal(np.sort(np.concatenate(labelled)), np.arange(len(cloud)))  # each point once
    with pytest.raises(ConfigError, match="votes must be an integer in 1..64"):
        EvalConfig(votes=0)


def test_a_block_that_fits_one_pass_is_not_passed_again_for_its_votes(
    scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    path, _ = scene
    roomy = dataclasses.replace(BLOCKS, points=4096, cache_points=4096)  # every block fits one pass
    index1, labels1, once = _label(model, path, blocks=roomy)
    index3, labels3, thrice = _label(model, path, blocks=roomy, evaluation=EvalConfig(votes=3))
    assert thrice.passes == once.passes == once.blocks  # the same points in the same order would give the same votes
    assert np.array_equal(index1, index3) and np.array_equal(labels1, labels3)


def test_columns_overlap_as_the_stride_says(scene: tuple[Path, PointCloud], model: torch.nn.Module) -> None:
    path, cloud = scene
    corner = cloud.xyz.min(axis=0)  # columns count from the scene's own corner
    x_columns = np.unique(np.floor((cloud.xyz[:, 0] - corner[0]) / 1.0)).size
    y_columns = np.unique(np.floor((cloud.xyz[:, 1] - corner[1]) / 1.0)).size

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
            result = label_scene(model, source, class_names=DEFAULT_CLASS_NAMES, blocks=BLOCKS,
                                 evaluation=EvalConfig(max_passes=1), chunk_points=5000)
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
    geometry, forward = features.local_geometry_scales, model.forward

    def spy_geometry(xyz: np.ndarray, scales: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
        seen["features"].append(denormals_kept())
        return geometry(xyz, scales)

    def spy_forward(xyz: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        seen["network"].append(denormals_kept())
        return forward(xyz, mask)

    monkeypatch.setattr(features, "local_geometry_scales", spy_geometry)
    monkeypatch.setattr(model, "forward", spy_forward)
    label_scene(model, list_scenes([scene[0]])[0], class_names=DEFAULT_CLASS_NAMES, blocks=BLOCKS,
                inputs=InputConfig(grid_m=0.0, features=("xyz", "normals")))
    assert seen["features"] and all(seen["features"])
    assert seen["network"] and not any(seen["network"])
    assert denormals_kept()  # and never left on


def _ordered(model: torch.nn.Module, path: Path, **options: object) -> tuple[np.ndarray, object]:
    index, prediction, result = _label(model, path, **options)
    out = np.empty(len(index), np.uint8)
    out[index] = prediction
    return out, result


RECIPE_INPUTS = InputConfig(grid_m=0.1, features=("xyz", "height", "normals", "shape"))


class LinearProbe(torch.nn.Module):
    """A fixed linear map of each point's input channels to class scores: unlike an untrained PCT
    (one class everywhere) its labels change with every input channel, so equal labels mean equal
    inputs."""

    def __init__(self, in_dim: int) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.randn(in_dim, 5, generator=torch.Generator().manual_seed(0)) * 3.0)

    def forward(self, xyz: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return xyz @ self.weight


def _recipe_model() -> torch.nn.Module:
    from bimscan.learn.features import input_channels

    return LinearProbe(input_channels(RECIPE_INPUTS.features)).eval()


def _varied(labels: np.ndarray) -> np.ndarray:
    counts = np.bincount(labels, minlength=5)
    assert (counts > 0.02 * len(labels)).sum() >= 3, counts  # the comparison means something
    return labels


def test_the_wide_shape_reaches_inference_with_its_own_neighbourhood(tmp_path: Path,
                                                                     room: Callable[..., PointCloud]) -> None:
    """``shape_wide`` is computed over ``wide_neighbours`` at inference as in training: the probe's
    labels change with the neighbourhood."""
    from bimscan.learn.features import input_channels

    cloud = room(3, size_m=(5.0, 4.0), points_per_m2=40)
    write_text_cloud(tmp_path / "room.txt", cloud)
    inputs = InputConfig(grid_m=0.1, features=("xyz", "shape_wide"), wide_neighbours=64)
    assert input_channels(inputs.features) == 6
    model = LinearProbe(6).eval()
    wide, _ = _ordered(model, tmp_path / "room.txt", inputs=inputs)
    _varied(wide)
    narrower, _ = _ordered(model, tmp_path / "room.txt", inputs=dataclasses.replace(inputs, wide_neighbours=8))
    assert (wide != narrower).mean() > 0.05
    with pytest.raises(ConfigError, match="wide_neighbours"):
        dataclasses.replace(inputs, wide_neighbours=2)


def test_a_scene_moved_far_away_gets_the_same_labels(tmp_path: Path, room: Callable[..., PointCloud]) -> None:
    """Columns, voxels and floors count from the scene itself: georeferenced coordinates (a site
    hundreds of kilometres from its origin) change nothing."""
    cloud = room(3, size_m=(5.0, 4.0), points_per_m2=40)
    shift = np.array([412_345.678, 5_321_987.654, 231.5])  # UTM-like
    write_text_cloud(tmp_path / "here.txt", cloud)
    write_text_cloud(tmp_path / "there.txt", PointCloud(xyz=cloud.xyz + shift, label=cloud.label))
    model = _recipe_model()

    here, _ = _ordered(model, tmp_path / "here.txt", inputs=RECIPE_INPUTS)
    _varied(here)
    there, _ = _ordered(model, tmp_path / "there.txt", inputs=RECIPE_INPUTS)

    # the coordinates themselves differ in their last bits after the shift (float64, 6 decimals in text)
    assert (here == there).mean() > 0.995


def test_the_same_scene_in_another_format_gets_the_same_labels(tmp_path: Path, room: Callable[..., PointCloud]) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.semantics import DEFAULT_SCHEME, load_scheme
    from bimscan.types import CloudHeader

    cloud = room(4, size_m=(4.0, 4.0), points_per_m2=40)
    cloud = PointCloud(xyz=np.round(cloud.xyz, 3), label=cloud.label)  # millimetres: what LAS stores exactly
    write_text_cloud(tmp_path / "room.txt", cloud)
    for name in ("room.ply", "room.laz"):
        with open_cloud_writer(tmp_path / name, header=CloudHeader(scheme=load_scheme(DEFAULT_SCHEME))) as writer:
            writer.write(cloud)
    model = _recipe_model()

    text, _ = _ordered(model, tmp_path / "room.txt", inputs=RECIPE_INPUTS)
    _varied(text)
    for name in ("room.ply", "room.laz"):
        other, _ = _ordered(model, tmp_path / name, inputs=RECIPE_INPUTS)
        assert (other == text).mean() > 0.995, name


def test_each_storey_is_labelled_in_blocks_of_its_own(tmp_path: Path, room: Callable[..., PointCloud]) -> None:
    """A column through two storeys is cut at the floors: the upper storey's blocks hold its points
    only, as if it were scanned alone (the network never saw a block of two storeys)."""
    lower = room(5, size_m=(4.0, 3.0), points_per_m2=30)
    upper = PointCloud(xyz=lower.xyz + [0.0, 0.0, 3.4], label=lower.label)  # the same room one storey up
    both = PointCloud(xyz=np.concatenate([lower.xyz, upper.xyz]), label=np.concatenate([lower.label, upper.label]))
    write_text_cloud(tmp_path / "both.txt", both)
    write_text_cloud(tmp_path / "lower.txt", lower)
    write_text_cloud(tmp_path / "upper.txt", upper)
    inputs = InputConfig(grid_m=0.1, features=("xyz", "height"))
    model = LinearProbe(4).eval()

    labels_both, result_both = _ordered(model, tmp_path / "both.txt", inputs=inputs)
    _, result_lower = _ordered(model, tmp_path / "lower.txt", inputs=inputs)
    labels_upper, result_upper = _ordered(model, tmp_path / "upper.txt", inputs=inputs)

    assert result_both.blocks == result_lower.blocks + result_upper.blocks  # type: ignore[attr-defined]
    # the upper storey's labels as when scanned alone (its blocks, its heights above its own floor)
    assert (labels_both[len(lower):] == _varied(labels_upper)).mean() > 0.99


def test_a_sparse_cloud_kilometres_wide_is_quick_and_warned_about(tmp_path: Path, model: torch.nn.Module) -> None:
    """Only the columns that hold points are labelled: 1,000 points over 10 km take seconds. Its extent gets one warning line (no building is 10 km wide: the unit is likely wrong)."""
    import time

    rng = np.random.default_rng(0)
    xyz = rng.random((1000, 3)) * [10_000.0, 10_000.0, 3.0]
    write_text_cloud(tmp_path / "sparse.txt", PointCloud(xyz=xyz, label=rng.integers(0, 5, 1000).astype(np.uint8)))
    warned: list[str] = []
    started = time.perf_counter()

    index, _, result = _label(model, tmp_path / "sparse.txt", warn=warned.append)

    assert time.perf_counter() - started < 60.0  # every 1 m column over 10 km: 10^8 columns, hours
    assert np.array_equal(np.sort(index), np.arange(1000))
    assert len(warned) == 1 and "check its unit" in warned[0]


def test_a_room_in_millimetres_is_refused_in_seconds_with_the_unit_named(
    tmp_path: Path, room: Callable[..., PointCloud], model: torch.nn.Module,
) -> None:
    """Read as metres, a room in millimetres puts about one point in each column: labelling it would
    pass every point through the network alone (minutes for a real room, labels of no use)."""
    import time

    cloud = room(8, size_m=(4.0, 3.0), points_per_m2=200)
    write_text_cloud(tmp_path / "mm.txt", PointCloud(xyz=cloud.xyz * 1000.0, label=cloud.label))
    warned: list[str] = []
    started = time.perf_counter()

    with pytest.raises(LearnError, match=r"looks like millimetres, so scale it to metres first .*per column"):
        _label(model, tmp_path / "mm.txt", warn=warned.append)

    assert time.perf_counter() - started < 30.0
    assert warned == []


def test_a_dense_scene_too_wide_for_metres_is_labelled_with_a_warning(
    tmp_path: Path, room: Callable[..., PointCloud], model: torch.nn.Module,
) -> None:
    """Too wide and tall for a building in metres, but with many points in every column (centimetres would
    fit it): labelled as given, the likely unit named in a warning."""
    rng = np.random.default_rng(3)
    xyz = rng.random((90_000, 3)) * [2_100.0, 0.4, 250.0]
    write_text_cloud(tmp_path / "cm.txt", PointCloud(xyz=xyz, label=rng.integers(0, 5, len(xyz)).astype(np.uint8)))
    warned: list[str] = []

    index, _, _ = _label(model, tmp_path / "cm.txt", warn=warned.append)

    assert np.array_equal(np.sort(index), np.arange(len(xyz)))
    assert len(warned) == 1 and "it looks like centimetres" in warned[0]


def _plane_scene() -> tuple[np.ndarray, np.ndarray]:
    """Representatives 0.1 m apart of a wall (x = 0, 4 m x 2.5 m) and a floor (z = 0, 3 m x 3 m),
    and their normals."""
    y, z = np.meshgrid(np.arange(0.0, 4.0, 0.1), np.arange(0.0, 2.5, 0.1), indexing="ij")
    wall = np.column_stack([np.zeros(y.size), y.ravel(), z.ravel()])
    x, y = np.meshgrid(np.arange(0.5, 3.5, 0.1), np.arange(0.0, 3.0, 0.1), indexing="ij")
    floor = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    from bimscan.learn.features import estimate_normals
    from bimscan.learn.regions import NORMAL_NEIGHBOURS

    xyz = np.concatenate([wall, floor])
    return xyz, estimate_normals(xyz, neighbours=NORMAL_NEIGHBOURS)


def test_a_vertical_plane_gives_its_walls_and_others_the_class_most_of_it_has() -> None:
    from bimscan.learn.regions import MIN_REGION, plane_votes

    xyz, normal = _plane_scene()
    wall = np.flatnonzero(xyz[:, 0] == 0.0)
    floor = np.flatnonzero(xyz[:, 0] != 0.0)
    assert np.abs(normal[wall, 0]).min() > 0.99 and np.abs(normal[floor, 2]).min() > 0.99
    wc, beam, covering, slab, others = range(5)
    votes = np.zeros((len(xyz), 5), dtype=np.float32)
    votes[wall, wc] = 0.7
    votes[wall, others] = 0.2
    behind_desk = wall[(xyz[wall, 2] < 0.8) & (xyz[wall, 1] < 1.5)]  # the network said Others there
    votes[behind_desk, wc], votes[behind_desk, others] = 0.3, 0.6
    a_beam = wall[(xyz[wall, 2] > 2.35) & (xyz[wall, 1] > 3.5)]  # another class: left alone
    votes[a_beam, beam] = 2.0
    votes[floor, others] = 0.6  # a horizontal plane does not vote
    votes[floor, slab] = 0.3
    mine = np.arange(len(xyz))
    after = plane_votes(xyz, normal, votes, mine, wc, others)
    assert set(after[behind_desk].argmax(axis=1).tolist()) == {wc}
    np.testing.assert_allclose(after[behind_desk, wc], 0.9, rtol=1e-6)  # the two classes' votes, summed on it
    assert set(after[a_beam].argmax(axis=1).tolist()) == {beam}
    np.testing.assert_array_equal(after[floor], votes[floor])
    # only the representatives asked for come back, computed over all of them (the stripes around)
    part = wall[::7]
    np.testing.assert_array_equal(plane_votes(xyz, normal, votes, part, wc, others), after[part])
    # a region too small to vote is left as it is
    few = behind_desk[: MIN_REGION - 1]
    np.testing.assert_array_equal(plane_votes(xyz[few], normal[few], votes[few], np.arange(len(few)), wc, others),
                                  votes[few])


def test_plane_votes_in_a_streamed_scene_do_not_depend_on_its_chunks_and_need_the_two_classes(
    scene: tuple[Path, PointCloud], model: torch.nn.Module,
) -> None:
    path, _ = scene
    evaluation = EvalConfig(plane_votes=True)
    inputs = InputConfig(grid_m=0.25, features=("xyz",))
    first = _label(model, path, evaluation=evaluation, inputs=inputs, chunk_points=10_000)
    second = _label(model, path, evaluation=evaluation, inputs=inputs, chunk_points=333)
    ordered = [np.empty(len(f[0]), np.uint8) for f in (first, second)]
    for out, (index, prediction, _) in zip(ordered, (first, second)):
        out[index] = prediction
    np.testing.assert_array_equal(ordered[0], ordered[1])
    with pytest.raises(LearnError, match="plane_votes: the model has no class 'Wall&Column'"):
        label_scene(model, list_scenes([path])[0], class_names=("a", "b", "c", "d", "e"), blocks=BLOCKS,
                    evaluation=evaluation, on_labels=lambda index, prediction: None)

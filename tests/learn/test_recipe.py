"""The sim-to-real recipe: density normalisation, augmentations, extra features, class weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from bimscan.errors import ConfigError
from bimscan.io.text import write_text_cloud
from bimscan.learn.augment import augment_points
from bimscan.learn.data import TileDataset, collect_scene_tiles, list_scenes
from bimscan.learn.density import grid_representatives, grid_sample, voxel_index
from bimscan.learn.features import estimate_normals, extra_features, local_geometry
from bimscan.learn.train import class_weights_from_labels, compute_loss
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES, AugmentConfig, BlockConfig, EvalConfig, InputConfig
from bimscan.types import PointCloud

from .conftest import COVERING, SLAB, make_room


def _as_set(xyz: np.ndarray) -> set[tuple[float, float, float]]:
    return {tuple(p) for p in np.asarray(xyz).tolist()}


def test_grid_sampling_keeps_one_point_per_voxel_whatever_the_order() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.random((20_000, 3)) * [4.0, 3.0, 2.5]
    picked = grid_sample(xyz, 0.2)
    cells = voxel_index(xyz[picked], 0.2)
    assert len(np.unique(cells, axis=0)) == len(picked)  # one per voxel
    assert len(picked) == len(np.unique(voxel_index(xyz, 0.2), axis=0))  # every occupied voxel
    for seed in (1, 2, 3):
        order = np.random.default_rng(seed).permutation(len(xyz))
        assert _as_set(xyz[order][grid_sample(xyz[order], 0.2)]) == _as_set(xyz[picked])


def test_every_point_maps_to_a_representative_of_its_own_voxel() -> None:
    xyz = np.random.default_rng(4).random((5000, 3)) * 2.0
    reps, rep_of = grid_representatives(xyz, 0.25)
    assert np.array_equal(np.unique(rep_of), reps)
    assert np.array_equal(voxel_index(xyz[rep_of], 0.25), voxel_index(xyz, 0.25))
    assert np.array_equal(rep_of[reps], reps)


def test_grid_tiles_do_not_depend_on_point_order_or_chunking(tmp_path: Path) -> None:
    room = make_room(3, size_m=(5.0, 4.0), points_per_m2=150)
    order = np.random.default_rng(9).permutation(len(room))
    write_text_cloud(tmp_path / "a.txt", room)
    write_text_cloud(tmp_path / "a-shuffled.txt", PointCloud(xyz=room.xyz[order], label=room.label[order]))
    blocks = BlockConfig(size_m=2.0, points=64, min_points=16, cache_points=200)
    results = []
    for name, chunk in (("a.txt", 1_000_000), ("a-shuffled.txt", 1_000_000), ("a-shuffled.txt", 3001)):
        source = list_scenes([tmp_path / name])[0]
        source = type(source)(source.path, source.kind, "room", None, None)  # same name: same seed
        results.append(collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0,
                                           chunk_points=chunk, grid_m=0.1))
    first = results[0]
    assert len(first) > 4 and (np.diff(first.offsets) == 200).any()  # some columns hit the cap
    for other in results[1:]:
        assert np.array_equal(first.key, other.key) and np.array_equal(first.offsets, other.offsets)
        for t in range(len(first)):
            a, b = first.tile_points(t), other.tile_points(t)
            assert _as_set(a[0] + first.origin[t]) == _as_set(b[0] + other.origin[t])
    absolute = np.concatenate([first.tile_points(t)[0] + first.origin[t] for t in range(len(first))])
    assert len(np.unique(voxel_index(absolute + 1e-9, 0.1), axis=0)) >= len(absolute) * 0.99  # ~one per voxel


def test_augmentation_is_seeded_and_keeps_labels_with_their_points() -> None:
    room = make_room(1, size_m=(3.0, 3.0), points_per_m2=80)
    config = AugmentConfig()
    a, ka, sa = augment_points(room.xyz, config=config, rng=np.random.default_rng(5))
    b, kb, sb = augment_points(room.xyz, config=config, rng=np.random.default_rng(5))
    c, _, _ = augment_points(room.xyz, config=config, rng=np.random.default_rng(6))
    assert sa == sb and 0.9 <= sa <= 1.1
    assert np.array_equal(a, b) and np.array_equal(ka, kb)
    assert len(c) != len(a) or not np.allclose(c, a)
    label = room.label[ka]
    # floor points stay below ceiling points, whatever rotation, flips, scaling and distortion
    assert a[label == SLAB, 2].max() < a[label == COVERING, 2].min()
    # rotation + flips + scaling only: distances between points scale by at most the scale range
    rigid = AugmentConfig(jitter_sigma_m=0.0, dropout_max=0.0, elastic=(), anisotropic=False)
    moved, kept, z_scale = augment_points(room.xyz, config=rigid, rng=np.random.default_rng(7))
    assert len(kept) == len(room)
    ratio = np.linalg.norm(moved[1:] - moved[0], axis=1) / np.linalg.norm(room.xyz[1:] - room.xyz[0], axis=1)
    assert np.allclose(ratio, ratio[0]) and 0.9 <= ratio[0] <= 1.1 and ratio[0] == pytest.approx(z_scale)


def test_augmented_blocks_are_identical_for_the_same_key_and_aligned(tmp_path: Path) -> None:
    write_text_cloud(tmp_path / "r.txt", make_room(2, size_m=(4.0, 4.0), points_per_m2=60))
    source = list_scenes([tmp_path / "r.txt"])[0]
    blocks = BlockConfig(size_m=4.0, points=256, min_points=16, cache_points=2048)
    tiles = collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0, grid_m=0.05)
    dataset = TileDataset(tiles, points=256, seed=0, inputs=InputConfig(grid_m=0.05), augment=AugmentConfig())
    one, two = dataset[(3, 0)], dataset[(3, 0)]
    assert all(np.array_equal(one[k], two[k]) for k in one)
    assert one["xyz"].shape == (256, 10)  # xyz, height, normals, shape
    other = dataset[(4, 0)]
    assert not np.array_equal(one["xyz"], other["xyz"])
    valid = one["mask"]
    height = one["xyz"][valid, 3]
    label = one["label"][valid]
    # the height channel puts floor points near 0 and ceiling points near 1 (3 m / 3 m)
    assert np.all(height[label == SLAB] < 0.2) and np.all(height[label == COVERING] > 0.8)


def test_a_floor_gets_upward_normals_and_its_height_in_storeys_and_a_wall_horizontal_normals() -> None:
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.random(500) * 2, rng.random(500) * 2, np.full(500, 1.0)])
    wall = np.column_stack([np.full(500, 3.0), rng.random(500) * 2, 1.0 + rng.random(500) * 2])
    normals = estimate_normals(np.concatenate([floor, wall]), neighbours=12)
    assert np.allclose(normals[:500], [0.0, 0.0, 1.0], atol=1e-6)
    assert np.allclose(np.abs(normals[500:, 0]), 1.0, atol=1e-6)
    extra = extra_features(floor, features=("xyz", "height", "normals"), height_m=np.full(500, 0.6),
                           height_scale_m=3.0, neighbours=8)
    assert extra.shape == (500, 4) and np.allclose(extra[:, 0], 0.2)
    assert extra_features(floor, features=("xyz",), height_m=None, height_scale_m=3.0, neighbours=8) is None


def test_shape_features_tell_planes_lines_and_scatter_apart() -> None:
    rng = np.random.default_rng(1)
    plane = np.column_stack([rng.random(400) * 2, rng.random(400) * 2, np.full(400, 1.0)])
    line = np.column_stack([10.0 + rng.random(400) * 2, np.zeros(400), np.full(400, 1.0)])
    blob = 20.0 + rng.normal(0.0, 0.1, (400, 3))  # an isotropic heap
    points = np.concatenate([plane, line, blob])
    normals, shape = local_geometry(points, neighbours=16)
    assert np.allclose(shape.sum(axis=1), 1.0, atol=1e-5)
    assert np.allclose(normals, estimate_normals(points, neighbours=16))
    linearity, planarity, scattering = shape.T
    assert np.all(scattering[:400] < 1e-6) and np.median(planarity[:400]) > np.median(linearity[:400])
    assert np.all(linearity[400:800] > 0.999)
    assert np.median(scattering[800:]) > 0.3 and np.median(scattering[800:]) > 5 * np.median(scattering[:400] + 1e-9)
    # the same points in another order: the same features, point for point
    order = rng.permutation(len(points))
    assert np.allclose(local_geometry(points[order], neighbours=16)[1], shape[order], atol=1e-6)
    extra = extra_features(points, features=("xyz", "normals", "shape"), height_m=None, height_scale_m=3.0,
                           neighbours=16)
    assert extra.shape == (1200, 6) and np.allclose(extra[:, 3:], shape)
    assert local_geometry(points[:2], neighbours=16)[1].shape == (2, 3)


def test_wide_shape_tells_a_wall_from_a_cabinet_side() -> None:
    """At the recipe's 32 neighbours a cabinet's side looks much like a wall; at 128 its top and front
    join its neighbourhood and it is no plane, while the wall stays one."""
    rng = np.random.default_rng(2)
    density = 40  # points per square metre: about a recipe block's (1024 points in a 3 m column)

    def patch(area_m2: float) -> tuple[np.ndarray, int]:
        count = int(area_m2 * density)
        return rng.random(count), count

    u, n = patch(18.0)
    wall = np.column_stack([np.zeros(n), u * 6, rng.random(n) * 3])  # 6 x 3 m at x = 0
    u, n = patch(0.54)
    side = np.column_stack([np.full(n, 5.0), u * 0.6, rng.random(n) * 0.9])  # a cabinet 0.8 wide, 0.6 deep, 0.9 tall
    u, n = patch(0.48)
    top = np.column_stack([5.0 + u * 0.8, rng.random(n) * 0.6, np.full(n, 0.9)])
    u, n = patch(0.72)
    front = np.column_stack([5.0 + u * 0.8, np.full(n, 0.6), rng.random(n) * 0.9])
    points = np.concatenate([wall, side, top, front])
    _, narrow = local_geometry(points, neighbours=32)
    _, wide = local_geometry(points, neighbours=128)
    on_wall = np.zeros(len(points), dtype=bool)
    on_wall[:len(wall)] = (np.abs(wall[:, 1] - 3) < 1) & (np.abs(wall[:, 2] - 1.5) < 0.5)
    on_side = np.zeros(len(points), dtype=bool)
    on_side[len(wall):len(wall) + len(side)] = True
    planarity_narrow, planarity_wide = narrow[:, 1], wide[:, 1]
    assert np.median(planarity_narrow[on_side]) > 0.5 * np.median(planarity_narrow[on_wall])
    assert np.median(planarity_wide[on_wall]) > 0.8
    assert np.median(planarity_wide[on_side]) < 0.25 * np.median(planarity_wide[on_wall])
    extra = extra_features(points, features=("xyz", "shape", "shape_wide"), height_m=None, height_scale_m=3.0,
                           neighbours=32, wide_neighbours=128)
    assert np.allclose(extra[:, :3], narrow) and np.allclose(extra[:, 3:], wide)
    with pytest.raises(ValueError, match="wide_neighbours"):
        extra_features(points, features=("xyz", "shape_wide"), height_m=None, height_scale_m=3.0, neighbours=16)


def test_class_weights_and_the_weighted_loss() -> None:
    label = np.r_[np.zeros(800), np.ones(200), np.full(0, 2), np.full(100, 3)].astype(np.uint8)
    inverse = class_weights_from_labels(label, classes=4, mode="inverse")
    share = np.array([800, 200, 0, 100]) / 1100
    assert inverse[2] == 0 and np.allclose(inverse[[0, 1, 3]] * share[[0, 1, 3]], inverse[0] * share[0])
    assert np.isclose(inverse[[0, 1, 3]].mean(), 1.0)
    root = class_weights_from_labels(label, classes=4, mode="inverse_sqrt")
    assert np.isclose(root[1] / root[0], 2.0)
    assert class_weights_from_labels(label, classes=4, mode="none") is None
    logits = torch.randn(2, 50, 4)
    target = torch.randint(0, 4, (2, 50))
    target[0, :5] = 255
    weight = torch.tensor([0.5, 1.0, 2.0, 3.0])
    loss, count = compute_loss(logits, target, weight)
    expected = F.cross_entropy(logits.reshape(-1, 4), target.reshape(-1), weight=weight, ignore_index=255)
    assert torch.isclose(loss, expected) and int(count) == 95


def test_input_config_rejects_bad_values() -> None:
    with pytest.raises(ConfigError, match="start with 'xyz'"):
        InputConfig(features=("height",))
    with pytest.raises(ConfigError, match="at most once"):
        InputConfig(features=("xyz", "colour"))
    with pytest.raises(ConfigError, match="label_neighbours must be an integer in 0..64"):
        EvalConfig(label_neighbours=-1)
    with pytest.raises(ConfigError, match="scale_range"):
        AugmentConfig(scale_range=(1.2, 0.8))


def test_per_station_columns_keep_each_tripod_apart(tmp_path: Path) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.semantics import DEFAULT_SCHEME, load_scheme
    from bimscan.types import CloudHeader

    room = make_room(5, size_m=(3.0, 3.0), origin=(0.5, 0.5), points_per_m2=60)  # inside one 4 m column
    station = (room.xyz[:, 0] > 2.0).astype(np.uint16)  # two "stations", one per half of the room
    header = CloudHeader(scheme=load_scheme(DEFAULT_SCHEME))
    with open_cloud_writer(tmp_path / "scan", header=header) as writer:
        writer.write(PointCloud(xyz=room.xyz, label=room.label, station=station,
                                component=np.zeros(len(room), np.int32)))
    source = list_scenes([tmp_path / "scan"])[0]
    blocks = BlockConfig(size_m=4.0, points=64, min_points=16, cache_points=100_000)
    merged = collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0)
    apart = collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0, per_station=True)
    assert len(merged) == 1 and len(apart) == 2
    assert np.allclose(apart.origin[:, :2], merged.origin[0, :2])  # same place, one column per station
    assert int(apart.offsets[-1]) == int(merged.offsets[-1]) == len(room)
    halves = [apart.tile_points(t)[0][:, 0] + apart.origin[t, 0] for t in range(2)]
    assert {bool((h > 2.0).all()) for h in halves} == {True, False}


def _write_station_scan(folder: Path, room: PointCloud, station: np.ndarray) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.semantics import DEFAULT_SCHEME, load_scheme
    from bimscan.types import CloudHeader

    with open_cloud_writer(folder, header=CloudHeader(scheme=load_scheme(DEFAULT_SCHEME))) as writer:
        writer.write(PointCloud(xyz=room.xyz, label=room.label, station=station,
                                component=np.zeros(len(room), np.int32)))


def test_grid_station_tiles_do_not_depend_on_chunking(tmp_path: Path) -> None:
    # two stations see the same voxels: each keeps its own point there, whatever the chunking
    room = make_room(8, size_m=(5.0, 4.0), points_per_m2=150)
    station = np.random.default_rng(8).integers(0, 2, len(room)).astype(np.uint16)
    _write_station_scan(tmp_path / "scan", room, station)
    source = list_scenes([tmp_path / "scan"])[0]
    blocks = BlockConfig(size_m=2.0, points=64, min_points=16, cache_points=100_000)
    results = [collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0, grid_m=0.2,
                                   per_station=True, chunk_points=chunk) for chunk in (1_000_000, 997)]
    first, other = results
    assert np.array_equal(first.key, other.key) and np.array_equal(first.offsets, other.offsets)
    for t in range(len(first)):
        assert _as_set(first.tile_points(t)[0] + first.origin[t]) == _as_set(other.tile_points(t)[0] + other.origin[t])
    # both stations' columns hold a point in most voxels of the room (each station saw them)
    cells = [voxel_index(first.tile_points(t)[0] + first.origin[t] + 1e-9, 0.2) for t in range(len(first))]
    assert sum(len(c) for c in cells) > 1.5 * len(np.unique(np.concatenate(cells), axis=0))


def test_both_train_columns_cut_every_station_scan_per_station_and_merged(tmp_path: Path) -> None:
    from bimscan.learn.train import DistributedContext, _collect_tiles
    from bimscan.learn.train_config import DataConfig, TrainRunConfig

    room = make_room(5, size_m=(3.0, 3.0), origin=(0.5, 0.5), points_per_m2=60)  # inside one 4 m column
    _write_station_scan(tmp_path / "scan", room, (room.xyz[:, 0] > 2.0).astype(np.uint16))  # two stations
    write_text_cloud(tmp_path / "room.txt", room)  # no stations recorded: a real room
    sources = list_scenes([tmp_path / "scan", tmp_path / "room.txt"])
    ctx = DistributedContext(1, 0, 0, torch.device("cpu"), False)
    counts = {}
    for columns in ("scene", "station", "both"):
        blocks = BlockConfig(size_m=4.0, points=64, min_points=16, cache_points=100_000, train_columns=columns)
        config = TrainRunConfig(data=DataConfig(train=("a",)), blocks=blocks)
        tiles = _collect_tiles(sources, config=config, cache_dir=tmp_path / columns, ctx=ctx, columns=columns)
        names = np.array(tiles.scene_names)[tiles.scene]
        counts[columns] = [int(np.sum(names == s.name)) for s in sources]
    assert counts["scene"] == [1, 1] and counts["station"] == [2, 1]
    # both: the station scan's two stations apart and merged; the real room's one column once, not twice
    assert counts["both"] == [3, 1]
    assert len(list((tmp_path / "both").glob("*.npz"))) == 3  # the real room read once, not cut twice


def test_too_many_stations_for_station_columns_is_a_clear_error(tmp_path: Path) -> None:
    from bimscan.errors import LearnError

    room = make_room(9, size_m=(2.0, 2.0), points_per_m2=20)
    _write_station_scan(tmp_path / "scan", room, np.full(len(room), 600, np.uint16))
    source = list_scenes([tmp_path / "scan"])[0]
    blocks = BlockConfig(size_m=2.0, points=64, min_points=16, cache_points=1000)
    with pytest.raises(LearnError, match="train_columns = \"scene\""):
        collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0, per_station=True)
    assert len(collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0)) >= 1


def test_a_config_stored_before_the_recipe_reads_back_as_the_paper_baseline() -> None:
    from bimscan.learn.train_config import DataConfig, TrainRunConfig, dump_config, parse_config

    stored = dump_config(TrainRunConfig(data=DataConfig(train=("a",))))
    for section in ("input", "augment"):
        del stored[section]
    del stored["blocks"]["train_columns"]
    del stored["train"]["class_weights"]
    old = parse_config(stored, where="old.pt")
    assert old.input.grid_m == 0.0 and old.input.features == ("xyz",)
    assert not old.augment.enabled
    assert old.blocks.train_columns == "scene" and old.train.class_weights == "none"
    today = parse_config(dump_config(TrainRunConfig(data=DataConfig(train=("a",)))), where="new.pt")
    assert today.input.features == ("xyz", "height", "normals", "shape") and today.blocks.train_columns == "station"


def test_colour_is_an_input_read_from_real_and_synthetic_scans_and_grey_where_a_scan_has_none(
    tmp_path: Path,
) -> None:
    """Tiles keep each point's own colour (the S3DIS reader keeps its r g b); a scene without
    colour reads as mid grey; the feature is the colour centred on zero."""
    from bimscan.io.s3dis import read_s3dis_room
    from bimscan.learn.data import GREY

    rng = np.random.default_rng(0)
    notes = tmp_path / "Area_1" / "room_1" / "Annotations"
    notes.mkdir(parents=True)
    floor = np.c_[rng.uniform(0, 3, 4000), rng.uniform(0, 3, 4000), np.zeros(4000)]
    wall = np.c_[rng.uniform(0, 3, 4000), np.zeros(4000), rng.uniform(0, 2.8, 4000)]
    np.savetxt(notes / "floor_1.txt", np.c_[floor, np.tile([200, 10, 10], (4000, 1))], fmt="%.4f")
    np.savetxt(notes / "wall_1.txt", np.c_[wall, np.tile([10, 10, 240], (4000, 1))], fmt="%.4f")
    room = read_s3dis_room(tmp_path / "Area_1" / "room_1")
    assert room.rgb is not None and {tuple(c) for c in room.rgb.tolist()} == {(200, 10, 10), (10, 10, 240)}

    blocks = BlockConfig(size_m=3.0, points=256, min_points=32, cache_points=512)
    (source,) = list_scenes([tmp_path / "Area_1" / "room_1"])
    tiles = collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0, colour=True)
    assert tiles.rgb is not None and len(tiles.rgb) == len(tiles.label)
    slab = tiles.label == 3  # floor -> Slab: red; wall -> Wall&Column: blue
    assert (tiles.rgb[slab] == [200, 10, 10]).all() and (tiles.rgb[tiles.label == 0] == [10, 10, 240]).all()
    write_text_cloud(tmp_path / "bare.xyz", PointCloud(xyz=np.concatenate([floor, wall])))
    (bare,) = list_scenes([tmp_path / "bare.xyz"])
    grey = collect_scene_tiles(bare, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0, colour=True,
                               labelled=False)
    assert grey.rgb is not None and (grey.rgb == GREY).all()
    features = extra_features(floor[:5], features=("xyz", "rgb"), height_m=None, height_scale_m=3.0, neighbours=8,
                              rgb=np.tile([255, 0, 128], (5, 1)).astype(np.uint8))
    assert np.allclose(features, [[0.5, -0.5, 128 / 255 - 0.5]] * 5, atol=1e-6)
    assert collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0).rgb is None


def test_colour_randomisation_draws_nothing_when_off_and_keeps_colours_in_range() -> None:
    from bimscan.learn.augment import augment_colour

    rgb = np.random.default_rng(1).integers(0, 256, (500, 3)).astype(np.uint8)
    rng = np.random.default_rng(2)
    assert augment_colour(rgb, config=AugmentConfig(), rng=rng) is rgb
    assert rng.random() == np.random.default_rng(2).random()  # no draw taken
    jittered = augment_colour(rgb, config=AugmentConfig(colour_gain_sigma=0.2, colour_noise=0.05),
                              rng=np.random.default_rng(3))
    assert jittered.dtype == np.uint8 and jittered.shape == rgb.shape and not np.array_equal(jittered, rgb)
    dropped = augment_colour(rgb, config=AugmentConfig(colour_drop=1.0), rng=np.random.default_rng(4))
    assert (dropped == 128).all()
    grey = augment_colour(rgb, config=AugmentConfig(colour_grey=1.0), rng=np.random.default_rng(5))
    assert (grey[:, 0] == grey[:, 1]).all() and (grey[:, 1] == grey[:, 2]).all()

"""Scenes for learning: discovery (datasets, S3DIS areas, clouds), training tiles kept in
bounded memory, and blocks that depend only on (seed, epoch, tile)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from bimscan.dataset.layout import DatasetFolder, Manifest, ManifestEntry
from bimscan.errors import InputFileError, LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.blocks import locate_columns, encode_column_key
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES, BlockConfig
from bimscan.learn.data import (
    TileDataset, _sort_by_column_and_key, collect_scene_tiles, list_scenes, load_or_collect_tiles, read_labelled_cloud,
)
from bimscan.learn.mapping import LabelMapping
from bimscan.types import PointCloud


def _write_manifest(folder: Path, units: list[dict[str, object]]) -> None:
    DatasetFolder(folder).write_manifest(Manifest(units=tuple(
        ManifestEntry(id=u["id"], scene="s", config="c", status=u["status"], files=u["files"])  # type: ignore[arg-type]
        for u in units
    )))


def test_dataset_folder_expands_to_its_done_units_preferring_the_numpy_folder(tmp_path: Path) -> None:
    for unit in ("a", "b", "c"):
        (tmp_path / "units" / unit / "cloud").mkdir(parents=True)
        (tmp_path / "units" / unit / "cloud" / "coord.npy").write_bytes(b"")
        (tmp_path / "units" / unit / "cloud.laz").write_bytes(b"")
    _write_manifest(tmp_path, [
        {"id": "a", "status": "done", "files": {"laz": "units/a/cloud.laz", "npy": "units/a/cloud"}},
        {"id": "b", "status": "failed", "files": {"npy": "units/b/cloud"}},
        {"id": "c", "status": "done", "files": {"laz": "units/c/cloud.laz"}},
    ])

    scenes = list_scenes([tmp_path])

    assert [(s.name, s.kind, s.path.relative_to(tmp_path).as_posix()) for s in scenes] == [
        ("a", "npy", "units/a/cloud"), ("c", "laz", "units/c/cloud.laz"),
    ]


def test_a_unit_folder_is_its_cloud_the_numpy_folder_first(tmp_path: Path) -> None:
    both, laz_only, no_cloud = (tmp_path / "units" / name for name in ("a__exp1", "b__exp1", "c__exp1"))
    for unit in (both, laz_only, no_cloud):
        unit.mkdir(parents=True)
        (unit / "unit.json").write_text("{}")
    (both / "cloud").mkdir()
    (both / "cloud" / "coord.npy").write_bytes(b"")
    for unit in (both, laz_only):
        (unit / "cloud.laz").write_bytes(b"")

    scenes = list_scenes([both, laz_only], label_field="label")

    assert [(s.name, s.kind, s.path.relative_to(tmp_path).as_posix(), s.label_field) for s in scenes] == [
        ("a__exp1", "npy", "units/a__exp1/cloud", "label"), ("b__exp1", "laz", "units/b__exp1/cloud.laz", "label"),
    ]
    with pytest.raises(InputFileError, match="not a scene"):
        list_scenes([no_cloud])


def test_dataset_without_finished_units_is_refused(tmp_path: Path) -> None:
    _write_manifest(tmp_path, [{"id": "a", "status": "pending", "files": {}}])

    with pytest.raises(LearnError, match="no unit with status 'done'"):
        list_scenes([tmp_path])


def test_paths_that_are_no_scene_are_one_line_errors(tmp_path: Path) -> None:
    (tmp_path / "notes.doc").write_text("x")
    (tmp_path / "empty").mkdir()

    for path, message in ((tmp_path / "notes.doc", "not a scene"), (tmp_path / "empty", "not a scene"),
                          (tmp_path / "missing.laz", "no such file")):
        with pytest.raises(InputFileError, match=message):
            list_scenes([path])


def test_a_georeferenced_scan_makes_the_tiles_of_the_same_scan_at_the_origin(
    tmp_path: Path, room: Callable[..., PointCloud],
) -> None:
    """Real scans come in map coordinates (a UTM northing of 5,401 km is 2.7 million 2 m
    columns): their tiles are those of the same points near the origin, moved."""
    scene = room(8, size_m=(5.0, 3.0), points_per_m2=60)
    shift = np.array([512_346.0, 5_401_234.0, 312.0])  # whole columns: the same grid cells
    for folder, moved in (("local", scene.xyz), ("utm", scene.xyz + shift)):  # one name: one random subset
        (tmp_path / folder).mkdir()
        write_text_cloud(tmp_path / folder / "scan.txt", PointCloud(xyz=moved, label=scene.label))
    blocks = BlockConfig(size_m=2.0, points=64, min_points=16, cache_points=300)

    local, utm = (collect_scene_tiles(list_scenes([tmp_path / folder / "scan.txt"])[0], blocks=blocks,
                                      class_names=DEFAULT_CLASS_NAMES, seed=3) for folder in ("local", "utm"))

    assert len(utm) == len(local) > 1
    np.testing.assert_array_equal(utm.offsets, local.offsets)
    np.testing.assert_array_equal(utm.label, local.label)
    np.testing.assert_allclose(utm.xyz, local.xyz, atol=2e-3)  # the text file's millimetres
    np.testing.assert_allclose(utm.origin, local.origin + shift, atol=2e-3)
    assert utm.xyz[:, :2].min() >= -1e-3 and utm.xyz[:, :2].max() <= 2.0 + 1e-3  # inside its own column


def test_a_scene_wider_than_the_columns_can_number_is_refused(tmp_path: Path, room: Callable[..., PointCloud]) -> None:
    scene = room(9, size_m=(4.0, 3.0), points_per_m2=40)
    far = scene.xyz + [150_000.0, 0.0, 0.0]  # two rooms 150 km apart in one file: 600,000 columns of 0.25 m
    write_text_cloud(tmp_path / "wide.txt", PointCloud(xyz=np.concatenate([scene.xyz, far]),
                                                       label=np.concatenate([scene.label, scene.label])))
    blocks = BlockConfig(size_m=0.25, points=64, min_points=16, cache_points=300)

    with pytest.raises(LearnError, match=r"wide.txt: the scene spans 150 km, more than training columns of 0.25 m can "
                                         r"number; cut it into buildings or sites"):
        collect_scene_tiles(list_scenes([tmp_path / "wide.txt"])[0], blocks=blocks, class_names=DEFAULT_CLASS_NAMES,
                            seed=3)


def test_tiles_keep_a_random_subset_per_column_whatever_the_chunking(
    tmp_path: Path, room: Callable[..., PointCloud],
) -> None:
    scene = room(4, size_m=(5.0, 3.0), points_per_m2=60)
    write_text_cloud(tmp_path / "scene.txt", scene)
    source = list_scenes([tmp_path / "scene.txt"])[0]
    blocks = BlockConfig(size_m=2.0, points=64, min_points=16, cache_points=300)

    small = collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=3, chunk_points=500)
    large = collect_scene_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=3, chunk_points=10**6)

    np.testing.assert_array_equal(small.xyz, large.xyz)
    np.testing.assert_array_equal(small.offsets, large.offsets)
    ix, iy = locate_columns(scene.xyz[:, :2], size_m=2.0)
    keys, counts = np.unique(encode_column_key(ix, iy), return_counts=True)
    full = dict(zip(keys.tolist(), counts.tolist(), strict=True))
    for t in range(len(small)):
        kept = int(small.offsets[t + 1] - small.offsets[t])
        tx, ty = np.rint(small.origin[t, :2] / 2.0).astype(np.int64)  # the tile's column, from its corner
        column = int(encode_column_key(np.array([tx]), np.array([ty]))[0])
        assert small.count[t] == full[column]
        assert kept == min(300, full[column])
    # the kept points are points of the scene, in their own column, with their own labels
    xyz, label, _ = small.tile_points(0)
    absolute = xyz + small.origin[0]
    distance = np.linalg.norm(scene.xyz[None, :, :] - absolute[:20, None, :], axis=2)
    nearest = distance.argmin(axis=1)
    assert distance.min(axis=1).max() < 1e-5
    np.testing.assert_array_equal(scene.label[nearest], label[:20])


def test_tiles_with_too_few_points_are_dropped(tmp_path: Path) -> None:
    xyz = np.array([[0.5, 0.5, 0.0]] * 50 + [[3.5, 0.5, 0.0]] * 5, dtype=np.float64)
    write_text_cloud(tmp_path / "two.txt", PointCloud(xyz=xyz, label=np.zeros(55, np.uint8)))
    blocks = BlockConfig(size_m=2.0, points=16, min_points=10, cache_points=64)

    tiles = collect_scene_tiles(list_scenes([tmp_path / "two.txt"])[0], blocks=blocks,
                                class_names=DEFAULT_CLASS_NAMES, seed=0)

    assert len(tiles) == 1 and tiles.count.tolist() == [50]


def test_tile_cache_on_disk_gives_the_same_tiles(tmp_path: Path, room: Callable[..., PointCloud]) -> None:
    write_text_cloud(tmp_path / "scene.txt", room(1, points_per_m2=30))
    source = list_scenes([tmp_path / "scene.txt"])[0]
    blocks = BlockConfig(size_m=2.0, points=32, min_points=8, cache_points=64)

    built = load_or_collect_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=1,
                                  cache_dir=tmp_path / "cache")
    cached = load_or_collect_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=1,
                                   cache_dir=tmp_path / "cache", build=False)

    assert len(list((tmp_path / "cache").glob("tiles-*.npz"))) == 1
    np.testing.assert_array_equal(built.xyz, cached.xyz)
    np.testing.assert_array_equal(built.label, cached.label)
    with pytest.raises(LearnError, match="tile cache missing"):
        load_or_collect_tiles(source, blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=2,
                              cache_dir=tmp_path / "cache", build=False)


def test_training_blocks_depend_only_on_seed_epoch_and_tile(tmp_path: Path, room: Callable[..., PointCloud]) -> None:
    write_text_cloud(tmp_path / "scene.txt", room(2, points_per_m2=60))
    blocks = BlockConfig(size_m=2.0, points=64, min_points=16, cache_points=256)
    tiles = collect_scene_tiles(list_scenes([tmp_path / "scene.txt"])[0], blocks=blocks,
                                class_names=DEFAULT_CLASS_NAMES, seed=0)
    dataset = TileDataset(tiles, points=64, seed=5)

    first, again, other_epoch = dataset[(0, 1)], dataset[(0, 1)], dataset[(1, 1)]

    np.testing.assert_array_equal(first["xyz"], again["xyz"])
    assert not np.array_equal(first["xyz"], other_epoch["xyz"])
    assert first["xyz"].shape == (64, 3) and first["mask"].all()
    assert np.abs(first["xyz"]).max() <= 1.0 + 1e-6


def test_a_stored_scheme_free_text_cloud_is_read_with_its_labels_as_they_are(tmp_path: Path) -> None:
    xyz = np.zeros((4, 3))
    write_text_cloud(tmp_path / "a.txt", PointCloud(xyz=xyz, label=np.array([0, 4, 255, 2], np.uint8)))
    write_text_cloud(tmp_path / "b.txt", PointCloud(xyz=xyz, label=np.array([0, 5, 6, 2], np.uint8)))

    assert read_labelled_cloud(tmp_path / "a.txt").label.tolist() == [0, 4, 255, 2]
    with pytest.raises(LearnError, match="labels 5, 6 are not training classes"):
        read_labelled_cloud(tmp_path / "b.txt")


@pytest.mark.parametrize("name", ["scene.laz", "scene.las", "scene.ply", "scene"])
def test_every_bimscan_cloud_format_loads_with_its_labels(
    tmp_path: Path, room: Callable[..., PointCloud], name: str,
) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.semantics.scheme import load_scheme
    from bimscan.types import CloudHeader

    cloud = room(3, points_per_m2=10)
    with open_cloud_writer(tmp_path / name, header=CloudHeader(scheme=load_scheme())) as writer:
        writer.write(cloud)

    back = read_labelled_cloud(tmp_path / name)

    np.testing.assert_array_equal(back.label, cloud.label)
    np.testing.assert_allclose(back.xyz, cloud.xyz, atol=1e-4)


def test_a_stored_scheme_in_another_order_is_mapped_by_class_name(
    tmp_path: Path, room: Callable[..., PointCloud],
) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.types import CloudHeader, LabelClass, LabelScheme

    reversed_names = list(reversed(DEFAULT_CLASS_NAMES))  # id 0 = Others ... id 4 = Wall&Column
    scheme = LabelScheme(name="reversed", classes=tuple(LabelClass(i, n, "#000000") for i, n in enumerate(reversed_names)),
                         rules=(), default_label="Others")
    cloud = room(8, points_per_m2=10)
    stored = PointCloud(xyz=cloud.xyz, label=(4 - cloud.label).astype(np.uint8))
    with open_cloud_writer(tmp_path / "scene.laz", header=CloudHeader(scheme=scheme)) as writer:
        writer.write(stored)

    np.testing.assert_array_equal(read_labelled_cloud(tmp_path / "scene.laz").label, cloud.label)


@pytest.mark.parametrize("classification", [0, 1])
def test_a_foreign_las_never_classified_has_no_ground_truth(
    tmp_path: Path, room: Callable[..., PointCloud], foreign_las: Callable[..., Path], classification: int,
) -> None:
    cloud = room(9, points_per_m2=10)
    path = foreign_las(tmp_path / "site.las", cloud, classification=classification)
    blocks = BlockConfig(size_m=2.0, points=32, min_points=8, cache_points=64)

    with pytest.raises(LearnError, match="no ground-truth labels: its LAS classification is only 0/1.*--label-field"):
        read_labelled_cloud(path)
    with pytest.raises(LearnError, match="no ground-truth labels"):
        collect_scene_tiles(list_scenes([path])[0], blocks=blocks, class_names=DEFAULT_CLASS_NAMES, seed=0)
    np.testing.assert_array_equal(read_labelled_cloud(path, label_field="gt").label, cloud.label)
    everything_others = LabelMapping(name="all-others", default="Others")
    assert set(read_labelled_cloud(path, mapping=everything_others).label.tolist()) == {4}


def test_a_foreign_las_with_classes_keeps_them(
    tmp_path: Path, room: Callable[..., PointCloud], foreign_las: Callable[..., Path],
) -> None:
    cloud = room(10, points_per_m2=10)

    back = read_labelled_cloud(foreign_las(tmp_path / "site.las", cloud))

    np.testing.assert_array_equal(back.label, cloud.label)


def test_a_label_field_names_a_text_header_column_and_cannot_apply_to_s3dis_rooms(tmp_path: Path) -> None:
    (tmp_path / "scan.txt").write_text("x y z label gt\n0 0 0 9 1\n1 1 1 9 2\n")
    room = tmp_path / "Area_1" / "office_1"
    (room / "Annotations").mkdir(parents=True)
    (room / "Annotations" / "wall_1.txt").write_text("0 0 0 1 2 3\n")

    assert read_labelled_cloud(tmp_path / "scan.txt", label_field="gt").label.tolist() == [1, 2]
    with pytest.raises(LearnError, match="label field 'gt' cannot apply to S3DIS rooms"):
        list_scenes([tmp_path / "Area_1"], label_field="gt")
    # in a list with other scans it names their field; the rooms keep their annotation labels
    scenes = list_scenes([tmp_path / "scan.txt", tmp_path / "Area_1"], label_field="gt")
    assert [(s.kind, s.label_field) for s in scenes] == [("text", "gt"), ("s3dis", None)]


def test_sorting_by_column_and_random_key_equals_lexsort_ties_included() -> None:
    rng = np.random.default_rng(0)
    for spread in (3, 1000, 1 << 29):  # few columns: every random-key bit fits; many: ties to resolve
        ix = rng.integers(-spread, spread, 5000)
        iy = rng.integers(-spread, spread, 5000)
        ix[:2000], iy[:2000] = ix[0], iy[0]  # one crowded column
        key = encode_column_key(ix, iy)
        prio = np.floor(rng.random(5000) * 2**20) / 2**20  # coarse: exact ties too
        prio[100:110] = prio[99]

        order, column = _sort_by_column_and_key(key, prio)

        np.testing.assert_array_equal(order, np.lexsort((prio, key)))
        changes = np.flatnonzero(np.diff(key[order]) != 0)
        np.testing.assert_array_equal(changes, np.flatnonzero(np.diff(column.astype(np.int64)) != 0))

"""The second model family: gradient-boosted trees on per-point geometric features ([model] kind = "gbm")."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.cli.main import main
from bimscan.errors import LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.boosted import BoostedTrees, block_tree_features, tree_feature_names
from bimscan.learn.checkpoint import load_trained_model, load_trained_models
from bimscan.learn.evaluate import evaluate_checkpoint
from bimscan.learn.train import train_model
from bimscan.learn.train_config import load_train_config

from .conftest import make_room

TREES = '[model]\nkind = "gbm"\ngbm_rounds = 25\ngbm_leaves = 15\ngbm_min_leaf_points = 20\n'


def _tree_config(folder: Path, tiny_config: Callable[..., Path], *, seed: int = 0, out_dir: str = "trees",
                 name: str = "trees.toml") -> Path:
    train = []
    for i in range(3):
        if not (folder / f"room{i}.txt").exists():
            write_text_cloud(folder / f"room{i}.txt", make_room(i, size_m=(4.0 + i, 3.0), points_per_m2=40))
        train.append(f"room{i}.txt")
    if not (folder / "real.txt").exists():
        write_text_cloud(folder / "real.txt", make_room(100, size_m=(4.0, 4.0), points_per_m2=40))
    path = tiny_config(folder, train=train, val=["real.txt"], epochs=2, out_dir=out_dir, seed=seed, name=name)
    path.write_text(path.read_text().replace("[model]\n", TREES), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def trees_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Trees trained once on the three tiny rooms (shared; read-only for tests)."""
    from .conftest import write_tiny_config

    folder = tmp_path_factory.mktemp("trees")
    config, base = load_train_config(_tree_config(folder, write_tiny_config))
    train_model(config, base_dir=base, log=lambda text: None)
    return folder


def test_the_tree_features_place_each_point_in_its_column_and_keep_the_inputs_that_mean_the_same_in_any_heading(
) -> None:
    features = ("xyz", "height", "normals", "shape", "rgb")
    block = np.zeros((4, 3 + 1 + 3 + 3 + 3), dtype=np.float32)
    block[:, :2] = [[0.0, 0.0], [0.5, 0.5], [0.01, 0.02], [-0.5, 0.3]]  # the first and third in one plan cell
    block[:, 2] = [-1.0, 0.5, 1.0, 0.0]  # z
    block[:, 3] = [0.0, 0.5, 0.9, 0.3]  # height
    block[:, 4:7] = [[0, 0, 1], [1, 0, 0], [0, 0, 1], [0.6, 0, 0.8]]  # normals
    block[:, 7:10] = [[0.1, 0.8, 0.1]] * 4  # shape
    block[:, 10:13] = [[0.2, 0.2, 0.2], [0.2, 0.2, 0.2], [0.2, 0.2, 0.2], [-0.4, 0.1, 0.3]]  # rgb: one differs
    rows = block_tree_features(block, features)
    names = tree_feature_names(features)
    assert rows.shape == (4, len(names))
    column = {name: rows[:, i] for i, name in enumerate(names)}
    np.testing.assert_allclose(column["z_rank"], [0.0, 2 / 3, 1.0, 1 / 3])
    np.testing.assert_allclose(column["below_top"], [2.0, 0.5, 0.0, 1.0])
    np.testing.assert_allclose(column["above_bottom"], [0.0, 1.5, 2.0, 1.0])
    np.testing.assert_allclose(column["normal_z"], [1.0, 0.0, 1.0, 0.8])
    np.testing.assert_allclose(column["cell_share"], [0.5, 0.25, 0.5, 0.25])
    np.testing.assert_allclose(column["cell_span"], [2.0, 0.0, 2.0, 0.0])
    np.testing.assert_allclose(column["cell_spread"], [1.0, 0.0, 1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(column["below_cell_top"], [2.0, 0.0, 0.0, 0.0])  # the floor point has the top above it
    np.testing.assert_allclose(column["above_cell_bottom"], [0.0, 0.0, 2.0, 0.0])
    np.testing.assert_allclose(column["red_contrast"], [0.0, 0.0, 0.0, -0.6], atol=1e-6)  # against the median
    assert "normal_x" not in names and "x" not in names  # which way a wall faces, where the block lies: not read


def test_trees_train_from_a_training_file_and_label_a_room_through_evaluate_and_predict(
    tmp_path: Path, trees_run: Path,
) -> None:
    checkpoint = trees_run / "trees" / "last.pt"
    assert {"last.pt", "metrics.csv", "curves.png"} <= {p.name for p in (trees_run / "trees").iterdir()}
    trained = load_trained_model(checkpoint)
    assert isinstance(trained.model, BoostedTrees)
    found = evaluate_checkpoint(checkpoint, [trees_run / "real.txt"], device="cpu")[0].labels.confusion
    assert np.trace(found) / found.sum() > 0.8  # the tiny rooms are easy: a wrong feature or label order fails it
    out = tmp_path / "labelled.laz"
    assert main(["predict", str(checkpoint), str(trees_run / "real.txt"), str(out), "--device", "cpu"]) == 0
    import laspy

    assert len(laspy.read(out).classification) == int(found.sum())


def test_the_same_seed_gives_the_same_trees_and_another_seed_others(
    tmp_path: Path, trees_run: Path, tiny_config: Callable[..., Path],
) -> None:
    first = torch.load(trees_run / "trees" / "last.pt", weights_only=True)["model"]["booster"]
    for seed, same in ((0, True), (1, False)):
        path = _tree_config(tmp_path, tiny_config, seed=seed, out_dir=f"seed{seed}", name=f"seed{seed}.toml")
        if seed == 0:  # the blocks' features computed in two worker processes: the same trees
            path.write_text(path.read_text().replace("num_workers = 0", "num_workers = 2"), encoding="utf-8")
        config, base = load_train_config(path)
        train_model(config, base_dir=base, log=lambda text: None)
        again = torch.load(tmp_path / f"seed{seed}" / "last.pt", weights_only=True)["model"]["booster"]
        assert (again == first) is same


def test_trees_and_a_pct_of_the_same_inputs_make_an_ensemble_of_their_mean_probabilities(
    trees_run: Path, trained_run: Path,
) -> None:
    trees, network = trees_run / "trees" / "last.pt", trained_run / "run" / "last.pt"
    ensemble = load_trained_models([network, trees]).model
    one, two = load_trained_model(network).model, load_trained_model(trees).model
    channels = 3 + 1 + 3 + 3  # the tiny runs' default inputs: xyz, height, normals, shape
    generator = torch.Generator().manual_seed(0)
    xyz = torch.rand(2, 64, channels, generator=generator) * 2 - 1
    mask = torch.ones(2, 64, dtype=torch.bool)
    mask[1, 40:] = False
    with torch.inference_mode():
        mean = (torch.softmax(one(xyz, mask), -1) + torch.softmax(two(xyz, mask), -1)) / 2
        mixed = torch.softmax(ensemble(xyz, mask), -1)
    torch.testing.assert_close(mixed[mask], mean[mask], atol=1e-5, rtol=1e-4)


def test_bimscan_train_fits_trees_from_the_command_line(
    tmp_path: Path, tiny_config: Callable[..., Path], capsys: pytest.CaptureFixture[str],
) -> None:
    config = _tree_config(tmp_path, tiny_config, out_dir="cli")
    assert main(["train", str(config)]) == 0
    captured = capsys.readouterr()
    assert "trained gradient-boosted trees; checkpoint" in captured.out
    assert "trained gradient-boosted trees (25 rounds x 5 classes) on " in captured.err  # points, time, scores
    assert isinstance(load_trained_model(tmp_path / "cli" / "last.pt").model, BoostedTrees)


def test_what_trees_cannot_do_is_refused_in_one_line(
    tmp_path: Path, trees_run: Path, tiny_config: Callable[..., Path], capsys: pytest.CaptureFixture[str],
) -> None:
    config_path = trees_run / "trees.toml"
    assert main(["train", str(config_path), "--resume"]) != 0  # finished: nothing to resume
    assert "nothing to resume" in capsys.readouterr().err
    fresh = _tree_config(tmp_path, tiny_config, out_dir="started")
    assert main(["train", str(fresh), "--init", str(trees_run / "trees" / "last.pt")]) != 0
    assert "do not start from a checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "started").exists()  # refused before any folder is made


def test_a_checkpoint_whose_trees_are_damaged_is_refused_in_one_line(tmp_path: Path, trees_run: Path) -> None:
    payload = torch.load(trees_run / "trees" / "last.pt", weights_only=True)
    payload["model"]["booster"] = payload["ema"]["booster"] = "tree\nversion=v4\nnum_class=5\nnot trees at all"
    damaged = tmp_path / "damaged.pt"
    torch.save(payload, damaged)
    with pytest.raises(LearnError, match=r"damaged\.pt: ") as refused:
        load_trained_model(damaged)
    assert "\n" not in str(refused.value)
    # trees that split on other features than this bimscan computes (another version's) are refused too
    payload = torch.load(trees_run / "trees" / "last.pt", weights_only=True)
    payload["config"]["input"]["features"] = ["xyz", "height", "normals", "shape", "shape_wide"]
    torch.save(payload, damaged)
    with pytest.raises(LearnError, match=r"damaged\.pt: its trees split on 14 features that are not the 17"):
        load_trained_model(damaged)


def test_an_ensemble_of_models_reading_other_features_gives_each_its_own_channels(
    tmp_path: Path, trained_run: Path, tiny_config: Callable[..., Path],
) -> None:
    path = _tree_config(tmp_path, tiny_config, out_dir="wide")
    path.write_text(path.read_text() + '\n[input]\nfeatures = ["xyz", "height", "normals", "shape", "shape_wide"]\n',
                    encoding="utf-8")
    config, base = load_train_config(path)
    train_model(config, base_dir=base, log=lambda text: None)
    network, trees = trained_run / "run" / "last.pt", tmp_path / "wide" / "last.pt"
    together = load_trained_models([network, trees])
    assert together.config.input.features == ("xyz", "height", "normals", "shape", "shape_wide")  # computed once
    one, two = load_trained_model(network).model, load_trained_model(trees).model
    generator = torch.Generator().manual_seed(1)
    xyz = torch.rand(2, 64, 13, generator=generator) * 2 - 1
    mask = torch.ones(2, 64, dtype=torch.bool)
    with torch.inference_mode():
        mean = (torch.softmax(one(xyz[..., :10], mask), -1) + torch.softmax(two(xyz, mask), -1)) / 2
        mixed = torch.softmax(together.model(xyz, mask), -1)
    torch.testing.assert_close(mixed, mean, atol=1e-5, rtol=1e-4)
    found = evaluate_checkpoint(network, [trained_run / "real.txt"], device="cpu", ensemble=[trees])
    assert found[0].labels.confusion.sum() > 0

"""Adaptation to unlabelled scans: class-balanced pseudo-label thresholds, column mixing of
unlabelled and synthetic columns, labels of the unlabelled scans never read, a resumed
adaptation equal to an uninterrupted one."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.errors import ConfigError, LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.adapt import AdaptedBlocks, class_thresholds, mixed_cells
from bimscan.learn.data import TileSet
from bimscan.learn.train import train_model
from bimscan.learn.train_config import IGNORE_LABEL, AdaptConfig, InputConfig, load_train_config
from bimscan.types import PointCloud

from .conftest import make_room


def test_each_class_keeps_its_most_confident_share_under_a_cap() -> None:
    rng = np.random.default_rng(0)
    prediction = np.repeat([0, 1, 2], [1000, 100, 10])
    confidence = np.concatenate([rng.uniform(0.9, 1.0, 1000), rng.uniform(0.3, 0.6, 100), rng.uniform(0.5, 0.7, 10)])

    thresholds = class_thresholds(confidence, prediction, classes=4, share=0.5, cap=0.95)

    # the rare, unsure class keeps half its points as the common, sure one does (one global
    # threshold at the median of all would keep none of classes 1 and 2)
    for c, n in ((1, 100), (2, 10)):
        kept = (confidence[prediction == c] >= thresholds[c]).sum()
        assert n // 2 <= kept <= n // 2 + 1
    assert thresholds[0] == 0.95  # capped: a class it is sure of is not cut to half
    assert (confidence[prediction == 0] >= thresholds[0]).mean() == pytest.approx(0.5, abs=0.06)
    assert thresholds[3] == 0.95  # never predicted


def test_a_synthetic_column_fills_some_cells_never_none_or_all() -> None:
    rng = np.random.default_rng(1)
    for cells in (2, 3, 4):
        grids = [mixed_cells(cells, rng) for _ in range(50)]
        assert all(0 < g.sum() < cells * cells for g in grids)
        assert len({g.tobytes() for g in grids}) > 1
    assert not mixed_cells(1, rng).any()  # one cell: the unlabelled column alone


def _tiles(xyz: np.ndarray, label: np.ndarray) -> TileSet:
    return TileSet(xyz=xyz.astype(np.float32), label=label.astype(np.uint8), offsets=np.array([0, len(xyz)]),
                   origin=np.zeros((1, 3)), key=np.zeros(1, np.int64), count=np.array([len(xyz)]),
                   scene=np.zeros(1, np.int32), scene_names=("scene",), height=xyz[:, 2].astype(np.float32))


def test_an_adapted_block_takes_its_synthetic_cells_points_with_their_true_labels() -> None:
    rng = np.random.default_rng(2)
    grid = rng.random((4000, 3)) * [2.0, 2.0, 3.0]  # one 2 m column of each
    target = _tiles(grid, np.full(len(grid), IGNORE_LABEL))
    source = _tiles(grid + [0.0, 0.0, 0.001], np.full(len(grid), 1))  # synthetic points: class 1, 1 mm higher
    blocks = AdaptedBlocks(target, source, points=4000, size_m=2.0, seed=0, inputs=InputConfig(grid_m=0.0),
                           augment=None, config=AdaptConfig(mix_cells=2))
    pseudo = np.where(grid[:, 2] < 1.5, 0, 3).astype(np.uint8)  # the round's pseudo-labels of the target
    from bimscan.learn.adapt import PseudoLabels

    blocks.set_pseudo_labels(PseudoLabels(label=pseudo, thresholds=np.zeros(5), predicted=np.zeros(5, np.int64),
                                          kept=np.zeros(5, np.int64)))

    for slot in range(6):
        block = blocks.block(0, slot)
        label = block["label"][block["mask"]]
        assert set(np.unique(label)) <= {0, 1, 3}
        share = (label == 1).mean()  # a random half of the 4 cells: 1 to 3 of them synthetic
        assert 0.2 < share < 0.8
        assert (label == 0).any() and (label == 3).any()  # the target's cells keep their pseudo-labels
    assert blocks.block(3, 5)["xyz"].tobytes() == blocks.block(3, 5)["xyz"].tobytes()  # seeded by (epoch, slot)


def _adapt_config(tmp_path: Path, tiny_config: Callable[..., Path], *, out_dir: str, targets: list[str],
                  epochs: int = 2) -> Path:
    path = tiny_config(tmp_path, train=["room0.txt", "room1.txt"], val=["real.txt"], epochs=epochs, out_dir=out_dir,
                       name=f"{out_dir}.toml")
    text = path.read_text().replace("val = [", "adapt = [" + ", ".join(f'"{t}"' for t in targets) + "]\nval = [")
    path.write_text(text + "\n[adapt]\npseudo_share = 0.6\nmix_cells = 2\n")
    return path


@pytest.fixture
def adapt_dir(tmp_path: Path) -> Path:
    for i in range(2):
        write_text_cloud(tmp_path / f"room{i}.txt", make_room(i, size_m=(4.0 + i, 3.0), points_per_m2=40))
    write_text_cloud(tmp_path / "real.txt", make_room(100, size_m=(4.0, 4.0), points_per_m2=40))
    for i in range(2):  # the "user's scans": other rooms, 20 cm lower ceilings, their labels in the file
        room = make_room(50 + i, size_m=(5.0, 4.0), height_m=2.8, points_per_m2=40)
        write_text_cloud(tmp_path / f"target{i}.txt", room)
    return tmp_path


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=True)["model"]


@pytest.mark.slow
def test_the_labels_of_the_unlabelled_scans_are_never_read(
    adapt_dir: Path, tiny_config: Callable[..., Path], trained_run: Path,
) -> None:
    """Scrambling the adaptation scans' labels (or dropping them) leaves the adapted model's
    bytes as they were."""
    start = trained_run / "run" / "last.pt"
    config, base = load_train_config(_adapt_config(adapt_dir, tiny_config, out_dir="a", targets=["target0.txt",
                                                                                                 "target1.txt"]))
    first = train_model(config, base_dir=base, init=start, log=lambda text: None)

    rng = np.random.default_rng(9)
    for i in range(2):
        room = make_room(50 + i, size_m=(5.0, 4.0), height_m=2.8, points_per_m2=40)
        scrambled = PointCloud(xyz=room.xyz, label=rng.integers(0, 5, len(room)).astype(np.uint8))
        write_text_cloud(adapt_dir / f"scrambled{i}.txt", scrambled)
        write_text_cloud(adapt_dir / f"bare{i}.xyz", PointCloud(xyz=room.xyz))
    for name, targets in (("b", ["scrambled0.txt", "scrambled1.txt"]), ("c", ["bare0.xyz", "bare1.xyz"])):
        other, base = load_train_config(_adapt_config(adapt_dir, tiny_config, out_dir=name, targets=targets))
        again = train_model(other, base_dir=base, init=start, log=lambda text: None)
        a, b = _weights(first.checkpoint), _weights(again.checkpoint)
        assert all(torch.equal(a[key], b[key]) for key in a), name
    assert not torch.equal(_weights(first.checkpoint)["classifier.weight"], _weights(start)["classifier.weight"])


@pytest.mark.slow
def test_an_adaptation_resumed_equals_an_uninterrupted_one(
    adapt_dir: Path, tiny_config: Callable[..., Path], trained_run: Path,
) -> None:
    start = trained_run / "run" / "last.pt"
    targets = ["target0.txt", "target1.txt"]
    straight, base = load_train_config(_adapt_config(adapt_dir, tiny_config, out_dir="straight", targets=targets))
    train_model(straight, base_dir=base, init=start, log=lambda text: None)
    resumed, base = load_train_config(_adapt_config(adapt_dir, tiny_config, out_dir="resumed", targets=targets))

    def crash(epoch: int, step: int) -> None:
        if (epoch, step) == (1, 0):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_model(resumed, base_dir=base, init=start, on_step_end=crash, log=lambda text: None)
    train_model(resumed, base_dir=base, init=start, resume=True, log=lambda text: None)

    a, b = _weights(adapt_dir / "straight" / "last.pt"), _weights(adapt_dir / "resumed" / "last.pt")
    assert all(torch.equal(a[key], b[key]) for key in a)


def test_adapting_without_a_model_to_start_from_is_refused(adapt_dir: Path, tiny_config: Callable[..., Path]) -> None:
    config, base = load_train_config(_adapt_config(adapt_dir, tiny_config, out_dir="fresh", targets=["target0.txt"]))

    with pytest.raises(LearnError, match=r"\[data\] adapt: adapting to unlabelled scans starts from a trained model"):
        train_model(config, base_dir=base, log=lambda text: None)

    assert not (adapt_dir / "fresh").exists()


def test_adaptation_settings_are_checked_where_declared() -> None:
    with pytest.raises(ConfigError, match=r"pseudo_share must be a number in \(0, 1\], got 0"):
        AdaptConfig(pseudo_share=0.0)
    with pytest.raises(ConfigError, match=r"mix_cells must be an integer in 1..8, got 9"):
        AdaptConfig(mix_cells=9)


def test_adaptation_settings_without_scans_to_adapt_to_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "train.toml"
    path.write_text('[data]\ntrain = ["synthetic"]\n\n[adapt]\npseudo_share = 0.8\n')

    with pytest.raises(ConfigError, match=r"\[adapt\]: its settings act only on unlabelled scans, and \[data\] adapt"):
        load_train_config(path)


def test_a_column_whose_points_all_lie_in_the_synthetic_cells_is_trained_alone() -> None:
    """A real room's edge column fills part of its footprint: when the cells left to it hold
    none of its points, the block is the unlabelled column alone, never an empty block."""
    rng = np.random.default_rng(5)
    corner = rng.random((3000, 3)) * [0.9, 0.9, 3.0]  # one corner cell of a 2 m column
    target = _tiles(corner, np.full(len(corner), IGNORE_LABEL))
    source = _tiles(rng.random((3000, 3)) * [2.0, 2.0, 3.0], np.full(3000, 1))
    blocks = AdaptedBlocks(target, source, points=512, size_m=2.0, seed=0, inputs=InputConfig(grid_m=0.0),
                           augment=None, config=AdaptConfig(mix_cells=2))
    from bimscan.learn.adapt import PseudoLabels

    blocks.set_pseudo_labels(PseudoLabels(label=np.zeros(len(corner), np.uint8), thresholds=np.zeros(5),
                                          predicted=np.zeros(5, np.int64), kept=np.zeros(5, np.int64)))
    for slot in range(40):
        block = blocks.block(0, slot)
        assert block["mask"].sum() > 0
        assert (block["label"][block["mask"]] == 0).any()  # the real column's own points are always there

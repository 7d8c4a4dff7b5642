"""Ensembles: several checkpoints' class probabilities averaged in evaluate and predict."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.cli.main import main
from bimscan.errors import LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.checkpoint import Ensemble, load_trained_model, load_trained_models
from bimscan.learn.evaluate import evaluate_checkpoint
from bimscan.learn.features import input_channels
from bimscan.types import PointCloud


def test_an_ensemble_gives_the_mean_of_its_members_probabilities(trained_run: Path) -> None:
    checkpoint = trained_run / "run" / "last.pt"
    trained = load_trained_model(checkpoint, weights="ema")
    averaged, live = trained.model, load_trained_model(checkpoint, weights="live").model
    ensemble = Ensemble([averaged, live], ["ema", "live"]).eval()
    generator = torch.Generator().manual_seed(0)
    channels = input_channels(trained.config.input.features)
    xyz = torch.rand(3, 128, channels, generator=generator) * 2 - 1
    mask = torch.ones(3, 128, dtype=torch.bool)
    with torch.inference_mode():
        one, two = torch.softmax(averaged(xyz, mask), -1), torch.softmax(live(xyz, mask), -1)
        mixed = torch.softmax(ensemble(xyz, mask), -1)
    assert (one - two).abs().max() > 1e-3  # two different networks
    torch.testing.assert_close(mixed, (one + two) / 2, atol=1e-6, rtol=1e-5)


def test_an_ensemble_of_one_network_twice_labels_as_the_network(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud],
) -> None:
    checkpoint = trained_run / "run" / "last.pt"
    twin = shutil.copy(checkpoint, tmp_path / "twin.pt")
    write_text_cloud(tmp_path / "real.txt", room(40, size_m=(4.0, 3.5), points_per_m2=30))
    alone = evaluate_checkpoint(checkpoint, [tmp_path / "real.txt"], device="cpu")[0].labels.confusion
    both = evaluate_checkpoint(checkpoint, [tmp_path / "real.txt"], device="cpu", ensemble=[twin])[0].labels.confusion
    assert both.sum() == alone.sum()
    assert np.abs(np.diag(both) - np.diag(alone)).sum() <= 0.001 * alone.sum()


def test_checkpoints_of_other_inputs_are_refused_naming_what_differs(tmp_path: Path, trained_run: Path) -> None:
    checkpoint = trained_run / "run" / "last.pt"
    payload = torch.load(checkpoint, weights_only=True)
    payload["config"]["input"]["grid_m"] = 0.2
    other = tmp_path / "other.pt"
    torch.save(payload, other)
    with pytest.raises(LearnError, match=r"its \[input\] grid_m \(0\.2 against 0\.05\) differs from an earlier member's"):
        load_trained_models([checkpoint, other])


def test_predict_with_an_ensemble_from_the_command_line_records_it(
    tmp_path: Path, trained_run: Path, room: Callable[..., PointCloud], capsys: pytest.CaptureFixture[str],
) -> None:
    from bimscan.io import read_cloud_header

    checkpoint = trained_run / "run" / "last.pt"
    twin = shutil.copy(checkpoint, tmp_path / "twin.pt")
    write_text_cloud(tmp_path / "scan.txt", room(41, size_m=(4.0, 3.0), points_per_m2=30))
    out = tmp_path / "labelled.laz"
    assert main(["predict", str(checkpoint), str(tmp_path / "scan.txt"), str(out), "--ensemble", str(twin),
                 "--device", "cpu"]) == 0
    assert "wrote" in capsys.readouterr().out
    header = read_cloud_header(out)
    assert header is not None and header.metadata["prediction"]["ensemble"] == [str(twin)]


def test_merged_inputs_compute_each_feature_once_with_the_settings_of_the_models_that_read_it() -> None:
    from bimscan.learn.train_config import InputConfig, merge_inputs

    network = InputConfig(grid_m=0.1, features=("xyz", "height", "normals", "shape"), wide_neighbours=128)
    trees = InputConfig(grid_m=0.1, features=("xyz", "shape_wide", "height"), wide_neighbours=64)
    union, channels = merge_inputs([network, trees])
    assert union.features == ("xyz", "height", "normals", "shape", "shape_wide")
    assert union.wide_neighbours == 64  # the network does not read shape_wide: the trees' neighbourhood counts
    assert channels == [list(range(10)), [0, 1, 2, 10, 11, 12, 3]]
    with pytest.raises(ValueError, match=r"\[input\] wide_neighbours \(32 against 64\)"):
        merge_inputs([network, trees, InputConfig(grid_m=0.1, features=("xyz", "shape_wide"), wide_neighbours=32)])
    with pytest.raises(ValueError, match=r"\[input\] grid_m \(0.2 against 0.1\)"):
        merge_inputs([network, InputConfig(grid_m=0.2, features=("xyz",))])

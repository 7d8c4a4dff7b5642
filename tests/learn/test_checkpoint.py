"""Checkpoints: damaged, foreign, incomplete or mismatching files give one error line each."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import pytest
import torch

from bimscan.errors import InputFileError, LearnError
from bimscan.learn.checkpoint import load_trained_model, read_checkpoint


def _garbage(tmp_path: Path, trained_run: Path) -> dict[str, bytes]:
    real = (trained_run / "run" / "last.pt").read_bytes()
    archive = io.BytesIO()
    with zipfile.ZipFile(archive, "w") as handle:
        handle.writestr("archive/data.pkl", b"\x80\x02}q\x00.")  # a zip torch half understands
    return {
        "empty.pt": b"", "text.pt": b"not a checkpoint\n" * 10, "truncated.pt": real[: len(real) // 2],
        "zip.pt": archive.getvalue(), "noise.pt": bytes(range(256)) * 40,
    }


def test_damaged_or_foreign_files_are_one_error_line(tmp_path: Path, trained_run: Path) -> None:
    for name, data in _garbage(tmp_path, trained_run).items():
        (tmp_path / name).write_bytes(data)

        with pytest.raises(InputFileError, match="not a readable checkpoint|not a bimscan PCT checkpoint") as caught:
            load_trained_model(tmp_path / name)

        assert "\n" not in str(caught.value), name


def test_a_checkpoint_without_its_configuration_is_one_error_line(tmp_path: Path, trained_run: Path) -> None:
    payload = torch.load(trained_run / "run" / "last.pt", map_location="cpu", weights_only=True)
    del payload["config"]
    torch.save(payload, tmp_path / "partial.pt")

    with pytest.raises(InputFileError, match="incomplete checkpoint, no 'config'"):
        load_trained_model(tmp_path / "partial.pt")


def test_weights_that_do_not_fit_the_stored_model_are_one_short_error_line(tmp_path: Path, trained_run: Path) -> None:
    payload = torch.load(trained_run / "run" / "last.pt", map_location="cpu", weights_only=True)
    payload["class_names"] = [*payload["class_names"], "Extra"]  # one class more than the weights hold
    payload["config"]["model"]["embed_dim"] = 32  # and every layer wider
    torch.save(payload, tmp_path / "mismatch.pt")

    with pytest.raises(LearnError, match=r"the stored ema weights do not fit \(size mismatch for .* and \d+ more\)") as caught:
        load_trained_model(tmp_path / "mismatch.pt")

    assert "\n" not in str(caught.value) and len(str(caught.value)) < 400


def test_a_complete_checkpoint_reads(trained_run: Path) -> None:
    payload = read_checkpoint(trained_run / "run" / "last.pt")

    assert payload["epoch"] == 3 and payload["device"] == "cpu"


def test_a_checkpoint_with_non_finite_weights_is_refused_by_every_reader(tmp_path: Path, trained_run: Path) -> None:
    """A diverged run's model labels every point alike: predict, evaluate, --init and --resume refuse it."""
    from bimscan.learn.train import read_start
    from bimscan.learn.train_config import parse_config

    payload = torch.load(trained_run / "run" / "last.pt", map_location="cpu", weights_only=True)
    payload["ema"]["classifier.weight"][0, 0] = float("nan")
    torch.save(payload, tmp_path / "nan-ema.pt")
    payload = torch.load(trained_run / "run" / "last.pt", map_location="cpu", weights_only=True)
    payload["model"]["classifier.bias"][1] = float("inf")
    torch.save(payload, tmp_path / "inf-model.pt")

    for weights in ("ema", "live"):
        with pytest.raises(InputFileError, match=r"nan-ema.pt: its ema weights hold 1 non-finite value\(s\) "
                                                 r"\(classifier.weight\): the training that wrote it diverged"):
            load_trained_model(tmp_path / "nan-ema.pt", weights=weights)  # type: ignore[arg-type]
    with pytest.raises(InputFileError, match=r"its model weights hold 1 non-finite value\(s\) \(classifier.bias\)"):
        load_trained_model(tmp_path / "inf-model.pt")
    config = parse_config(payload["config"], where="test")
    with pytest.raises(InputFileError, match="non-finite"):
        read_start(tmp_path / "nan-ema.pt", config)

"""Training: deterministic on CPU, resume equals an uninterrupted run, two torchrun processes
equal one process with the same global batch, metrics CSV and curves written, and the
configuration checked."""

from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

import bimscan
from bimscan.errors import ConfigError, LearnError
from bimscan.learn.train_config import load_train_config
from bimscan.learn.plots import CSV_COLUMNS
from bimscan.learn.train import GlobalBatchSampler, train_model
from bimscan.io.text import write_text_cloud
from bimscan.types import PointCloud

from .conftest import denormals_kept


def _run(config_path: Path, **options: object) -> Path:
    config, base = load_train_config(config_path)
    return train_model(config, base_dir=base, log=lambda text: None, **options).checkpoint  # type: ignore[arg-type]


def _load(path: Path) -> dict[str, object]:
    return torch.load(path, map_location="cpu", weights_only=True)


def _assert_same_weights(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor], *, atol: float = 0.0) -> None:
    assert a.keys() == b.keys()
    for key in a:
        torch.testing.assert_close(a[key], b[key], atol=atol, rtol=0.0 if atol == 0.0 else 1e-4, msg=key)


def _metrics(history: list[dict[str, float]]) -> list[dict[str, float]]:
    return [{k: v for k, v in row.items() if k != "seconds"} for row in history]


def test_training_twice_with_one_seed_gives_identical_weights_whatever_the_loader_workers(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    first = _run(tiny_config(tmp_path, **room_files, out_dir="a", name="a.toml"))
    with_workers = tiny_config(tmp_path, **room_files, out_dir="b", name="b.toml")
    with_workers.write_text(with_workers.read_text().replace("num_workers = 0", "num_workers = 2"))
    second = _run(with_workers)
    other_seed = _run(tiny_config(tmp_path, **room_files, out_dir="c", name="c.toml", seed=1, epochs=1))

    a, b, c = _load(first), _load(second), _load(other_seed)
    _assert_same_weights(a["model"], b["model"])
    _assert_same_weights(a["ema"], b["ema"])
    assert _metrics(a["history"]) == _metrics(b["history"])
    assert not torch.equal(a["model"]["classifier.weight"], c["model"]["classifier.weight"])


def test_resumed_run_equals_an_uninterrupted_run(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    straight = _run(tiny_config(tmp_path, **room_files, epochs=3, out_dir="straight", name="s.toml"))
    resumed_config = tiny_config(tmp_path, **room_files, epochs=3, out_dir="resumed", name="r.toml")

    def crash(epoch: int, step: int) -> None:
        if (epoch, step) == (1, 1):  # in the middle of the second epoch, after one checkpoint
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(resumed_config, on_step_end=crash)
    assert _load(tmp_path / "resumed" / "last.pt")["epoch"] == 1
    resumed = _run(resumed_config, resume=True)

    a, b = _load(straight), _load(resumed)
    _assert_same_weights(a["model"], b["model"])
    _assert_same_weights(a["ema"], b["ema"])
    assert a["optimizer"]["state"][0]["step"] == b["optimizer"]["state"][0]["step"]
    assert _metrics(a["history"]) == _metrics(b["history"])


@pytest.mark.slow
def test_two_torchrun_processes_equal_one_process_with_the_same_global_batch(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    # global batch 4 both ways: 2 blocks x 2 processes x 1 accumulation = 2 x 1 x 2
    ddp_config = tiny_config(tmp_path, **room_files, accumulation=1, out_dir="ddp", name="ddp.toml")
    single_config = tiny_config(tmp_path, **room_files, accumulation=2, out_dir="single", name="single.toml")
    env = {**os.environ, "PYTHONPATH": str(Path(bimscan.__file__).resolve().parents[1]), "BIMSCAN_PROGRESS": "0"}
    env.pop("WORLD_SIZE", None)

    done = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
         "-m", "bimscan.cli.main", "train", str(ddp_config)],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    single = _run(single_config)

    ddp, one = _load(tmp_path / "ddp" / "last.pt"), _load(single)
    assert ddp["world_size"] == 2 and ddp["global_batch"] == one["global_batch"] == 4
    _assert_same_weights(ddp["model"], one["model"], atol=1e-5)
    _assert_same_weights(ddp["ema"], one["ema"], atol=1e-5)
    for row_ddp, row_one in zip(ddp["history"], one["history"], strict=True):
        assert row_ddp["train_loss"] == pytest.approx(row_one["train_loss"], rel=1e-5)
        assert row_ddp["val_miou"] == pytest.approx(row_one["val_miou"], abs=1e-6)


def test_training_writes_metric_history_and_curves(trained_run: Path) -> None:
    run = trained_run / "run"

    with (run / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))

    assert tuple(rows[0].keys()) == CSV_COLUMNS
    assert [int(r["epoch"]) for r in rows] == [1, 2, 3]
    for row in rows:
        for split in ("train", "val"):
            for name in ("oa", "miou", "macc", "fwiou"):
                assert 0.0 <= float(row[f"{split}_{name}"]) <= 1.0
            assert float(row[f"{split}_loss"]) > 0.0
    assert float(rows[-1]["train_loss"]) < float(rows[0]["train_loss"])  # it learns
    assert (run / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    checkpoint = _load(run / "last.pt")
    assert checkpoint["epoch"] == 3 and checkpoint["class_names"] == list(checkpoint["config"]["data"]["class_names"])
    assert (run / "best.pt").is_file()


def test_starting_over_an_existing_run_without_resume_is_refused(trained_run: Path) -> None:
    config, base = load_train_config(trained_run / "train.toml")

    with pytest.raises(LearnError, match="already holds a training run; pass --resume"):
        train_model(config, base_dir=base, log=lambda text: None)


def test_resuming_with_a_changed_configuration_is_refused_and_a_finished_run_is_not_called_interrupted(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    path = tiny_config(tmp_path, **room_files, epochs=2, name="run.toml")

    def crash(epoch: int, step: int) -> None:
        if epoch == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(path, on_step_end=crash)
    changed = tiny_config(tmp_path, **room_files, epochs=2, seed=9, name="changed.toml")
    with pytest.raises(LearnError, match=r"\[train\] seed was 0 in the interrupted run and is 9 now; resume with the "
                                         r"same configuration \(--resume\), or start a new run in another out_dir$"):
        _run(changed, resume=True)
    _run(path, resume=True)  # both epochs done
    with pytest.raises(LearnError, match=r"\[train\] seed was 0 in the finished run and is 9 now; start a new run in "
                                         r"another out_dir$"):
        _run(changed, resume=True)


def test_unknown_config_key_is_a_config_error(tmp_path: Path, room_files: dict[str, list[str]],
                                              tiny_config: Callable[..., Path]) -> None:
    path = tiny_config(tmp_path, **room_files)
    path.write_text(path.read_text().replace("max_lr = 0.01", "max_lr = 0.01\nlearning_rate = 0.1"))

    with pytest.raises(ConfigError, match="unknown key\\(s\\) 'learning_rate'"):
        load_train_config(path)


def test_block_size_must_be_a_whole_multiple_of_the_stride(tmp_path: Path, room_files: dict[str, list[str]],
                                                           tiny_config: Callable[..., Path]) -> None:
    path = tiny_config(tmp_path, **room_files)
    path.write_text(path.read_text().replace("stride_m = 1.0", "stride_m = 1.5"))

    with pytest.raises(ConfigError, match="stride_m = 1.5 does not divide the 2 m blocks whole"):
        load_train_config(path)


def test_a_setting_that_moved_names_its_new_home(tmp_path: Path, room_files: dict[str, list[str]],
                                                 tiny_config: Callable[..., Path]) -> None:
    path = tiny_config(tmp_path, **room_files)
    path.write_text(path.read_text().replace("size_m = 2.0", "size_m = 2.0\neval_votes = 3"))

    with pytest.raises(ConfigError, match=r"\[blocks\] eval_votes is now \[eval\] votes"):
        load_train_config(path)


@pytest.mark.parametrize(("world", "accumulation"), [(2, 1), (2, 2), (4, 1)])
def test_processes_split_each_global_batch_like_one_process_accumulating(world: int, accumulation: int) -> None:
    one = GlobalBatchSampler(23, batch_size=2, accumulation=world * accumulation, world=1, rank=0, seed=4)
    ranks = [GlobalBatchSampler(23, batch_size=2, accumulation=accumulation, world=world, rank=r, seed=4)
             for r in range(world)]
    for sampler in (one, *ranks):
        sampler.set_epoch(3)

    single = list(one)
    per_rank = [list(r) for r in ranks]
    rebuilt = []
    for step in range(one.steps_per_epoch):
        for rank_batches in per_rank:
            rebuilt += rank_batches[step * accumulation:(step + 1) * accumulation]

    assert rebuilt == single
    assert one.steps_per_epoch == math.ceil(23 / (2 * world * accumulation))
    assert {i for batch in single for _, i in batch} == set(range(23))  # every tile each epoch


@pytest.mark.parametrize("name", ["table2.toml", "tiny_cpu.toml"])
def test_the_shipped_training_configs_load(name: str) -> None:
    path = Path(bimscan.__file__).resolve().parents[2] / "configs" / "training" / name

    config, base = load_train_config(path)

    assert base == path.parent
    if name == "table2.toml":  # the paper's Table 2, to the letter
        assert (config.blocks.points, config.train.batch_size, config.train.accumulation_steps) == (8192, 2, 4)
        assert (config.train.max_lr, config.train.weight_decay, config.train.ema_alpha) == (2e-3, 5e-4, 0.99)
        assert config.train.amp == "float16" and len(config.data.class_names) == 5
        # and none of bimscan's sim-to-real recipe, whose defaults are on
        assert config.input.features == ("xyz",) and config.input.grid_m == 0.0
        assert not config.augment.enabled and config.train.class_weights == "none"
        assert config.blocks.train_columns == "scene"


def test_a_validation_set_without_labels_is_refused_before_training(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path], room: Callable[..., PointCloud],
) -> None:
    write_text_cloud(tmp_path / "bare.xyz", PointCloud(xyz=room(60, points_per_m2=40).xyz))
    steps: list[int] = []

    with pytest.raises(LearnError, match=r"\[data\] val: no column of its 1 scene\(s\) has ground truth"):
        _run(tiny_config(tmp_path, train=room_files["train"], val=["bare.xyz"], out_dir="bare"),
             on_step_end=lambda epoch, step: steps.append(step))

    assert steps == [] and not (tmp_path / "bare" / "last.pt").exists()


def test_a_run_refused_while_reading_its_scenes_leaves_no_folder_behind(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path], room: Callable[..., PointCloud],
) -> None:
    """The run folder (and its tile cache) goes with a bad input when this run made it; an empty
    folder that was there before stays."""
    write_text_cloud(tmp_path / "bare.xyz", PointCloud(xyz=room(60, points_per_m2=40).xyz))
    config = tiny_config(tmp_path, train=room_files["train"], val=["bare.xyz"], out_dir="fresh")

    with pytest.raises(LearnError, match=r"\[data\] val: no column"):
        _run(config)
    assert not (tmp_path / "fresh").exists()

    (tmp_path / "empty").mkdir()
    with pytest.raises(LearnError, match=r"\[data\] val: no column"):
        _run(tiny_config(tmp_path, train=room_files["train"], val=["bare.xyz"], out_dir="empty"))
    assert (tmp_path / "empty").is_dir() and not (tmp_path / "empty" / "last.pt").exists()


def test_the_logged_learning_rate_is_the_last_one_each_epoch_applied(trained_run: Path) -> None:
    checkpoint = _load(trained_run / "run" / "last.pt")
    settings = checkpoint["config"]["train"]
    total = checkpoint["scheduler"]["total_steps"]
    per_epoch = total // settings["epochs"]
    parameter = torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.Adam([parameter], lr=settings["max_lr"])
    scheduler = torch.optim.lr_scheduler.OneCycleLR(
        optimizer, max_lr=settings["max_lr"], total_steps=total, pct_start=settings["pct_start"],
        anneal_strategy="cos", div_factor=settings["div_factor"], final_div_factor=settings["final_div_factor"],
    )
    applied = []
    for _ in range(total):
        applied.append(optimizer.param_groups[0]["lr"])
        optimizer.step()
        scheduler.step()

    logged = [row["lr"] for row in checkpoint["history"]]

    assert logged == pytest.approx([applied[(epoch + 1) * per_epoch - 1] for epoch in range(settings["epochs"])])


def test_resuming_on_another_kind_of_device_is_refused(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    config = tiny_config(tmp_path, **room_files, epochs=2)

    def crash(epoch: int, step: int) -> None:
        if epoch == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(config, on_step_end=crash)
    last = tmp_path / "run" / "last.pt"
    payload = _load(last)
    used, other = payload["device"], "cuda" if payload["device"] == "cpu" else "cpu"
    payload["device"] = other
    torch.save(payload, last)

    with pytest.raises(LearnError, match=f"the interrupted run trained on {other} and would continue on {used}; "
                                         f'continue it on {other} \\(\\[train\\] device = "{other}"\\)'):
        _run(config, resume=True)


def test_cycling_adam_beta1_with_the_learning_rate_is_a_setting(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    cycled = _run(tiny_config(tmp_path, **room_files, epochs=1, out_dir="cycled", name="cycled.toml"))
    fixed_config = tiny_config(tmp_path, **room_files, epochs=1, out_dir="fixed", name="fixed.toml")
    fixed_config.write_text(fixed_config.read_text().replace("max_lr = 0.01", "max_lr = 0.01\ncycle_momentum = false"))
    fixed = _run(fixed_config)

    assert _load(cycled)["optimizer"]["param_groups"][0]["betas"][0] != 0.9  # PyTorch's default: cycled
    assert _load(fixed)["optimizer"]["param_groups"][0]["betas"][0] == 0.9


def test_training_flushes_denormals_for_the_network_only(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path], monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The loader's features (SciPy's cKDTree, which crashed under flush-to-zero) run with
    denormals kept; the network's forward with them flushed (its CPU speed)."""
    import numpy as np

    import bimscan.learn.features as features
    from bimscan.learn.model import PCTSegmentation

    seen: dict[str, list[bool]] = {"features": [], "network": []}
    geometry, forward = features.local_geometry_scales, PCTSegmentation.forward

    def spy_geometry(xyz: np.ndarray, scales: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
        seen["features"].append(denormals_kept())
        return geometry(xyz, scales)

    def spy_forward(self: PCTSegmentation, xyz: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        seen["network"].append(denormals_kept())
        return forward(self, xyz, mask)

    monkeypatch.setattr(features, "local_geometry_scales", spy_geometry)
    monkeypatch.setattr(PCTSegmentation, "forward", spy_forward)
    _run(tiny_config(tmp_path, **room_files, epochs=1))
    assert seen["features"] and all(seen["features"])  # the recipe's normals and shape, training and validation
    assert seen["network"] and not any(seen["network"])
    assert denormals_kept()



def test_a_diverged_training_stops_with_one_line_and_keeps_the_last_finite_checkpoint(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Weights gone non-finite in the second epoch (an exploding step: here a NaN put into one
    weight by its second optimizer step): the run stops at that step, naming it, and last.pt stays
    the first epoch's, finite."""
    import bimscan.learn.train as train_module

    config, base = load_train_config(tiny_config(tmp_path, **room_files, epochs=3, out_dir="run"))
    in_second_epoch: list[bool] = []
    original = train_module.finish_step

    def exploding_step(model: torch.nn.Module, **kwargs: object) -> None:
        original(model, **kwargs)  # type: ignore[arg-type]
        if in_second_epoch:
            with torch.no_grad():
                model.classifier.weight[0, 0] = math.nan

    def after_step(epoch: int, step: int) -> None:
        if (epoch, step) == (1, 0):
            in_second_epoch.append(True)

    monkeypatch.setattr(train_module, "finish_step", exploding_step)
    with pytest.raises(LearnError) as caught:
        train_model(config, base_dir=base, log=lambda text: None, on_step_end=after_step)

    message = str(caught.value)
    assert message.startswith("training diverged at epoch 2, step 2 (loss ")
    assert "the weights are no longer finite" in message and "last.pt (epoch 1) is the last finite checkpoint" in message
    assert "lower [train] max_lr (now 0.01)" in message and "\n" not in message
    kept = _load(tmp_path / "run" / "last.pt")
    assert kept["epoch"] == 1
    assert all(bool(torch.isfinite(t).all()) for t in kept["model"].values() if t.is_floating_point())


def test_an_absurd_learning_rate_is_refused_when_the_file_is_read(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    path = tiny_config(tmp_path, **room_files)
    path.write_text(path.read_text().replace("max_lr = 0.01", "max_lr = 1e9"))

    with pytest.raises(ConfigError, match=r"key 'train': max_lr must be a number in \(0, 1\], got 1e\+09"):
        load_train_config(path)


def test_freezing_without_a_checkpoint_to_start_from_is_refused(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    path = tiny_config(tmp_path, **room_files, out_dir="frozen")
    path.write_text(path.read_text().replace("num_workers = 0", 'num_workers = 0\nfreeze = ["embedding"]'))

    with pytest.raises(LearnError, match=r"freeze = \['embedding'\] .* without --init they start random"):
        _run(path)

    assert not (tmp_path / "frozen").exists()


def test_resuming_with_another_start_checkpoint_is_refused_and_with_the_same_one_continues(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path], trained_run: Path,
) -> None:
    parent = trained_run / "run" / "last.pt"
    other = _run(tiny_config(tmp_path, **room_files, epochs=1, out_dir="other", name="other.toml"))
    path = tiny_config(tmp_path, **room_files, epochs=2, out_dir="tuned", name="tuned.toml")

    def crash(epoch: int, step: int) -> None:
        if epoch == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _run(path, init=parent, on_step_end=crash)
    with pytest.raises(LearnError, match=r"started from another checkpoint .* leave --init out"):
        _run(path, resume=True, init=other)
    scratch = _run(tiny_config(tmp_path, **room_files, epochs=2, out_dir="scratch", name="scratch.toml"))
    with pytest.raises(LearnError, match="started from random weights"):
        _run(tmp_path / "scratch.toml", resume=True, init=parent)

    resumed = _load(_run(path, resume=True, init=parent))
    assert resumed["epoch"] == 2 and resumed["init"]["checkpoint"] == str(parent)
    assert _load(scratch)["init"] is None


def test_a_network_that_reads_colour_trains_on_coloured_scans_and_labels_one_without_colour(
    tmp_path: Path, tiny_config: Callable[..., Path], room: Callable[..., PointCloud],
) -> None:
    import numpy as np

    from bimscan.learn.checkpoint import load_trained_model
    from bimscan.learn.data import list_scenes
    from bimscan.learn.infer import label_scene

    rng = np.random.default_rng(0)
    train = []
    for i in range(2):
        cloud = room(i, size_m=(4.0 + i, 3.0), points_per_m2=40)
        palette = rng.integers(0, 256, (5, 3)).astype(np.uint8)  # a colour per class, as surface styles give
        write_text_cloud(tmp_path / f"room{i}.txt", PointCloud(xyz=cloud.xyz, label=cloud.label,
                                                               rgb=palette[cloud.label]))
        train.append(f"room{i}.txt")
    write_text_cloud(tmp_path / "real.txt", room(100, size_m=(4.0, 4.0), points_per_m2=40))
    path = tiny_config(tmp_path, train=train, val=["real.txt"], epochs=1, out_dir="colour")
    path.write_text(path.read_text() + '\n[input]\nfeatures = ["xyz", "height", "rgb"]\n\n[augment]\n'
                    'colour_gain_sigma = 0.1\ncolour_drop = 0.2\n')

    checkpoint = _run(path)

    trained = load_trained_model(checkpoint)
    assert trained.config.input.features == ("xyz", "height", "rgb")
    (source,) = list_scenes([tmp_path / "real.txt"])  # no colour: read as mid grey
    labels = label_scene(trained.model, source, class_names=trained.class_names, blocks=trained.config.blocks,
                         evaluation=trained.config.eval, inputs=trained.config.input)
    assert labels.labelled == labels.points > 0

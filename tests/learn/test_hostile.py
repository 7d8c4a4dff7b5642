"""Hostile input to the learning commands (issue 50): a checkpoint whose weights are finite but
absurd, a scan in millimetres or centimetres, a scan that holds no point, a batch larger than the
data, an adaptation rerun with other arguments. Each stops with one line that names what the user
gave and what to do, before any expensive work and without leaving a model behind."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.cli.main import main
from bimscan.errors import LearnError
from bimscan.io.text import write_text_cloud
from bimscan.learn.data import list_scenes
from bimscan.learn.train_config import AdaptationSchedule, BlockConfig, load_train_config
from bimscan.types import PointCloud

from .conftest import make_room


def _absurd_checkpoint(trained_run: Path, out: Path) -> Path:
    """The tiny trained checkpoint with its classifier's weights times 1e38: finite, but every
    output of the network is tens of orders of magnitude beyond any trained network's."""
    payload = torch.load(trained_run / "run" / "last.pt", map_location="cpu", weights_only=True)
    for key in ("model", "ema"):
        payload[key]["classifier.weight"] = payload[key]["classifier.weight"] * 1e38
    torch.save(payload, out)
    return out


def _one_error_line(capsys: pytest.CaptureFixture[str], *, after_log: bool = False) -> str:
    """The one ``error:`` line the command ended with (``after_log``: after its progress lines)."""
    err = capsys.readouterr().err
    last = err.splitlines(keepends=True)[-1] if after_log and err else err
    assert last.startswith("error: ") and last.count("\n") == 1 and err.count("error: ") == 1, err
    return last


def _scaled_room(path: Path, factor: float, *, seed: int = 60) -> Path:
    cloud = make_room(seed, size_m=(4.0, 3.0), points_per_m2=40)
    write_text_cloud(path, PointCloud(xyz=cloud.xyz * factor, label=cloud.label))
    return path


# -- a checkpoint whose weights are finite but absurd -------------------------------------------


def test_predict_and_evaluate_stop_at_a_checkpoint_whose_finite_weights_overflow_the_network(
    tmp_path: Path, trained_run: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    """Its outputs (1e37 and more) pass a softmax as one-hot votes: every point would get one class
    and the command exit 0. It stops at the first block, naming the checkpoint; no cloud is left."""
    absurd = _absurd_checkpoint(trained_run, tmp_path / "absurd.pt")
    scan = trained_run / "real.txt"

    assert main(["predict", str(absurd), str(scan), str(tmp_path / "out.laz"), "--device", "cpu"]) == 1
    err = _one_error_line(capsys)
    assert f"{absurd}: the network's outputs on {scan} overflow" in err and "pass another checkpoint" in err
    assert not (tmp_path / "out.laz").exists()
    assert main(["evaluate", str(absurd), str(scan), "--device", "cpu"]) == 1
    assert f"{absurd}: the network's outputs on {scan} overflow" in _one_error_line(capsys)


def test_adapting_or_fine_tuning_from_a_checkpoint_whose_finite_weights_overflow_stops_and_saves_nothing(
    tmp_path: Path, trained_run: Path, tiny_config: Callable[..., Path], capsys: pytest.CaptureFixture[str],
) -> None:
    """adapt stops when its teacher (the checkpoint's weights) labels the scans, fine-tuning at its
    first step (a loss of inf): neither trains on, nor writes last.pt."""
    absurd = _absurd_checkpoint(trained_run, tmp_path / "absurd.pt")

    assert main(["adapt", str(absurd), str(trained_run / "real.txt"), str(tmp_path / "adapted"), "--device", "cpu"]) == 1
    err = _one_error_line(capsys, after_log=True)
    assert f"{absurd}: the network's outputs on the unlabelled scans overflow" in err
    assert "start from another checkpoint" in err
    assert not (tmp_path / "adapted" / "last.pt").exists()

    rooms = [str(trained_run / f"room{i}.txt") for i in range(3)]
    config = tiny_config(tmp_path, train=rooms, val=[], epochs=1, out_dir="tuned")
    assert main(["train", str(config), "--init", str(absurd)]) == 1
    err = _one_error_line(capsys, after_log=True)
    assert f"{absurd}: its weights make the network's outputs overflow (loss inf at the first step" in err
    assert not (tmp_path / "tuned" / "last.pt").exists()


def test_a_loss_that_overflows_while_the_weights_stay_finite_stops_the_run_and_keeps_the_last_checkpoint(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The issue's "train loss inf" that kept going and saved last.pt: an infinite loss in the
    second epoch (the weights untouched: an optimizer step skipped as float16 AMP's scaler skips
    it) stops the run at that step; last.pt stays the first epoch's."""
    import bimscan.learn.train as train_module

    config, base = load_train_config(tiny_config(tmp_path, **room_files, epochs=2, out_dir="run"))
    original_step, original_save = train_module.run_micro_batch, train_module._save_epoch
    saved: list[bool] = []

    def overflowing(*args: object, **kwargs: object) -> tuple[torch.Tensor, ...]:
        logits, loss, count, objective = original_step(*args, **kwargs)  # type: ignore[arg-type]
        if saved:  # in the second epoch
            return logits, loss * torch.inf, count, objective * torch.inf
        return logits, loss, count, objective

    def save(*args: object) -> None:
        original_save(*args)  # type: ignore[arg-type]
        saved.append(True)

    monkeypatch.setattr(train_module, "run_micro_batch", overflowing)
    monkeypatch.setattr(train_module, "_save_epoch", save)
    with pytest.raises(LearnError) as caught:
        train_module.train_model(config, base_dir=base, log=lambda text: None)

    message = str(caught.value)
    assert message.startswith("training diverged at epoch 2, step 1 (loss inf): the loss or the network's outputs "
                              "overflow")
    assert "last.pt (epoch 1) is the last finite checkpoint and is kept" in message
    assert torch.load(tmp_path / "run" / "last.pt", weights_only=True)["epoch"] == 1


# -- batches larger than the data -----------------------------------------------------------------


@pytest.mark.parametrize(("setting", "value", "batch"), [("batch_size", 4096, "8,192"),
                                                         ("accumulation_steps", 4096, "8,192")])
def test_a_global_batch_over_twice_the_blocks_of_an_epoch_is_refused_before_training(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path], setting: str, value: int,
    batch: str,
) -> None:
    """batch_size 4096 over a few dozen blocks made every epoch thousands of draws of the same
    blocks (49 s instead of 1 s); accumulation_steps 4096 ran for hours."""
    import bimscan.learn.train as train_module

    path = tiny_config(tmp_path, **room_files, epochs=1)  # batch_size 2, accumulation_steps 2
    path.write_text(path.read_text().replace(f"{setting} = 2", f"{setting} = {value}"))
    config, base = load_train_config(path)

    with pytest.raises(LearnError, match=rf"^one optimizer step takes a global batch of {batch} blocks \(\[train\] "
                                         r"batch_size \d+ x 1 process\(es\) x \[train\] accumulation_steps \d+\), more "
                                         r"than twice the \d+ an epoch draws .*; lower \[train\] batch_size or "
                                         r"accumulation_steps, or train on more data$"):
        train_module.train_model(config, base_dir=base, log=lambda text: None)
    assert not (tmp_path / "run" / "last.pt").exists()


def test_a_run_says_how_many_blocks_its_epochs_draw_before_it_starts(
    tmp_path: Path, room_files: dict[str, list[str]], tiny_config: Callable[..., Path],
) -> None:
    from bimscan.learn.train import train_model

    config, base = load_train_config(tiny_config(tmp_path, **room_files, epochs=1))
    lines: list[str] = []

    def stop(epoch: int, step: int) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_model(config, base_dir=base, log=lines.append, on_step_end=stop)

    assert "global batch 4 = 2 x 1 process(es) x 2 accumulation" in lines[0]
    steps = int(lines[0].split(" steps/epoch")[0].rsplit(" ", 1)[1])
    assert f"{steps} steps/epoch ({4 * steps} blocks drawn)" in lines[0]


# -- scans that hold no point, or are not in metres ----------------------------------------------


@pytest.mark.parametrize("header", ["x y z\n", "x,y,z,classification\n"])
def test_adapting_to_a_scan_that_holds_only_a_header_is_one_line(
    tmp_path: Path, trained_run: Path, capsys: pytest.CaptureFixture[str], header: str,
) -> None:
    """Was a traceback (zip() argument 2 is longer than argument 1) after reading the other scans."""
    scan = tmp_path / "header-only.txt"
    scan.write_text(header)

    assert main(["adapt", str(trained_run / "run" / "last.pt"), str(scan), str(tmp_path / "adapted")]) == 1
    assert "header-only.txt: the scene holds no points" in _one_error_line(capsys)
    assert not (tmp_path / "adapted").exists()


@pytest.mark.parametrize(("factor", "unit"), [(1000.0, "millimetres"), (100.0, "centimetres")])
def test_predict_and_evaluate_refuse_a_room_in_another_unit_before_labelling_it(
    tmp_path: Path, trained_run: Path, monkeypatch: pytest.MonkeyPatch, factor: float, unit: str,
) -> None:
    """A room in centimetres is no wider than a building in metres, so no extent check saw it; read
    as metres its columns hold a point or two, and labelling it ran minutes. It is refused from its
    first points, before anything is labelled."""
    import bimscan.learn.evaluate as evaluate_module
    import bimscan.learn.predict as predict_module

    def labelled(*args: object, **kwargs: object) -> None:
        raise AssertionError("the scene was labelled")

    monkeypatch.setattr(predict_module, "label_scene", labelled)
    monkeypatch.setattr(evaluate_module, "label_scene", labelled)
    checkpoint = trained_run / "run" / "last.pt"
    scan = _scaled_room(tmp_path / "room.txt", factor)

    pattern = rf"room.txt: the scene is .* units across; bimscan reads metres: it looks like {unit}, so scale it to " \
              r"metres first \(its [\d,]+ points spread over [\d,]+ columns of 2 m, [\d.]+ per column, under \[blocks\] " \
              r"min_points = 32"
    with pytest.raises(LearnError, match=pattern):
        predict_module.predict_cloud(checkpoint, scan, tmp_path / "out.laz", device="cpu")
    with pytest.raises(LearnError, match=pattern):
        evaluate_module.evaluate_checkpoint(checkpoint, [trained_run / "real.txt", scan], device="cpu")
    assert not (tmp_path / "out.laz").exists()


def test_adapting_to_or_training_on_a_room_in_millimetres_is_refused_before_any_scene_is_read(
    tmp_path: Path, trained_run: Path, tiny_config: Callable[..., Path], capsys: pytest.CaptureFixture[str],
) -> None:
    """adapt read every scan into tiles for 37 s before "no column ... holds blocks.min_points"; now
    the unit is named at once, and neither OUT nor its tile cache is made."""
    scan = _scaled_room(tmp_path / "mm.txt", 1000.0)

    assert main(["adapt", str(trained_run / "run" / "last.pt"), str(scan), str(tmp_path / "adapted")]) == 1
    assert "mm.txt: the scene is" in (err := _one_error_line(capsys)) and "it looks like millimetres" in err
    assert not (tmp_path / "adapted").exists()

    config = tiny_config(tmp_path, train=[str(trained_run / "room0.txt"), "mm.txt"], val=[], out_dir="run")
    assert main(["train", str(config)]) == 1
    assert "it looks like millimetres" in _one_error_line(capsys)
    assert not (tmp_path / "run").exists()


def test_scans_in_metres_pass_the_unit_check_however_large_or_far_from_the_origin(tmp_path: Path) -> None:
    """A 500 m site of rooms in UTM coordinates (5,400 km north), a 10 m tall hall (in feet it
    would be a storey) and a sparse cloud kilometres wide that fits no other unit all pass."""
    from bimscan.learn.data import check_scene_unit

    blocks = BlockConfig(size_m=3.0, points=1024, min_points=256, cache_points=4096)
    rooms = [make_room(i, size_m=(6.0, 4.0), points_per_m2=20, origin=(100.0 * (i % 6), 500.0 * (i // 5)))
             for i in range(10)]
    site = PointCloud.concatenate(rooms)
    write_text_cloud(tmp_path / "site.txt", PointCloud(xyz=site.xyz + [500_000.0, 5_400_000.0, 300.0], label=site.label))
    hall = make_room(20, size_m=(20.0, 10.0), height_m=10.0, points_per_m2=20)
    write_text_cloud(tmp_path / "hall.txt", hall)
    rng = np.random.default_rng(0)
    write_text_cloud(tmp_path / "sparse.txt", PointCloud(xyz=rng.random((1000, 3)) * [10_000.0, 10_000.0, 3.0]))

    for name in ("site.txt", "hall.txt", "sparse.txt"):
        check_scene_unit(list_scenes([tmp_path / name])[0], blocks=blocks)


# -- bimscan adapt speaks of its own arguments ---------------------------------------------------


def _adaptation_in(out: Path, checkpoint: Path, scans: list[Path], *, epochs_done: int, epochs: int = 1) -> None:
    """``out`` as ``bimscan adapt CHECKPOINT SCAN... OUT --epochs epochs`` leaves it after
    ``epochs_done`` epochs: its last.pt (the trained checkpoint's state under the adaptation's
    configuration; what resuming reads)."""
    from bimscan.files import file_sha256
    from bimscan.learn.adapt import adaptation_config
    from bimscan.learn.checkpoint import save_checkpoint
    from bimscan.learn.train_config import dump_config

    payload = torch.load(checkpoint, map_location="cpu", weights_only=True)
    schedule = AdaptationSchedule(epochs=epochs)
    payload.update(config=dump_config(adaptation_config(checkpoint, scans, schedule=schedule)), epoch=epochs_done,
                   init={"checkpoint": str(checkpoint), "sha256": file_sha256(checkpoint), "epoch": payload["epoch"]})
    out.mkdir()
    save_checkpoint(out / "last.pt", {k: v for k, v in payload.items() if k not in ("format", "version")})


def test_adapt_refusals_name_its_own_arguments_and_a_finished_adaptation_is_not_called_interrupted(
    tmp_path: Path, trained_run: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    checkpoint = trained_run / "run" / "last.pt"
    scan, other = trained_run / "real.txt", trained_run / "room0.txt"
    finished, stopped = tmp_path / "finished", tmp_path / "stopped"
    _adaptation_in(finished, checkpoint, [scan], epochs_done=1)
    _adaptation_in(stopped, checkpoint, [scan], epochs_done=1, epochs=2)
    outputs = []

    assert main(["adapt", str(checkpoint), str(other), str(finished)]) == 1
    outputs.append(err := _one_error_line(capsys))
    assert f"SCAN... was ['{scan}'] in the finished adaptation and is ['{other}'] now; give another OUT\n" in err
    assert main(["adapt", str(checkpoint), str(scan), str(finished), "--epochs", "2"]) == 1
    outputs.append(err := _one_error_line(capsys))
    assert "--epochs was 1 in the finished adaptation and is 2 now; give another OUT\n" in err
    assert main(["adapt", str(checkpoint), str(other), str(stopped), "--epochs", "2"]) == 1
    outputs.append(err := _one_error_line(capsys))
    assert ("in the interrupted adaptation and is ['" + str(other) + "'] now; give the same CHECKPOINT, SCAN... and "
            "options to continue it, or give another OUT\n") in err
    another = tmp_path / "another.pt"
    another.write_bytes(checkpoint.read_bytes() + b"\0")  # other bytes: another checkpoint
    assert main(["adapt", str(another), str(scan), str(finished)]) == 1
    outputs.append(err := _one_error_line(capsys))
    assert f"CHECKPOINT {another}: the adaptation in {finished} started from another checkpoint ({checkpoint}); give " \
           "that checkpoint to continue it, or another OUT" in err
    for line in outputs:
        assert not any(word in line for word in ("--init", "--resume", "out_dir", "[train] epochs", "[data] adapt"))


def test_an_adapting_variant_takes_bimscan_adapts_schedule_from_its_parent(tmp_path: Path) -> None:
    """The adaptation experiment copied adapt's learning rate as a literal (1e-3, a fifth of its
    parent's 5e-3): a change of either left them apart. Both now read AdaptationSchedule; a
    variant's own [train] still wins."""
    from bimscan.learn.experiment import parse_experiment, training_sections

    write_text_cloud(tmp_path / "real.txt", make_room(1, size_m=(4.0, 3.0), points_per_m2=40))
    (tmp_path / "exp.toml").write_text("""\
[real]
scenes = ["real.txt"]

[train]
epochs = 3
max_lr = 5e-3
freeze = ["embedding"]

[[variants]]
name = "parent"
data = "real.txt"
train = { freeze = [] }

[[variants]]
name = "adapted"
init = "parent"
data = "real.txt"
adapt_to = "scored"

[[variants]]
name = "own-schedule"
init = "parent"
data = "real.txt"
adapt_to = "scored"
train = { epochs = 2 }
""")
    variants = {v.name: training_sections(v)["train"] for v in parse_experiment(tmp_path / "exp.toml").variants}

    schedule = AdaptationSchedule()
    assert (variants["adapted"].epochs, variants["adapted"].max_lr) == (schedule.epochs, 1e-3)
    assert variants["adapted"].freeze == ()  # the parent's, as bimscan adapt trains every part
    assert (variants["own-schedule"].epochs, variants["own-schedule"].max_lr) == (2, 1e-3)
    shipped = Path(__file__).parents[2] / "configs" / "experiments" / "sim2real_adapt_cpu.toml"
    assert "max_lr" not in shipped.read_text().split("[[variants]]", 1)[1]  # no copy of the schedule left

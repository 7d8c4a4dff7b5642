"""bimscan sim2real: the experiment file is checked before any work; a tiny experiment runs end
to end (one generated building built, two variants trained, scored on a labelled room), writes
every output and continues where it stopped; variants training on real rooms (alone, or
fine-tuning a synthetic model) are never scored on a room they trained on."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from bimscan.cli.main import main
from bimscan.errors import ConfigError, IfcError, InputFileError, LearnError, OutputError
from bimscan.io.text import write_text_cloud
from bimscan.types import PointCloud
from bimscan.learn.experiment import training_sections
from bimscan.sim2real import load_experiment, run_experiment, training_config

from .conftest import make_room

SPEC = """\
name = "tiny"
seed = 0
formats = ["npy"]

[[scenes]]
name = "b"
generate = { seed = 3, storeys = 1 }

[[configs]]
name = "exp1"
preset = "exp1"
head_deg_per_s = 180.0
"""

EXPERIMENT = """\
[experiment]
name = "tiny"

[real]
scenes = ["real.txt"]

[eval]
stride_m = 1.5

[blocks]
size_m = 3.0
points = 128
min_points = 32
cache_points = 512

[input]
grid_m = 0.15

[model]
embed_dim = 8
attention_layers = 1
fuse_dim = 16
head_dims = [16]
dropout = 0.0

[train]
epochs = 2
batch_size = 4
accumulation_steps = 1
max_lr = 0.01
amp = "off"
num_workers = 0
device = "cpu"

[[variants]]
name = "baseline"
data = "spec.toml"
input = { grid_m = 0.0, features = ["xyz"] }
augment = { enabled = false }
train = { class_weights = "none" }
blocks = { train_columns = "scene" }

[[variants]]
name = "recipe"
description = "all of it"
data = "spec.toml"
"""


class _Sections:
    def __init__(self, sections: dict[str, object]) -> None:
        self.__dict__.update(sections)


def _config(variant: object) -> _Sections:
    """A variant's training sections as attributes (``.model``, ``.train``, ...)."""
    return _Sections(training_sections(variant))  # type: ignore[arg-type]


SHARED_ROOMS = ("Area_6_office_1", "Area_6_hallway_3", "Area_6_copyRoom_1")


@pytest.fixture
def shipped_configs(tmp_path: Path, box_room_ifc: Path) -> Path:
    """The project's configs/ copied beside a stand-in for ../shared (the four sample IFC models, a
    box room each, and three tiny labelled S3DIS rooms): every shipped config loads as on a fresh
    clone, with or without the shared folder."""
    import shutil

    configs = tmp_path / "project" / "configs"
    shutil.copytree(Path(__file__).resolve().parents[2] / "configs", configs)
    models = tmp_path / "shared" / "data" / "ifc"
    models.mkdir(parents=True)
    for name in ("duplex", "AC20-FZK-Haus", "IfcOpenHouse_IFC4", "example"):
        shutil.copy(box_room_ifc, models / f"{name}.ifc")
    names = {0: "wall", 1: "beam", 2: "ceiling", 3: "floor", 4: "table"}
    for k, room in enumerate(SHARED_ROOMS):
        folder = tmp_path / "shared" / "data" / "real" / "s3dis_area6" / room / "Annotations"
        folder.mkdir(parents=True)
        cloud = make_room(40 + k, points_per_m2=20)
        for label, name in names.items():
            xyz = cloud.xyz[cloud.label == label]
            np.savetxt(folder / f"{name}_1.txt", np.column_stack([xyz, np.full((len(xyz), 3), 128.0)]),
                       fmt="%.4f %.4f %.4f %d %d %d")
    return configs


@pytest.fixture
def experiment_dir(tmp_path: Path) -> Path:
    (tmp_path / "spec.toml").write_text(SPEC, encoding="utf-8")
    (tmp_path / "exp.toml").write_text(EXPERIMENT, encoding="utf-8")
    write_text_cloud(tmp_path / "real.txt", make_room(100, size_m=(4.0, 4.0), points_per_m2=40))
    return tmp_path


def test_a_tiny_experiment_runs_end_to_end_and_resumes(experiment_dir: Path) -> None:
    out = experiment_dir / "out"
    summary = run_experiment(load_experiment(experiment_dir / "exp.toml"), out, log=lambda text: None)
    assert [v.variant for v in summary] == ["baseline", "recipe"]
    for name in ("report.md", "results.csv", "results.json", "val_miou.png", "experiment.json"):
        assert (out / name).stat().st_size > 0, name
    for variant in ("baseline", "recipe"):
        folder = out / "variants" / variant
        for name in ("train/last.pt", "train/metrics.csv", "train/curves.png", "eval/confusion.png",
                     "eval/evaluation.json", "eval/evaluation.md", "result.json"):
            assert (folder / name).is_file(), f"{variant}/{name}"
        result = json.loads((folder / "result.json").read_text())
        assert [len(epochs) for epochs in result["val_miou_per_epoch"]] == [2]
        assert set(result["pooled"]["iou"]) == {"Wall&Column", "Beam", "Covering", "Slab", "Others"}
        assert sum(map(sum, result["confusion"])) == result["pooled"]["points"] > 0
    report = (out / "report.md").read_text()
    assert "| baseline |" in report and "| recipe |" in report and "IoU Beam" in report
    # the recipe's model sees 10 channels (xyz, height, normals, shape), the baseline's 3: both were really trained as configured
    from bimscan.learn.checkpoint import load_trained_model

    assert load_trained_model(out / "variants/recipe/train/last.pt").model.embed1.conv.in_channels == 10
    assert load_trained_model(out / "variants/baseline/train/last.pt").model.embed1.conv.in_channels == 3

    # a killed run continues: the second run rebuilds nothing and retrains nothing
    (out / "variants" / "recipe" / "result.json").unlink()
    messages: list[str] = []
    again = run_experiment(load_experiment(experiment_dir / "exp.toml"), out, log=messages.append)
    assert any("baseline: finished earlier" in m for m in messages)
    assert not any("training" in m for m in messages)
    assert again[1].pooled == summary[1].pooled
    assert any("0 built, 1 already done" in m for m in messages)

    # once the data changes, the finished variants no longer stand for it: refused before training
    (experiment_dir / "spec.toml").write_text(SPEC.replace("head_deg_per_s = 180.0", "head_deg_per_s = 170.0"))
    with pytest.raises(LearnError, match="trained on other synthetic data"):
        run_experiment(load_experiment(experiment_dir / "exp.toml"), out, log=lambda text: None)


@pytest.mark.parametrize(("patch", "message"), [
    (("[input]\ngrid_m = 0.15", "[input]\ngrid_m = 0.15\nspeed = 2"), "unknown key"),
    (('scenes = ["real.txt"]', 'scenes = ["missing.txt"]'), "real scenes not found"),
    (('name = "recipe"', 'name = "baseline"'), "used twice"),
    (('data = "spec.toml"\ninput', 'data = "nothing.toml"\ninput'), "data not found"),
    (("epochs = 2", "epochs = 0"), "epochs must be an integer in 1..100000"),
    (('augment = { enabled = false }', 'augment = { enabled = false, flips = 1 }'), "flips"),
    (('name = "baseline"', 'name = "base line/x"'), "not a usable name"),
])
def test_bad_experiment_files_are_one_line_errors_before_any_work(
    experiment_dir: Path, patch: tuple[str, str], message: str, capsys: pytest.CaptureFixture[str],
) -> None:
    text = EXPERIMENT.replace(*patch)
    assert text != EXPERIMENT
    (experiment_dir / "exp.toml").write_text(text, encoding="utf-8")
    with pytest.raises((ConfigError, InputFileError), match=message):
        load_experiment(experiment_dir / "exp.toml")
    status = main(["sim2real", str(experiment_dir / "exp.toml"), str(experiment_dir / "out")])
    err = capsys.readouterr().err
    assert status == 1
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (experiment_dir / "out").exists()


def test_real_scenes_on_the_command_line_replace_those_of_the_file(experiment_dir: Path) -> None:
    write_text_cloud(experiment_dir / "other.txt", make_room(7, size_m=(3.0, 3.0), points_per_m2=40))
    parsed = load_experiment(experiment_dir / "exp.toml", real=[experiment_dir / "other.txt"], device="cpu")
    assert parsed.real.scenes == (str((experiment_dir / "other.txt").resolve()),)
    from bimscan.sim2real import _runs, _scored_scenes

    run = _runs(parsed, parsed.variants[0], _scored_scenes(parsed))[0]
    config = training_config(parsed, run, experiment_dir / "out")
    assert config.data.val is not None and config.data.val.scenes == parsed.real.scenes


def test_a_seed_on_the_command_line_replaces_every_variants_training_seed(experiment_dir: Path) -> None:
    from bimscan.sim2real import _runs, _scored_scenes

    parsed = load_experiment(experiment_dir / "exp.toml", seed=7)
    for variant in parsed.variants:
        config = training_config(parsed, _runs(parsed, variant, _scored_scenes(parsed))[0], experiment_dir / "out")
        assert config.train.seed == 7
    as_written = load_experiment(experiment_dir / "exp.toml")
    assert {v.sections["train"].get("seed", 0) for v in as_written.variants} != {7}


def test_every_shipped_experiment_and_spec_loads_on_a_fresh_clone(shipped_configs: Path) -> None:
    from bimscan.dataset.spec import load_spec

    experiments = sorted((shipped_configs / "experiments").glob("*.toml"))
    specs = sorted((shipped_configs / "datasets").glob("*.toml"))
    assert len(experiments) >= 4 and len(specs) >= 5
    for path in experiments:
        assert load_experiment(path).variants, path.name
    for path in specs:
        assert load_spec(path).unit_ids(), path.name
    listed = (shipped_configs / "README.md").read_text(encoding="utf-8")
    for path in shipped_configs.rglob("*.toml"):  # the README's table names every shipped file
        assert f"`{path.relative_to(shipped_configs).as_posix()}`" in listed, path


def test_the_shipped_experiments_train_the_one_cpu_recipe(shipped_configs: Path) -> None:
    """Every CPU variant trains the recipe's network and schedule as written once, in
    sim2real_cpu.toml; a variant states only how it departs from it."""
    from bimscan.learn.train_config import AdaptationSchedule

    experiments = shipped_configs / "experiments"
    recipe = load_experiment(experiments / "sim2real_cpu.toml")
    assert [v.name for v in recipe.variants] == ["sim2real-recipe", "sim2real-handheld"]
    assert len(recipe.holdout.ifc) == 4
    assert recipe.holdout.config == {"preset": "exp3", "head_deg_per_s": 75.0, "clutter": {"density": 0.3}}
    whole = _config(recipe.variants[0])
    assert (whole.blocks.train_columns, whole.train.epochs, whole.train.cpu_threads) == ("both", 3, 2)
    for variant in recipe.variants[1:]:
        assert training_sections(variant) == training_sections(recipe.variants[0]), variant.name
    # the handheld variant: the same recipe on the same buildings, walked with the handheld scanner
    from bimscan.dataset.spec import load_spec

    tripod, handheld = (load_spec(v.specs[0]) for v in recipe.variants)
    assert [s.generate for s in tripod.scenes] == [s.generate for s in handheld.scenes]
    assert [c.platform for c in handheld.configs] == ["handheld"]

    finetune = {v.name: v for v in load_experiment(experiments / "finetune_cpu.toml").variants}
    assert list(finetune) == ["synthetic-only", "real-only-12", "finetune-1", "finetune-3", "finetune-12"]
    assert [len(finetune[f"finetune-{n}"].rooms) for n in (1, 3)] == [1, 3] and finetune["finetune-12"].rooms == "all"
    assert training_sections(finetune["synthetic-only"]) == training_sections(recipe.variants[0])

    families = {v.name: v for v in load_experiment(experiments / "families_cpu.toml").variants}
    assert list(families) == ["pct", "trees", "pct-and-trees"]
    assert training_sections(families["pct"]) == training_sections(recipe.variants[0])
    trees = _config(families["trees"])
    assert trees.model.kind == "gbm" and families["trees"].specs == families["pct"].specs
    assert dataclasses.replace(trees.model, kind="pct") == whole.model and trees.input == whole.input
    assert families["pct-and-trees"].ensemble == ("pct", "trees")

    adapt = load_experiment(experiments / "sim2real_adapt_cpu.toml")
    variants = {v.name: v for v in adapt.variants}
    assert list(variants) == ["synthetic-only", "adapt-transductive", "adapt-inductive"]
    assert (variants["adapt-transductive"].adapt_to, variants["adapt-inductive"].adapt_to) == ("scored", "others")
    assert training_sections(variants["synthetic-only"]) == training_sections(recipe.variants[0])
    schedule = AdaptationSchedule()  # bimscan adapt's: the experiment measures what users run
    for name in ("adapt-transductive", "adapt-inductive"):
        config = _config(variants[name])
        assert variants[name].init == "synthetic-only" and variants[name].specs == variants["synthetic-only"].specs
        assert config.train.epochs == schedule.epochs
        assert config.train.max_lr == pytest.approx(whole.train.max_lr * schedule.lr_factor)
        assert dataclasses.replace(config.train, epochs=whole.train.epochs, max_lr=whole.train.max_lr) == whole.train


def test_the_shipped_gpu_experiment_starts_from_the_papers_baseline(shipped_configs: Path) -> None:
    parsed = load_experiment(shipped_configs / "experiments" / "sim2real_table2.toml")
    assert [v.name for v in parsed.variants][0] == "paper-baseline"
    baseline = _config(parsed.variants[0])
    assert baseline.input.features == ("xyz",) and baseline.input.grid_m == 0
    assert not baseline.augment.enabled and baseline.train.class_weights == "none"
    assert baseline.blocks.train_columns == "scene"


COMPANION = """\
[experiment]
name = "companion"
base = "../exp.toml"

[train]
epochs = 3

[[variants]]
name = "more"
data = "../spec.toml"
model = { dropout = 0.1 }
"""


def test_a_companion_experiment_takes_its_base_files_sections_key_by_key(experiment_dir: Path) -> None:
    (experiment_dir / "more").mkdir()
    (experiment_dir / "more" / "exp.toml").write_text(COMPANION, encoding="utf-8")
    base = _config(load_experiment(experiment_dir / "exp.toml").variants[1])
    companion = load_experiment(experiment_dir / "more" / "exp.toml")
    assert companion.name == "companion" and [v.name for v in companion.variants] == ["more"]
    config = _config(companion.variants[0])
    # the base's real scenes, relative to the base file, not to the companion
    assert companion.real.scenes == (str((experiment_dir / "real.txt").resolve()),)
    assert config.blocks == base.blocks and config.input == base.input
    assert config.train.epochs == 3 and config.train.max_lr == base.train.max_lr  # own key replaces, others kept
    assert config.model.dropout == 0.1 and config.model.embed_dim == base.model.embed_dim


@pytest.mark.parametrize(("base", "message"), [
    ('"../nothing.toml"', "base not found"),
    ('"exp.toml"', "names this file itself"),
    ("3", "expected the path"),
    ('"../chained.toml"', "has a base of its own"),
])
def test_a_bad_base_is_a_one_line_error(experiment_dir: Path, base: str, message: str) -> None:
    (experiment_dir / "chained.toml").write_text(EXPERIMENT.replace('name = "tiny"', 'name = "c"\nbase = "exp.toml"', 1))
    (experiment_dir / "more").mkdir()
    (experiment_dir / "more" / "exp.toml").write_text(COMPANION.replace('"../exp.toml"', base), encoding="utf-8")
    with pytest.raises((ConfigError, InputFileError), match=message):
        load_experiment(experiment_dir / "more" / "exp.toml")


def test_missing_real_scenes_of_a_base_name_the_base_file(experiment_dir: Path) -> None:
    (experiment_dir / "exp.toml").write_text(EXPERIMENT.replace('scenes = ["real.txt"]', 'scenes = ["gone.txt"]'))
    (experiment_dir / "more").mkdir()
    (experiment_dir / "more" / "exp.toml").write_text(COMPANION, encoding="utf-8")
    base_file = re.escape(str((experiment_dir / "exp.toml").resolve()))
    with pytest.raises(InputFileError, match=rf"fix \[real\] scenes in {base_file} or"):
        load_experiment(experiment_dir / "more" / "exp.toml")


def test_cpu_threads_are_set_for_training_and_checked() -> None:
    import torch

    from bimscan.learn.train import use_cpu_threads
    from bimscan.learn.train_config import TrainConfig

    before = torch.get_num_threads()
    try:
        use_cpu_threads(1)
        assert torch.get_num_threads() == 1
        use_cpu_threads(0)  # 0 leaves PyTorch's count as it is
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ConfigError, match="cpu_threads must be an integer in 0..1024"):
        TrainConfig(cpu_threads=-1)


ROOMS_EXPERIMENT = """\
[experiment]
name = "rooms"
folds = 2

[real]
scenes = ["r1.txt", "r2.txt", "r3.txt"]

[rooms]
scenes = ["r1.txt", "r2.txt", "r3.txt"]

[blocks]
size_m = 3.0
points = 128
min_points = 32
cache_points = 512

[input]
grid_m = 0.15

[model]
embed_dim = 8
attention_layers = 1
fuse_dim = 16
head_dims = [16]
dropout = 0.0

[train]
epochs = 1
batch_size = 4
max_lr = 0.01
amp = "off"
num_workers = 0
device = "cpu"

[eval]
stride_m = 1.5
votes = 1

[[variants]]
name = "synthetic"
data = "synthetic.txt"

[[variants]]
name = "real-only"
rooms = "all"

[[variants]]
name = "finetune-1"
init = "synthetic"
rooms = ["r2.txt"]
room_weight = 4.0

[[variants]]
name = "finetune-all"
init = "synthetic"
rooms = "all"
train = { epochs = 2, freeze = ["embedding"] }

[[variants]]
name = "mixed-1"
data = "synthetic.txt"
rooms = ["r1.txt"]
room_weight = 2.0
"""


@pytest.fixture
def rooms_dir(tmp_path: Path) -> Path:
    for k in (1, 2, 3):
        write_text_cloud(tmp_path / f"r{k}.txt", make_room(10 + k, size_m=(4.0, 3.0 + k), points_per_m2=40))
    write_text_cloud(tmp_path / "synthetic.txt", make_room(5, size_m=(6.0, 5.0), points_per_m2=40))
    (tmp_path / "exp.toml").write_text(ROOMS_EXPERIMENT, encoding="utf-8")
    return tmp_path


def test_variants_training_on_real_rooms_are_never_scored_on_them(rooms_dir: Path) -> None:
    import torch

    from bimscan.learn.checkpoint import read_checkpoint

    out = rooms_dir / "out"
    results = {r.variant: r for r in run_experiment(load_experiment(rooms_dir / "exp.toml"), out, log=lambda t: None)}
    rooms = {"r1", "r2", "r3"}
    assert results["synthetic"].train_rooms == [[]] and set(results["synthetic"].scenes) == rooms
    # every room once in one fold's scored scenes, the other fold trained on it
    real_only = results["real-only"]
    assert real_only.folds == 2 and sorted(map(sorted, real_only.train_rooms)) == [["r1", "r3"], ["r2"]]
    assert set(real_only.scenes) == rooms and real_only.excluded == sorted(rooms)
    for fold, trained in enumerate(real_only.train_rooms, start=1):
        scored = json.loads((out / f"variants/real-only/fold-{fold}/eval/evaluation.json").read_text())
        assert {s["name"] for s in scored["scenes"]} and not {s["name"] for s in scored["scenes"]} & set(trained)
    # one named room: trained once, scored on the two others
    assert results["finetune-1"].train_rooms == [["r2"]] and set(results["finetune-1"].scenes) == {"r1", "r3"}
    assert sum(map(sum, results["finetune-1"].confusion)) == results["finetune-1"].pooled["points"]
    # synthetic scans and a real room together, from scratch: scored on the rooms it did not see
    assert results["mixed-1"].train_rooms == [["r1"]] and set(results["mixed-1"].scenes) == {"r2", "r3"}

    # a fine-tuned run starts from its parent's EMA weights, tensor for tensor, and records which
    parent = read_checkpoint(out / "variants/synthetic/train/last.pt")
    for fold in (1, 2):
        child = read_checkpoint(out / f"variants/finetune-all/fold-{fold}/train/last.pt")
        assert child["init"]["checkpoint"] == str(out / "variants/synthetic/train/last.pt")
        frozen = [k for k in parent["ema"] if k.startswith(("embed1.", "embed2.")) and parent["ema"][k].is_floating_point()]
        assert frozen and all(torch.equal(child["model"][k], parent["ema"][k]) for k in frozen)  # kept as they were
        moved = [k for k in parent["ema"] if k.startswith("attention.") and parent["ema"][k].is_floating_point()]
        assert any(not torch.equal(child["model"][k], parent["ema"][k]) for k in moved)  # the rest trained on

    report = (out / "report.md").read_text()
    assert "| finetune-all |" in report and "2 folds" in report
    assert (out / "label_efficiency.png").stat().st_size > 0
    csv_rows = [row.split(",") for row in (out / "results.csv").read_text().splitlines()]
    assert csv_rows[0][:3] == ["variant", "scope", "oa"]
    assert [row[0] for row in csv_rows if row[1] == "all points"] == list(results)
    assert {row[1] for row in csv_rows if row[0] == "finetune-1"} >= {"r1", "r3"}


@pytest.mark.parametrize(("patch", "message"), [
    (('init = "synthetic"\nrooms = ["r2.txt"]', 'init = "later"\nrooms = ["r2.txt"]'), "not an earlier variant"),
    (('rooms = ["r2.txt"]', 'rooms = ["r9.txt"]'), "'r9.txt' is not of the \\[rooms\\] scenes"),
    (("room_weight = 4.0", "room_weight = 0.0"), "room_weight"),
    (('[rooms]\nscenes = ["r1.txt", "r2.txt", "r3.txt"]', ""), "'all' of no rooms"),
    (("folds = 2", "folds = 1"), "folds must be an integer in 2..64, got 1"),
    (('freeze = ["embedding"]', 'freeze = ["head"]'), "freeze"),
    (("stride_m = 1.5", "stride_m = 0.7"), r"#1 \(synthetic\): \[eval\] stride_m = 0.7 does not divide"),
    (("[rooms]", '[holdout]\nifc = ["house.ifc"]\nconfig = { clutter = { density = -1.0 } }\n\n[rooms]'),
     r"\[holdout\].*clutter density must be a number in \[0, 2\] .*, got -1"),
    (("[rooms]", '[holdout]\nifc = ["house.ifc"]\nclutter = 0.3\n\n[rooms]'),
     r"\[holdout\] clutter: the holdout's scan settings are a dataset configuration table now"),
    (('train = { epochs = 2, freeze = ["embedding"] }', 'train = { epochs = 2 }\nmodel = { embed_dim = 16 }'),
     r"#4 \(finetune-all\): init 'synthetic' trains another \[model\]"),
    (('rooms = ["r1.txt"]\nroom_weight = 2.0', 'rooms = ["r1.txt"]\nroom_weight = 2.0\ntrain = { freeze = ["attention"] }'),
     r"#5 \(mixed-1\) \[train\] freeze = \['attention'\]: without 'init' those parts of the network stay random"),
    (('rooms = ["r2.txt"]', 'rooms = ["r2.txt", "r2.txt"]'), r"'r2.txt' is listed twice"),
    (("max_lr = 0.01", "max_lr = 1e9"), r"\[train\]: max_lr must be a number in \(0, 1\], got 1e\+09"),
])
def test_bad_room_variants_are_one_line_errors(rooms_dir: Path, patch: tuple[str, str], message: str) -> None:
    text = ROOMS_EXPERIMENT.replace(*patch)
    assert text != ROOMS_EXPERIMENT
    (rooms_dir / "exp.toml").write_text(text, encoding="utf-8")
    (rooms_dir / "house.ifc").write_text("ISO-10303-21;\nEND-ISO-10303-21;\n", encoding="utf-8")  # a holdout model must exist
    with pytest.raises(ConfigError, match=message) as caught:
        load_experiment(rooms_dir / "exp.toml")
    assert "\n" not in str(caught.value)


def test_a_variant_training_on_every_scored_room_by_name_is_refused(rooms_dir: Path) -> None:
    text = ROOMS_EXPERIMENT.replace('rooms = ["r2.txt"]', 'rooms = ["r1.txt", "r2.txt", "r3.txt"]')
    (rooms_dir / "exp.toml").write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match="trains on every scored scene"):
        run_experiment(load_experiment(rooms_dir / "exp.toml"), rooms_dir / "out", log=lambda t: None)


def test_the_holdout_models_are_scanned_with_the_given_sensor_settings(rooms_dir: Path) -> None:
    from bimscan.sim2real import _holdout_spec

    (rooms_dir / "house.ifc").write_text("ISO-10303-21;\nEND-ISO-10303-21;\n", encoding="utf-8")
    holdout = ('[holdout]\nifc = ["house.ifc"]\nconfig = { realism = "paper", sensor = { glass = true }, '
               'clutter = { density = 0.2, kinds = ["office"] } }\n\n[rooms]')
    (rooms_dir / "exp.toml").write_text(ROOMS_EXPERIMENT.replace("[rooms]", holdout, 1), encoding="utf-8")
    (config,) = _holdout_spec(load_experiment(rooms_dir / "exp.toml")).configs
    assert (config.realism, config.sensor) == ("paper", {"glass": True})
    (rooms_dir / "exp.toml").write_text(ROOMS_EXPERIMENT.replace("[rooms]", holdout.replace("glass", "glas"), 1))
    with pytest.raises(ConfigError, match="glas") as caught:
        load_experiment(rooms_dir / "exp.toml")
    assert "\n" not in str(caught.value)


def test_an_experiment_into_a_users_folder_is_refused_before_any_work_and_kept(rooms_dir: Path) -> None:
    out = rooms_dir / "results"
    out.mkdir()
    (out / "report.md").write_text("# my own report\n")
    with pytest.raises(OutputError) as caught:
        run_experiment(load_experiment(rooms_dir / "exp.toml"), out, log=lambda t: None)
    assert str(caught.value).startswith(f"{out.resolve()} is a folder bimscan did not make (it holds report.md)")
    assert sorted(p.name for p in out.iterdir()) == ["report.md"]
    assert (out / "report.md").read_text() == "# my own report\n"


def test_a_variant_training_on_the_holdout_is_refused_before_any_work(rooms_dir: Path) -> None:
    (rooms_dir / "house.ifc").write_text("ISO-10303-21;\nEND-ISO-10303-21;\n", encoding="utf-8")
    (rooms_dir / "out" / "holdout").mkdir(parents=True)
    (rooms_dir / "houses.toml").write_text(
        'name = "houses"\n\n[[scenes]]\nname = "house"\nifc = "house.ifc"\n\n[[configs]]\nname = "exp1"\npreset = "exp1"\n',
        encoding="utf-8")
    scans = rooms_dir / "scans"  # another run's scans of the house: a built dataset folder
    scans.mkdir()
    (scans / "dataset.json").write_text(json.dumps({"spec": {"scenes": [
        {"name": "villa", "ifc": str(rooms_dir / "house.ifc")}, {"name": "gen", "ifc": None}]}}), encoding="utf-8")
    holdout = '[holdout]\nifc = ["house.ifc"]\n\n[rooms]'
    for data, message in (('"out/holdout"', "trains on the holdout scans"),
                          ('"houses.toml"', "trains on holdout model .*house.ifc .*scene 'house' of houses.toml"),
                          ('"scans"', "trains on holdout model .*house.ifc .*scene 'villa' of .*scans")):
        text = ROOMS_EXPERIMENT.replace("[rooms]", holdout, 1).replace('data = "synthetic.txt"', f"data = {data}", 1)
        (rooms_dir / "exp.toml").write_text(text, encoding="utf-8")
        with pytest.raises(ConfigError, match=message) as caught:
            run_experiment(load_experiment(rooms_dir / "exp.toml"), rooms_dir / "out", log=lambda t: None)
        assert "\n" not in str(caught.value)
        assert sorted(p.name for p in (rooms_dir / "out").iterdir()) == ["holdout"]  # nothing built, nothing trained


def test_a_holdout_model_that_is_not_an_ifc_file_is_refused_before_any_work(rooms_dir: Path) -> None:
    (rooms_dir / "notes.ifc").write_text("meeting notes, not a model\n", encoding="utf-8")
    text = ROOMS_EXPERIMENT.replace("[rooms]", '[holdout]\nifc = ["notes.ifc"]\n\n[rooms]')
    (rooms_dir / "exp.toml").write_text(text, encoding="utf-8")

    with pytest.raises(IfcError, match=r"\[holdout\].*notes.ifc: not an IFC file \(no ISO-10303-21 STEP header\)") as caught:
        load_experiment(rooms_dir / "exp.toml")

    assert "\n" not in str(caught.value)


def test_real_scenes_without_labels_are_refused_before_any_build(rooms_dir: Path) -> None:
    """A scored scene without labels is named with where it came from ([real] or --real), before a
    dataset is built or a model trained (it was refused at training time, as '[data] val')."""
    write_text_cloud(rooms_dir / "bare.xyz", PointCloud(xyz=make_room(60, points_per_m2=40).xyz))
    experiment = load_experiment(rooms_dir / "exp.toml", real=[rooms_dir / "bare.xyz"])
    out = rooms_dir / "out"

    with pytest.raises(LearnError, match=r"bare.xyz: holds no labels \(\[real\] scenes or --real"):
        run_experiment(experiment, out, log=lambda text: None)

    assert not (out / "variants").exists() and not (out / "datasets").exists()


ADAPT_VARIANTS = """
[[variants]]
name = "adapt-transductive"
init = "synthetic"
data = "synthetic.txt"
adapt_to = "scored"
train = { epochs = 1 }

[[variants]]
name = "adapt-inductive"
init = "synthetic"
data = "synthetic.txt"
adapt_to = "others"
train = { epochs = 1 }
"""


@pytest.mark.slow
def test_adapted_variants_adapt_to_the_scored_scenes_or_to_the_others_in_folds(rooms_dir: Path) -> None:
    head = ROOMS_EXPERIMENT[:ROOMS_EXPERIMENT.index('[[variants]]\nname = "real-only"')]
    (rooms_dir / "exp.toml").write_text(head + ADAPT_VARIANTS, encoding="utf-8")
    out = rooms_dir / "out"

    results = {r.variant: r for r in run_experiment(load_experiment(rooms_dir / "exp.toml"), out, log=lambda t: None)}

    rooms = {"r1", "r2", "r3"}
    transductive, inductive = results["adapt-transductive"], results["adapt-inductive"]
    assert [set(names) for names in transductive.adapted] == [rooms] and set(transductive.scenes) == rooms
    assert transductive.excluded == [] and transductive.train_rooms == [[]]
    assert inductive.folds == 2 and set(inductive.scenes) == rooms
    for fold, adapted in enumerate(inductive.adapted, start=1):  # never adapted to a scene it is scored on
        scored = json.loads((out / f"variants/adapt-inductive/fold-{fold}/eval/evaluation.json").read_text())
        assert adapted and not {s["name"] for s in scored["scenes"]} & set(adapted)
    config = json.loads((out / "variants/adapt-transductive/result.json").read_text())
    assert config["init"] == "synthetic"
    report = (out / "report.md").read_text()
    assert "adapted to 3 unlabelled scene(s) (their labels never read)" in report


@pytest.mark.parametrize(("variant", "message"), [
    ('name = "a"\ndata = "synthetic.txt"\nadapt_to = "scored"', "adapting starts from a trained model"),
    ('name = "a"\ninit = "synthetic"\nrooms = ["r1.txt"]\nadapt_to = "scored"', "not both"),
    ('name = "a"\ninit = "synthetic"\ndata = "synthetic.txt"\nadapt_to = "everything"', "adapt_to"),
    ('name = "a"\ninit = "synthetic"\ndata = "synthetic.txt"\nadapt_to = ["missing.laz"]', "scans not found"),
])
def test_bad_adapted_variants_are_one_line_errors(rooms_dir: Path, variant: str, message: str) -> None:
    head = ROOMS_EXPERIMENT[:ROOMS_EXPERIMENT.index('[[variants]]\nname = "real-only"')]
    (rooms_dir / "exp.toml").write_text(head + "[[variants]]\n" + variant + "\n", encoding="utf-8")

    with pytest.raises((ConfigError, InputFileError), match=message) as caught:
        load_experiment(rooms_dir / "exp.toml")

    assert "\n" not in str(caught.value)


def test_an_inductive_variant_with_one_scored_room_is_refused_before_any_work(rooms_dir: Path) -> None:
    """Its folds need two scored rooms: it is refused before the variants before it train (a
    user's --real with one room found out after the synthetic-only model's training)."""
    head = ROOMS_EXPERIMENT[:ROOMS_EXPERIMENT.index('[[variants]]\nname = "real-only"')]
    (rooms_dir / "exp.toml").write_text(head + ADAPT_VARIANTS, encoding="utf-8")
    out = rooms_dir / "out"

    with pytest.raises(ConfigError, match=r"'adapt-inductive' adapt_to = \"others\" needs two scored scenes or more"):
        run_experiment(load_experiment(rooms_dir / "exp.toml", real=[rooms_dir / "r1.txt"]), out, log=lambda t: None)

    assert not out.exists()


FAMILIES = EXPERIMENT[:EXPERIMENT.index("[[variants]]")] + """\
[[variants]]
name = "recipe"
data = "spec.toml"

[[variants]]
name = "trees"
data = "spec.toml"
model = { kind = "gbm", gbm_rounds = 20, gbm_leaves = 15, gbm_min_leaf_points = 20 }

[[variants]]
name = "both"
description = "the two families averaged"
ensemble = ["recipe", "trees"]
eval = { votes = 2 }
"""


def test_an_ensemble_variant_scores_the_mean_of_its_members_models_and_trains_nothing(experiment_dir: Path) -> None:
    from bimscan.learn.checkpoint import load_trained_model
    from bimscan.learn.evaluate import evaluate_checkpoint

    (experiment_dir / "exp.toml").write_text(FAMILIES, encoding="utf-8")
    out = experiment_dir / "out"
    experiment = load_experiment(experiment_dir / "exp.toml")
    results = {r.variant: r for r in run_experiment(experiment, out, log=lambda text: None)}
    assert type(load_trained_model(out / "variants/trees/train/last.pt").model).__name__ == "BoostedTrees"
    both = results["both"]
    assert both.ensemble == ["recipe", "trees"] and not (out / "variants/both/train").exists()
    assert both.train_seconds == pytest.approx(results["recipe"].train_seconds + results["trees"].train_seconds)
    assert both.evaluation["votes"] == 2 and results["recipe"].evaluation["votes"] == 1  # its own [eval]
    # its scores are those of the members' mean probabilities, members in the order named
    evaluation = training_sections(next(v for v in experiment.variants if v.name == "both"))["eval"]
    found = evaluate_checkpoint(out / "variants/recipe/train/last.pt", [experiment_dir / "real.txt"], device="cpu",
                                evaluation=evaluation, ensemble=[out / "variants/trees/train/last.pt"])
    assert found[0].labels.confusion.tolist() == both.confusion
    assert "The mean class probabilities of recipe, trees (trains nothing)" in (out / "report.md").read_text()


@pytest.mark.parametrize(("patch", "message"), [
    (('ensemble = ["recipe", "trees"]', 'ensemble = ["recipe", "forest"]'), "'forest' is not an earlier variant"),
    (('ensemble = ["recipe", "trees"]', 'ensemble = ["recipe"]'), "name two earlier variants or more"),
    (('ensemble = ["recipe", "trees"]', 'ensemble = ["recipe", "trees"]\ndata = "spec.toml"'), "remove data"),
    (('ensemble = ["recipe", "trees"]\neval', 'ensemble = ["recipe", "trees"]\nmodel = { dropout = 0.1 }\neval'),
     "only its [eval] may be set"),
    (('name = "trees"\ndata = "spec.toml"', 'name = "trees"\ndata = "spec.toml"\ninput = { grid_m = 0.2 }'),
     "'trees' has another [input] grid_m (0.2 against 0.15) than an earlier member"),
    (('name = "trees"\ndata = "spec.toml"', 'name = "trees"\ndata = "spec.toml"\nblocks = { points = 64 }'),
     "'trees' reads other [blocks] than 'recipe'"),
])
def test_bad_ensemble_variants_are_one_line_errors_before_any_work(
    experiment_dir: Path, patch: tuple[str, str], message: str,
) -> None:
    text = FAMILIES.replace(*patch)
    assert text != FAMILIES
    (experiment_dir / "exp.toml").write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_experiment(experiment_dir / "exp.toml")

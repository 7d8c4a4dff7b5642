"""Segmentation commands: train, evaluate, predict (PCT, the paper's Table 2/3, and gradient-boosted trees)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import click

from bimscan.constraints import choices_of, default_of
from bimscan.learn.train_config import AdaptationSchedule, EvalConfig, TrainConfig

DEVICES = click.Choice(choices_of(TrainConfig, "device"))
F = TypeVar("F", bound=Callable[..., object])


def inference_options(command: F) -> F:
    """The options evaluate and predict share: --device, --ensemble and how to label (--stride, --votes,
    --label-neighbours, --batch-size, --max-passes, --weights, --seed, --plane-votes: the checkpoint's
    [eval] unless given)."""
    options = [
        click.option("--device", type=DEVICES, default=default_of(TrainConfig, "device"), show_default=True),
        click.option("--ensemble", "ensemble", multiple=True, type=click.Path(path_type=Path, dir_okay=False),
                     help="Another checkpoint whose class probabilities are averaged with CHECKPOINT's (repeatable; "
                          "seeds of one recipe: the same classes, inputs and blocks). How to label is CHECKPOINT's."),
        click.option("--stride", "stride_m", type=float, default=None,
                     help="Columns every this many metres (a whole divisor of the block size). Default: the "
                          "checkpoint's [eval] stride_m."),
        click.option("--votes", type=click.IntRange(min=1, max=64), default=None,
                     help="Random samples of every column each point is voted on. Default: the checkpoint's [eval] votes."),
        click.option("--label-neighbours", type=click.IntRange(min=0, max=64), default=None,
                     help="Points off the voxel grid take the votes of this many nearest representatives (0: their "
                          "voxel's). Default: the checkpoint's [eval] label_neighbours."),
        click.option("--batch-size", type=click.IntRange(min=1), default=None,
                     help="Blocks per forward pass (speed and memory only). Default: the checkpoint's [eval] batch_size."),
        click.option("--max-passes", type=click.IntRange(min=0), default=None,
                     help="Passes per block at most (0: every point seen; else the rest from nearest neighbours). "
                          "Default: the checkpoint's [eval] max_passes (0)."),
        click.option("--weights", type=click.Choice(choices_of(EvalConfig, "weights")), default=None,
                     help="The averaged (EMA) weights or the live ones. Default: the checkpoint's [eval] weights (ema)."),
        click.option("--seed", type=click.IntRange(min=0), default=None,
                     help="Seed of the shuffles that cut blocks into groups. Default: the checkpoint's [eval] seed, "
                          "else its training seed (as sim2real scores)."),
        click.option("--plane-votes/--no-plane-votes", "plane_votes", default=None,
                     help="Each vertical planar region gives its Wall&Column and Others points the one of the two "
                          "most of them got. Default: the checkpoint's [eval] plane_votes (off)."),
    ]
    for option in reversed(options):  # decorators apply bottom-up: keep the listed order in --help
        command = option(command)
    return command


def evaluation_settings(checkpoint: Path, **given: object):  # -> EvalConfig
    """The checkpoint's [eval] with the options given on the command line in place of its values."""
    import dataclasses

    from bimscan.learn.checkpoint import stored_eval_config

    changes = {key: value for key, value in given.items() if value is not None}
    return dataclasses.replace(stored_eval_config(checkpoint), **changes)


@click.command("train")
@click.argument("config", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--resume", is_flag=True, help="Continue the run in the output folder from its last checkpoint.")
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False), default=None,
              help="Output folder (default: [train] out_dir of the config, relative to the config file): new, "
                   "empty, or one bimscan made; files of yours in it are left alone.")
@click.option("--init", "init", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="Start from this checkpoint's weights (fine-tuning: same network and classes); its own "
                   "schedule is the config's [train] (epochs, max_lr, freeze).")
def train(config: Path, resume: bool, out_dir: Path | None, init: Path | None) -> None:
    """Train PCT on synthetic scenes as CONFIG.toml says (Table 2 defaults), or gradient-boosted
    trees on per-point features of the same blocks with [model] kind = "gbm".

    Writes last.pt (every epoch; the trees: once, fitted), best.pt (a PCT's best validation mIoU),
    metrics.csv and curves.png.
    For DDP start it with torchrun, e.g.
    `torchrun --nproc_per_node 4 -m bimscan.cli.main train CONFIG.toml`.
    """
    from bimscan.learn.train_config import load_train_config
    from bimscan.learn.train import train_model

    settings, base = load_train_config(config)
    result = train_model(settings, base_dir=base, out_dir=out_dir, resume=resume, init=init,
                         log=lambda text: click.echo(text, err=True))
    if int(os.environ.get("RANK", "0")) == 0:
        what = "gradient-boosted trees" if settings.model.kind == "gbm" else f"{result.epochs_done} epoch(s)"
        click.echo(f"trained {what}; checkpoint {result.checkpoint}; "
                   f"metrics {result.out_dir / 'metrics.csv'}; curves {result.out_dir / 'curves.png'}")


@click.command("evaluate")
@click.argument("checkpoint", type=click.Path(path_type=Path, dir_okay=False))
@click.argument("scenes", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--out", "out_dir", type=click.Path(path_type=Path, file_okay=False), default=None,
              help="Folder for evaluation.md/.csv/.json and confusion.csv/.png: new, empty, or one bimscan made "
                   "(a training run's); files of yours in it are left alone.")
@click.option("--label-field", default=None,
              help="Field holding the ground truth: LAS/PLY dimension, NumPy folder file, text header column "
                   "(default: classification/label; S3DIS rooms: their annotation names).")
@click.option("--mapping", type=click.Path(path_type=Path, dir_okay=False), default=None,
              help="Mapping TOML from the scenes' classes to the checkpoint's (S3DIS rooms: built in).")
@inference_options
def evaluate(
    checkpoint: Path, scenes: tuple[Path, ...], out_dir: Path | None, label_field: str | None, mapping: Path | None,
    device: str, ensemble: tuple[Path, ...], stride_m: float | None, votes: int | None, label_neighbours: int | None,
    batch_size: int | None, max_passes: int | None, weights: str | None, seed: int | None, plane_votes: bool | None,
) -> None:
    """Score CHECKPOINT on labelled SCENE... (every point): OA, mIoU, mAcc, FWIoU, kappa per scene.

    SCENE: clouds (.las .laz .ply .txt ...), NumPy cloud folders, bimscan dataset folders or
    their unit folders (units/<scene>__<config>), S3DIS rooms or areas. Prints the table (as
    the paper's Table 3) and the IoU per class in Markdown; with --out also writes
    evaluation.md/.csv/.json (per-class IoU, accuracy, support and confusion matrix per scene)
    and the pooled confusion matrix as confusion.csv/.png, and for bimscan clouds elements.csv:
    where each IFC class's points went.
    """
    from bimscan.learn.evaluate import check_evaluation_output, evaluate_checkpoint, format_markdown, write_evaluation
    from bimscan.learn.mapping import load_label_mapping

    if out_dir is not None:
        check_evaluation_output(out_dir)  # before the checkpoint and scenes are read
    label_mapping = None if mapping is None else load_label_mapping(mapping)
    evaluation = evaluation_settings(checkpoint, stride_m=stride_m, votes=votes, label_neighbours=label_neighbours,
                                     batch_size=batch_size, max_passes=max_passes, weights=weights, seed=seed,
                                     plane_votes=plane_votes)
    results = evaluate_checkpoint(
        checkpoint, scenes, label_field=label_field, mapping=label_mapping, device=device, evaluation=evaluation,
        warn=lambda line: click.echo(f"warning: {line}", err=True), ensemble=ensemble,
    )
    click.echo(format_markdown(results), nl=False)  # the metrics table, then IoU per class
    if out_dir is not None:
        members = f" (+ {len(ensemble)} more, averaged)" if ensemble else ""
        title = f"{checkpoint.name}{members}: confusion over {len(results)} scene(s), all points"
        files = write_evaluation(results, out_dir, results[0].class_names, title=title)
        click.echo("wrote " + ", ".join(str(p) for p in files.paths()))


@click.command("predict")
@click.argument("checkpoint", type=click.Path(path_type=Path, dir_okay=False))
@click.argument("in_path", metavar="IN", type=click.Path(path_type=Path))
@click.argument("out_path", metavar="OUT", type=click.Path(path_type=Path))
@click.option("--overwrite", is_flag=True,
              help="Replace OUT if bimscan wrote it (a cloud file in OUT's format or a bimscan NumPy folder); anything "
                   "else there is refused, never removed. OUT may be IN itself when the labelled copy keeps all of "
                   "it (same format); it is replaced at the end.")
@inference_options
def predict(
    checkpoint: Path, in_path: Path, out_path: Path, overwrite: bool, device: str, ensemble: tuple[Path, ...],
    stride_m: float | None, votes: int | None, label_neighbours: int | None, batch_size: int | None, max_passes: int | None,
    weights: str | None, seed: int | None, plane_votes: bool | None,
) -> None:
    """Label every point of the scan IN with CHECKPOINT and write OUT (.laz/.las/.ply/.e57 or a folder;
    a text cloud's own suffix for a text IN).

    OUT in IN's format (LAS and LAZ alike) is a copy of IN with only the class changed: everything
    else IN holds is kept (a LAS's scales, offsets, CRS, VLRs, extra dimensions and point records;
    every property and element of a PLY; every column of a text cloud; every array of a NumPy
    folder; an E57's scans and point fields). The class goes to `classification` (LAS/LAZ),
    `bimscan:label` (E57), the label property or column IN has, else a new `label` (PLY, text),
    or `segment.npy` (NumPy), replacing whatever labels IN had (they are not read). In another
    format OUT keeps what that format holds, and a warning names what it does not.
    """
    from bimscan.learn.predict import check_prediction_output, predict_cloud

    check_prediction_output(in_path, out_path, overwrite=overwrite)  # before the checkpoint is read
    evaluation = evaluation_settings(checkpoint, stride_m=stride_m, votes=votes, label_neighbours=label_neighbours,
                                     batch_size=batch_size, max_passes=max_passes, weights=weights, seed=seed,
                                     plane_votes=plane_votes)
    result = predict_cloud(
        checkpoint, in_path, out_path, device=device, evaluation=evaluation, overwrite=overwrite,
        warn=lambda line: click.echo(f"warning: {line}", err=True), ensemble=ensemble,
    )
    shares = ", ".join(
        f"{name} {100.0 * count / max(result.points, 1):.1f}%"
        for name, count in zip(result.class_names, result.class_counts.tolist(), strict=True)
    )
    click.echo(f"wrote {result.path}: {result.points:,} points in {result.seconds:.1f} s "
               f"({result.points / max(result.seconds, 1e-9):,.0f} points/s; {result.network_points:,} through the "
               f"network) ({shares})")


@click.command("adapt")
@click.argument("checkpoint", type=click.Path(path_type=Path, dir_okay=False))
@click.argument("scans", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.argument("out_dir", metavar="OUT", type=click.Path(path_type=Path, file_okay=False))
@click.option("--synthetic", multiple=True, type=click.Path(path_type=Path),
              help="Labelled training data to keep training on (repeatable). Default: the data the checkpoint "
                   "trained on, where it was.")
@click.option("--epochs", type=click.IntRange(min=1), default=None,
              help=f"Passes over the synthetic data, each with adapted blocks beside. Default: "
                   f"{default_of(AdaptationSchedule, 'epochs')}.")
@click.option("--device", type=DEVICES, default=None, help="Replaces the checkpoint's [train] device.")
def adapt(checkpoint: Path, scans: tuple[Path, ...], out_dir: Path, synthetic: tuple[Path, ...], epochs: int | None,
          device: str | None) -> None:
    """Adapt CHECKPOINT to your own unlabelled scans SCAN... and write the adapted model to OUT.

    SCAN: clouds of the building (.las .laz .e57 .ply .txt ..., NumPy folders, S3DIS rooms); their
    labels, if any, are never read. The model labels them itself (pseudo-labels of its averaged
    weights, the most confident share of each class) and trains on them, mixed with its synthetic
    training data, for a short fine-tune. Then label the scans with
    'bimscan predict OUT/last.pt SCAN OUT.laz'. Run the same command again to continue a stopped run.
    """
    import dataclasses

    from bimscan.learn.adapt import adaptation_config
    from bimscan.learn.train import RunTerms, train_model

    schedule = AdaptationSchedule() if epochs is None else dataclasses.replace(AdaptationSchedule(), epochs=epochs)
    settings = adaptation_config(checkpoint, scans, synthetic=synthetic, schedule=schedule, device=device)
    last = out_dir / "last.pt"
    resume = last.is_file()
    terms = RunTerms(  # its refusals name its own arguments, not train's --init, --resume, out_dir
        run="adaptation", activity="adaptation", start="CHECKPOINT", new_run="give another OUT",
        again="give the same CHECKPOINT, SCAN... and options to continue it",
        other_start="give that checkpoint to continue it, or another OUT",
        named={("data", "adapt"): "SCAN...", ("data", "train"): "--synthetic", ("train", "epochs"): "--epochs",
               ("train", "device"): "--device"},
        settings_of=str(checkpoint),
        diverged=(f"adapting at a learning rate of {{max_lr}} ({schedule.lr_factor:g} x {checkpoint}'s max_lr) diverges "
                  f"on these scans; label them with {checkpoint} as it is, or adapt another checkpoint"),
        few_blocks="give more labelled data with --synthetic",
    )
    result = train_model(settings, base_dir=Path.cwd(), out_dir=out_dir, resume=resume, init=checkpoint,
                         log=lambda text: click.echo(text, err=True), terms=terms)
    click.echo(f"adapted {checkpoint} to {len(scans)} scan(s) in {result.epochs_done} epoch(s): {result.checkpoint}; "
               f"label a scan with 'bimscan predict {result.checkpoint} SCAN OUT.laz'")


@click.command("sim2real")
@click.argument("experiment", type=click.Path(path_type=Path, dir_okay=False))
@click.argument("out_dir", type=click.Path(path_type=Path, file_okay=False))
@click.option("--real", "real", multiple=True, type=click.Path(path_type=Path),
              help="Real labelled scenes to score on, replacing [real] scenes of the file (repeatable).")
@click.option("--device", type=DEVICES, default=None, help="Replaces [train] device of the file.")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Replaces [train] seed of every variant: a repeat with other weights and block order on the "
                   "same scans (give each repeat its own OUT_DIR).")
def sim2real(experiment: Path, out_dir: Path, real: tuple[Path, ...], device: str | None, seed: int | None) -> None:
    """Train variants (synthetic scans, real rooms, fine-tuned) and score each on real scans it never
    saw (see configs/experiments/sim2real_cpu.toml, configs/experiments/finetune_cpu.toml).

    Builds the variants' datasets and the holdout buildings' scans (resumable), trains one model per
    variant (or per fold, when it trains on the scored rooms; an ensemble variant averages earlier
    variants' models), evaluates each on the real scenes it did not train on and on the holdout
    buildings, and writes OUT_DIR/report.md, results.csv/.json,
    val_miou.png, label_efficiency.png and per variant its confusion matrices and curves. Run the
    same command again to continue a killed run.
    """
    from bimscan.sim2real import format_report, load_experiment, run_experiment

    parsed = load_experiment(experiment, real=list(real) or None, device=device, seed=seed)
    results = run_experiment(parsed, out_dir, log=lambda text: click.echo(text, err=True))
    click.echo(format_report(results, parsed), nl=False)


COMMANDS: list[click.Command] = [train, adapt, evaluate, predict, sim2real]

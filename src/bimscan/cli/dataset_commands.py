"""Dataset commands: ``build``, ``stats``, ``render``, ``figure`` and ``demo``."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from bimscan.cli.ifc_commands import SCHEME_HELP
from bimscan.dataset.executors import USER_EXECUTORS
from bimscan.demo import DEFAULT_HEAD_DEG_PER_S
from bimscan.render.cloud import COLOR_MODES, CUT_MODES, DEFAULT_MAX_POINTS

SIZE_HELP = "Picture size in pixels, WIDTHxHEIGHT."

if TYPE_CHECKING:
    from bimscan.dataset.build import BuildReport


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise click.BadParameter(f"{text!r} is not WIDTHxHEIGHT, e.g. 1600x800") from exc
    return width, height


def _report_build(report: BuildReport) -> None:
    """Print the build's warnings, failures and summary; raise DatasetError if a unit failed."""
    from bimscan.errors import DatasetError

    for note in report.notes:
        click.echo(f"warning: {note}", err=True)
    said: set[tuple[str, str]] = set()  # a scene dressed as several sites reports its IFC once
    for scene in report.scenes:
        for note in scene.notes:
            if (scene.scene, note) not in said:
                said.add((scene.scene, note))
                click.echo(f"warning: scene {scene.scene}: {note}", err=True)
    for entry in report.entries:
        if entry.status == "failed":
            click.echo(f"failed: {entry.id}: {entry.error}", err=True)
    click.echo(f"{report.out_dir}: {report.summary()}")
    if len(report.nodes) > 1:
        click.echo("units built per node: " + ", ".join(f"{node} {n}" for node, n in sorted(report.nodes.items())))
    if report.eta is not None and report.eta.elapsed_s + report.eta.actual_left_s >= 60:  # not worth a line sooner
        click.echo(report.eta.line())
    if not report.ok:
        pending = sum(e.status == "pending" for e in report.entries)
        raise DatasetError(f"{report.failed} of {len(report.entries)} units failed"
                           f"{f' and {pending} are pending' if pending else ''}; fix the causes above and run the "
                           "same command again to finish them")


@click.command("build")
@click.argument("spec", type=click.Path(path_type=Path))
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Units built at once (default: one per core); each casts on cores // workers threads.")
@click.option("--executor", type=click.Choice(USER_EXECUTORS), default="local", show_default=True,
              help="local: spawned processes on this machine; ray: Ray tasks.")
@click.option("--ray-address", default=None,
              help="Address of a running Ray cluster (with --executor ray; OUT_DIR must be on storage all nodes see). "
                   "Default: a local Ray instance.")
def build(spec: Path, out_dir: Path, workers: int | None, executor: str, ray_address: str | None) -> None:
    """Build the dataset described by SPEC (a TOML file) into OUT_DIR (new, empty, or one bimscan made).

    One data unit per (scene, configuration): units/<scene>__<config>/ with the cloud file(s),
    unit.json and timings.json; manifest.json lists every unit and its status. Everything in
    SPEC is checked before any work. Once the scenes' stations are planned, the output's size is
    estimated and the build refuses to start when OUT_DIR's disk cannot hold it. Interrupted or
    failed builds resume: run the same command again and only the missing units are built
    (finished ones are verified by checksum).
    """
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import device_warnings, load_spec

    if ray_address and executor != "ray":
        raise click.BadParameter("--ray-address needs --executor ray", param_hint="--ray-address")
    dataset_spec = load_spec(spec)
    for warning in device_warnings(dataset_spec):
        click.echo(f"warning: {warning}", err=True)
    report = build_dataset(dataset_spec, out_dir, workers=workers, executor=executor, ray_address=ray_address,
                           log=lambda line: click.echo(line, err=True))
    _report_build(report)


@click.command("stats")
@click.argument("dataset_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Folder for the tables, plots and report (default: DATASET_DIR/stats): new, empty, or one "
                   "bimscan made.")
@click.option("--from-clouds", is_flag=True,
              help="Recount every unit by streaming its cloud file instead of reading the counts in unit.json.")
@click.option("--verify", is_flag=True,
              help="Check every unit's files against the checksums recorded when it was built (reads them all).")
def stats(dataset_dir: Path, out_dir: Path | None, from_clouds: bool, verify: bool) -> None:
    """Statistics of a built dataset: points, extents and class proportions per configuration.

    Writes units.csv, configs.csv, scenes.csv, stats.json, points.png (paper Fig. 4),
    extents.png (Fig. 5), classes.png (Fig. 6) and report.md, which states whether extents and
    class proportions stay stable across configurations.
    """
    from bimscan.stats.report import write_stats

    result = write_stats(dataset_dir, out_dir, from_clouds=from_clouds, verify=verify)
    extent, extent_scene, axis = result.stats.max_extent_spread()
    share, share_scene, name = result.stats.max_class_spread()
    click.echo(f"{len(result.stats.units)} units summarised -> {result.out_dir / 'report.md'}")
    click.echo("  unit files verified against their checksums" if verify else
               "  unit files not verified against their checksums (pass --verify to check them)")
    if extent_scene:
        click.echo(f"  largest extent spread across configurations: {100 * extent:.2f} % ({extent_scene}, {axis.upper()})")
        click.echo(f"  largest class share spread: {share:.2f} percentage points ({share_scene}, {name})")


@click.command("render")
@click.argument("cloud", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--color", type=click.Choice(COLOR_MODES),
              default="label", show_default=True,
              help="What the colours show (rgb: the points' own colour; returns: single / first / last returns).")
@click.option("--max-points", type=click.IntRange(min=1), default=DEFAULT_MAX_POINTS, show_default=True,
              help="Uniform random sample drawn (the whole file is streamed).")
@click.option("--size", default="1600x800", show_default=True, help=SIZE_HELP)
@click.option("--cut", type=click.Choice(CUT_MODES), default="auto", show_default=True,
              help="auto: open the top storey (floor plan on top, rooms from above); none: the whole cloud.")
@click.option("--trajectory", default="auto", show_default=True,
              help="A mobile scan's walk drawn over the top view: 'auto' (CLOUD.trajectory.csv when it is there), "
                   "'none', or a trajectory CSV file.")
def render(cloud: Path, out: Path, color: str, max_points: int, size: str, cut: str, trajectory: str) -> None:
    """Draw CLOUD (LAS/LAZ/PLY/NumPy folder) as OUT.png: top and oblique views with a legend (and a
    mobile scan's walk over the top view)."""
    from bimscan.render.cloud import render_cloud
    from bimscan.survey.trajectory import read_trajectory, trajectory_path

    width, height = _size(size)
    walk, source = None, None
    if trajectory == "auto":
        beside = trajectory_path(cloud)
        walk, source = (read_trajectory(beside), beside) if beside.is_file() else (None, None)
    elif trajectory != "none":
        walk, source = read_trajectory(trajectory), trajectory
    result = render_cloud(cloud, out, color=color, max_points=max_points, width=width, height=height, cut=cut,
                          trajectory=walk)
    if walk is not None and not result.walk_drawn:
        shown = "the floors shown (--cut none shows every floor)" if result.section is not None else "the picture"
        click.echo(f"warning: the walk of {source} lies outside {shown}; it is not drawn and not in the legend",
                   err=True)
    click.echo(f"{result.path}: {result.total_points:,} points, {result.drawn_points:,} drawn, by {color}")


@click.command("figure")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("cloud", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--real", type=click.Path(path_type=Path), default=None,
              help="A real scan of the same building, drawn as a third panel.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--max-points", type=click.IntRange(min=1), default=DEFAULT_MAX_POINTS, show_default=True,
              help="Points drawn per cloud.")
@click.option("--size", default="1800x700", show_default=True, help=SIZE_HELP)
@click.option("--cut", type=click.Choice(CUT_MODES), default="auto", show_default=True,
              help="auto: cut every panel at the top storey's plan height; none: no cut.")
def figure(model: Path, cloud: Path, out: Path, real: Path | None, scheme: str | None, max_points: int, size: str,
           cut: str) -> None:
    """Side by side: the BIM MODEL (IFC) shaded by class, its synthetic CLOUD, optionally a --real scan."""
    from bimscan.errors import InputFileError
    from bimscan.pipeline import load_scene
    from bimscan.render.compose import check_png_output
    from bimscan.render.figure import render_figure
    from bimscan.semantics import load_scheme

    width, height = _size(size)
    check_png_output(out)
    label_scheme = load_scheme(scheme)
    for path in (cloud, real):
        if path is not None and not path.exists():  # before the (slow) parse
            raise InputFileError(f"{path}: no such file or folder; check the path")
    scene = load_scene(model, scheme=label_scheme)
    result = render_figure(scene.mesh, scene.components.label, label_scheme, cloud, out, real=real, width=width,
                           height=height, max_points=max_points, cut=cut, model_name=model.name)
    click.echo(f"{result.path}: " + " | ".join(result.panels))


@click.command("demo")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--workers", type=click.IntRange(min=1), default=None, help="Units built at once (default: one per core).")
@click.option("--executor", type=click.Choice(USER_EXECUTORS), default="local", show_default=True)
@click.option("--head-speed", "head_deg_per_s", type=float, default=DEFAULT_HEAD_DEG_PER_S, show_default=True,
              help="Head rotation in deg/s for every configuration (the presets turn at 10; faster: fewer points).")
def demo(out_dir: Path, workers: int | None, executor: str, head_deg_per_s: float) -> None:
    """The whole pipeline on generated buildings: dataset, statistics, pictures, in OUT_DIR.

    Two demo buildings x the paper's six configurations (at a faster head speed, so it runs in
    minutes), then `bimscan stats` and pictures of each scene. Run it again to resume.
    OUT_DIR/dataset.toml is the spec: change it and run `bimscan build` on it for your own.
    """
    from bimscan.demo import run_demo
    from bimscan.errors import DatasetError

    result = run_demo(out_dir, workers=workers, executor=executor, head_deg_per_s=head_deg_per_s,
                      log=lambda line: click.echo(line, err=line.startswith("note:")))
    failure: DatasetError | None = None
    try:
        _report_build(result.build)
    except DatasetError as exc:
        failure = exc  # statistics and pictures of the finished units were still made
    if result.stats_report is not None:
        click.echo(f"statistics: {result.stats_report}")
    for first, second in zip(result.pictures[::2], result.pictures[1::2]):
        click.echo(f"pictures: {first}, {second}")
    click.echo(f"spec: {result.spec} (edit it and run 'bimscan build {result.spec} {result.dataset}' to rebuild)")
    click.echo(f"manifest: {result.dataset / 'manifest.json'}")
    if failure is not None:
        raise failure


COMMANDS: list[click.Command] = [build, stats, render, figure, demo]

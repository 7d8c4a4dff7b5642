"""``bimscan plan``: the fewest tripod stations that cover a model's surfaces as asked, or the
figures of a given plan (``--check``)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from bimscan.cli.ifc_commands import LENGTH_UNIT_HELP, SCHEME_HELP
from bimscan.cli.site_options import site_options
from bimscan.constraints import choices_of, default_of
from bimscan.errors import ConfigError
from bimscan.ifc.units import LENGTH_UNITS
from bimscan.scan.device import DEFAULT_PRESET, DEFAULT_SCANNER, PRESETS, SCANNERS
from bimscan.survey.planning.config import DEFAULT_CLASSES, PlanConfig, setting_text
from bimscan.survey.coverage import COVERED_SHARE, DENSITY_PER_M2, RADIUS_M
from bimscan.survey.recipe import ScanRecipe

if TYPE_CHECKING:
    from bimscan.site.model import SiteModel

_DEFAULTS = PlanConfig()
# the options that set a PlanConfig key, by the key's name (--seed is the scan's, for the site's dressing)
_SETTINGS = {f.name for f in dataclasses.fields(PlanConfig)} - {"seed"}


def _fractions(text: str, flag: str, example: str) -> tuple[float, ...]:
    """Comma-separated fractions as typed ('none': no value)."""
    if text.strip().lower() == "none":
        return ()
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as exc:
        raise click.BadParameter(f"{text!r} is not a list of numbers; give {example}", param_hint=flag) from exc


def _in_flag_terms(message: str, given: dict[str, tuple[str, Any, str]]) -> str:
    """A settings message in the words of the command line: each setting that a flag set (key ->
    (flag, value, text typed)) named by its flag, its value as typed (``--coverage 0.9,1.5``, not
    ``coverage = [0.9, 1.5]``)."""
    for key, (flag, value, typed) in given.items():
        shown = setting_text(value)
        named = rf"(?<![\w-]){key}\b"  # the key, not a flag made of it already
        message = re.sub(rf"{named} = {re.escape(shown)}", f"{flag} {typed}", message)
        if isinstance(value, tuple):
            message = message.replace(shown, typed)
        message = re.sub(named, flag, message)
    return message


def _plan_config(config_file: str | None, flags: dict[str, tuple[str, Any, str]], *, checking: bool) -> PlanConfig:
    """The planner's settings: the TOML file's keys, the flags over them (key -> (flag, value, text
    typed)); refusals name the file's keys, and the flags as typed."""
    from bimscan.toml_files import build_dataclass, load_toml

    table = dict(load_toml(config_file)) if config_file is not None else {}
    table |= {key: value for key, (_, value, _) in flags.items()}
    try:
        if config_file is None:
            config = PlanConfig(**table)
        else:
            config = build_dataclass(PlanConfig, table, where=f"{config_file} with the flags")
        if checking:
            config.check_for_checking()
    except ConfigError as exc:
        raise ConfigError(_in_flag_terms(str(exc), flags)) from exc
    return config


@click.command("plan")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--classes", default=None,
              help=f"Comma-separated classes of the label scheme to cover. Default: {','.join(DEFAULT_CLASSES)}.")
@click.option("--coverage", default=None,
              help=f"Fraction of each class's visible surface to cover: one value, or one per class. "
                   f"Default: {_DEFAULTS.coverage[0]:g}.")
@click.option("--density", "density_pts_m2", type=float, default=None,
              help=f"Points per square metre a surface needs to count as covered (the stations summed). "
                   f"Default: {_DEFAULTS.density_pts_m2:g}.")
@click.option("--max-incidence-deg", type=float, default=None,
              help=f"A station's points count only where its beam meets the surface at most this far from the "
                   f"normal. Default: {_DEFAULTS.max_incidence_deg:g}.")
@click.option("--overlap", type=float, default=None,
              help=f"Two stations register when the surface both see is at least this fraction of what the smaller "
                   f"sees (and pins every direction). Default: {_DEFAULTS.overlap:g}.")
@click.option("--grid", "grid_m", type=float, default=None,
              help=f"Spacing of the candidate spots, metres. Default: {_DEFAULTS.grid_m:g}.")
@click.option("--solver", type=click.Choice(choices_of(PlanConfig, "solver")), default=None,
              help="greedy (greedy cover, then local and iterated greedy search), milp (then scipy's HiGHS within "
                   "--time-limit) or auto (the MILP on small models, its answer when proved optimal). "
                   f"Default: {default_of(PlanConfig, 'solver')}.")
@click.option("--time-limit", "milp_time_limit_s", type=float, default=None,
              help=f"Seconds the MILP may take (--solver milp or auto; refused with greedy, which runs no MILP). "
                   f"Default: {_DEFAULTS.milp_time_limit_s:g}.")
@click.option("--ladder", "coverage_ladder", default=None,
              help="Coverages at which the plan also reports the stations needed, every class asked the same "
                   "share (what the last few percent cost; each costs about as long as the plan's own search; "
                   "the asked --coverage joins them when it is one value), or 'none'. "
                   f"Default: {','.join(f'{c:g}' for c in _DEFAULTS.coverage_ladder)}.")
@click.option("--config", "config_file", default=None,
              help="A TOML file of planner settings (the keys of PlanConfig); the flags above override it.")
@click.option("--check", default=None,
              help="Report the figures of a given plan instead: a station file, or 'auto' for the per-room plan "
                   "of 'bimscan scan --stations auto'.")
@click.option("--cloud", default=None, type=click.Path(path_type=Path),
              help="With --check: a cloud 'bimscan scan' made from those stations; coverage is measured on it too.")
@click.option("--preset", default=None,
              help=f"Scan settings of every station: {', '.join(PRESETS)} or a settings TOML file. "
                   f"Default: {DEFAULT_PRESET}.")
@click.option("--scanner", default=None,
              help=f"Scanner: a name ({', '.join(SCANNERS)}) or a scanner TOML file. Default: {DEFAULT_SCANNER}.")
@click.option("--head-speed", "head_deg_per_s", type=float, default=None,
              help="Head rotation in deg/s, overriding the preset (fewer points per station when faster).")
@click.option("--seed", default=ScanRecipe.seed, show_default=True, type=int,
              help="The scan's seed: the site is dressed with it (give 'bimscan scan' the same).")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None, help=LENGTH_UNIT_HELP)
@click.option("--threads", default=ScanRecipe.threads, show_default=True, type=int, help="Cores to use (0 = all).")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it is a plan folder bimscan wrote.")
@site_options
def plan(model: Path, out: Path, classes: str | None, coverage: str | None, density_pts_m2: float | None,
         max_incidence_deg: float | None, overlap: float | None, grid_m: float | None, solver: str | None,
         milp_time_limit_s: float | None, coverage_ladder: str | None, config_file: str | None, check: str | None,
         cloud: Path | None, preset: str | None, scanner: str | None, head_deg_per_s: float | None, seed: int,
         scheme: str | None, length_unit: str | None, threads: int, overwrite: bool, site: SiteModel) -> None:
    """Plan a tripod survey of MODEL.ifc into the folder OUT: the fewest stations such that the
    chosen classes reach the asked coverage at the asked point density, with a connected
    registration graph.

    OUT gets stations.csv (in scan order; 'bimscan scan --stations OUT/stations.csv' takes it as it
    is), coverage.csv (per element: GlobalId, class, storey, covered fraction, median density, what
    no spot sees), registration.csv (which stations register to which), plan.json and a picture
    per storey; it also says how many stations each coverage of --ladder needs (what the last few
    percent cost). With --check STATIONS.csv (or 'auto') the same figures for a given plan; with
    --cloud as well, measured on its scan. Give the site flags (--clutter, --stage, ...) and
    --seed that the scan will get: the stations are checked on that site as the scan checks them.
    What loading the model repaired or lost is said as 'bimscan scan' says it.
    """
    context = click.get_current_context()
    flags: dict[str, tuple[str, Any, str]] = {}
    for param in context.command.params:
        value = context.params.get(param.name or "")
        if param.name in _SETTINGS and value is not None:
            typed = value if isinstance(value, str) else f"{value:g}" if isinstance(value, float) else str(value)
            if param.name == "classes":
                value = tuple(c.strip() for c in value.split(",") if c.strip())
            elif param.name == "coverage":
                value = _fractions(value, "--coverage", "a fraction (0.95) or one per class (0.95,0.9,0.9,0.8)")
            elif param.name == "coverage_ladder":
                value = _fractions(value, "--ladder", "fractions (0.8,0.9,0.95) or none")
            flags[param.name] = (param.opts[0], value, typed)
    config = _plan_config(config_file, flags, checking=check is not None)
    recipe = ScanRecipe.resolve(preset=preset, scanner=scanner, head_deg_per_s=head_deg_per_s, seed=seed,
                                site=site, threads=threads)
    if cloud is not None and check is None:
        raise click.UsageError("--cloud needs --check STATIONS.csv: the stations the cloud was scanned from")
    from bimscan.pipeline import plan_model

    run = plan_model(model, out, recipe, config, check=check, cloud=cloud, scheme=scheme, overwrite=overwrite,
                     length_unit=length_unit, warn=lambda line: click.echo(f"warning: {line}", err=True))
    evaluation, plan_ = run.evaluation, run.plan
    what = "checked" if check is not None else "planned"
    solver_line = ""
    if plan_.solver is not None:
        s = plan_.solver
        solver_line = f" (greedy {s.greedy}, after search {s.improved}"
        if s.milp_status != "not run":
            bound = f", lower bound {s.milp_bound:.0f}" if s.milp_bound is not None else ""
            solver_line += f", MILP {s.milp_status}{'' if s.milp is None else f' {s.milp}'}{bound}"
        solver_line += ")"
    click.echo(f"{out}: {len(plan_.stations)} stations {what}{solver_line}, {plan_.space.n_spots} candidate spots")
    header = "  class            asked   visible m2   covered" + ("   on the scan" if run.scan is not None else "")
    click.echo(header)
    for name, figures in evaluation.classes.items():
        if figures["visible_m2"] <= 0:
            click.echo(f"  {name:<15}  {100 * figures['asked']:4.0f} %   nothing in view")
            continue
        line = (f"  {name:<15}  {100 * figures['asked']:4.0f} %   {figures['visible_m2']:10.1f}   "
                f"{100 * figures['covered_fraction']:6.1f} %")
        if run.scan is not None:
            line += f"   {100 * run.scan.classes[name]['covered_fraction']:6.1f} %"
        click.echo(line)
    stations_by_storey: dict[str, int] = {}
    for station in plan_.stations:
        stations_by_storey[station.storey or "-"] = stations_by_storey.get(station.storey or "-", 0) + 1
    click.echo("  stations per storey: " + ", ".join(f"{k} {v}" for k, v in stations_by_storey.items()))
    if plan_.ladder:
        click.echo("  stations by coverage: " + ", ".join(
            f"{100 * rung.coverage:g} % " + ("out of reach" if rung.stations is None else str(rung.stations))
            for rung in plan_.ladder))
    click.echo(f"  registration graph: {len(evaluation.edges)} edges, "
               + ("connected" if evaluation.parts <= 1 else f"{evaluation.parts} parts (the candidate spots allow "
                                                            f"no fewer than {evaluation.spot_parts})"))
    if run.density_ratio is not None:
        q1, median, q3 = run.density_ratio
        click.echo(f"  scan density / estimate: median {median:.2f} (quartiles {q1:.2f}-{q3:.2f})")
    click.echo("  files: " + ", ".join(run.files))
    click.echo("  seconds: " + ", ".join(f"{step} {seconds:.1f}" for step, seconds in run.steps.items()))


@click.command("coverage")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("cloud", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--density", "density_pts_m2", type=float, default=DENSITY_PER_M2, show_default=True,
              help="Points per square metre that count a spot of an element's outer surface as covered.")
@click.option("--radius", "radius_m", type=float, default=RADIUS_M, show_default=True,
              help="Metres around each spot the density is counted over.")
@click.option("--share", type=float, default=COVERED_SHARE, show_default=True,
              help="The share of an element's outer surface that must be covered.")
@click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None, help=LENGTH_UNIT_HELP)
@click.option("--overwrite", is_flag=True, help="Replace OUT if it is a file of its kind (a CSV); anything else "
              "there is refused, never removed.")
def coverage(model: Path, cloud: Path, out: Path, density_pts_m2: float, radius_m: float, share: float,
             length_unit: str | None, overwrite: bool) -> None:
    """Say how much of each element's outer surface CLOUD covers and write OUT.csv: every element of
    MODEL.ifc seen from outside (roofs, facades, what stands out of the ground), its outer area, the
    share covered at --density within --radius, the share below the ground, and 'covered' or why not
    (below the ground, facing down, not reached). For a drone's flight, or any scan in the model's
    coordinates (align a site scan first: 'bimscan align'). The cloud is read in chunks."""
    from bimscan.files import check_input_file, write_atomic
    from bimscan.io import check_output_path, iter_cloud_chunks
    from bimscan.pipeline import load_scene
    from bimscan.survey.coverage import coverage_csv, element_coverage

    for name, value, low, high in (("--density", density_pts_m2, 0.0, 1e6), ("--radius", radius_m, 0.0, 10.0),
                                   ("--share", share, 0.0, 1.0)):
        if not low < value <= high:
            raise click.UsageError(f"{name} must be in ({low:g}, {high:g}], got {value:g}")
    check_input_file(cloud, what="a point cloud (LAS/LAZ, E57, PLY, text or a NumPy folder)", folders=True)
    check_output_path(out, overwrite=overwrite)  # both before the (slow) model
    scene = load_scene(model, length_unit=length_unit)
    chunks = (chunk.xyz for chunk in iter_cloud_chunks(cloud, labels=False))
    elements = element_coverage(scene, chunks, density_per_m2=density_pts_m2, radius_m=radius_m)
    write_atomic(out, coverage_csv(elements, share=share))
    short = [e for e in elements if e.covered_share < share]
    reachable = [e for e in elements if e.buried <= 0.5]
    click.echo(f"{out}: {len(elements)} elements with an outer surface; {sum(e.covered_share >= share for e in reachable)} "
               f"of the {len(reachable)} above the ground covered on >= {share:.0%} at {density_pts_m2:g} points/m2")
    for e in short:
        click.echo(f"  {e.ifc_class} {e.name or '(no name)'} ({e.global_id}): {e.covered_share:.0%} of "
                   f"{e.outer_m2:.1f} m2, {e.why_not()}")


COMMANDS: list[click.Command] = [plan, coverage]

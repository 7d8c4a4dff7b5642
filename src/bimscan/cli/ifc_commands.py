"""IFC commands: ``info`` (parse and summarise) and ``export-obj`` (OBJ + component index, HELIOS++ scene and survey)."""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

import click

from bimscan.cli.site_options import site_options, yard_option
from bimscan.scan.device import DEFAULT_PRESET, DEFAULT_SCANNER, PRESETS
from bimscan.ifc.units import LENGTH_UNITS

SCHEME_HELP = "Label scheme: a built-in name (spc5) or a TOML file. Default: spc5, the paper's five classes."
STRICT_IFC_HELP = ("Refuse an IFC file that needed a repair, has a problem (syntax error, dangling reference, unknown "
                   "entity, no length unit, ...) or loses an element, instead of loading what a viewer shows.")
LENGTH_UNIT_HELP = "Read the model's lengths in this unit, whatever the file says (or when it says nothing)."


def ifc_options(command: click.Command) -> click.Command:
    """The IFC loading options every command that reads a model shares: --strict, --length-unit."""
    command = click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None,
                           help=LENGTH_UNIT_HELP)(command)
    return click.option("--strict", is_flag=True, help=STRICT_IFC_HELP)(command)


def echo_load_report(scene: object) -> None:
    """Print what loading the model repaired, assumed, found wrong or lost, as ``warning:`` lines."""
    from bimscan.ifc.summary import report_lines

    for line in report_lines(scene):  # type: ignore[arg-type]
        click.echo(f"warning: {line}", err=True)


@click.command("info")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of a report.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--no-cache", is_flag=True, help="Parse again even if this file's geometry is cached.")
@ifc_options
def info(model: Path, as_json: bool, scheme: str | None, no_cache: bool, strict: bool, length_unit: str | None) -> None:
    """Parse MODEL.ifc and summarise its components, labels, failures, repairs, problems and bounds."""
    from bimscan.ifc.watchdog import prestart_worker

    prestart_worker()
    from bimscan.pipeline import load_scene
    from bimscan.ifc.summary import format_summary, summarize_scene

    scene = load_scene(model, scheme=scheme, use_cache=not no_cache, strict=strict, length_unit=length_unit)
    echo_load_report(scene)
    summary = summarize_scene(scene)
    click.echo(json.dumps(summary, indent=2) if as_json else format_summary(summary))


HELIOS_HELP = ("Also write HELIOS++ inputs: helios/scene.xml (one <part> per component file) and helios/survey.xml "
               "(the stations and scan settings of 'bimscan scan' with the same options, one leg per station). Run "
               "them from inside OUT_DIR: cd OUT_DIR && helios++ helios/survey.xml --assets . (HELIOS++ finds the "
               "scene's files only through --assets, and a mobile survey's trajectory file only from the current "
               "folder).")


@click.command("export-obj")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out_dir", type=click.Path(path_type=Path))
@click.option("--helios", is_flag=True, help=HELIOS_HELP)
@click.option("--stations", default=None,
              help="With --helios: 'auto' (planned as 'bimscan scan' plans them; the default) or a station CSV file.")
@click.option("--preset", default=None, help=f"With --helios: scan settings {', '.join(PRESETS)} or a settings TOML "
                                             f"file (default: {DEFAULT_PRESET}, as 'bimscan scan').")
@click.option("--scanner", default=None, help=f"With --helios: {DEFAULT_SCANNER} (default) or a scanner TOML file that "
                                              "keeps that name (HELIOS++ has its own definition of the device); with "
                                              "--platform, the platform's lidar: velodyne_vlp16 or a Risley lidar "
                                              "(written beside the survey as HELIOS++'s risley optics).")
@click.option("--head-speed", "head_deg_per_s", type=float, default=None,
              help="With --helios: head rotation in deg/s, overriding the preset.")
@click.option("--platform", default=None,
              help="With --helios: a mobile platform (handheld, backpack, drone or a platform file): the survey "
                   "follows its trajectory on HELIOS++'s interpolated platform, one survey per lidar (a Risley lidar's "
                   "definition written beside it).")
@click.option("--trajectory", default=None,
              help="With --helios and --platform: 'auto' (planned as 'bimscan scan' plans it; the default) or a "
                   "trajectory CSV file.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--overwrite", is_flag=True,
              help="Replace the export's files and folders already in OUT_DIR if bimscan wrote them; anything else "
                   "there is refused, never removed.")
@click.option("--seed", default=0, show_default=True, type=int, help="Placement seed of the site flags' clutter.")
@site_options
@yard_option
@ifc_options
def export_obj_command(model: Path, out_dir: Path, helios: bool, stations: str | None, preset: str | None,
                       scanner: str | None, head_deg_per_s: float | None, platform: str | None, trajectory: str | None,
                       scheme: str | None, overwrite: bool, seed: int, site: Any, strict: bool,
                       length_unit: str | None) -> None:
    """Export MODEL.ifc as OBJ: model.obj (one group per component), components/c<id>.obj
    (one file per component, as HELIOS++ wants), classes.mtl and index.csv (component id,
    GlobalId, IFC class, label); with --helios also a HELIOS++ scene and survey. With the site
    flags, the scene as 'bimscan scan' with the same flags and seed scans it (clutter as
    components, elements not yet built left out)."""
    from bimscan.ifc.watchdog import prestart_worker

    prestart_worker()  # IfcOpenShell loads in the geometry worker while this process goes on
    from bimscan.io import export_obj
    from bimscan.pipeline import build_site, load_scene, site_and_stations
    from bimscan.survey.recipe import ScanRecipe

    survey_options = {"--stations": stations, "--preset": preset, "--scanner": scanner, "--head-speed": head_deg_per_s,
                      "--platform": platform, "--trajectory": trajectory}
    given = [name for name, value in survey_options.items() if value is not None]
    if given and not helios:
        raise click.UsageError(f"{', '.join(given)} describe the HELIOS++ survey; add --helios")
    mobile = platform is not None and platform != "tripod"
    # settings errors before the (slow) parse
    recipe = ScanRecipe.resolve(preset=preset, scanner=None if mobile else scanner, head_deg_per_s=head_deg_per_s,
                                stations_from=stations or "auto", seed=seed, site=site, platform=platform,
                                lidar=scanner if mobile else None, trajectory=trajectory)
    if helios:
        from bimscan.io.helios import HELIOS_LIDARS, helios_scanner
        from bimscan.scan.risley import RisleyScanner

        if recipe.mobile is None:
            helios_scanner(recipe.scanner)  # a scanner HELIOS++ has a definition of
        elif recipe.mobile.lidar.name not in HELIOS_LIDARS and not isinstance(recipe.mobile.lidar, RisleyScanner):
            raise click.UsageError(f"HELIOS++ has a definition of {', '.join(HELIOS_LIDARS)} only, not of "
                                   f"{recipe.mobile.lidar.name}; pass --scanner velodyne_vlp16 or a Risley lidar")
        for warning in recipe.warnings:
            click.echo(f"warning: {warning}", err=True)
    scene = load_scene(model, scheme=scheme, strict=strict, length_unit=length_unit)
    echo_load_report(scene)
    survey_xml = None
    mobile_files = None
    n_legs = 0
    if helios:
        from bimscan.io.helios import helios_mobile_files, helios_scene_id, helios_survey_xml

        chosen = site_and_stations(scene, recipe)
        scene = chosen.scene
        if chosen.plan is not None and chosen.plan.rooms_without_station:
            click.echo(f"warning: {chosen.plan.rooms_without_station_line()}", err=True)
        if chosen.trajectory is not None:
            mobile_files = helios_mobile_files(chosen.trajectory, recipe.mobile, scene_id=helios_scene_id(scene.source),
                                               name=Path(scene.source).stem)
            n_legs = chosen.trajectory.n_passes
        else:
            survey_xml = helios_survey_xml(chosen.stations, recipe.settings, recipe.scanner,
                                           scene_id=helios_scene_id(scene.source), name=Path(scene.source).stem)
            n_legs = len(chosen.stations)
    else:
        scene = build_site(scene, recipe)
    result = export_obj(scene, out_dir, helios=helios, helios_survey=survey_xml, helios_files=mobile_files,
                        overwrite=overwrite)
    click.echo(f"{result.out_dir}: {len(result.component_files)} component files, {result.n_triangles:,} triangles; "
               f"index {result.index_csv.name}" + (f"; HELIOS++ scene {result.helios_scene}" if result.helios_scene else ""))
    if result.helios_survey is not None:
        more = [name for name in (mobile_files or {}) if Path(name).name.startswith("survey_mount")]
        click.echo(f"HELIOS++ survey {result.helios_survey} ({n_legs} legs)"
                   + (f" and {', '.join(more)} (one survey per lidar)" if more else "") + "; run it with:\n"
                   f"  cd {shlex.quote(str(result.out_dir))} && helios++ "
                   f"{shlex.quote(str(result.helios_survey.relative_to(result.out_dir)))} --assets .")


COMMANDS: list[click.Command] = [info, export_obj_command]

"""IFC commands: ``info`` (parse and summarise) and ``export-obj`` (OBJ + component index, HELIOS++ scene)."""

from __future__ import annotations

import json
from pathlib import Path

import click

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


@click.command("export-obj")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out_dir", type=click.Path(path_type=Path))
@click.option("--helios", is_flag=True, help="Also write a HELIOS++ scene XML (one <part> per component file).")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--overwrite", is_flag=True, help="Replace files already in OUT_DIR.")
@ifc_options
def export_obj_command(model: Path, out_dir: Path, helios: bool, scheme: str | None, overwrite: bool, strict: bool,
                       length_unit: str | None) -> None:
    """Export MODEL.ifc as OBJ: model.obj (one group per component), components/c<id>.obj
    (one file per component, as HELIOS++ wants), classes.mtl and index.csv (component id,
    GlobalId, IFC class, label)."""
    from bimscan.ifc.watchdog import prestart_worker

    prestart_worker()
    from bimscan.pipeline import load_scene
    from bimscan.io import export_obj

    scene = load_scene(model, scheme=scheme, strict=strict, length_unit=length_unit)
    echo_load_report(scene)
    result = export_obj(scene, out_dir, helios=helios, overwrite=overwrite)
    click.echo(f"{result.out_dir}: {len(result.component_files)} component files, {result.n_triangles:,} triangles; "
               f"index {result.index_csv.name}" + (f"; HELIOS++ scene {result.helios_scene}" if result.helios_scene else ""))


COMMANDS: list[click.Command] = [info, export_obj_command]

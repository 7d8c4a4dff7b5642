"""IFC commands: ``info`` (parse and summarise) and ``export-obj`` (OBJ + component index, HELIOS++ scene)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from bimscan.cli.site_options import site_options

SCHEME_HELP = "Label scheme: a built-in name (spc5) or a TOML file. Default: spc5, the paper's five classes."


@click.command("info")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of a report.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--no-cache", is_flag=True, help="Parse again even if this file's geometry is cached.")
def info(model: Path, as_json: bool, scheme: str | None, no_cache: bool) -> None:
    """Parse MODEL.ifc and summarise its components, labels, failures and bounds."""
    from bimscan.pipeline import load_scene
    from bimscan.ifc.summary import format_summary, summarize_scene

    scene = load_scene(model, scheme=scheme, use_cache=not no_cache)
    summary = summarize_scene(scene)
    click.echo(json.dumps(summary, indent=2) if as_json else format_summary(summary))


@click.command("export-obj")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out_dir", type=click.Path(path_type=Path))
@click.option("--helios", is_flag=True, help="Also write a HELIOS++ scene XML (one <part> per component file).")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--overwrite", is_flag=True, help="Replace files already in OUT_DIR.")
@click.option("--seed", default=0, show_default=True, type=int, help="Placement seed of the site flags' clutter.")
@site_options
def export_obj_command(model: Path, out_dir: Path, helios: bool, scheme: str | None, overwrite: bool, seed: int,
                       site: Any) -> None:
    """Export MODEL.ifc as OBJ: model.obj (one group per component), components/c<id>.obj
    (one file per component, as HELIOS++ wants), classes.mtl and index.csv (component id,
    GlobalId, IFC class, label). With the site flags, the scene as 'bimscan scan' with the same
    flags and seed scans it (clutter as components, elements not yet built left out)."""
    from bimscan.pipeline import build_site, load_scene
    from bimscan.io import export_obj
    from bimscan.scan.recipe import ScanRecipe

    scene = build_site(load_scene(model, scheme=scheme), ScanRecipe(seed=seed, site=site))
    result = export_obj(scene, out_dir, helios=helios, overwrite=overwrite)
    click.echo(f"{result.out_dir}: {len(result.component_files)} component files, {result.n_triangles:,} triangles; "
               f"index {result.index_csv.name}" + (f"; HELIOS++ scene {result.helios_scene}" if result.helios_scene else ""))


COMMANDS: list[click.Command] = [info, export_obj_command]

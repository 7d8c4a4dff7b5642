"""IFC commands: ``info`` (parse and summarise a model)."""

from __future__ import annotations

import json
from pathlib import Path

import click

SCHEME_HELP = "Label scheme: a built-in name (spc5) or a TOML file. Default: spc5, the paper's five classes."


@click.command("info")
@click.argument("model", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print a JSON object instead of a report.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--no-cache", is_flag=True, help="Parse again even if this file's geometry is cached.")
def info(model: Path, as_json: bool, scheme: str | None, no_cache: bool) -> None:
    """Parse MODEL.ifc and summarise its components, labels, failures and bounds."""
    from bimscan.ifc.load import load_ifc
    from bimscan.ifc.summary import format_summary, summarize_scene
    from bimscan.semantics import load_scheme

    scene = load_ifc(model, scheme=load_scheme(scheme), use_cache=not no_cache)
    summary = summarize_scene(scene)
    click.echo(json.dumps(summary, indent=2) if as_json else format_summary(summary))


COMMANDS: list[click.Command] = [info]

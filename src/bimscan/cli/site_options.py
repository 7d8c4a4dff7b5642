"""The site options shared by the commands that scan or export a scene (``bimscan.site``)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import click

from bimscan.site.library import CLUTTER_KINDS, GROUPS
from bimscan.site.model import DEFAULT_STAGE, STAGES, ClutterSettings, SiteModel, StageSettings


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(",") if n.strip()) if text else ()


def site_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """Add the site flags to a click command; the command receives one ``site: SiteModel``."""
    options = [
        click.option("--clutter", "clutter", type=float, default=ClutterSettings.density, show_default=True,
                     help="Clutter and temporary works: objects per square metre of free floor (0 = none; "
                          "an office holds as much furniture as the real S3DIS rooms at about 0.75)."),
        click.option("--clutter-kinds", default=None,
                     help=f"Comma-separated kinds ({', '.join(CLUTTER_KINDS)}) or groups ({', '.join(GROUPS)}). "
                          "Default: by stage (finished: office,ceiling,people; earlier: site,people)."),
        click.option("--stage", default=DEFAULT_STAGE, show_default=True, type=click.Choice(list(STAGES)),
                     help="Construction stage: structure (slabs, walls, columns, beams, stairs), enclosed "
                          "(+ windows, doors), finished (everything)."),
        click.option("--stage-include", default=None, help="Comma-separated IFC classes built (replaces the stage's)."),
        click.option("--stage-exclude", default=None, help="Comma-separated IFC classes left out."),
        click.option("--walls-missing", type=float, default=StageSettings.walls_missing_fraction, show_default=True,
                     help="Fraction of the walls not yet built (with their doors and windows)."),
        click.option("--ceilings-open", type=float, default=StageSettings.ceilings_open_fraction, show_default=True,
                     help="Fraction of the ceiling bays (between grid lines) without panels."),
        click.option("--props", type=float, default=StageSettings.props_fraction, show_default=True,
                     help="Fraction of the rooms with steel props on a 1.5 m grid under the slab."),
        click.option("--at", "at", default=None,
                     help="A date (YYYY-MM-DD): keep what the model's work schedule has built by then."),
    ]

    @functools.wraps(command)
    def wrapper(*args: Any, clutter: float, clutter_kinds: str | None, stage: str, stage_include: str | None,
                stage_exclude: str | None, walls_missing: float, ceilings_open: float, props: float, at: str | None,
                **kwargs: Any) -> Any:
        site = SiteModel(
            stage=StageSettings(name=stage, include=_names(stage_include), exclude=_names(stage_exclude),
                                walls_missing_fraction=walls_missing, ceilings_open_fraction=ceilings_open,
                                props_fraction=props, at=at),
            clutter=ClutterSettings(density=clutter, kinds=_names(clutter_kinds)))
        return command(*args, site=site, **kwargs)

    for option in reversed(options):
        wrapper = option(wrapper)
    return wrapper


def yard_option(command: Callable[..., Any]) -> Callable[..., Any]:
    """Add --yard to a command that can fly a drone (the yard stands on the ground a flight adds); put it
    under ``site_options``: the command receives the site with its ``yard_density``."""

    @functools.wraps(command)
    def wrapper(*args: Any, yard: float, site: SiteModel, **kwargs: Any) -> Any:
        return command(*args, site=dataclasses.replace(site, yard_density=yard), **kwargs)

    return click.option("--yard", "yard", type=float, default=SiteModel.yard_density, show_default=True,
                        help="Site objects (containers, stacks, pallets, bins, drums, scaffold towers) per 100 m2 of "
                             "the ground around the building; needs the ground, which a drone's flight adds "
                             "(--platform drone).")(wrapper)


def describe_site(state: Any) -> str | None:
    """One line on what dressing did (``types.SiteState``), or None for an undressed scene."""
    if state is None:
        return None
    placed = ", ".join(f"{k} {v}" for k, v in state.placed.items()) or "nothing"
    removed = sum(state.removed.values())
    return (f"  site: {removed} components not built; placed {sum(state.placed.values())} objects "
            f"in {state.rooms} rooms ({state.free_floor_m2:.0f} m2 free floor): {placed}")

"""Generator commands: make-building."""

from __future__ import annotations

from pathlib import Path

import click

# The style table is plain data: importing it keeps --help free of IfcOpenShell.
from bimscan.ifc.generate.styles import DEFAULT_STYLE, MAX_STOREYS, MIN_STOREYS, STYLES


@click.command("make-building")
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "--seed", type=int, default=0, show_default=True, help="Layout seed; the same seed gives the same file bytes."
)
@click.option(
    "--storeys",
    type=int,
    default=2,
    show_default=True,
    help=f"Number of storeys, {MIN_STOREYS}..{MAX_STOREYS}; more than one adds a stair between them.",
)
@click.option(
    "--style",
    type=click.Choice(list(STYLES)),
    default=DEFAULT_STYLE,
    show_default=True,
    help="office: cellular offices with downstand beams and ceilings (like S3DIS); residential: smaller "
    "rooms, lower storeys, no column grid; site: a bare structural frame, open areas, no finishes.",
)
@click.option(
    "--schedule",
    "schedule_start",
    metavar="START",
    default=None,
    help="Add a construction work schedule from START (YYYY-MM-DD): storey by storey from the bottom, "
    "structure, exterior and interior walls, windows and doors, finishes, furniture, the roof after the "
    "top storey's structure; working days (Monday to Friday) drawn from the seed. Every element is built "
    "by one task, so --at DATE keeps what stands that day.",
)
@click.option("--overwrite", is_flag=True,
              help="Replace OUT if bimscan wrote it (an IFC whose header names a bimscan author); a model of yours "
                   "is refused, never replaced.")
def make_building_command(out: Path, seed: int, storeys: int, style: str, schedule_start: str | None,
                          overwrite: bool) -> None:
    """Write a procedural building to OUT (an .ifc file, IFC4).

    A seeded corridor block of the chosen style, rectangular or L, U, T shaped or notched:
    exterior and interior walls with doors and windows (punched or in bands), columns and
    beams, floor/roof slabs, ceilings, a stair, furniture, one IfcSpace per room; most
    rectangular residential buildings get an attic under a gable roof, and some buildings of two
    storeys or more a double-height hall. With --schedule, the IFC work schedule of its construction.
    An existing OUT is kept unless --overwrite; OUT is written atomically.
    """
    from bimscan.ifc.generate import make_building

    building = make_building(out, seed=seed, storeys=storeys, style=style, schedule_start=schedule_start,
                             overwrite=overwrite)
    plan = building.plan
    x0, y0, x1, y1 = building.footprint_m
    rooms = "+".join(str(n) for n in building.rooms_per_storey)
    counts = ", ".join(f"{cls} {n}" for cls, n in building.placed.items())
    roof = "flat roof" if plan.roof is None else f"attic under a {plan.roof.pitch_deg:g} deg gable roof"
    if plan.hall is not None:
        roof += (f", a double-height hall of {plan.hall.rect.area:.0f} m2 through storeys {plan.hall.storey}-"
                 f"{plan.hall.storey + 1}")
    works = building.works
    click.echo(
        f"wrote {out}: {style} seed {seed}, {building.storeys} storeys, {sum(building.rooms_per_storey)} rooms "
        f"({rooms}), {plan.shape} {x1 - x0:.1f} x {y1 - y0:.1f} x {building.height_m:.2f} m, storey "
        f"{plan.storey_height_m:.2f} m, ceiling {plan.ceiling_height_m:.2f} m ({plan.ceiling_system}), {roof}; {counts}"
        + (f"; work schedule of {len(works)} tasks from {min(t.start for t in works)} to {max(t.finish for t in works)}"
           if works else "")
    )


COMMANDS: list[click.Command] = [make_building_command]

"""Generator commands: make-building."""

from __future__ import annotations

from pathlib import Path

import click

# The layout module is plain NumPy: importing it keeps --help free of IfcOpenShell.
from bimscan.ifc.generate.layout import MAX_STOREYS, MIN_STOREYS


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
def make_building_command(out: Path, seed: int, storeys: int) -> None:
    """Write a procedural demo building to OUT (an .ifc file, IFC4).

    A seeded office block: exterior and interior walls with doors and windows, columns and
    downstand beams, floor/roof slabs, ceilings, a stair, furniture, one IfcSpace per room.
    OUT is replaced if it exists; it is written atomically.
    """
    from bimscan.ifc.generate import make_building

    building = make_building(out, seed=seed, storeys=storeys)
    x0, y0, x1, y1 = building.footprint_m
    rooms = "+".join(str(n) for n in building.rooms_per_storey)
    counts = ", ".join(f"{cls} {n}" for cls, n in building.placed.items())
    click.echo(
        f"wrote {out}: seed {seed}, {building.storeys} storeys, {sum(building.rooms_per_storey)} rooms ({rooms}), "
        f"{x1 - x0:.1f} x {y1 - y0:.1f} x {building.height_m:.2f} m; {counts}"
    )


COMMANDS: list[click.Command] = [make_building_command]

"""``bimscan align`` and ``bimscan progress``: a site scan against its IFC model."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import click

from bimscan.cli.ifc_commands import LENGTH_UNIT_HELP
from bimscan.compare.config import AlignConfig, ProgressConfig
from bimscan.ifc.units import LENGTH_UNITS

_ALIGN = AlignConfig()
_PROGRESS = ProgressConfig()
CLOUD_FORMATS = ("laz", "las", "ply", "e57", "npy")


def _date(context: click.Context, parameter: click.Parameter, value: str | None) -> str | None:
    del context, parameter
    if value is None:
        return None
    try:
        return dt.date.fromisoformat(value).isoformat()
    except ValueError as exc:
        raise click.BadParameter(f"{value!r} is not a date; give YYYY-MM-DD, e.g. 2026-11-29") from exc


def _echo_alignment(alignment, *, indent: str = "  ") -> None:  # type: ignore[no-untyped-def]
    click.echo(f"{indent}inliers: {alignment.inlier_share:.1%} of the scan within {alignment.inlier_m * 100:g} cm of "
               f"the model; their distance: median {alignment.median_m * 1000:.1f} mm, 90 % under "
               f"{alignment.p90_m * 1000:.1f} mm")
    placed = {"search": f"{alignment.candidates} coarse poses tried", "init": "started from --init",
              "georeferencing": "placed by the model's georeferencing (IfcMapConversion)"}[alignment.placed_by]
    click.echo(f"{indent}levelled by {alignment.up_tilt_deg:.2f} deg; {placed}")
    for line in alignment.warnings:
        click.echo(f"warning: {line}", err=True)


@click.command("align")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("scan", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--init", "init", type=click.Path(path_type=Path), default=None,
              help="Start from this rough pose instead of searching: a 4x4 matrix file (four lines of four numbers, "
                   "or a transform.json) or a CSV of three or more point pairs scan_x,scan_y,scan_z,model_x,model_y,model_z.")
@click.option("--levelled", is_flag=True,
              help="The scan's z axis is up (a levelled tripod): search only the heading and the offset.")
@click.option("--aligned", "aligned_format", type=click.Choice(CLOUD_FORMATS), default=None,
              help="Also write the scan moved into the model's frame, OUT/aligned.<format>, every column kept.")
@click.option("--voxel", "voxel_m", type=float, default=None,
              help=f"Thin the scan to the centroids of cubes of this edge, metres. Default: {_ALIGN.voxel_m:g}.")
@click.option("--seed", type=int, default=_ALIGN.seed, show_default=True, help="Seed of the random draws.")
@click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None, help=LENGTH_UNIT_HELP)
@click.option("--overwrite", is_flag=True, help="Replace OUT if it is an alignment folder bimscan wrote.")
def align(model: Path, scan: Path, out: Path, init: Path | None, levelled: bool, aligned_format: str | None,
          voxel_m: float | None, seed: int, length_unit: str | None, overwrite: bool) -> None:
    """Find the rigid transform that puts SCAN (any cloud bimscan reads) into MODEL.ifc's frame,
    without a starting guess, and write it to the folder OUT.

    Up comes from the scan's floors, ceilings and walls (or its z axis with --levelled), the
    heading from its walls' directions, the offset from its floor plan and floor heights; then a
    robust point-to-plane ICP against the model's surfaces, which holds when most elements are not
    built yet, under clutter, and for scans in map coordinates. OUT gets transform.json (the 4x4
    matrix, its inverse, the residuals, the inlier share, warnings) and transform.txt (the matrix
    as CloudCompare and PDAL read it). A fit that leaves a direction free (a corridor) or that
    another pose matches almost as well (a symmetric plan) is reported.
    """
    from bimscan.toml_files import build_dataclass

    table = {"levelled": levelled, "seed": seed} | ({} if voxel_m is None else {"voxel_m": voxel_m})
    config = build_dataclass(AlignConfig, table, where="the flags")
    from bimscan.pipeline import align_model

    run = align_model(model, scan, out, config, init=init, aligned_format=aligned_format, overwrite=overwrite,
                      length_unit=length_unit)
    a = run.alignment
    click.echo(f"{out}: {scan.name} aligned to {model.name} ({a.points:,} points, {a.centroids:,} centroids)")
    _echo_alignment(a)
    click.echo("  files: " + ", ".join(run.files))
    click.echo("  seconds: " + ", ".join(f"{step} {seconds:.1f}" for step, seconds in run.steps.items()))


@click.command("progress")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("scan", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--align", "align_first", is_flag=True, help="Align the scan to the model first (as 'bimscan align').")
@click.option("--transform", type=click.Path(path_type=Path), default=None,
              help="The scan's pose in the model: a transform.json of 'bimscan align', a 4x4 matrix file, or a CSV "
                   "of three or more point pairs scan_x,scan_y,scan_z,model_x,model_y,model_z (surveyed control "
                   "targets: deviations are then measured against the site's grid). Default: the scan is in the "
                   "model's frame already.")
@click.option("--at", callback=_date, default=None,
              help="A date (YYYY-MM-DD): judge each element against what the model's work schedule has standing "
                   "then (on time, behind, ahead), with percent complete per storey and class.")
@click.option("--model", "checkpoint", type=click.Path(path_type=Path), default=None,
              help="A segmentation checkpoint (bimscan train): points it labels Others (clutter, people, "
                   "furniture) support no element.")
@click.option("--stations", type=click.Path(path_type=Path), default=None,
              help="Where the stations stood, a CSV of id,x,y,z in the scan's frame, over what the scan's file says "
                   "(E57 poses, a bimscan header) or what is estimated from its points.")
@click.option("--support", "support_m", type=float, default=None,
              help=f"A return within this of a model surface's range supports it, metres. Default: {_PROGRESS.support_m:g}.")
@click.option("--points", "points_format", type=click.Choice(CLOUD_FORMATS + ("none",)), default="laz",
              show_default=True, help="Format of OUT/points.*, the scan with each point's element and distance "
                                      "to the model; none: not written.")
@click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None, help=LENGTH_UNIT_HELP)
@click.option("--overwrite", is_flag=True, help="Replace OUT if it is a progress folder bimscan wrote.")
def progress(model: Path, scan: Path, out: Path, align_first: bool, transform: Path | None, at: str | None,
             checkpoint: Path | None, stations: Path | None, support_m: float | None, points_format: str,
             length_unit: str | None, overwrite: bool) -> None:
    """Compare SCAN with MODEL.ifc element by element and write the folder OUT: what is built,
    not built, not visible (no verdict: hidden, out of range, outside the scan) or built out of
    tolerance (ACI 117-10 by class).

    Visibility is judged along the scanner's beams from the stations (E57 poses, a bimscan
    header, --stations, or estimated from each station's points; a mobile scan's beam origins):
    a return at a surface's range supports it, returns only beyond it show it is not there. OUT
    gets elements.csv (per element: GlobalId, class, storey, status, visible and supported shares,
    deviation), summary.json (percent complete by class and storey), progress.ifc (the model with
    a property set per element), points.laz (each point's element and signed distance), issues.bcf
    (elements out of tolerance or behind schedule) and pictures per storey.
    """
    from bimscan.toml_files import build_dataclass

    if align_first and transform is not None:
        raise click.UsageError("--align and --transform both say where the scan lies; give one")
    config = build_dataclass(ProgressConfig, {} if support_m is None else {"support_m": support_m},
                             where="the flags")
    from bimscan.pipeline import compare_model

    run = compare_model(model, scan, out, config, align=AlignConfig() if align_first else None, transform=transform,
                        at=at, checkpoint=checkpoint, stations=stations,
                        points_format=None if points_format == "none" else points_format, overwrite=overwrite,
                        length_unit=length_unit, log=lambda line: click.echo(f"warning: {line}", err=True))
    result = run.result
    click.echo(f"{out}: {len(result.elements.status)} elements of {model.name} against {scan.name} "
               f"({result.points:,} points, {len(result.views)} views)")
    if run.alignment is not None:
        _echo_alignment(run.alignment)
    control = run.summary.get("control")
    if control is not None:
        click.echo(f"  placed by {control['pairs']} point pairs: their residuals median {control['median_mm']:.1f} mm, "
                   f"largest {control['max_mm']:.1f} mm")
    click.echo("  class            elements   built   out of tol.   not built   not visible   complete")
    for name, tally in run.summary["by_class"].items():
        complete = "-" if tally["complete_share"] is None else f"{100 * tally['complete_share']:.0f} %"
        click.echo(f"  {name or '-':<15}  {tally['elements']:8d}   {tally['built']:5d}   "
                   f"{tally['built out of tolerance']:11d}   {tally['not built']:9d}   {tally['not visible']:11d}   "
                   f"{complete:>8}")
    if at is not None:
        everything = run.summary["all"]
        click.echo(f"  against the schedule on {at}: on time {everything['on time']}, behind {everything['behind']}, "
                   f"ahead {everything['ahead']}, not due {everything['not due']}, unknown {everything['unknown']}")
    click.echo("  files: " + ", ".join(run.files))
    click.echo("  seconds: " + ", ".join(f"{step} {seconds:.1f}" for step, seconds in run.steps.items()))


COMMANDS: list[click.Command] = [align, progress]

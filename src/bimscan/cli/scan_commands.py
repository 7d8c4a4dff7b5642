"""``bimscan scan``: one IFC model -> one merged, labelled multi-station TLS cloud."""

from __future__ import annotations

from pathlib import Path

import click

from bimscan.cli.ifc_commands import LENGTH_UNIT_HELP, SCHEME_HELP, echo_load_report
from bimscan.ifc.units import LENGTH_UNITS


@click.command("scan")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--preset", default="exp3", show_default=True,
              help="Scan settings: exp1..exp6 (the paper's Table 1) or a settings TOML file.")
@click.option("--stations", default="auto", show_default=True,
              help="'auto' (planned per storey and room) or a CSV file (x,y,z or x,y,height[,storey][,heading_deg]).")
@click.option("--seed", default=0, show_default=True, type=int, help="Noise seed; same seed, same bytes.")
@click.option("--no-noise", is_flag=True, help="Exact points on the hit surfaces (no range or angle noise).")
@click.option("--range-sigma", "range_sigma_m", default=0.005, show_default=True, type=float, help="Range noise sigma, metres.")
@click.option("--angle-sigma", "angle_sigma_deg", default=0.03, show_default=True, type=float,
              help="Azimuth and elevation noise sigma, degrees.")
@click.option("--registration-sigma", "registration_sigma_m", default=0.0, show_default=True, type=float,
              help="Per-station registration error: translation sigma per axis, metres (0 = perfect registration).")
@click.option("--registration-sigma-deg", "registration_sigma_deg", default=0.0, show_default=True, type=float,
              help="Per-station registration error: rotation sigma about the vertical, degrees.")
@click.option("--strict", is_flag=True, help="Settings outside the device's limits are errors, not warnings; so is an "
              "IFC file that needed a repair, has a problem or loses an element (see 'bimscan info --help').")
@click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None, help=LENGTH_UNIT_HELP)
@click.option("--scanner", default=None, help="Scanner: riegl_vz400 (default) or a scanner TOML file.")
@click.option("--head-speed", "head_deg_per_s", type=float, default=None,
              help="Head rotation in deg/s, overriding the preset (fewer points per station when faster).")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--engine", default="open3d", show_default=True, help="Ray engine: open3d or embreex.")
@click.option("--threads", default=0, show_default=True, type=int, help="Cores to use (0 = all).")
@click.option("--overwrite", is_flag=True, help="Replace OUT if it exists.")
def scan(model: Path, out: Path, preset: str, stations: str, seed: int, no_noise: bool, range_sigma_m: float,
         angle_sigma_deg: float, registration_sigma_m: float, registration_sigma_deg: float, strict: bool, scanner: str | None, head_deg_per_s: float | None, scheme: str | None,
         engine: str, threads: int, overwrite: bool, length_unit: str | None) -> None:
    """Scan MODEL.ifc with a virtual TLS and write a labelled cloud to OUT.

    OUT's suffix picks the format: .laz, .las, .ply, or a folder (no suffix) of NumPy arrays
    in the Pointcept layout. Class ids go to LAS classification; component and station are
    extra dimensions; class names and the component table are stored with the file.
    """
    from bimscan.ifc.watchdog import prestart_worker

    prestart_worker()  # IfcOpenShell loads in the geometry worker while this process loads the scanner
    from bimscan.pipeline import load_scene
    from bimscan.io import check_cloud_output
    from bimscan.pipeline import ScanOptions, prepare_survey, resolve_settings, scan_survey
    from bimscan.scan.noise import NoiseModel

    noise = NoiseModel.off() if no_noise else NoiseModel(
        range_sigma_m=range_sigma_m, angle_sigma_deg=angle_sigma_deg,
        registration_sigma_m=registration_sigma_m, registration_sigma_deg=registration_sigma_deg)
    options = ScanOptions(preset=preset, scanner=scanner, stations=stations, seed=seed, noise=noise, strict=strict,
                          head_deg_per_s=head_deg_per_s, engine=engine, threads=threads)
    check_cloud_output(out, overwrite=overwrite)  # output, settings: errors before the slow parts
    _, _, warnings = resolve_settings(options)
    for warning in warnings:
        click.echo(f"warning: {warning}", err=True)
    scene = load_scene(model, scheme=scheme, strict=strict, length_unit=length_unit)
    echo_load_report(scene)
    survey = prepare_survey(scene, options)
    if survey.plan is not None and survey.plan.rooms_without_station:
        click.echo("warning: rooms without a station (too small for a tripod or no floor): "
                   + ", ".join(survey.plan.rooms_without_station), err=True)
    result = scan_survey(survey, out, options, overwrite=overwrite)
    extents = result.summary.extents()
    names = survey.scene.scheme.names
    click.echo(f"{result.path}: {result.points:,} points from {len(survey.stations)} stations in {result.seconds:.1f} s "
               f"({result.points / max(result.seconds, 1e-9) / 1e6:.2f} Mpts/s)")
    click.echo("  extent (m): " + " x ".join(f"{v:.2f}" for v in extents["size"]))
    click.echo("  classes: " + ", ".join(f"{k} {v:,}" for k, v in result.summary.histogram(names).items()))


COMMANDS: list[click.Command] = [scan]

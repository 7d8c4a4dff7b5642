"""``bimscan scan``: one IFC model -> one merged, labelled multi-station TLS cloud."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from bimscan.cli.ifc_commands import LENGTH_UNIT_HELP, SCHEME_HELP
from bimscan.cli.site_options import describe_site, site_options, yard_option
from bimscan.constraints import default_of
from bimscan.ifc.units import LENGTH_UNITS
from bimscan.scan.device import DEFAULT_PRESET, DEFAULT_SCANNER, PRESETS, SCANNERS
from bimscan.scan.engine import AUTO_ENGINE, DEFAULT_ENGINE, ENGINES
from bimscan.scan.noise import NoiseModel
from bimscan.scan.sensor import REALISMS, RETURN_MODES, SensorModel
from bimscan.scan.lidars import MOBILE_LIDARS
from bimscan.survey.drift import (RTK_HEADING_DEG_PER_M, RTK_VERTICAL_RATIO, DriftModel, GnssInsModel,
                                  registration_drift)
from bimscan.survey.platform import PLATFORM_NAMES, TRIPOD
from bimscan.survey.recipe import AUTO_STATIONS, DEFAULT_MAX_STATION_PULSES, DEFAULT_MAX_WALK_PULSES, ScanRecipe

if TYPE_CHECKING:
    from bimscan.site.model import SiteModel


@click.command("scan")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(path_type=Path))
@click.option("--preset", default=None,
              help=f"Tripod scan settings: {', '.join(PRESETS)} (the paper's Table 1) or a settings TOML file. "
                   f"Default: {DEFAULT_PRESET}. Refused on a mobile platform (its lidars fire their own pattern).")
@click.option("--stations", default=AUTO_STATIONS, show_default=True,
              help="'auto' (planned on the floors the model has: one per room, then every spot of a level seen "
                   "from a station within 12 m) or a CSV file (x,y,z or x,y,height[,storey][,heading_deg]). On a "
                   "mobile platform: the waypoints of a planned walk (refused beside a --trajectory file).")
@click.option("--seed", default=ScanRecipe.seed, show_default=True, type=int, help="Noise seed; same seed, same bytes.")
@click.option("--no-noise", is_flag=True, help="Exact points on the hit surfaces (no range or angle noise).")
@click.option("--range-sigma", "range_sigma_m", default=None, type=float,
              help="Range noise sigma, metres. Default: the scanner's range accuracy (VZ-400: 0.005).")
@click.option("--angle-sigma", "angle_sigma_deg", default=None, type=float,
              help="Azimuth and elevation noise sigma, degrees. Default: the scanner's angle accuracy (VZ-400: 0.03).")
@click.option("--registration-sigma", "registration_sigma_m", default=NoiseModel.registration_sigma_m, show_default=True,
              type=float,
              help="Per-station registration error: translation sigma per axis, metres (0 = perfect registration).")
@click.option("--registration-sigma-deg", "registration_sigma_deg", default=NoiseModel.registration_sigma_deg,
              show_default=True, type=float,
              help="Per-station registration error: rotation sigma about the vertical, degrees.")
@click.option("--strict", is_flag=True, help="Settings outside the device's limits are errors, not warnings; so is an "
              "IFC file that needed a repair, has a problem or loses an element (see 'bimscan info --help').")
@click.option("--length-unit", type=click.Choice(list(LENGTH_UNITS)), default=None, help=LENGTH_UNIT_HELP)
@click.option("--scanner", default=None,
              help=f"Scanner: a name ({', '.join([*SCANNERS, *MOBILE_LIDARS])}) or a scanner TOML file. Default: "
                   f"{DEFAULT_SCANNER} on the tripod, the platform's lidar on a mobile platform.")
@click.option("--platform", default=TRIPOD, show_default=True,
              help=f"What carries the scanner: {', '.join(PLATFORM_NAMES)} (a person walking with lidars, or a drone "
                   "with a Risley lidar), or a platform TOML file.")
@click.option("--trajectory", default=None,
              help="Mobile platforms: 'auto' (a walk planned from the model through the stations of --stations, "
                   "back to its start; a drone's flight planned around and over it; the default) or a CSV file "
                   "t,x,y,z,roll,pitch,yaw (degrees).")
@click.option("--drift", "drift_m", type=float, default=None,
              help="Walking platforms: SLAM drift, the position error's sigma after 10 m walked (metres; heading "
                   "drifts alike), pinned to zero at loop closures. "
                   f"Default: {default_of(DriftModel, 'sigma_m'):g} (none).")
@click.option("--gnss", "gnss_m", type=float, default=None,
              help=f"Drones: the GNSS/INS error, its horizontal sigma in metres (vertical {RTK_VERTICAL_RATIO:g}x, heading "
                   f"{RTK_HEADING_DEG_PER_M / 100:g} degree per centimetre; a Gauss-Markov process with a "
                   f"{default_of(GnssInsModel, 'correlation_s'):g} s correlation time). 0.01 is an RTK-fixed DJI M350 "
                   "with a Zenmuse L2. Default: none.")
@click.option("--rotation-hz", type=float, default=None,
              help="Mobile platforms: a multi-beam lidar's rotation rate. Default: the scanner's (VLP-16: 10 Hz). "
                   "Refused for a Risley-prism lidar (its prisms turn at its scanner file's rates).")
@click.option("--head-speed", "head_deg_per_s", type=float, default=None,
              help="Tripod head rotation in deg/s, overriding the preset (fewer points per station when faster). "
                   "Refused on a mobile platform.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--engine", type=click.Choice([*ENGINES, AUTO_ENGINE]), default=DEFAULT_ENGINE, show_default=True,
              help="Ray engine: open3d (Embree), embreex, warp (NVIDIA Warp: CUDA GPU, else its CPU device) or auto "
                   "(warp on a CUDA GPU, open3d otherwise).")
@click.option("--realism", type=click.Choice(list(REALISMS)), default=None,
              help=f"Sensor effects: paper (thin ray, Gaussian noise) or full (every effect below on). "
                   f"Default: {SensorModel.realism}.")
@click.option("--sensor", "sensor_file", default=None,
              help="A TOML file of sensor settings (the keys of a dataset spec's [sensor] table).")
@click.option("--returns", type=click.Choice(list(RETURN_MODES)), default=None,
              help=f"Which echoes of a pulse become points. Default: {SensorModel.returns}. Acts only with the "
                   "footprint or glass (a pulse has one echo without them): another value is refused without them, "
                   "and on a mobile platform.")
@click.option("--footprint/--no-footprint", default=None, help="Beam footprint with sub-rays at edges (mixed pixels).")
@click.option("--beam-sample-quality", type=int, default=None,
              help=f"Sub-ray rings of the footprint (HELIOS++'s beamSampleQuality; 3 = 19 sub-rays). Default: "
                   f"{SensorModel.beam_sample_quality}. Acts only with the footprint: another value is refused "
                   "without it, and on a mobile platform.")
@click.option("--detection/--no-detection", default=None,
              help="Return probability from the range equation (reflectance, incidence, range) with speckle.")
@click.option("--glass/--no-glass", default=None, help="Transparent surfaces pass the beam.")
@click.option("--rgb/--no-rgb", "color", default=None, help="Per-point colour from the surface styles.")
@click.option("--as-built/--no-as-built", "deviations", default=None,
              help="As-built deviations of every component within construction tolerances (ACI 117).")
@click.option("--material-table", default=None,
              help="A TOML material table replacing the built-in one. Acts only with materials, glass or colour "
                   "(--realism full, --glass, --rgb): refused without them.")
@click.option("--threads", default=ScanRecipe.threads, show_default=True, type=int, help="Cores to use (0 = all).")
@click.option("--max-station-pulses", default=None, type=int,
              help=f"Tripod: refuse settings under which one station would fire more pulses (a guard against "
                   f"typos). Default: {DEFAULT_MAX_STATION_PULSES:,}. Refused on a mobile platform.")
@click.option("--max-walk-pulses", default=None, type=int,
              help=f"Mobile platforms: refuse a walk whose lidars would fire more pulses in all (its duration x "
                   f"the lidars' pulse rates; checked before the model is read when the trajectory is a file). "
                   f"Default: {DEFAULT_MAX_WALK_PULSES:,}. Refused on the tripod.")
@click.option("--overwrite", is_flag=True,
              help="Replace OUT (and a mobile scan's OUT.trajectory.csv, which a tripod scan removes) if bimscan "
                   "wrote it: a cloud file in OUT's format or a bimscan NumPy folder. Anything else there is refused, "
                   "never removed.")
@site_options
@yard_option
def scan(model: Path, out: Path, preset: str | None, stations: str, seed: int, no_noise: bool,
         range_sigma_m: float | None, angle_sigma_deg: float | None, registration_sigma_m: float,
         registration_sigma_deg: float, strict: bool, scanner: str | None, head_deg_per_s: float | None,
         scheme: str | None, engine: str, realism: str | None, sensor_file: str | None, returns: str | None,
         footprint: bool | None, beam_sample_quality: int | None, detection: bool | None, glass: bool | None,
         color: bool | None, deviations: bool | None, material_table: str | None, threads: int,
         max_station_pulses: int | None, max_walk_pulses: int | None, overwrite: bool, length_unit: str | None,
         site: SiteModel, platform: str, trajectory: str | None, drift_m: float | None, gnss_m: float | None,
         rotation_hz: float | None) -> None:
    """Scan MODEL.ifc with a virtual TLS (or a mobile scanner) and write a labelled cloud to OUT.

    OUT's suffix picks the format: .laz, .las, .e57, .ply, or a folder (no suffix) of NumPy arrays
    in the Pointcept layout. Class ids go to LAS classification; component and station are
    extra dimensions; class names and the component table are stored with the file. With
    sensor effects on, return numbers (and colour with --rgb) are stored too. With
    --clutter/--stage the building is scanned as a site (objects added as components, elements
    not yet built left out); stations are planned on that scene. With --platform handheld or
    backpack the scanner walks a trajectory instead: every point carries its time, ring, lidar and
    beam origin, and the trajectory walked is written beside OUT as OUT.trajectory.csv. An option
    that would change nothing (a preset on a mobile platform, --returns without the footprint or
    glass, ...) is refused before any work.
    """
    from bimscan.ifc.watchdog import prestart_worker

    prestart_worker()  # IfcOpenShell loads in the geometry worker while this process loads the scanner
    from bimscan.pipeline import scan_model
    from bimscan.survey.recipe import resolve_sensor
    from bimscan.toml_files import load_toml

    if no_noise:
        range_sigma_m, angle_sigma_deg = 0.0, 0.0
    noise = NoiseModel(range_sigma_m=range_sigma_m, angle_sigma_deg=angle_sigma_deg,
                       registration_sigma_m=registration_sigma_m, registration_sigma_deg=registration_sigma_deg)
    sensor = dict(load_toml(sensor_file)) if sensor_file is not None else {}
    flags = {"returns": returns, "footprint": footprint, "beam_sample_quality": beam_sample_quality,
             "detection": detection, "glass": glass, "color": color, "deviations": deviations,
             "material_table": material_table}
    sensor |= {key: value for key, value in flags.items() if value is not None}
    settings = resolve_sensor(sensor, realism=realism,
                              where=f"{sensor_file} with the sensor flags" if sensor_file else "the sensor flags")
    mobile = platform != TRIPOD
    recipe = ScanRecipe.resolve(preset=preset, scanner=None if mobile else scanner, lidar=scanner if mobile else None,
                                head_deg_per_s=head_deg_per_s, noise=noise, seed=seed,
                                engine=engine, stations_from=stations, strict=strict, threads=threads,
                                max_station_pulses=max_station_pulses, max_walk_pulses=max_walk_pulses,
                                sensor=settings, site=site, platform=platform, trajectory=trajectory,
                                drift=registration_drift(drift_m, gnss_m), rotation_hz=rotation_hz)
    result = scan_model(model, out, recipe, scheme=scheme, overwrite=overwrite, length_unit=length_unit,
                        warn=lambda line: click.echo(f"warning: {line}", err=True))
    extents = result.summary.extents()
    names = result.survey.scene.scheme.names
    walked = result.survey.trajectory
    moved = "flight" if result.survey.recipe.mobile is not None and result.survey.recipe.mobile.platform.flies else "walk"
    source = (f"{len(result.survey.stations)} stations" if walked is None else
              f"a {walked.length_m():.0f} m {moved} of {walked.duration_s():.0f} s in {walked.n_passes} "
              f"pass{'es' if walked.n_passes > 1 else ''}")
    click.echo(f"{result.path}: {result.points:,} points from {source} in "
               f"{result.seconds:.1f} s ({result.points / max(result.seconds, 1e-9) / 1e6:.2f} Mpts/s)")
    if walked is not None:
        from bimscan.survey.trajectory import trajectory_path

        from bimscan.survey.flight import FlightReport

        walk = result.survey.walk
        if isinstance(walk, FlightReport):
            click.echo(f"  trajectory: {trajectory_path(result.path)}")
            click.echo(f"  {walk.line()}")
        else:
            rooms = (f"; rooms visited: {len(walk.rooms)}, stations of the tripod plan missed: {len(walk.missed)}"
                     if walk else "")
            click.echo(f"  trajectory: {trajectory_path(result.path)} ({len(walked.closures)} loop closures{rooms})")
    plan = result.survey.plan
    if plan is not None and plan.stations_per_storey:
        click.echo("  stations per storey: " + ", ".join(f"{k} {v}" for k, v in plan.stations_per_storey.items()))
    click.echo("  extent (m): " + " x ".join(f"{v:.2f}" for v in extents["size"]))
    click.echo("  classes: " + ", ".join(f"{k} {v:,}" for k, v in result.summary.histogram(names).items()))
    line = describe_site(result.survey.scene.site)
    if line:
        click.echo(line)
    click.echo("  seconds: " + ", ".join(f"{step} {seconds:.1f}" for step, seconds in result.steps.items()))


@click.command("furnish")
@click.argument("model", type=click.Path(path_type=Path))
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--seed", default=ScanRecipe.seed, show_default=True, type=int,
              help="Placement seed; same seed, same objects.")
@click.option("--scheme", default=None, help=SCHEME_HELP)
@click.option("--overwrite", is_flag=True,
              help="Replace OUT if bimscan wrote it (an IFC whose header names a bimscan author); a model of "
                   "yours is refused, never replaced, and so is MODEL itself.")
@site_options
def furnish(model: Path, out: Path, seed: int, scheme: str | None, overwrite: bool, site: SiteModel) -> None:
    """Write OUT.ifc: a copy of MODEL.ifc with the site's clutter as IfcFurniture and
    IfcBuildingElementProxy elements (ObjectType = bimscan's class, e.g. Clutter.Chair) and the
    elements the stage leaves out removed: the scene 'bimscan scan' with the same flags and
    seed scans, for other tools to see."""
    from bimscan.pipeline import furnish_model

    if site.is_bare:
        raise click.UsageError("nothing to furnish: give --clutter DENSITY and/or --stage")
    dressed = furnish_model(model, out, ScanRecipe(seed=seed, site=site), scheme=scheme, overwrite=overwrite)
    click.echo(f"wrote {out}")
    line = describe_site(dressed.site)
    if line:
        click.echo(line)


COMMANDS: list[click.Command] = [scan, furnish]

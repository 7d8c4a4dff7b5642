"""Multi-station surveys: a scene with its scanner, recipe and stations, scanned into one stream.

``prepare_survey`` places the scanner in the scene and fixes the stations (planned, read from a
file, or given); the ``Survey`` keeps the recipe it was prepared with, so what is scanned and what
the cloud's metadata records cannot disagree. ``run_survey`` scans the stations in id order and
concatenates their chunks: the merged cloud is the stations' clouds one after another, each point
keeping its station id. Station ``k``'s clock starts where station ``k - 1``'s rotation ended.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bimscan import __version__
from bimscan.errors import StationError, number
from bimscan.scan.device import MAX_HEAD_DEG_PER_S
from bimscan.scan.pattern import PulsePattern
from bimscan.scan.probe import Prober
from bimscan.survey.recipe import AUTO_STATIONS, ScanRecipe
from bimscan.scan.virtual_scanner import VirtualScanner
from bimscan.survey.mobile import AUTO_TRAJECTORY, MobileScan
from bimscan.survey.stations import PlanReport, plan_stations, read_stations, station_spots
from bimscan.survey.trajectory import Trajectory, read_trajectory
from bimscan.site.classes import SITE_CLASSES
from bimscan.survey.flight import FlightReport, lidar_half_extent_deg, plan_flight
from bimscan.survey.walk import WalkReport, plan_walk
from bimscan.types import BimScene, CloudHeader, PointCloud, Station

SITE_OBJECT_CLASSES = tuple(SITE_CLASSES)  # what a flight does not fly around: the ground, the yard, clutter
YARD_CLASSES = tuple(c for c in SITE_CLASSES if c != "Terrain.Ground")  # what a flight keeps clear of
FLIGHT_MARGIN_M = 500.0  # a flight file may reach this far beyond the model (a walk's: 5 m)


@dataclass(frozen=True)
class Survey:
    """A scene ready to scan: the scanner placed in it, the recipe, the stations (and the plan
    report when they were planned)."""

    scene: BimScene
    scanner: VirtualScanner
    recipe: ScanRecipe
    stations: tuple[Station, ...]
    plan: PlanReport | None = None
    trajectory: Trajectory | None = None
    walk: WalkReport | FlightReport | None = None

    def pulses(self) -> int:
        """Emitted pulses of the whole survey (for progress bars and size estimates)."""
        if self.trajectory is not None:
            return self.recipe.mobile.walk_pulses(self.trajectory)
        return station_pulses(self.recipe) * len(self.stations)


def station_pulses(recipe: ScanRecipe) -> int:
    """Emitted pulses of one station scanned with ``recipe`` (exact, line by line)."""
    return PulsePattern.of(recipe.settings, recipe.scanner).count()


def choose_stations(scene: BimScene, recipe: ScanRecipe, *, prober: Prober | None = None,
                    check: bool = True) -> tuple[tuple[Station, ...], PlanReport | None]:
    """The stations of a scene as ``recipe.stations_from`` says: planned (``"auto"``) or read from
    a CSV file, each checked against the scene (``stations.check_station``; a file's stations only
    placed when not ``check``: they are checked on the scene as scanned, a site dressed from this
    one). ``prober``: probes of this scene's mesh already built (else built here)."""
    prober = prober or Prober(scene.mesh, threads=recipe.threads)
    if recipe.stations_from != AUTO_STATIONS:
        settings = recipe.settings
        return read_stations(recipe.stations_from, scene, prober, recipe.scanner, check=check,
                             head_span_deg=settings.head_stop_deg - settings.head_start_deg), None
    return plan_stations(scene, prober, recipe.scanner)


def choose_trajectory(scene: BimScene, recipe: ScanRecipe, *, prober: Prober | None = None,
                      stations: tuple[Station, ...] | None = None) -> tuple[Trajectory, WalkReport | FlightReport | None]:
    """The trajectory of a mobile recipe: planned from the scene (``survey.walk``) through
    ``stations`` (when not given: the recipe's stations, planned or read from its station file), a
    drone's flight planned around and over it (``survey.flight``), or read from its CSV file and
    checked against the scene (a flight within ``FLIGHT_MARGIN_M`` of the model)."""
    mobile = recipe.mobile
    if mobile.platform.flies:  # a flight around and over the model, or the user's
        if mobile.trajectory_from == AUTO_TRAJECTORY:
            return plan_scene_flight(scene, mobile)
        trajectory = read_trajectory(mobile.trajectory_from)
        check_trajectory(trajectory, scene, mobile.trajectory_from, margin_m=FLIGHT_MARGIN_M)
        return trajectory, None
    prober = prober or Prober(scene.mesh, threads=recipe.threads)
    if mobile.trajectory_from == AUTO_TRAJECTORY:
        if not stations:  # the waypoints: the stations a tripod survey would scan from (planned or read)
            stations, _ = choose_stations(scene, recipe, prober=prober)
        return plan_walk(scene, prober, mobile.platform, stations)
    trajectory = read_trajectory(mobile.trajectory_from)
    check_trajectory(trajectory, scene, mobile.trajectory_from)
    return trajectory, None


def plan_scene_flight(scene: BimScene, mobile: MobileScan) -> tuple[Trajectory, FlightReport]:
    """The flight a drone's recipe plans around and over ``scene`` (``survey.flight``)."""
    mesh = scene.mesh
    building = ~np.isin(scene.components.ifc_class, SITE_OBJECT_CLASSES)[mesh.face_component]  # not the ground, yard
    vertices = mesh.vertices[np.unique(mesh.faces[building])]
    if len(vertices) == 0:
        raise StationError(f"{scene.source}: nothing but site objects to fly around; a flight needs a building")
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    yard = np.isin(scene.components.ifc_class, YARD_CLASSES)[mesh.face_component]  # what stands outside
    obstacles = mesh.vertices[np.unique(mesh.faces[yard])]
    return plan_flight(vertices[:, :2], (float(lo[2]), float(hi[2])),
                       tuple(s.elevation_m for s in scene.storeys), mobile.platform.flight,
                       lidar_half_extent_deg(mobile.lidar), obstacles=obstacles)


def check_trajectory(trajectory: Trajectory, scene: BimScene, source: str | Path, *, margin_m: float = 5.0) -> None:
    """Raise StationError when a trajectory leaves the model's bounds by more than ``margin_m`` (a file
    in another coordinate system or unit). Its pulses are the recipe's to check (``ScanRecipe.check_walk``)."""
    lo, hi = scene.mesh.bounds()
    outside = np.any((trajectory.xyz < lo - margin_m) | (trajectory.xyz > hi + margin_m), axis=1)
    if outside.any():
        k = int(np.flatnonzero(outside)[0])
        raise StationError(f"{source}: pose {k} (t = {trajectory.t[k]:g} s) at "
                           f"{', '.join(number(v) for v in trajectory.xyz[k])} lies more than {margin_m:g} m outside the model "
                           f"(x {number(lo[0], 1)}..{number(hi[0], 1)}, y {number(lo[1], 1)}..{number(hi[1], 1)}, "
                           f"z {number(lo[2], 1)}..{number(hi[2], 1)}); give "
                           "the trajectory in the model's coordinates, in metres")


def require_tripod_spots(scene: BimScene, recipe: ScanRecipe) -> None:
    """Raise StationError when no tripod can stand anywhere in the scene (the first step of a plan,
    for a quick check before slow work)."""
    station_spots(scene, Prober(scene.mesh, threads=recipe.threads), recipe.scanner)


def place_scanner(scene: BimScene, recipe: ScanRecipe) -> VirtualScanner:
    """The recipe's scanner placed in the scene's mesh, on its engine and threads; with as-built
    deviations on, in the mesh moved by them (drawn from the recipe's seed and each GlobalId)."""
    mesh, deviations = scene.mesh, None
    if recipe.sensor.on("deviations"):
        from bimscan.scan.asbuilt import apply_deviations, sample_deviations

        deviations = sample_deviations(scene.mesh, scene.components.global_id, recipe.sensor, recipe.seed)
        mesh = apply_deviations(scene.mesh, deviations)
    scanner = VirtualScanner(mesh, scene.components.label, scanner=recipe.scanner, engine=recipe.engine,
                             threads=recipe.threads, components=scene.components, surfaces=scene.surfaces,
                             deviations=deviations)
    scanner.as_built = _as_built(recipe)
    return scanner


def _as_built(recipe: ScanRecipe) -> tuple | None:
    """What decides a scanner's as-built mesh (None: the IFC-true mesh)."""
    sensor = recipe.sensor
    if not sensor.on("deviations"):
        return None
    return (recipe.seed, sensor.position_tolerance_m, sensor.level_tolerance_m, sensor.plumb_tolerance_m,
            sensor.sigmas_per_tolerance)


def fits(scanner: VirtualScanner, recipe: ScanRecipe) -> bool:
    """Whether ``scanner`` can scan with ``recipe``: the same device in the same (as-built) mesh."""
    return scanner.scanner == recipe.scanner and scanner.as_built == _as_built(recipe)


def check_site(scene: BimScene, recipe: ScanRecipe) -> None:
    """Raise ValueError when the scene was not dressed with the recipe's site model and seed
    (``pipeline.build_site`` first), so a cloud's metadata cannot claim clutter it does not hold."""
    from bimscan.site import site_settings

    wanted = None if recipe.site.is_bare else site_settings(recipe.site, recipe.seed)
    have = None if scene.site is None else scene.site.settings
    if wanted != have:
        raise ValueError("the scene was not dressed with this recipe's site model and seed; dress it with "
                         "bimscan.pipeline.build_site(scene, recipe) before preparing the survey")


def prepare_survey(scene: BimScene, recipe: ScanRecipe, *, scanner: VirtualScanner | None = None,
                   stations: tuple[Station, ...] | None = None, plan: PlanReport | None = None,
                   trajectory: Trajectory | None = None, walk: WalkReport | FlightReport | None = None) -> Survey:
    """Place the scanner in the scene and fix the stations (``recipe.stations_from``).

    ``scanner``: reuse a VirtualScanner already built over this scene with the recipe's model.
    ``stations`` given: use them as they are (chosen and checked on this scene by the caller, as
    ``pipeline.site_and_stations`` and the dataset builder do; ``plan`` is their planner's report);
    ``recipe.stations_from`` is then not consulted. A mobile recipe takes ``trajectory`` (and the
    ``walk`` report that planned it) instead, chosen by ``choose_trajectory`` when not given, and
    refuses a walk over its pulse budget (``ScanRecipe.check_walk``).
    """
    check_site(scene, recipe)
    if scanner is None or not fits(scanner, recipe):
        scanner = place_scanner(scene, recipe)
    if recipe.mobile is not None:
        if trajectory is None:
            trajectory, walk = choose_trajectory(scene, recipe)
        recipe.check_walk(trajectory)  # the walk's pulse budget, before any scanning
        return Survey(scene=scene, scanner=scanner, recipe=recipe, stations=(), trajectory=trajectory, walk=walk)
    if stations is None:
        stations, plan = choose_stations(scene, recipe)
    if not stations:
        raise StationError(f"{scene.source}: an empty station list was given; pass at least one station")
    return Survey(scene=scene, scanner=scanner, recipe=recipe, stations=tuple(stations), plan=plan)


def run_survey(survey: Survey, *, on_pulses: Callable[[int], None] | None = None,
               reuse_buffers: bool = False) -> Iterator[PointCloud]:
    """Stream the merged, labelled cloud of all stations (raw: not yet filtered or checked).

    on_pulses(n) is called after each chunk with the number of pulses it covered (progress).
    reuse_buffers: chunks are overwritten by the next one (see VirtualScanner.scan_station).
    """
    if survey.trajectory is not None:
        yield from _run_mobile(survey, on_pulses=on_pulses, reuse_buffers=reuse_buffers)
        return
    duration = survey.recipe.settings.duration_s()
    clock = survey.scanner.clock
    for index, station in enumerate(survey.stations):
        yield from clock.timed("scan", survey.scanner.scan_station(station, survey.recipe, time0_s=index * duration,
                                                                   on_pulses=on_pulses, reuse_buffers=reuse_buffers))


def _run_mobile(survey: Survey, *, on_pulses: Callable[[int], None] | None,
                reuse_buffers: bool) -> Iterator[PointCloud]:
    """The mobile scan's points: pass by pass, each mount's lidar in turn, drift applied."""
    from bimscan.survey.drift import drift_track

    recipe, trajectory = survey.recipe, survey.trajectory
    drift = None if recipe.mobile.drift.is_off else drift_track(trajectory, recipe.mobile.drift, recipe.seed)
    clock = survey.scanner.clock
    for pass_id, part in enumerate(trajectory.pass_slices()):
        for mount_index in range(len(recipe.mobile.platform.mounts)):
            yield from clock.timed("scan", survey.scanner.scan_pass(trajectory, part, pass_id, mount_index, recipe,
                                                                    drift=drift, on_pulses=on_pulses,
                                                                    reuse_buffers=reuse_buffers))


def probe_points_per_pulse(scene: BimScene, recipe: ScanRecipe, stations: tuple[Station, ...], *,
                           lines: int = 120, pulses_per_line: int = 120) -> float:
    """Points a pulse of the tripod ``recipe`` gives in ``scene`` from ``stations``, measured by
    scanning a thinned copy of its pattern: the same scanner, elevation window, head turn and sensor
    effects, with at most ``lines`` mirror lines of at most ``pulses_per_line`` pulses per station
    (about 15,000 pulses instead of up to millions). Pulses that hit nothing (open sky, out of
    range) give no point, extra echoes (``returns = "all"``) give more, as in the scan. For size
    estimates before a build: a thinned pattern samples the same directions evenly, so its share
    of hits is the full pattern's within a few per cent."""
    settings = recipe.settings
    low, high = settings.window(recipe.scanner)
    line_pulses = settings.pulse_freq_hz / settings.scan_freq_hz * (high - low) / recipe.scanner.mirror_sweep_deg
    n_lines = settings.scan_freq_hz * settings.duration_s()
    # (the head turns at most as fast as any head can: past that, more lines than ``lines``)
    head_deg_per_s = min(settings.head_deg_per_s * max(1.0, n_lines / lines), MAX_HEAD_DEG_PER_S)
    thinned = dataclasses.replace(settings,
                                  pulse_freq_hz=settings.pulse_freq_hz * min(1.0, pulses_per_line / line_pulses),
                                  head_deg_per_s=head_deg_per_s)
    survey = prepare_survey(scene, recipe.with_fields(settings=thinned, strict=False, mobile=None), stations=stations)
    points = 0
    for chunk in run_survey(survey, reuse_buffers=True):
        points += int(np.isfinite(chunk.xyz).all(axis=1).sum())
    return points / max(survey.pulses(), 1)


def cloud_origin(scene: BimScene) -> tuple[float, float, float]:
    """Local origin for the writers: the model's lower corner in whole metres."""
    lo, _ = scene.mesh.bounds()
    return tuple(float(math.floor(v)) for v in lo)  # type: ignore[return-value]


def survey_metadata(survey: Survey) -> dict[str, Any]:
    """What a cloud file records about how it was made (JSON-able): the recipe, the source, the
    stations and the device warnings."""
    scene = survey.scene
    metadata = survey.recipe.to_json() | {
        "software": f"bimscan {__version__}",
        "source": {"file": Path(scene.source).name, "sha256": scene.file_sha256, "schema": scene.schema},
        "stations": [dataclasses.asdict(s) for s in survey.stations],
        "device_warnings": list(survey.recipe.warnings),
        "site_state": None if scene.site is None else scene.site.to_json(),
    }
    if survey.scanner.deviations is not None:
        metadata["as_built"] = survey.scanner.deviations.to_json(survey.recipe.sensor)
    if survey.trajectory is not None:
        trajectory = survey.trajectory
        metadata["trajectory"] = {"passes": trajectory.n_passes, "samples": len(trajectory.t),
                                  "length_m": round(trajectory.length_m(), 6),
                                  "duration_s": round(trajectory.duration_s(), 6),
                                  "loop_closures_s": [round(float(t), 6) for t in trajectory.closures]}
        if isinstance(survey.walk, FlightReport):
            metadata["trajectory"]["flight"] = survey.walk.to_json()
        elif survey.walk is not None:
            metadata["trajectory"]["rooms"] = list(survey.walk.rooms)
    return metadata


def cloud_header(survey: Survey, *, extra_metadata: dict[str, Any] | None = None) -> CloudHeader:
    """The header every writer stores with the survey's cloud (scheme, components, stations, metadata)."""
    scene = survey.scene
    return CloudHeader(scheme=scene.scheme, components=scene.components, stations=survey.stations,
                       origin=cloud_origin(scene), metadata=survey_metadata(survey) | (extra_metadata or {}))

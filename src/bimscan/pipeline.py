"""The pipeline composed: IFC -> labelled scene -> site as scanned -> planned survey -> streamed,
checked cloud file; and IFC -> survey plan folder (``plan_model``, ``bimscan plan``).

This thin layer joins the stages for the CLI and for the dataset builder; each stage stays
usable alone (``load_ifc``, ``label_model``, ``dress_scene``, ``VirtualScanner``,
``prepare_survey``, ``run_survey``, ``open_cloud_writer``). ``scan_model`` is the whole of
``bimscan scan``.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bimscan.errors import ConfigError, InputFileError, OutputError, StationError
from bimscan.files import remove_output
from bimscan.process.checks import check_semantics, filter_invalid
from bimscan.process.summary import CloudSummary
from bimscan.progress import StageClock, progress_bar, step_line
from bimscan.survey.recipe import AUTO_STATIONS, ScanRecipe
from bimscan.site import DressTimings, dress_scene_timed
from bimscan.survey.mobile import AUTO_TRAJECTORY
from bimscan.survey.stations import PlanReport
from bimscan.survey.trajectory import Trajectory, read_trajectory, trajectory_path, write_trajectory
from bimscan.survey.flight import FlightReport
from bimscan.survey.walk import WalkReport
from bimscan.survey.survey import Survey, cloud_header, prepare_survey, run_survey
from bimscan.types import BimScene, BuildDates, LabelScheme, PointCloud, Station

if TYPE_CHECKING:
    from bimscan.survey.planning.config import PlanConfig
    from bimscan.survey.planning.plan import PlanEvaluation, SurveyPlan


@dataclass(frozen=True)
class ScanResult:
    """What ``scan_survey`` wrote: the file, its point count, the survey, running totals, time
    (``seconds``: scanning and writing; ``steps``: seconds per step of ``scan_model``)."""

    path: Path
    points: int
    survey: Survey
    summary: CloudSummary
    seconds: float
    steps: Mapping[str, float] = field(default_factory=dict)


def load_label_scheme(source: str | Path | LabelScheme | None = None) -> LabelScheme:
    """A label scheme (None: spc5; a built-in name, a TOML file, or one already loaded) whose rules
    name only IFC classes that some supported schema knows, or bimscan's own site classes
    (``Clutter.Chair``, ``Temporary``, ...); a misspelt class is a SchemeError."""
    from bimscan.ifc.schema import known_classes
    from bimscan.semantics import check_rule_classes, load_scheme
    from bimscan.site import site_class_names

    scheme = source if isinstance(source, LabelScheme) else load_scheme(source)
    check_rule_classes(scheme, known_classes() | site_class_names())
    return scheme


def load_scene(path: str | Path, *, scheme: str | Path | LabelScheme | None = None, use_cache: bool = True,
               threads: int | None = None, strict: bool = False, length_unit: str | None = None) -> BimScene:
    """IFC file -> labelled scene: stage 1 (``load_ifc``) then stage 3 (``label_model``).

    The scheme is checked before the (slow) parse. ``strict`` and ``length_unit``: see ``load_ifc``;
    the scene's ``report`` and ``failed`` say what loading repaired, assumed, found wrong or lost.
    """
    from bimscan.ifc.load import load_ifc
    from bimscan.semantics import label_model

    label_scheme = load_label_scheme(scheme)
    model = load_ifc(path, use_cache=use_cache, threads=threads, strict=strict, length_unit=length_unit)
    return label_model(model, label_scheme)


def build_site(scene: BimScene, recipe: ScanRecipe, *, keep_clear: Sequence[Station] = ()) -> BimScene:
    """The scene as the recipe's site model has it when scanned (stage, clutter; ``bimscan.site``).

    With ``stage.at`` the model's work schedule is read (ConfigError when it links no element to
    a dated task). ``keep_clear``: stations whose spots clutter keeps clear of (stations given in a
    file). A bare site model returns ``scene``.
    """
    return build_site_timed(scene, recipe, keep_clear=keep_clear)[0]


def build_site_timed(scene: BimScene, recipe: ScanRecipe, *, keep_clear: Sequence[Station] = (),
                     progress: bool = False) -> tuple[BimScene, DressTimings]:
    """``build_site`` and its ``site.DressTimings`` (with a progress bar over the rooms when ``progress``)."""
    site = recipe.site
    if site.is_bare:
        return scene, DressTimings()
    spots = tuple((s.position[0], s.position[1], s.floor_z if s.floor_z is not None else
                   s.position[2] - recipe.scanner.instrument_height_m) for s in keep_clear)
    return dress_scene_timed(scene, site, seed=recipe.seed, schedule=read_site_schedule(scene, recipe),
                             keep_clear=spots, threads=recipe.threads, progress=progress)


def read_site_schedule(scene: BimScene, recipe: ScanRecipe) -> dict[str, BuildDates] | None:
    """The model's work schedule when the recipe's stage names a date (``--at``), else None.
    ConfigError when the model links no element to a dated task."""
    at = recipe.site.stage.at
    if at is None:
        return None
    from bimscan.ifc.schedule import read_schedule

    schedule = read_schedule(scene.source)
    if not schedule:
        raise ConfigError(f"{scene.source}: --at {at}: the model links no element to a dated task "
                          "(IfcTask with task times, through IfcRelAssignsToProcess or IfcRelAssignsToProduct); "
                          "leave --at out or add a work schedule to the model")
    return schedule


@dataclass(frozen=True)
class SiteAndStations:
    """A scene dressed as its recipe's site, with the stations chosen on it (``site_and_stations``)."""

    scene: BimScene
    stations: tuple[Station, ...]
    plan: PlanReport | None
    timings: DressTimings
    trajectory: Trajectory | None = None
    walk: WalkReport | FlightReport | None = None


def site_and_stations(scene: BimScene, recipe: ScanRecipe, *, progress: bool = False) -> SiteAndStations:
    """The scene dressed as the recipe's site model has it, and its stations, every check first.

    The stations are chosen on the scene as loaded (a file read and its stations placed, or,
    before a dressing, the check that a tripod can stand somewhere: a model where none can fails
    here, in seconds), and the work schedule is read before any dressing. Then the scene is
    dressed, a file's stations kept clear of clutter, and the stations are chosen again on the
    dressed scene: planned anew (the plan sees the clutter; dressing keeps a tripod spot clear in
    every room) or the file's read and checked there. A file's stations are checked before the
    dressing too, unless the stage leaves elements out: then they are judged only on the scene as
    scanned, as ``bimscan plan`` chose them there (a spot in a doorway is free once the stage leaves
    the door out). A bare site model dresses nothing and chooses once.
    """
    from bimscan.survey.survey import choose_stations, choose_trajectory, require_tripod_spots

    if recipe.mobile is not None:  # a walk instead of stations, planned (or checked) on the dressed scene
        if recipe.mobile.trajectory_from == AUTO_TRAJECTORY and not recipe.mobile.platform.flies:
            require_tripod_spots(scene, recipe)  # the walk goes where a tripod plan would: fail in seconds
        dressed, timings = (scene, DressTimings()) if recipe.site.is_bare else build_site_timed(scene, recipe,
                                                                                              progress=progress)
        with step_line("planning the flight" if recipe.mobile.platform.flies else "planning the walk", enabled=progress):
            trajectory, walk = choose_trajectory(dressed, recipe)
        return SiteAndStations(scene=dressed, stations=(), plan=None, timings=timings, trajectory=trajectory, walk=walk)
    from_file = recipe.stations_from != AUTO_STATIONS
    stations: tuple[Station, ...] = ()
    if recipe.site.is_bare or from_file:
        with step_line("checking stations" if from_file else "planning stations", enabled=progress):
            # checked now unless the stage leaves elements out: a station is judged on the scene as scanned
            stations, plan = choose_stations(scene, recipe, check=recipe.site.stage.is_bare)
        if recipe.site.is_bare:
            return SiteAndStations(scene=scene, stations=stations, plan=plan, timings=DressTimings())
    else:
        require_tripod_spots(scene, recipe)  # a model where no tripod can stand fails before the dressing
    dressed, timings = build_site_timed(scene, recipe, keep_clear=stations, progress=progress)
    with step_line("checking stations" if from_file else "planning stations", enabled=progress):
        stations, plan = choose_stations(dressed, recipe)
    return SiteAndStations(scene=dressed, stations=stations, plan=plan, timings=timings)


def furnish_model(model: str | Path, out: str | Path, recipe: ScanRecipe, *,
                  scheme: str | Path | LabelScheme | None = None, overwrite: bool = False) -> BimScene:
    """Write a copy of the IFC ``model`` dressed as the recipe's site (``bimscan furnish``): the
    placed objects as IfcFurniture / IfcBuildingElementProxy, the elements the stage leaves out
    removed. An existing ``out`` is replaced only with ``overwrite``, and only when bimscan wrote it.
    Returns the dressed scene."""
    from bimscan.ifc.furnish import FurnishObject, check_furnished_output, write_furnished
    from bimscan.site import SITE_CLASSES

    check_furnished_output(out, source=model, overwrite=overwrite)  # before the (slow) parse and dressing
    scene = load_scene(model, scheme=scheme, threads=recipe.threads or None)
    dressed = build_site(scene, recipe)
    table, mesh = dressed.components, dressed.mesh
    order = np.argsort(mesh.face_component, kind="stable")
    starts = np.searchsorted(mesh.face_component[order], np.arange(len(table) + 1))
    objects = []
    for c in range(len(table)):
        cls = str(table.ifc_class[c])
        if cls not in SITE_CLASSES:
            continue
        faces = mesh.faces[order[starts[c]:starts[c + 1]]]
        used, inverse = np.unique(faces, return_inverse=True)
        objects.append(FurnishObject(global_id=str(table.global_id[c]), ifc_classes=SITE_CLASSES[cls].ifc_classes,
                                     object_type=cls, name=str(table.name[c]), storey=str(table.storey[c]),
                                     vertices=mesh.vertices[used], faces=inverse.reshape(-1, 3).astype(np.int32)))
    removed = set(scene.components.global_id.tolist()) - set(table.global_id.tolist())
    write_furnished(model, out, objects, removed, overwrite=overwrite)
    return dressed


def stream_checked(survey: Survey, *, summary: CloudSummary, on_pulses: Callable[[int], None] | None = None,
                   clock: StageClock | None = None) -> Iterator[PointCloud]:
    """The survey's merged cloud as filtered, semantically checked chunks (stage 6 on stage 4).

    Every chunk has its invalid points dropped (counted in ``summary.dropped_invalid``) and is
    checked against the component table (``SemanticError`` on a contradiction) before it is
    yielded; ``summary`` accumulates counts, extents and histograms of what is yielded. A chunk
    is valid until the next one is requested (the scanner reuses its buffers): write it out or
    copy it first. ``clock``: gets the checks' time as its "checks" step.
    """
    for chunk in run_survey(survey, on_pulses=on_pulses, reuse_buffers=True):
        start = time.perf_counter()
        chunk, dropped = filter_invalid(chunk)
        summary.dropped_invalid += dropped
        check_semantics(chunk, survey.scene.components)
        summary.add(chunk)
        if clock is not None:
            clock.add("checks", time.perf_counter() - start)
        yield chunk


def scan_survey(survey: Survey, out: str | Path, *, overwrite: bool = False, progress: bool = True,
                extra_metadata: dict[str, Any] | None = None) -> ScanResult:
    """Scan every station and stream the merged cloud to ``out`` (format by suffix), checked.

    Every chunk is filtered for invalid points and checked for semantic consistency before it is
    written; the file appears only when complete (the writer renames a temporary file).
    """
    from bimscan.io import open_cloud_writer

    start = time.perf_counter()
    header = cloud_header(survey, extra_metadata=extra_metadata)
    summary = CloudSummary()
    writer = open_cloud_writer(out, header=header, overwrite=overwrite)
    finished = False
    try:
        with progress_bar(total=survey.pulses(), desc="scanning", unit="pulse", enabled=progress) as bar:
            for chunk in stream_checked(survey, summary=summary, on_pulses=bar.update):
                writer.write(chunk)
        if summary.points == 0:
            raise StationError(f"the scan of {survey.scene.source} has no point: {_blind_survey(survey)}")
        written = writer.close()
        finished = True
    finally:
        if not finished:
            writer.abort()  # never leave a half-written cloud, whatever stopped us (Ctrl-C included)
    return ScanResult(path=Path(written.path), points=summary.points, survey=survey, summary=summary,
                      seconds=time.perf_counter() - start)


def _blind_survey(survey: Survey) -> str:
    """Why a survey saw nothing, naming the device that scanned and its range, and what to check."""
    mobile = survey.recipe.mobile
    if mobile is not None:
        lidar, mounts = mobile.lidar, len(mobile.platform.mounts)
        return (f"no pose of the walk sees a surface between {lidar.min_range_m:g} and {lidar.max_range_m:g} m (the "
                f"range of {mounts} x {lidar.name} on the {mobile.platform.name} platform); check that the trajectory "
                "runs through the model, and the lidar's range")
    scanner = survey.recipe.scanner
    return (f"no station sees a surface between {scanner.min_range_m:g} and {scanner.max_range_m:g} m (the range of "
            f"{scanner.name}); check the stations and the scanner's range")


def scan_model(model: str | Path, out: str | Path, recipe: ScanRecipe, *,
               scheme: str | Path | LabelScheme | None = None, overwrite: bool = False, progress: bool = True,
               length_unit: str | None = None, warn: Callable[[str], None] | None = None) -> ScanResult:
    """IFC file -> labelled multi-station cloud file: the whole of ``bimscan scan``.

    Output and scheme errors come before the (slow) parse. ``recipe.strict`` also refuses an IFC
    file that needed repairs or lost an element; ``length_unit`` overrides the model's. ``warn``
    receives one line per thing a user should know (settings outside the device's limits, what
    loading the model repaired, assumed or lost, rooms left without a station).
    """
    from bimscan.ifc.summary import report_lines
    from bimscan.io import check_cloud_output, check_free_space

    check_cloud_output(out, overwrite=overwrite)
    check_walk_sidecar(out, overwrite=overwrite)  # a tripod scan, too, must not leave an earlier scan's walk beside it
    if recipe.mobile is not None:
        check_mobile_output(out, overwrite=overwrite)
        if recipe.mobile.trajectory_from != AUTO_TRAJECTORY:  # a bad file or budget fails now, before the parse
            recipe.check_walk(read_trajectory(recipe.mobile.trajectory_from), source=recipe.mobile.trajectory_from)
    say = warn or (lambda line: None)
    for warning in recipe.warnings + recipe.site.warnings:
        say(warning)
    start = time.perf_counter()
    scene = load_scene(model, scheme=scheme, threads=recipe.threads or None, strict=recipe.strict,
                       length_unit=length_unit)
    for line in report_lines(scene):
        say(line)
    loaded = time.perf_counter()
    chosen = site_and_stations(scene, recipe, progress=progress)
    survey = prepare_survey(chosen.scene, recipe, stations=chosen.stations or None, plan=chosen.plan,
                            trajectory=chosen.trajectory, walk=chosen.walk)
    prepared = time.perf_counter()
    if survey.plan is not None and survey.plan.rooms_without_station:
        say(survey.plan.rooms_without_station_line())
    check_free_space(out, points=survey.pulses())
    result = scan_survey(survey, out, overwrite=overwrite, progress=progress)
    if survey.trajectory is not None:
        write_trajectory(trajectory_path(result.path), survey.trajectory)
    else:  # the walk of the mobile scan this one replaced is not this cloud's (render would draw it over it)
        remove_output(trajectory_path(result.path))
    dressing = chosen.timings.total_s
    steps = {"load": loaded - start, "dressing": dressing, "stations": prepared - loaded - dressing,
             "scan and write": result.seconds}
    return dataclasses.replace(result, steps=steps)


def check_mobile_output(out: str | Path, *, overwrite: bool) -> None:
    """Raise before any work when a mobile scan cannot be written to ``out``: E57 stores one pose per
    scan (a mobile scan's per-point beam origins and rings would be lost), and the trajectory
    beside the cloud must not replace a file unless asked, nor ever anything bimscan did not write."""
    from bimscan.io import check_cloud_output
    from bimscan.io.e57 import MOBILE_COLUMNS

    check_cloud_output(out, overwrite=overwrite, columns=tuple(MOBILE_COLUMNS))
    check_walk_sidecar(out, overwrite=overwrite)


def check_walk_sidecar(out: str | Path, *, overwrite: bool) -> None:
    """Raise before any work when ``OUT.trajectory.csv`` is there and may not go: a mobile scan
    replaces it with its walk, a tripod scan removes it (it is the walk of an earlier scan at OUT),
    so it must be asked for (``overwrite``) and be bimscan's (``check_replaceable``)."""
    from bimscan.files import check_replaceable

    beside = trajectory_path(out)
    if os.path.lexists(beside):
        if not overwrite:
            raise OutputError(f"{beside} exists (the trajectory of a mobile scan at {out}); pass --overwrite to "
                              "replace that scan and its walk, or choose another OUT")
        check_replaceable(beside)


@dataclass(frozen=True)
class PlanRun:
    """What ``plan_model`` did: the plan (chosen or checked), its evaluation on the plan's own
    estimate and, with a cloud, on the scan; the files written into OUT, seconds per step, and the
    quartiles of the scan's density over the estimate's (surface patches with an estimate of at
    least 10 % of the asked density; None without a cloud)."""

    plan: SurveyPlan
    evaluation: PlanEvaluation
    scan: PlanEvaluation | None
    files: list[str]
    steps: dict[str, float]
    density_ratio: tuple[float, float, float] | None = None


def plan_model(model: str | Path, out: str | Path, recipe: ScanRecipe, config: PlanConfig, *, check: str | None = None,
               cloud: str | Path | None = None, scheme: str | Path | LabelScheme | None = None,
               overwrite: bool = False, progress: bool = True, length_unit: str | None = None,
               warn: Callable[[str], None] | None = None) -> PlanRun:
    """IFC file -> survey plan folder: the whole of ``bimscan plan``.

    Without ``check``: the fewest stations reaching ``config`` (a ``survey.planning.PlanConfig``)
    on the scene dressed as ``recipe.site`` has it. With ``check`` (a station file, or "auto" for
    the per-room plan of ``--stations auto``): those stations' figures, on the scene dressed as
    ``bimscan scan`` dresses it for them; with ``cloud`` too (a bimscan scan from those
    stations), the coverage measured on the scan. Output and input errors come before the parse;
    so does the refusal of a search setting when checking (``PlanConfig.check_for_checking``).
    ``warn`` receives one line per thing a user should know, as ``scan_model`` gives them (what
    loading the model repaired, assumed or lost first).
    """
    from bimscan.files import check_input_file
    from bimscan.ifc.summary import report_lines
    from bimscan.io import iter_cloud_chunks, read_cloud_header
    from bimscan.render.survey_plan import draw_plan_pictures
    from bimscan.survey.planning.measure import patch_density, patch_matrix, points_per_sample
    from bimscan.survey.planning.plan import check_survey, evaluate, plan_survey, prepare_space
    from bimscan.survey.planning.report import check_plan_output, plan_summary, write_plan_folder

    say = warn or (lambda line: None)
    out = Path(out)
    check_plan_output(out, overwrite=overwrite)
    if recipe.mobile is not None:
        raise ConfigError("a survey plan is made for tripod stations; leave --platform out")
    if check is not None:
        config.check_for_checking()
    header = None
    if cloud is not None:
        if check is None:
            raise ConfigError("--cloud measures the scan of a checked plan; give its stations with "
                              "--check STATIONS.csv")
        header = read_cloud_header(check_input_file(cloud, what="a point cloud file or folder", folders=True))
        if header is None or not header.stations:
            raise InputFileError(f"{cloud}: not a cloud bimscan scanned (no stations stored with it); measure a "
                                 "cloud written by 'bimscan scan'")
    if check is not None and check != AUTO_STATIONS:
        check_input_file(check, what="a station file")
    for warning in recipe.warnings + recipe.site.warnings:
        say(warning)
    steps: dict[str, float] = {}
    start = time.perf_counter()
    scene = load_scene(model, scheme=scheme, threads=recipe.threads or None, strict=recipe.strict,
                       length_unit=length_unit)
    for line in report_lines(scene):  # what loading repaired, assumed or lost, as 'bimscan scan' says it
        say(line)
    steps["load"] = time.perf_counter() - start
    start = time.perf_counter()
    if check is None:
        if not recipe.site.is_bare:
            from bimscan.survey.survey import require_tripod_spots

            require_tripod_spots(scene, recipe)  # a model where no tripod can stand fails before the dressing
        dressed, _ = build_site_timed(scene, recipe, progress=progress)
        given: tuple[Station, ...] = ()
    else:
        chosen = site_and_stations(scene, recipe.with_fields(stations_from=check), progress=progress)
        dressed, given = chosen.scene, chosen.stations
        if header is not None:
            _check_cloud_stations(cloud, header.stations, given)
    steps["site and stations"] = time.perf_counter() - start
    start = time.perf_counter()
    space = prepare_space(dressed, recipe.scanner, recipe.settings, config, given=given, threads=recipe.threads,
                          progress=progress)
    steps |= space.seconds
    start = time.perf_counter()
    plan = check_survey(space, given) if check is not None else plan_survey(space, progress=progress)
    steps["choose"] = time.perf_counter() - start
    evaluation = evaluate(plan)
    scan_evaluation, ratio = None, None
    if cloud is not None:
        start = time.perf_counter()
        # the cloud's stations are the checked ones, in order (checked above): the candidates after the spots
        columns = {s.id: space.n_spots + i for i, s in enumerate(header.stations)}
        with step_line("measuring the scan", enabled=progress):
            counts = points_per_sample(iter_cloud_chunks(cloud), space.samples, space.visibility, columns,
                                       counted=space.klass >= 0, threads=recipe.threads or -1)
            patches = patch_matrix(space.samples)
            measured = patch_density(counts, space.samples, per_area=True, patches=patches)
            estimate = patch_density(evaluation.density, space.samples, per_area=False, patches=patches)
        scan_evaluation = evaluate(plan, density=measured)
        useful = space.visibility.reachable & (estimate >= 0.1 * config.density_pts_m2)
        if useful.any():
            q = np.percentile(measured[useful] / estimate[useful], [25, 50, 75])
            ratio = (float(q[0]), float(q[1]), float(q[2]))
        steps["measure"] = time.perf_counter() - start
    if evaluation.parts > 1:
        why = (f"the candidate spots themselves form {evaluation.spot_parts} parts no station can join"
               if evaluation.parts == evaluation.spot_parts else "a checked plan")
        say(f"the registration graph of the {len(plan.stations)} stations falls into {evaluation.parts} parts that "
            f"share too little surface (--overlap {config.overlap:g}; {why}): closed doors between rooms? plan and "
            "scan with --stage-exclude IfcDoor (doors open); storeys or wings no spot sees both of? register them "
            "with targets")
    start = time.perf_counter()
    summary = plan_summary(plan, evaluation, scan_evaluation, recipe, mode="check" if check else "plan",
                           density_ratio=ratio)
    title = f"{Path(scene.source).name}: {len(plan.stations)} stations"
    files = write_plan_folder(out, plan, evaluation, summary=summary, scan=scan_evaluation, overwrite=overwrite,
                              pictures=lambda folder: draw_plan_pictures(plan, evaluation, folder, title=title))
    steps["write"] = time.perf_counter() - start
    return PlanRun(plan=plan, evaluation=evaluation, scan=scan_evaluation, files=files, steps=steps,
                   density_ratio=ratio)


def _check_cloud_stations(cloud: str | Path, stored: Sequence[Station], given: Sequence[Station]) -> None:
    """StationError when the cloud was not scanned from the checked stations (count or a position
    more than 1 cm off)."""
    if len(stored) != len(given) or any(
            np.linalg.norm(np.subtract(a.position, b.position)) > 0.01 for a, b in zip(stored, given)):
        raise StationError(f"{cloud} was scanned from {len(stored)} stations that are not the {len(given)} checked "
                           "ones; give the station file the cloud was scanned with to --check")


# -- scan against model ----------------------------------------------------------------------------

def _check_report_folder(out: Path, *, kind: str, overwrite: bool) -> None:
    """OutputError before any slow work when ``out`` cannot be written: what is there is not a folder
    of ``kind`` bimscan wrote (said first, naming what it holds), or the shared output rules
    (``io._writer.check_output_path``: parent, permissions, ``--overwrite``) refuse it."""
    from bimscan.files import check_replaceable
    from bimscan.io._writer import check_output_path

    if out.exists() or out.is_symlink():
        check_replaceable(out, kind=kind)
    check_output_path(out, overwrite=overwrite, kind=kind)


@dataclass(frozen=True)
class AlignRun:
    """What ``align_model`` wrote: the alignment, the folder and its files, seconds per step."""

    alignment: Any
    out: Path
    files: tuple[str, ...]
    steps: Mapping[str, float]


def align_model(model: str | Path, scan: str | Path, out: str | Path, config: Any, *, init: str | Path | None = None,
                aligned_format: str | None = None, overwrite: bool = False, length_unit: str | None = None,
                log: Callable[[str], None] | None = None) -> AlignRun:
    """``bimscan align``: put ``scan`` into ``model``'s frame (``bimscan.compare.align``) and write the
    alignment folder ``out`` (``bimscan.compare.report``); ``init``: a rough matrix or point pairs
    file to start from; ``aligned_format``: also write the moved scan in this format ("laz", ...)."""
    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.report import (
        ALIGN_KIND, ALIGNED_STEM, TRANSFORM_JSON, TRANSFORM_TEXT, StagedFolder, format_matrix,
        read_transform, transform_document, write_json,
    )
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.ifc.georef import read_map_conversion
    from bimscan.io import check_input_path, count_points

    out, scan = Path(out), check_input_path(scan)
    _check_report_folder(out, kind="alignment", overwrite=overwrite)
    start = read_transform(init, pairs=True) if init is not None else None
    total = count_points(scan)
    steps: dict[str, float] = {}
    clock = time.perf_counter()
    scene = load_scene(model, length_unit=length_unit)
    surfaces = ModelSurfaces(scene.mesh)
    steps["model"] = time.perf_counter() - clock
    clock = time.perf_counter()
    with progress_bar(total=total, desc="align: read", unit="pt") as bar:
        seen = [0]

        def advance(points: int) -> None:
            bar.update(points - seen[0])
            seen[0] = points

        digest = digest_scan(scan, voxel_m=config.voxel_m, progress=advance)
    steps["read"] = time.perf_counter() - clock
    with step_line("align: search and fit"):
        alignment = align_digest(digest, surfaces, config, init=start, georeference=read_map_conversion(model))
    steps |= alignment.steps
    with StagedFolder(out, kind="alignment") as staged:
        document = transform_document(alignment.matrix, kind=ALIGN_KIND, model=Path(model), scan=scan,
                                      alignment=alignment.to_json() | {"settings": config.to_json()})
        write_json(staged.path / TRANSFORM_JSON, document)
        (staged.path / TRANSFORM_TEXT).write_text(format_matrix(alignment.matrix), encoding="utf-8")
        files = [TRANSFORM_JSON, TRANSFORM_TEXT]
        if aligned_format is not None:
            clock = time.perf_counter()
            name = f"{ALIGNED_STEM}.{aligned_format}" if aligned_format != "npy" else ALIGNED_STEM
            write_moved_cloud(scan, staged.path / name, alignment.matrix, origin=surfaces.centre, total=total,
                              metadata={"alignment": alignment.to_json()})
            files.append(name)
            steps["write"] = time.perf_counter() - clock
    return AlignRun(alignment=alignment, out=out, files=tuple(files), steps=steps)


def write_moved_cloud(scan: Path, out: Path, matrix: np.ndarray, *, origin: np.ndarray, total: int,
                      metadata: Mapping[str, Any]) -> None:
    """The scan's points (every column it has; beam origins moved too) moved by ``matrix`` into ``out``."""
    from bimscan.compare.planes import apply
    from bimscan.io import iter_cloud_chunks, open_cloud_writer, read_cloud_header
    from bimscan.semantics import DEFAULT_SCHEME
    from bimscan.types import CloudHeader

    stored = read_cloud_header(scan)
    header = CloudHeader(
        scheme=stored.scheme if stored is not None else load_label_scheme(DEFAULT_SCHEME),
        components=None if stored is None else stored.components,
        stations=() if stored is None else tuple(
            dataclasses.replace(s, position=tuple(float(v) for v in apply(matrix, np.array([s.position]))[0]))
            for s in stored.stations),
        origin=tuple(float(v) for v in np.round(origin)),  # type: ignore[arg-type]
        metadata={**({} if stored is None else {"source_metadata": dict(stored.metadata)}), **metadata,
                  "moved_from": str(scan)})
    with progress_bar(total=total, desc="write", unit="pt") as bar, open_cloud_writer(out, header=header) as writer:
        for chunk in iter_cloud_chunks(scan, labels=stored is not None):
            moved = dataclasses.replace(
                chunk, xyz=apply(matrix, chunk.xyz),
                sensor_xyz=None if chunk.sensor_xyz is None else apply(matrix, chunk.sensor_xyz))
            writer.write(moved)
            bar.update(len(chunk))


@dataclass(frozen=True)
class ProgressRun:
    """What ``compare_model`` wrote: the comparison, the alignment (with ``align``), the summary,
    the folder and its files, seconds per step."""

    result: Any
    alignment: Any
    summary: Mapping[str, Any]
    out: Path
    files: tuple[str, ...]
    steps: Mapping[str, float]


def compare_model(model: str | Path, scan: str | Path, out: str | Path, config: Any, *, align: Any = None,
                  transform: str | Path | None = None, at: str | None = None, checkpoint: str | Path | None = None,
                  stations: str | Path | None = None, points_format: str | None = "laz", overwrite: bool = False,
                  length_unit: str | None = None, log: Callable[[str], None] | None = None) -> ProgressRun:
    """``bimscan progress``: compare ``scan`` with ``model`` element by element
    (``bimscan.compare.progress``) and write the progress folder ``out`` (``bimscan.compare.report``).

    The scan's frame: ``align`` (an AlignConfig: align it first), or ``transform`` (a matrix file),
    or the model's. ``at``: judge against the work schedule on this ISO date. ``checkpoint``: a
    segmentation model whose Others points support no element. ``stations``: a station file (id,x,y,z
    in the scan's frame). ``points_format``: the per-point output's format (None: none).
    """
    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.progress import compare_scan, summary as progress_summary
    from bimscan.compare.report import (
        BCF_FILE, ELEMENTS_FILE, ELEMENT_COLUMNS, IFC_FILE, POINTS_STEM, PROGRESS_KIND, PSET_NAME, SUMMARY_FILE,
        TRANSFORM_JSON, TRANSFORM_TEXT, StagedFolder, bcf_topics, element_rows,
        CONTROL_RESIDUAL_M, control_document, format_matrix, pair_residuals_m, points_writer, property_values,
        read_pose, read_station_file, transform_document, write_json,
    )
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.files import csv_bytes, remove_path
    from bimscan.ifc.georef import read_map_conversion
    from bimscan.io import check_input_path

    out, scan, model = Path(out), check_input_path(scan), Path(model)
    _check_report_folder(out, kind="progress", overwrite=overwrite)
    if align is not None and transform is not None:
        raise ConfigError("--align and --transform both say where the scan lies; give one")
    matrix, pairs = read_pose(transform, pairs=True) if transform is not None else (np.eye(4), None)
    residuals = None if pairs is None else pair_residuals_m(pairs, matrix)
    control = None if residuals is None else control_document(Path(transform), residuals)  # type: ignore[arg-type]
    if residuals is not None and residuals.max() > CONTROL_RESIDUAL_M and log is not None:
        worst = int(np.argmax(residuals))
        log(f"{transform}: point pair {worst + 1} lies {residuals[worst] * 1000:.0f} mm from where the pose the pairs "
            f"agree on puts it (median {np.median(residuals) * 1000:.1f} mm); check that pair")
    given_stations = read_station_file(stations) if stations is not None else None
    steps: dict[str, float] = {}
    clock = time.perf_counter()
    scene = load_scene(model, length_unit=length_unit)
    surfaces = ModelSurfaces(scene.mesh)
    schedule = None
    if at is not None:
        from bimscan.ifc.schedule import read_schedule

        schedule = read_schedule(model)
        if not schedule:
            raise ConfigError(f"{model}: --at {at}: the model links no element to a dated task (IfcTask with task "
                              "times); leave --at out or add a work schedule to the model")
    steps["model"] = time.perf_counter() - clock
    alignment = None
    if align is not None:
        clock = time.perf_counter()
        with step_line("progress: align"):
            alignment = align_digest(digest_scan(scan, voxel_m=align.voxel_m), surfaces, align,
                                     georeference=read_map_conversion(model))
        matrix = alignment.matrix
        steps["align"] = time.perf_counter() - clock
    supports: SegmentationSupport | None = None
    with StagedFolder(out, kind="progress") as staged:
        if checkpoint is not None:
            clock = time.perf_counter()
            supports = SegmentationSupport(checkpoint, scan, staged.path, log=log)
            steps["segment"] = time.perf_counter() - clock
        writer = points_writer(staged.path, POINTS_STEM, points_format, scene=scene, origin=surfaces.centre,
                               matrix=matrix, scan=scan) if points_format is not None else None
        try:
            result = compare_scan(scene, scan, matrix=matrix, config=config, at=at, schedule=schedule,
                                  stations=given_stations, supports=supports,
                                  on_chunk=None if writer is None else writer.write, surfaces=surfaces, warn=log)
            files = [] if writer is None else [writer.close()]
            if checkpoint is not None:
                remove_path(staged.path / _LABELLED)
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
        steps |= result.steps
        clock = time.perf_counter()
        summary = progress_summary(result, scene)
        document = transform_document(matrix, kind=PROGRESS_KIND, model=model, scan=scan,
                                      alignment=None if alignment is None else alignment.to_json(), control=control)
        write_json(staged.path / TRANSFORM_JSON, document)
        (staged.path / TRANSFORM_TEXT).write_text(format_matrix(matrix), encoding="utf-8")
        (staged.path / ELEMENTS_FILE).write_bytes(csv_bytes(element_rows(result, scene), ELEMENT_COLUMNS))
        files += [TRANSFORM_JSON, TRANSFORM_TEXT, ELEMENTS_FILE]
        values = property_values(result, scene)
        if values:
            from bimscan.ifc.annotate import write_property_sets

            global_ids = {int(step): str(gid) for step, gid in zip(scene.components.step_id.tolist(),
                                                                   scene.components.global_id.tolist()) if step >= 0}
            write_property_sets(model, staged.path / IFC_FILE, values, pset_name=PSET_NAME, global_ids=global_ids)
            files.append(IFC_FILE)
        topics = bcf_topics(result, scene)
        if topics:
            from bimscan.io.bcf import write_bcf

            write_bcf(staged.path / BCF_FILE, topics, project_name=model.stem)
            files.append(BCF_FILE)
        from bimscan.render.progress import draw_progress_pictures

        storeys = sorted(((s.name, s.elevation_m) for s in scene.storeys), key=lambda s: s[1])
        status_of_sample = result.elements.status[result.samples.component]
        files += draw_progress_pictures(
            staged.path, title=f"{model.name} against {scan.name}", storeys=storeys, sample_xyz=result.samples.xyz,
            sample_normal_z=result.samples.normal[:, 2], sample_status=status_of_sample,
            view_origins=np.array([v.origin for v in result.views]).reshape(-1, 3), point_xyz=result.point_xyz,
            point_signed=result.point_signed, tolerance_m=config.default_tolerance_m)
        summary = {"kind": PROGRESS_KIND, "model": str(model), "scan": str(scan), "files": sorted(files),
                   **summary, **({} if supports is None else {"segmentation": supports.to_json()}),
                   **({} if control is None else {"control": control})}
        write_json(staged.path / SUMMARY_FILE, summary)
        files.append(SUMMARY_FILE)
        steps["write"] = time.perf_counter() - clock
    return ProgressRun(result=result, alignment=alignment, summary=summary, out=out, files=tuple(sorted(files)),
                       steps=steps)


_LABELLED = "labels.laz"  # the segmentation model's labels of the scan, while the comparison runs


class SegmentationSupport:
    """Which points may support an element: those a segmentation model does not call Others (clutter,
    people, furniture: what stands in the building without being part of it). Reads the model's
    labelled copy of the scan chunk by chunk beside the comparison (the same points, the same order)."""

    def __init__(self, checkpoint: str | Path, scan: Path, work: Path, *, log: Callable[[str], None] | None) -> None:
        from bimscan.io import iter_cloud_chunks
        from bimscan.learn.predict import predict_cloud

        self.checkpoint = Path(checkpoint)
        self.labelled = work / _LABELLED
        result = predict_cloud(checkpoint, scan, self.labelled, warn=log)
        if "Others" not in result.class_names:
            raise ConfigError(f"{checkpoint}: the model's classes ({', '.join(result.class_names)}) have no Others "
                              "to leave out; give a model trained on the spc5 classes")
        self.others = result.class_names.index("Others")
        self._chunks = iter_cloud_chunks(self.labelled, chunk_points=2_000_000)
        self.points = self.left_out = 0

    def __call__(self, chunk: PointCloud, xyz: np.ndarray) -> np.ndarray:
        labels = next(self._chunks, None)
        if labels is None or len(labels) != len(chunk) or labels.label is None:
            raise OutputError(f"{self.labelled}: the labelled copy does not follow the scan's points; run again")
        keep = labels.label != self.others
        self.points += len(keep)
        self.left_out += int((~keep).sum())
        return keep

    def to_json(self) -> dict[str, Any]:
        return {"checkpoint": str(self.checkpoint), "others_share": round(self.left_out / max(self.points, 1), 6)}

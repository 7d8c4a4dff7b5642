"""The work of a build, run in worker processes: scene tasks and unit tasks.

A *scene task* parses a scene once (filling the on-disk geometry cache), dresses it as the site
its units scan (construction stage, clutter; ``pipeline.build_site``) and plans its stations on
that scene once (``scenes/<scene>[.<site>].stations.json``): every configuration of the scene
and site state scans from the same viewpoints, as in the paper; the dressed scene is kept beside
them (``scenes/<scene>.<site>.site.npz``). A *unit task* reads that dressed scene (or, when it
is missing, dresses the scene again: seeded, the same objects in the same places), scans the
survey with its recipe and streams the merged cloud through the post-processing (invalid points dropped and counted, semantic checks,
optional voxel subsampling) into every requested format at once, checks what was written, and
writes ``unit.json`` (reproducible) and ``timings.json`` (not: times, and the host and Ray node
that built it). The unit is built in a hidden staging folder and renamed into place when whole. Tasks are module-level functions so they
pickle by name; they return outcomes and never raise for a user error.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import shutil
import time
from collections.abc import Mapping
from concurrent.futures import BrokenExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from bimscan.dataset.executors import driver_alive, report_pulses, worker_node
from bimscan.dataset.layout import (
    FORMAT_FILES, STATIONS_FORMAT, STATIONS_VERSION, TIMINGS_NAME, TRAJECTORY_NAME, DatasetFolder, UnitRecord, read_json,
    read_site_scene, write_json, write_site_scene, write_unit_record,
)
from bimscan.dataset.plan import SceneJob, UnitJob
from bimscan.errors import BimscanError, DatasetError, SemanticError
from bimscan.files import file_sha256, replace_path
from bimscan.progress import StageClock
from bimscan.survey.recipe import AUTO_STATIONS
from bimscan.types import Station

if TYPE_CHECKING:
    from bimscan.io import CloudWriter, WrittenCloud
    from bimscan.process.summary import CloudSummary


@dataclass(frozen=True)
class SceneOutcome:
    scene: str
    error: str | None = None
    n_stations: int = 0
    parse_s: float = 0.0
    notes: tuple[str, ...] = ()
    site_tag: str = ""
    site_s: float = 0.0  # dressing the scene (stage, free floor, placement)
    placement_s: float = 0.0  # of which placing the objects (and cutting the tiles of lay-in fittings)
    site_rooms: int = 0
    points_per_pulse: float = 0.0  # measured on a thinned pattern from the stations (size estimate)
    probe_s: float = 0.0  # measuring it
    stations_s: float = 0.0  # planning (or checking) the stations, writing them and the dressed scene


@dataclass(frozen=True)
class UnitOutcome:
    unit: str
    status: str  # "done" or "failed"
    error: str | None = None
    points: int = 0
    files: dict[str, str] = field(default_factory=dict)  # format -> name in the unit folder
    load_s: float = 0.0
    seconds: float = 0.0
    site_s: float = 0.0
    node: str = ""  # where it was built: the host name, with the Ray node id's start on Ray ("host/3fa2c19b")


def task_error(error: BaseException) -> str:
    """One line for an exception that escaped a task (a crash, not a user error)."""
    if isinstance(error, BrokenExecutor):
        return "the worker process died (killed, or out of memory); run the build again to retry"
    text = " ".join(str(error).split())
    return f"{type(error).__name__}: {text}" if text else type(error).__name__


def _one_line(error: BaseException) -> str:
    if isinstance(error, BimscanError):
        return " ".join(str(error).split())
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full while writing {error.filename or 'the unit'}; free space and run the build again"
    return task_error(error)


def run_scene_job(job: SceneJob) -> SceneOutcome:
    """Parse the scene (filling the geometry cache), dress it, and plan or read its stations once."""
    from bimscan.ifc.summary import report_lines
    from bimscan.pipeline import load_scene, site_and_stations
    from bimscan.survey.survey import probe_points_per_pulse

    try:
        start = time.perf_counter()
        scene = load_scene(job.ifc, scheme=job.scheme, threads=job.recipe.threads, strict=job.recipe.strict,
                           length_unit=job.length_unit)
        parse_s = time.perf_counter() - start
        loading = tuple(report_lines(scene))  # what the IFC needed repaired or lost: said at every build
        path = Path(job.stations_file)
        site_path = Path(job.site_file) if job.site_file else None
        if path.is_file():
            try:
                stored = read_json(path)
                dressed = scene if site_path is None else read_site_scene(site_path, scene, job.stations_key)
                if stored.get("key") == job.stations_key and dressed is not None:
                    stations = tuple(Station.from_dict(s) for s in stored["stations"])
                    probe_start = time.perf_counter()
                    per_pulse = probe_points_per_pulse(dressed, job.recipe, stations)
                    return SceneOutcome(scene=job.scene, n_stations=len(stations), parse_s=parse_s,
                                        notes=loading + tuple(stored.get("notes", ())), site_tag=job.site_tag,
                                        points_per_pulse=per_pulse, probe_s=time.perf_counter() - probe_start)
            except (DatasetError, KeyError, TypeError, ValueError):
                pass  # damaged: plan again
        site_start = time.perf_counter()
        chosen = site_and_stations(scene, job.recipe)
        scene, stations, plan, timings = chosen.scene, chosen.stations, chosen.plan, chosen.timings
        if site_path is not None:
            write_site_scene(site_path, scene, job.stations_key)
        notes: list[str] = []
        if plan is not None and plan.rooms_without_station:
            notes.append(plan.rooms_without_station_line())
        write_json(path, {"format": STATIONS_FORMAT, "version": STATIONS_VERSION, "key": job.stations_key,
                          "scene": job.scene, "site": job.site_tag,
                          "stations": [dataclasses.asdict(s) for s in stations], "notes": notes})
        probe_start = time.perf_counter()
        per_pulse = probe_points_per_pulse(scene, job.recipe, stations)
        return SceneOutcome(scene=job.scene, n_stations=len(stations), parse_s=parse_s, notes=loading + tuple(notes),
                            site_tag=job.site_tag, site_s=timings.total_s,
                            placement_s=timings.placement_s + timings.cut_s, site_rooms=timings.rooms,
                            stations_s=probe_start - site_start - timings.total_s, points_per_pulse=per_pulse,
                            probe_s=time.perf_counter() - probe_start)
    except (BimscanError, OSError) as exc:
        return SceneOutcome(scene=job.scene, error=_one_line(exc), site_tag=job.site_tag)


def run_unit_job(job: UnitJob) -> UnitOutcome:
    """Scan one unit into a staging folder, check what was written, and move it into place."""
    from bimscan.io import open_cloud_writer
    from bimscan.ifc.summary import report_document
    from bimscan.pipeline import build_site, load_scene, stream_checked
    from bimscan.process.subsample import VoxelSubsampler
    from bimscan.process.summary import CloudSummary
    from bimscan.survey.survey import choose_trajectory, cloud_header, prepare_survey
    from bimscan.survey.trajectory import write_trajectory

    start = time.perf_counter()
    started_at = time.time()
    clock = StageClock()
    folder = DatasetFolder(job.out_dir)
    staged: Path | None = None
    writers: dict[str, CloudWriter] = {}
    try:
        with clock.step("load"):
            scene = load_scene(job.ifc, scheme=job.scheme, threads=job.recipe.threads, strict=job.recipe.strict,
                               length_unit=job.length_unit)
        load_s = time.perf_counter() - start
        with clock.step("site"):
            stations = folder.read_stations(job.scene, job.site_tag)
            if job.site_tag:  # the scene task's dressed scene, else dressed again (the same bytes)
                stored = read_site_scene(folder.site_scene_path(job.scene, job.site_tag), scene, job.site_key)
                keep_clear = stations if job.inputs["stations"] != AUTO_STATIONS else ()  # the scene's station file
                scene = stored if stored is not None else build_site(scene, job.recipe, keep_clear=keep_clear)
        site_s = time.perf_counter() - start - load_s
        with clock.step("survey"):
            trajectory = walk = None
            if job.recipe.mobile is not None:  # a walk through the scene's stations (or the scene's trajectory file)
                trajectory, walk = choose_trajectory(scene, job.recipe, stations=stations)
            survey = prepare_survey(scene, job.recipe, stations=stations, trajectory=trajectory, walk=walk)
            header = cloud_header(survey, extra_metadata={
                "unit": {"id": job.unit, "scene": job.scene, "config": job.config, "voxel_size_m": job.voxel_size_m,
                         "fingerprint": job.fingerprint}})
            staged = folder.staging_dir(job.unit)
            writers = {fmt: open_cloud_writer(staged / FORMAT_FILES[fmt], header=header) for fmt in job.formats}
        scanned = CloudSummary()
        kept = CloudSummary() if job.voxel_size_m else scanned  # without subsampling, what is kept is what was scanned
        subsampler = VoxelSubsampler(job.voxel_size_m, origin=header.origin) if job.voxel_size_m else None
        scan_start = time.perf_counter()
        for chunk in stream_checked(survey, summary=scanned, on_pulses=functools.partial(report_pulses, unit=job.unit),
                                    clock=clock):
            if not driver_alive():
                raise DatasetError("the build driver is gone; unit abandoned (run the build again to finish it)")
            if subsampler is not None:
                with clock.step("subsample"):
                    chunk = subsampler.filter(chunk)
                    kept.add(chunk)
            with clock.step("write"):
                for writer in writers.values():
                    writer.write(chunk)
        with clock.step("write"):
            written = {fmt: writer.close() for fmt, writer in writers.items()}
        scan_s = time.perf_counter() - scan_start
        with clock.step("verify"):
            check_written(kept, written)
        checksums: dict[str, str] = {}
        n_bytes = 0
        for cloud in written.values():
            checksums.update(cloud.sha256)
            n_bytes += cloud.n_bytes
        files = {fmt: FORMAT_FILES[fmt] for fmt in job.formats}
        if trajectory is not None:  # kept and verified with the clouds
            checksums[TRAJECTORY_NAME] = file_sha256(write_trajectory(staged / TRAJECTORY_NAME, trajectory))
        record = UnitRecord(
            id=job.unit, scene=job.scene, config=job.config, fingerprint=job.fingerprint, inputs=job.inputs,
            ifc_schema=scene.schema, stations=stations, device_warnings=job.recipe.warnings, points=kept.points,
            points_scanned=scanned.points, dropped_invalid=scanned.dropped_invalid,
            dropped_by_voxel=scanned.points - kept.points, extents=kept.extents(),
            class_histogram=kept.histogram(scene.scheme.names),
            station_counts={str(k): v for k, v in sorted(kept.station_counts.items())}, files=files,
            checksums=checksums, bytes=n_bytes, site={} if scene.site is None else scene.site.to_json(),
            ifc={"report": report_document(scene.report), "failed": [dataclasses.asdict(f) for f in scene.failed]},
        )
        with clock.step("record"):
            write_unit_record(staged, record)
        total_s = time.perf_counter() - start
        stages = unit_stages(clock, survey.scanner.clock, [writer.clock for writer in writers.values()], total_s)
        place = worker_node()
        write_json(staged / TIMINGS_NAME, {"load_s": round(load_s, 3), "site_s": round(site_s, 3),
                                           "scan_write_s": round(scan_s, 3), "total_s": round(total_s, 3),
                                           "threads": job.recipe.threads,
                                           "points_per_s": round(kept.points / max(scan_s, 1e-9)),
                                           "pulses": survey.pulses(), "stages_s": stages,
                                           "started_at": round(started_at, 3), **place})  # Unix time: the timeline
        replace_path(staged, folder.unit_dir(job.unit), kind="unit")
        staged = None
        return UnitOutcome(unit=job.unit, status="done", points=kept.points, files=files, load_s=load_s,
                           seconds=time.perf_counter() - start, site_s=site_s,
                           node=f"{place['host']}/{place['ray_node'][:8]}" if "ray_node" in place else place["host"])
    except (BimscanError, OSError) as exc:
        return UnitOutcome(unit=job.unit, status="failed", error=_one_line(exc), seconds=time.perf_counter() - start)
    finally:
        for writer in writers.values():
            writer.abort()  # a no-op for writers that closed
        if staged is not None:
            shutil.rmtree(staged, ignore_errors=True)


UNIT_STAGES = ("load", "site", "survey", "rays", "cast", "hits", "checks", "subsample", "encode", "compress",
               "store", "checksum", "write_other", "verify", "record", "other")


def unit_stages(unit: StageClock, scanner: StageClock, writers: list[StageClock], total_s: float) -> dict[str, float]:
    """Where a unit task's ``total_s`` seconds went (``UNIT_STAGES``, rounded to the millisecond):
    the scene read from the cache (load) and its dressing (site), the scanner placed in it (survey:
    the BVH, the face tables, the writers opened), ray generation, the engine's casts, the rest of
    the scan (hits: noise, labels, intensity, compaction), the semantic checks, voxel subsampling,
    then the writers' own steps (LAS/LAZ encoding and compression or storing, checksums) and the
    rest of writing, the read-back check, the records, and what no step claims (other). The
    stations' clouds stream one after another into the writers: merging them costs nothing."""
    writer_steps: dict[str, float] = {}
    for clock in writers:
        for step, seconds in clock.seconds.items():
            writer_steps[step] = writer_steps.get(step, 0.0) + seconds
    scan = scanner.seconds.get("scan", 0.0)
    rays, cast = scanner.seconds.get("rays", 0.0), scanner.seconds.get("cast", 0.0)
    stages = {step: unit.seconds.get(step, 0.0) for step in ("load", "site", "survey")}
    stages |= {"rays": rays, "cast": cast, "hits": max(scan - rays - cast, 0.0),
               "checks": unit.seconds.get("checks", 0.0), "subsample": unit.seconds.get("subsample", 0.0)}
    stages |= {step: writer_steps.get(step, 0.0) for step in ("encode", "compress", "store", "checksum")}
    stages["write_other"] = max(unit.seconds.get("write", 0.0) - sum(writer_steps.values()), 0.0)
    stages |= {step: unit.seconds.get(step, 0.0) for step in ("verify", "record")}
    stages["other"] = max(total_s - sum(stages.values()), 0.0)
    return {step: round(stages[step], 3) for step in UNIT_STAGES}


def check_written(kept: CloudSummary, written: Mapping[str, WrittenCloud]) -> None:
    """The unit's post-checks on what was written, read back from the files: every output holds
    as many points as the stream had (its header count; bodies shorter than the header are
    caught), and the stream was not empty. (Every point's label was checked against its
    component's class while it streamed: ``stream_checked`` runs ``check_semantics`` on each chunk.)
    Raises SemanticError."""
    from bimscan.io import count_points

    if kept.points == 0:
        raise SemanticError("the scan has no point (no station sees a surface within the scanner's range); "
                            "check the scene and its stations")
    for fmt, cloud in written.items():
        try:
            stored = count_points(cloud.path)
        except BimscanError as exc:
            raise SemanticError(f"the {fmt} output cannot be read back ({exc})") from exc
        if stored != kept.points:
            raise SemanticError(f"the {fmt} output holds {stored} points, the stream had {kept.points}")

"""Build a dataset: every (scene, configuration) pair of a spec scanned into one data unit.

The driver (``build_dataset``) runs in the calling process; the work runs as tasks on an
executor (``bimscan.dataset.executors``):

1. Scenes. Generated demo buildings are written to ``scenes/``. One *scene task* per scene
   with missing units parses its IFC once (filling the on-disk geometry cache) and plans its
   stations once (``scenes/<scene>.stations.json``): every configuration of the scene scans
   from the same viewpoints, as in the paper, and its unit tasks load the parsed geometry from
   the cache instead of parsing again.
2. Units. One *unit task* per missing unit scans the survey and streams the merged cloud
   through the post-processing (invalid points dropped and counted, semantic checks, optional
   voxel subsampling) into every requested format at once, checks the outputs agree, and
   writes ``unit.json`` (reproducible) and ``timings.json`` (not). The unit is built in a
   hidden staging folder and renamed into place when whole.

Resuming: a unit whose folder exists, was built from the same inputs (a fingerprint of the
scene file, configuration, scanner, stations mode, scheme, noise, seed, formats, voxel size,
engine and software version) and whose files still match their SHA-256 is kept; everything
else is (re)built. A failing scene or unit is recorded in the manifest with its reason and the
rest go on. A lock file keeps two builds out of one folder.
"""

from __future__ import annotations

import dataclasses
import errno
import fcntl
import os
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from concurrent.futures import BrokenExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any


from bimscan import __version__
from bimscan.dataset.executors import TaskFunction, driver_alive, make_executor, report_pulses
from bimscan.dataset.manifest import (
    DATASET_NAME,
    SCENES_DIR,
    TIMINGS_NAME,
    UNIT_FORMAT,
    UNIT_NAME,
    UNIT_VERSION,
    UNITS_DIR,
    fingerprint,
    manifest_entry,
    read_json,
    remove_leftovers,
    staging_dir,
    unit_dir,
    verify_unit,
    write_json,
    write_manifest,
)
from bimscan.dataset.spec import (
    FORMAT_FILES,
    ConfigSpec,
    DatasetSpec,
    config_settings,
    preset_name,
    resolve_scanner,
    resolve_scheme,
    unit_id,
)
from bimscan.errors import BimscanError, DatasetError, OutputError
from bimscan.files import file_sha256, replace_path
from bimscan.progress import progress_bar
from bimscan.scan.noise import NoiseModel
from bimscan.scan.device import ScannerModel, ScanSettings
from bimscan.scan.virtual_scanner import DEFAULT_CHUNK_PULSES
from bimscan.types import Station

if TYPE_CHECKING:
    from bimscan.io import CloudWriter, WrittenCloud
    from bimscan.process.summary import CloudSummary

STATIONS_VERSION = 1


@dataclass(frozen=True)
class SceneJob:
    """What a scene task needs: parse the IFC (into the cache) and plan or read the stations."""

    scene: str
    ifc: str
    scheme: str
    scanner: str
    stations: str  # "auto" or a station CSV file
    engine: str
    threads: int
    stations_file: str  # where the planned stations go
    stations_key: str  # fingerprint of what the stations depend on


@dataclass(frozen=True)
class SceneOutcome:
    scene: str
    error: str | None = None
    n_stations: int = 0
    parse_s: float = 0.0
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class UnitJob:
    """What a unit task needs to scan one scene with one configuration into a unit folder."""

    unit: str
    scene: str
    config: str
    ifc: str
    scheme: str
    scanner: str
    settings: ScanSettings
    preset: str | None
    noise: NoiseModel
    seed: int
    engine: str
    strict: bool
    formats: tuple[str, ...]
    voxel_size_m: float | None
    stations_file: str
    out_dir: str
    threads: int
    inputs: dict[str, Any]
    fingerprint: str
    chunk_pulses: int = DEFAULT_CHUNK_PULSES


@dataclass(frozen=True)
class UnitOutcome:
    unit: str
    status: str  # "done" or "failed"
    error: str | None = None
    points: int = 0
    files: dict[str, str] = field(default_factory=dict)  # format -> path relative to the unit folder
    load_s: float = 0.0
    seconds: float = 0.0


@dataclass(frozen=True)
class BuildReport:
    """What a build did. ``entries`` are the manifest rows; the rest sums them up."""

    out_dir: Path
    entries: list[dict[str, Any]]
    reused: int  # units found finished and verified
    built: int  # units built by this run
    failed: int
    points_built: int
    seconds: float
    scenes: list[SceneOutcome]
    unit_load_s: float  # total time unit tasks spent loading their (cached) scene
    workers: int
    threads: int

    @property
    def ok(self) -> bool:
        return self.failed == 0

    def summary(self) -> str:
        """One line: units, outcome, points, time."""
        total = len(self.entries)
        rate = self.points_built / self.seconds / 1e6 if self.seconds > 0 else 0.0
        return (f"{total} units: {self.built} built, {self.reused} already done, {self.failed} failed; "
                f"{self.points_built:,} points built in {self.seconds:.1f} s ({rate:.2f} Mpts/s)")


def default_workers() -> int:
    """One worker per core, each casting on one thread.

    Measured with ``benchmarks/bench_dataset.py`` on 2 cores (12 units, 61M points, LAZ, quiet
    machine, alternating runs): two one-thread workers build at 3.13-3.16 Mpts/s, the rate of a
    single ``bimscan scan`` on both cores; one two-thread worker at 2.62-2.67 Mpts/s. Two units
    side by side keep both cores busy through the parts of a unit that use one (LAZ encoding,
    per-chunk checks).
    """
    return max(1, os.cpu_count() or 1)


def build_dataset(spec: DatasetSpec, out_dir: str | Path, *, workers: int | None = None, executor: str = "local",
                  ray_address: str | None = None, progress: bool = True,
                  chunk_pulses: int = DEFAULT_CHUNK_PULSES) -> BuildReport:
    """Build (or finish) the dataset of ``spec`` in ``out_dir``; see the module docs.

    workers: tasks run at once (default: one per core); each gets cores // workers threads, where
    workers counts only as many as there are units to build.
    executor: "local" (spawned processes), "ray" (Ray tasks; ``ray_address`` for a cluster) or
    "serial" (the calling process). Returns the report; failed units are in it, not raised.
    Raises DatasetError when another build holds ``out_dir``, OutputError when it cannot be created.
    """
    start = time.perf_counter()
    out = Path(out_dir).resolve()
    workers = workers if workers is not None else default_workers()
    if workers < 1:
        raise DatasetError(f"--workers {workers} is impossible; give 1 or more")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the dataset folder {out} ({exc.strerror}); check the path") from exc
    with _build_lock(out):
        remove_leftovers(out)
        (out / UNITS_DIR).mkdir(exist_ok=True)
        (out / SCENES_DIR).mkdir(exist_ok=True)
        write_json(out / DATASET_NAME, {"format": "bimscan-dataset-info", "version": 1, "name": spec.name,
                                        "software": f"bimscan {__version__}", "spec": dataclasses.asdict(spec)})
        scene_files, scene_errors = _scene_files(spec, out)
        entries, jobs = _plan_units(spec, out, scene_files, scene_errors, chunk_pulses=chunk_pulses)
        write_manifest(out, entries)
        workers = max(1, min(workers, len(jobs)))  # fewer units than workers: give each more threads
        threads = max(1, (os.cpu_count() or 1) // workers)
        reused = sum(e["status"] == "done" for e in entries)
        outcome = _run(spec, out, entries, jobs, scene_files, executor=executor, workers=workers, threads=threads,
                       ray_address=ray_address, progress=progress)
    built = [o for o in outcome.units if o.status == "done"]
    return BuildReport(
        out_dir=out, entries=entries, reused=reused, built=len(built),
        failed=sum(e["status"] == "failed" for e in entries), points_built=sum(o.points for o in built),
        seconds=time.perf_counter() - start, scenes=outcome.scenes, unit_load_s=sum(o.load_s for o in outcome.units),
        workers=workers, threads=threads,
    )


@contextmanager
def _build_lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``out/.lock`` (released by the kernel even on kill -9)."""
    handle = (out / ".lock").open("a")
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as exc:
            raise DatasetError(f"another build is running in {out}; wait for it or use another folder") from exc
        yield
    finally:
        handle.close()


# -- the driver's preparation -----------------------------------------------------------------

def _scene_files(spec: DatasetSpec, out: Path) -> tuple[dict[str, Path], dict[str, str]]:
    """The IFC file of every scene (generating demo buildings that are not there yet) and errors."""
    files: dict[str, Path] = {}
    errors: dict[str, str] = {}
    for scene in spec.scenes:
        if scene.ifc is not None:
            files[scene.name] = Path(scene.ifc)
            continue
        path = out / SCENES_DIR / f"{scene.name}.ifc"
        generate = scene.generate
        if not path.is_file() and generate is not None:
            try:
                from bimscan.ifc.generate import make_building

                make_building(path, seed=generate.seed, storeys=generate.storeys)
            except BimscanError as exc:
                errors[scene.name] = f"could not generate scene {scene.name!r}: {exc}"
                continue
        files[scene.name] = path
    return files, errors


def _shared_inputs(spec: DatasetSpec) -> dict[str, Any]:
    """The inputs every unit of ``spec`` shares (JSON-able)."""
    return {
        "scanner": dataclasses.asdict(resolve_scanner(spec)),
        "scheme": dataclasses.asdict(resolve_scheme(spec)),
        "noise": dataclasses.asdict(spec.noise),
        "seed": spec.seed,
        "engine": spec.engine,
        "strict": spec.strict,
        "formats": list(spec.formats),
        "voxel_size_m": spec.voxel_size_m,
        "software": f"bimscan {__version__}",
    }


def _scene_inputs(spec: DatasetSpec, scene_name: str, scene_file: Path) -> dict[str, Any]:
    """The inputs of one scene: its file (by content) and how its stations are chosen."""
    scene = spec.scene(scene_name)
    stations: Any = "auto"
    if scene.stations != "auto":
        stations = {"file": Path(scene.stations).name, "sha256": file_sha256(Path(scene.stations))}
    return {"scene": {"name": scene.name, "file": scene_file.name, "sha256": file_sha256(scene_file),
                      "generated": None if scene.generate is None else dataclasses.asdict(scene.generate)},
            "stations": stations}


def _unit_inputs(shared: dict[str, Any], scene: dict[str, Any], config: ConfigSpec) -> dict[str, Any]:
    """Everything a unit's bytes depend on (JSON-able); its fingerprint decides reuse."""
    settings = config_settings(config)
    return shared | scene | {
        "config": {"name": config.name, "preset": preset_name(config.preset) if config.settings is None else None,
                   "head_deg_per_s_override": config.head_deg_per_s, "settings": dataclasses.asdict(settings)},
    }


def _plan_units(spec: DatasetSpec, out: Path, scene_files: dict[str, Path], scene_errors: dict[str, str], *,
                chunk_pulses: int) -> tuple[list[dict[str, Any]], dict[str, UnitJob]]:
    """Manifest rows for every unit (finished ones verified) and jobs for the rest."""
    entries: list[dict[str, Any]] = []
    jobs: dict[str, UnitJob] = {}
    shared = _shared_inputs(spec)
    for scene in spec.scenes:
        scene_inputs = None if scene.name in scene_errors else _scene_inputs(spec, scene.name, scene_files[scene.name])
        for config in spec.configs:
            uid = unit_id(scene.name, config.name)
            if scene_inputs is None:
                entries.append(manifest_entry(unit=uid, scene=scene.name, config=config.name, status="failed",
                                              error=scene_errors[scene.name]))
                continue
            inputs = _unit_inputs(shared, scene_inputs, config)
            key = fingerprint(inputs)
            folder = unit_dir(out, uid)
            if folder.exists():
                problem = verify_unit(folder, expected_fingerprint=key)
                if problem is None:
                    meta = read_json(folder / UNIT_NAME)
                    entries.append(manifest_entry(unit=uid, scene=scene.name, config=config.name, status="done",
                                                  points=meta["points"], files=_manifest_files(uid, meta["files"])))
                    continue
                # stale or damaged: rebuilt below; replace_path swaps it out only once the new one is complete
            entries.append(manifest_entry(unit=uid, scene=scene.name, config=config.name, status="pending"))
            jobs[uid] = UnitJob(
                unit=uid, scene=scene.name, config=config.name, ifc=str(scene_files[scene.name]), scheme=spec.scheme,
                scanner=spec.scanner, settings=config_settings(config), preset=preset_name(config.preset), noise=spec.noise,
                seed=spec.seed, engine=spec.engine, strict=spec.strict, formats=spec.formats,
                voxel_size_m=spec.voxel_size_m, stations_file=str(_stations_path(out, scene.name)), out_dir=str(out),
                threads=1, inputs=inputs, fingerprint=key, chunk_pulses=chunk_pulses,  # threads: set in _run
            )
    return entries, jobs


def _stations_path(out: Path, scene: str) -> Path:
    return out / SCENES_DIR / f"{scene}.stations.json"


def _manifest_files(uid: str, files: dict[str, str]) -> dict[str, str]:
    return {fmt: f"{UNITS_DIR}/{uid}/{name}" for fmt, name in files.items()}


@dataclass
class _RunOutcome:
    scenes: list[SceneOutcome] = field(default_factory=list)
    units: list[UnitOutcome] = field(default_factory=list)


def _run(spec: DatasetSpec, out: Path, entries: list[dict[str, Any]], jobs: dict[str, UnitJob],
         scene_files: dict[str, Path], *, executor: str, workers: int, threads: int, ray_address: str | None,
         progress: bool) -> _RunOutcome:
    """Run the scene tasks, then each scene's unit tasks as soon as its scene is ready."""
    result = _RunOutcome()
    if not jobs:
        return result
    row = {e["id"]: e for e in entries}
    jobs = {uid: dataclasses.replace(job, threads=threads) for uid, job in jobs.items()}
    scanner = resolve_scanner(spec)
    by_scene: dict[str, list[UnitJob]] = {}
    for job in jobs.values():
        by_scene.setdefault(job.scene, []).append(job)
    environment = {"BIMSCAN_PROGRESS": "0"}  # bars belong to the driver, not to the workers
    if os.environ.get("BIMSCAN_CACHE_DIR"):
        environment["BIMSCAN_CACHE_DIR"] = os.environ["BIMSCAN_CACHE_DIR"]
    pool = make_executor(executor, workers=workers, environment=environment, address=ray_address)
    handles: dict[Any, tuple[str, str]] = {}  # handle -> ("scene" | "unit", name)

    def submit(kind: str, name: str, fn: TaskFunction, job: SceneJob | UnitJob) -> None:
        nonlocal pool
        try:
            handle = pool.submit(fn, job, cpus=threads)
        except BrokenExecutor:  # a worker died hard (killed, out of memory): start a fresh pool
            pool.close()
            pool = make_executor(executor, workers=workers, environment=environment, address=ray_address)
            handle = pool.submit(fn, job, cpus=threads)
        handles[handle] = (kind, name)

    for scene_name in by_scene:
        scene = spec.scene(scene_name)
        key = fingerprint({"ifc": by_scene[scene_name][0].inputs["scene"]["sha256"],
                           "stations": by_scene[scene_name][0].inputs["stations"],
                           "scanner": dataclasses.asdict(scanner), "software": __version__,
                           "version": STATIONS_VERSION})
        submit("scene", scene_name, run_scene_job, SceneJob(
            scene=scene_name, ifc=str(scene_files[scene_name]), scheme=spec.scheme, scanner=spec.scanner,
            stations=scene.stations, engine=spec.engine, threads=threads,
            stations_file=str(_stations_path(out, scene_name)), stations_key=key))

    def finish_unit(outcome: UnitOutcome) -> None:
        entry = row[outcome.unit]
        entry.update(manifest_entry(unit=outcome.unit, scene=entry["scene"], config=entry["config"],
                                    status=outcome.status, error=outcome.error, points=outcome.points,
                                    files=_manifest_files(outcome.unit, outcome.files)))
        result.units.append(outcome)
        write_manifest(out, entries)

    with progress_bar(total=len(jobs), desc="units", unit="unit", enabled=progress) as unit_bar, \
            progress_bar(total=0, desc="scanning", unit="pulse", enabled=progress) as pulse_bar:
        finished = False
        try:
            while handles:
                for handle, value, error in pool.wait(list(handles), timeout=0.5):
                    kind, name = handles.pop(handle)
                    if kind == "scene":
                        scene_outcome = value if error is None else SceneOutcome(scene=name, error=_task_error(error))
                        result.scenes.append(scene_outcome)
                        if scene_outcome.error is not None:
                            for job in by_scene[name]:
                                finish_unit(UnitOutcome(unit=job.unit, status="failed",
                                                        error=f"scene {name!r}: {scene_outcome.error}"))
                                unit_bar.update(1)
                            continue
                        for job in by_scene[name]:
                            pulse_bar.total += _expected_pulses(job, scanner, scene_outcome.n_stations)
                            submit("unit", job.unit, run_unit_job, job)
                        pulse_bar.refresh()
                    else:
                        finish_unit(value if error is None else
                                    UnitOutcome(unit=name, status="failed", error=_task_error(error)))
                        unit_bar.update(1)
                pulse_bar.update(pool.drain_pulses())
            finished = True
        finally:
            if not finished:
                # Ctrl-C or a driver bug: stop the workers, keep what is finished (the manifest says which).
                pool.close(cancel=True)
                write_manifest(out, entries)
        pool.close()
    return result


def _expected_pulses(job: UnitJob, scanner: ScannerModel, n_stations: int) -> int:
    from bimscan.scan.pattern import PulsePattern

    return PulsePattern.of(job.settings, scanner).count() * n_stations


def _task_error(error: BaseException) -> str:
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
    return _task_error(error)


# -- tasks (run in worker processes; module-level functions so they pickle by name) ---------

def run_scene_job(job: SceneJob) -> SceneOutcome:
    """Parse the scene (filling the geometry cache) and plan or read its stations once."""
    from bimscan.pipeline import load_scene
    from bimscan.scan.device import load_scanner
    from bimscan.scan.virtual_scanner import VirtualScanner
    from bimscan.pipeline import choose_stations

    try:
        start = time.perf_counter()
        scene = load_scene(job.ifc, scheme=job.scheme, threads=job.threads)
        parse_s = time.perf_counter() - start
        path = Path(job.stations_file)
        if path.is_file():
            try:
                stored = read_json(path)
                if stored.get("key") == job.stations_key:
                    return SceneOutcome(scene=job.scene, n_stations=len(stored["stations"]),
                                        parse_s=parse_s, notes=tuple(stored.get("notes", ())))
            except (DatasetError, KeyError, TypeError):
                pass  # damaged: plan again
        scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=load_scanner(job.scanner),
                                 engine=job.engine, threads=job.threads)
        stations, plan = choose_stations(scene, scanner, job.stations)
        notes: list[str] = []
        if plan is not None and plan.rooms_without_station:
            notes.append("rooms without a station: " + ", ".join(plan.rooms_without_station))
        write_json(path, {"format": "bimscan-stations", "version": STATIONS_VERSION, "key": job.stations_key,
                          "scene": job.scene, "stations": [dataclasses.asdict(s) for s in stations],
                          "notes": notes})
        return SceneOutcome(scene=job.scene, n_stations=len(stations), parse_s=parse_s, notes=tuple(notes))
    except (BimscanError, OSError) as exc:
        return SceneOutcome(scene=job.scene, error=_one_line(exc))


def read_stations_file(path: str | Path) -> tuple[Station, ...]:
    """The stations a scene task stored (``scenes/<scene>.stations.json``)."""
    document = read_json(Path(path))
    try:
        return tuple(Station.from_dict(s) for s in document["stations"])
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: damaged station file ({exc}); delete it and run the build again") from exc


def run_unit_job(job: UnitJob) -> UnitOutcome:
    """Scan one unit into a staging folder, check it, and move it into place."""
    from bimscan.io import open_cloud_writer
    from bimscan.pipeline import load_scene
    from bimscan.pipeline import ScanOptions, cloud_header, prepare_survey, stream_survey
    from bimscan.process.checks import SemanticError
    from bimscan.process.summary import CloudSummary
    from bimscan.process.subsample import VoxelSubsampler

    start = time.perf_counter()
    out = Path(job.out_dir)
    staged: Path | None = None
    writers: dict[str, CloudWriter] = {}
    try:
        scene = load_scene(job.ifc, scheme=job.scheme, threads=job.threads)
        load_s = time.perf_counter() - start
        stations = read_stations_file(job.stations_file)
        options = ScanOptions(settings=job.settings, scanner=job.scanner, seed=job.seed, noise=job.noise,
                              strict=job.strict, engine=job.engine, threads=job.threads, chunk_pulses=job.chunk_pulses)
        survey = prepare_survey(scene, options, stations=stations)
        header = cloud_header(survey, options, extra_metadata={
            "unit": {"id": job.unit, "scene": job.scene, "config": job.config, "preset": job.preset,
                     "voxel_size_m": job.voxel_size_m, "fingerprint": job.fingerprint}})
        staged = staging_dir(out, job.unit)
        writers = {fmt: open_cloud_writer(staged / FORMAT_FILES[fmt], header=header) for fmt in job.formats}
        scanned = CloudSummary()
        kept = CloudSummary() if job.voxel_size_m else scanned  # without subsampling, what is kept is what was scanned
        subsampler = VoxelSubsampler(job.voxel_size_m, origin=header.origin) if job.voxel_size_m else None
        scan_start = time.perf_counter()
        for chunk in stream_survey(survey, options, summary=scanned, on_pulses=report_pulses):
            if not driver_alive():
                raise DatasetError("the build driver is gone; unit abandoned (run the build again to finish it)")
            if subsampler is not None:
                chunk = subsampler.filter(chunk)
                kept.add(chunk)
            for writer in writers.values():
                writer.write(chunk)
        written = {fmt: writer.close() for fmt, writer in writers.items()}
        scan_s = time.perf_counter() - scan_start
        _check_unit(kept, written)
        names = scene.scheme.names
        checksums: dict[str, str] = {}
        n_bytes = 0
        for cloud in written.values():
            checksums.update(cloud.sha256)
            n_bytes += cloud.n_bytes
        files = {fmt: FORMAT_FILES[fmt] for fmt in job.formats}
        meta = {
            "format": UNIT_FORMAT, "version": UNIT_VERSION, "id": job.unit, "scene": job.scene, "config": job.config,
            "fingerprint": job.fingerprint, "inputs": job.inputs, "ifc_schema": scene.schema,
            "stations": [dataclasses.asdict(s) for s in stations], "device_warnings": list(survey.warnings),
            "points": kept.points, "points_scanned": scanned.points, "dropped_invalid": scanned.dropped_invalid,
            "dropped_by_voxel": scanned.points - kept.points,
            "extents": kept.extents(), "class_histogram": kept.histogram(names),
            "station_counts": {str(k): v for k, v in sorted(kept.station_counts.items())},
            "files": files, "checksums": checksums, "bytes": n_bytes,
        }
        write_json(staged / UNIT_NAME, meta)
        write_json(staged / TIMINGS_NAME, {"load_s": round(load_s, 3), "scan_write_s": round(scan_s, 3),
                                           "total_s": round(time.perf_counter() - start, 3), "threads": job.threads,
                                           "points_per_s": round(kept.points / max(scan_s, 1e-9))})
        replace_path(staged, unit_dir(out, job.unit))
        staged = None
        return UnitOutcome(unit=job.unit, status="done", points=kept.points, files=files, load_s=load_s,
                           seconds=time.perf_counter() - start)
    except (BimscanError, SemanticError, OSError, ValueError) as exc:
        return UnitOutcome(unit=job.unit, status="failed", error=_one_line(exc), seconds=time.perf_counter() - start)
    finally:
        for writer in writers.values():
            writer.abort()  # a no-op for writers that closed
        if staged is not None:
            shutil.rmtree(staged, ignore_errors=True)


def _check_unit(kept: CloudSummary, written: dict[str, WrittenCloud]) -> None:
    """The post-processing checks after the stream: every output holds every point, the histogram
    counts every point. (Every point's label was checked against its component's class while it
    streamed: ``stream_survey`` runs ``check_semantics`` on each chunk.)"""
    from bimscan.process.checks import SemanticError

    if kept.points == 0:
        raise SemanticError("the scan has no point (no station sees a surface within the scanner's range); "
                            "check the scene and its stations")
    for fmt, cloud in written.items():
        if cloud.n_points != kept.points:
            raise SemanticError(f"the {fmt} output holds {cloud.n_points} points, the stream had {kept.points}")
    if int(kept.class_counts.sum()) != kept.points:
        raise SemanticError(f"the class histogram counts {int(kept.class_counts.sum())} points of {kept.points}")

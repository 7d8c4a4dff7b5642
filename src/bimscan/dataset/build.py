"""Build a dataset: every (scene, configuration) pair of a spec scanned into one data unit.

The driver (``build_dataset``) runs in the calling process and the work runs as tasks on an
executor (``bimscan.dataset.executors``): it writes the generated scenes, plans the build
(``bimscan.dataset.plan``: finished units verified and kept, jobs for the rest), runs one scene
task per scene with missing units (parse once, stations once), estimates the output from the
stations and refuses to start when it would not fit the free space (``bimscan.dataset.estimate``),
then runs the unit tasks (``bimscan.dataset.tasks``) with a progress bar weighted by the pulses
each unit scans, and keeps ``manifest.json`` up to date as units finish. A failing scene or unit
is recorded in the manifest with its reason and the rest go on. A lock file keeps two builds out
of one folder; a killed build resumes where it stopped (see ``bimscan.dataset.layout``).
"""

from __future__ import annotations

import dataclasses
import fcntl
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from concurrent.futures import BrokenExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bimscan import __version__
from bimscan.dataset.estimate import (
    EtaCheck, SizeEstimate, UnitWork, WorkProgress, check_output_fits, estimate_size, tripod_unit_work,
    with_unknown_as_mean,
)
from bimscan.dataset.executors import TaskFunction, make_executor
from bimscan.dataset.layout import (
    LOCK_NAME, SCENES_DIR, UNITS_DIR, DatasetFolder, Manifest, ManifestEntry, write_json,
)
from bimscan.dataset.plan import SceneJob, UnitJob, check_unit_folders, generate_scenes, plan_build
from bimscan.dataset.spec import DatasetSpec
from bimscan.dataset.tasks import SceneOutcome, UnitOutcome, run_scene_job, run_unit_job, task_error
from bimscan.errors import DatasetError
from bimscan.files import claim_output
from bimscan.progress import progress_bar
from bimscan.survey.survey import station_pulses


@dataclass(frozen=True)
class BuildReport:
    """What a build did. ``entries`` are the manifest rows; the rest sums them up."""

    out_dir: Path
    entries: list[ManifestEntry]
    reused: int  # units found finished and verified
    built: int  # units built by this run
    failed: int
    points_built: int
    seconds: float
    scenes: list[SceneOutcome]
    unit_load_s: float  # total time unit tasks spent loading their (cached) scene
    workers: int
    threads: int
    notes: tuple[str, ...] = ()  # what the user should know about the scenes (e.g. regenerated ones)
    estimate: SizeEstimate | None = None  # the output of the units to build, estimated before they ran
    eta: EtaCheck | None = None  # the time left predicted after a tenth of the work, against what it took
    nodes: dict[str, int] = field(default_factory=dict)  # units built per host (host/Ray node on Ray)

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
                  ray_address: str | None = None, progress: bool = True, chunk_pulses: int | None = None,
                  log: Callable[[str], None] | None = None) -> BuildReport:
    """Build (or finish) the dataset of ``spec`` in ``out_dir``; see the module docs.

    workers: tasks run at once (default: one per core); each gets cores // workers threads, where
    workers counts only as many as there are units to build.
    executor: "local" (spawned processes), "ray" (Ray tasks; ``ray_address`` for a cluster) or
    "serial" (the calling process). chunk_pulses: pulses per scan chunk (memory; never the output).
    log: receives the size estimate line once the scenes are planned.
    Returns the report; failed units are in it, not raised.
    Raises DatasetError when another build holds ``out_dir``, OutputError when it cannot be created,
    when it is a folder bimscan did not make or holds a user's file at a name the build writes
    (``DatasetFolder.prepare``), when a unit would replace a folder bimscan did not write (both
    before any work), or when the units to build would not fit its free space (the scenes' work is
    kept: stations).
    """
    start = time.perf_counter()
    folder = DatasetFolder(Path(out_dir).resolve())
    workers = workers if workers is not None else default_workers()
    if workers < 1:
        raise DatasetError(f"--workers {workers} is impossible; give 1 or more")
    folder.prepare()  # a user's folder, or a user's manifest.json in it, is refused here
    with _build_lock(folder.root):
        check_unit_folders(spec, folder)  # before any scene is generated or scanned
        folder.remove_leftovers()
        claim_output(folder.root, f"{UNITS_DIR}/")
        claim_output(folder.root, f"{SCENES_DIR}/")
        write_json(folder.info_path, {"format": "bimscan-dataset-info", "version": 1, "name": spec.name,
                                      "software": f"bimscan {__version__}", "spec": dataclasses.asdict(spec)})
        scenes = generate_scenes(spec, folder)
        plan = plan_build(spec, folder, scenes, chunk_pulses=chunk_pulses)
        folder.write_manifest(Manifest(units=tuple(plan.entries)))
        workers = max(1, min(workers, len(plan.unit_jobs)))  # fewer units than workers: give each more threads
        threads = max(1, (os.cpu_count() or 1) // workers)
        reused = sum(e.status == "done" for e in plan.entries)
        rows = {e.id: e for e in plan.entries}
        outcome = _run(folder, rows, plan.unit_jobs, plan.scene_jobs, executor=executor, workers=workers,
                       threads=threads, ray_address=ray_address, progress=progress, log=log or (lambda line: None))
    entries = list(rows.values())
    built = [o for o in outcome.units if o.status == "done"]
    nodes: dict[str, int] = {}
    for unit in built:
        nodes[unit.node] = nodes.get(unit.node, 0) + 1
    return BuildReport(
        out_dir=folder.root, entries=entries, reused=reused, built=len(built),
        failed=sum(e.status == "failed" for e in entries), points_built=sum(o.points for o in built),
        seconds=time.perf_counter() - start, scenes=outcome.scenes, unit_load_s=sum(o.load_s for o in outcome.units),
        workers=workers, threads=threads, notes=scenes.notes, estimate=outcome.estimate, eta=outcome.eta, nodes=nodes,
    )


@contextmanager
def _build_lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``out/.lock`` (released by the kernel even on kill -9)."""
    handle = claim_output(out, LOCK_NAME).open("a")
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as exc:
            raise DatasetError(f"another build is running in {out}; wait for it or use another folder") from exc
        yield
    finally:
        handle.close()


@dataclass
class _RunOutcome:
    scenes: list[SceneOutcome] = field(default_factory=list)
    units: list[UnitOutcome] = field(default_factory=list)
    estimate: SizeEstimate | None = None
    eta: EtaCheck | None = None


def _run(folder: DatasetFolder, rows: dict[str, ManifestEntry], unit_jobs: dict[str, UnitJob],
         scene_jobs: list[SceneJob], *, executor: str, workers: int, threads: int, ray_address: str | None,
         progress: bool, log: Callable[[str], None]) -> _RunOutcome:
    """Run the scene tasks, then (once the output is known to fit) the unit tasks; ``rows`` (the
    manifest, in order) is updated and written as units finish."""
    result = _RunOutcome()
    if not unit_jobs:
        return result

    def with_threads(job: Any) -> Any:
        return dataclasses.replace(job, recipe=job.recipe.with_fields(threads=threads))

    by_scene: dict[tuple[str, str], list[UnitJob]] = {}  # (scene, site tag) -> its units
    for job in unit_jobs.values():
        by_scene.setdefault((job.scene, job.site_tag), []).append(with_threads(job))
    environment = {"BIMSCAN_PROGRESS": "0"}  # bars belong to the driver, not to the workers
    if os.environ.get("BIMSCAN_CACHE_DIR"):
        environment["BIMSCAN_CACHE_DIR"] = os.environ["BIMSCAN_CACHE_DIR"]
    pool = make_executor(executor, workers=workers, environment=environment, address=ray_address)
    handles: dict[Any, Any] = {}  # handle -> (scene, site tag) of a scene task | unit id of a unit task

    def submit(name: Any, fn: TaskFunction, job: SceneJob | UnitJob) -> None:
        nonlocal pool
        try:
            handle = pool.submit(fn, job, cpus=threads)
        except BrokenExecutor:  # a worker died hard (killed, out of memory): start a fresh pool
            pool.close()
            pool = make_executor(executor, workers=workers, environment=environment, address=ray_address)
            handle = pool.submit(fn, job, cpus=threads)
        handles[handle] = name

    def write_manifest() -> None:
        folder.write_manifest(Manifest(units=tuple(rows.values())))

    def finish_unit(outcome: UnitOutcome) -> None:
        entry = rows[outcome.unit]
        rows[outcome.unit] = dataclasses.replace(entry, status=outcome.status, error=outcome.error,
                                                 points=outcome.points,
                                                 files=folder.unit_files(outcome.unit, outcome.files))
        result.units.append(outcome)
        write_manifest()

    finished = False
    try:
        # 1. Every scene task first: the units' work is known once their stations are.
        for scene_job in scene_jobs:
            submit((scene_job.scene, scene_job.site_tag), run_scene_job, with_threads(scene_job))
        ready: dict[tuple[str, str], SceneOutcome] = {}
        with progress_bar(total=len(scene_jobs), desc="scenes (load, dress, plan stations)", unit="scene",
                          enabled=progress) as scene_bar:
            while handles:
                for handle, value, error in pool.wait(list(handles), timeout=0.5):
                    name = handles.pop(handle)
                    scene_outcome = value if error is None else SceneOutcome(scene=name[0], error=task_error(error),
                                                                             site_tag=name[1])
                    result.scenes.append(scene_outcome)
                    scene_bar.update(1)
                    if scene_outcome.error is None:
                        ready[name] = scene_outcome
                        continue
                    for job in by_scene[name]:
                        finish_unit(UnitOutcome(unit=job.unit, status="failed",
                                                error=f"scene {name[0]!r}: {scene_outcome.error}"))
        position = {unit: k for k, unit in enumerate(unit_jobs)}  # the plan's order: each scene's largest first
        jobs = sorted((job for name in ready for job in by_scene[name]), key=lambda job: position[job.unit])
        if jobs:
            # 2. The output's size against the free space, before any unit writes.
            works = with_unknown_as_mean([_unit_work(job, ready[(job.scene, job.site_tag)]) for job in jobs])
            finished_units = [(record.bytes, record.points) for record in
                              (folder.read_unit(e.id) for e in rows.values() if e.status == "done")]
            result.estimate = estimate_size(works, folder.root, formats=jobs[0].formats, finished=finished_units)
            log(result.estimate.line())
            check_output_fits(result.estimate)
            # 3. The units, the progress weighted by the pulses each scans.
            work = WorkProgress({w.unit: w.pulses for w in works})
            for job in jobs:
                submit(job.unit, run_unit_job, job)
            with progress_bar(total=work.total, desc="units", unit="pulse", enabled=progress,
                              bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}{postfix}") as unit_bar:
                while handles:
                    for handle, value, error in pool.wait(list(handles), timeout=0.5):
                        name = handles.pop(handle)
                        outcome = value if error is None else UnitOutcome(unit=name, status="failed",
                                                                          error=task_error(error))
                        finish_unit(outcome)
                        work.finished(name, seconds=outcome.seconds if outcome.status == "done" else None)
                    for unit, pulses in pool.drain_pulses().items():
                        work.scanned(unit, pulses)
                    unit_bar.total, unit_bar.n = work.total, work.done  # the total grows with the fitted fixed time
                    unit_bar.set_postfix_str(work.status(), refresh=True)
            result.eta = work.eta_check()
        finished = True
    finally:
        if not finished:
            # Ctrl-C, a refusal or a driver bug: stop the workers, keep what is finished (the manifest says which),
            # and remove the ended workers' staging (workers on other machines: the next build does)
            pool.close(cancel=True)
            if ray_address is None:
                folder.remove_dead_temps()
            write_manifest()
    pool.close()
    # A task cut short (its worker or node died, then run again elsewhere) leaves its staging
    # folder; nothing of this build runs any more.
    folder.remove_leftovers()
    return result


def _unit_work(job: UnitJob, scene: SceneOutcome) -> UnitWork:
    """What a unit will scan, from its scene task's stations and points per pulse."""
    if job.recipe.mobile is not None:  # its walk is planned by its own task
        return UnitWork(unit=job.unit, scene=job.scene, pulses=0.0, points=0.0, most_points=0.0, known=False)
    sensor = job.recipe.sensor
    return tripod_unit_work(job.unit, job.scene, station_pulses=station_pulses(job.recipe), stations=scene.n_stations,
                            points_per_pulse=scene.points_per_pulse,
                            echoes=sensor.max_returns if sensor.returns == "all" else 1)

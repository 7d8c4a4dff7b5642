"""Planning a build: which units are finished, which must be (re)built, and the jobs that do it.

A unit is reused when its folder exists, was built from the same inputs and its files still
match their checksums. Its inputs (``unit_inputs``) are everything its bytes depend on: the scan
recipe (``ScanRecipe.to_json``: scanner, settings, noise, seed and noise stream, engine, how the
stations are chosen, the site model: stage and clutter), the scene file (by content) and station
file (by content), the label
scheme, the output formats, the voxel size and the software version; their fingerprint decides
reuse. Jobs are small picklable records the executors send to worker processes.

Stations depend on the scene as scanned: a scene dressed as a site (clutter, a construction
stage) gets its own stations, planned on the dressed scene, so there is one scene job per
distinct site state of a scene (``site_tag``), shared by the configurations that scan it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bimscan import __version__
from bimscan.dataset.layout import (
    STATIONS_VERSION, DatasetFolder, ManifestEntry, read_json, unit_id, verify_unit, write_json,
)
from bimscan.dataset.spec import DatasetSpec, SceneSpec, resolve_scheme
from bimscan.errors import BimscanError
from bimscan.ifc.generate.styles import GENERATOR_VERSION
from bimscan.files import FOLDER_OUTPUTS, dump_json, file_sha256
from bimscan.survey.mobile import AUTO_TRAJECTORY
from bimscan.survey.recipe import AUTO_STATIONS, ScanRecipe


@dataclass(frozen=True)
class SceneJob:
    """What a scene task needs: parse the IFC (into the geometry cache) and plan or read the stations."""

    scene: str
    ifc: str
    scheme: str
    recipe: ScanRecipe  # the scanner, engine, threads, station source and site of the scene's units
    stations_file: str  # where the chosen stations go
    stations_key: str  # fingerprint of what the stations depend on
    site_tag: str = ""  # the site state ("" for the model as it is)
    site_file: str = ""  # where the dressed scene goes ("" for the model as it is)
    length_unit: str | None = None  # the scene's length unit override


@dataclass(frozen=True)
class UnitJob:
    """What a unit task needs to scan one scene with one recipe into a unit folder."""

    unit: str
    scene: str
    config: str
    ifc: str
    scheme: str
    recipe: ScanRecipe
    formats: tuple[str, ...]
    voxel_size_m: float | None
    out_dir: str
    inputs: Mapping[str, Any]
    fingerprint: str
    site_tag: str = ""  # which of the scene's station files (and dressed scenes) it scans from
    site_key: str = ""  # what its dressed scene must have been dressed from (the scene job's stations key)
    length_unit: str | None = None  # the scene's length unit override


@dataclass(frozen=True)
class BuildPlan:
    """The manifest rows of every unit (finished ones verified, the rest pending or failed), the jobs
    of the units to build, and the scene jobs they wait for."""

    entries: list[ManifestEntry]
    unit_jobs: dict[str, UnitJob]
    scene_jobs: list[SceneJob]


def fingerprint(inputs: Mapping[str, Any]) -> str:
    """SHA-256 of the canonical JSON of a unit's inputs: equal inputs, equal fingerprint."""
    return hashlib.sha256(dump_json(inputs)).hexdigest()


@dataclass(frozen=True)
class SceneFiles:
    """The IFC file of every scene that has one, why the others have none, and what the user
    should know (generated scenes found changed by hand)."""

    files: dict[str, Path]
    errors: dict[str, str]
    notes: tuple[str, ...] = ()


def generate_scenes(spec: DatasetSpec, folder: DatasetFolder) -> SceneFiles:
    """The IFC file of every scene, writing generated buildings that are missing or stale.

    A generated scene is kept only when ``scenes/<scene>.generated.json`` says it was made with
    the spec's options by this software and generator version and the file still has the
    checksum recorded then;
    otherwise it is made again (a scene edited by hand is reported: scan your own model as an
    ``ifc = ...`` scene instead).
    """
    from bimscan.ifc.generate import make_building

    files: dict[str, Path] = {}
    errors: dict[str, str] = {}
    notes: list[str] = []
    for scene in spec.scenes:
        if scene.generate is None:  # an IFC file (the spec holds exactly one of the two)
            files[scene.name] = Path(str(scene.ifc))
            continue
        path = folder.generated_scene_path(scene.name)
        record_path = folder.generated_record_path(scene.name)
        wanted = {"generate": dataclasses.asdict(scene.generate), "software": f"bimscan {__version__}",
                  "generator": GENERATOR_VERSION}
        record = read_json(record_path) if record_path.is_file() else {}
        current = {k: record.get(k) for k in wanted} == wanted
        if path.is_file() and current and file_sha256(path) == record.get("sha256"):
            files[scene.name] = path
            continue
        if path.is_file() and current:
            notes.append(f"scene {scene.name!r}: {path} was changed since it was generated; generated again from its "
                         "options (to scan an edited model, give it as an 'ifc = ...' scene)")
        try:
            make_building(path, **dataclasses.asdict(scene.generate))
        except BimscanError as exc:
            errors[scene.name] = f"could not generate scene {scene.name!r}: {exc}"
            continue
        write_json(record_path, wanted | {"sha256": file_sha256(path)})
        files[scene.name] = path
    return SceneFiles(files=files, errors=errors, notes=tuple(notes))


def scene_inputs(scene: SceneSpec, scene_file: Path) -> dict[str, Any]:
    """The inputs of one scene: its file (by content) and its station file (by content) when given."""
    stations: Any = AUTO_STATIONS
    if scene.stations != AUTO_STATIONS:
        stations = {"file": Path(scene.stations).name, "sha256": file_sha256(Path(scene.stations))}
    return {"scene": {"name": scene.name, "file": scene_file.name, "sha256": file_sha256(scene_file),
                      "generated": None if scene.generate is None else dataclasses.asdict(scene.generate),
                      "length_unit": scene.length_unit},
            "stations": stations}


def unit_inputs(spec: DatasetSpec, scheme: Mapping[str, Any], scene: Mapping[str, Any], config: str,
                recipe: ScanRecipe) -> dict[str, Any]:
    """Everything a unit's bytes depend on (JSON-able); its fingerprint decides reuse."""
    inputs = {**scene, "config": config, "recipe": recipe.to_json(), "scheme": dict(scheme),
              "formats": list(spec.formats), "voxel_size_m": spec.voxel_size_m, "software": f"bimscan {__version__}"}
    if recipe.mobile is not None and recipe.mobile.trajectory_from != AUTO_TRAJECTORY:
        inputs["trajectory_sha256"] = file_sha256(recipe.mobile.trajectory_from)
    return inputs


def site_tag(recipe: ScanRecipe) -> str:
    """A short name of the recipe's site state ("" for the model as it is): the stage and a hash of
    the site model and seed, e.g. ``structure-3fa2c19b0e``."""
    if recipe.site.is_bare:
        return ""
    from bimscan.site import site_settings

    return f"{recipe.site.stage.name}-{fingerprint(site_settings(recipe.site, recipe.seed))[:10]}"


def stations_key(scene: Mapping[str, Any], recipe: ScanRecipe) -> str:
    """Fingerprint of what a scene's chosen stations depend on: the scene and station files, the
    scanner, the site as scanned (stage, clutter, seed) and the planner's version (not the scan
    settings: every configuration of one site state scans the same stations)."""
    from bimscan.site import site_settings

    key = {"ifc": scene["scene"]["sha256"], "stations": scene["stations"],
           "scanner": dataclasses.asdict(recipe.scanner), "software": __version__, "version": STATIONS_VERSION}
    if not recipe.site.is_bare:
        key["site"] = site_settings(recipe.site, recipe.seed)
    return fingerprint(key)


def check_unit_folders(spec: DatasetSpec, folder: DatasetFolder) -> None:
    """OutputError before any work when a unit of ``spec`` would go where a build may never write:
    a file, a link or a folder that is not a bimscan data unit (a unit with files added by hand is
    refused by ``plan_build`` if it is to be rebuilt; kept as it is, it is fine)."""
    for scene in spec.scenes:
        for config in spec.configs:
            path = folder.unit_dir(unit_id(scene.name, config.name))
            if os.path.lexists(path) and (path.is_symlink() or not path.is_dir()
                                          or FOLDER_OUTPUTS["unit"].foreign(path) is None):
                folder.check_unit_folder(unit_id(scene.name, config.name))


def plan_build(spec: DatasetSpec, folder: DatasetFolder, scenes: SceneFiles, *,
               chunk_pulses: int | None = None) -> BuildPlan:
    """Manifest rows for every unit (finished ones verified) and jobs for the rest.

    ``chunk_pulses`` goes into every job's recipe (it does not change the output); the driver
    sets the threads once it knows how many units run at once.
    """
    entries: list[ManifestEntry] = []
    unit_jobs: dict[str, UnitJob] = {}
    scene_jobs: list[SceneJob] = []
    scheme = dataclasses.asdict(resolve_scheme(spec))
    runtime: dict[str, Any] = {} if chunk_pulses is None else {"chunk_pulses": chunk_pulses}
    scene_files, scene_errors = scenes.files, scenes.errors
    for scene in spec.scenes:
        inputs_of_scene = None if scene.name in scene_errors else scene_inputs(scene, scene_files[scene.name])
        scene_recipes: dict[str, ScanRecipe] = {}  # site tag -> the recipe of its first unit to build
        for config in spec.configs:
            uid = unit_id(scene.name, config.name)
            if inputs_of_scene is None:
                entries.append(ManifestEntry(id=uid, scene=scene.name, config=config.name, status="failed",
                                             error=scene_errors[scene.name]))
                continue
            recipe = spec.recipe(scene, config).with_fields(**runtime)
            inputs = unit_inputs(spec, scheme, inputs_of_scene, config.name, recipe)
            key = fingerprint(inputs)
            unit_folder = folder.unit_dir(uid)
            if unit_folder.exists() and verify_unit(unit_folder, expected_fingerprint=key) is None:
                record = folder.read_unit(uid)
                entries.append(ManifestEntry(id=uid, scene=scene.name, config=config.name, status="done",
                                             points=record.points, files=folder.unit_files(uid, record.files)))
                continue
            # stale or damaged: rebuilt; the old folder is swapped out only once the new one is complete, and
            # only when it holds nothing bimscan did not write: found now, before anything is scanned
            folder.check_unit_folder(uid)
            entries.append(ManifestEntry(id=uid, scene=scene.name, config=config.name, status="pending"))
            tag = site_tag(recipe)
            unit_jobs[uid] = UnitJob(unit=uid, scene=scene.name, config=config.name, ifc=str(scene_files[scene.name]),
                                     scheme=spec.scheme, recipe=recipe, formats=spec.formats,
                                     voxel_size_m=spec.voxel_size_m, out_dir=str(folder.root), inputs=inputs,
                                     fingerprint=key, site_tag=tag, site_key=stations_key(inputs_of_scene, recipe),
                                     length_unit=scene.length_unit)
            # the scene task plans (or reads) the tripod stations of the scene, whatever the configuration
            scene_recipes.setdefault(tag, recipe.with_fields(mobile=None, stations_from=scene.stations))
        if inputs_of_scene is not None:
            for tag, scene_recipe in scene_recipes.items():
                stations_file = str(folder.stations_path(scene.name, tag))
                site_file = str(folder.site_scene_path(scene.name, tag)) if tag else ""
                scene_jobs.append(SceneJob(scene=scene.name, ifc=str(scene_files[scene.name]), scheme=spec.scheme,
                                           recipe=scene_recipe, stations_file=stations_file,
                                           stations_key=stations_key(inputs_of_scene, scene_recipe), site_tag=tag,
                                           site_file=site_file, length_unit=scene.length_unit))
    return BuildPlan(entries=entries, unit_jobs=largest_first(unit_jobs), scene_jobs=scene_jobs)


def largest_first(unit_jobs: dict[str, UnitJob]) -> dict[str, UnitJob]:
    """The jobs in the order they should start: a scene's units by their pulses per station, most
    first (the same stations scan them all), so that the workers finish together instead of one
    scanning the scene's largest unit alone at the end (longest processing time first). A mobile
    unit, whose walk is not planned yet, keeps its place after the tripod units of its scene. The
    order changes no output: each unit's bytes depend on its own inputs only."""
    from bimscan.survey.survey import station_pulses

    def size(job: UnitJob) -> int:
        return 0 if job.recipe.mobile is not None else station_pulses(job.recipe)

    order = sorted(unit_jobs, key=lambda unit: -size(unit_jobs[unit]))  # stable: ties keep the spec's order
    return {unit: unit_jobs[unit] for unit in order}

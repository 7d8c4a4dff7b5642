"""The pipeline composed: IFC -> labelled scene -> planned survey -> streamed, checked cloud file.

This thin layer joins the stages for the CLI and for the dataset builder; each stage stays
usable alone (``load_ifc``, ``VirtualScanner``, ``plan_stations``, ``run_survey``,
``open_cloud_writer``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bimscan import __version__
from bimscan.errors import StationError
from bimscan.process.checks import check_semantics, filter_invalid
from bimscan.process.summary import CloudSummary
from bimscan.progress import progress_bar
from bimscan.scan.noise import NoiseModel
from bimscan.scan.device import ScannerModel, ScanSettings, check_settings, load_scanner, load_settings, with_overrides
from bimscan.scan.virtual_scanner import DEFAULT_CHUNK_PULSES, VirtualScanner
from bimscan.survey.run import run_survey, survey_pulses
from bimscan.survey.stations import PlanReport, check_station, plan_stations, read_stations
from bimscan.types import BimScene, CloudHeader, LabelScheme, PointCloud, Station


@dataclass(frozen=True)
class ScanOptions:
    """Everything that decides a scan besides the model (config as data)."""

    preset: str = "exp3"  # preset name (exp1..exp6) or a settings TOML file
    settings: ScanSettings | None = None  # explicit settings (a dataset spec's table); replaces preset
    scanner: str | None = None  # registry name or a scanner TOML file; default riegl_vz400
    stations: str = "auto"  # "auto" or a station CSV file
    seed: int = 0
    noise: NoiseModel = field(default_factory=NoiseModel)
    strict: bool = False
    head_deg_per_s: float | None = None  # overrides the preset's head speed
    engine: str = "open3d"
    threads: int = 0
    chunk_pulses: int = DEFAULT_CHUNK_PULSES


@dataclass(frozen=True)
class Survey:
    """A scene ready to scan: the scanner placed in it, settings, stations."""

    scene: BimScene
    scanner: VirtualScanner
    settings: ScanSettings
    stations: tuple[Station, ...]
    plan: PlanReport | None
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class ScanResult:
    path: Path
    points: int
    survey: Survey
    summary: CloudSummary
    seconds: float
    metadata: dict[str, Any]


def resolve_settings(options: ScanOptions) -> tuple[ScannerModel, ScanSettings, list[str]]:
    """Scanner model and settings of ``options``, validated (warnings for device limits)."""
    model = load_scanner(options.scanner)
    base = options.settings if options.settings is not None else load_settings(options.preset)
    settings = with_overrides(base, head_deg_per_s=options.head_deg_per_s)
    warnings = check_settings(settings, model, strict=options.strict)
    return model, settings, warnings


def choose_stations(scene: BimScene, scanner: VirtualScanner, mode: str) -> tuple[tuple[Station, ...], PlanReport | None]:
    """The stations of a scene: planned (``mode == "auto"``, each then checked) or read from a CSV file."""
    if mode != "auto":
        return read_stations(mode, scene, scanner), None
    stations, plan = plan_stations(scene, scanner)
    for station in stations:
        check_station(station, scene, scanner)
    return stations, plan


def prepare_survey(scene: BimScene, options: ScanOptions, *, scanner: VirtualScanner | None = None,
                   stations: tuple[Station, ...] | None = None) -> Survey:
    """Place the scanner in the scene and fix the stations (planned or from a file).

    ``stations`` given: use them as they are (planned once per scene and reused for every
    configuration, as the dataset builder does); ``options.stations`` is then not consulted.
    """
    model, settings, warnings = resolve_settings(options)
    if scanner is None or scanner.scanner != model:
        scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=model, engine=options.engine,
                                 threads=options.threads)
    if stations is not None:
        if not stations:
            raise StationError(f"{scene.source}: an empty station list was given; pass at least one station")
        return Survey(scene=scene, scanner=scanner, settings=settings, stations=tuple(stations), plan=None,
                      warnings=tuple(warnings))
    stations, plan = choose_stations(scene, scanner, options.stations)
    return Survey(scene=scene, scanner=scanner, settings=settings, stations=stations, plan=plan, warnings=tuple(warnings))


def cloud_origin(scene: BimScene) -> tuple[float, float, float]:
    """Local origin for the writers: the model's lower corner in whole metres."""
    lo, _ = scene.mesh.bounds()
    return tuple(float(math.floor(v)) for v in lo)  # type: ignore[return-value]


def survey_metadata(survey: Survey, options: ScanOptions) -> dict[str, Any]:
    """What a cloud file records about how it was made (JSON-able)."""
    settings = dataclasses.asdict(survey.settings)
    return {
        "software": f"bimscan {__version__}",
        "source": {"file": Path(survey.scene.source).name, "sha256": survey.scene.file_sha256, "schema": survey.scene.schema},
        "scanner": dataclasses.asdict(survey.scanner.scanner),
        "preset": options.preset if options.settings is None else None,
        "settings": settings,
        "noise": dataclasses.asdict(options.noise),
        "seed": options.seed,
        "engine": options.engine,
        "stations": [dataclasses.asdict(s) for s in survey.stations],
        "device_warnings": list(survey.warnings),
    }


def cloud_header(survey: Survey, options: ScanOptions, *, extra_metadata: dict[str, Any] | None = None) -> CloudHeader:
    """The header every writer stores with the survey's cloud (scheme, components, stations, metadata)."""
    scene = survey.scene
    metadata = survey_metadata(survey, options) | (extra_metadata or {})
    return CloudHeader(scheme=scene.scheme, components=scene.components, stations=survey.stations,
                       origin=cloud_origin(scene), metadata=metadata)


def stream_survey(survey: Survey, options: ScanOptions, *, summary: CloudSummary,
                  on_pulses: Callable[[int], None] | None = None) -> Iterator[PointCloud]:
    """The survey's merged cloud as filtered, semantically checked chunks.

    Every chunk has its invalid points dropped (counted in ``summary.dropped_invalid``) and is
    checked against the component table (``SemanticError`` on a contradiction) before it is
    yielded; ``summary`` accumulates counts, extents and histograms of what is yielded. A chunk
    is valid until the next one is requested (the scanner reuses its buffers): write it out or
    copy it first.
    """
    for chunk in run_survey(survey.scanner, survey.stations, survey.settings, noise=options.noise,
                            seed=options.seed, chunk_pulses=options.chunk_pulses, on_pulses=on_pulses,
                            reuse_buffers=True):
        chunk, dropped = filter_invalid(chunk)
        summary.dropped_invalid += dropped
        check_semantics(chunk, survey.scene.components)
        summary.add(chunk)
        yield chunk


def scan_survey(survey: Survey, out: str | Path, options: ScanOptions, *, overwrite: bool = False,
                progress: bool = True, extra_metadata: dict[str, Any] | None = None) -> ScanResult:
    """Scan every station and stream the merged cloud to ``out`` (format by suffix), checked.

    Every chunk is filtered for invalid points and checked for semantic consistency before it is
    written; the file appears only when complete (the writer renames a temporary file).
    """
    from bimscan.io import open_cloud_writer

    start = time.perf_counter()
    header = cloud_header(survey, options, extra_metadata=extra_metadata)
    metadata = dict(header.metadata)
    summary = CloudSummary()
    total = survey_pulses(survey.stations, survey.settings, survey.scanner)
    writer = open_cloud_writer(out, header=header, overwrite=overwrite)
    finished = False
    try:
        with progress_bar(total=total, desc="scanning", unit="pulse", enabled=progress) as bar:
            for chunk in stream_survey(survey, options, summary=summary, on_pulses=bar.update):
                writer.write(chunk)
        written = writer.close()
        finished = True
    finally:
        if not finished:
            writer.abort()  # never leave a half-written cloud, whatever stopped us (Ctrl-C included)
    path = Path(written.path)
    return ScanResult(path=path, points=summary.points, survey=survey, summary=summary,
                      seconds=time.perf_counter() - start, metadata=metadata)


def load_label_scheme(source: str | Path | LabelScheme | None = None) -> LabelScheme:
    """A label scheme (None: spc5; a built-in name, a TOML file, or one already loaded) whose rules
    name only IFC classes that some supported schema knows (a misspelt class is a SchemeError)."""
    from bimscan.ifc.schema import known_classes
    from bimscan.semantics import check_rule_classes, load_scheme

    scheme = source if isinstance(source, LabelScheme) else load_scheme(source)
    check_rule_classes(scheme, known_classes())
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


def scan_model(model: str | Path, out: str | Path, options: ScanOptions = ScanOptions(), *, scheme: str | None = None,
               overwrite: bool = False, progress: bool = True) -> ScanResult:
    """IFC file -> labelled multi-station cloud file: the whole of ``bimscan scan``."""
    from bimscan.io import check_cloud_output

    check_cloud_output(out, overwrite=overwrite)  # output and settings errors before the (slow) parse
    resolve_settings(options)
    scene = load_scene(model, scheme=scheme)
    survey = prepare_survey(scene, options)
    return scan_survey(survey, out, options, overwrite=overwrite, progress=progress)

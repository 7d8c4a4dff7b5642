"""The plan folder: what ``bimscan plan`` writes, and the one place that knows its layout.

- ``stations.csv``: the stations in scan order, a station file ``bimscan scan --stations`` reads
  as it is (``survey.stations.format_stations``);
- ``coverage.csv``: one row per element of the chosen classes (GlobalId, IFC class, class,
  storey, name, areas, covered fraction, median density, status; with a scan measured, the same
  figures on the scan);
- ``registration.csv``: the registration graph's edges between the stations;
- ``plan.json``: the settings, the per-class figures, the stations, how they were chosen and the
  stations each coverage of the ladder needs, and what loading the IFC repaired or lost;
- ``plan_<n>_<storey>.png``: a picture per storey (``render.survey_plan``).

The folder is written under a temporary name and renamed when complete. An existing OUT is
replaced only with ``overwrite`` and only when it is a plan folder (it holds ``plan.json`` written
by ``bimscan plan`` and nothing but the files that plan wrote: its fixed files and the pictures its
``plan.json`` lists), as ``bimscan.files.check_replaceable`` decides for every output: bimscan
never removes what it did not write (a ``plan_signed_by_client.png`` put beside a plan included).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import (
    FOLDER_OUTPUTS, FolderOutput, check_replaceable, csv_bytes, dump_json, folder_entries, read_marker, remove_path, replace_path,
    temp_path,
)
from bimscan.ifc.summary import report_document
from bimscan.survey.planning.plan import PlanEvaluation, SurveyPlan
from bimscan.survey.stations import format_stations

if TYPE_CHECKING:
    from bimscan.survey.recipe import ScanRecipe

STATIONS_FILE = "stations.csv"
COVERAGE_FILE = "coverage.csv"
REGISTRATION_FILE = "registration.csv"
SUMMARY_FILE = "plan.json"
PLAN_KIND = "bimscan plan"
COVERAGE_COLUMNS = ("global_id", "ifc_class", "class", "storey", "name", "area_m2", "visible_m2", "edge_on_m2",
                    "covered_fraction", "median_density_pts_m2", "status")
SCAN_COLUMNS = ("scan_covered_fraction", "scan_median_density_pts_m2", "scan_status")


def foreign_plan_entries(folder: Path) -> list[str] | None:
    """The entries of ``folder`` a plan did not write (its fixed files and the pictures its
    ``plan.json`` lists are its own), or None when it is no plan folder (its ``plan.json`` is
    missing or not a plan's): ``FOLDER_OUTPUTS["plan"]``."""
    try:
        summary = json.loads(read_marker(folder / SUMMARY_FILE) or b"")
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(summary, dict) or summary.get("kind") != PLAN_KIND:
        return None
    pictures = summary.get("pictures")
    if not isinstance(pictures, list) or not all(isinstance(name, str) for name in pictures):
        return None
    own = {STATIONS_FILE, COVERAGE_FILE, REGISTRATION_FILE, SUMMARY_FILE, *pictures}
    return [name for name in folder_entries(folder) if name not in own]


FOLDER_OUTPUTS["plan"] = FolderOutput(what="a bimscan plan folder", foreign=foreign_plan_entries)


def check_plan_output(out: Path, *, overwrite: bool) -> None:
    """Raise OutputError now (before any slow work) when the plan folder cannot be written: an
    existing OUT is replaced only with ``overwrite`` and only when ``check_replaceable`` allows it."""
    if not out.parent.is_dir():
        raise OutputError(f"output folder {out.parent} does not exist; create it first or choose another OUT")
    if os.path.lexists(out) and not overwrite:
        raise OutputError(f"{out} already exists; pass --overwrite to replace a plan folder, or choose another OUT")
    check_replaceable(out, kind="plan")


def _number(value: float, digits: int = 4) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def coverage_rows(evaluation: PlanEvaluation, scan: PlanEvaluation | None = None) -> list[dict[str, str]]:
    """The rows of ``coverage.csv``: by storey, class, then GlobalId."""
    measured = {e.component: e for e in scan.elements} if scan is not None else {}
    rows = []
    for e in sorted(evaluation.elements, key=lambda e: (e.storey, e.klass, e.global_id)):
        row = {"global_id": e.global_id, "ifc_class": e.ifc_class, "class": e.klass, "storey": e.storey,
               "name": e.name, "area_m2": _number(e.area_m2, 3), "visible_m2": _number(e.visible_m2, 3),
               "edge_on_m2": _number(e.edge_on_m2, 3), "covered_fraction": _number(e.covered_fraction),
               "median_density_pts_m2": _number(e.median_density_pts_m2, 1), "status": e.status}
        if scan is not None:
            m = measured[e.component]
            row |= {"scan_covered_fraction": _number(m.covered_fraction),
                    "scan_median_density_pts_m2": _number(m.median_density_pts_m2, 1), "scan_status": m.status}
        rows.append(row)
    return rows


def write_plan_folder(out: Path, plan: SurveyPlan, evaluation: PlanEvaluation, *, summary: dict[str, Any],
                      scan: PlanEvaluation | None = None, overwrite: bool = False,
                      pictures: Callable[[Path], list[str]] | None = None) -> list[str]:
    """Write the plan folder (see the module docs) atomically; returns the names written.
    ``summary``: the ``plan.json`` document (``kind`` is added); ``pictures(folder)`` draws the
    pictures into the staged folder and returns their names."""
    check_plan_output(out, overwrite=overwrite)
    staged = temp_path(out)
    staged.mkdir()
    try:
        config = plan.space.config
        comments = (f"bimscan plan of {Path(plan.space.scene.source).name}: {len(plan.stations)} stations in scan "
                    f"order, for {', '.join(config.classes)} at {config.density_pts_m2:g} points/m2",)
        (staged / STATIONS_FILE).write_text(format_stations(plan.stations, comments=comments), "utf-8")
        columns = COVERAGE_COLUMNS + (SCAN_COLUMNS if scan is not None else ())
        (staged / COVERAGE_FILE).write_bytes(csv_bytes(coverage_rows(evaluation, scan), columns))
        edges = [{"station_a": str(a), "station_b": str(b), "shared_m2": _number(shared, 2),
                  "shared_fraction": _number(fraction), "weakest_direction_share": _number(weakest)}
                 for a, b, shared, fraction, weakest in evaluation.edges]
        (staged / REGISTRATION_FILE).write_bytes(csv_bytes(edges, ("station_a", "station_b", "shared_m2", "shared_fraction",
                                                              "weakest_direction_share")))
        names = pictures(staged) if pictures is not None else []
        document = {"kind": PLAN_KIND, **summary, "pictures": names}
        (staged / SUMMARY_FILE).write_bytes(dump_json(document))
        replace_path(staged, out, kind="plan")
    finally:
        remove_path(staged)  # gone already when the rename succeeded
    return [STATIONS_FILE, COVERAGE_FILE, REGISTRATION_FILE, SUMMARY_FILE, *names]


def _finite(value: Any) -> Any:
    """JSON-able: NaN becomes None (the plan's figures are NaN where a class has no visible surface)."""
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def plan_summary(plan: SurveyPlan, evaluation: PlanEvaluation, scan: PlanEvaluation | None, recipe: ScanRecipe, *,
                 mode: str,
                 density_ratio: tuple[float, float, float] | None = None) -> dict[str, Any]:
    """The ``plan.json`` document of a plan (JSON-able, the same bytes for the same inputs)."""
    from bimscan import __version__

    space = plan.space
    scene, config, grid = space.scene, space.config, space.grid
    classes = {}
    for name, figures in evaluation.classes.items():
        entry = {k: (round(v, 6) if isinstance(v, float) else v) for k, v in figures.items()}
        if scan is not None:
            entry["scan_covered_fraction"] = round(scan.classes[name]["covered_fraction"], 6)
        classes[name] = entry
    statuses: dict[str, int] = {}
    for element in evaluation.elements:
        statuses[element.status] = statuses.get(element.status, 0) + 1
    document = {
        "mode": mode,
        "software": f"bimscan {__version__}",
        "source": {"file": Path(scene.source).name, "sha256": scene.file_sha256, "schema": scene.schema},
        # what loading the IFC repaired, assumed or lost, as 'bimscan info --json' gives it
        "load_report": report_document(scene.report),
        "failed": [dataclasses.asdict(f) for f in scene.failed],
        "config": config.to_json(),
        "scanner": recipe.scanner.name,
        "preset": recipe.preset,
        "angular_step_deg": {"vertical": round(float(np.degrees(grid.vertical_step_rad)), 6),
                             "horizontal": round(float(np.degrees(grid.horizontal_step_rad)), 6)},
        "reach_m": round(grid.reach_m(config.density_pts_m2), 3),
        "site": None if scene.site is None else scene.site.to_json(),
        "candidate_spots": space.n_spots,
        "surface_samples": len(space.samples),
        "solver": None if plan.solver is None else plan.solver.to_json(),
        "coverage_ladder": None if plan.solver is None else [
            {"coverage": rung.coverage, "stations": rung.stations} for rung in plan.ladder],
        "stations": [{"id": s.id, "position": [round(v, 4) for v in s.position],
                      "floor_z": None if s.floor_z is None else round(s.floor_z, 4), "storey": s.storey,
                      "room": s.room} for s in plan.stations],
        "classes": classes,
        "met": evaluation.met(),
        "registration": {"edges": len(evaluation.edges), "parts": evaluation.parts,
                         "spot_parts": evaluation.spot_parts},
        "elements": dict(sorted(statuses.items())),
    }
    if scan is not None:
        document["scan_met"] = scan.met()
        document["scan_density_over_estimate_quartiles"] = None if density_ratio is None else [
            round(v, 4) for v in density_ratio]
    return _finite(document)

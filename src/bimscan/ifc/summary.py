"""A plain summary of a parsed model (what ``bimscan info`` prints), and its load report in words."""

from __future__ import annotations

import dataclasses
from collections import Counter
from typing import Any

from bimscan.ifc.units import unit_name
from bimscan.ifc.report import IfcLoadReport
from bimscan.types import BimScene, ParsedModel

# What each issue kind is called in a report line ("3 dangling references").
ISSUE_WORDS = {
    "syntax": ("statement that does not parse", "statements that do not parse"),
    "unknown-entity": ("instance of an unknown entity", "instances of unknown entities"),
    "duplicate-id": ("id defined twice", "ids defined twice"),
    "dangling-reference": ("dangling reference", "dangling references"),
    "attribute-count": ("instance with a wrong attribute count", "instances with a wrong attribute count"),
    "invalid-attribute": ("invalid attribute value", "invalid attribute values"),
    "length-unit": ("length unit assumed", "length units assumed"),
}
REPAIR_WORDS = {
    "schema": "FILE_SCHEMA naming a schema IfcOpenShell does not read, read as its closest successor",
    "derived-attribute": "'*' (derived) in attributes the schema does not derive, read as unset",
    "globalid": "GlobalIds missing or not a string ('$', '*', a number), given one made from the file's hash",
}
_SHOWN_LINES = 5
_SHOWN_FAILURES = 3


def _plural(count: int, words: tuple[str, str]) -> str:
    return f"{count} {words[0] if count == 1 else words[1]}"


def _lines(lines: tuple[int, ...], count: int) -> str:
    if not lines:
        return ""
    shown = ", ".join(str(n) for n in lines[:_SHOWN_LINES])
    more = ", ..." if count > len(lines[:_SHOWN_LINES]) else ""
    return f" (line{'s' if len(lines) > 1 or count > 1 else ''} {shown}{more})"


def report_lines(model: ParsedModel | BimScene) -> list[str]:
    """One line per kind of thing the load lost, found wrong or repaired (the CLI prints each as
    ``warning: ...``): failed elements first, then file problems, then repairs. Empty when clean."""
    name = model.source
    report = model.report
    lines = []
    if model.failed:
        shown = "; ".join(
            f"{f.ifc_class} #{f.step_id}" + (f" (line {f.line})" if f.line else "") + f": {f.reason}"
            for f in model.failed[:_SHOWN_FAILURES])
        more = f"; and {len(model.failed) - _SHOWN_FAILURES} more" if len(model.failed) > _SHOWN_FAILURES else ""
        lines.append(f"{name}: {len(model.failed)} of {report.declared_elements or len(model.failed)} declared elements "
                     f"not loaded: {shown}{more}")
    for issue in report.issues:
        words = ISSUE_WORDS.get(issue.kind, (issue.kind, issue.kind))
        lines.append(f"{name}: {_plural(issue.count, words)}{_lines(issue.lines, issue.count)}: {issue.example}")
    for repair in report.repairs:
        classes = ", ".join(f"{k} {v}" for k, v in repair.per_class.items())
        named = _made_up_names(model) if repair.kind == "globalid" else ""
        lines.append(f"{name}: repaired {repair.count} {REPAIR_WORDS.get(repair.kind, repair.kind)}: {classes}"
                     f"{_lines(repair.lines, repair.count)}{named}")
    return lines


def _made_up_names(model: ParsedModel | BimScene) -> str:
    """"; bimscan's outputs name #57 (IfcWall 'south') 2ppg...": the GlobalIds bimscan made up for
    loaded elements (what a cloud's component table and a plan's coverage.csv call them), the
    first few; empty when no loaded element needed one."""
    from bimscan.ifc.step import derived_global_id

    table = model.components
    if table.step_id is None:
        return ""
    made_up = [c for c in range(len(table)) if table.step_id[c] >= 0
               and table.global_id[c] == derived_global_id(model.file_sha256, int(table.step_id[c]))]
    if not made_up:
        return ""
    shown = ", ".join(f"#{table.step_id[c]} ({table.ifc_class[c]}"
                      + (f" {str(table.name[c])!r}" if table.name[c] else "") + f") {table.global_id[c]}"
                      for c in made_up[:_SHOWN_FAILURES])
    more = f" and {len(made_up) - _SHOWN_FAILURES} more" if len(made_up) > _SHOWN_FAILURES else ""
    return f"; bimscan's outputs name {shown}{more}"


def report_document(report: IfcLoadReport) -> dict[str, Any]:
    """The load report as plain JSON-able data (for unit metadata and ``info --json``)."""
    document = dataclasses.asdict(report)
    document["repairs"] = [dict(r, count=sum(r["per_class"].values())) for r in document["repairs"]]
    return document


def summarize_scene(scene: BimScene) -> dict[str, Any]:
    """JSON-able summary: schema, counts per IFC class and label, failures, load report, bounds (metres)."""
    names = scene.scheme.names
    by_label = Counter(names[int(i)] for i in scene.components.label)
    lo, hi = scene.mesh.bounds()
    return {
        "file": scene.source,
        "sha256": scene.file_sha256,
        "schema": scene.schema,
        "components": len(scene.components),
        "declared_elements": scene.report.declared_elements,
        "triangles": scene.mesh.n_triangles,
        "by_ifc_class": dict(sorted(Counter(scene.components.ifc_class.tolist()).items())),
        "scheme": scene.scheme.name,
        "by_label": {c.name: by_label.get(c.name, 0) for c in scene.scheme.classes},
        "fell_through_to_default": {"label": scene.scheme.default_label, "ifc_classes": dict(scene.unmapped_classes)},
        "failed": [dataclasses.asdict(f) for f in scene.failed],
        "load_report": report_document(scene.report),
        "storeys": [{"name": s.name, "elevation_m": s.elevation_m} for s in scene.storeys],
        "spaces": len(scene.spaces),
        "bounds": {"min": [round(float(x), 6) for x in lo], "max": [round(float(x), 6) for x in hi]},
    }


def format_summary(summary: dict[str, Any]) -> str:
    """The summary as a short human-readable report."""
    report = summary["load_report"]
    unit = unit_name(report["length_unit_m"]) + {"file": "", "assumed": " (assumed)", "override": " (given)"}.get(
        report["length_unit_source"], "")
    lines = [
        f"{summary['file']}  ({summary['schema']})",
        f"  components {summary['components']} of {summary['declared_elements']} declared elements, "
        f"triangles {summary['triangles']}, spaces {summary['spaces']}",
        f"  length unit {unit}",
        "  bounds (m)  min " + " ".join(f"{v:.3f}" for v in summary["bounds"]["min"])
        + "  max " + " ".join(f"{v:.3f}" for v in summary["bounds"]["max"]),
        "  storeys     " + (", ".join(f"{s['name'] or '(unnamed)'} @ {s['elevation_m']:g} m" for s in summary["storeys"]) or "none"),
        f"  labels ({summary['scheme']}):",
    ]
    lines += [f"    {name:<14} {count:>7}" for name, count in summary["by_label"].items()]
    lines.append("  IFC classes:")
    lines += [f"    {name:<28} {count:>7}" for name, count in summary["by_ifc_class"].items()]
    fell = summary["fell_through_to_default"]
    if fell["ifc_classes"]:
        lines.append(f"  fell through to default class {fell['label']!r}: "
                     + ", ".join(f"{k} ({v})" for k, v in fell["ifc_classes"].items()))
    if summary["failed"]:
        lines.append(f"  failed elements ({len(summary['failed'])}), skipped:")
        lines += [f"    {f['ifc_class']} #{f['step_id']} {f['global_id']}"
                  + (f" (line {f['line']})" if f["line"] else "") + f" [{f['cause']}]: {f['reason']}"
                  for f in summary["failed"]]
    if report["issues"]:
        lines.append("  problems in the file:")
        lines += [f"    {i['kind']} x{i['count']}: {i['example']}" for i in report["issues"]]
    if report["repairs"]:
        lines.append("  repaired:")
        lines += [f"    {r['kind']} x{r['count']}: " + ", ".join(f"{k} {v}" for k, v in r["per_class"].items())
                  for r in report["repairs"]]
    return "\n".join(lines)

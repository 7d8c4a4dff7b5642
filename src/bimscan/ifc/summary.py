"""A plain summary of a parsed model (what ``bimscan info`` prints)."""

from __future__ import annotations

from collections import Counter
from typing import Any

from bimscan.types import BimScene


def summarize_scene(scene: BimScene) -> dict[str, Any]:
    """JSON-able summary: schema, counts per IFC class and label, failures, bounds (metres)."""
    names = scene.scheme.names
    by_label = Counter(names[int(i)] for i in scene.components.label)
    lo, hi = scene.mesh.bounds()
    return {
        "file": scene.source,
        "sha256": scene.file_sha256,
        "schema": scene.schema,
        "components": len(scene.components),
        "triangles": scene.mesh.n_triangles,
        "by_ifc_class": dict(sorted(Counter(scene.components.ifc_class.tolist()).items())),
        "scheme": scene.scheme.name,
        "by_label": {c.name: by_label.get(c.name, 0) for c in scene.scheme.classes},
        "fell_through_to_default": {"label": scene.scheme.default_label, "ifc_classes": dict(scene.unmapped_classes)},
        "failed": [{"global_id": f.global_id, "ifc_class": f.ifc_class, "reason": f.reason} for f in scene.failed],
        "storeys": [{"name": s.name, "elevation_m": s.elevation_m} for s in scene.storeys],
        "spaces": len(scene.spaces),
        "bounds": {"min": [round(float(x), 6) for x in lo], "max": [round(float(x), 6) for x in hi]},
    }


def format_summary(summary: dict[str, Any]) -> str:
    """The summary as a short human-readable report."""
    lines = [
        f"{summary['file']}  ({summary['schema']})",
        f"  components {summary['components']}, triangles {summary['triangles']}, spaces {summary['spaces']}",
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
        lines += [f"    {f['ifc_class']} {f['global_id']}: {f['reason']}" for f in summary["failed"]]
    return "\n".join(lines)

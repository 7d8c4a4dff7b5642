"""Write a dataset's statistics: CSV tables, JSON, PNG plots and a Markdown report.

Files written to the output folder (each atomically):

- ``units.csv``: one row per finished unit: points, min/max/extent along X, Y, Z, class counts and shares;
- ``configs.csv``: one row per configuration (Figs. 4-6 in numbers);
- ``scenes.csv``: one row per scene: points range, extent spread, class spread;
- ``stats.json``: all of the above;
- ``points.png``, ``extents.png``, ``classes.png``: Figs. 4, 5 and 6;
- ``report.md``: the plots and tables, and whether extents and class shares stay stable
  across configurations, in numbers.

The folder is an output folder (``bimscan.files.prepare_output_folder``): a new or empty one, or
one bimscan made; a user's file at one of these names is refused before the units are read.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

from bimscan.files import check_output_folder, dump_json, json_marker, prepare_output_folder, read_marker, write_atomic
from bimscan.stats.collect import collect_units
from bimscan.stats.plots import plot_classes, plot_extents, plot_points
from bimscan.stats.summary import AXES, DatasetStats, summarize_dataset

# What the report calls stable (the paper's Figs. 5 and 6 claim "highly consistent").
STABLE_EXTENT_SPREAD = 0.05  # 5 % of the extent
STABLE_CLASS_SPREAD_PP = 5.0  # 5 percentage points


STATS_FILES = ("units.csv", "configs.csv", "scenes.csv", "stats.json", "points.png", "extents.png", "classes.png",
               "report.md")


def is_earlier_stats(folder: Path) -> bool:
    """Whether ``folder`` holds statistics written before output folders had records (its stats.json)."""
    return json_marker(read_marker(folder / "stats.json"), "configs")


@dataclass(frozen=True)
class StatsOutputs:
    out_dir: Path
    files: tuple[Path, ...]
    stats: DatasetStats


def _csv(rows: list[list[object]]) -> bytes:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerows(rows)
    return buffer.getvalue().encode("utf-8")


def _f(value: float, digits: int = 4) -> str:
    return f"{value:.{digits}f}"


def units_table(stats: DatasetStats) -> list[list[object]]:
    header = ["unit", "scene", "config", "points", *(f"min_{a}_m" for a in AXES), *(f"max_{a}_m" for a in AXES),
              *(f"size_{a}_m" for a in AXES), *(f"count_{c}" for c in stats.classes), *(f"pct_{c}" for c in stats.classes)]
    rows: list[list[object]] = [header]
    for u in stats.units:
        shares = u.proportions_pct(stats.classes)
        rows.append([u.unit, u.scene, u.config, u.points, *(_f(v) for v in u.minimum), *(_f(v) for v in u.maximum),
                     *(_f(v) for v in u.size), *(u.class_counts.get(c, 0) for c in stats.classes),
                     *(_f(v, 3) for v in shares)])
    return rows


def configs_table(stats: DatasetStats) -> list[list[object]]:
    header = ["config", "units", "points_total", "points_mean", "points_min", "points_max",
              *(f"size_{a}_mean_m" for a in AXES), *(f"pct_{c}" for c in stats.classes)]
    rows: list[list[object]] = [header]
    for c in stats.configs:
        rows.append([c.config, c.units, c.points_total, _f(c.points_mean, 1), c.points_min, c.points_max,
                     *(_f(v) for v in c.size_mean_m), *(_f(c.proportions_pct[k], 3) for k in stats.classes)])
    return rows


def scenes_table(stats: DatasetStats) -> list[list[object]]:
    header = ["scene", "configs", "points_min", "points_max", *(f"extent_spread_{a}_pct" for a in AXES),
              "max_class_spread_pp"]
    rows: list[list[object]] = [header]
    for s in stats.scenes:
        rows.append([s.scene, len(s.configs), min(s.points.values()), max(s.points.values()),
                     *(_f(100 * v, 3) for v in s.extent_spread), _f(s.max_class_spread_pp, 3)])
    return rows


def _markdown_table(rows: list[list[object]]) -> str:
    lines = ["| " + " | ".join(str(v) for v in rows[0]) + " |", "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(str(v) for v in row) + " |" for row in rows[1:]]
    return "\n".join(lines)


def format_report(stats: DatasetStats, *, title: str) -> str:
    """The Markdown report (plots referenced by file name, beside it)."""
    extent, extent_scene, extent_axis = stats.max_extent_spread()
    share, share_scene, share_class = stats.max_class_spread()
    multi = [s for s in stats.scenes if len(s.configs) >= 2]
    total = sum(u.points for u in stats.units)
    out = [f"# {title}", ""]
    out.append(f"{len(stats.units)} finished units ({len(stats.scenes)} scenes x {len(stats.configs)} configurations), "
               f"{total:,} points in all.")
    if stats.missing:
        out.append("")
        out.append(f"{len(stats.missing)} unit(s) are not in these statistics: "
                   + "; ".join(f"{m.id} ({m.status}{': ' + m.error if m.error else ''})"
                               for m in stats.missing))
    out += ["", "## Stability across configurations", ""]
    if not multi:
        out.append("No scene has two or more finished configurations: nothing to compare.")
    else:
        extent_ok = extent <= STABLE_EXTENT_SPREAD
        share_ok = share <= STABLE_CLASS_SPREAD_PP
        out.append(f"- Spatial extents: the largest relative spread of a scene's extent across its configurations "
                   f"is {100 * extent:.2f} % (scene {extent_scene}, axis {extent_axis.upper()}), so extents "
                   f"{'stay stable' if extent_ok else 'do NOT stay stable'} (threshold {100 * STABLE_EXTENT_SPREAD:.0f} %).")
        out.append(f"- Class proportions: the largest spread of a class share across a scene's configurations is "
                   f"{share:.2f} percentage points (scene {share_scene}, class {share_class}), so proportions "
                   f"{'stay stable' if share_ok else 'do NOT stay stable'} (threshold {STABLE_CLASS_SPREAD_PP:.0f} pp).")
        if stats.configs:
            shares = {c: [cfg.proportions_pct[c] for cfg in stats.configs] for c in stats.classes}
            dataset_spread = max((max(v) - min(v) for v in shares.values()), default=0.0)
            out.append(f"- Over all scenes together, class shares differ between configurations by at most "
                       f"{dataset_spread:.2f} percentage points.")
    out += ["", "## Points per configuration (Fig. 4)", "", "![points per configuration](points.png)", "",
            _markdown_table(_points_rows(stats)), "",
            "## Spatial extents (Fig. 5)", "", "![extents per configuration](extents.png)", "",
            _markdown_table(_extent_rows(stats)), "",
            "## Class proportions (Fig. 6)", "", "![class proportions per configuration](classes.png)", "",
            _markdown_table(_class_rows(stats)), "",
            "## Per scene", "", _markdown_table(scenes_table(stats)), "",
            "Tables as CSV: `units.csv`, `configs.csv`, `scenes.csv`; everything in `stats.json`.", ""]
    return "\n".join(out)


def _points_rows(stats: DatasetStats) -> list[list[object]]:
    rows: list[list[object]] = [["config", "units", "total", "mean per scene", "min", "max"]]
    for c in stats.configs:
        rows.append([c.config, c.units, f"{c.points_total:,}", f"{c.points_mean:,.0f}", f"{c.points_min:,}",
                     f"{c.points_max:,}"])
    return rows


def _extent_rows(stats: DatasetStats) -> list[list[object]]:
    configs = [c.config for c in stats.configs]
    rows: list[list[object]] = [["scene", *configs, "spread"]]
    for s in stats.scenes:
        cells = [" x ".join(f"{v:.2f}" for v in s.size_m[c]) if c in s.size_m else "-" for c in configs]
        rows.append([s.scene, *cells, f"{100 * s.max_extent_spread:.2f} %"])
    return rows


def _class_rows(stats: DatasetStats) -> list[list[object]]:
    rows: list[list[object]] = [["config", *stats.classes]]
    for c in stats.configs:
        rows.append([c.config, *(f"{c.proportions_pct[k]:.2f} %" for k in stats.classes)])
    return rows


def write_stats(dataset_dir: str | Path, out_dir: str | Path | None = None, *, from_clouds: bool = False,
                verify: bool = False) -> StatsOutputs:
    """Compute and write the statistics of a built dataset (default output: ``DATASET_DIR/stats``).

    ``verify``: check every finished unit's files against the checksums in its unit.json first
    (a DatasetError names the first damaged unit).
    """
    from bimscan.errors import DatasetError

    dataset = Path(dataset_dir)
    out = Path(out_dir) if out_dir is not None else dataset / "stats"
    check_output_folder(out, names=STATS_FILES, made_by=is_earlier_stats)  # before the units are read
    collected = collect_units(dataset, from_clouds=from_clouds, verify=verify)
    if not collected.units:
        raise DatasetError(f"{dataset}: no finished unit to summarise; run 'bimscan build' first")
    stats = summarize_dataset(collected)
    prepare_output_folder(out, names=STATS_FILES, made_by=is_earlier_stats)
    outputs = {
        "units.csv": _csv(units_table(stats)),
        "configs.csv": _csv(configs_table(stats)),
        "scenes.csv": _csv(scenes_table(stats)),
        "stats.json": dump_json(stats.to_json()),
        "points.png": plot_points(stats),
        "extents.png": plot_extents(stats),
        "classes.png": plot_classes(stats),
        "report.md": format_report(stats, title=f"Statistics of {dataset.resolve().name}").encode("utf-8"),
    }
    for name, data in outputs.items():
        write_atomic(out / name, data)
    return StatsOutputs(out_dir=out, files=tuple(out / n for n in outputs), stats=stats)

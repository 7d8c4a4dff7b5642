"""Pictures of a scan-against-model comparison, one pair per storey.

``progress_<n>_<storey>.png``: the model's surfaces seen from above (walls and floor) and from
below (the ceiling), every surface sample a dot coloured by its element's status: built, built
out of tolerance, not built, not visible; with the views the scan was seen from.
``deviation_<n>_<storey>.png``: the scan's points on the model, coloured by their signed distance
to the nearest model surface (in front of it: red; behind it: blue), from -2 to +2 tolerances.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bimscan.files import save_png
from bimscan.render.survey_plan import frame_plan_view, storey_bands, storey_slug

STATUS_COLORS = {"built": "#2ca02c", "built out of tolerance": "#ff7f0e", "not built": "#d62728",
                 "not visible": "#c7c7c7"}
MAX_DOTS = 200_000  # per panel: a picture is for the eye
DOT_PT = 1.4  # a surface sample's square, points across


def _slug(prefix: str, index: int, name: str) -> str:
    return storey_slug(index, name).replace("plan_", f"{prefix}_", 1)


def draw_progress_pictures(folder: Path, *, title: str, storeys: list[tuple[str, float]], sample_xyz: np.ndarray,
                           sample_normal_z: np.ndarray, sample_status: np.ndarray, view_origins: np.ndarray,
                           point_xyz: np.ndarray, point_signed: np.ndarray, tolerance_m: float) -> list[str]:
    """Write the pictures (see the module docs) into ``folder``; returns their file names.

    storeys: (name, elevation) lowest first; sample_xyz (S, 3), sample_normal_z (S,) (outward) and
    sample_status (S,) str of the model's surface samples; view_origins (V, 3); point_xyz (P, 3)
    and point_signed (P,) metres: a sample of the scan's points attached to the model."""
    elevations = np.array([e for _, e in storeys] or [float(sample_xyz[:, 2].min()) if len(sample_xyz) else 0.0])
    names = [n for n, _ in storeys] or [""]
    band, ceiling = storey_bands(sample_xyz[:, 2], sample_normal_z, elevations)
    point_band, _ = storey_bands(point_xyz[:, 2], np.zeros(len(point_xyz)), elevations)
    view_band, _ = storey_bands(view_origins[:, 2] - 1.5, np.zeros(len(view_origins)), elevations)
    lo = sample_xyz.min(axis=0) if len(sample_xyz) else np.zeros(3)
    hi = sample_xyz.max(axis=0) if len(sample_xyz) else np.ones(3)
    written = []
    for index, name in enumerate(names):
        mine = band == index
        if not mine.any():
            continue
        label = f"{title} - {name or 'all levels'}"
        status_name = _slug("progress", index + 1, name)
        _draw_status(folder / status_name, label, sample_xyz, sample_status, mine & ~ceiling, mine & ceiling,
                     view_origins[view_band == index], lo, hi)
        written.append(status_name)
        points = point_band == index
        if points.any():
            deviation_name = _slug("deviation", index + 1, name)
            _draw_deviation(folder / deviation_name, label, point_xyz[points], point_signed[points], tolerance_m, lo, hi)
            written.append(deviation_name)
    return written


def _thin(index: np.ndarray) -> np.ndarray:
    return index[:: int(np.ceil(len(index) / MAX_DOTS))] if len(index) > MAX_DOTS else index


def _save(figure: object, path: Path) -> None:
    save_png(figure, path, dpi=100)


def _draw_status(path: Path, title: str, xyz: np.ndarray, status: np.ndarray, below: np.ndarray, above: np.ndarray,
                 views: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    figure = Figure(figsize=(16, 8.2), layout="constrained")
    axes = figure.subplots(1, 2, sharex=True, sharey=True)
    order = {s: i for i, s in enumerate(("not visible", "built", "built out of tolerance", "not built"))}
    for axis, members, heading in ((axes[0], below, "walls and floor (seen from above)"),
                                   (axes[1], above, "ceiling (seen from below)")):
        index = _thin(np.flatnonzero(members))
        # one marker set per status, not visible at the bottom, what is wrong on top: what needs
        # attention shows (a set of one colour draws several times faster than dots coloured one by one)
        for name in sorted(set(status[index].tolist()), key=lambda s: order.get(s, 0)):
            mine = index[status[index] == name]
            axis.plot(xyz[mine, 0], xyz[mine, 1], linestyle="", marker="s", markersize=DOT_PT, markeredgewidth=0,
                      color=STATUS_COLORS.get(name, "#000000"), antialiased=False, rasterized=True)
        if len(views):
            axis.scatter(views[:, 0], views[:, 1], s=14, facecolors="white", edgecolors="black", linewidths=0.8)
        frame_plan_view(axis, heading, lo, hi)
    axes[0].set_ylabel("y (m)")
    handles = [Line2D([], [], marker="o", linestyle="", color=c, label=n) for n, c in STATUS_COLORS.items()]
    handles.append(Line2D([], [], marker="o", linestyle="", markerfacecolor="white", markeredgecolor="black",
                          label="scanned from"))
    figure.legend(handles=handles, loc="outside lower center", ncols=len(handles), frameon=False, fontsize=9)
    figure.suptitle(title, fontsize=11)
    _save(figure, path)


def _draw_deviation(path: Path, title: str, xyz: np.ndarray, signed: np.ndarray, tolerance_m: float,
                    lo: np.ndarray, hi: np.ndarray) -> None:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(9, 8.2), layout="constrained")
    axis = figure.subplots(1, 1)
    index = _thin(np.arange(len(xyz)))
    index = index[np.argsort(np.abs(signed[index]), kind="stable")]  # the largest deviations on top
    limit = 2.0 * tolerance_m * 1000.0
    image = axis.scatter(xyz[index, 0], xyz[index, 1], s=1.5, c=signed[index] * 1000.0, cmap="RdBu_r",
                         vmin=-limit, vmax=limit, linewidths=0, antialiased=False, rasterized=True)
    colorbar = figure.colorbar(image, ax=axis, shrink=0.8)
    colorbar.set_label("distance to the model surface (mm; + in front of it)")
    frame_plan_view(axis, "", lo, hi)
    axis.set_ylabel("y (m)")
    figure.suptitle(f"{title}: deviation from the model (seen from above)", fontsize=11)
    _save(figure, path)

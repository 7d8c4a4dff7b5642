"""Pictures of point clouds: streamed uniform sample, colours, z-buffered splats, PNG.

``render_cloud`` reads any cloud bimscan reads (LAS/LAZ/PLY/NumPy folder, its own or another
tool's) in chunks, keeps a uniform random sample of at most ``max_points`` points (a few million
show every surface of a building at screen resolution), colours it, and draws a top view and an
oblique view side by side with a legend. Drawing is a z-buffered splat (Numba): nearest point
wins per pixel, no blending, so colours stay exactly the class colours.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import ConfigError, InputFileError
from bimscan.process.subsample import UniformSampler
from bimscan.render.compose import UNKNOWN_RGB, Panel, check_png_output, class_color_table, compose_png
from bimscan.render.raster import new_canvas, splat_points
from bimscan.render.view import OBLIQUE, TOP, Camera, Section, find_section
from bimscan.survey.trajectory import Trajectory
from bimscan.types import CloudHeader, LabelScheme, PointCloud

COLOR_MODES = ("label", "station", "intensity", "component", "height", "rgb", "returns")
DEFAULT_MAX_POINTS = 3_000_000
RETURN_COLORS = (("single return", (170, 170, 170)), ("first of several", (31, 119, 180)),
                 ("intermediate", (44, 160, 44)), ("last of several", (214, 39, 40)))


@dataclass(frozen=True)
class CloudSample:
    """A uniform sample of a cloud file: the points, how many the file holds, its bimscan header."""

    cloud: PointCloud
    total: int
    header: CloudHeader | None


@dataclass(frozen=True)
class RenderResult:
    """What ``render_cloud`` drew. walk_drawn: whether any of a given trajectory is in the picture."""

    path: Path
    total_points: int
    drawn_points: int
    color: str
    section: Section | None
    walk_drawn: bool = False


def sample_cloud(path: str | Path, *, max_points: int = DEFAULT_MAX_POINTS, seed: int = 0,
                 chunk_points: int = 2_000_000) -> CloudSample:
    """Stream ``path`` and keep a uniform sample of at most ``max_points`` points (same seed, same sample).
    InputFileError for a cloud without points: there is nothing to draw."""
    from bimscan.io import iter_cloud_chunks, read_cloud_header

    header = read_cloud_header(path)
    sampler = UniformSampler(max_points, seed=seed)
    for chunk in iter_cloud_chunks(path, chunk_points=chunk_points):
        sampler.add(PointCloud(xyz=chunk.xyz, label=chunk.label, component=chunk.component, station=chunk.station,
                               intensity=chunk.intensity, return_number=chunk.return_number,
                               number_of_returns=chunk.number_of_returns,
                               rgb=chunk.rgb))  # time is not drawn: do not keep it
    if sampler.seen == 0:  # (a picture of nothing, or a complaint about its columns, would hide why)
        raise InputFileError(f"{path}: the cloud is empty (0 points); there is nothing to draw, pass a cloud with "
                             "points")
    return CloudSample(cloud=sampler.result(), total=sampler.seen, header=header)


def _palette(n: int) -> np.ndarray:
    """(n, 3) uint8 distinct colours: golden-ratio hues, alternating lightness."""
    hues = (np.arange(n) * 0.618033988749895) % 1.0
    rows = [colorsys.hsv_to_rgb(h, 0.75, 0.95 if i % 2 == 0 else 0.7) for i, h in enumerate(hues)]
    return (np.array(rows).reshape(-1, 3) * 255).round().astype(np.uint8)


def _ramp(values: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours of values in [0, 1] on matplotlib's viridis."""
    from matplotlib import colormaps

    return (colormaps["viridis"](np.clip(values, 0, 1))[:, :3] * 255).round().astype(np.uint8)


def point_colors(cloud: PointCloud, mode: str, scheme: LabelScheme | None) -> tuple[np.ndarray, list[tuple[str, tuple[int, int, int]]]]:
    """(N, 3) uint8 colours of ``cloud``'s points by ``mode`` and the legend entries (name, rgb).

    label: the scheme's class colours (ids it lacks grey), or distinct colours per class id for a
    foreign file (``scheme`` None); station / component: distinct colours per id; intensity /
    height: viridis from the 2nd to the 98th percentile; rgb: the points' own colour; returns:
    single returns grey, first / intermediate / last of several returns in three colours.
    Raises ConfigError when the cloud lacks the column ``mode`` needs.
    """
    if mode not in COLOR_MODES:
        raise ConfigError(f"unknown colour mode {mode!r}; use one of {', '.join(COLOR_MODES)}")
    n = len(cloud)
    column = {"label": cloud.label, "station": cloud.station, "intensity": cloud.intensity,
              "component": cloud.component, "height": cloud.xyz[:, 2], "rgb": cloud.rgb,
              "returns": cloud.number_of_returns}[mode]
    if column is None or (mode == "returns" and cloud.return_number is None):
        raise ConfigError(f"the cloud has no {mode} column to colour by; use --color height (or another column it has)")
    if mode == "rgb":
        return np.ascontiguousarray(column), [("the points' own colour (RGB)", (128, 128, 128))]
    if mode == "returns":
        kinds = np.where(column <= 1, 0, np.where(cloud.return_number == 1, 1,
                                                   np.where(cloud.return_number >= column, 3, 2)))
        table = np.array([RETURN_COLORS[k][1] for k in range(4)], dtype=np.uint8)
        present = np.bincount(kinds, minlength=4) if n else np.zeros(4, dtype=np.int64)
        return table[kinds], [RETURN_COLORS[k] for k in range(4) if present[k]]  # type: ignore[return-value]
    if mode == "label" and scheme is None:
        # a foreign file: its class ids follow its own convention (ASPRS codes, ...), not ours
        ids, inverse = np.unique(column, return_inverse=True)
        palette = _palette(len(ids))
        legend = [(f"class {int(i)}", tuple(int(v) for v in palette[k])) for k, i in enumerate(ids[:24])]
        return palette[inverse], legend  # type: ignore[return-value]
    if mode == "label":
        table = class_color_table(scheme)
        present = np.bincount(column, minlength=256) if n else np.zeros(256, dtype=np.int64)
        legend = [(cls.name, cls.rgb) for cls in scheme.classes if present[cls.id]]
        if any(present[i] for i in range(256) if i not in {c.id for c in scheme.classes}):
            legend.append(("unknown class", UNKNOWN_RGB))
        return table[column], legend
    if mode in ("station", "component"):
        ids = column.astype(np.int64)
        unique, inverse = np.unique(ids, return_inverse=True)
        palette = _palette(len(unique))
        colors = palette[inverse]
        if mode == "station" and len(unique) <= 24:
            legend = [(f"station {int(i)}", tuple(int(v) for v in palette[k])) for k, i in enumerate(unique)]
        else:
            legend = [(f"{len(unique)} {mode}s, one colour each", tuple(int(v) for v in palette[0]))]
        return colors, legend  # type: ignore[return-value]
    values = column.astype(np.float64)
    lo, hi = (np.percentile(values, [2, 98]) if n else (0.0, 1.0))
    colors = _ramp((values - lo) / (hi - lo if hi > lo else 1.0))
    ends = _ramp(np.array([0.0, 1.0]))
    unit = " m" if mode == "height" else ""
    legend = [(f"{mode} {lo:.3g}{unit}", tuple(int(v) for v in ends[0])),
              (f"{mode} {hi:.3g}{unit}", tuple(int(v) for v in ends[1]))]
    return colors, legend  # type: ignore[return-value]


def draw_points(xyz: np.ndarray, colors: np.ndarray, camera: Camera, *, radius: int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 image of points (N, 3) with colours (N, 3), nearest first, white background."""
    image, zbuffer = new_canvas(camera.width, camera.height)
    if len(xyz) == 0:
        return image
    sx, sy, depth = camera.project(xyz)
    if radius is None:
        # sparse samples need bigger splats to read as surfaces
        radius = 0 if len(xyz) >= 4 * camera.width * camera.height else 1
    splat_points(sx, sy, depth, np.ascontiguousarray(colors, dtype=np.uint8), int(radius), zbuffer, image)
    return image


CUT_MODES = ("auto", "none")


def view_masks(z: np.ndarray, cut: str) -> tuple[Section | None, np.ndarray, np.ndarray]:
    """The section (``cut`` "auto": ``find_section``; "none": no cut) and the (N,) masks of the
    points the top view (the top storey's floor plan band) and the oblique view (everything under
    the plan cut: rooms opened from above) draw."""
    if cut not in CUT_MODES:
        raise ConfigError(f"unknown cut {cut!r}; use one of {', '.join(CUT_MODES)}")
    section = find_section(z) if cut == "auto" else None
    if section is None:
        everything = np.ones(len(z), dtype=bool)
        return None, everything, everything
    below = z <= section.plan_z
    return section, below & (z >= section.floor_z - 0.15), below


def draw_path(image: np.ndarray, xyz: np.ndarray, camera: Camera, colors: np.ndarray, *, mark_start: bool) -> int:
    """Draw the polyline through ``xyz`` (M, 3) over ``image`` (on top of everything, 3 px wide),
    segment k in colour ``colors[k]``, and (``mark_start``) a black square at its start. Returns
    the pixels of the line written (0: none of it lies in the picture, or fewer than 2 points)."""
    if len(xyz) < 2:
        return 0
    sx, sy, _ = camera.project(xyz)
    step = np.hypot(np.diff(sx), np.diff(sy))
    counts = np.maximum(1, np.ceil(step * 2).astype(np.int64))
    segment = np.repeat(np.arange(len(step)), counts)
    f = (np.arange(len(segment)) - np.repeat(np.cumsum(counts) - counts, counts)) / np.repeat(counts, counts)
    px = sx[segment] + f * (sx[segment + 1] - sx[segment])
    py = sy[segment] + f * (sy[segment + 1] - sy[segment])
    on_top = np.full((image.shape[0], image.shape[1]), np.inf)
    written = splat_points(px, py, np.full(len(px), -1.0), np.ascontiguousarray(colors[segment]), 1, on_top, image)
    if mark_start:
        splat_points(sx[:1], sy[:1], np.full(1, -2.0), np.zeros((1, 3), dtype=np.uint8), 5, on_top, image)
    return int(written)


def render_cloud(path: str | Path, out: str | Path, *, color: str = "label", max_points: int = DEFAULT_MAX_POINTS,
                 width: int = 1600, height: int = 800, cut: str = "auto", seed: int = 0,
                 trajectory: Trajectory | None = None) -> RenderResult:
    """Top and oblique views of the cloud at ``path`` side by side, with a legend, as a PNG.

    cut: "auto" opens the top storey of a building (a floor plan on top, rooms opened from above
    in the oblique view; see ``find_section``) or "none". ``trajectory``: a mobile scan's walk,
    drawn over the top view (the part of it on the floors shown), coloured from its start to its
    end, its start marked by a black square; the legend and the panel title name it only when some
    of it is drawn (``RenderResult.walk_drawn``). The PNG is exactly width x height pixels and is
    written atomically.
    """
    if color not in COLOR_MODES:
        raise ConfigError(f"unknown colour mode {color!r}; use one of {', '.join(COLOR_MODES)}")
    check_size(width, height)
    check_png_output(out)
    sample = sample_cloud(path, max_points=max_points, seed=seed)
    cloud = sample.cloud
    colors, legend = point_colors(cloud, color, sample.header.scheme if sample.header else None)
    section, top_mask, oblique_mask = view_masks(cloud.xyz[:, 2], cut)
    panel_w, panel_h = panel_size(width, height, panels=2)
    panels = []
    walk_pixels = 0
    metadata = sample.header.metadata if sample.header is not None else {}
    flown = ((metadata.get("mobile") or {}).get("platform") or {}).get("kind") == "flying"
    path_name = "flight" if flown else "walk"  # a drone's trajectory is a flight
    for title, (azimuth, elevation), mask in (("top view", TOP, top_mask), ("oblique view", OBLIQUE, oblique_mask)):
        is_top = title == "top view"
        xyz = cloud.xyz[mask]
        low, high = (xyz.min(axis=0), xyz.max(axis=0)) if len(xyz) else (np.zeros(3), np.ones(3))
        camera = Camera.fit(low, high, azimuth_deg=azimuth, elevation_deg=elevation, width=panel_w, height=panel_h)
        if section is not None:
            title += (f", z {section.floor_z - 0.15:.2f} to {section.plan_z:.2f} m" if is_top
                      else f", below z {section.plan_z:.2f} m")
        image = draw_points(xyz, colors[mask], camera)
        if trajectory is not None and is_top:
            shown = np.ones(len(trajectory.t), dtype=bool) if section is None else (
                (trajectory.xyz[:, 2] >= section.floor_z - 0.5) & (trajectory.xyz[:, 2] <= section.plan_z))
            for part in trajectory.pass_slices():  # one polyline per pass, broken where it leaves the floors shown
                index = np.arange(part.start, part.stop)[shown[part]]
                for run in np.split(index, np.flatnonzero(np.diff(index) > 1) + 1):
                    progress = (trajectory.t[run] - trajectory.t[0]) / max(float(np.ptp(trajectory.t)), 1e-9)
                    if len(run):
                        walk_pixels += draw_path(image, trajectory.xyz[run], camera, _ramp(0.15 + 0.85 * progress),
                                                 mark_start=bool(run[0] == part.start))
            if walk_pixels:
                title += f", {path_name} drawn over it"
        panels.append(Panel(title=title, image=image))
    if walk_pixels:
        ends = _ramp(np.array([0.15, 1.0]))
        legend = [*legend, (f"{path_name}: start (black square)", tuple(int(v) for v in ends[0])),
                  (f"{path_name}: end", tuple(int(v) for v in ends[1]))]
    title = f"{Path(path).name}: {sample.total:,} points ({len(cloud):,} sampled), coloured by {color}"
    compose_png(panels, legend=legend, title=title, out=out, width=width, height=height)
    return RenderResult(path=Path(out), total_points=sample.total, drawn_points=len(cloud), color=color,
                        section=section, walk_drawn=walk_pixels > 0)


def check_size(width: int, height: int) -> None:
    if not (200 <= width <= 16000 and 150 <= height <= 16000):
        raise ConfigError(f"image size {width}x{height} is impossible; give a width of 200..16000 and a height of "
                          "150..16000 pixels")


def panel_size(width: int, height: int, *, panels: int) -> tuple[int, int]:
    """Pixel size of each of ``panels`` side-by-side panels in a composed image (see ``compose``)."""
    from bimscan.render.compose import GAP_PX, LEGEND_PX, TITLE_PX

    return (width - GAP_PX * (panels + 1)) // panels, height - TITLE_PX - LEGEND_PX

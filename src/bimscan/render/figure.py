"""The side-by-side figure of the paper's Fig. 3: BIM model, synthetic scan, optionally a real scan.

All panels look from the same oblique direction. The BIM model and the synthetic scan share one
camera (fitted to the model), so they line up; a real scan has its own frame and gets its own.
With the section on (the default), each panel is cut at the top storey's plan height found in
its cloud, so the rooms can be seen.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import ConfigError
from bimscan.render.cloud import DEFAULT_MAX_POINTS, check_size, draw_points, panel_size, point_colors, sample_cloud
from bimscan.render.compose import Panel, check_png_output, compose_png
from bimscan.render.mesh import draw_mesh, face_colors
from bimscan.render.view import OBLIQUE, Camera, find_section
from bimscan.types import LabelScheme, SceneMesh


@dataclass(frozen=True)
class FigureResult:
    path: Path
    panels: tuple[str, ...]


def render_figure(mesh: SceneMesh, component_label: np.ndarray, scheme: LabelScheme, cloud: str | Path,
                  out: str | Path, *, real: str | Path | None = None, width: int = 1800, height: int = 700,
                  max_points: int = DEFAULT_MAX_POINTS, cut: str = "auto", model_name: str = "BIM model") -> FigureResult:
    """Write the figure: the mesh flat-shaded by class, the synthetic cloud and the real cloud by label.

    component_label: (C,) uint8 class of each component of ``mesh``. A real cloud without labels
    is coloured by height. The PNG is exactly width x height pixels, written atomically.
    """
    if cut not in ("auto", "none"):
        raise ConfigError(f"unknown cut {cut!r}; use auto or none")
    check_size(width, height)
    check_png_output(out)
    n_panels = 3 if real is not None else 2
    panel_w, panel_h = panel_size(width, height, panels=n_panels)
    azimuth, elevation = OBLIQUE
    synthetic = sample_cloud(cloud, max_points=max_points)
    section = find_section(synthetic.cloud.xyz[:, 2]) if cut == "auto" else None
    cut_z = None if section is None else section.plan_z
    low, high = mesh.bounds()
    if cut_z is not None:
        high = np.array([high[0], high[1], min(high[2], cut_z)])
    camera = Camera.fit(low, high, azimuth_deg=azimuth, elevation_deg=elevation, width=panel_w, height=panel_h)
    light = camera.towards + np.array([0.35, -0.25, 0.6])
    panels = [Panel(title=model_name + (f", cut at z {cut_z:.2f} m" if cut_z is not None else ""),
                    image=draw_mesh(mesh, face_colors(mesh, component_label, scheme, light_towards=light), camera,
                                    cut_z=cut_z))]
    colors, _ = point_colors(synthetic.cloud, "label" if synthetic.cloud.label is not None else "height",
                             synthetic.header.scheme if synthetic.header else scheme)
    keep = np.ones(len(synthetic.cloud), dtype=bool) if cut_z is None else synthetic.cloud.xyz[:, 2] <= cut_z
    panels.append(Panel(title=f"synthetic scan ({synthetic.total:,} points)",
                        image=draw_points(synthetic.cloud.xyz[keep], colors[keep], camera)))
    if real is not None:
        measured = sample_cloud(real, max_points=max_points)
        xyz = measured.cloud.xyz
        real_section = find_section(xyz[:, 2]) if cut == "auto" and len(xyz) else None
        keep = np.ones(len(xyz), dtype=bool) if real_section is None else xyz[:, 2] <= real_section.plan_z
        # all zeros is LAS "never classified" (a foreign scan without labels): colour by height then
        mode = "label" if measured.cloud.label is not None and measured.cloud.label.any() else "height"
        colors, _ = point_colors(measured.cloud, mode, measured.header.scheme if measured.header else scheme)
        low_r, high_r = (xyz[keep].min(axis=0), xyz[keep].max(axis=0)) if keep.any() else (np.zeros(3), np.ones(3))
        real_camera = Camera.fit(low_r, high_r, azimuth_deg=azimuth, elevation_deg=elevation, width=panel_w,
                                 height=panel_h)
        panels.append(Panel(title=f"real scan ({measured.total:,} points, by {mode})",
                            image=draw_points(xyz[keep], colors[keep], real_camera)))
    legend = [(c.name, c.rgb) for c in scheme.classes]
    title = f"{model_name}: model, synthetic scan{' and real scan' if real is not None else ''}"
    compose_png(panels, legend=legend, title=title, out=out, width=width, height=height)
    return FigureResult(path=Path(out), panels=tuple(p.title for p in panels))

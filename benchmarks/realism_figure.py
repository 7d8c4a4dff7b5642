"""The README's picture of sensor realism: one room of a generated building scanned from one
station with the paper's scanner and with every sensor effect on, side by side.

Run: python benchmarks/realism_figure.py [OUT.png]   (default: docs/realism.png)

Panels: the ideal scan (realism "paper") by class, the full scan by class (points behind the
windows, mixed pixels, as-built walls), and the full scan in its own RGB colour. Same seed,
same station, same pulses; the ceiling is cut away to look into the room.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np


def main() -> None:
    from bimscan.ifc.generate import make_building
    from bimscan.pipeline import load_scene
    from bimscan.render.cloud import draw_points, point_colors
    from bimscan.render.compose import Panel, compose_png
    from bimscan.render.view import OBLIQUE, Camera
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.scan.sensor import SensorModel
    from bimscan.survey.survey import choose_stations, prepare_survey
    from bimscan.types import PointCloud

    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / "docs" / "realism.png"
    work = Path(tempfile.mkdtemp(prefix="bimscan-realism-"))
    make_building(work / "house.ifc", seed=3, storeys=1)
    scene = load_scene(work / "house.ifc")
    paper = ScanRecipe.resolve(preset="exp3", head_deg_per_s=20.0, seed=1)
    stations, _ = choose_stations(scene, paper)
    windows = np.flatnonzero(scene.components.ifc_class == "IfcWindow")
    # the station of the room with the most windows in view: the one nearest to most windows
    centres = np.array([scene.mesh.vertices[scene.mesh.faces[scene.mesh.face_component == w]].reshape(-1, 3).mean(0)
                        for w in windows])
    positions = np.array([s.position for s in stations])
    near = (np.linalg.norm(centres[None, :, :2] - positions[:, None, :2], axis=2) < 4.0).sum(axis=1)
    station = stations[int(np.argmax(near))]
    clouds = {}
    for name, realism in (("paper", "paper"), ("full", "full")):
        recipe = paper.with_fields(sensor=SensorModel(realism=realism))
        survey = prepare_survey(scene, recipe, stations=(station,))
        clouds[name] = PointCloud.concatenate(list(survey.scanner.scan_station(station, recipe)))
    origin = np.asarray(station.position)
    floor = station.floor_z if station.floor_z is not None else origin[2] - 1.7

    def room(cloud: PointCloud) -> PointCloud:  # within 9 m of the station, ceiling cut away
        d = cloud.xyz - origin
        return cloud.take((np.abs(d[:, 0]) < 9) & (np.abs(d[:, 1]) < 9) & (cloud.xyz[:, 2] < floor + 2.3))

    shown = {name: room(cloud) for name, cloud in clouds.items()}
    low = np.minimum(shown["paper"].xyz.min(0), shown["full"].xyz.min(0))
    high = np.maximum(shown["paper"].xyz.max(0), shown["full"].xyz.max(0))
    width, height, panel_w = 1500, 560, 488
    camera = Camera.fit(low, high, azimuth_deg=OBLIQUE[0], elevation_deg=OBLIQUE[1], width=panel_w,
                        height=height - 46 - 36)
    panels, legend = [], []
    for title, name, mode in (("paper: thin ray, Gaussian noise (by class)", "paper", "label"),
                              ("full: footprint, returns, glass, detection, as-built (by class)", "full", "label"),
                              ("full: RGB from the IFC surface styles", "full", "rgb")):
        cloud = shown[name]
        colors, entries = point_colors(cloud, mode, scene.scheme)
        legend += [e for e in entries if e not in legend and mode == "label"]
        panels.append(Panel(title=title, image=draw_points(cloud.xyz, colors, camera, radius=0)))
    counts = {name: len(cloud) for name, cloud in clouds.items()}
    compose_png(panels, legend=legend, width=width, height=height, out=out,
                title=f"one station, exp3 at 20 deg/s: {counts['paper']:,} points (paper), {counts['full']:,} (full)")
    print(f"{out}: station {station.id} ({station.room}); paper {counts['paper']:,} points, full {counts['full']:,}")


if __name__ == "__main__":
    main()

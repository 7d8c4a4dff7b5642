"""Planned walks on real IFC models: a handheld walk (``--trajectory auto``) planned on each model.

Run: python benchmarks/bench_walks.py [MODEL.ifc ...]   (default: ../shared/data/ifc/*.ifc)

For each model: the tripod plan's stations, how many of them the walk visits and misses, its
passes (parts of the building that cannot be walked to from each other), metres, seconds, loop
closures and the seconds the walk took to plan (the tripod plan not counted). A model that stops
shows its one error line. Prints a Markdown table.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ifc"


def main() -> None:
    from bimscan.errors import BimscanError
    from bimscan.pipeline import load_scene
    from bimscan.scan.device import SCANNERS
    from bimscan.scan.probe import Prober
    from bimscan.survey.platform import PLATFORMS
    from bimscan.survey.stations import plan_stations
    from bimscan.survey.walk import plan_walk

    models = [Path(p) for p in sys.argv[1:]] or sorted(SHARED.glob("*.ifc"))
    print("| model | stations | visited | missed | passes | walk m | walk s | closures | plan s | note |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for path in models:
        try:
            scene = load_scene(path)
            prober = Prober(scene.mesh)
            stations, _ = plan_stations(scene, prober, SCANNERS["riegl_vz400"])
            start = time.perf_counter()
            walk, report = plan_walk(scene, prober, PLATFORMS["handheld"], stations)
            seconds = time.perf_counter() - start
            print(f"| {path.stem} | {len(stations)} | {len(report.visited)} | {len(report.missed)} | {walk.n_passes} | "
                  f"{walk.length_m():.0f} | {walk.duration_s():.0f} | {len(walk.closures)} | {seconds:.1f} | |",
                  flush=True)
        except BimscanError as exc:
            print(f"| {path.stem} | | | | | | | | | error: {exc} |", flush=True)


if __name__ == "__main__":
    main()

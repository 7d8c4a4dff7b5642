"""Dataset build throughput next to the single-scan rate, and the paper's dataset projected.

Run: python benchmarks/bench_dataset.py [--head-speed 60] [--workers 1 2] [--formats laz] [--engine warp]

Builds 2 generated scenes x the 6 presets (12 units, LAZ) with the local executor, once per
``--workers`` value, each into a fresh folder with a cold geometry cache. Before and after each
build, in the same run, it scans one unit (the two-storey scene, exp5) the way ``bimscan scan``
does (one process, all cores, stations planned beforehand) to LAZ. Prints points/s and
units/min of every build, its ratio to the mean of the single scans around it, how long parsing
took in the scene tasks (once per scene) and in the unit tasks (cache hits), and the time the
paper's 8.75e9 points would take on this machine at each build's rate. The head speed (default 60 deg/s, the demo's) scales every unit's points
by 10 / head speed relative to the presets.

With ``--clutter D`` (default 0.25; 0 skips it) the same dataset is built once more with every
scene dressed as a site (clutter at D objects per square metre of free floor, ``bimscan.site``),
by the last ``--workers`` value, and the dressing is reported: per scene task the time to find
the free floor and to place the objects (per room), its share of the build's task time, and how
long a unit takes to read the dressed scene the scene task kept.
--engine picks the ray engine of the builds and the single scans (the spec's ``engine``; warp:
NVIDIA Warp, on a CUDA GPU if visible). Each single scan is also split into casting and writing:
the same unit scanned to NumPy chunks only (ray generation, cast, per-hit work) against the whole
scan to LAZ, so the rest is checking and LAZ writing: with a GPU engine, writing is the expected
bottleneck.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

PAPER_POINTS = 8.75e9
SCENES = (("office-2f", 1, 2), ("office-1f", 2, 1))


def spec_text(head_deg_per_s: float, formats: list[str], engine: str, clutter: float = 0.0) -> str:
    lines = [f"name = \"bench\"\nformats = [{', '.join(repr(f).replace(chr(39), chr(34)) for f in formats)}]\n"
             f"engine = \"{engine}\"\n"]
    if clutter > 0:
        lines.append(f"clutter = {{ density = {clutter!r} }}\n")
    for name, seed, storeys in SCENES:
        lines.append(f"[[scenes]]\nname = \"{name}\"\ngenerate = {{ seed = {seed}, storeys = {storeys} }}\n")
    for k in range(1, 7):
        lines.append(f"[[configs]]\nname = \"exp{k}\"\npreset = \"exp{k}\"\nhead_deg_per_s = {head_deg_per_s!r}\n")
    return "\n".join(lines)


def single_scan(folder: Path, scene_ifc: Path, *, head_deg_per_s: float, engine: str) -> tuple[int, float, float]:
    """One unit the way `bimscan scan` runs it (stations planned beforehand, not timed): points,
    seconds to LAZ, and seconds of the same scan to NumPy chunks only (no checks, no writing)."""
    from bimscan.pipeline import load_scene, scan_survey
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.survey import prepare_survey, run_survey

    recipe = ScanRecipe.resolve(preset="exp5", head_deg_per_s=head_deg_per_s, engine=engine)
    scene = load_scene(scene_ifc)
    survey = prepare_survey(scene, recipe)
    start = time.perf_counter()
    for _ in run_survey(survey, reuse_buffers=True):
        pass
    casting = time.perf_counter() - start
    start = time.perf_counter()
    result = scan_survey(survey, folder / "single.laz", progress=False, overwrite=True)
    return result.points, time.perf_counter() - start, casting


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--head-speed", type=float, default=60.0, help="deg/s for every preset (10 = the paper's)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to compare")
    parser.add_argument("--formats", nargs="+", default=["laz"], help="unit formats (laz, las, ply, npy)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the built datasets in this folder")
    parser.add_argument("--clutter", type=float, default=0.25,
                        help="also build the dataset dressed with this clutter density (objects/m2; 0 skips it)")
    parser.add_argument("--engine", default="open3d", help="ray engine of the builds and single scans (open3d, warp, auto)")
    args = parser.parse_args()

    root = Path(tempfile.mkdtemp(prefix="bimscan-bench-dataset-")) if args.keep is None else args.keep
    root.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("BIMSCAN_PROGRESS", "0")
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import load_spec
    from bimscan.ifc.generate import make_building

    spec_path = root / "bench.toml"
    spec_path.write_text(spec_text(args.head_speed, args.formats, args.engine))
    spec = load_spec(spec_path)
    cores = os.cpu_count() or 1
    print(f"machine: {cores} cores; dataset: {len(spec.scenes)} scenes x {len(spec.configs)} presets, "
          f"head {args.head_speed:g} deg/s, formats {', '.join(args.formats)}, engine {spec.recipe(spec.scenes[0], spec.configs[0]).engine}")

    os.environ["BIMSCAN_CACHE_DIR"] = str(root / "cache-single")
    name, seed, storeys = SCENES[0]
    ifc = make_building(root / f"{name}.ifc", seed=seed, storeys=storeys).path
    single_scan(root, ifc, head_deg_per_s=args.head_speed * 4, engine=args.engine)  # warm-up: JIT caches, page cache

    def single_rate() -> float:
        points, seconds, casting = single_scan(root, ifc, head_deg_per_s=args.head_speed, engine=args.engine)
        print(f"  single scan ({name}, exp5, {points:,} points to LAZ, one process, {cores} threads): "
              f"{seconds:.2f} s = {points / seconds / 1e6:.2f} Mpts/s; the scan alone to NumPy {casting:.2f} s "
              f"({points / casting / 1e6:.2f} Mpts/s), so checking and writing LAZ take {1 - casting / seconds:.0%}")
        return points / seconds

    # Machines are shared and noisy: every build is bracketed by single scans and compared with their mean.
    rows = []
    before = single_rate()
    for workers in args.workers:
        out = root / f"dataset-w{workers}"
        shutil.rmtree(out, ignore_errors=True)
        os.environ["BIMSCAN_CACHE_DIR"] = str(root / f"cache-w{workers}")  # cold: every scene parsed here
        shutil.rmtree(os.environ["BIMSCAN_CACHE_DIR"], ignore_errors=True)
        report = build_dataset(spec, out, workers=workers, progress=False)
        if not report.ok:
            sys.exit(f"build failed: {report.summary()}")
        os.environ["BIMSCAN_CACHE_DIR"] = str(root / "cache-single")
        after = single_rate()
        rows.append((workers, report, (before + after) / 2))
        before = after

    print(f"{'workers':>7} {'threads':>7} {'units':>5} {'points':>13} {'seconds':>8} {'Mpts/s':>7} {'units/min':>9} "
          f"{'vs single':>9} {'parse s':>8} {'unit loads s':>12} {'8.75e9 pts':>11}")
    for workers, report, single in rows:
        rate = report.points_built / report.seconds
        parse = sum(s.parse_s for s in report.scenes)
        projected_h = PAPER_POINTS / rate / 3600
        print(f"{workers:>7} {report.threads:>7} {report.built:>5} {report.points_built:>13,} {report.seconds:>8.1f} "
              f"{rate / 1e6:>7.2f} {report.built / report.seconds * 60:>9.1f} {rate / single:>8.2f}x "
              f"{parse:>8.2f} {report.unit_load_s:>12.2f} {projected_h:>9.1f} h")
    print("parse s: the scene tasks' IFC parse (once per scene, cold cache); unit loads s: all unit tasks' loads "
          "of the same scenes from the cache")
    if args.clutter > 0:
        site_build(root, args, rows[-1][1])
    if args.keep is None:
        shutil.rmtree(root, ignore_errors=True)


def site_build(root: Path, args: argparse.Namespace, plain) -> None:
    """The dataset again, every scene dressed with clutter: what dressing costs, per room and per unit."""
    import json

    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import load_spec

    workers = args.workers[-1]
    spec_path = root / "bench-site.toml"
    spec_path.write_text(spec_text(args.head_speed, args.formats, args.engine, clutter=args.clutter))
    out = root / "dataset-site"
    shutil.rmtree(out, ignore_errors=True)
    os.environ["BIMSCAN_CACHE_DIR"] = str(root / f"cache-w{workers}")  # warm: only the dressing is new
    report = build_dataset(load_spec(spec_path), out, workers=workers, progress=False)
    if not report.ok:
        sys.exit(f"site build failed: {report.summary()}")
    print(f"\nwith clutter {args.clutter:g}/m2 ({workers} workers): {report.built} units, "
          f"{report.points_built:,} points in {report.seconds:.1f} s = {report.points_built / report.seconds / 1e6:.2f} "
          f"Mpts/s; without: {plain.points_built / plain.seconds / 1e6:.2f} Mpts/s")
    print(f"{'scene task':>12} {'rooms':>5} {'dress s':>8} {'place s':>8} {'ms/room':>8}")
    for scene in report.scenes:
        print(f"{scene.scene:>12} {scene.site_rooms:>5} {scene.site_s:>8.2f} {scene.placement_s:>8.2f} "
              f"{1000 * scene.placement_s / max(scene.site_rooms, 1):>8.1f}")
    units = [json.loads(t.read_text()) for t in sorted(out.glob("units/*/timings.json"))]
    dressing = sum(scene.site_s for scene in report.scenes)
    unit_s = sum(u["total_s"] for u in units)
    reads = [1000 * u["site_s"] for u in units]
    print(f"dressing (once per scene and site, in the scene tasks): {dressing:.1f} s = "
          f"{100 * dressing / (dressing + unit_s):.1f} % of the build's task time ({unit_s:.1f} s in {len(units)} units); "
          f"each unit reads its dressed scene in {min(reads):.0f}-{max(reads):.0f} ms")


if __name__ == "__main__":
    main()

"""Mobile scanning throughput: the handheld path next to the tripod path, on the same scene and engine.

Run: python benchmarks/bench_mobile.py [--model MODEL.ifc] [--seconds 20] [--rounds 5]

1. Planning: seconds to plan the tripod stations and the walk through them (``survey.walk``),
   with the walk's length, duration, passes and loop closures.
2. Scan path, side by side (interleaved rounds, best of each): rays/s of
   - the mobile path (``VirtualScanner.scan_pass``: per-pulse poses interpolated along the walk,
     rays, casting, noise, labels, beam origins, compaction) over the first ``--seconds`` of the
     planned handheld walk (VLP-16 at 10 Hz on the rotating head);
   - the tripod path (``VirtualScanner.scan_station``) of the first planned station, the VZ-400 at
     300 kHz and 120 lines/s turning 10 deg/s (4.5M pulses, about as many);
   - the raw engine cast of each path's own rays (what the BVH alone costs for them).
3. Whole surveys, side by side (interleaved rounds, best of ``--whole-rounds``): the handheld
   walk through the whole building against the tripod survey of every station it visits, in
   rays/s and in points/s, with the share of rays that hit. A tripod's rays that leave the
   building (through windows, doors, over a terrace) miss, and a miss costs the engine little,
   so rays/s favours the path with more misses; section 2 compares one station with a window
   of the walk, this one the same building both ways.
   The issue's target without HELIOS++ at hand: the mobile path at >= 80 % of the tripod path's rays/s.

Default model: the shared duplex (two storeys, stairs), else a generated two-storey office.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from bimscan.scan.virtual_scanner import VirtualScanner
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.trajectory import Trajectory
    from bimscan.types import PointCloud, Station

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ifc"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", type=Path)
    parser.add_argument("--seconds", type=float, default=20.0, help="seconds of the walk scanned per round")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--whole-rounds", type=int, default=3, help="rounds of the whole surveys (0: skip them)")
    args = parser.parse_args()

    from bimscan.pipeline import load_scene
    from bimscan.scan.device import ScanSettings
    from bimscan.scan.multibeam import moving_rays
    from bimscan.scan.pattern import PulsePattern
    from bimscan.scan.probe import Prober
    from bimscan.survey.platform import PLATFORMS
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.stations import plan_stations
    from bimscan.survey.survey import place_scanner
    from bimscan.survey.trajectory import Trajectory
    from bimscan.survey.walk import plan_walk

    with tempfile.TemporaryDirectory() as scratch:
        model = args.model
        if model is None:
            model = SHARED / "duplex.ifc"
            if not model.is_file():
                from bimscan.ifc.generate import make_building

                model = make_building(Path(scratch) / "office.ifc", seed=4, storeys=2, style="office").path
        scene = load_scene(model)
    mobile_recipe = ScanRecipe.resolve(platform="handheld")
    tripod_recipe = ScanRecipe(settings=ScanSettings(pulse_freq_hz=300000, scan_freq_hz=120, head_deg_per_s=10.0),
                               preset=None)
    start = time.perf_counter()
    prober = Prober(scene.mesh)
    stations, _ = plan_stations(scene, prober, tripod_recipe.scanner)
    planned_stations = time.perf_counter()
    trajectory, report = plan_walk(scene, prober, PLATFORMS["handheld"], stations)
    planned_walk = time.perf_counter()
    print(f"model: {Path(model).name}, {scene.mesh.n_triangles:,} triangles")
    print(f"planning: stations {planned_stations - start:.2f} s ({len(stations)}), walk {planned_walk - planned_stations:.2f} s"
          f" ({trajectory.length_m():.0f} m, {trajectory.duration_s():.0f} s, {trajectory.n_passes} passes, "
          f"{len(trajectory.closures)} loop closures, {len(report.rooms)} rooms)")

    first = trajectory.pass_slices()[0]
    window = np.flatnonzero(trajectory.t[first] <= trajectory.t[first][0] + args.seconds)
    part = slice(int(window[0]), int(window[-1]) + 1)
    piece = Trajectory(t=trajectory.t[part], xyz=trajectory.xyz[part], roll=trajectory.roll[part],
                       pitch=trajectory.pitch[part], yaw=trajectory.yaw[part],
                       pass_id=np.zeros(part.stop - part.start, dtype=np.int32))
    scanner = place_scanner(scene, tripod_recipe)
    whole = slice(0, len(piece.t))

    def mobile_once() -> tuple[int, int]:
        return _rays_and_points(lambda on_pulses: scanner.scan_pass(piece, whole, 0, 0, mobile_recipe,
                                                                    reuse_buffers=True, on_pulses=on_pulses))

    def tripod_once() -> tuple[int, int]:
        return _rays_and_points(lambda on_pulses: scanner.scan_station(stations[0], tripod_recipe, reuse_buffers=True,
                                                                       on_pulses=on_pulses))

    # the raw cast of the mobile path's own rays (generated once, outside the timing)
    lidar, mount = mobile_recipe.mobile.lidar, mobile_recipe.mobile.platform.mounts[0]
    n = mobile_recipe.mobile.pass_pulses(float(piece.t[-1] - piece.t[0]))
    rays = np.empty((n, 6), dtype=np.float32)
    origin = np.empty((n, 3))
    pulse_time = np.empty(n)
    elevation = np.radians(np.asarray(lidar.beam_elevation_deg))
    moving_rays(np.int64(0), np.int64(n), np.int64(lidar.n_beams), lidar.firing_cycle_us * 1e-6, float(piece.t[0]),
                np.asarray(lidar.firing_offset_us) * 1e-6, np.cos(elevation), np.sin(elevation),
                np.radians(np.asarray(lidar.beam_azimuth_offset_deg)), 2 * math.pi * mobile_recipe.mobile.rotation_hz,
                piece.t, piece.xyz, piece.ypr(), mount.lever_arm(), mount.rotation(),
                2 * math.pi * mount.head_rotation_hz, np.asarray(scanner.engine.centre, dtype=np.float64), rays, origin,
                pulse_time)

    def raw_once() -> tuple[int, int]:
        for begin in range(0, n, mobile_recipe.chunk_pulses):
            scanner.engine.cast(rays[begin:begin + mobile_recipe.chunk_pulses])
        return n, 0

    # the raw cast of the tripod path's own rays, chunk by chunk as it generates them
    pattern = PulsePattern.of(tripod_recipe.settings, tripod_recipe.scanner)
    origin_local = (np.asarray(stations[0].position) - scanner.engine.centre).astype(np.float32)
    tripod_chunks = []
    for lines in pattern.line_chunks(tripod_recipe.chunk_pulses):
        chunk_rays = np.empty((lines.n, 6), dtype=np.float32)
        pattern.fill_rays(lines, stations[0].heading_deg, origin_local, chunk_rays, np.empty(lines.n, dtype=np.int64))
        tripod_chunks.append(chunk_rays)

    def tripod_raw_once() -> tuple[int, int]:
        for chunk_rays in tripod_chunks:
            scanner.engine.cast(chunk_rays)
        return sum(len(c) for c in tripod_chunks), 0

    mobile_once(), tripod_once()  # compile and warm up
    best, counts = _best_of(args.rounds, {"mobile": mobile_once, "tripod": tripod_once, "raw": raw_once,
                                          "tripod_raw": tripod_raw_once})
    print(f"scan path, best of {args.rounds} interleaved rounds:")
    for name, label in (("mobile", f"handheld VLP-16, {args.seconds:g} s of the walk"),
                        ("tripod", "tripod station, VZ-400 300 kHz at 10 deg/s"),
                        ("raw", "raw cast of the handheld rays"),
                        ("tripod_raw", "raw cast of the tripod rays")):
        rays_n, points = counts[name]
        print(f"  {label:45s} {rays_n:>10,} rays {best[name]:7.3f} s  {rays_n / best[name] / 1e6:6.2f} Mrays/s"
              + (f"  {points:>10,} points" if points else ""))
    ratio = (counts["mobile"][0] / best["mobile"]) / (counts["tripod"][0] / best["tripod"])
    print(f"mobile path / tripod path rays/s: {ratio:.2f} (target >= 0.80)")
    print(f"mobile path / raw cast of its rays: {(counts['mobile'][0] / best['mobile']) / (n / best['raw']):.2f}; "
          f"tripod path / raw cast of its rays: "
          f"{(counts['tripod'][0] / best['tripod']) / (counts['tripod_raw'][0] / best['tripod_raw']):.2f}")
    print(f"raw cast, handheld rays / tripod rays (rays/s): "
          f"{(n / best['raw']) / (counts['tripod_raw'][0] / best['tripod_raw']):.2f}")
    if args.whole_rounds > 0:
        _whole_surveys(scanner, trajectory, stations, mobile_recipe, tripod_recipe, args.whole_rounds)


def _whole_surveys(scanner: VirtualScanner, trajectory: Trajectory, stations: list[Station], mobile_recipe: ScanRecipe,
                   tripod_recipe: ScanRecipe, rounds: int) -> None:
    """Section 3 of the module docstring."""

    def walk(on_pulses: Callable[[int], None]) -> Iterator[PointCloud]:
        for index, piece in enumerate(trajectory.pass_slices()):
            yield from scanner.scan_pass(trajectory, piece, index, 0, mobile_recipe, reuse_buffers=True,
                                         on_pulses=on_pulses)

    def every_station(on_pulses: Callable[[int], None]) -> Iterator[PointCloud]:
        for station in stations:
            yield from scanner.scan_station(station, tripod_recipe, reuse_buffers=True, on_pulses=on_pulses)

    best, counts = _best_of(rounds, {"walk": lambda: _rays_and_points(walk),
                                     "stations": lambda: _rays_and_points(every_station)})
    print(f"whole surveys, best of {rounds} interleaved rounds:")
    for name, label in (("walk", f"handheld walk, {trajectory.duration_s():.0f} s"),
                        ("stations", f"tripod, all {len(stations)} stations")):
        rays, points = counts[name]
        print(f"  {label:45s} {rays:>11,} rays {best[name]:7.2f} s  {rays / best[name] / 1e6:6.2f} Mrays/s  "
              f"{points / best[name] / 1e6:6.2f} Mpoints/s  {points / rays:6.1%} hit")
    rate = {name: counts[name][0] / best[name] for name in best}
    points_rate = {name: counts[name][1] / best[name] for name in best}
    print(f"handheld walk / tripod survey: rays/s {rate['walk'] / rate['stations']:.2f} (target >= 0.80), "
          f"points/s {points_rate['walk'] / points_rate['stations']:.2f}")


def _rays_and_points(scan: Callable[[Callable[[int], None]], Iterable[PointCloud]]) -> tuple[int, int]:
    """(pulses fired, points kept) of one scan; ``scan(on_pulses)`` streams its chunks."""
    fired = []
    points = sum(len(chunk) for chunk in scan(fired.append))
    return sum(fired), points


def _best_of(rounds: int, runs: dict[str, Callable[[], tuple[int, int]]]
             ) -> tuple[dict[str, float], dict[str, tuple[int, int]]]:
    """Best wall seconds of each run over ``rounds`` interleaved rounds, and each run's counts."""
    best = dict.fromkeys(runs, math.inf)
    counts = {}
    for _ in range(rounds):
        for name, run in runs.items():
            start = time.perf_counter()
            counts[name] = run()
            best[name] = min(best[name], time.perf_counter() - start)
    return best, counts


if __name__ == "__main__":
    main()

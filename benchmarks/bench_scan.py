"""Scan throughput: the whole scan path next to the raw ray engine on the same rays.

Run: python benchmarks/bench_scan.py [--model MODEL.ifc] [--memory] [--engine warp [--warp-device cpu]]
                                     [--preset exp5 [--stations K]] [--chunk-pulses N]

1. Engines: rays/s of Open3D (Embree, all cores and one core) and embreex (one core; it holds
   the GIL) on the same rays of one station. With --engine warp: Warp's raw query on rays
   already on its device (what the BVH walk alone does) and its ``cast`` from NumPy (with the
   transfers).
2. Scan path: pulses/s and labelled points/s of VirtualScanner.scan_station (ray generation,
   casting, noise, labels, intensity, compaction) against the raw cast of exactly the rays it
   generates, measured side by side (best of several rounds, interleaved). With --engine warp
   the same for Warp's fused device path (to NumPy output) against its raw device query; the
   issue's goal on a GPU: >= 1e9 rays/s raw and the path >= 50 % of that.
3. Sensor effects (bimscan.scan.sensor): the same station with each effect alone, with every
   effect (realism "full"), and with the footprint's sub-rays on every pulse (HELIOS++'s way),
   each as a ratio of time to the paper path and of the raw engine's time to it, interleaved;
   in wall time and in the process's CPU time (the work done, which a busy machine disturbs less).
4. With --memory: peak resident memory of whole `bimscan scan` runs to LAZ of about 10M and
   100M points (in subprocesses), to show it stays flat as the point count grows.
4. With --preset NAME: a whole survey of the model with that preset at its own head speed (exp5:
   500 kHz, 7.5M pulses per station, the SPC paper's scale), Open3D and the --engine one after
   the other, to NumPy chunks (no writing); --stations K scans only the first K stations.

--chunk-pulses sets the recipe's chunk size (default 1M pulses; a GPU wants 16M or more, so the
per-chunk launches and copies are a small part of each chunk). Figures taken on Warp's CPU device
are CPU figures (one core), not GPU ones.

Default model: a generated demo building if bimscan.ifc.generate is available, else the duplex
sample from ../shared/data/ifc.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ifc"


def default_model(folder: Path) -> Path:
    try:
        from bimscan.ifc.generate import make_building
    except ImportError:
        return SHARED / "duplex.ifc"
    path = folder / "bench_building.ifc"
    make_building(path, seed=1, storeys=2)
    return path


def best_of(fn, rounds: int = 5) -> float:
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", type=Path)
    parser.add_argument("--memory", action="store_true", help="also measure peak memory of 10M/100M point scans")
    parser.add_argument("--quick", action="store_true", help="fewer rounds of the sensor effects")
    parser.add_argument("--engine", choices=["open3d", "warp"], default="open3d",
                        help="also measure this engine beside Open3D (warp: NVIDIA Warp)")
    parser.add_argument("--warp-device", default=None, help="Warp device (default: cuda:0 if visible, else cpu)")
    parser.add_argument("--preset", default=None, help="also scan a whole survey with this preset (e.g. exp5)")
    parser.add_argument("--stations", type=int, default=None, help="with --preset: scan only the first K stations")
    parser.add_argument("--chunk-pulses", type=int, default=None, help="pulses per scan chunk (default: the recipe's)")
    args = parser.parse_args()
    os.environ.setdefault("BIMSCAN_CACHE_DIR", tempfile.mkdtemp(prefix="bimscan-bench-"))
    from bimscan.pipeline import load_scene
    from bimscan.scan.engine import make_engine
    from bimscan.scan.noise import NoiseModel
    from bimscan.scan.pattern import PulsePattern
    from bimscan.scan.device import SCANNERS, ScanSettings
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.scan.virtual_scanner import VirtualScanner
    from bimscan.scan.probe import Prober
    from bimscan.survey.stations import plan_stations

    work = Path(tempfile.mkdtemp(prefix="bimscan-bench-scan-"))
    model = args.model or default_model(work)
    scene = load_scene(model)
    vz400 = SCANNERS["riegl_vz400"]
    scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=vz400, components=scene.components,
                             surfaces=scene.surfaces)
    prober = Prober(scene.mesh)
    stations, _ = plan_stations(scene, prober, vz400)
    # the station whose rays most often give a point (a room, not a narrow corridor where the
    # 1.5 m minimum range drops most returns): "labelled points/s" then means most of the rays
    from bimscan.survey.stations import useful_return_fraction

    useful = useful_return_fraction(prober, vz400, np.array([s.position for s in stations]))
    station = stations[int(np.argmax(useful))]
    settings = ScanSettings(pulse_freq_hz=300000, scan_freq_hz=120, head_deg_per_s=30)  # 1.5M pulses
    pattern = PulsePattern.of(settings, vz400)
    lines = next(pattern.line_chunks(1 << 62))  # the whole station as one chunk
    n = lines.n
    rays = np.empty((n, 6), dtype=np.float32)
    pulse = np.empty(n, dtype=np.int64)
    origin = (np.asarray(station.position) - scanner.engine.centre).astype(np.float32)
    pattern.fill_rays(lines, 0.0, origin, rays, pulse)
    print(f"model {model.name}: {len(scene.components)} components, {scene.mesh.n_triangles} triangles; "
          f"station {station.id} ({station.room or 'no room'}) of {len(stations)}; {n:,} rays (300 kHz, 120 Hz, 30 deg/s); {os.cpu_count()} cores")

    print("\n1. ray engines on the same rays")
    engines = [("open3d, all cores", make_engine(scene.mesh, name="open3d")),
               ("open3d, 1 core", make_engine(scene.mesh, name="open3d", threads=1))]
    try:
        engines.append(("embreex, 1 core (GIL)", make_engine(scene.mesh, name="embreex")))
    except Exception as exc:  # optional engine
        print(f"   embreex unavailable: {exc}")
    warp = None
    if args.engine == "warp":
        from bimscan.scan.warp_engine import WarpEngine

        warp = WarpEngine(scene.mesh, device=args.warp_device)
        engines.append((f"warp ({warp.device}), cast()", warp))
    for name, engine in engines:
        engine.cast(rays)
        seconds = best_of(lambda: engine.cast(rays))
        print(f"   {name:<24} {n / seconds / 1e6:7.2f} Mrays/s")
    if warp is not None:
        raw_warp = warp_raw_query(warp, rays)
        seconds = best_of(raw_warp)
        print(f"   {'warp (' + str(warp.device) + '), raw query':<24} {n / seconds / 1e6:7.2f} Mrays/s "
              "(rays already on the device; the cast() row adds the transfers)")

    print("\n2. whole scan path vs raw engine (interleaved rounds, best of each)")
    chunk = {} if args.chunk_pulses is None else {"chunk_pulses": args.chunk_pulses}
    paths = [("open3d", scanner, lambda: scanner.engine.cast(rays), "85 %")]
    if warp is not None:
        warp_scanner = VirtualScanner(scene.mesh, scene.components.label, scanner=vz400, engine=warp)
        paths.append((f"warp ({warp.device}), fused", warp_scanner, warp_raw_query(warp, rays), "50 % on a GPU"))
    for engine_label, path_scanner, raw_cast, target in paths:
        for label, noise in (("noise on ", NoiseModel()), ("noise off", NoiseModel.off())):
            recipe = ScanRecipe(scanner=vz400, settings=settings, preset=None, noise=noise, seed=1, **chunk)

            def path_once() -> int:  # as the pipeline runs it: reused output buffers
                return sum(len(c) for c in path_scanner.scan_station(station, recipe, reuse_buffers=True))

            points = path_once()  # JIT warm-up
            raw, path = float("inf"), float("inf")
            for _ in range(7):
                raw = min(raw, best_of(raw_cast, 1))
                path = min(path, best_of(path_once, 1))
            print(f"   {engine_label}, {label}: raw {n / raw / 1e6:7.2f} Mrays/s | path {n / path / 1e6:7.2f} Mpulses/s "
                  f"({points / path / 1e6:6.2f} M labelled points/s, {points / n:.1%} of pulses hit) | "
                  f"path/raw = {raw / path:.1%} (target >= {target})")

    print("\n3. sensor effects on the same station (noise on; interleaved rounds, best of each)")
    from bimscan.scan.sensor import SensorModel
    from bimscan.survey.survey import place_scanner

    variants = [("paper", SensorModel())]
    variants += [(effect, SensorModel(**{effect: True})) for effect in
                 ("footprint", "detection", "geometric_noise", "materials", "glass", "color", "deviations")]
    variants += [("full", SensorModel(realism="full")),
                 ("full, sub-rays on every pulse", SensorModel(realism="full", adaptive_footprint=False))]
    runs = []
    for name, sensor in variants:
        recipe = ScanRecipe(scanner=vz400, settings=settings, preset=None, noise=NoiseModel(), seed=1, sensor=sensor)
        placed = place_scanner(scene, recipe) if sensor.on("deviations") else scanner
        runs.append((name, recipe, placed))

    def effect_once(recipe: ScanRecipe, placed: VirtualScanner) -> int:
        return sum(len(c) for c in placed.scan_station(station, recipe, reuse_buffers=True))

    def timed(fn) -> tuple[float, float]:
        """(wall seconds, CPU seconds of the whole process: every thread's work, not the waits of a busy machine)."""
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        return time.perf_counter() - wall, time.process_time() - cpu

    counts = {name: effect_once(recipe, placed) for name, recipe, placed in runs}  # JIT warm-up
    best = {name: (float("inf"), float("inf")) for name, _, _ in runs}
    raw = (float("inf"), float("inf"))
    for _ in range(3 if args.quick else 5):
        raw = tuple(map(min, raw, timed(lambda: scanner.engine.cast(rays))))
        for name, recipe, placed in runs:
            best[name] = tuple(map(min, best[name], timed(lambda: effect_once(recipe, placed))))
    print(f"   {'':<31} {'':>15} {'':>23} | wall time: x paper, path/raw | CPU time: x paper, path/raw")
    for name, _, _ in runs:
        (wall, cpu), (paper_wall, paper_cpu) = best[name], best["paper"]
        print(f"   {name:<31} {n / wall / 1e6:6.2f} Mpulses/s  {counts[name] / n:6.1%} points per pulse | "
              f"x{wall / paper_wall:5.2f} {raw[0] / wall:6.1%} | x{cpu / paper_cpu:5.2f} {raw[1] / cpu:6.1%}")

    if args.memory:
        print("\n4. peak memory of whole scans written to LAZ (subprocess max RSS)")
        for target in (10_000_000, 100_000_000):
            # pulse count per station at 500 kHz: 500000 * 360/head * 100/240
            per_station_at_1dps = 500000 * 360 * 100 / 240
            head = per_station_at_1dps * len(stations) / target
            out = work / f"scan_{target}.laz"
            argv = ["scan", str(model), str(out), "--preset", "exp5", "--head-speed", f"{head:.6f}", "--seed", "1",
                    "--overwrite"]
            code = ("import resource, sys; from bimscan.cli.main import main; rc = main(sys.argv[1:]); "
                    "print('PEAK_KIB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)")
            start_time = time.perf_counter()
            result = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True,
                                    env=os.environ | {"BIMSCAN_PROGRESS": "0"})
            seconds = time.perf_counter() - start_time
            if result.returncode != 0:
                print(f"   {target:>11,}: failed: {result.stderr.strip()}")
                continue
            peak_kib = int(next(line.split()[1] for line in result.stderr.splitlines() if line.startswith("PEAK_KIB")))
            summary = result.stdout.splitlines()[0]
            print(f"   target {target:>11,}: peak RSS {peak_kib / 1024:7.0f} MiB, {seconds:6.1f} s | {summary}")
            out.unlink(missing_ok=True)

    if args.preset:
        survey_rates(scene, model.name, args.preset, "open3d" if warp is None else "warp", warp, args.stations, chunk)


def warp_raw_query(warp, rays: np.ndarray):
    """A function that casts ``rays`` with Warp's kernel alone: rays and outputs stay on the device."""
    import warp as wp

    device_rays = wp.array(rays, dtype=wp.float32, device=warp.device)
    t_hit = wp.empty(len(rays), dtype=wp.float32, device=warp.device)
    face = wp.empty(len(rays), dtype=wp.uint32, device=warp.device)

    def query() -> None:
        warp.query(device_rays, t_hit, face)
        wp.synchronize_device(warp.device)

    query()
    return query


def survey_rates(scene, model_name: str, preset: str, engine_name: str, warp, stations_limit: int | None,
                 chunk: dict) -> None:
    """Section 4: a whole survey with ``preset`` at its own head speed, per engine, to NumPy chunks."""
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.scan.virtual_scanner import VirtualScanner
    from bimscan.survey.survey import prepare_survey, run_survey

    recipe = ScanRecipe.resolve(preset=preset, seed=1, **chunk)
    survey = prepare_survey(scene, recipe)
    stations = survey.stations if stations_limit is None else survey.stations[:stations_limit]
    print(f"\n4. whole survey of {model_name}, preset {preset} ({recipe.settings.pulse_freq_hz / 1e3:g} kHz, "
          f"{recipe.settings.scan_freq_hz:g} Hz, {recipe.settings.head_deg_per_s:g} deg/s): "
          f"{len(stations)} of {len(survey.stations)} stations, to NumPy chunks (no writing)")
    engines = [("open3d", survey.scanner)]
    if engine_name == "warp":
        engines.append((f"warp ({warp.device}), fused",
                        VirtualScanner(scene.mesh, scene.components.label, scanner=recipe.scanner, engine=warp)))
    for label, virtual in engines:
        limited = dataclasses.replace(survey, scanner=virtual, stations=tuple(stations))
        pulses = [0]
        start = time.perf_counter()
        points = sum(len(c) for c in run_survey(limited, reuse_buffers=True,
                                                 on_pulses=lambda k: pulses.__setitem__(0, pulses[0] + k)))
        seconds = time.perf_counter() - start
        print(f"   {label:<24} {pulses[0]:>13,} pulses {points:>13,} points {seconds:8.2f} s = "
              f"{pulses[0] / seconds / 1e6:7.2f} Mpulses/s, {points / seconds / 1e6:7.2f} Mpts/s")


if __name__ == "__main__":
    main()

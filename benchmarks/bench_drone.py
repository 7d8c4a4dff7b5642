"""Risley-prism lidars and drone flights: the patterns against their makers' figures, planned flights'
coverage of every shared IFC model, and the optics and a whole flight against HELIOS++.

Run: python benchmarks/bench_drone.py [--helios PATH_TO/helios++] [--helios-assets HELIOS_SOURCE_TREE]

1. Patterns: each built-in Risley lidar's field of view (its pattern's extent over 1 s) against its
   datasheet's; the Livox Mid-40's FOV coverage after 0.1, 0.2, 0.5, 1.0 and 1.4 s of integration
   against Livox's curve (``risley.fov_coverage``: spots of the beam's larger divergence).
2. Flights: the drone's planned flight over each shared IFC model (``bimscan scan --platform
   drone``, DJI Zenmuse L2, default flight), the whole process timed, and every outer element's
   coverage at 100 points/m^2 (``survey.coverage``); elements below 80 % are listed with why.
3. With HELIOS++ (``--helios``, built from source; ``--helios-assets``: its source tree, whose
   ``python/pyhelios`` holds its platform definitions):
   - optics: each built-in Risley lidar standing still in a closed 200 m cube, HELIOS++'s points'
     directions against bimscan's ``RisleyScanner.directions`` at the same pulse times (HELIOS++
     fires pulse k at (k + 1) / rate: its deflector's clock steps before each pulse);
   - the same flight: 20 s of the duplex's planned flight in bimscan and in HELIOS++ (``bimscan
     export-obj --helios --platform drone``), point counts, labels of nearest pairs, 1 m density
     maps, whole processes timed.
"""

from __future__ import annotations

import argparse
import csv
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ifc"
BIMSCAN = [str(Path(sys.executable).with_name("bimscan"))]  # the console script beside this Python
# Livox wiki, "Livox scanning pattern" (its Mid-40 FOV coverage curve, read off the figure, +-3 points)
LIVOX_MID40_COVERAGE = {0.1: 0.20, 0.2: 0.37, 0.5: 0.68, 1.0: 0.92, 1.4: 0.98}
DATASHEET_FOV = {"livox_mid40": "38.4 (circular)", "livox_mid70": "70.4 (circular)", "livox_avia": "70.4 x 77.2",
                 "dji_zenmuse_l2": "70 x 75", "dji_zenmuse_l2_repetitive": "70 x 3",
                 "livox_mid360": "360 x 59 (-7 to 52)"}


def patterns() -> None:
    from bimscan.scan.risley import RISLEY_SCANNERS, fov_coverage

    print("1. Patterns: field of view over 1 s against the datasheet (degrees, sensor x by y; a spinning head's:")
    print("   azimuth by elevation)")
    for name, lidar in RISLEY_SCANNERS.items():
        x, y = lidar.pattern_extent_deg()
        band = " (elevation {:.1f} to {:.1f})".format(*lidar.elevation_range_deg()) if lidar.spinning else ""
        print(f"   {name:26s} {x:6.1f} x {y:5.1f}{band}   datasheet {DATASHEET_FOV.get(name, '?')}")
    mid40 = RISLEY_SCANNERS["livox_mid40"]
    spot = math.degrees(mid40.beam_divergence_rad)
    print(f"   Livox Mid-40 FOV coverage (spots {spot:.2f} degrees across) against Livox's curve:")
    for seconds, livox in LIVOX_MID40_COVERAGE.items():
        t = np.arange(int(seconds * mid40.pulse_rate_hz)) / mid40.pulse_rate_hz
        start = time.perf_counter()
        share = fov_coverage(mid40.directions(t), mid40.fov_deg, spot)
        print(f"   {seconds:4.1f} s: bimscan {100 * share:5.1f} %, Livox {100 * livox:3.0f} % "
              f"({100 * (share - livox):+5.1f} points; {time.perf_counter() - start:.1f} s to compute)")


def models() -> list[Path]:
    return sorted(SHARED.glob("*.ifc")) if SHARED.is_dir() else []


def flights(work: Path) -> None:
    from bimscan.io import iter_cloud_chunks
    from bimscan.pipeline import build_site, load_scene
    from bimscan.survey.coverage import element_coverage
    from bimscan.survey.recipe import ScanRecipe

    print("2. Flights: the drone's planned flight over each shared model, coverage of outer elements at 100 pts/m^2")
    if not models():
        print(f"   skipped: no shared IFC models at {SHARED}")
        return
    for model in models():
        out = work / f"{model.stem}-drone.laz"
        start = time.perf_counter()
        done = subprocess.run([*BIMSCAN, "scan", str(model), str(out), "--platform", "drone", "--seed", "1",
                               "--overwrite"], capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if done.returncode:
            print(f"   {model.name}: scan failed: {done.stderr.strip().splitlines()[-1]}")
            continue
        flight = next((line.strip() for line in done.stdout.splitlines() if line.strip().startswith("flight:")), "")
        points = done.stdout.split(" points")[0].split(": ")[-1]
        scene = build_site(load_scene(model), ScanRecipe.resolve(platform="drone", seed=1))
        coverage = element_coverage(scene, (chunk.xyz for chunk in iter_cloud_chunks(out, labels=False)))
        low = [e for e in coverage if e.covered_share < 0.8]
        reachable = [e for e in coverage if e.buried <= 0.5]
        print(f"   {model.name}: {points} points in {seconds:.1f} s (whole process); {flight}")
        print(f"      outer elements {len(coverage)}, above the ground {len(reachable)}: "
              f"{sum(e.covered_share >= 0.8 for e in reachable)} covered >= 80 %; below 80 %: {len(low)}")
        for element in low:
            print(f"      - {element.ifc_class} {element.name[:40]!r} ({element.global_id}): "
                  f"{100 * element.covered_share:.0f} % of {element.outer_m2:.1f} m2, {element.why_not()}")


def cube_obj(path: Path, half: float) -> None:
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in corners]
    lines += [f"f {a + 1} {b + 1} {c + 1}\nf {a + 1} {c + 1} {d + 1}" for a, b, c, d in quads]
    path.write_text("\n".join(lines) + "\n")


def read_helios_points(folder: Path) -> np.ndarray:
    """Every point file HELIOS++ wrote under ``folder`` (its xyz text output) as one array."""
    files = sorted(folder.rglob("*_points.xyz")) or sorted(folder.rglob("*.xyz"))
    parts = [np.loadtxt(f, ndmin=2) for f in files if f.stat().st_size]
    return np.concatenate(parts) if parts else np.zeros((0, 12))


def helios_optics(helios: Path, assets: Path, work: Path) -> None:
    from bimscan.io.helios import TRIPOD_MOUNT_Z_M, helios_risley_scanner_xml
    from bimscan.scan.risley import RISLEY_SCANNERS

    print("3a. Optics against HELIOS++: directions of the same pulses, the lidar still in a closed 200 m cube")
    print("    (HELIOS++'s static tripod: the beam leaves 1.5 m above the leg, along its scanner frame's +Y: bimscan's")
    print("    sensor direction (x, y, z) is HELIOS++'s (x, z, -y); its pulse k fires at (k + 1) / rate)")
    for name, lidar in RISLEY_SCANNERS.items():
        if lidar.spinning:
            print(f"    {name}: not compared (HELIOS++'s Risley optics do not spin)")
            continue
        folder = work / f"optics-{name}"
        folder.mkdir(parents=True, exist_ok=True)
        cube_obj(folder / "cube.obj", 100.0)
        (folder / "scanners.xml").write_bytes(helios_risley_scanner_xml(lidar))
        (folder / "scene.xml").write_text(
            '<?xml version="1.0" encoding="UTF-8"?>\n<document>\n<scene id="cube" name="cube">\n<part id="0">\n'
            '<filter type="objloader"><param type="string" key="filepath" value="cube.obj" /></filter>\n'
            '</part>\n</scene>\n</document>\n')
        seconds = 0.02
        (folder / "survey.xml").write_text(
            f'<?xml version="1.0" encoding="UTF-8"?>\n<document>\n<survey name="optics" scene="scene.xml#cube" '
            f'platform="data/platforms.xml#tripod" scanner="scanners.xml#{name}">\n'
            f'<leg maxDuration_s="{seconds}"><platformSettings x="0" y="0" z="0" onGround="false" />\n'
            f'<scannerSettings active="true" pulseFreq_hz="{int(round(lidar.pulse_rate_hz))}" headRotatePerSec_deg="0" />'
            '</leg>\n</survey>\n</document>\n')
        done = subprocess.run([str(helios), "survey.xml", "--assets", ".", "--assets", str(assets / "python/pyhelios"),
                               "--assets", str(assets / "python/pyhelios/data"), "-j", "1", "--seed", "1",
                               "--output", "out"],
                              cwd=folder, capture_output=True, text=True)
        points = read_helios_points(folder / "out")
        if done.returncode or len(points) == 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
            print(f"   {name}: HELIOS++ gave no points ({done.returncode}): {' | '.join(tail)}")
            continue
        ray = points[:, :3] - np.array([0.0, 0.0, TRIPOD_MOUNT_Z_M])
        d = ray / np.linalg.norm(ray, axis=1, keepdims=True)
        gps = points[:, 10]  # seconds from the survey's start time (the clock's time, when not given)
        pulse = np.rint((gps - gps.min()) * lidar.pulse_rate_hz).astype(np.int64)  # every pulse hits the cube
        best = None
        for channel in range(lidar.n_beams):
            mine = lidar.directions((pulse + 1) / lidar.pulse_rate_hz, channel)
            theirs_frame = np.column_stack([mine[:, 0], mine[:, 2], -mine[:, 1]])
            angle = np.degrees(np.arccos(np.clip((theirs_frame * d).sum(axis=1), -1, 1)))
            best = angle if best is None else np.minimum(best, angle)
        print(f"   {name}: {len(points):,} points; angle to bimscan's direction of the same pulse (nearest channel): "
              f"median {np.median(best):.2e}, largest {best.max():.2e} degrees")


def read_helios_las(folder: Path) -> dict[str, np.ndarray]:
    """Every LAS file HELIOS++ wrote under ``folder`` (``--lasOutput``): xyz, classification and the hit
    object (its ``hitObjectId`` extra bytes: the part id, bimscan's component)."""
    import laspy

    parts = []
    for path in sorted(folder.rglob("*.las")):
        las = laspy.read(path)
        parts.append((np.column_stack([las.x, las.y, las.z]), np.asarray(las.classification, dtype=np.int64),
                      np.asarray(las["hitObjectId"], dtype=np.int64)))
    return {"xyz": np.concatenate([p[0] for p in parts]), "label": np.concatenate([p[1] for p in parts]),
            "component": np.concatenate([p[2] for p in parts])}


def helios_flight(helios: Path, assets: Path, work: Path, model: Path, seconds: float | None) -> None:
    """The same flight in both simulators: counts, labels of nearest pairs, 1 m density maps, times."""
    from scipy.spatial import cKDTree

    from bimscan.io import read_cloud

    span = "the whole planned flight" if seconds is None else f"the first {seconds:g} s of the planned flight"
    print(f"3b. The same flight in bimscan and HELIOS++: {model.name}, {span} (Zenmuse L2), whole processes")
    flight = None
    if seconds is not None:  # the planned flight's first seconds, as a trajectory file
        from bimscan.pipeline import build_site, load_scene
        from bimscan.survey.recipe import ScanRecipe
        from bimscan.survey.survey import plan_scene_flight
        from bimscan.survey.trajectory import Trajectory, write_trajectory

        recipe = ScanRecipe.resolve(platform="drone", seed=1)
        planned, _ = plan_scene_flight(build_site(load_scene(model), recipe), recipe.mobile)
        keep = planned.t <= seconds
        flight = write_trajectory(work / "flight.csv", Trajectory(
            t=planned.t[keep], xyz=planned.xyz[keep], roll=planned.roll[keep], pitch=planned.pitch[keep],
            yaw=planned.yaw[keep], pass_id=planned.pass_id[keep]))
    options = ["--platform", "drone"] + (["--trajectory", str(flight)] if flight else [])
    out = work / "bimscan.laz"
    start = time.perf_counter()
    done = subprocess.run([*BIMSCAN, "scan", str(model), str(out), "--seed", "1", "--overwrite", *options],
                          capture_output=True, text=True)
    bimscan_s = time.perf_counter() - start
    if done.returncode:
        print(f"   bimscan failed: {done.stderr.strip().splitlines()[-1]}")
        return
    export = work / "helios-export"
    subprocess.run([*BIMSCAN, "export-obj", str(model), str(export), "--helios", "--overwrite", *options],
                   capture_output=True, text=True, check=True)
    start = time.perf_counter()
    ran = subprocess.run([str(helios), "helios/survey.xml", "--assets", ".", "--assets", str(assets / "python/pyhelios"),
                          "--assets", str(assets / "python/pyhelios/data"), "-j", "2", "--seed", "1", "--lasOutput",
                          "--output", "out"], cwd=export, capture_output=True, text=True)
    helios_s = time.perf_counter() - start
    if ran.returncode:
        print(f"   HELIOS++ failed ({ran.returncode}): {(ran.stderr or ran.stdout).strip().splitlines()[-1]}")
        return
    theirs = read_helios_las(export / "out")
    mine = read_cloud(out)
    n_mine, n_theirs = len(mine.xyz), len(theirs["xyz"])
    print(f"   points: bimscan {n_mine:,}, HELIOS++ {n_theirs:,} ({100 * (n_theirs / n_mine - 1):+.2f} %)")
    rng = np.random.default_rng(0)
    sample = rng.choice(n_theirs, size=min(n_theirs, 1_000_000), replace=False)
    tree = cKDTree(mine.xyz)
    distance, nearest = tree.query(theirs["xyz"][sample], workers=-1)
    same_label = mine.label[nearest] == theirs["label"][sample]
    same_component = mine.component[nearest] == theirs["component"][sample]
    print(f"   nearest pairs (1M of HELIOS++'s points): median distance {1000 * np.median(distance):.1f} mm; labels agree "
          f"on {100 * same_label.mean():.2f} %, components on {100 * same_component.mean():.2f} %")
    lo = np.minimum(mine.xyz.min(axis=0), theirs["xyz"].min(axis=0))[:2]
    hi = np.maximum(mine.xyz.max(axis=0), theirs["xyz"].max(axis=0))[:2]
    bins = [np.arange(lo[a], hi[a] + 1.0, 1.0) for a in range(2)]
    a = np.histogram2d(mine.xyz[:, 0], mine.xyz[:, 1], bins=bins)[0]
    b = np.histogram2d(theirs["xyz"][:, 0], theirs["xyz"][:, 1], bins=bins)[0]
    dense = (a >= 100) | (b >= 100)
    ratio = b[dense] / np.maximum(a[dense], 1)
    print(f"   1 m density maps: {dense.sum():,} cells with >= 100 points; correlation {np.corrcoef(a.ravel(), b.ravel())[0, 1]:.4f}; "
          f"HELIOS++ / bimscan per cell: median {np.median(ratio):.3f}, {100 * np.mean(np.abs(ratio - 1) <= 0.1):.1f} % "
          "of cells within 10 %")
    print(f"   whole processes: bimscan {bimscan_s:.1f} s, HELIOS++ {helios_s:.1f} s (-j 2): {helios_s / bimscan_s:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--helios", type=Path, default=None, help="the helios++ executable (section 3)")
    parser.add_argument("--helios-assets", type=Path, default=None, help="HELIOS++'s source tree (its python/pyhelios)")
    parser.add_argument("--skip-flights", action="store_true", help="skip section 2")
    parser.add_argument("--flight-seconds", type=float, default=None,
                        help="3b: the first seconds of the duplex's planned flight (default: the whole flight)")
    args = parser.parse_args()
    patterns()
    with tempfile.TemporaryDirectory(prefix="bench-drone-") as tmp:
        work = Path(tmp)
        if not args.skip_flights:
            flights(work)
        helios = args.helios or (Path(shutil.which("helios++")) if shutil.which("helios++") else None)
        if helios is None or args.helios_assets is None:
            print("3. HELIOS++: skipped (give --helios PATH and --helios-assets SOURCE_TREE)")
            return
        helios_optics(helios, args.helios_assets, work)
        duplex = SHARED / "duplex.ifc"
        if duplex.exists():
            helios_flight(helios, args.helios_assets, work, duplex, args.flight_seconds)
        else:
            print(f"3b. skipped: no {duplex}")


if __name__ == "__main__":
    main()

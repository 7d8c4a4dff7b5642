"""Cloud writer throughput and memory, measured side by side in one run.

    python benchmarks/bench_io.py                 # 5 M points, 3 repeats, memory at 2 M and 20 M
    python benchmarks/bench_io.py --points 1000000 --repeats 1 --memory 1000000 4000000

The points are scan-like, not random: a TLS station in the middle of a 30 x 20 x 3.5 m hall
sweeps vertical lines (-40..+60 deg elevation) around 360 deg, every pulse hits a wall, the floor
or the ceiling (5 mm range noise), in scanner order, with the label/component of the plane hit,
an intensity falling with range and incidence, and the pulse time. Real scans compress like this
(neighbouring points are close), random points do not.

Rates: best of ``--repeats`` runs of writing the same in-memory chunks of 1 M points, outputs
deleted between runs outside the timing. The laspy rows do the same work with plain laspy
(``LasData`` columns assigned, then ``write``), as in shared/PERFORMANCE.md.
Memory: peak RSS of a fresh process that generates the chunks on the fly, with and without the
LAZ writer, so the difference is what the writer holds; it must not grow with the point count.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from bimscan.io import open_cloud_writer
from bimscan.types import CloudHeader, LabelClass, LabelScheme, PointCloud, Station

HALL_HALF_M = np.array([15.0, 10.0])
HALL_HEIGHT_M = 3.5
BEAM_Z_M = 1.7
CHUNK_POINTS = 1_000_000
PULSE_FREQ_HZ = 500_000.0
ELEVATIONS_PER_LINE = 2_000


def bench_header() -> CloudHeader:
    names = ("Wall&Column", "Beam", "Covering", "Slab", "Others")
    scheme = LabelScheme(
        name="spc5", classes=tuple(LabelClass(i, n, "#808080") for i, n in enumerate(names)), rules=(), default_label="Others"
    )
    return CloudHeader(scheme=scheme, stations=(Station(0, (0.0, 0.0, BEAM_Z_M)),), origin=(0.0, 0.0, 0.0))


def scan_chunks(n_points: int, *, seed: int = 0) -> Iterator[PointCloud]:
    """Scan-like chunks of CHUNK_POINTS rows (see the module docstring), n_points in all."""
    rng = np.random.default_rng(seed)
    elevation = np.deg2rad(np.linspace(-40.0, 60.0, ELEVATIONS_PER_LINE))
    n_lines = -(-n_points // ELEVATIONS_PER_LINE)
    azimuth_step = 2 * np.pi / n_lines
    for start in range(0, n_points, CHUNK_POINTS):
        index = np.arange(start, min(start + CHUNK_POINTS, n_points))
        az = (index // ELEVATIONS_PER_LINE) * azimuth_step
        el = elevation[index % ELEVATIONS_PER_LINE]
        d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
        with np.errstate(divide="ignore"):
            t_wall = np.min(HALL_HALF_M / np.abs(d[:, :2]), axis=1)
            t_floor = np.where(d[:, 2] < 0, BEAM_Z_M / -d[:, 2], np.inf)
            t_ceiling = np.where(d[:, 2] > 0, (HALL_HEIGHT_M - BEAM_Z_M) / d[:, 2], np.inf)
        t = np.minimum(t_wall, np.minimum(t_floor, t_ceiling))
        plane = np.where(t == t_floor, 3, np.where(t == t_ceiling, 2, 0)).astype(np.uint8)
        incidence = np.where(plane == 0, np.max(np.abs(d[:, :2]), axis=1), np.abs(d[:, 2]))
        t_noisy = t + rng.normal(0.0, 0.005, len(t))
        yield PointCloud(
            xyz=d * t_noisy[:, None] + np.array([0.0, 0.0, BEAM_Z_M]),
            label=plane,
            component=(plane.astype(np.int32) * 10 + (az // (np.pi / 2)).astype(np.int32)),
            station=np.zeros(len(t), dtype=np.uint16),
            intensity=np.clip(60_000 * incidence / (1 + 0.05 * t), 0, 65_535).astype(np.uint16),
            time=index / PULSE_FREQ_HZ,
        )


def remove(path: Path) -> None:
    for target in (path, path.with_name(path.name + ".json")):
        if target.is_dir():
            shutil.rmtree(target)
        elif target.exists():
            target.unlink()


def time_best(run: Callable[[], None], cleanup: Callable[[], None], repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        cleanup()
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    cleanup()
    return best


def laspy_baseline(path: Path, chunks: list[PointCloud], *, compress: bool) -> None:
    """Plain laspy: one LasData for the whole cloud (what the reference figures measured)."""
    import laspy

    cloud = PointCloud.concatenate(chunks)
    las_header = laspy.LasHeader(version="1.4", point_format=6)
    las_header.add_extra_dims([laspy.ExtraBytesParams("component", np.int32), laspy.ExtraBytesParams("station", np.uint16)])
    las_header.scales = np.full(3, 1e-4)
    las = laspy.LasData(las_header, points=laspy.ScaleAwarePointRecord.zeros(len(cloud), header=las_header))
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.classification, las.intensity, las.gps_time = cloud.label, cloud.intensity, cloud.time
    las.component, las.station = cloud.component, cloud.station
    las.write(path, laz_backend=laspy.LazBackend.LazrsParallel if compress else None)


def rates(n_points: int, repeats: int, out: Path) -> None:
    chunks = list(scan_chunks(n_points))
    header = bench_header()
    print(f"write rate, {n_points / 1e6:g} M scan-like points in chunks of {CHUNK_POINTS / 1e6:g} M, best of {repeats}")
    print(f"{'format':<26}{'seconds':>9}{'Mpts/s':>9}{'MB':>9}{'bytes/pt':>10}")
    results: dict[str, float] = {}
    for label, name, checksum in [
        ("LAS", "scan.las", False), ("LAS + sha256", "scan.las", True),
        ("LAZ", "scan.laz", False), ("LAZ + sha256", "scan.laz", True),
        ("PLY", "scan.ply", False), ("NumPy folder", "scan", False),
    ]:
        path = out / name

        def run(path: Path = path, checksum: bool = checksum) -> None:
            with open_cloud_writer(path, header=header, checksum=checksum, overwrite=True) as writer:
                for chunk in chunks:
                    writer.write(chunk)

        seconds = time_best(run, lambda path=path: remove(path), repeats)
        run()
        size = sum(p.stat().st_size for p in ([path] if path.is_file() else path.rglob("*")))
        remove(path)
        results[label] = n_points / seconds / 1e6
        print(f"{label:<26}{seconds:>9.2f}{results[label]:>9.2f}{size / 1e6:>9.1f}{size / n_points:>10.2f}")
    for label, name, compress in [("laspy LAS (baseline)", "base.las", False), ("laspy LAZ (baseline)", "base.laz", True)]:
        path = out / name
        seconds = time_best(lambda path=path, compress=compress: laspy_baseline(path, chunks, compress=compress),
                            lambda path=path: remove(path), repeats)
        results[label] = n_points / seconds / 1e6
        print(f"{label:<26}{seconds:>9.2f}{results[label]:>9.2f}")
    print(f"ratio bimscan/laspy: LAS {results['LAS'] / results['laspy LAS (baseline)']:.2f}, "
          f"LAZ {results['LAZ'] / results['laspy LAZ (baseline)']:.2f}")


def memory_child(n_points: int, out: Path, write: bool) -> None:
    """Run in a fresh process: stream n_points through the LAZ writer (or only generate them)."""
    start = time.perf_counter()
    if write:
        with open_cloud_writer(out / f"mem{n_points}.laz", header=bench_header(), overwrite=True) as writer:
            for chunk in scan_chunks(n_points):
                writer.write(chunk)
    else:
        for chunk in scan_chunks(n_points):
            pass
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
    print(f"{peak_mib:.1f} {time.perf_counter() - start:.2f}")


def memory(sizes: list[int], out: Path) -> None:
    print("\npeak memory of a fresh process streaming chunks of 1 M points (ru_maxrss, MiB)")
    print(f"{'points':>12}{'generate only':>15}{'+ LAZ writer':>14}{'writer share':>14}{'LAZ Mpts/s':>12}")
    for n_points in sizes:
        measured = []
        for write in (False, True):
            done = subprocess.run(
                [sys.executable, __file__, "--memory-child", str(n_points), str(out), str(int(write))],
                capture_output=True, text=True, check=True,
            )
            measured.append([float(v) for v in done.stdout.split()])
        (base, _), (peak, seconds) = measured
        print(f"{n_points:>12,}{base:>15.1f}{peak:>14.1f}{peak - base:>14.1f}{n_points / seconds / 1e6:>12.2f}")
        remove(out / f"mem{n_points}.laz")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=5_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--memory", type=int, nargs="*", default=[2_000_000, 20_000_000])
    parser.add_argument("--out", type=Path, default=None, help="scratch folder (default: a new temporary one)")
    parser.add_argument("--memory-child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.memory_child:
        n_points, out, write = args.memory_child
        memory_child(int(n_points), Path(out), write == "1")
        return
    with tempfile.TemporaryDirectory(prefix="bench-io-", dir=args.out) as scratch:
        rates(args.points, args.repeats, Path(scratch))
        if args.memory:
            memory(args.memory, Path(scratch))


if __name__ == "__main__":
    main()

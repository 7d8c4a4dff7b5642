"""Cloud writer throughput and memory, measured side by side in one run.

    python benchmarks/bench_io.py                 # 5 M points, 3 repeats, memory at 2 M and 20 M,
                                                  # OBJ export of 2.4 M triangles
    python benchmarks/bench_io.py --points 1000000 --repeats 1 --memory 1000000 4000000

The points are scan-like, not random: a TLS station in the middle of a 30 x 20 x 3.5 m hall
sweeps vertical lines (-40..+60 deg elevation) around 360 deg, every pulse hits a wall, the floor
or the ceiling (5 mm range noise), in scanner order, with the label/component of the plane hit,
an intensity falling with range and incidence, and the pulse time. Real scans compress like this
(neighbouring points are close), random points do not.

Rates: best of ``--repeats`` rounds (each round runs every writer once, in turn) of writing the
same in-memory chunks of 1 M points; outputs are deleted and the page cache written back
(``os.sync``) between runs, outside the timing. The laspy rows time plain laspy writing
the same points already packed in one ``LasData`` (``LasData.write`` only, as the figures of
shared/PERFORMANCE.md), so they leave out the quantising and packing that bimscan's rows include.
The E57 row writes the same points as one posed scan (cartesian and spherical doubles, intensity,
time stamp, return index/count, label and component extension fields); the bench's synthetic
pulse schedule is not a bimscan scan pattern, so it has no row/column grid fields.
Memory: peak RSS of a fresh process that generates the chunks on the fly, with and without the
LAZ writer, so the difference is what the writer holds; it must not grow with the point count.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from bimscan.io import export_obj, open_cloud_writer, read_obj
from bimscan.types import (
    BimScene,
    CloudHeader,
    ComponentTable,
    LabelClass,
    LabelScheme,
    PointCloud,
    SceneMesh,
    Station,
)

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


def time_rounds(runs: dict[str, tuple[Callable[[], None], Callable[[], None]]], repeats: int) -> dict[str, float]:
    """Best wall time of each run over ``repeats`` rounds; every round runs them all in turn, so
    load from other processes hits all of them alike. Outputs are removed outside the timing."""
    best = dict.fromkeys(runs, float("inf"))
    for _ in range(repeats):
        for label, (run, cleanup) in runs.items():
            cleanup()
            os.sync()  # write back the previous run's files now, not while this run is timed
            start = time.perf_counter()
            run()
            best[label] = min(best[label], time.perf_counter() - start)
    return best


def laspy_data(chunks: list[PointCloud]) -> object:
    """The whole cloud as one plain-laspy ``LasData`` (packed outside the timing)."""
    import laspy

    cloud = PointCloud.concatenate(chunks)
    las_header = laspy.LasHeader(version="1.4", point_format=6)
    las_header.add_extra_dims([laspy.ExtraBytesParams("component", np.int32), laspy.ExtraBytesParams("station", np.uint16)])
    las_header.scales = np.full(3, 1e-4)
    las = laspy.LasData(las_header, points=laspy.ScaleAwarePointRecord.zeros(len(cloud), header=las_header))
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.classification, las.intensity, las.gps_time = cloud.label, cloud.intensity, cloud.time
    las.component, las.station = cloud.component, cloud.station
    return las


def rates(n_points: int, repeats: int, out: Path) -> None:
    chunks = list(scan_chunks(n_points))
    header = bench_header()

    def ours(path: Path, checksum: bool) -> Callable[[], None]:
        def run() -> None:
            with open_cloud_writer(path, header=header, checksum=checksum, overwrite=True) as writer:
                for chunk in chunks:
                    writer.write(chunk)
        return run

    outputs = {
        "LAS": out / "scan.las", "LAS + sha256": out / "scan.las", "LAZ": out / "scan.laz",
        "LAZ + sha256": out / "scan.laz", "E57": out / "scan.e57", "E57 + sha256": out / "scan.e57",
        "PLY": out / "scan.ply", "NumPy folder": out / "scan",
        "laspy LAS (baseline)": out / "base.las", "laspy LAZ (baseline)": out / "base.laz",
    }
    import laspy

    packed = laspy_data(chunks)
    runs: dict[str, tuple[Callable[[], None], Callable[[], None]]] = {}
    for label, path in outputs.items():
        if label.startswith("laspy"):
            backend = laspy.LazBackend.LazrsParallel if path.suffix == ".laz" else None
            run = (lambda path=path, backend=backend: packed.write(path, laz_backend=backend))
        else:
            run = ours(path, checksum=label.endswith("sha256"))
        runs[label] = (run, lambda path=path: remove(path))
    best = time_rounds(runs, repeats)
    print(f"write rate, {n_points / 1e6:g} M scan-like points in chunks of {CHUNK_POINTS / 1e6:g} M, best of {repeats}")
    print(f"{'format':<26}{'seconds':>9}{'Mpts/s':>9}{'MB':>9}{'bytes/pt':>10}")
    rate = {}
    for label, (run, cleanup) in runs.items():
        run()
        path = outputs[label]
        files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
        size = sum(p.stat().st_size for p in files)
        cleanup()
        rate[label] = n_points / best[label] / 1e6
        print(f"{label:<26}{best[label]:>9.2f}{rate[label]:>9.2f}{size / 1e6:>9.1f}{size / n_points:>10.2f}")
    print(f"ratio bimscan/laspy: LAS {rate['LAS'] / rate['laspy LAS (baseline)']:.2f}, "
          f"LAZ {rate['LAZ'] / rate['laspy LAZ (baseline)']:.2f}")
    print(f"ratio E57/LAZ {rate['E57'] / rate['LAZ']:.2f}, E57/LAS {rate['E57'] / rate['LAS']:.2f}")


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
    print(f"{peak_rss_mib():.1f} {time.perf_counter() - start:.2f}")


def peak_rss_mib() -> float:
    """This process's peak resident memory in MiB.

    VmHWM (Linux) belongs to the process image, while ru_maxrss survives fork + exec and would
    report the parent's peak (this benchmark's parent holds 5 M points).
    """
    status = Path("/proc/self/status")
    if status.is_file():
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def memory(sizes: list[int], out: Path) -> None:
    print("\npeak memory of a fresh process streaming chunks of 1 M points (VmHWM, MiB)")
    print(f"{'points':>12}{'generate only':>15}{'+ LAZ writer':>14}{'writer share':>14}{'Mpts/s incl. generation':>25}")
    for n_points in sizes:
        measured = []
        for write in (False, True):
            done = subprocess.run(
                [sys.executable, __file__, "--memory-child", str(n_points), str(out), str(int(write))],
                capture_output=True, text=True, check=True,
            )
            measured.append([float(v) for v in done.stdout.split()])
        (base, _), (peak, seconds) = measured
        print(f"{n_points:>12,}{base:>15.1f}{peak:>14.1f}{peak - base:>14.1f}{n_points / seconds / 1e6:>25.2f}")
        remove(out / f"mem{n_points}.laz")


def grid_scene(n_triangles: int, n_components: int) -> BimScene:
    """A BIM-like scene: n_components wall panels, each a triangulated grid with shared vertices."""
    per = max(2, n_triangles // n_components // 2 * 2)  # triangles per component (even)
    cells_x = max(d for d in range(1, int(np.sqrt(per // 2)) + 1) if (per // 2) % d == 0)
    cells_y = per // 2 // cells_x
    gx, gy = np.meshgrid(np.linspace(0.0, 4.0, cells_x + 1), np.linspace(0.0, 2.8, cells_y + 1), indexing="ij")
    panel = np.stack([gx.ravel(), np.zeros(gx.size), gy.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(cells_x), np.arange(cells_y), indexing="ij")
    a = (i * (cells_y + 1) + j).ravel()
    quads = np.stack([a, a + cells_y + 1, a + cells_y + 2, a + 1], axis=1)
    panel_faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    offsets = np.stack([np.arange(n_components) % 100 * 5.0, np.arange(n_components) // 100 * 0.3, np.zeros(n_components)], 1)
    vertices = (panel[None, :, :] + offsets[:, None, :]).reshape(-1, 3) + np.array([512_300.0, 5_403_100.0, 41.0])
    faces = (panel_faces[None, :, :] + (np.arange(n_components) * len(panel))[:, None, None]).reshape(-1, 3)
    face_component = np.repeat(np.arange(n_components), len(panel_faces))
    text = np.array([f"{c:022d}" for c in range(n_components)])
    table = ComponentTable(
        global_id=text, ifc_class=np.full(n_components, "IfcWall"), predefined_type=np.full(n_components, ""),
        name=text, storey=np.full(n_components, "EG"), parent_class=np.full(n_components, ""),
        label=np.zeros(n_components, dtype=np.uint8),
    )
    return BimScene(
        source="bench.ifc", file_sha256="", schema="IFC4",
        mesh=SceneMesh(vertices, faces.astype(np.int32), face_component.astype(np.int32)),
        components=table, scheme=bench_header().scheme, storeys=(), spaces=(), failed=(), unmapped_classes={},
    )


def obj_export(n_triangles: int, n_components: int, out: Path) -> None:
    scene = grid_scene(n_triangles, n_components)
    print(f"\nOBJ export of {scene.mesh.n_triangles:,} triangles, {len(scene.mesh.vertices):,} vertices, "
          f"{n_components:,} components (one file each), HELIOS++ scene included")
    start = time.perf_counter()
    export = export_obj(scene, out / "obj", helios=True)
    written = time.perf_counter() - start
    start = time.perf_counter()
    groups = read_obj(export.model_obj)
    read = time.perf_counter() - start
    size = sum(p.stat().st_size for p in (out / "obj").rglob("*") if p.is_file())
    print(f"export_obj {written:.2f} s ({size / 1e6:.0f} MB written), read_obj(model.obj) {read:.2f} s, {len(groups):,} groups")
    shutil.rmtree(out / "obj")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=5_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--memory", type=int, nargs="*", default=[2_000_000, 20_000_000])
    parser.add_argument("--obj-triangles", type=int, default=2_400_000, help="0 skips the OBJ export")
    parser.add_argument("--obj-components", type=int, default=20_000)
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
        if args.obj_triangles:
            obj_export(args.obj_triangles, args.obj_components, Path(scratch))


if __name__ == "__main__":
    main()

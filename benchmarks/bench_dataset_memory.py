"""Peak memory of a dataset build against its number of units: one unit, then many, same workers.

Run: python benchmarks/bench_dataset_memory.py [--head-speed 60] [--workers 1 2]

Builds with ``bimscan build`` (a subprocess, local executor, LAZ, one shared warm geometry cache),
for every ``--workers`` value (1 or 2): as many units as workers, the largest (the two-storey
generated office scanned with exp5, and exp6: the densest presets), then the dataset of the
benchmarks (2 generated scenes x the 6 presets, 12 units; ``--scenes 4`` for 24). While each build
runs, every process of its tree is read from /proc every 0.1 s: the peak of each process's own
resident memory (VmHWM: the driver, the largest worker) and the peak of their sum (what the build
takes from the machine). Prints one row per build and the ratio of the many-unit build's peaks
to the one-unit build's with the same workers: a build whose memory is bounded holds it near 1
whatever the number of units (the workers each hold one unit at a time, the driver a manifest row
per unit).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCENES = (("office-2f", 1, 2), ("office-1f", 2, 1), ("office-3f", 3, 3), ("office-1f-b", 4, 1))


def spec_text(scenes: list[tuple[str, int, int]], presets: list[int], head_deg_per_s: float) -> str:
    lines = ['name = "memory"\nformats = ["laz"]\n']
    for name, seed, storeys in scenes:
        lines.append(f'[[scenes]]\nname = "{name}"\ngenerate = {{ seed = {seed}, storeys = {storeys} }}\n')
    for k in presets:
        lines.append(f'[[configs]]\nname = "exp{k}"\npreset = "exp{k}"\nhead_deg_per_s = {head_deg_per_s!r}\n')
    return "\n".join(lines)


def _tree(root: int) -> list[int]:
    """``root`` and its descendants (from /proc)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError):
                continue
    found, frontier = [root], [root]
    while frontier:
        frontier = [pid for pid, parent in parents.items() if parent in frontier]
        found += frontier
    return found


def _memory_kb(pid: int) -> tuple[int, int]:
    """(VmRSS, VmHWM) of a process in kB; zeros when it is gone."""
    values = {"VmRSS": 0, "VmHWM": 0}
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            key = line.split(":", 1)[0]
            if key in values:
                values[key] = int(line.split()[1])
    except (OSError, ValueError):
        pass
    return values["VmRSS"], values["VmHWM"]


def measure_build(spec: Path, out: Path, workers: int, environment: dict[str, str]) -> dict[str, float]:
    """Run one build; its driver's and largest worker's peak RSS, and the peak of the tree's sum (MB)."""
    command = [sys.executable, "-m", "bimscan.cli.main", "build", str(spec), str(out), "--workers", str(workers)]
    start = time.perf_counter()
    process = subprocess.Popen(command, env=environment, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    driver_peak, worker_peak, total_peak = 0, 0, 0
    while process.poll() is None:
        total = 0
        for pid in _tree(process.pid):
            rss, hwm = _memory_kb(pid)
            total += rss
            if pid == process.pid:
                driver_peak = max(driver_peak, hwm)
            else:
                worker_peak = max(worker_peak, hwm)
        total_peak = max(total_peak, total)
        time.sleep(0.1)
    output = process.stdout.read()
    if process.returncode != 0:
        sys.exit(f"build failed:\n{output}")
    summary = next(line for line in output.splitlines() if " units: " in line)
    units = int(summary.split(": ", 1)[1].split(" units")[0])
    points = int(summary.split("; ")[1].split(" points")[0].replace(",", ""))
    return {"units": units, "points": points, "seconds": time.perf_counter() - start,
            "driver_mb": driver_peak / 1024, "worker_mb": worker_peak / 1024, "total_mb": total_peak / 1024}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--head-speed", type=float, default=60.0, help="deg/s for every preset (10 = the paper's)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], choices=[1, 2], help="worker counts")
    parser.add_argument("--scenes", type=int, default=2, choices=[2, 3, 4], help="scenes of the many-unit build")
    args = parser.parse_args()

    root = Path(tempfile.mkdtemp(prefix="bimscan-bench-memory-"))
    environment = os.environ | {"BIMSCAN_PROGRESS": "0", "BIMSCAN_CACHE_DIR": str(root / "cache")}
    many = root / "many.toml"
    many.write_text(spec_text(list(SCENES[:args.scenes]), [1, 2, 3, 4, 5, 6], args.head_speed))
    warm = root / "warm.toml"
    warm.write_text(spec_text(list(SCENES[:args.scenes]), [1], args.head_speed * 6))
    measure_build(warm, root / "warm", 2, environment)  # the geometry cache and page cache warm for every build
    print(f"machine: {os.cpu_count()} cores; LAZ, head {args.head_speed:g} deg/s; peaks of resident memory in MB")
    print(f"{'workers':>7} {'units':>5} {'points':>12} {'seconds':>8} {'driver':>7} {'worker':>7} {'all':>7}"
          f" {'driver x':>8} {'worker x':>8} {'all x':>6}")
    for workers in args.workers:
        one = root / f"one-w{workers}.toml"  # as many units as run at once: the largest
        one.write_text(spec_text([SCENES[0]], [5, 6][:workers], args.head_speed))
        rows = []
        for spec in (one, many):
            row = measure_build(spec, root / f"{spec.stem}-w{workers}", workers, environment)
            rows.append(row)
            base = rows[0]
            print(f"{workers:>7} {row['units']:>5} {row['points']:>12,} {row['seconds']:>8.1f} "
                  f"{row['driver_mb']:>7.0f} {row['worker_mb']:>7.0f} {row['total_mb']:>7.0f} {row['driver_mb'] / base['driver_mb']:>8.2f} "
                  f"{row['worker_mb'] / base['worker_mb']:>8.2f} {row['total_mb'] / base['total_mb']:>6.2f}")
    print("driver, worker: the peak RSS of the build's process and of its largest worker; all: the peak of the "
          "tree's summed RSS; x: against the build of as many units as workers (the largest), same workers")


if __name__ == "__main__":
    main()

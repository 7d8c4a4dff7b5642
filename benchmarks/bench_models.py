"""Every model scans end to end: ``bimscan scan MODEL OUT --stations auto`` as a user runs it, plain,
with clutter and at the structure stage, on real IFC files and the generated styles.

Run: python benchmarks/bench_models.py [MODEL.ifc ...] [--styles office residential site]
     [--modes plain clutter structure] [--head-speed 60] [--csv models.csv]
(default models: ../shared/data/ifc/*.ifc; generated buildings: seed 1, 2 storeys)

For each model and mode: exit status, stations, points, whole-process seconds (the geometry cache
warmed first by ``bimscan info``, so the parse is not counted twice), the share of that time spent
dressing the site (``seconds:`` line of ``bimscan scan``), and the clutter run's time over the plain
run's (the dressing cost, whole process). A failure shows its one error line.
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
DEFAULT = sorted((HERE.parent.parent / "shared" / "data" / "ifc").glob("*.ifc"))
MODES = {"plain": [], "clutter": ["--clutter", "0.3"], "structure": ["--stage", "structure"]}
POINTS = re.compile(r": ([\d,]+) points from (\d+) stations")
STEPS = re.compile(r"seconds: (.*)$", re.M)


def bimscan(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bimscan.cli.main", *args], capture_output=True, text=True)


def run(model: Path, mode: str, work: Path, head_speed: float) -> dict[str, object]:
    out = work / f"{model.stem}.{mode}.laz"
    start = time.perf_counter()
    done = bimscan("scan", str(model), str(out), "--stations", "auto", "--head-speed", str(head_speed), "--overwrite",
                   *MODES[mode])
    seconds = time.perf_counter() - start
    out.unlink(missing_ok=True)
    row: dict[str, object] = {"model": model.stem, "mode": mode, "exit": done.returncode, "seconds": round(seconds, 1)}
    found = POINTS.search(done.stdout)
    if found:
        row |= {"stations": int(found.group(2)), "points": int(found.group(1).replace(",", ""))}
    steps = STEPS.search(done.stdout)
    if steps:
        parts = dict(part.rsplit(" ", 1) for part in steps.group(1).split(", "))
        row["dressing_share"] = round(float(parts.get("dressing", 0.0)) / seconds, 3)
    if done.returncode:
        row["error"] = next((line for line in done.stderr.splitlines() if line.startswith("error:")), done.stderr[-200:])
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="*", type=Path, default=DEFAULT)
    parser.add_argument("--styles", nargs="*", default=["office", "residential", "site"])
    parser.add_argument("--modes", nargs="*", default=list(MODES), choices=list(MODES))
    parser.add_argument("--head-speed", type=float, default=60.0, help="deg/s (exp3's pulse and line rates)")
    parser.add_argument("--csv", type=Path, default=None)
    args = parser.parse_args()
    os.environ.setdefault("BIMSCAN_PROGRESS", "0")
    work = Path(tempfile.mkdtemp(prefix="bimscan-bench-models-"))
    models = list(args.models)
    for style in args.styles:
        path = work / f"generated_{style}.ifc"
        bimscan("make-building", str(path), "--seed", "1", "--storeys", "2", "--style", style)
        models.append(path)
    rows = []
    print(f"exp3 at {args.head_speed:g} deg/s, --stations auto; whole-process seconds with a warm geometry cache\n")
    print("| model | mode | exit | stations | points | seconds | dressing share | clutter / plain |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for model in models:
        bimscan("info", str(model))  # warms the geometry cache
        plain_seconds = None
        for mode in args.modes:
            row = run(model, mode, work, args.head_speed)
            if mode == "plain" and row["exit"] == 0:
                plain_seconds = float(row["seconds"])  # type: ignore[arg-type]
            ratio = (f"{float(row['seconds']) / plain_seconds:.2f}" if mode == "clutter" and plain_seconds and
                     row["exit"] == 0 else "")
            row["clutter_over_plain"] = ratio
            rows.append(row)
            share = f"{100 * float(row['dressing_share']):.0f} %" if "dressing_share" in row else ""
            print(f"| {row['model']} | {mode} | {row['exit']} | {row.get('stations', '')} | "
                  f"{row.get('points', 0):,} | {row['seconds']} | {share} | {ratio} |"
                  + (f" {row['error']}" if "error" in row else ""), flush=True)
    if args.csv:
        with args.csv.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=sorted({k for r in rows for k in r}))
            writer.writeheader()
            writer.writerows(rows)


if __name__ == "__main__":
    main()

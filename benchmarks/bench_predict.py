"""Prediction rate of ``bimscan predict`` on a whole-building scan, and its scores on real rooms,
this checkout and an earlier one side by side in one run.

    python benchmarks/bench_predict.py CHECKPOINT --baseline-src ../old/src
    python benchmarks/bench_predict.py CHECKPOINT --scan my_building.laz --real ../shared/data/real/s3dis_area6

CHECKPOINT must be readable by both checkouts (one trained by the earlier one: the current code
reads old checkpoints with the evaluation settings they were trained with). ``--baseline-src``
is the ``src`` folder of another checkout (``git worktree add ../old <commit>``); without it only
this checkout's rows are printed.

The scans: ``--scan`` (LAS/LAZ, repeatable), or by default two scans of the shared duplex model
(two storeys, auto stations, clutter at 0.3), made once with this checkout and kept in
``--work``: the default preset (exp3 at 10 deg/s, what ``bimscan scan`` makes; 13.4M points)
and a sparse one (exp1 at 60 deg/s; 1.1M points, ten per 0.1 m voxel). Labelling costs per
voxel (the network) and per point (reading, spreading votes, writing), so points/s depends on
the density: the sparse scan shows the per-voxel cost, the default one a scan as users bring.
``--also "--stride 1.5 --votes 1"`` adds a row of this checkout with those evaluation options
(repeatable). Every row is a fresh process (``python -m bimscan.cli.main predict``), timed
whole (start-up, reading, features, the network, writing), with the same checkpoint, device
(CPU), batch size and seed; the rate is the scan's points over the best of ``--repeats`` wall
times. ``agree`` is the share of points given the same class as this checkout's first row.
With ``--real``, ``bimscan evaluate`` of both on those labelled rooms: pooled mIoU and kappa.
Run it on a quiet machine: two cores are easily saturated.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DUPLEX = ROOT.parent / "shared" / "data" / "ifc" / "duplex.ifc"


def _run(src: Path, args: list[str]) -> float:
    """Wall seconds of ``bimscan ARGS`` run from the checkout whose package lies in ``src``."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bimscan.cli.main", *args], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"error: bimscan {' '.join(args[:1])} failed under {src}:\n{done.stderr.strip()[-2000:]}")
    return seconds


SCANS = {  # name: preset and head speed of the default scans
    "duplex_exp3_clutter.laz": ("exp3", None),
    "duplex_exp1_clutter.laz": ("exp1", "60"),
}


def _default_scans(work: Path) -> list[Path]:
    scans = []
    for name, (preset, head_speed) in SCANS.items():
        scan = work / name
        if not scan.exists():
            if not DUPLEX.is_file():
                raise SystemExit(f"error: {DUPLEX} absent; give a scan with --scan")
            print(f"scanning {DUPLEX.name} once into {scan} ...", flush=True)
            _run(ROOT / "src", ["scan", str(DUPLEX), str(scan), "--stations", "auto", "--preset", preset,
                                *(["--head-speed", head_speed] if head_speed else []), "--clutter", "0.3", "--seed", "0"])
        scans.append(scan)
    return scans


def _classes(path: Path) -> np.ndarray:
    return np.asarray(laspy.read(path).classification, dtype=np.int64)


def _evaluate(src: Path, checkpoint: Path, real: Path, out: Path, batch: int) -> tuple[float, float, float]:
    seconds = _run(src, ["evaluate", str(checkpoint), str(real), "--out", str(out), "--device", "cpu",
                         "--batch-size", str(batch)])
    pooled = json.loads((out / "evaluation.json").read_text())["all points"]["metrics"]
    return pooled["miou"], pooled["kappa"], seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--scan", type=Path, action="append",
                        help="a LAS/LAZ scan to label (repeatable; default: two scans of the shared duplex, made once)")
    parser.add_argument("--baseline-src", type=Path, help="the src folder of an earlier checkout, for its rows")
    parser.add_argument("--real", type=Path, help="labelled real rooms to score both checkouts on")
    parser.add_argument("--work", type=Path, default=Path("/tmp/bimscan-bench-predict"))
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--also", action="append", default=[], help="options of an extra row of this checkout")
    args = parser.parse_args()

    args.work.mkdir(parents=True, exist_ok=True)
    scans = args.scan or _default_scans(args.work)
    checkouts = {"this checkout": ROOT / "src"}
    if args.baseline_src:
        checkouts["baseline"] = args.baseline_src.resolve()
    rows = [(name, src, []) for name, src in checkouts.items()]
    rows += [(f"this checkout, {options}", ROOT / "src", options.split()) for options in args.also]

    for scan in scans:
        points = laspy.open(scan).header.point_count
        print(f"\npredict: {scan.name}, {points:,} points, checkpoint {args.checkpoint.name}, CPU, batch {args.batch_size}")
        print("| checkout | seconds (whole process) | points/s | agree |")
        print("|---|---:|---:|---:|")
        labels: dict[str, np.ndarray] = {}
        for k, (name, src, options) in enumerate(rows):
            out = args.work / f"predicted-{k}.laz"
            best = min(_run(src, ["predict", str(args.checkpoint), str(scan), str(out), "--overwrite", "--device", "cpu",
                                  "--batch-size", str(args.batch_size), "--seed", "0", *options])
                       for _ in range(args.repeats))
            labels[name] = _classes(out)
            agree = float(np.mean(labels[name] == labels["this checkout"]))
            print(f"| {name} | {best:.1f} | {points / best:,.0f} | {agree:.3f} |", flush=True)

    if args.real:
        print(f"\nevaluate: {args.real}")
        print("| checkout | mIoU | kappa | seconds |")
        print("|---|---:|---:|---:|")
        for name, src in checkouts.items():
            miou, kappa, seconds = _evaluate(src, args.checkpoint, args.real, args.work / f"eval-{name.replace(' ', '-')}",
                                             args.batch_size)
            print(f"| {name} | {miou:.4f} | {kappa:.4f} | {seconds:.0f} |", flush=True)


if __name__ == "__main__":
    main()

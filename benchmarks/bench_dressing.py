"""What dressing a site costs against the plain scan, on big generated offices and the shared models,
this checkout and (optionally) an earlier one side by side in one run.

Run: python benchmarks/bench_dressing.py [MODEL.ifc ...] [--storeys 5 10] [--rounds 1]
     [--baseline-src ../old/src] [--clutter 0.3] [--preset exp1] [--head-speed 60]
(default models: generated offices, seed 2, of each ``--storeys`` count, and ../shared/data/ifc/*.ifc)

For every model, as a new user runs it: ``bimscan scan MODEL OUT --preset exp1 --head-speed 60
--stations auto`` (plain) and the same with ``--clutter 0.3``, each a fresh process timed whole,
with the geometry cache warmed first by ``bimscan info`` (the parse is not counted twice); the
best of ``--rounds`` interleaved rounds. Printed: the dressing's seconds (the scan's ``seconds:``
line), dressing / plain scan and the cluttered scan's whole process / the plain one's (the target
is at most 3; the shared models have been at 1.1-1.3).

Then the dressing alone, per step, in a fresh process per model and checkout (``dress_scene_timed``
with the same site model and seed 0): the construction stage, the free floor (the probes' BVH and
every room's floor grid), placing the objects, cutting the ceiling tiles where lay-in fittings sit,
milliseconds per room and per object placed, and the dressed mesh's triangles. A dressing whose cost
follows the objects placed keeps its milliseconds per object when the building grows; one that
does per-room work over the whole building does not.

``--baseline-src`` is the ``src`` folder of another checkout (``git archive COMMIT src | tar -x
-C ../old``): its rows come from the same commands with that package first on the path.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SRC = HERE.parent / "src"
SHARED = sorted((HERE.parent.parent / "shared" / "data" / "ifc").glob("*.ifc"))
STEPS = re.compile(r"seconds: (.*)$", re.M)
PLACED = re.compile(r"placed (\d+) objects in (\d+) rooms")

# Run in a fresh process with one checkout's package: the dressing alone, per step (any checkout's DressTimings).
DRESS_ALONE = """
import dataclasses, json, sys, time
from bimscan.pipeline import load_scene
from bimscan.site import dress_scene_timed
from bimscan.site.model import ClutterSettings, SiteModel
scene = load_scene(sys.argv[1])
start = time.perf_counter()
dressed, timings = dress_scene_timed(scene, SiteModel(clutter=ClutterSettings(density=float(sys.argv[2]))), seed=0)
out = dataclasses.asdict(timings) | {"wall_s": time.perf_counter() - start, "objects": sum(dressed.site.placed.values()),
                                     "triangles_before": len(scene.mesh.faces), "triangles": len(dressed.mesh.faces)}
print(json.dumps(out))
"""


def bimscan(src: Path, *args: str) -> tuple[subprocess.CompletedProcess, float]:
    """``bimscan ARGS`` in a fresh process with the package of ``src`` first; its wall seconds."""
    env = {**os.environ, "PYTHONPATH": str(src), "BIMSCAN_PROGRESS": "0"}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "bimscan.cli.main", *args], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"error: bimscan {' '.join(args)} failed under {src}:\n{done.stderr.strip()[-2000:]}")
    return done, seconds


def scan_row(src: Path, model: Path, work: Path, args: argparse.Namespace, rounds: int) -> dict[str, float]:
    """Best whole-process seconds of the plain and the cluttered scan (interleaved rounds) and the
    dressing's seconds, rooms and objects of the best cluttered run."""
    common = ["--preset", args.preset, "--head-speed", str(args.head_speed), "--stations", "auto", "--overwrite"]
    best: dict[str, float] = {}
    for _ in range(rounds):
        _, plain = bimscan(src, "scan", str(model), str(work / "plain.laz"), *common)
        done, clutter = bimscan(src, "scan", str(model), str(work / "clutter.laz"), *common,
                                "--clutter", str(args.clutter))
        steps = dict(part.rsplit(" ", 1) for part in STEPS.search(done.stdout).group(1).split(", "))
        best["plain_s"] = min(best.get("plain_s", float("inf")), plain)
        if clutter < best.get("clutter_s", float("inf")):
            placed = PLACED.search(done.stdout)
            best |= {"clutter_s": clutter, "dressing_s": float(steps["dressing"]),
                     "objects": int(placed.group(1)) if placed else 0, "rooms": int(placed.group(2)) if placed else 0}
    return best


def dress_alone(src: Path, model: Path, density: float) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "BIMSCAN_PROGRESS": "0"}
    done = subprocess.run([sys.executable, "-c", DRESS_ALONE, str(model), str(density)], env=env, capture_output=True,
                          text=True)
    if done.returncode != 0:
        raise SystemExit(f"error: dressing {model} failed under {src}:\n{done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="*", type=Path, default=None, help="IFC files (default: the shared models)")
    parser.add_argument("--storeys", type=int, nargs="*", default=[5, 10],
                        help="generated offices (seed 2) of these storey counts (none: --storeys with no value)")
    parser.add_argument("--rounds", type=int, default=1, help="interleaved rounds; the best of each is kept")
    parser.add_argument("--baseline-src", type=Path, default=None, help="the src folder of an earlier checkout")
    parser.add_argument("--clutter", type=float, default=0.3, help="clutter density (objects per m2 of free floor)")
    parser.add_argument("--preset", default="exp1")
    parser.add_argument("--head-speed", type=float, default=60.0)
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="bimscan-bench-dressing-"))
    os.environ.setdefault("BIMSCAN_CACHE_DIR", str(work / "cache"))
    checkouts = [("this", SRC)] + ([("baseline", args.baseline_src.resolve())] if args.baseline_src else [])
    models: list[tuple[str, Path]] = []
    for storeys in args.storeys:
        path = work / f"office-{storeys}f.ifc"
        bimscan(SRC, "make-building", str(path), "--seed", "2", "--storeys", str(storeys), "--style", "office")
        models.append((f"office seed 2, {storeys} storeys", path))
    models += [(p.stem, p) for p in (args.models if args.models else SHARED)]
    cores = os.cpu_count() or 1
    print(f"{cores} cores, load average {os.getloadavg()[0]:.1f}; {args.preset} at {args.head_speed:g} deg/s, "
          f"--stations auto, --clutter {args.clutter:g}; whole-process seconds, warm geometry cache, "
          f"best of {args.rounds}\n")
    print("| model | checkout | rooms | objects | plain s | clutter s | dressing s | dressing / plain | clutter / plain |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, model in models:
        bimscan(SRC, "info", str(model))  # warms the geometry cache (the same cache format for both)
        for label, src in checkouts:
            row = scan_row(src, model, work, args, args.rounds)
            print(f"| {name} | {label} | {row['rooms']} | {row['objects']:,} | {row['plain_s']:.1f} | "
                  f"{row['clutter_s']:.1f} | {row['dressing_s']:.1f} | {row['dressing_s'] / row['plain_s']:.2f} | "
                  f"{row['clutter_s'] / row['plain_s']:.2f} |", flush=True)
    print("\nThe dressing alone, per step (seconds; fresh process, seed 0):\n")
    print("| model | checkout | stage | free floor | placement | tile cuts | total | ms / room | ms / object | "
          "triangles before -> after |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    notes = []
    for name, model in models:
        for label, src in checkouts:
            t = dress_alone(src, model, args.clutter)
            total = t["stage_s"] + t["floor_s"] + t["placement_s"] + t.get("cut_s", 0.0)
            cuts = f"{t['cut_s']:.2f}" if "cut_s" in t else "(in placement)"
            print(f"| {name} | {label} | {t['stage_s']:.2f} | {t['floor_s']:.2f} | {t['placement_s']:.2f} | {cuts} | "
                  f"{total:.2f} | {1000 * total / max(t['rooms'], 1):.0f} | {1000 * total / max(t['objects'], 1):.1f} | "
                  f"{t['triangles_before']:,} -> {t['triangles']:,} |", flush=True)
            rooms = t.get("per_room") or []
            per_object = sorted(1000 * s / n for _, n, s in rooms if n)
            if per_object:
                slowest = max(rooms, key=lambda r: r[2])
                notes.append(f"- {name} ({label}): placement per room, ms per object placed: median "
                             f"{per_object[len(per_object) // 2]:.1f}, max {per_object[-1]:.1f}; slowest room "
                             f"{slowest[0]!r} ({slowest[1]} objects, {slowest[2]:.2f} s)")
    print("\n" + "\n".join(notes))
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()

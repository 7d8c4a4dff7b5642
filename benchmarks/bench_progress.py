"""Scan against model, measured against the truth bimscan's own scans carry.

Run: python benchmarks/bench_progress.py [--quick | --large | --cases NAME,...] [--keep DIR [--rescore | --reuse-align]]

Every case is a scan bimscan makes of a shared IFC model or a generated building, as the site
stands at a construction stage or date (walls missing, clutter, people, as-built deviations,
sensor effects), tripod or handheld; the scan is then moved by a random rigid motion (any
heading, an offset of up to 500 km as map coordinates have, and in the unlevelled cases a tilt
of up to 3 degrees) and written as another tool's LAS would hold it: station ids in
``point_source_id``, nothing else (tripod; the stations must be estimated), or as bimscan's own
file in map coordinates (handheld: its beam origins).

Then, as a user would, ``bimscan align MODEL SCAN OUT`` (no ``--init``, no ``--levelled``) and
``bimscan progress MODEL SCAN OUT --transform OUT/transform.json`` (``--at`` where the case
scanned a date), each timed as a whole process. Against the truth:

- alignment: the rotation between the found and the true pose (degrees) and the distance
  between where they put the scan's centre (cm);
- status, on the elements the truth says are visible: built against not built, precision and
  recall per class; the share of them the comparison left "not visible"; and the elements it
  calls "not built" that no station could see (must be none). Truth: an element is built when
  the scan's component table holds it; visible when rays from the scan's stations (the walk's
  poses, every second, for a handheld scan) reach at least 0.05 m2 and 5 % of its surface
  within the scanner's range, at most 80 degrees from the surface's normal, with nothing of the
  scanned scene (clutter and people included) in front; faces flush with another element's
  face are left out, as the comparison leaves them out (no scan can tell which of two coincident
  faces stands);
- deviation: for the elements the truth displaced by more than twice the scanner's range noise
  (10 mm), the reported offset against the true one along the axes the fit pins: the share
  within 5 mm;
- deviation against the site's grid: the cases with as-built deviations are compared once more
  with ``--transform control.csv``, six surveyed targets (the model's bounding-box corners and two
  mid-height points, each known to CONTROL_SIGMA_M per axis in both frames, as a total station's
  control and a target's fitted centre are) instead of the found pose, which is the mean of the
  deviated elements themselves;
- schedule (the cases scanned with ``--at DATE``, judged with the same date): how many elements
  the comparison calls on time, not due, behind, ahead (the site stands as scheduled: behind and
  ahead are errors);
- stations (tripod): the largest distance between a station and the one ``progress`` estimated
  from the points of its id.

``--large`` times the duplex at the sizes the targets name (about 50M and 100M points).

Prints one Markdown table per measure, every case a row; timings are this machine's.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ifc"
BIMSCAN = [sys.executable, "-m", "bimscan.cli.main"]
CLASSES = ("Wall&Column", "Slab", "Beam", "Covering")
VISIBLE_M2 = 0.05
VISIBLE_SHARE = 0.05
MAX_INCIDENCE_DEG = 80.0
TRUTH_RANGE_M = 30.0  # a handheld walk's lidar (VLP-16: 100 m, but sparse past a few rooms)
IN_FRONT_M = 0.05
CONTROL_SIGMA_M = 0.002  # a control target's place, per axis, in the site grid and in the scan (survey practice: 1-2 mm)


@dataclass(frozen=True)
class Case:
    name: str
    model: str  # a shared file name, or "generated:<style>:<seed>:<storeys>[:<schedule start>]"
    scan_args: tuple[str, ...]
    tilt_deg: float = 0.0
    seed: int = 0
    at: str | None = None
    handheld: bool = False


CASES = (
    Case("duplex-structure-30%-missing", "duplex.ifc", ("--stage", "structure", "--walls-missing", "0.3", "--clutter",
                                                        "0.3", "--as-built"), seed=1),
    Case("duplex-structure-70%-missing-tilted", "duplex.ifc", ("--stage", "structure", "--walls-missing", "0.7",
                                                               "--clutter", "0.3", "--as-built"), tilt_deg=3.0, seed=2),
    Case("duplex-finished-full", "duplex.ifc", ("--stage", "finished", "--clutter", "0.75", "--realism", "full"),
         seed=3),
    Case("duplex-enclosed-handheld", "duplex.ifc", ("--stage", "enclosed", "--walls-missing", "0.3", "--clutter",
                                                    "0.3", "--platform", "handheld"), seed=4, handheld=True),
    Case("fzk-structure-30%-missing", "AC20-FZK-Haus.ifc", ("--stage", "structure", "--walls-missing", "0.3",
                                                            "--clutter", "0.3", "--as-built"), seed=5),
    Case("fzk-enclosed-tilted", "AC20-FZK-Haus.ifc", ("--stage", "enclosed", "--clutter", "0.5", "--as-built",
                                                      "--realism", "full"), tilt_deg=3.0, seed=6),
    Case("ifcopenhouse-structure", "IfcOpenHouse_IFC4.ifc", ("--stage", "structure", "--walls-missing", "0.3",
                                                             "--clutter", "0.3", "--as-built"), seed=7),
    Case("example-finished", "example.ifc", ("--stage", "finished", "--clutter", "0.5", "--as-built"), seed=8),
    Case("office-structure-70%-missing", "generated:office:1:2", ("--stage", "structure", "--walls-missing", "0.7",
                                                                   "--clutter", "0.3", "--as-built"), seed=9),
    Case("office-enclosed-tilted", "generated:office:2:3", ("--stage", "enclosed", "--walls-missing", "0.3",
                                                            "--clutter", "0.5", "--as-built", "--realism", "full"),
         tilt_deg=3.0, seed=10),
    Case("residential-finished", "generated:residential:3:2", ("--stage", "finished", "--clutter", "0.75",
                                                               "--as-built"), seed=11),
    Case("site-structure-tilted", "generated:site:4:2", ("--stage", "structure", "--walls-missing", "0.5",
                                                         "--clutter", "0.5", "--as-built"), tilt_deg=3.0, seed=12),
    Case("office-structure-handheld", "generated:office:5:2", ("--stage", "structure", "--walls-missing", "0.3",
                                                               "--clutter", "0.3", "--platform", "handheld"),
         seed=13, handheld=True),
    Case("office-scheduled-tilted", "generated:office:6:2:2026-09-07", ("--at", "2026-10-19", "--clutter", "0.3",
                                                                        "--as-built"),
         tilt_deg=2.0, seed=14, at="2026-10-19"),
    Case("residential-scheduled-handheld", "generated:residential:7:2:2026-09-07",
         ("--at", "2026-11-02", "--clutter", "0.3", "--platform", "handheld"), seed=15, at="2026-11-02", handheld=True),
)
# --large: whole-process times at the sizes the targets name (the duplex at 500 kHz, the head
# turning at 14 and 6.6 deg/s: about 50M and 100M points)
LARGE = (
    Case("duplex-50M", "duplex.ifc", ("--stage", "finished", "--clutter", "0.3", "--as-built", "--preset", "exp5",
                                      "--head-speed", "14"), seed=16),
    Case("duplex-100M", "duplex.ifc", ("--stage", "finished", "--clutter", "0.3", "--as-built", "--preset", "exp5",
                                       "--head-speed", "6.6"), seed=17),
)
QUICK = ("duplex-structure-30%-missing", "fzk-enclosed-tilted", "office-structure-70%-missing")


def run(command: list[str], *, log: Path) -> float:
    """Run a command (a whole process, as a user would); its seconds. Stops the benchmark on failure."""
    start = time.perf_counter()
    with log.open("a") as out:
        out.write("$ " + " ".join(command) + "\n")
        out.flush()
        done = subprocess.run(command, stdout=out, stderr=subprocess.STDOUT, env={"BIMSCAN_PROGRESS": "0",
                                                                              **__import__("os").environ})
    if done.returncode:
        raise SystemExit(f"failed ({done.returncode}): {' '.join(command)}; see {log}")
    return time.perf_counter() - start


def model_path(case: Case, work: Path) -> Path:
    if not case.model.startswith("generated:"):
        path = SHARED / case.model
        if not path.is_file():
            raise SystemExit(f"{path} is absent: the benchmark needs ../shared/data/ifc beside the checkout")
        return path
    from bimscan.ifc.generate import make_building

    _, style, seed, storeys, *start = case.model.split(":")
    path = work / f"{style}-{seed}-{storeys}{'-' + start[0] if start else ''}.ifc"
    if not path.exists():
        make_building(path, seed=int(seed), storeys=int(storeys), style=style, schedule_start=start[0] if start else None)
    return path


def motion(seed: int, tilt_deg: float) -> np.ndarray:
    """A random rigid motion (4, 4) model frame -> scan frame: any heading, a map-like offset."""
    from bimscan.compare.planes import rigid, rotation_about, rotation_z

    rng = np.random.default_rng(1000 + seed)
    rotation = rotation_z(rng.uniform(0, 2 * np.pi))
    if tilt_deg:
        axis = np.array([*rng.normal(size=2), 0.0])
        rotation = rotation @ rotation_about(axis / np.linalg.norm(axis), np.radians(rng.uniform(-tilt_deg, tilt_deg)))
    offset = np.array([rng.uniform(-5e5, 5e5), rng.uniform(4.0e6, 5.5e6), rng.uniform(-50, 500)])
    return rigid(rotation, offset)


def move_foreign(scan: Path, out: Path, matrix: np.ndarray) -> None:
    """The scan moved by ``matrix`` into a LAS as another tool writes it: xyz in 1 mm steps around a map
    offset, station ids in point_source_id, intensity; no bimscan header."""
    import laspy

    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets = np.round(matrix[:3, 3])
    header.scales = np.full(3, 0.001)
    with laspy.open(scan) as reader, laspy.open(out, mode="w", header=header) as writer:
        for points in reader.chunk_iterator(2_000_000):
            xyz = np.stack([points.x, points.y, points.z], axis=1) @ matrix[:3, :3].T + matrix[:3, 3]
            record = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
            record.x, record.y, record.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            record.intensity = points.intensity
            record.point_source_id = points.station
            record.gps_time = points.gps_time
            writer.write_points(record)


def write_control(case: Case, model: Path, out: Path, matrix: np.ndarray) -> None:
    """Six control targets: the model's bounding-box corners (at floor and roof height) and two
    mid-height points, as point pairs scan -> model, each end off by CONTROL_SIGMA_M per axis."""
    from bimscan.pipeline import load_scene

    vertices = load_scene(model).mesh.vertices
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    mid = (lo + hi) / 2
    targets = np.array([[lo[0], lo[1], lo[2]], [hi[0], lo[1], hi[2]], [hi[0], hi[1], lo[2]], [lo[0], hi[1], hi[2]],
                        [mid[0], lo[1], mid[2]], [mid[0], hi[1], mid[2]]])
    rng = np.random.default_rng(2000 + case.seed)
    site = targets + rng.normal(scale=CONTROL_SIGMA_M, size=targets.shape)
    scanned = (targets + rng.normal(scale=CONTROL_SIGMA_M, size=targets.shape)) @ matrix[:3, :3].T + matrix[:3, 3]
    out.write_text("".join(",".join(f"{v:.4f}" for v in (*s, *m)) + "\n" for s, m in zip(scanned, site)))


def truth(case: Case, model: Path, scan: Path, work: Path) -> dict[str, object]:
    """What the scan's own header says (built elements, stations, deviations) and the truth
    visibility of every model element (see the module docs)."""
    from bimscan.compare.distance import BandDistances
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.io import read_cloud_header
    from bimscan.pipeline import build_site, load_scene
    from bimscan.scan.probe import Prober
    from bimscan.site.model import ClutterSettings, SiteModel, StageSettings
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.trajectory import read_trajectory, trajectory_path

    header = read_cloud_header(scan)
    assert header is not None and header.components is not None
    built = set(header.components.global_id.tolist())
    stage_doc = header.metadata["site"]["stage"]  # type: ignore[index]
    clutter_doc = header.metadata["site"]["clutter"]  # type: ignore[index]
    site = SiteModel(stage=StageSettings(name=stage_doc["name"], include=tuple(stage_doc["include"]),
                                         exclude=tuple(stage_doc["exclude"]),
                                         walls_missing_fraction=stage_doc["walls_missing_fraction"],
                                         ceilings_open_fraction=stage_doc["ceilings_open_fraction"],
                                         props_fraction=stage_doc["props_fraction"], at=stage_doc["at"]),
                     clutter=ClutterSettings(density=clutter_doc["density"], kinds=tuple(clutter_doc["kinds"])))
    scene = load_scene(model)
    dressed = build_site(scene, ScanRecipe.resolve(site=site, seed=int(header.metadata["seed"])))  # type: ignore[arg-type]
    if case.handheld:
        walk = read_trajectory(trajectory_path(scan))
        keep = np.minimum(np.unique(np.searchsorted(walk.t, np.arange(walk.t[0], walk.t[-1], 1.0))), len(walk.t) - 1)
        yaw = walk.ypr()[keep, 0]  # radians
        # the lidars' places: the walk's pose and each mount's lever arm (forward, lateral, height)
        origins = np.concatenate([walk.xyz[keep] + np.column_stack([
            np.cos(yaw) * m["forward_m"] - np.sin(yaw) * m["lateral_m"],
            np.sin(yaw) * m["forward_m"] + np.cos(yaw) * m["lateral_m"],
            np.full(len(keep), m["height_m"])]) for m in header.metadata["mobile"]["platform"]["mounts"]])  # type: ignore[index]
        max_range, elevation = TRUTH_RANGE_M, (-90.0, 90.0)
    else:
        origins = np.array([s.position for s in header.stations])
        scanner = header.metadata["scanner"]  # type: ignore[index]
        max_range = float(scanner["max_range_m"])
        elevation = (float(scanner["elevation_min_deg"]), float(scanner["elevation_max_deg"]))
    surfaces = ModelSurfaces(scene.mesh)
    samples = surfaces.samples(samples_per_m2=25.0, min_samples=8, seed=0)
    contact = BandDistances(scene.mesh, band_m=0.15).query(samples.xyz, other_than=samples.component).distance <= 0.01
    prober = Prober(dressed.mesh)
    seen = np.zeros(len(samples), dtype=bool)
    cos_limit = np.cos(np.radians(MAX_INCIDENCE_DEG))
    for origin in origins:
        offset = samples.xyz - origin
        distance = np.linalg.norm(offset, axis=1)
        direction = offset / np.maximum(distance, 1e-9)[:, None]
        up = np.degrees(np.arcsin(np.clip(direction[:, 2], -1, 1)))
        facing = np.abs(np.einsum("ij,ij->i", direction, samples.normal)) >= cos_limit
        test = ~seen & ~contact & facing & (distance > 0.5) & (distance < max_range) & (up >= elevation[0]) \
            & (up <= elevation[1])
        index = np.flatnonzero(test)
        hit, _ = prober.cast(origin, direction[index])
        seen[index[hit >= distance[index] - IN_FRONT_M]] = True
    n = len(scene.components)
    area = np.bincount(samples.component, weights=samples.area_m2, minlength=n)
    visible_m2 = np.bincount(samples.component, weights=samples.area_m2 * seen, minlength=n)
    visible = (visible_m2 >= VISIBLE_M2) & (visible_m2 >= VISIBLE_SHARE * area)
    as_built = header.metadata.get("as_built")
    shifts = {} if not as_built else dict(zip(as_built["components"]["global_id"],  # type: ignore[index]
                                              np.array(as_built["components"]["shift_m"])))  # type: ignore[index]
    centres = {} if not as_built else dict(zip(as_built["components"]["global_id"],  # type: ignore[index]
                                               np.array(as_built["components"]["centre_m"])))  # type: ignore[index]
    return {"built": built, "visible": visible, "shifts": shifts, "centres": centres,
            "noise_m": float(header.metadata["noise"]["range_sigma_m"]) if "noise" in header.metadata else 0.005}  # type: ignore[index]


def score(case: Case, model: Path, progress_dir: Path, found: np.ndarray, true: np.ndarray, scan_lower: np.ndarray,
          scan_upper: np.ndarray, facts: dict[str, object]) -> dict[str, object]:
    from bimscan.compare.planes import apply, rotation_angle_deg
    from bimscan.pipeline import load_scene

    centre = ((scan_lower + scan_upper) / 2)[None]
    result: dict[str, object] = {
        "rotation_deg": rotation_angle_deg(found[:3, :3] @ true[:3, :3].T),
        "centre_cm": float(np.linalg.norm(apply(found, centre) - apply(true, centre))) * 100,
    }
    scene = load_scene(model)
    rows = {row["global_id"]: row for row in _csv(progress_dir / "elements.csv")}
    names = scene.scheme.names
    visible = facts["visible"]
    built = facts["built"]
    per_class = {}
    never_seen_not_built = 0
    for c, gid in enumerate(scene.components.global_id.tolist()):
        row = rows[gid]
        klass = names.get(int(scene.components.label[c]), "")
        status = row["status"]
        if not visible[c]:  # type: ignore[index]
            never_seen_not_built += status == "not built"
            continue
        tally = per_class.setdefault(klass, {"tp": 0, "fp": 0, "fn": 0, "tn": 0, "not_visible": 0, "visible": 0})
        tally["visible"] += 1
        if status == "not visible":
            tally["not_visible"] += 1
            continue
        said = status in ("built", "built out of tolerance")
        real = gid in built  # type: ignore[operator]
        tally[("t" if said == real else "f") + ("p" if said else "n")] += 1
    result["classes"] = per_class
    # a site scanned as its schedule has it on the date: every decided element is on time or not due
    result["schedule"] = {state: sum(row["schedule"] == state for row in rows.values())
                          for state in ("on time", "not due", "behind", "ahead", "unknown")} if case.at else None
    result["never_seen_not_built"] = never_seen_not_built
    errors, errors_given_pose = [], []
    for gid, shift in facts["shifts"].items():  # type: ignore[union-attr]
        row = rows.get(gid)
        if row is None or not row["offset_x_mm"] + row["offset_y_mm"] + row["offset_z_mm"]:
            continue
        offset = np.array([float(row[f"offset_{a}_mm"]) if row[f"offset_{a}_mm"] else np.nan for a in "xyz"]) / 1000
        pinned = np.isfinite(offset)
        if np.abs(shift[pinned]).max(initial=0.0) <= 2 * facts["noise_m"]:  # type: ignore[operator]
            continue
        errors.append(float(np.abs(offset[pinned] - shift[pinned]).max()))
        # the same element as the found pose shows it: its true place moved by the pose's own error there
        centre = np.asarray(facts["centres"][gid])[None]  # type: ignore[index]
        seen_shift = shift + (apply(found @ np.linalg.inv(true), centre + shift) - (centre + shift))[0]
        errors_given_pose.append(float(np.abs(offset[pinned] - seen_shift[pinned]).max()))
    result["deviation_errors_mm"] = [e * 1000 for e in errors]
    result["deviation_errors_given_pose_mm"] = [e * 1000 for e in errors_given_pose]
    return result


def station_errors_cm(scan: Path, progress_dir: Path) -> list[float]:
    """For each tripod station of the scan's header, the distance (cm) to the nearest view origin
    ``progress`` estimated (its points carry station ids only), both in the model's frame: the
    estimate's error and the alignment's together. Empty for a walk."""
    from bimscan.io import read_cloud_header

    header = read_cloud_header(scan)
    views = json.loads((progress_dir / "summary.json").read_text())["views"]
    if header is None or not header.stations or not views:
        return []
    found = np.array([v["origin_m"] for v in views])
    return [float(np.linalg.norm(found - np.asarray(s.position), axis=1).min()) * 100 for s in header.stations]


def _csv(path: Path) -> list[dict[str, str]]:
    import csv

    with path.open(encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    parser.add_argument("--cases", default=None, help="comma-separated case names")
    parser.add_argument("--large", action="store_true", help=f"only {', '.join(c.name for c in LARGE)}")
    parser.add_argument("--rescore", action="store_true",
                        help="with --keep: score the folders a run left there again, without running align and progress")
    parser.add_argument("--reuse-align", action="store_true",
                        help="with --keep: take the alignments a run left there, run progress again")
    parser.add_argument("--keep", type=Path, default=None, help="keep the scans and folders here")
    args = parser.parse_args()
    wanted = set(QUICK) if args.quick else {c.name for c in LARGE} if args.large else set(args.cases.split(",")) \
        if args.cases else {c.name for c in CASES}
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench-progress-"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / "commands.log"
    rows = []
    try:
        for case in CASES + LARGE:
            if case.name not in wanted:
                continue
            model = model_path(case, work)
            scan = work / f"{case.name}.laz"
            if not scan.exists():
                run(BIMSCAN + ["scan", str(model), str(scan), "--seed", str(case.seed), *case.scan_args], log=log)
            true_motion = motion(case.seed, case.tilt_deg)
            moved = work / f"{case.name}-moved.{'laz' if case.handheld else 'las'}"
            if not moved.exists():
                if case.handheld:
                    from bimscan.io import count_points
                    from bimscan.pipeline import write_moved_cloud

                    write_moved_cloud(scan, moved, true_motion, origin=true_motion[:3, 3], total=count_points(scan),
                                      metadata={})
                else:
                    move_foreign(scan, moved, true_motion)
            align_dir, progress_dir = work / f"{case.name}-align", work / f"{case.name}-progress"
            control_dir = work / f"{case.name}-control"
            as_built = "--as-built" in case.scan_args
            times = work / f"{case.name}-seconds.json"
            if args.rescore and (progress_dir / "summary.json").is_file():
                spent = json.loads(times.read_text()) if times.is_file() else {}
                align_s, progress_s = spent.get("align", float("nan")), spent.get("progress", float("nan"))
            else:
                reuse = args.reuse_align and (align_dir / "transform.json").is_file()
                for folder in (progress_dir, control_dir) if reuse else (align_dir, progress_dir, control_dir):
                    shutil.rmtree(folder, ignore_errors=True)
                align_s = json.loads(times.read_text())["align"] if reuse and times.is_file() else \
                    run(BIMSCAN + ["align", str(model), str(moved), str(align_dir)], log=log)
                at = ["--at", case.at] if case.at else []
                progress_s = run(BIMSCAN + ["progress", str(model), str(moved), str(progress_dir), "--transform",
                                            str(align_dir / "transform.json"), *at], log=log)
                if as_built:
                    write_control(case, model, work / f"{case.name}-control.csv", true_motion)
                    run(BIMSCAN + ["progress", str(model), str(moved), str(control_dir), "--transform",
                                   str(work / f"{case.name}-control.csv"), "--points", "none", *at], log=log)
                times.write_text(json.dumps({"align": align_s, "progress": progress_s}))
            found = np.array(json.loads((align_dir / "transform.json").read_text())["matrix"])
            facts = truth(case, model, scan, work)
            from bimscan.compare.planes import apply
            from bimscan.io import iter_cloud_chunks

            lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
            for chunk in iter_cloud_chunks(moved, labels=False):
                lower, upper = np.minimum(lower, chunk.xyz.min(axis=0)), np.maximum(upper, chunk.xyz.max(axis=0))
            summary = json.loads((progress_dir / "summary.json").read_text())
            measured = score(case, model, progress_dir, found, np.linalg.inv(true_motion), lower, upper, facts)
            measured["deviation_errors_control_mm"] = [] if not (control_dir / "summary.json").is_file() else \
                score(case, model, control_dir, np.array(json.loads((control_dir / "transform.json").read_text())[
                    "matrix"]), np.linalg.inv(true_motion), lower, upper, facts)["deviation_errors_mm"]
            measured |= {"case": case.name, "points": summary["points"], "align_s": align_s,
                         "progress_s": progress_s,
                         "station_cm": [] if case.handheld else station_errors_cm(scan, progress_dir)}
            rows.append(measured)
            print(f"{case.name}: rotation {measured['rotation_deg']:.3f} deg, centre {measured['centre_cm']:.2f} cm, "
                  f"align {align_s:.0f} s, progress {progress_s:.0f} s", flush=True)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    report(rows)


def _share(numerator: int, denominator: int) -> str:
    return "-" if denominator == 0 else f"{numerator / denominator:.3f}"


def report(rows: list[dict[str, object]]) -> None:
    print("\n| case | points | rotation error (deg) | centre error (cm) | within 2 cm and 0.1 deg | stations estimated: "
          "median / largest error (cm), within 5 cm | align (s) | progress (s) |\n|---|---|---|---|---|---|---|---|")
    good = 0
    for row in rows:
        ok = row["rotation_deg"] <= 0.1 and row["centre_cm"] <= 2.0  # type: ignore[operator]
        good += ok
        station = np.array(row["station_cm"])  # type: ignore[arg-type]
        stations = "-" if not len(station) else \
            f"{np.median(station):.1f} / {station.max():.1f}, {(station <= 5).sum()} of {len(station)}"
        print(f"| {row['case']} | {row['points']:,} | {row['rotation_deg']:.3f} | {row['centre_cm']:.2f} | "
              f"{'yes' if ok else 'NO'} | {stations} | "
              f"{row['align_s']:.0f} | {row['progress_s']:.0f} |")
    print(f"\naligned within 2 cm and 0.1 deg: {good} of {len(rows)}\n")
    print("| case | class | visible | not visible | precision | recall | TP | FP | FN | TN |\n|---|---|---|---|---|---|---|---|---|---|")
    totals: dict[str, dict[str, int]] = {}
    for row in rows:
        for klass in CLASSES:
            t = row["classes"].get(klass)  # type: ignore[union-attr]
            if not t:
                continue
            total = totals.setdefault(klass, {k: 0 for k in t})
            for key, value in t.items():
                total[key] += value
            print(f"| {row['case']} | {klass} | {t['visible']} | {t['not_visible']} | "
                  f"{_share(t['tp'], t['tp'] + t['fp'])} | {_share(t['tp'], t['tp'] + t['fn'])} | {t['tp']} | "
                  f"{t['fp']} | {t['fn']} | {t['tn']} |")
    for klass, t in totals.items():
        print(f"| **all** | {klass} | {t['visible']} | {t['not_visible']} ({_share(t['not_visible'], t['visible'])}) | "
              f"{_share(t['tp'], t['tp'] + t['fp'])} | {_share(t['tp'], t['tp'] + t['fn'])} | {t['tp']} | {t['fp']} | "
              f"{t['fn']} | {t['tn']} |")
    scheduled = [row for row in rows if row["schedule"]]
    if scheduled:
        print("\n| case (scanned on the date it is judged at) | on time | not due | behind | ahead | unknown |\n"
              "|---|---|---|---|---|---|")
        for row in scheduled:
            t = row["schedule"]  # type: ignore[index]
            print(f"| {row['case']} | {t['on time']} | {t['not due']} | {t['behind']} | {t['ahead']} | {t['unknown']} |")
    never = sum(int(row["never_seen_not_built"]) for row in rows)  # type: ignore[arg-type]
    print(f"\nelements no station could see called 'not built': {never}")
    for key, what in (("deviation_errors_mm", "against the true offsets"),
                      ("deviation_errors_given_pose_mm", "against the true offsets as the found pose shows them"),
                      ("deviation_errors_control_mm", "against the true offsets, the scan placed by six control "
                                                      "targets")):
        errors = [e for row in rows for e in row[key]]  # type: ignore[union-attr]
        if errors:
            errors_array = np.array(errors)
            print(f"deviation of elements displaced by more than twice the range noise, {what}: {len(errors)} "
                  f"elements, {(errors_array <= 5).mean():.1%} within 5 mm (median error {np.median(errors_array):.1f} "
                  f"mm, 90 % under {np.percentile(errors_array, 90):.1f} mm)")


if __name__ == "__main__":
    main()

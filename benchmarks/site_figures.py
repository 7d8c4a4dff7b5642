"""Class shares of a generated office dressed with clutter next to the real S3DIS rooms, and the
pictures of that office at each construction stage (README figures).

Run: python benchmarks/site_figures.py [--densities 0 0.1 0.2 0.3 0.4] [--pictures docs]

1. The real rooms: every room under ``../shared/data/real/s3dis_area6`` (S3DIS layout), its
   points counted per annotation file and mapped to the five spc5 classes with
   ``learn/mappings/s3dis_to_spc5.toml``; shares per room.
2. The synthetic office: ``make_building(seed=1, storeys=1)`` scanned (exp3 at 60 deg/s, stations
   planned on the dressed scene) at each clutter density (stage finished, office furniture and
   people); its points are split into the rooms (each IfcSpace's box grown by 5 cm, so the room's
   walls, floor and ceiling belong to it) and counted per class.
3. A Markdown table: per class, the mean share over rooms and its range, real and synthetic; the
   density whose mean Others share is nearest the real one.
4. With ``--pictures DIR``: the office at the stages structure, enclosed and finished, each with
   clutter at that density (kinds by stage), scanned and drawn with ``bimscan render`` into
   ``DIR/site_<stage>.png``.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real" / "s3dis_area6"
CLASSES = ("Wall&Column", "Beam", "Covering", "Slab", "Others")


def real_shares(root: Path) -> dict[str, np.ndarray]:
    """Room name -> (5,) class shares of an S3DIS room (points counted per annotation file)."""
    from bimscan.io.s3dis import class_of_annotation, list_s3dis_rooms

    mapping = tomllib.loads((REPO / "src/bimscan/learn/mappings/s3dis_to_spc5.toml").read_text())
    out = {}
    for room in list_s3dis_rooms(root):
        counts = np.zeros(len(CLASSES))
        for file in sorted((room / "Annotations").glob("*.txt")):
            target = mapping["classes"].get(class_of_annotation(file), mapping["default"])
            with file.open("rb") as handle:
                lines = sum(chunk.count(b"\n") for chunk in iter(lambda: handle.read(1 << 20), b""))
            counts[CLASSES.index(target)] += lines
        out[room.name] = counts / counts.sum()
    return out


def synthetic_shares(scene, cloud_path: Path) -> dict[str, np.ndarray]:
    """Room name -> (5,) class shares of the points inside each IfcSpace's box grown by 5 cm."""
    from bimscan.io import read_cloud

    cloud = read_cloud(cloud_path)
    out = {}
    for space in scene.spaces:
        lo, hi = space.vertices.min(axis=0) - 0.05, space.vertices.max(axis=0) + 0.05
        inside = ((cloud.xyz >= lo) & (cloud.xyz <= hi)).all(axis=1)
        counts = np.bincount(cloud.label[inside], minlength=len(CLASSES))[:len(CLASSES)].astype(float)
        if counts.sum():
            out[space.name] = counts / counts.sum()
    return out


def scan(ifc: Path, out: Path, site, *, seed: int = 0) -> tuple[object, float, float]:
    """Scan the model dressed as ``site``; returns the dressed scene, dressing and scanning seconds."""
    from bimscan.pipeline import build_site, load_scene, scan_survey
    from bimscan.survey.recipe import ScanRecipe
    from bimscan.survey.survey import prepare_survey

    recipe = ScanRecipe.resolve(preset="exp3", head_deg_per_s=60.0, seed=seed, site=site)
    start = time.perf_counter()
    scene = build_site(load_scene(ifc), recipe)
    dressed = time.perf_counter() - start
    survey = prepare_survey(scene, recipe)
    start = time.perf_counter()
    scan_survey(survey, out, overwrite=True, progress=False)
    return scene, dressed, time.perf_counter() - start


def summary(shares: dict[str, np.ndarray]) -> list[str]:
    values = np.array(list(shares.values())) * 100
    return [f"{m:.1f} ({lo:.0f}-{hi:.0f})" for m, lo, hi in zip(values.mean(0), values.min(0), values.max(0))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--densities", type=float, nargs="+", default=[0.0, 0.1, 0.2, 0.3, 0.4])
    parser.add_argument("--pictures", type=Path, default=None, help="folder for site_<stage>.png")
    parser.add_argument("--picture-density", type=float, default=None, help="default: the best-matching density")
    args = parser.parse_args()
    os.environ.setdefault("BIMSCAN_PROGRESS", "0")
    from bimscan.ifc.generate import make_building
    from bimscan.site import ClutterSettings, SiteModel, StageSettings

    folder = Path(tempfile.mkdtemp(prefix="bimscan-site-figures-"))
    os.environ.setdefault("BIMSCAN_CACHE_DIR", str(folder / "cache"))
    ifc = make_building(folder / "office.ifc", seed=1, storeys=1).path
    columns = {}
    if REAL.is_dir():
        real = real_shares(REAL)
        columns[f"S3DIS Area 6 ({len(real)} rooms)"] = real
    else:
        print(f"(no real rooms at {REAL}: the real column is left out)")
    for density in args.densities:
        site = SiteModel(clutter=ClutterSettings(density=density))
        scene, dress_s, scan_s = scan(ifc, folder / f"d{density}.laz", site)
        placed = 0 if scene.site is None else sum(scene.site.placed.values())
        print(f"density {density:g}: {placed} objects placed in {dress_s:.2f} s, scanned in {scan_s:.1f} s")
        columns[f"office, clutter {density:g}/m2"] = synthetic_shares(scene, folder / f"d{density}.laz")
    names = list(columns)
    print("\nclass share of a room's points, % : mean over rooms (min-max)\n")
    print("| class | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    table = {name: summary(shares) for name, shares in columns.items()}
    for k, cls in enumerate(CLASSES):
        print(f"| {cls} | " + " | ".join(table[name][k] for name in names) + " |")
    best = args.picture_density
    if REAL.is_dir() and best is None:
        target = np.mean([s[4] for s in columns[names[0]].values()])
        synthetic = {d: np.mean([s[4] for s in columns[n].values()]) for d, n in zip(args.densities, names[1:])}
        best = min(synthetic, key=lambda d: abs(synthetic[d] - target))
        print(f"\nreal mean Others {100 * target:.1f} %; nearest: clutter {best:g}/m2 ({100 * synthetic[best]:.1f} %)")
    if args.pictures is not None:
        from bimscan.render.cloud import render_cloud

        args.pictures.mkdir(parents=True, exist_ok=True)
        for stage in ("structure", "enclosed", "finished"):
            site = SiteModel(stage=StageSettings(name=stage, props_fraction=0.5 if stage == "structure" else 0.0),
                             clutter=ClutterSettings(density=best or 0.2))
            scene, _, _ = scan(ifc, folder / f"{stage}.laz", site)
            out = args.pictures / f"site_{stage}.png"
            render_cloud(folder / f"{stage}.laz", out, width=1200, height=560)
            print(f"{out}: {stage}, {sum(scene.site.placed.values())} objects, {out.stat().st_size / 1024:.0f} KiB")


if __name__ == "__main__":
    main()

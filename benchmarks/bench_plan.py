"""Survey plans on real and generated IFC models, checked on their scans and against the per-room plan.

Run: python benchmarks/bench_plan.py [--no-scan] [MODEL.ifc ...]
     (default: ../shared/data/ifc/*.ifc and the three generated styles, seed 0, two storeys)

Every model is planned as ``bimscan plan MODEL OUT --stage-exclude IfcDoor`` plans it (the
defaults: exp3 on the VZ-400, 95 % of Wall&Column, Beam, Covering and Slab at 1,000 points/m2
within 70 degrees; doors open, as a surveyor leaves them: closed doors seal rooms from each other).
For each model it prints:

- the plan: stations (greedy, after local search, the MILP where it ran), seconds (load and plan,
  this process, on this machine), each class's coverage as the plan estimates it;
- the scan: the plan's stations scanned as ``bimscan scan --stations OUT/stations.csv`` scans them
  (the same pipeline, its checked chunks counted instead of written), each class's coverage
  measured on the scan's labelled points, the largest gap between estimate and scan, and the
  median of the scan's density over the estimate on the surface patches;
- the per-room plan of ``--stations auto``: its stations (and with spots added along shortest
  paths until its registration graph is as connected as the spots allow), the coverage it reaches, and the
  planner's station count when asked for that same coverage, class by class: with its registration
  graph connected (as far as the spots allow), and with registration left out as the per-room plan
  leaves it (any two stations count as linked: registration by targets);
- the registration graph: parts of the plan's graph, the fewest the candidate spots allow, parts of
  the per-room plan's graph.

Prints two Markdown tables; timings are this machine's, measured while it runs.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data" / "ifc"
STYLES = ("office", "residential", "site")


def generated_models(folder: Path) -> list[Path]:
    from bimscan.ifc.generate import make_building

    paths = []
    for style in STYLES:
        path = folder / f"generated-{style}.ifc"
        make_building(path, seed=0, storeys=2, style=style)
        paths.append(path)
    return paths


def scan_density(model: Path, recipe, stations_file: Path, plan) -> np.ndarray:
    """(S,) points per square metre on every sample's patch, from the scan of the plan's station file."""
    from bimscan.pipeline import load_scene, site_and_stations, stream_checked
    from bimscan.process.summary import CloudSummary
    from bimscan.survey.planning.measure import patch_density, points_per_sample
    from bimscan.survey.survey import prepare_survey

    scan_recipe = recipe.with_fields(stations_from=str(stations_file))
    chosen = site_and_stations(load_scene(model), scan_recipe)
    survey = prepare_survey(chosen.scene, scan_recipe, stations=chosen.stations)
    columns = {s.id: int(plan.chosen[s.id]) for s in survey.stations}  # the file lists the plan's stations in order
    space = plan.space
    counts = points_per_sample(stream_checked(survey, summary=CloudSummary()), space.samples, space.visibility, columns,
                               counted=space.klass >= 0)
    return patch_density(counts, space.samples, per_area=True)


def unlinked_count(plan) -> int:
    """Stations the planner needs on the same space when registration is left out (every pair linked)."""
    import dataclasses

    from bimscan.survey.planning.select import greedy_cover, improve_cover, iterated_greedy, prune_cover

    problem = plan.space.problem
    linked = np.ones_like(problem.edges)
    np.fill_diagonal(linked, False)
    free = dataclasses.replace(problem, edges=linked)
    chosen = improve_cover(free, prune_cover(free, greedy_cover(free)))
    return len(iterated_greedy(free, chosen, rounds=plan.space.config.search_rounds, seed=plan.space.config.seed))


def joined_count(run) -> int:
    """The per-room plan's stations with the candidate spots added along shortest graph paths
    until its registration graph is as connected as the spots allow."""
    from bimscan.survey.planning.select import join_parts

    return len(join_parts(run.plan.space.problem, [int(c) for c in run.plan.chosen]))


def fractions(evaluation) -> dict[str, float]:
    return {name: c["covered_fraction"] for name, c in evaluation.classes.items() if c["visible_m2"] > 0}


def main() -> None:
    from bimscan.errors import BimscanError
    from bimscan.pipeline import plan_model
    from bimscan.site.model import SiteModel, StageSettings
    from bimscan.survey.planning.config import PlanConfig
    from bimscan.survey.planning.measure import patch_density
    from bimscan.survey.planning.plan import evaluate
    from bimscan.survey.recipe import ScanRecipe

    parser = argparse.ArgumentParser()
    parser.add_argument("--no-scan", action="store_true", help="skip the scans (plans and per-room plans only)")
    parser.add_argument("models", nargs="*", type=Path)
    args = parser.parse_args()
    recipe = ScanRecipe(site=SiteModel(stage=StageSettings(exclude=("IfcDoor",))))
    config = PlanConfig()
    summary_rows, class_rows = [], []
    with tempfile.TemporaryDirectory(prefix="bench-plan-") as scratch:
        scratch_dir = Path(scratch)
        models = args.models or [*sorted(SHARED.glob("*.ifc")), *generated_models(scratch_dir)]
        for model in models:
            name = model.stem
            try:
                start = time.perf_counter()
                run = plan_model(model, scratch_dir / f"{name}-plan", recipe, config, progress=False)
                plan_seconds = time.perf_counter() - start
                auto = plan_model(model, scratch_dir / f"{name}-auto", recipe, config, check="auto", progress=False)
                auto_fraction = fractions(auto.evaluation)
                matched = PlanConfig(coverage=tuple(math.floor(1000 * auto_fraction.get(c, 0.95)) / 1000 or 0.001
                                                    for c in config.classes))
                at_auto = plan_model(model, scratch_dir / f"{name}-at-auto", recipe, matched, progress=False)
            except BimscanError as exc:
                summary_rows.append(f"| {name} | error: {exc} |")
                print(summary_rows[-1], flush=True)
                continue
            estimate = fractions(run.evaluation)
            on_scan, gap, ratio = {}, math.nan, math.nan
            if not args.no_scan:
                measured = scan_density(model, recipe, scratch_dir / f"{name}-plan" / "stations.csv", run.plan)
                on_scan = fractions(evaluate(run.plan, density=measured))
                gap = max(abs(on_scan[c] - estimate[c]) for c in estimate)
                space = run.plan.space
                predicted = patch_density(run.evaluation.density, space.samples, per_area=False)
                useful = space.visibility.reachable & (space.klass >= 0) & (predicted >= 0.1 * config.density_pts_m2)
                ratio = float(np.median(measured[useful] / predicted[useful]))
            solver = run.plan.solver
            milp = f"{solver.milp_status}" + (f" {solver.milp}" if solver.milp is not None else "")
            met = "yes" if on_scan and all(v >= config.coverage_of(c) for c, v in on_scan.items()) else (
                "-" if not on_scan else "no")
            graph = f"{run.evaluation.parts} / {run.evaluation.spot_parts} / {auto.evaluation.parts}"
            per_room = f"{len(auto.plan.stations)} / {joined_count(auto)}"
            at_per_room = f"{len(at_auto.plan.stations)} / {unlinked_count(at_auto.plan)}"
            summary_rows.append(
                f"| {name} | {run.plan.space.n_spots} | {len(run.plan.stations)} | "
                f"{solver.greedy} / {solver.improved} / "
                f"{milp} | {plan_seconds:.0f} | {met} | {100 * gap:.1f} | {ratio:.2f} | {per_room} | {at_per_room} | "
                f"{graph} |")
            print(summary_rows[-1], flush=True)
            for c in estimate:
                scanned = f"{100 * on_scan[c]:.1f}" if on_scan else "-"
                class_rows.append(f"| {name} | {c} | {100 * estimate[c]:.1f} | {scanned} | "
                                  f"{100 * auto_fraction.get(c, math.nan):.1f} |")
    print()
    print("| model | spots | stations | greedy / after search / MILP | plan s | scan meets 95 % | max gap (points) | "
          "scan/estimate density | per-room stations: as planned / joined | planner at per-room coverage: linked / "
          "registration left out | "
          "graph parts: plan / spots allow / per-room |")
    print("|---|---:|---:|---|---:|---|---:|---:|---:|---:|---|")
    print("\n".join(summary_rows))
    print()
    print("| model | class | plan estimate % | on the scan % | per-room plan % |")
    print("|---|---|---:|---:|---:|")
    print("\n".join(class_rows))


if __name__ == "__main__":
    sys.exit(main())

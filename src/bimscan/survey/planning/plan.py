"""Planning a survey, and checking one: candidates, visibility, the cover, the evaluation.

``prepare_space`` builds what both need: the candidate spots (``survey.stations.station_spots``:
the tripod spot rules ``--stations auto`` uses, on a ``grid_m`` grid), samples over the surfaces
of the chosen classes, every candidate's visibility of them with the scanner's own angular grid
(``visibility``), the registration graph (``graph``) and the cover problem (``select``).
``plan_survey`` chooses the stations; ``check_survey`` evaluates given ones on the same space (a
plan's candidates are the denominator of coverage either way: what some tripod spot sees).
``evaluate`` gives per-element and per-class coverage and the chosen stations' graph.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from bimscan.errors import ConfigError, StationError
from bimscan.progress import step_line
from bimscan.scan.device import ScannerModel, ScanSettings
from bimscan.scan.probe import Prober
from bimscan.survey.planning.config import PlanConfig
from bimscan.survey.planning.graph import Overlaps, compute_overlaps, graph_parts, scan_order
from bimscan.survey.planning.select import (
    CoverProblem, greedy_cover, improve_cover, iterated_greedy, milp_cover, prune_cover, repair_cover,
)
from bimscan.survey.planning.surface import SurfaceSamples, sample_surfaces, triangle_areas
from bimscan.survey.planning.visibility import BeamGrid, Visibility, compute_visibility, facing_stations
from bimscan.survey.stations import station_on_floor, station_problem, station_spots, storey_at
from bimscan.types import BimScene, Station


@dataclass(frozen=True)
class PlanningSpace:
    """Everything a plan is chosen from and judged on.

    scene, scanner, settings, config: the inputs. grid: the scanner's angular grid. samples: the
    surface samples, on every element (registration aligns on whatever both stations see); klass
    (S,) int64: their class index in ``config.classes`` (-1: not a class to cover). heads (K, 3): beam
    origins of the candidates (the spots first, then any stations given to check); floors (K, 3):
    the floor points under them; headings_deg (K,); n_spots: how many of the K are grid spots.
    visibility, overlaps, edges (K, K) bool: the registration graph; problem: the cover problem.
    """

    scene: BimScene
    scanner: ScannerModel
    settings: ScanSettings
    config: PlanConfig
    grid: BeamGrid
    samples: SurfaceSamples
    klass: np.ndarray
    heads: np.ndarray
    floors: np.ndarray
    headings_deg: np.ndarray
    n_spots: int
    visibility: Visibility
    overlaps: Overlaps
    edges: np.ndarray
    problem: CoverProblem
    seconds: dict[str, float] = field(default_factory=dict)

    def class_areas(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N,) areas of each class's surface, square metres: all of it, what some candidate sees
        within the incidence limit (``reachable``: the denominator of coverage), and what some
        candidate sees only more edge-on than that."""
        n = len(self.config.classes)
        area = self.samples.area_m2
        counted = self.klass >= 0
        reachable, seen = self.visibility.reachable & counted, self.visibility.seen & counted
        edge_on = seen & ~reachable
        return (np.bincount(self.klass[counted], weights=area[counted], minlength=n),
                np.bincount(self.klass[reachable], weights=area[reachable], minlength=n),
                np.bincount(self.klass[edge_on], weights=area[edge_on], minlength=n))


def class_indices(scene: BimScene, classes: tuple[str, ...]) -> np.ndarray:
    """(C,) int64: each component's index in ``classes`` (-1: not one of them). ConfigError naming
    the scheme's classes for a class it does not have."""
    names = scene.scheme.names
    by_name = {name: label for label, name in names.items()}
    unknown = [c for c in classes if c not in by_name]
    if unknown:
        raise ConfigError(f"unknown class {unknown[0]!r} in --classes; the {scene.scheme.name} scheme has "
                          f"{', '.join(names.values())}")
    lookup = np.full(256, -1, dtype=np.int64)
    for index, name in enumerate(classes):
        lookup[by_name[name]] = index
    return lookup[scene.components.label]


def prepare_space(scene: BimScene, scanner: ScannerModel, settings: ScanSettings, config: PlanConfig, *,
                  given: tuple[Station, ...] = (), threads: int = 0, progress: bool = False) -> PlanningSpace:
    """The planning space of a scene (see the module docs); ``given`` stations join the candidates
    (after the spots) so that a plan can be checked. Raises StationError when no tripod can stand
    anywhere and no station is given, ConfigError for a class the scheme lacks."""
    seconds: dict[str, float] = {}
    start = time.perf_counter()
    component_class = class_indices(scene, config.classes)
    prober = Prober(scene.mesh, threads=threads)
    instrument = scanner.instrument_height_m
    with step_line("finding candidate spots", enabled=progress):
        try:
            spots = station_spots(scene, prober, scanner, grid_m=config.grid_m, clearance_m=config.clearance_m,
                                  max_columns=config.max_candidates)
            floors = spots.floor[_accepted(spots.floor, scene, prober, instrument)]
        except StationError:
            if not given:
                raise
            floors = np.zeros((0, 3))
    n_spots = len(floors)
    heads = floors + [0.0, 0.0, instrument]
    headings = np.zeros(n_spots)
    if given:
        given_heads = np.array([s.position for s in given], dtype=np.float64)
        given_floors = np.array([(s.position[0], s.position[1], s.floor_z if s.floor_z is not None
                                  else s.position[2] - instrument) for s in given])
        heads = np.concatenate([heads, given_heads])
        floors = np.concatenate([floors, given_floors])
        headings = np.concatenate([headings, [s.heading_deg for s in given]])
    seconds["candidates"] = time.perf_counter() - start
    start = time.perf_counter()
    samples = sample_surfaces(scene.mesh, np.ones(len(component_class), dtype=bool), seed=config.seed,
                              samples_per_m2=config.samples_per_m2, min_samples=config.min_samples)
    klass = component_class[samples.component]
    grid = BeamGrid.of(settings, scanner)
    visibility = compute_visibility(prober, samples, heads, grid, max_incidence_deg=config.max_incidence_deg,
                                    headings_deg=headings, progress=progress)
    samples = facing_stations(samples, visibility, heads)
    seconds["visibility"] = time.perf_counter() - start
    start = time.perf_counter()
    with step_line("registration graph", enabled=progress):
        overlaps = compute_overlaps(visibility, samples, density_pts_m2=config.overlap_density_pts_m2,
                                    seed=config.seed)
        edges = overlaps.edges(overlap=config.overlap, min_direction_share=config.min_direction_share)
    seconds["graph"] = time.perf_counter() - start
    reachable = visibility.reachable & (klass >= 0)
    n = len(config.classes)
    visible = np.bincount(klass[reachable], weights=samples.area_m2[reachable], minlength=n)
    need = np.array([config.coverage_of(c) for c in config.classes]) * visible
    problem = CoverProblem.of(visibility.matrix, samples.area_m2, np.where(reachable, klass, -1), need,
                              config.density_pts_m2, edges)
    return PlanningSpace(scene=scene, scanner=scanner, settings=settings, config=config, grid=grid, samples=samples,
                         klass=klass, heads=heads, floors=floors, headings_deg=headings, n_spots=n_spots,
                         visibility=visibility, overlaps=overlaps, edges=edges, problem=problem, seconds=seconds)


def _accepted(floors: np.ndarray, scene: BimScene, prober: Prober, instrument: float) -> np.ndarray:
    """(M,) bool: the spots (M, 3) where the station check of ``bimscan scan --stations`` accepts a
    station (``survey.stations.station_problem``, on this scene: the site as it will be scanned)."""
    stations = (Station(id=0, position=(float(x), float(y), float(z) + instrument), floor_z=float(z))
                for x, y, z in floors)
    return np.array([station_problem(s, scene, prober) is None for s in stations], dtype=bool).reshape(len(floors))


@dataclass(frozen=True)
class SolverReport:
    """How the stations were chosen: the greedy count, after the search (local and iterated
    greedy), the MILP's (None when
    not run or without an answer), its status ("not run", "too large", "optimal", "time limit",
    "infeasible"), the lower bound it proved on the station count, its surface groups, cut
    rounds and seconds, and which answer was taken."""

    greedy: int
    improved: int
    milp: int | None = None
    milp_status: str = "not run"
    milp_bound: float | None = None
    milp_groups: int = 0
    milp_rounds: int = 0
    milp_seconds: float = 0.0
    chosen_by: str = "greedy"

    def to_json(self) -> dict[str, object]:
        """The facts that do not depend on the machine's speed (a MILP stopped by its time limit
        found what it found in that time: its count and bound are left out)."""
        stopped = self.milp_status == "time limit"
        return {"greedy": self.greedy, "improved": self.improved, "milp_status": self.milp_status,
                "milp": None if stopped else self.milp, "milp_bound": None if stopped else self.milp_bound,
                "milp_groups": self.milp_groups, "chosen_by": self.chosen_by}


@dataclass(frozen=True)
class LadderRung:
    """What one coverage costs: ``stations`` (None: no choice of the candidate spots reaches it)
    chosen as the plan's are, every class asked ``coverage`` of its visible surface."""

    coverage: float
    stations: int | None


@dataclass(frozen=True)
class SurveyPlan:
    """Stations (in scan order, ids 0..n-1) on a planning space: ``chosen`` their candidate indices;
    ``solver``: how they were chosen (None for a checked plan); ``ladder``: the stations each of
    ``PlanConfig.coverage_ladder``'s coverages needs (empty for a checked plan)."""

    space: PlanningSpace
    chosen: np.ndarray
    stations: tuple[Station, ...]
    solver: SolverReport | None = None
    ladder: tuple[LadderRung, ...] = ()


def impossible_line(space: PlanningSpace) -> str | None:
    """The one-line reason no choice reaches the asked coverage (None when every candidate spot
    together does): the best coverage each short class reaches, and what holds the rest back."""
    config, problem = space.config, space.problem
    everything = space.visibility.density_of(np.arange(space.n_spots))
    covered = problem.covered_m2(problem.summed(np.arange(space.n_spots)))
    _, visible, _ = space.class_areas()
    short = [k for k in range(len(config.classes)) if covered[k] < problem.need_m2[k] * (1 - 1e-9)]
    if not short:
        return None
    reachable = space.visibility.reachable
    parts = []
    for k in short:
        sparse_area = space.samples.area_m2[(space.klass == k) & reachable & (everything < config.density_pts_m2)].sum()
        asked = 100 * config.coverage_of(config.classes[k])
        parts.append(f"{config.classes[k]} {100 * covered[k] / visible[k]:.1f} % of the {asked:g} % asked "
                     f"({sparse_area:.1f} m2 of its visible surface stay under it)")
    return (f"{space.scene.source}: no plan reaches the coverage asked at {config.density_pts_m2:g} points/m2: all "
            f"{space.n_spots} candidate spots together reach " + ", ".join(parts) +
            "; lower --coverage or --density, or scan denser (--preset, --head-speed)")


def plan_survey(space: PlanningSpace, *, progress: bool = False) -> SurveyPlan:
    """The fewest stations covering the asked classes (see ``select``), in scan order, with the
    coverage ladder (``coverage_ladder``). Raises StationError (one line) when no choice of the
    candidate spots reaches the coverage. Every candidate spot passed the station check already
    (``prepare_space``): the stations scan as they are."""
    if space.n_spots == 0:
        raise StationError(f"{space.scene.source}: no candidate spot for a tripod; give stations in a file")
    reason = impossible_line(space)
    if reason is not None:
        raise StationError(reason)
    allowed = np.zeros(space.problem.n_candidates, dtype=bool)
    allowed[:space.n_spots] = True
    chosen, report = _choose(space, space.problem, allowed, progress=progress)
    ladder = coverage_ladder(space, allowed, len(chosen), progress=progress)
    scene, instrument = space.scene, space.scanner.instrument_height_m
    order = scan_order(np.array(chosen), space.heads, space.edges)
    stations = tuple(station_on_floor(i, space.floors[j], scene, instrument) for i, j in enumerate(order))
    return SurveyPlan(space=space, chosen=order, stations=stations, solver=report, ladder=ladder)


def coverage_ladder(space: PlanningSpace, allowed: np.ndarray, planned: int, *,
                    progress: bool = False) -> tuple[LadderRung, ...]:
    """The stations each coverage of ``config.coverage_ladder`` (and the asked one, when it is one
    share for every class) needs, every class asked that share of its visible surface, chosen
    among the ``allowed`` candidates as the plan's stations are;
    ``planned``: the plan's own count. A cover of a higher coverage covers a lower one too, so a
    rung never shows more stations than a higher rung (or the plan, at or under every class's
    asked coverage) needs."""
    config, problem = space.config, space.problem
    if not config.coverage_ladder:
        return ()
    # the asked coverage is a rung too, when one share is asked of every class
    rungs = sorted(set(config.coverage_ladder) | (set(config.coverage) if len(config.coverage) == 1 else set()))
    _, visible, _ = space.class_areas()
    everything = problem.covered_m2(problem.summed(np.flatnonzero(allowed)))
    asked = np.array([config.coverage_of(c) for c in config.classes])
    counts: dict[float, int | None] = {}
    for coverage in rungs:
        if np.all(asked == coverage):
            counts[coverage] = planned
            continue
        need = coverage * visible
        if np.any(everything < need * (1 - 1e-9)):
            counts[coverage] = None
            continue
        rung = dataclasses.replace(problem, need_m2=need)
        with step_line(f"stations for {100 * coverage:g} % coverage", enabled=progress):
            counts[coverage] = len(_choose(space, rung, allowed, progress=False)[0])
    best: int | None = None
    for coverage in reversed(rungs):  # the fewest found at this coverage or any higher one
        count = counts[coverage]
        if coverage <= asked.min():
            count = planned if count is None else min(count, planned)
        if count is not None and best is not None:
            count = min(count, best)
        best = count if count is not None else best
        counts[coverage] = count
    return tuple(LadderRung(coverage=c, stations=counts[c]) for c in rungs)


def _choose(space: PlanningSpace, problem: CoverProblem, allowed: np.ndarray, *,
            progress: bool) -> tuple[list[int], SolverReport]:
    """The cover of ``problem`` (the space's, or a rung of its ladder) among the allowed
    candidates: greedy, pruned, improved; then the MILP (see ``PlanConfig.solver``), its answer
    repaired on the whole surface and taken when it is smaller."""
    config = space.config
    with step_line("greedy cover and search", enabled=progress):
        greedy = prune_cover(problem, greedy_cover(problem, allowed=allowed))
        if not problem.covers(greedy):
            raise StationError(impossible_line(space) or
                               f"{space.scene.source}: no plan found; give stations in a file")
        improved = improve_cover(problem, greedy, allowed=allowed)
        improved = iterated_greedy(problem, improved, allowed=allowed, rounds=config.search_rounds,
                                   seed=config.seed)
    report = SolverReport(greedy=len(greedy), improved=len(improved),
                          chosen_by="greedy" if len(improved) == len(greedy) else "search")
    if config.solver == "greedy" or len(improved) <= 1:
        return improved, report
    index = np.flatnonzero(allowed)
    restricted = CoverProblem.of(problem.density[:, index], problem.area_m2, problem.klass, problem.need_m2,
                                 problem.threshold_pts_m2, problem.edges[np.ix_(index, index)])
    max_groups = config.milp_max_groups if config.solver == "auto" else len(problem.klass)
    with step_line("exact cover (HiGHS)", enabled=progress):
        result = milp_cover(restricted, at_most=len(improved) - 1, max_groups=max_groups,
                            time_limit_s=config.milp_time_limit_s)
    milp = None
    if result.chosen is not None and (config.solver == "milp" or result.status == "optimal"):
        milp = repair_cover(problem, [int(index[j]) for j in result.chosen], allowed=allowed)
        if not (problem.covers(milp) and problem.parts(milp) <= problem.parts(improved)):
            milp = None
    better = milp is not None and len(milp) < len(improved)
    report = dataclasses.replace(report, milp=None if milp is None else len(milp), milp_status=result.status,
                                 milp_bound=result.bound, milp_groups=result.groups, milp_rounds=result.rounds,
                                 milp_seconds=result.seconds, chosen_by="milp" if better else report.chosen_by)
    return (milp if better else improved), report


def check_survey(space: PlanningSpace, stations: tuple[Station, ...]) -> SurveyPlan:
    """The given stations (the candidates after the spots, as ``prepare_space`` put them) as a plan."""
    if len(space.heads) - space.n_spots != len(stations):
        raise ValueError(f"the planning space holds {len(space.heads) - space.n_spots} given stations, not "
                         f"{len(stations)}: prepare it with given=stations")
    chosen = np.arange(space.n_spots, space.n_spots + len(stations))
    return SurveyPlan(space=space, chosen=chosen, stations=tuple(stations))


@dataclass(frozen=True)
class ElementCoverage:
    """One element's coverage: area_m2 of its surface; visible_m2 of it seen from some candidate
    spot within the incidence limit (the denominator); edge_on_m2 seen only more edge-on;
    covered_m2 of the visible at the asked density; median_density_pts_m2 over the visible
    surface (the plan's stations summed; NaN when nothing is visible)."""

    component: int
    global_id: str
    ifc_class: str
    klass: str
    storey: str
    name: str
    asked: float
    area_m2: float
    visible_m2: float
    edge_on_m2: float
    covered_m2: float
    median_density_pts_m2: float

    @property
    def covered_fraction(self) -> float:
        return self.covered_m2 / self.visible_m2 if self.visible_m2 > 0 else math.nan

    @property
    def status(self) -> str:
        """"covered" (at the asked fraction), "short", "seen only edge-on" or "never seen"."""
        if self.visible_m2 <= 0:
            return "seen only edge-on" if self.edge_on_m2 > 0 else "never seen"
        return "covered" if self.covered_fraction >= self.asked - 1e-9 else "short"


@dataclass(frozen=True)
class PlanEvaluation:
    """A plan's figures: per element; per class (area, visible, covered, asked fraction); the
    chosen stations' registration edges (pairs of station ids with shared m2, the shared fraction of
    the smaller's view and the weakest direction's share), how many parts the graph has, and in
    how many parts of the candidate spots' own graph the stations stand (no choice of spots joins
    those: a plan with as many parts is as connected as the spots allow)."""

    elements: tuple[ElementCoverage, ...]
    classes: dict[str, dict[str, float]]
    edges: tuple[tuple[int, int, float, float, float], ...]
    parts: int
    spot_parts: int
    density: np.ndarray  # (S,) summed density of the stations on every sample

    def met(self) -> bool:
        return all(c["covered_fraction"] >= c["asked"] - 1e-9 for c in self.classes.values() if c["visible_m2"] > 0)


def evaluate(plan: SurveyPlan, *, density: np.ndarray | None = None) -> PlanEvaluation:
    """The coverage and registration figures of a plan; ``density`` (S,): per-sample densities to
    judge instead of the plan's own estimate (e.g. measured on its scan)."""
    space = plan.space
    config, samples = space.config, space.samples
    summed = space.visibility.density_of(plan.chosen) if density is None else density
    counted = space.klass >= 0
    seen = space.visibility.reachable & counted
    edge_on = space.visibility.seen & ~seen & counted
    covered = seen & (summed >= config.density_pts_m2)
    scene = space.scene
    table = scene.components
    elements = []
    order = np.flatnonzero(counted)[np.argsort(samples.component[counted], kind="stable")]
    comp_sorted = samples.component[order]
    starts = np.flatnonzero(np.r_[True, comp_sorted[1:] != comp_sorted[:-1]])
    ends = np.r_[starts[1:], len(order)]
    component_area = np.bincount(scene.mesh.face_component, weights=triangle_areas(scene.mesh), minlength=len(table))
    for a, b in zip(starts, ends):
        idx = order[a:b]
        c = int(samples.component[idx[0]])
        w = samples.area_m2[idx]
        vis = seen[idx]
        storey = str(table.storey[c]) or storey_at(scene, float(np.median(samples.xyz[idx, 2])) - 0.5)
        klass = config.classes[int(space.klass[idx[0]])]
        elements.append(ElementCoverage(
            component=c, global_id=str(table.global_id[c]), ifc_class=str(table.ifc_class[c]),
            klass=klass, storey=storey, name=str(table.name[c]), asked=config.coverage_of(klass),
            area_m2=float(component_area[c]), visible_m2=float(w[vis].sum()), edge_on_m2=float(w[edge_on[idx]].sum()),
            covered_m2=float(w[covered[idx]].sum()),
            median_density_pts_m2=float(np.median(summed[idx][vis])) if vis.any() else math.nan))
    total, visible, edge_area = space.class_areas()
    covered_area = np.bincount(space.klass[covered], weights=samples.area_m2[covered], minlength=len(config.classes))
    classes = {name: {"area_m2": float(total[k]), "visible_m2": float(visible[k]), "edge_on_m2": float(edge_area[k]),
                      "covered_m2": float(covered_area[k]),
                      "covered_fraction": float(covered_area[k] / visible[k]) if visible[k] > 0 else math.nan,
                      "asked": config.coverage_of(name)}
               for k, name in enumerate(config.classes)}
    chosen = np.asarray(plan.chosen)
    shared = space.overlaps.shared_m2
    edges = []
    for a in range(len(chosen)):
        for b in range(a + 1, len(chosen)):
            i, j = chosen[a], chosen[b]
            if space.edges[i, j]:
                smaller = min(shared[i, i], shared[j, j])
                edges.append((a, b, float(shared[i, j]), float(shared[i, j] / smaller) if smaller > 0 else 0.0,
                              float(space.overlaps.weakest_share[i, j])))
    parts = int(graph_parts(space.edges, chosen).max() + 1) if len(chosen) else 0
    spot_parts = len(np.unique(graph_parts(space.edges)[chosen])) if len(chosen) else 0
    return PlanEvaluation(elements=tuple(elements), classes=classes, edges=tuple(edges), parts=parts,
                          spot_parts=spot_parts, density=summed)

"""The survey planner's settings: one frozen dataclass, every default in one place.

``PlanConfig`` travels from the CLI (or a TOML file of its keys) to the planner and into the
plan's ``plan.json``. Units are in the names. The definitions behind each setting (coverage,
density, incidence, registration overlap) are in docs/guide/planning.md.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from bimscan.errors import ConfigError

DEFAULT_CLASSES = ("Wall&Column", "Beam", "Covering", "Slab")
SOLVERS = ("auto", "greedy", "milp")
# A surface seen more edge-on than this from every spot counts as not seen at all (it is the
# denominator of coverage: "visible from some spot"); the asked incidence limit is at most this.
VISIBLE_INCIDENCE_DEG = 85.0


@dataclass(frozen=True)
class PlanConfig:
    """What a survey plan must reach, and how the planner searches (see docs/guide/planning.md).

    classes: the label scheme's classes whose surfaces must be covered. coverage: the fraction of
    each class's visible surface to cover, one value for all classes or one per class (in the
    order of ``classes``). density_pts_m2: the points per square metre a surface patch needs to
    count as covered (the stations' densities summed, each within the incidence limit).
    max_incidence_deg: a station's points on a patch count only when its beam meets the patch
    at most this far from the patch's normal.

    overlap: two stations register (an edge of the registration graph) when the surface both see
    at ``overlap_density_pts_m2`` or more is at least this fraction of what the smaller of the
    two sees, and the shared surface holds at least ``min_direction_share`` of its area facing
    its weakest direction (the smallest eigenvalue of the sum of n n^T over the shared surface,
    over its trace; 0 for a single wall, which lets ICP slide).

    grid_m, clearance_m, max_candidates: candidate spots on a grid over every floor (the tripod
    spot rules of ``survey.spots``), coarser on models with more grid cells than max_candidates.
    samples_per_m2, min_samples: surface samples per square metre of each element, and at least
    this many per element. solver: ``greedy`` (the connected greedy cover, pruned, then improved
    by local search and ``search_rounds`` rounds of iterated greedy, seeded by ``seed``), ``milp``
    (that, then scipy's HiGHS on the exact problem within
    ``milp_time_limit_s``; its answer, repaired, is used even when the time limit stopped it, so
    it may differ between machines) or ``auto`` (the MILP only on models of at most
    ``milp_max_groups`` surface groups, and its answer only when it proved it optimal: the same
    model and settings give the same plan everywhere). seed: the surface sampling's seed.
    """

    classes: tuple[str, ...] = DEFAULT_CLASSES
    coverage: tuple[float, ...] = (0.95,)
    density_pts_m2: float = 1000.0
    max_incidence_deg: float = 70.0
    overlap: float = 0.1
    overlap_density_pts_m2: float = 100.0
    min_direction_share: float = 0.03
    grid_m: float = 1.0
    clearance_m: float = 0.4
    max_candidates: int = 1500
    samples_per_m2: float = 25.0
    min_samples: int = 8
    solver: str = "auto"
    search_rounds: int = 200
    milp_max_groups: int = 3000
    milp_time_limit_s: float = 30.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.classes or len(set(self.classes)) != len(self.classes):
            raise ConfigError(f"classes = {list(self.classes)} must name at least one class, each once; "
                              f"e.g. {','.join(DEFAULT_CLASSES)}")
        if len(self.coverage) not in (1, len(self.classes)):
            raise ConfigError(f"coverage = {list(self.coverage)} must be one fraction, or one per class "
                              f"({len(self.classes)}: {', '.join(self.classes)})")
        for value in self.coverage:
            if not (math.isfinite(value) and 0 < value <= 1):
                raise ConfigError(f"coverage = {value} is impossible; give a fraction in (0, 1], e.g. 0.95")
        positive = {"density_pts_m2": self.density_pts_m2, "overlap_density_pts_m2": self.overlap_density_pts_m2,
                    "grid_m": self.grid_m, "samples_per_m2": self.samples_per_m2,
                    "milp_time_limit_s": self.milp_time_limit_s}
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{name} = {value} is impossible; give a number > 0")
        if not (math.isfinite(self.max_incidence_deg) and 0 < self.max_incidence_deg <= VISIBLE_INCIDENCE_DEG):
            raise ConfigError(f"max_incidence_deg = {self.max_incidence_deg} is impossible; give an angle in "
                              f"(0, {VISIBLE_INCIDENCE_DEG:g}] degrees from the surface normal")
        for name in ("overlap", "min_direction_share"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value < 1):
                raise ConfigError(f"{name} = {value} is impossible; give a fraction in [0, 1)")
        if self.min_direction_share > 1 / 3:
            raise ConfigError(f"min_direction_share = {self.min_direction_share} is impossible (a surface facing "
                              "every direction alike holds 1/3 in each); give at most 0.33")
        if not (math.isfinite(self.clearance_m) and self.clearance_m >= 0):
            raise ConfigError(f"clearance_m = {self.clearance_m} is impossible; give metres >= 0")
        if self.search_rounds < 0:
            raise ConfigError(f"search_rounds = {self.search_rounds} is impossible; give 0 (no search) or more")
        for name in ("max_candidates", "min_samples", "milp_max_groups"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} = {getattr(self, name)} is impossible; give 1 or more")
        if self.solver not in SOLVERS:
            raise ConfigError(f"solver = {self.solver!r} is unknown; choose one of {', '.join(SOLVERS)}")

    def coverage_of(self, name: str) -> float:
        """The coverage asked of class ``name`` (one of ``classes``)."""
        return self.coverage[0] if len(self.coverage) == 1 else self.coverage[self.classes.index(name)]

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

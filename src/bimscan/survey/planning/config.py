"""The survey planner's settings: one frozen dataclass, every default in one place.

``PlanConfig`` travels from the CLI (or a TOML file of its keys) to the planner and into the
plan's ``plan.json``. Units are in the names. The definitions behind each setting (coverage,
density, incidence, registration overlap) are in docs/guide/planning.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

from bimscan.constraints import Checked, Range, default_of, setting
from bimscan.errors import ConfigError

DEFAULT_CLASSES = ("Wall&Column", "Beam", "Covering", "Slab")
Solver = Literal["auto", "greedy", "milp"]
# A surface seen more edge-on than this from every spot counts as not seen at all (it is the
# denominator of coverage: "visible from some spot"); the asked incidence limit is at most this.
VISIBLE_INCIDENCE_DEG = 85.0


@dataclass(frozen=True)
class PlanConfig(Checked):
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
    coverage_ladder: the coverages at which the plan also reports the stations needed, every class
    asked the same share (what the last few percent cost; each one is a cover chosen as the plan's
    is, so each costs about as long as the plan's own search; the asked coverage joins them when
    it is one share for every class; empty: none).

    A setting that would change nothing is refused: the MILP's time limit and size limit with the
    greedy solver, its size limit with ``milp`` (which runs it on any model); and, when a given
    plan is checked (``check_for_checking``), every setting of the search.
    """

    classes: tuple[str, ...] = DEFAULT_CLASSES
    coverage: tuple[float, ...] = setting((0.95,), each=Range(0.0, 1.0, low_open=True), hint="fractions, e.g. 0.95")
    density_pts_m2: float = setting(1000.0, within=Range(0.0, None, low_open=True))
    max_incidence_deg: float = setting(70.0, within=Range(0.0, VISIBLE_INCIDENCE_DEG, low_open=True),
                                       hint="degrees from the surface normal")
    overlap: float = setting(0.1, within=Range(0.0, 1.0, high_open=True), hint="a fraction")
    overlap_density_pts_m2: float = setting(100.0, within=Range(0.0, None, low_open=True))
    min_direction_share: float = setting(0.03, within=Range(0.0, 1 / 3),
                                         hint="a surface facing every direction alike holds 1/3 in each")
    grid_m: float = setting(1.0, within=Range(0.0, None, low_open=True))
    clearance_m: float = setting(0.4, within=Range(0.0, None))
    max_candidates: int = setting(1500, within=Range(1, None))
    samples_per_m2: float = setting(25.0, within=Range(0.0, None, low_open=True))
    min_samples: int = setting(8, within=Range(1, None))
    solver: Solver = "auto"
    search_rounds: int = setting(200, within=Range(0, None), hint="0: no search")
    milp_max_groups: int = setting(3000, within=Range(1, None))
    milp_time_limit_s: float = setting(30.0, within=Range(0.0, None, low_open=True))
    seed: int = 0
    coverage_ladder: tuple[float, ...] = setting((0.8, 0.9, 0.95), each=Range(0.0, 1.0, low_open=True),
                                                 hint="fractions, e.g. 0.8,0.9,0.95")

    def check(self) -> None:
        if not self.classes or len(set(self.classes)) != len(self.classes):
            raise ConfigError(f"classes = {list(self.classes)} must name at least one class, each once; "
                              f"e.g. {','.join(DEFAULT_CLASSES)}")
        if len(self.coverage) not in (1, len(self.classes)):
            raise ConfigError(f"coverage = {list(self.coverage)} must be one fraction, or one per class "
                              f"({len(self.classes)}: {', '.join(self.classes)})")
        idle = [name for name in ("milp_time_limit_s", "milp_max_groups") if not self._acts(name)]
        if idle:
            shown = " and ".join(f"{name} = {setting_text(getattr(self, name))}" for name in idle)
            runs, other = (("runs no MILP", "'milp' or 'auto'") if self.solver == "greedy" else
                           ("runs the MILP on any model (only 'auto' leaves larger ones out)", "'auto'"))
            raise ConfigError(f"{shown} would change nothing: solver = {self.solver!r} {runs}; leave "
                              f"{'it' if len(idle) == 1 else 'them'} out, or choose {other} instead")

    def _acts(self, name: str) -> bool:
        """Whether setting ``name`` of the MILP acts under this solver (else it must stay at its default)."""
        if getattr(self, name) == default_of(PlanConfig, name):
            return True
        if name == "milp_time_limit_s":
            return self.solver != "greedy"
        return self.solver == "auto"  # milp_max_groups

    def check_for_checking(self) -> None:
        """Raise ConfigError when a setting that only chooses stations (the search, the MILP, the
        coverage ladder) is away from its default: it changes nothing when a given plan is checked."""
        idle = [name for name in ("solver", "search_rounds", "milp_max_groups", "milp_time_limit_s",
                                  "coverage_ladder") if getattr(self, name) != default_of(PlanConfig, name)]
        if idle:
            shown = " and ".join(f"{name} = {setting_text(getattr(self, name))}" for name in idle)
            raise ConfigError(f"{shown} would change nothing: a given plan is checked, no station is chosen; "
                              f"leave {'it' if len(idle) == 1 else 'them'} out")

    def coverage_of(self, name: str) -> float:
        """The coverage asked of class ``name`` (one of ``classes``)."""
        return self.coverage[0] if len(self.coverage) == 1 else self.coverage[self.classes.index(name)]

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def setting_text(value: Any) -> str:
    """A setting's value for a message, as a TOML file writes it (and as ``constraints`` shows it)."""
    if isinstance(value, tuple):
        return str(list(value))
    return f"{value:g}" if isinstance(value, float) else repr(value)

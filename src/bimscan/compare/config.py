"""Settings of scan-against-model comparison: alignment (``AlignConfig``) and the per-element
verdicts (``ProgressConfig``), every default in one place. They travel from the CLI into the
outputs (``transform.json``, ``summary.json``). docs/guide/progress.md explains each.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError

# Construction tolerances by class, metres: ACI 117-10 (the standard the as-built deviations of
# bimscan.scan.asbuilt draw from): lateral alignment of members 25 mm, plumb 25 mm (heights up to
# 30 m), level of slabs 19 mm. Coverings (ceilings) follow the slab's level tolerance; classes not
# named take ``default_tolerance_m``.
TOLERANCES_M = {"Wall&Column": 0.025, "Beam": 0.025, "Slab": 0.019, "Covering": 0.019}
TOLERANCE_STANDARD = "ACI 117-10: lateral alignment 25 mm, plumb 25 mm, slab level 19 mm"


@dataclass(frozen=True)
class AlignConfig(Checked):
    """How ``align_scan`` puts a scan into the model's frame.

    voxel_m: the cube the scan is thinned to (centroids). max_points: the centroids registration
    uses at most (drawn at random with ``seed``). levelled: the scan's z axis is up (a levelled
    tripod: only the heading and the offset are searched); otherwise up is estimated from its
    floors, ceilings and walls, within ``max_tilt_deg`` of its z axis. heading_step_deg: the
    resolution of the heading search; grid_m: the cell of the floor-plan correlation;
    candidates: poses refined by ICP. icp_scales_m: the robust scale of the point-to-plane ICP,
    coarse to fine (Geman-McClure weights; residuals beyond 3 scales are left out). inlier_m: a
    point within this of the model counts as an inlier. min_inlier_share: below this the scan
    is refused as not showing the model. ambiguity: another pose whose inlier share is at least
    this fraction of the best one's makes the fit ambiguous. free_share: a direction that holds
    less than this share of the surface normals' weight is free (a corridor's axis).
    """

    voxel_m: float = setting(0.05, within=Range(0.005, 1.0), hint="metres")
    max_points: int = setting(120_000, within=Range(1000, None))
    levelled: bool = False
    max_tilt_deg: float = setting(20.0, within=Range(0.0, 45.0), hint="degrees")
    heading_step_deg: float = setting(0.5, within=Range(0.05, 5.0), hint="degrees")
    grid_m: float = setting(0.1, within=Range(0.01, 2.0), hint="metres")
    candidates: int = setting(8, within=Range(1, 100))
    icp_scales_m: tuple[float, ...] = setting((0.5, 0.2, 0.08, 0.03), each=Range(0.001, 5.0, low_open=True),
                                              hint="metres, coarse to fine")
    icp_iterations: int = setting(30, within=Range(1, 1000), hint="per scale")
    inlier_m: float = setting(0.05, within=Range(0.001, 1.0), hint="metres")
    min_inlier_share: float = setting(0.2, within=Range(0.0, 1.0))
    ambiguity: float = setting(0.95, within=Range(0.0, 1.0, low_open=True))
    free_share: float = setting(0.02, within=Range(0.0, 1 / 3))
    seed: int = 0

    def check(self) -> None:
        if list(self.icp_scales_m) != sorted(self.icp_scales_m, reverse=True):
            raise ConfigError(f"icp_scales_m = {list(self.icp_scales_m)} must go from coarse to fine (decreasing)")

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class ProgressConfig(Checked):
    """How ``compare_scan`` judges each element (docs/guide/progress.md).

    samples_per_m2 / min_samples: surface samples per element, the unit of its visible and
    supported shares. support_m: a scan return within this of a sample's range (along the ray
    from a station, widened by the cell's spread at grazing incidence) supports it; one farther
    than this behind it shows the beam passed where the element would stand. max_incidence_deg:
    samples met more edge-on than this from a station decide nothing from it. cell_deg: the
    angular cell of each station's range image (None: twice the station's measured point
    spacing). built_share: an element whose visible surface is supported at least this much is
    built. min_visible_share / min_visible_m2: an element is decided only when at least this
    share and this area of its surface could be seen. band_m: scan points within this of the
    model are attached to the nearest element (distances, deviation fits). tolerances_m: the
    position tolerance per class (``TOLERANCES_M``), beyond which a built element is out of
    tolerance; default_tolerance_m for other classes. fit_points: points per element kept for
    its deviation fit at most. window_s: a mobile scan's points are grouped into stations of this
    many seconds of walk.
    """

    samples_per_m2: float = setting(25.0, within=Range(0.0, None, low_open=True))
    min_samples: int = setting(8, within=Range(1, None))
    support_m: float = setting(0.08, within=Range(0.001, 1.0), hint="metres")
    max_incidence_deg: float = setting(80.0, within=Range(0.0, 90.0, low_open=True), hint="degrees")
    cell_deg: float | None = setting(None, within=Range(0.005, 5.0), hint="degrees")
    built_share: float = setting(0.5, within=Range(0.0, 1.0, low_open=True))
    min_visible_share: float = setting(0.05, within=Range(0.0, 1.0))
    min_visible_m2: float = setting(0.05, within=Range(0.0, None), hint="square metres")
    band_m: float = setting(0.15, within=Range(0.001, 2.0), hint="metres")
    tolerances_m: dict[str, float] = field(default_factory=lambda: dict(TOLERANCES_M))
    default_tolerance_m: float = setting(0.025, within=Range(0.0, 1.0, low_open=True), hint="metres")
    fit_points: int = setting(4000, within=Range(10, None))
    window_s: float = setting(1.0, within=Range(0.01, 60.0), hint="seconds")
    seed: int = 0

    def check(self) -> None:
        for name, value in self.tolerances_m.items():
            if not isinstance(value, int | float) or isinstance(value, bool) or not 0 < value <= 1:
                raise ConfigError(f"tolerances_m[{name!r}] = {value!r} must be a number of metres in (0, 1]")

    def tolerance_of(self, class_name: str) -> float:
        return float(self.tolerances_m.get(class_name, self.default_tolerance_m))

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

"""What a mobile scan is: a platform carrying lidars along a trajectory, with drift.

``MobileScan`` is the mobile half of a ``ScanRecipe`` (``ScanRecipe.mobile``; None for a tripod
survey): the platform (``survey.platform``), the lidar on each of its mounts (``scan.lidars``:
a multi-beam or a Risley-prism lidar), a multi-beam lidar's rotation rate, where the trajectory comes from (``"auto"``:
planned from the model by ``survey.walk``; else a CSV file, ``survey.trajectory``) and the
SLAM-like drift (``survey.drift``). ``pass_pulses`` and ``walk_pulses`` count what a pass and a
walk fire, exactly.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ScannerSettingsError
from bimscan.scan.lidars import Lidar
from bimscan.scan.risley import RisleyScanner
from bimscan.survey.drift import DriftModel, GnssInsModel
from bimscan.survey.platform import Platform
from bimscan.survey.trajectory import Trajectory

AUTO_TRAJECTORY = "auto"
UNUSED_LIDAR_FIELDS = ("beam_divergence_rad", "wavelength_nm")  # recorded facts the thin-ray scan does not use


@dataclass(frozen=True)
class MobileScan(Checked):
    """See the module docs. rotation_hz None: the lidar's default rate (set on construction); a rate
    outside the lidar's own rates is a warning (``warnings``), an error under ``strict``. A Risley
    lidar has no spinning head: its rotation_hz stays None (a rate given is refused)."""

    platform: Platform
    lidar: Lidar
    rotation_hz: float | None = setting(None, within=Range(0.0, None, low_open=True))
    trajectory_from: str = AUTO_TRAJECTORY
    drift: DriftModel | GnssInsModel = field(default_factory=DriftModel)

    def __post_init__(self) -> None:
        if self.rotation_hz is None:
            object.__setattr__(self, "rotation_hz", self.lidar.rotation_hz)
        super().__post_init__()

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(problem)

    def check(self) -> None:
        if self.platform.flies:
            from bimscan.survey.flight import check_pointable

            check_pointable(self.lidar)
            if isinstance(self.drift, DriftModel) and not self.drift.is_off:
                raise self.refusal("SLAM drift (--drift) is a walking platform's error; a drone's position comes from "
                                   "GNSS/INS: give --gnss instead")
        elif isinstance(self.drift, GnssInsModel) and not self.drift.is_off:
            raise self.refusal("a GNSS/INS error (--gnss) is a drone's; a walking platform's SLAM error is --drift")
        if isinstance(self.lidar, RisleyScanner) and self.rotation_hz is not None:
            raise self.refusal(f"{self.lidar.name} is a Risley-prism lidar: its prisms turn at the rates of its "
                               "scanner file and it has no head rotation rate; leave rotation_hz (--rotation-hz) out")

    def warnings(self, *, strict: bool = False) -> list[str]:
        return self.lidar.check_rotation(self.rotation_hz, strict=strict)

    def pass_pulses(self, duration_s: float) -> int:
        """Pulses one mount fires over a pass of ``duration_s``: whole firing sequences only."""
        sequences = int(math.floor(duration_s / (self.lidar.firing_cycle_us * 1e-6) + 1e-9))
        return max(0, sequences) * self.lidar.n_beams

    def walk_pulses(self, trajectory: Trajectory) -> int:
        """Pulses the whole walk fires: every pass, every mount's lidar (exactly what is scanned)."""
        per_mount = sum(self.pass_pulses(float(trajectory.t[p][-1] - trajectory.t[p][0]))
                        for p in trajectory.pass_slices())
        return per_mount * len(self.platform.mounts)

    def to_json(self) -> dict[str, Any]:
        """What a mobile scan records (and its fingerprint's input). The lidar's divergence and
        wavelength are left out: the thin-ray scan does not use them (as a tripod recipe leaves out
        the device facts only the sensor effects use)."""
        trajectory = self.trajectory_from if self.trajectory_from == AUTO_TRAJECTORY else Path(self.trajectory_from).name
        lidar = {k: v for k, v in dataclasses.asdict(self.lidar).items() if k not in UNUSED_LIDAR_FIELDS}
        platform = dataclasses.asdict(self.platform)
        if not self.platform.flies:  # what walking platforms recorded before drones flew (their fingerprints)
            del platform["kind"], platform["flight"]
        return {"platform": platform, "scanner": lidar,
                "rotation_hz": self.rotation_hz, "trajectory_from": trajectory, "drift": self.drift.to_json()}

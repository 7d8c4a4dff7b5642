"""Measurement noise of the virtual scanner (the paper's intrinsic scanning errors)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from bimscan.errors import ScannerSettingsError


@dataclass(frozen=True)
class NoiseModel:
    """Zero-mean Gaussian noise: along the beam (metres) and on azimuth and elevation (degrees).

    Defaults are the SPC paper's: 5 mm range, 0.03 degrees on each angle. ``NoiseModel.off()``
    gives exact points on the hit surfaces.
    """

    range_sigma_m: float = 0.005
    angle_sigma_deg: float = 0.03

    def __post_init__(self) -> None:
        for name in ("range_sigma_m", "angle_sigma_deg"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise ScannerSettingsError(f"{name} = {value} is impossible; allowed: a number >= 0")
        if self.angle_sigma_deg > 5:
            raise ScannerSettingsError(f"angle_sigma_deg = {self.angle_sigma_deg} is impossible for a laser scanner; allowed: 0..5")

    @staticmethod
    def off() -> NoiseModel:
        return NoiseModel(range_sigma_m=0.0, angle_sigma_deg=0.0)

    @property
    def enabled(self) -> bool:
        return self.range_sigma_m > 0 or self.angle_sigma_deg > 0

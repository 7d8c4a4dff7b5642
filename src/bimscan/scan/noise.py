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

    Registration error (off by default, as in the paper; real multi-station surveys have a few
    millimetres): each station's points are moved by one rigid transform drawn per station: a
    translation with ``registration_sigma_m`` per axis and a rotation about the station's vertical
    axis with ``registration_sigma_deg``, as left by target- or cloud-based registration.
    """

    range_sigma_m: float = 0.005
    angle_sigma_deg: float = 0.03
    registration_sigma_m: float = 0.0
    registration_sigma_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("range_sigma_m", "angle_sigma_deg", "registration_sigma_m", "registration_sigma_deg"):
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
        return self.range_sigma_m > 0 or self.angle_sigma_deg > 0 or self.registers_with_error

    @property
    def registers_with_error(self) -> bool:
        return self.registration_sigma_m > 0 or self.registration_sigma_deg > 0

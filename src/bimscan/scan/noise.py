"""Measurement noise of the virtual scanner (the paper's intrinsic scanning errors).

The scanner's datasheet drives it: a sigma left unset (None) is the scanner model's accuracy
(``ScannerModel.range_accuracy_m``, ``angle_accuracy_deg``), so a custom scanner file changes the
noise. ``NoiseModel.resolved(scanner)`` fills those in; a ``ScanRecipe`` holds the resolved model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from bimscan.errors import ScannerSettingsError

if TYPE_CHECKING:
    from bimscan.scan.device import ScannerModel

MAX_ANGLE_SIGMA_DEG = 5.0  # beyond this no laser scanner measures; a typo for radians or arc minutes
MAX_RANGE_SIGMA_M = 1.0  # beyond this no laser scanner measures; a typo for millimetres


@dataclass(frozen=True)
class NoiseModel:
    """Zero-mean Gaussian noise: along the beam (metres) and on azimuth and elevation (degrees).

    ``range_sigma_m``/``angle_sigma_deg`` None: the scanner's range and angle accuracy (the SPC
    paper's 5 mm and 0.03 degrees for the RIEGL VZ-400). ``NoiseModel.off()`` gives exact points
    on the hit surfaces.

    Registration error (off by default, as in the paper; real multi-station surveys have a few
    millimetres): each station's points are moved by one rigid transform drawn per station: a
    translation with ``registration_sigma_m`` per axis and a rotation about the station's vertical
    axis with ``registration_sigma_deg``, as left by target- or cloud-based registration.
    """

    range_sigma_m: float | None = None
    angle_sigma_deg: float | None = None
    registration_sigma_m: float = 0.0
    registration_sigma_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("range_sigma_m", "angle_sigma_deg", "registration_sigma_m", "registration_sigma_deg"):
            value = getattr(self, name)
            if value is not None and (not math.isfinite(value) or value < 0):
                raise ScannerSettingsError(f"{name} = {value} is impossible; allowed: a number >= 0")
        if self.range_sigma_m is not None and self.range_sigma_m > MAX_RANGE_SIGMA_M:
            raise ScannerSettingsError(f"range_sigma_m = {self.range_sigma_m} is impossible for a laser scanner (metres, "
                                       f"not millimetres); allowed: 0..{MAX_RANGE_SIGMA_M:g}")
        if self.angle_sigma_deg is not None and self.angle_sigma_deg > MAX_ANGLE_SIGMA_DEG:
            raise ScannerSettingsError(f"angle_sigma_deg = {self.angle_sigma_deg} is impossible for a laser scanner; "
                                       f"allowed: 0..{MAX_ANGLE_SIGMA_DEG:g}")

    @staticmethod
    def off() -> NoiseModel:
        return NoiseModel(range_sigma_m=0.0, angle_sigma_deg=0.0)

    def resolved(self, scanner: ScannerModel) -> NoiseModel:
        """This model with unset sigmas taken from the scanner's accuracies."""
        return replace(
            self,
            range_sigma_m=scanner.range_accuracy_m if self.range_sigma_m is None else self.range_sigma_m,
            angle_sigma_deg=scanner.angle_accuracy_deg if self.angle_sigma_deg is None else self.angle_sigma_deg,
        )

    @property
    def registers_with_error(self) -> bool:
        return self.registration_sigma_m > 0 or self.registration_sigma_deg > 0

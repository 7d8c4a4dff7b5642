"""Measurement noise of the virtual scanner (the paper's intrinsic scanning errors).

The scanner's datasheet drives it: a sigma left unset (None) is the scanner model's accuracy
(``ScannerModel.range_accuracy_m``, ``angle_accuracy_deg``), so a custom scanner file changes the
noise. ``NoiseModel.resolved(scanner)`` fills those in; a ``ScanRecipe`` holds the resolved model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ScannerSettingsError

if TYPE_CHECKING:
    from bimscan.scan.device import ScannerModel

MAX_ANGLE_SIGMA_DEG = 5.0  # beyond this no laser scanner measures; a typo for radians or arc minutes
MAX_RANGE_SIGMA_M = 1.0  # beyond this no laser scanner measures; a typo for millimetres


@dataclass(frozen=True)
class NoiseModel(Checked):
    """Zero-mean Gaussian noise: along the beam (metres) and on azimuth and elevation (degrees).

    ``range_sigma_m``/``angle_sigma_deg`` None: the scanner's range and angle accuracy (the SPC
    paper's 5 mm and 0.03 degrees for the RIEGL VZ-400). ``NoiseModel.off()`` gives exact points
    on the hit surfaces.

    Registration error (off by default, as in the paper; real multi-station surveys have a few
    millimetres): each station's points are moved by one rigid transform drawn per station: a
    translation with ``registration_sigma_m`` per axis and a rotation about the station's vertical
    axis with ``registration_sigma_deg``, as left by target- or cloud-based registration.
    """

    # beyond their ranges no laser scanner measures: a typo for millimetres, radians or arc minutes
    range_sigma_m: float | None = setting(None, within=Range(0.0, MAX_RANGE_SIGMA_M))
    angle_sigma_deg: float | None = setting(None, within=Range(0.0, MAX_ANGLE_SIGMA_DEG))
    registration_sigma_m: float = setting(0.0, within=Range(0.0, MAX_RANGE_SIGMA_M))
    registration_sigma_deg: float = setting(0.0, within=Range(0.0, 180.0))

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(f"impossible noise for a laser scanner: {problem} (sigmas are in metres, not "
                                    "millimetres, and degrees: 5 mm is 0.005)")

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

"""Mobile platforms as data: where a walking operator or a drone carries the lidars, and how they move.

``PLATFORMS`` maps a name (``handheld``, ``backpack``, ``drone``) to a ``Platform`` read from
``survey/platforms.toml``; users pass their own file with ``load_platform(path)`` (one table of
the same keys). ``TRIPOD`` names the static platform of TLS stations, which is not a
``Platform``: a tripod scan has stations, a mobile scan a trajectory.

A walking platform (``kind = "walking"``) follows a walk planned through the building
(``survey.walk``); a flying one (``kind = "flying"``) a flight planned around and over it
(``survey.flight``, its settings the platform's ``flight`` table).

Frames: the platform's origin is on the floor under the operator (a drone's: its gimbal-stabilised
payload, see ``survey.flight``); x points along the walk, y to the left, z up. A trajectory gives the origin's position and the platform's yaw, pitch and roll
over time. A mount places one lidar: at (forward_m, lateral_m, height_m), its spin axis tilted
``tilt_deg`` from the vertical towards the front (a rotation about y), then turned ``yaw_deg``
about z; a motor-driven head turns the mount about the platform's z at ``head_rotation_hz``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError
from bimscan.scan.virtual_scanner import MAX_MOUNTS
from bimscan.survey.flight import FlightSettings
from bimscan.toml_files import build_dataclass, load_named, read_package_tables

TRIPOD = "tripod"


@dataclass(frozen=True)
class Mount(Checked):
    """One lidar on the platform (see the module docs for the frames)."""

    height_m: float = setting(1.3, within=Range(0.0, 5.0), hint="metres, for a walking operator")
    forward_m: float = setting(0.0, within=Range())
    lateral_m: float = setting(0.0, within=Range())
    tilt_deg: float = setting(0.0, within=Range(-180.0, 180.0), hint="degrees")
    yaw_deg: float = setting(0.0, within=Range())
    head_rotation_hz: float = setting(0.0, within=Range(-10.0, 10.0), hint="Hz")

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"mount {problem}")

    def lever_arm(self) -> np.ndarray:
        """(3,) the sensor's position in the platform frame."""
        return np.array([self.forward_m, self.lateral_m, self.height_m])

    def rotation(self) -> np.ndarray:
        """(3, 3) sensor -> platform rotation at head angle 0: Rz(yaw) Ry(tilt)."""
        t, y = math.radians(self.tilt_deg), math.radians(self.yaw_deg)
        ry = np.array([[math.cos(t), 0.0, math.sin(t)], [0.0, 1.0, 0.0], [-math.sin(t), 0.0, math.cos(t)]])
        rz = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
        return rz @ ry


@dataclass(frozen=True)
class Platform(Checked):
    """A walking operator or a drone with one to four lidars.

    mounts: where each lidar sits (no default: a platform without a lidar placed is refused).
    kind: ``walking`` or ``flying`` (see the module docs). default_scanner: the lidar used unless
    one is given. walking_speed_m_s, stair_speed_m_s, max_turn_deg_per_s: how a planned walk moves
    (``survey.walk``). body_radius_m, headroom_m: the free space the operator needs (a planned walk
    keeps to it). flight: how a flying platform's flight is planned (``survey.flight``).
    """

    name: str
    mounts: tuple[Mount, ...]
    kind: Literal["walking", "flying"] = "walking"
    description: str = ""
    default_scanner: str = "velodyne_vlp16"
    walking_speed_m_s: float = setting(1.0, within=Range(0.05, 5.0))
    stair_speed_m_s: float = setting(0.5, within=Range(0.05, 5.0))
    max_turn_deg_per_s: float = setting(60.0, within=Range(1.0, 720.0))
    body_radius_m: float = setting(0.25, within=Range(0.05, 1.0))
    headroom_m: float = setting(1.9, within=Range(0.5, 4.0))
    flight: FlightSettings = field(default_factory=FlightSettings)

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"platform {self.name!r}: {problem}")

    def check(self) -> None:
        if not 1 <= len(self.mounts) <= MAX_MOUNTS:
            raise self.refusal(f"give 1..{MAX_MOUNTS} mounts, got {len(self.mounts)}")
        if self.kind == "walking" and self.flight != FlightSettings():
            raise self.refusal("a [flight] table plans a drone's flight; a walking platform walks: give kind = "
                               "\"flying\" or leave the table out")

    @property
    def flies(self) -> bool:
        return self.kind == "flying"


PLATFORMS: dict[str, Platform] = {
    name: build_dataclass(Platform, {"name": name, **table}, where=f"platforms.toml [{name}]")
    for name, table in read_package_tables("bimscan.survey", "platforms.toml").items()
}
PLATFORM_NAMES = (TRIPOD, *PLATFORMS)


def load_platform(source: str | Path) -> Platform:
    """A mobile platform by name (``PLATFORMS``) or from a TOML file of one platform's keys."""
    return load_named(source, PLATFORMS, kind="platform", names=PLATFORM_NAMES, read=_read_platform_file)


def _read_platform_file(table: dict[str, Any], path: Path) -> Platform:
    if not table.get("mounts"):  # no lidar placed: a platform file must say where its lidars sit
        raise ConfigError(f"{path}: the platform has no [[mounts]]; add one [[mounts]] table per lidar (height_m, "
                          "forward_m, lateral_m, tilt_deg, yaw_deg, head_rotation_hz), as in "
                          "docs/guide/mobile.md#platforms")
    return build_dataclass(Platform, {"name": path.stem, **table}, where=str(path))

"""SLAM-like registration error of a mobile scan: a smooth random walk along the path, closed at
loop closures (``--drift``).

A SLAM solution registers each sweep to the map built so far, so its error accumulates with the
distance walked like odometry error: a random walk whose variance grows linearly with path length
(Brownian motion in the distance travelled; the standard model of dead-reckoning and odometry
drift, e.g. Thrun, Burgard and Fox, *Probabilistic Robotics*, 2005, ch. 5; and of the
pose-graph errors that loop closures remove, Kuemmerle et al., "On measuring the accuracy of
SLAM algorithms", Autonomous Robots 27, 2009). Its parameters:

- ``sigma_m``: the position error's standard deviation per axis after ``REFERENCE_PATH_M``
  (10 m) walked since the last closure, growing with the square root of the distance; z drifts at
  ``vertical_ratio`` of that. Vendors state mobile scanners' relative accuracy as 1-3 cm
  (GeoSLAM ZEB Horizon: up to 6 mm relative, 1-3 cm typical; NavVis VLX: 5 mm), which a
  ``sigma_m`` of 0.005-0.02 reproduces over a room-sized loop.
- ``heading_sigma_deg``: the heading (yaw) error's standard deviation after 10 m (default:
  the angle whose lever over 10 m is ``sigma_m``, so position and heading drift agree).
- ``smoothing_m``: the walk is drawn on 1 m knots and smoothed with a Gaussian of this width,
  so the error changes smoothly along the path, as a SLAM trajectory does between sweeps.

Loop closures pin the error to zero: at the start of each pass and at every time in
``Trajectory.closures`` (the walk comes back to where it was), the walk between two pins is a
Brownian bridge (the random walk with the straight line between its values at the pins taken
off), which is how a pose-graph optimisation spreads the error found at a closure back along the
loop. After the last pin the error grows freely.

The error moves each point as the mis-registered sensor pose would:
``p' = Rz(dyaw(t)) (p - c(t)) + c(t) + d(t)``, with ``c(t)`` the beam origin at the point's time.

A drone is not registered by SLAM but placed by its GNSS/INS solution (``GnssInsModel``): its
position error per axis and its heading error are first-order Gauss-Markov processes in time
(stationary, standard deviation sigma, correlation time tau: ``x(t + dt) = phi x(t) +
sqrt(1 - phi^2) sigma w``, ``phi = exp(-dt / tau)``; the standard model of GNSS and INS error
states, e.g. Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation
Systems*, 2nd ed., 2013, sections 14.2 and 9.4), drawn at ``GNSS_KNOT_S`` knots and applied
as above. No closure pins it: GNSS holds the error bounded instead. Defaults for an RTK-fixed
DJI Matrice 350 with a Zenmuse L2 (DJI's specifications: RTK positioning 1 cm + 1 ppm
horizontally, 1.5 cm + 1 ppm vertically; the L2's IMU yaw accuracy 0.05 degree after
post-processing, 0.2 degree in real time): ``--gnss 0.01`` gives 1 cm horizontally, 1.5 cm
vertically and 0.05 degree of heading; the correlation time (30 s) is an assumption (the
multipath and atmospheric errors of RTK change over tens of seconds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ConfigError
from bimscan.survey.trajectory import Trajectory

REFERENCE_PATH_M = 10.0
KNOT_M = 1.0
GNSS_KNOT_S = 0.5
RTK_VERTICAL_RATIO = 1.5  # DJI RTK: 1.5 cm vertically for 1 cm horizontally
RTK_HEADING_DEG_PER_M = 5.0  # the L2's 0.05 degree of yaw for 1 cm of position
MAX_RTK_SIGMA_M = 2.0  # where the heading reaches GnssInsModel's 10 degrees


@dataclass(frozen=True)
class DriftModel(Checked):
    """See the module docs. sigma_m = 0: no drift (the points are where the true poses put them)."""

    sigma_m: float = setting(0.0, within=Range(0.0, 1.0), hint="metres per 10 m walked")
    heading_sigma_deg: float | None = setting(None, within=Range(0.0, 10.0), hint="degrees per 10 m walked")
    vertical_ratio: float = setting(0.5, within=Range(0.0, 10.0))
    smoothing_m: float = setting(2.0, within=Range(0.0, 100.0))

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"drift {problem}")

    @property
    def is_off(self) -> bool:
        return self.sigma_m == 0.0 and not self.heading_sigma_deg

    def heading_sigma_rad(self) -> float:
        if self.heading_sigma_deg is not None:
            return math.radians(self.heading_sigma_deg)
        return self.sigma_m / REFERENCE_PATH_M

    def to_json(self) -> dict[str, float]:
        return {"sigma_m": self.sigma_m, "heading_sigma_deg": math.degrees(self.heading_sigma_rad()),
                "vertical_ratio": self.vertical_ratio, "smoothing_m": self.smoothing_m}


@dataclass(frozen=True, eq=False)
class DriftTrack:
    """The drift at knot times: t (K,) seconds, offset (K, 3) metres, yaw (K,) radians."""

    t: np.ndarray
    offset: np.ndarray
    yaw: np.ndarray

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(offset (N, 3), yaw (N,)) at times t, linear between knots."""
        offset = np.column_stack([np.interp(t, self.t, self.offset[:, axis]) for axis in range(3)])
        return offset, np.interp(t, self.t, self.yaw)

    def apply(self, xyz: np.ndarray, sensor: np.ndarray, t: np.ndarray) -> None:
        """Move points (N, 3) and their beam origins (N, 3) in place by the drift at their times."""
        offset, yaw = self.at(t)
        c, s = np.cos(yaw), np.sin(yaw)
        rel = xyz - sensor
        x = c * rel[:, 0] - s * rel[:, 1]
        y = s * rel[:, 0] + c * rel[:, 1]
        xyz[:, 0] = sensor[:, 0] + x + offset[:, 0]
        xyz[:, 1] = sensor[:, 1] + y + offset[:, 1]
        xyz[:, 2] += offset[:, 2]
        sensor += offset


@dataclass(frozen=True)
class GnssInsModel(Checked):
    """A drone's GNSS/INS error (see the module docs); every sigma 0: none."""

    horizontal_sigma_m: float = setting(0.0, within=Range(0.0, 10.0), hint="metres per horizontal axis")
    vertical_sigma_m: float = setting(0.0, within=Range(0.0, 10.0))
    heading_sigma_deg: float = setting(0.0, within=Range(0.0, 10.0))
    correlation_s: float = setting(30.0, within=Range(0.01, 3600.0), hint="seconds")

    def refusal(self, problem: str) -> ConfigError:
        return ConfigError(f"GNSS/INS error {problem}")

    @staticmethod
    def rtk(horizontal_sigma_m: float) -> GnssInsModel:
        """The DJI RTK figures scaled to ``horizontal_sigma_m`` (vertical ``RTK_VERTICAL_RATIO`` x;
        heading ``RTK_HEADING_DEG_PER_M`` degrees per metre, 0.05 per centimetre), as ``--gnss`` gives
        them; ConfigError, naming --gnss, beyond ``MAX_RTK_SIGMA_M``."""
        if not 0.0 <= horizontal_sigma_m <= MAX_RTK_SIGMA_M:
            raise ConfigError(f"--gnss (gnss_m) must be a horizontal sigma in [0, {MAX_RTK_SIGMA_M:g}] metres (0.01: an "
                              f"RTK-fixed drone), got {horizontal_sigma_m:g}")
        return GnssInsModel(horizontal_sigma_m=horizontal_sigma_m,
                            vertical_sigma_m=RTK_VERTICAL_RATIO * horizontal_sigma_m,
                            heading_sigma_deg=RTK_HEADING_DEG_PER_M * horizontal_sigma_m)

    @property
    def is_off(self) -> bool:
        return self.horizontal_sigma_m == 0.0 and self.vertical_sigma_m == 0.0 and self.heading_sigma_deg == 0.0

    def to_json(self) -> dict[str, float | str]:
        return {"kind": "gnss_ins", "horizontal_sigma_m": self.horizontal_sigma_m,
                "vertical_sigma_m": self.vertical_sigma_m, "heading_sigma_deg": self.heading_sigma_deg,
                "correlation_s": self.correlation_s}


def registration_drift(drift_m: float | None, gnss_m: float | None) -> DriftModel | GnssInsModel | None:
    """A mobile scan's registration error from ``drift_m`` (a walk's SLAM drift, ``--drift``) or
    ``gnss_m`` (a drone's GNSS/INS error, ``--gnss``); ConfigError when both are given."""
    if drift_m is not None and gnss_m is not None:
        raise ConfigError("give --drift / drift_m (a walking platform's SLAM drift) or --gnss / gnss_m (a drone's "
                          "GNSS/INS error), not both")
    if gnss_m is not None:
        return GnssInsModel.rtk(gnss_m)
    return None if drift_m is None else DriftModel(sigma_m=drift_m)


def gauss_markov(rng: np.random.Generator, n: int, dt: float, correlation_s: float, sigmas: np.ndarray) -> np.ndarray:
    """(n, D) a stationary first-order Gauss-Markov process sampled every ``dt`` seconds, one column per
    sigma of ``sigmas`` (D,)."""
    phi = math.exp(-dt / correlation_s)
    draws = rng.standard_normal((n, len(sigmas)))
    out = np.empty((n, len(sigmas)))
    out[0] = draws[0]
    scale = math.sqrt(1.0 - phi * phi)
    for k in range(1, n):
        out[k] = phi * out[k - 1] + scale * draws[k]
    return out * sigmas


def _bridged(walk: np.ndarray, s: np.ndarray, pins: np.ndarray) -> np.ndarray:
    """The walk (K, D) pinned to zero at knot indices ``pins`` (sorted, first 0): Brownian bridges
    between pins, a free walk after the last."""
    out = np.empty_like(walk)
    bounds = list(pins) + [len(walk)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        part = walk[a:b] - walk[a]
        if b < len(walk):  # bridge to the next pin
            span = s[b] - s[a]
            ramp = ((s[a:b] - s[a]) / span)[:, None] if span > 0 else np.zeros((b - a, 1))
            part = part - ramp * (walk[b] - walk[a])
        out[a:b] = part
    return out


def drift_track(trajectory: Trajectory, model: DriftModel | GnssInsModel, seed: int) -> DriftTrack:
    """The drift of every pass of ``trajectory`` (see the module docs), drawn from ``seed``."""
    rng = np.random.default_rng([seed, 0x64726966])  # "drif": its own stream of the recipe's seed
    if isinstance(model, GnssInsModel):
        t0, t1 = float(trajectory.t[0]), float(trajectory.t[-1])
        n = max(2, int(math.ceil((t1 - t0) / GNSS_KNOT_S)) + 1)
        knots = np.linspace(t0, t1, n)
        sigmas = np.array([model.horizontal_sigma_m, model.horizontal_sigma_m, model.vertical_sigma_m,
                           math.radians(model.heading_sigma_deg)])
        error = gauss_markov(rng, n, (t1 - t0) / (n - 1), model.correlation_s, sigmas)
        return DriftTrack(t=knots, offset=error[:, :3], yaw=error[:, 3])
    times, offsets, yaws = [], [], []
    sigma_v = model.sigma_m * model.vertical_ratio
    scales = np.array([model.sigma_m, model.sigma_m, sigma_v, model.heading_sigma_rad()])
    for part in trajectory.pass_slices():
        t, xyz = trajectory.t[part], trajectory.xyz[part]
        s_samples = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
        n = max(2, int(math.ceil(s_samples[-1] / KNOT_M)) + 1)
        s = np.linspace(0.0, max(s_samples[-1], 1e-9), n)
        step = np.diff(s, prepend=0.0)
        increments = rng.standard_normal((n, 4)) * np.sqrt(step / REFERENCE_PATH_M)[:, None] * scales
        walk = np.cumsum(increments, axis=0)
        if model.smoothing_m > 0:
            walk = gaussian_filter1d(walk, sigma=model.smoothing_m / KNOT_M, axis=0, mode="nearest")
        knot_t = np.interp(s, s_samples, t)
        closures = trajectory.closures[(trajectory.closures > t[0]) & (trajectory.closures <= t[-1])]
        pins = np.unique(np.concatenate([[0], np.searchsorted(knot_t, closures).clip(1, n - 1)])).astype(int)
        walk = _bridged(walk, s, pins)
        times.append(knot_t)
        offsets.append(walk[:, :3])
        yaws.append(walk[:, 3])
    return DriftTrack(t=np.concatenate(times), offset=np.concatenate(offsets), yaw=np.concatenate(yaws))

"""Risley-prism lidars (Livox-type sensors, the DJI Zenmuse L1/L2), as data, and their ray kernel.

A Risley scanner sends each of its ``C`` lasers (channels) through a stack of wedge prisms that
turn about the optical axis at their own rates; the beam leaving the last prism draws a rosette
that, when the rates are incommensurate, never repeats and fills the field of view over time.

The pattern is the prisms' optics, not a lookup table. Sensor frame: the optical axis is +z
(what the beam does without prisms), x and y across it. Each channel's beam enters the first
prism tilted ``channel_x_deg`` towards +x and ``channel_y_deg`` towards +y. A prism has one flat
face (normal along the axis) and one face inclined by its wedge angle ``wedge_deg``: the entrance
face (``inclined_face = "entrance"``) or the exit face. At time ``t`` the inclined face's normal,
pointing back against the beam, is (sin w cos phi, sin w sin phi, -cos w) with w the wedge angle
and phi = start_deg + 360 rotation_hz t (counter-clockwise seen from the scene, looking back
along -z). At each face the beam refracts by Snell's law in vector form (air 1.0 to the prism's
``refractive_index`` and back; Born and Wolf, Principles of Optics, 1.5): for a unit direction d,
a unit normal n against it and eta = n1 / n2,

    t = eta d + (eta cos_i - cos_t) n,  cos_i = -n . d,  cos_t = sqrt(1 - eta^2 (1 - cos_i^2)).

This is HELIOS++'s ``RisleyBeamDeflector`` (``Prism::refractBeam``); its scanner XML maps onto
these keys with ``risley_from_helios`` (its forward +y is our +z; a positive ``angleK_deg``
inclines the entrance face, a negative one the exit face; its prism angle at time 0 is our
start_deg - 90 or + 90 degrees).

A spinning head (``spin_hz`` not 0; the Livox Mid-360's 360-degree design): the prisms and lasers
sit in a head that turns about the sensor's z axis. The optics above then live in the head's
frame: its optical axis at elevation ``axis_elevation_deg`` above the sensor's xy plane, at
azimuth psi = 360 spin_hz t, its x across the axis and upwards (a laser tilted towards +x looks
higher), its y = z x x; a direction (dx, dy, dz) of the optics is, in the sensor frame,

    dx (-sin e cos psi, -sin e sin psi, cos e) + dy (sin psi, -cos psi, 0) + dz (cos e cos psi, cos e sin psi, sin e).

Firing: every channel fires ``pulse_rate_hz`` pulses a second, all channels at once, so pulse
``i`` of a pass is channel ``i mod C`` at ``t = (i div C) / pulse_rate_hz``; the scan kernels of
the multi-beam lidars (``scan.multibeam``) read that as a firing sequence of ``C`` beams with
zero offsets every ``1 / pulse_rate_hz`` seconds.

``RISLEY_SCANNERS`` maps a name to a ``RisleyScanner`` made of the TOML files in
``scan/scanners`` whose ``kind`` is ``"risley"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numba as nb
import numpy as np

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ScannerSettingsError
from bimscan.scan.device import RISLEY_KIND, SCANNER_TABLES
from bimscan.scan.kernels import _FAST
from bimscan.scan.multibeam import pulse_origin, sequence_pose
from bimscan.scan.noise import MAX_ANGLE_SIGMA_DEG, MAX_RANGE_SIGMA_M
from bimscan.toml_files import build_dataclass

MAX_PRISMS = 4
MAX_CHANNELS = 64
# Prism angles sampled per prism when a scanner is checked for total internal reflection and its
# field of view measured (a full turn each; every combination of the prisms' angles).
CHECK_STEPS = 72
CHECK_INDEX_MARGIN = 0.01
CHECK_COMBINATIONS = 1e5  # prism angle combinations checked per channel (a grid of about this many)


@dataclass(frozen=True)
class Prism(Checked):
    """One wedge prism of a Risley scanner (see the module docs for the frame)."""

    wedge_deg: float = setting(within=Range(0.0, 60.0, low_open=True), hint="degrees")
    rotation_hz: float = setting(within=Range(-1e4, 1e4), hint="turns per second, + counter-clockwise")
    refractive_index: float = setting(1.5, within=Range(1.0, 4.0, low_open=True))
    inclined_face: Literal["entrance", "exit"] = "entrance"
    start_deg: float = setting(0.0, within=Range(-360.0, 360.0))

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(f"prism {problem}")


@dataclass(frozen=True)
class RisleyScanner(Checked):
    """A Risley-prism lidar (see the module docs for the optics and the firing).

    prisms: the wedge prisms in the order the beam crosses them (1..4). channel_x_deg /
    channel_y_deg: each laser's tilt before the first prism (one entry per channel). pulse_rate_hz:
    pulses per second of each channel. fov_deg: the datasheet's field of view (the full cone
    angle, or its larger extent), a recorded fact the pattern is tested against.
    range_accuracy_m / angle_accuracy_deg: the noise defaults. min_range_m / max_range_m: returns
    are recorded between these. beam_divergence_rad, wavelength_nm: recorded facts (the thin-ray
    path does not use them).
    """

    name: str
    prisms: tuple[Prism, ...]
    kind: Literal["risley"] = RISLEY_KIND
    description: str = ""
    channel_x_deg: tuple[float, ...] = setting((0.0,), each=Range(-30.0, 30.0))
    channel_y_deg: tuple[float, ...] = setting((0.0,), each=Range(-30.0, 30.0))
    pulse_rate_hz: float = setting(100000.0, within=Range(0.0, 1e7, low_open=True))
    fov_deg: float = setting(70.4, within=Range(0.0, 180.0, low_open=True))
    range_accuracy_m: float = setting(0.02, within=Range(0.0, MAX_RANGE_SIGMA_M))
    angle_accuracy_deg: float = setting(0.0, within=Range(0.0, MAX_ANGLE_SIGMA_DEG))
    min_range_m: float = setting(0.5, within=Range(0.0, 1e5))
    max_range_m: float = setting(260.0, within=Range(0.0, 1e5, low_open=True))
    beam_divergence_rad: float = setting(0.0005, within=Range(0.0, 0.1))
    wavelength_nm: float = setting(905.0, within=Range(0.0, 1e5, low_open=True))
    spin_hz: float = setting(0.0, within=Range(-1e3, 1e3), hint="turns per second of a spinning head; 0: none")
    axis_elevation_deg: float = setting(0.0, within=Range(-90.0, 90.0), hint="degrees, a spinning head's optical axis")

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(f"scanner {self.name!r}: {problem}; fix the scanner file")

    @property
    def spinning(self) -> bool:
        """The optics turn on a spinning head (a 360-degree field of view about the sensor's z)."""
        return self.spin_hz != 0.0

    def spin_table(self) -> np.ndarray:
        """(4,) float64 what the kernels read of the head: 1 when it spins, its rate (rad/s), and the
        cosine and sine of its optical axis's elevation."""
        elevation = math.radians(self.axis_elevation_deg)
        return np.array([1.0 if self.spinning else 0.0, 2 * math.pi * self.spin_hz, math.cos(elevation),
                         math.sin(elevation)], dtype=np.float64)

    def check(self) -> None:
        if not 1 <= len(self.prisms) <= MAX_PRISMS:
            raise self.refusal(f"give 1..{MAX_PRISMS} [[prisms]], got {len(self.prisms)}")
        if not 1 <= len(self.channel_x_deg) <= MAX_CHANNELS or len(self.channel_y_deg) != len(self.channel_x_deg):
            raise self.refusal(f"channel_x_deg and channel_y_deg must list the same 1..{MAX_CHANNELS} channels, got "
                               f"{len(self.channel_x_deg)} and {len(self.channel_y_deg)}")
        if not self.min_range_m < self.max_range_m:
            raise self.refusal(f"need min_range_m < max_range_m, got {self.min_range_m} and {self.max_range_m}")
        if self.axis_elevation_deg != 0.0 and not self.spinning:
            raise self.refusal("axis_elevation_deg places a spinning head's optical axis; give spin_hz too, or leave it out")
        # every combination of the prisms' angles on a grid (coarser for more prisms: about
        # CHECK_COMBINATIONS in all), each index CHECK_INDEX_MARGIN higher, so that no angle between
        # the grid's comes near total reflection either (and none turns the beam further than that)
        steps = min(CHECK_STEPS, max(8, int(round(CHECK_COMBINATIONS ** (1 / len(self.prisms))))))
        angles = np.radians(np.arange(steps) * (360.0 / steps))
        grid = np.stack(np.meshgrid(*[angles] * len(self.prisms), indexing="ij"), axis=-1).reshape(-1, len(self.prisms))
        steeper = self.prism_table()
        steeper[:, 1] *= 1 + CHECK_INDEX_MARGIN
        incident = self.incident()
        for channel in range(self.n_beams):
            directions = _refracted(steeper, incident[channel], grid)
            if not np.isfinite(directions).all():
                raise self.refusal(f"channel {channel}'s beam is totally reflected inside a prism at some prism angles, "
                                   f"or comes within {CHECK_INDEX_MARGIN:.0%} of it (wedge angles too steep for the "
                                   "refractive index)")
            if (directions[:, 2] <= 0.0).any():
                raise self.refusal(f"channel {channel}'s beam turns 90 degrees or more off the optical axis (or "
                                   f"would with {CHECK_INDEX_MARGIN:.0%} more refractive index)")

    @property
    def n_beams(self) -> int:
        """Channels: the beams of one firing sequence."""
        return len(self.channel_x_deg)

    @property
    def firing_cycle_us(self) -> float:
        """One firing sequence (every channel once): a channel's pulse period."""
        return 1e6 / self.pulse_rate_hz

    @property
    def firing_offset_us(self) -> tuple[float, ...]:
        """All channels fire at once."""
        return (0.0,) * self.n_beams

    @property
    def total_pulse_rate_hz(self) -> float:
        return self.pulse_rate_hz * self.n_beams

    @property
    def rotation_hz(self) -> None:
        """A Risley scanner has no spinning head (its prisms turn at their own rates)."""
        return None

    def ring_of_beam(self) -> np.ndarray:
        """(C,) uint8: each pulse's ``ring`` is its channel."""
        return np.arange(self.n_beams, dtype=np.uint8)

    def check_rotation(self, rotation_hz: float | None, *, strict: bool = False) -> list[str]:
        return []

    def prism_table(self) -> np.ndarray:
        """(P, 7) float64 per prism: wedge (rad), refractive index, rotation (rad/s), start (rad), 1 when the
        exit face is the inclined one, and the wedge's sine and cosine (not taken per pulse): what the
        kernels read."""
        return np.array([[math.radians(p.wedge_deg), p.refractive_index, 2 * math.pi * p.rotation_hz,
                          math.radians(p.start_deg), 1.0 if p.inclined_face == "exit" else 0.0,
                          math.sin(math.radians(p.wedge_deg)), math.cos(math.radians(p.wedge_deg))]
                         for p in self.prisms], dtype=np.float64)

    def incident(self) -> np.ndarray:
        """(C, 3) float64 each channel's unit direction before the first prism."""
        x, y = np.tan(np.radians(self.channel_x_deg)), np.tan(np.radians(self.channel_y_deg))
        d = np.column_stack([x, y, np.ones_like(x)])
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def directions(self, t: np.ndarray, channel: int = 0) -> np.ndarray:
        """(N, 3) the unit beam directions of ``channel`` at times t (seconds), in the sensor frame
        (a spinning head's turned by its spin)."""
        table = self.prism_table()
        t = np.asarray(t, dtype=np.float64)
        optics = refract_through(self, table[:, 3][None, :] + t[:, None] * table[:, 2][None, :], channel)
        if not self.spinning:
            return optics
        out = np.empty_like(optics)
        _spin_many(optics, t, self.spin_table(), out)
        return out

    def pattern_extent_deg(self, seconds: float = 1.0) -> tuple[float, float]:
        """The pattern's full extent over the pulses of every channel in ``seconds`` (degrees): the
        datasheet's "FOV a x b". Across the optical axis, towards x and towards y (the angle of the
        beam's projection on the xz and yz planes); a spinning head's: in azimuth about z, and in
        elevation."""
        t = np.arange(int(seconds * self.pulse_rate_hz)) / self.pulse_rate_hz
        d = np.concatenate([self.directions(t, channel) for channel in range(self.n_beams)])
        if self.spinning:
            elevation = np.degrees(np.arcsin(np.clip(d[:, 2], -1.0, 1.0)))
            azimuth = np.sort(np.degrees(np.arctan2(d[:, 1], d[:, 0])))
            widest_gap = float(np.diff(np.r_[azimuth, azimuth[0] + 360.0]).max())
            return 360.0 - widest_gap, float(elevation.max() - elevation.min())
        x, y = np.degrees(np.arctan2(d[:, 0], d[:, 2])), np.degrees(np.arctan2(d[:, 1], d[:, 2]))
        return float(x.max() - x.min()), float(y.max() - y.min())

    def elevation_range_deg(self, seconds: float = 1.0) -> tuple[float, float]:
        """The lowest and highest elevation above the sensor's xy plane of every channel's pulses in
        ``seconds`` (degrees): a spinning head's datasheet "vertical FOV -7 to 52 degrees"."""
        t = np.arange(int(seconds * self.pulse_rate_hz)) / self.pulse_rate_hz
        d = np.concatenate([self.directions(t, channel) for channel in range(self.n_beams)])
        elevation = np.degrees(np.arcsin(np.clip(d[:, 2], -1.0, 1.0)))
        return float(elevation.min()), float(elevation.max())


def fov_coverage(directions: np.ndarray, fov_deg: float, spot_deg: float, *, cell_deg: float = 0.02) -> float:
    """The share of a circular field of view ``fov_deg`` wide (full cone angle) that beams along
    ``directions`` (N, 3; sensor frame, optical axis +z) illuminate, each a disc ``spot_deg`` across:
    Livox's "FOV coverage" (the area illuminated by the laser beams over the area of the FOV).

    Livox does not publish the spot it counts; its reference figures for spinning lidars (a 32-line
    lidar over 41 degrees: 21 %, a 64-line one over 27 degrees: 67 %) are the lines' count times
    0.28 degrees (the larger beam divergence of its sensors) over the vertical FOV, so a spot of
    the beam's larger divergence is what reproduces them. Areas are counted on a grid of
    ``cell_deg`` in the azimuthal equidistant projection about the axis (angles off the axis)."""
    d = np.asarray(directions, dtype=np.float64)
    off_axis = np.degrees(np.arccos(np.clip(d[:, 2] / np.linalg.norm(d, axis=1), -1.0, 1.0)))
    azimuth = np.arctan2(d[:, 1], d[:, 0])
    radius = fov_deg / 2.0
    n = int(math.ceil(2.0 * radius / cell_deg)) + 1
    lit = np.zeros((n, n), dtype=np.bool_)
    reach = spot_deg / 2.0 / cell_deg
    span = int(reach) + 1
    di, dj = np.mgrid[-span:span + 1, -span:span + 1]
    disc = di**2 + dj**2 <= reach * reach
    di, dj = di[disc], dj[disc]
    ci = np.rint((off_axis * np.cos(azimuth) + radius) / cell_deg).astype(np.int64)
    cj = np.rint((off_axis * np.sin(azimuth) + radius) / cell_deg).astype(np.int64)
    for start in range(0, len(ci), 200_000):  # bounded memory: the disc's cells of 200k spots at a time
        i = (ci[start:start + 200_000, None] + di[None, :]).ravel()
        j = (cj[start:start + 200_000, None] + dj[None, :]).ravel()
        keep = (i >= 0) & (i < n) & (j >= 0) & (j < n)
        lit[i[keep], j[keep]] = True
    axis = np.arange(n) * cell_deg - radius
    inside = axis[:, None] ** 2 + axis[None, :] ** 2 <= radius * radius
    return float((lit & inside).sum() / inside.sum())


def refract_through(scanner: RisleyScanner, phi: np.ndarray, channel: int) -> np.ndarray:
    """(N, 3) ``channel``'s beam after the prisms turned to angles ``phi`` (N, P) radians (the inclined
    faces' azimuths); NaN rows where a face reflects it totally."""
    return _refracted(scanner.prism_table(), scanner.incident()[channel], phi)


def _refracted(table: np.ndarray, incident: np.ndarray, phi: np.ndarray) -> np.ndarray:
    out = np.empty((len(phi), 3))
    phi = np.asarray(phi, dtype=np.float64)
    _refract_many(np.ascontiguousarray(np.cos(phi)), np.ascontiguousarray(np.sin(phi)), table, incident, out)
    return out


@nb.njit(cache=True, inline="always")
def _refract(dx: float, dy: float, dz: float, nx: float, ny: float, nz: float, eta: float) -> tuple:
    """Snell's law in vector form (see the module docs): d through a face of unit normal n (against d)
    from index n1 to n2 = n1 / eta. NaN when the beam is totally reflected."""
    cos_i = -(dx * nx + dy * ny + dz * nz)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    if sin2_t > 1.0:
        return math.nan, math.nan, math.nan
    k = eta * cos_i - math.sqrt(1.0 - sin2_t)
    tx, ty, tz = eta * dx + k * nx, eta * dy + k * ny, eta * dz + k * nz
    norm = math.sqrt(tx * tx + ty * ty + tz * tz)
    return tx / norm, ty / norm, tz / norm


@nb.njit(cache=True, inline="always")
def _through_prisms(dx: float, dy: float, dz: float, table: np.ndarray, cos_phi: np.ndarray,
                    sin_phi: np.ndarray) -> tuple:
    """A direction through every prism of ``table`` (``RisleyScanner.prism_table``), each turned to
    the azimuth whose cosine and sine are given."""
    for p in range(table.shape[0]):
        sw, cw, index = table[p, 5], table[p, 6], table[p, 1]
        tilted = (sw * cos_phi[p], sw * sin_phi[p], -cw)
        if table[p, 4] == 0.0:  # the entrance face inclined, the exit face flat
            dx, dy, dz = _refract(dx, dy, dz, tilted[0], tilted[1], tilted[2], 1.0 / index)
            dx, dy, dz = _refract(dx, dy, dz, 0.0, 0.0, -1.0, index)
        else:
            dx, dy, dz = _refract(dx, dy, dz, 0.0, 0.0, -1.0, 1.0 / index)
            dx, dy, dz = _refract(dx, dy, dz, tilted[0], tilted[1], tilted[2], index)
    return dx, dy, dz


# Serial on purpose: it runs when the presets are read (at import), and a parallel Numba launch
# there changed the numbers of PyTorch training later in the same process (its threading layer).
@nb.njit(cache=True)
def _refract_many(cos_phi: np.ndarray, sin_phi: np.ndarray, table: np.ndarray, incident: np.ndarray,
                  out: np.ndarray) -> None:
    for i in range(cos_phi.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _through_prisms(incident[0], incident[1], incident[2], table, cos_phi[i],
                                                          sin_phi[i])


@nb.njit(cache=True, inline="always")
def _spun(dx: float, dy: float, dz: float, cos_psi: float, sin_psi: float, spin: np.ndarray) -> tuple:
    """A direction of the optics in the sensor frame of a head turned to azimuth psi (module docs)."""
    ce, se = spin[2], spin[3]
    return (-dx * se * cos_psi + dy * sin_psi + dz * ce * cos_psi,
            -dx * se * sin_psi - dy * cos_psi + dz * ce * sin_psi,
            dx * ce + dz * se)


@nb.njit(cache=True)
def _spin_many(optics: np.ndarray, t: np.ndarray, spin: np.ndarray, out: np.ndarray) -> None:
    for i in range(optics.shape[0]):
        psi = spin[1] * t[i]
        out[i, 0], out[i, 1], out[i, 2] = _spun(optics[i, 0], optics[i, 1], optics[i, 2], math.cos(psi),
                                                math.sin(psi), spin)


@nb.njit(cache=True, parallel=True, fastmath=_FAST)
def risley_rays(first_pulse: np.int64, n: np.int64, n_beams: np.int64, cycle_s: float, t0: float, clock_origin: float,
                prisms: np.ndarray, spin: np.ndarray, incident: np.ndarray, track_t: np.ndarray, track_xyz: np.ndarray,
                track_ypr: np.ndarray, mount_xyz: np.ndarray, mount_rotation: np.ndarray, head_rad_s: float,
                centre: np.ndarray, rays: np.ndarray, origin: np.ndarray, time: np.ndarray) -> None:
    """``multibeam.moving_rays`` for a Risley scanner: pulses first_pulse .. first_pulse + n - 1 of a
    pass starting at ``t0`` (whole firing sequences: one pulse of each of the ``n_beams`` channels
    every ``cycle_s``). Each sequence's direction is its channels' ``incident`` beams (C, 3) through
    the ``prisms`` (``RisleyScanner.prism_table``) turned to their angles at the sequence's time since
    ``clock_origin`` (the trajectory's first time: the prisms start there at ``start_deg`` and keep
    turning between passes; seconds since it keep the angles exact whatever the clock's epoch),
    turned by the spinning head (``RisleyScanner.spin_table``; on the same clock) when it spins,
    then by the sequence's pose."""
    first_sequence = first_pulse // n_beams
    n_sequences = n // n_beams
    n_prisms = prisms.shape[0]
    phase = np.empty((n_sequences, 2, n_prisms))
    for q in nb.prange(n_sequences):
        s = first_sequence + q
        t = t0 + s * cycle_s
        for p in range(n_prisms):
            angle = prisms[p, 3] + prisms[p, 2] * (t - clock_origin)
            phase[q, 0, p] = math.cos(angle)
            phase[q, 1, p] = math.sin(angle)
        k, lx, ly, lz, w00, w01, w02, w10, w11, w12, w20, w21, w22 = sequence_pose(
            t, track_t, track_ypr, mount_xyz, mount_rotation, head_rad_s)
        ox, oy, oz = pulse_origin(t, k, track_t, track_xyz, lx, ly, lz)
        psi = spin[1] * (t - clock_origin)
        cos_psi, sin_psi = math.cos(psi), math.sin(psi)
        for b in range(n_beams):
            i = q * n_beams + b
            dx, dy, dz = _through_prisms(incident[b, 0], incident[b, 1], incident[b, 2], prisms, phase[q, 0],
                                         phase[q, 1])
            if spin[0] != 0.0:
                dx, dy, dz = _spun(dx, dy, dz, cos_psi, sin_psi, spin)
            origin[i, 0] = ox
            origin[i, 1] = oy
            origin[i, 2] = oz
            rays[i, 0] = ox - centre[0]
            rays[i, 1] = oy - centre[1]
            rays[i, 2] = oz - centre[2]
            rays[i, 3] = w00 * dx + w01 * dy + w02 * dz
            rays[i, 4] = w10 * dx + w11 * dy + w12 * dz
            rays[i, 5] = w20 * dx + w21 * dy + w22 * dz
            time[i] = t


RISLEY_SCANNERS: dict[str, RisleyScanner] = {
    name: build_dataclass(RisleyScanner, table, where=f"built-in scanner {name}")
    for name, table in SCANNER_TABLES.items() if table.get("kind") == RISLEY_KIND
}

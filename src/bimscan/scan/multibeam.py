"""Multi-beam spinning lidars (the sensors of handheld and backpack scanners), as data, and their
fused ray kernels.

A multi-beam lidar spins its head about its own axis at ``rotation_hz`` and fires its ``N`` beams
in a fixed sequence: beam ``b`` fires ``firing_offset_us[b]`` after the start of each firing
sequence, one sequence every ``firing_cycle_us`` (the VLP-16 fires its 16 lasers 2.304 us apart
and starts a new sequence every 55.296 us). So pulse ``i`` of a pass is beam ``b = i mod N`` of
sequence ``s = i div N``; it fires at ``t = s * cycle + offset[b]`` and leaves the sensor at the
beam's elevation ``beam_elevation_deg[b]`` and at azimuth ``360 * rotation_hz * t +
beam_azimuth_offset_deg[b]`` about the spin axis (azimuth grows counter-clockwise seen from
above the sensor, from its +x axis). Per-point time and beam are therefore exact, and a pass of
``T`` seconds fires ``N * floor(T / cycle)`` pulses whatever the rotation rate: a faster head
spreads the same pulses over more turns.

``LIDARS`` maps a name to a ``MultiBeamScanner`` made of the TOML files in ``scan/scanners``
whose ``kind`` is ``"multibeam"`` (``bimscan.scan.device.SCANNER_TABLES``, which reads the folder;
the rotating-mirror TLS files are ``bimscan.scan.device.SCANNERS``, the Risley-prism lidars
``bimscan.scan.risley.RISLEY_SCANNERS``; ``bimscan.scan.lidars.load_lidar`` reads any lidar).
The kernels turn a chunk of pulses into world rays along a trajectory (``moving_rays``) and the
engine's hits into labelled points with each pulse's beam origin (``finish_moving_hits``); both
are Numba-parallel over fixed blocks, so outputs do not depend on thread counts or chunking.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numba as nb
import numpy as np

from bimscan.constraints import Checked, Range, setting
from bimscan.errors import ScannerSettingsError
from bimscan.scan.kernels import _BLOCK, _FAST, _keep, hit_point
from bimscan.scan.noise import MAX_ANGLE_SIGMA_DEG, MAX_RANGE_SIGMA_M
from bimscan.scan.device import MULTIBEAM_KIND, SCANNER_TABLES
from bimscan.toml_files import build_dataclass


@dataclass(frozen=True)
class MultiBeamScanner(Checked):
    """A spinning multi-beam lidar (see the module docs for the firing model).

    beam_elevation_deg, beam_azimuth_offset_deg, firing_offset_us: one entry per beam, in firing
    order (the laser ids of the datasheet). firing_cycle_us: period of one firing sequence.
    rotation_hz_min / rotation_hz_max: the head's rotation rates; rotation_hz: the default.
    range_accuracy_m / angle_accuracy_deg: the noise defaults (``NoiseModel.resolved``).
    min_range_m / max_range_m: returns are recorded between these. beam_divergence_rad and
    wavelength_nm are recorded facts (the thin-ray path does not use them).
    """

    name: str
    kind: Literal["multibeam"] = MULTIBEAM_KIND
    description: str = ""
    beam_elevation_deg: tuple[float, ...] = setting((), each=Range(-90.0, 90.0))
    beam_azimuth_offset_deg: tuple[float, ...] = setting((), each=Range(-360.0, 360.0))
    firing_offset_us: tuple[float, ...] = setting((), each=Range(0.0, 1e6))
    firing_cycle_us: float = setting(55.296, within=Range(0.0, 1e6, low_open=True))
    rotation_hz_min: float = setting(5.0, within=Range(0.0, 1e3, low_open=True))
    rotation_hz_max: float = setting(20.0, within=Range(0.0, 1e3, low_open=True))
    rotation_hz: float = setting(10.0, within=Range(0.0, 1e3, low_open=True))
    range_accuracy_m: float = setting(0.03, within=Range(0.0, MAX_RANGE_SIGMA_M))
    angle_accuracy_deg: float = setting(0.0, within=Range(0.0, MAX_ANGLE_SIGMA_DEG))
    min_range_m: float = setting(0.5, within=Range(0.0, 1e5))
    max_range_m: float = setting(100.0, within=Range(0.0, 1e5, low_open=True))
    beam_divergence_rad: float = setting(0.003, within=Range(0.0, 0.1))
    wavelength_nm: float = setting(903.0, within=Range(0.0, 1e5, low_open=True))

    def check(self) -> None:
        n = len(self.beam_elevation_deg)
        if not 1 <= n <= 256:
            raise self.refusal(f"beam_elevation_deg must list 1..256 beams, got {n}")
        if len(self.beam_azimuth_offset_deg) != n or len(self.firing_offset_us) != n:
            raise self.refusal(f"beam_azimuth_offset_deg and firing_offset_us must have one entry per beam ({n}), got "
                               f"{len(self.beam_azimuth_offset_deg)} and {len(self.firing_offset_us)}")
        if not all(f < self.firing_cycle_us for f in self.firing_offset_us):
            raise self.refusal(f"every firing_offset_us must lie in [0, firing_cycle_us = {self.firing_cycle_us:g})")
        if not self.rotation_hz_min <= self.rotation_hz <= self.rotation_hz_max:
            raise self.refusal(f"need rotation_hz_min <= rotation_hz <= rotation_hz_max, got {self.rotation_hz_min}, "
                               f"{self.rotation_hz}, {self.rotation_hz_max}")
        if not self.min_range_m < self.max_range_m:
            raise self.refusal(f"need min_range_m < max_range_m, got {self.min_range_m} and {self.max_range_m}")

    def refusal(self, problem: str) -> ScannerSettingsError:
        return ScannerSettingsError(f"scanner {self.name!r}: {problem}; fix the scanner file")

    @property
    def n_beams(self) -> int:
        return len(self.beam_elevation_deg)

    @property
    def pulse_rate_hz(self) -> float:
        """Pulses per second (single return): beams / firing cycle."""
        return self.n_beams / (self.firing_cycle_us * 1e-6)

    def ring_of_beam(self) -> np.ndarray:
        """(N,) uint8: each beam's ring, its rank by elevation (0 = lowest; the ROS drivers' ``ring``)."""
        order = np.argsort(np.asarray(self.beam_elevation_deg), kind="stable")
        ring = np.empty(self.n_beams, dtype=np.uint8)
        ring[order] = np.arange(self.n_beams)
        return ring

    def check_rotation(self, rotation_hz: float, *, strict: bool = False) -> list[str]:
        """A warning line when ``rotation_hz`` (a possible rate: ``MobileScan`` declares what is)
        is outside the device's rates (an error under ``strict``)."""
        if self.rotation_hz_min <= rotation_hz <= self.rotation_hz_max:
            return []
        line = (f"rotation_hz = {rotation_hz:g} is outside {self.name}'s rotation rates "
                f"{self.rotation_hz_min:g}..{self.rotation_hz_max:g} Hz")
        if strict:
            raise ScannerSettingsError(f"outside the device's limits (--strict): {line}")
        return [line]


LIDARS: dict[str, MultiBeamScanner] = {
    name: build_dataclass(MultiBeamScanner, table, where=f"built-in scanner {name}")
    for name, table in SCANNER_TABLES.items() if table.get("kind") == MULTIBEAM_KIND
}


@nb.njit(cache=True, inline="always")
def _rotation_zyx(yaw: float, pitch: float, roll: float) -> tuple:
    """Rows of R = Rz(yaw) Ry(pitch) Rx(roll) (radians): the platform's body -> world rotation."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    return (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
            -sp, cp * sr, cp * cr)


@nb.njit(cache=True, inline="always")
def sequence_pose(t_seq: float, track_t: np.ndarray, track_ypr: np.ndarray, mount_xyz: np.ndarray,
                  m: np.ndarray, head_rad_s: float) -> tuple:
    """The sensor's pose at the start of a firing sequence at ``t_seq``: the trajectory sample k
    before it, the lever arm (lx, ly, lz) turned into the world, and the rows of the sensor ->
    world rotation R_platform R_head R_mount (w00 .. w22). The platform's orientation is
    interpolated linearly between samples (yaw, pitch, roll; see ``moving_rays``)."""
    k_last = len(track_t) - 1
    k = np.searchsorted(track_t, t_seq, side="right") - 1
    k = min(max(k, 0), k_last - 1) if k_last > 0 else 0
    k1 = min(k + 1, k_last)
    span = track_t[k1] - track_t[k]
    w = min(max((t_seq - track_t[k]) / span, 0.0), 1.0) if span > 0 else 0.0
    r = _rotation_zyx(track_ypr[k, 0] + w * (track_ypr[k1, 0] - track_ypr[k, 0]),
                      track_ypr[k, 1] + w * (track_ypr[k1, 1] - track_ypr[k, 1]),
                      track_ypr[k, 2] + w * (track_ypr[k1, 2] - track_ypr[k, 2]))
    head = head_rad_s * t_seq
    ch, sh = math.cos(head), math.sin(head)
    # the lever arm turned by the head, then by the platform
    ax = ch * mount_xyz[0] - sh * mount_xyz[1]
    ay = sh * mount_xyz[0] + ch * mount_xyz[1]
    az_ = mount_xyz[2]
    lx = r[0] * ax + r[1] * ay + r[2] * az_
    ly = r[3] * ax + r[4] * ay + r[5] * az_
    lz = r[6] * ax + r[7] * ay + r[8] * az_
    # sensor -> world rotation of this sequence: R_platform R_head R_mount
    a00 = ch * m[0, 0] - sh * m[1, 0]
    a01 = ch * m[0, 1] - sh * m[1, 1]
    a02 = ch * m[0, 2] - sh * m[1, 2]
    a10 = sh * m[0, 0] + ch * m[1, 0]
    a11 = sh * m[0, 1] + ch * m[1, 1]
    a12 = sh * m[0, 2] + ch * m[1, 2]
    a20, a21, a22 = m[2, 0], m[2, 1], m[2, 2]
    return (k, lx, ly, lz,
            r[0] * a00 + r[1] * a10 + r[2] * a20, r[0] * a01 + r[1] * a11 + r[2] * a21,
            r[0] * a02 + r[1] * a12 + r[2] * a22, r[3] * a00 + r[4] * a10 + r[5] * a20,
            r[3] * a01 + r[4] * a11 + r[5] * a21, r[3] * a02 + r[4] * a12 + r[5] * a22,
            r[6] * a00 + r[7] * a10 + r[8] * a20, r[6] * a01 + r[7] * a11 + r[8] * a21,
            r[6] * a02 + r[7] * a12 + r[8] * a22)


@nb.njit(cache=True, inline="always")
def pulse_origin(t: float, k: np.int64, track_t: np.ndarray, track_xyz: np.ndarray, lx: float, ly: float,
                 lz: float) -> tuple:
    """A pulse's beam origin at its own time ``t`` (on or after sample k, its sequence's): the
    platform's position, linear between samples, plus the lever arm of its sequence."""
    k_last = len(track_t) - 1
    kk = k
    while kk < k_last - 1 and track_t[kk + 1] <= t:  # a sample may fall inside the sequence
        kk += 1
    kk1 = min(kk + 1, k_last)
    span = track_t[kk1] - track_t[kk]
    wt = min(max((t - track_t[kk]) / span, 0.0), 1.0) if span > 0 else 0.0
    return (track_xyz[kk, 0] + wt * (track_xyz[kk1, 0] - track_xyz[kk, 0]) + lx,
            track_xyz[kk, 1] + wt * (track_xyz[kk1, 1] - track_xyz[kk, 1]) + ly,
            track_xyz[kk, 2] + wt * (track_xyz[kk1, 2] - track_xyz[kk, 2]) + lz)


@nb.njit(cache=True, parallel=True, fastmath=_FAST)
def moving_rays(first_pulse: np.int64, n: np.int64, n_beams: np.int64, cycle_s: float, t0: float,
                firing_offset_s: np.ndarray, cos_el: np.ndarray, sin_el: np.ndarray, azimuth_offset: np.ndarray,
                rotation_rad_s: float, track_t: np.ndarray, track_xyz: np.ndarray, track_ypr: np.ndarray,
                mount_xyz: np.ndarray, mount_rotation: np.ndarray, head_rad_s: float, centre: np.ndarray,
                rays: np.ndarray, origin: np.ndarray, time: np.ndarray) -> None:
    """Fill rays (n, 6) float32 (engine frame: world minus ``centre``), origin (n, 3) float64 world
    beam origins and time (n,) float64 for pulses first_pulse .. first_pulse + n - 1 of a pass that
    starts at ``t0`` (``first_pulse`` and ``n`` whole firing sequences).

    The platform's position at a pulse's time is interpolated linearly between the trajectory
    samples (track_t (K,) seconds, track_xyz (K, 3) world metres); its orientation (track_ypr
    (K, 3) yaw, pitch, roll in radians, unwrapped) and the head's turn are taken once per firing
    sequence, at its start: within one sequence (55 us for the VLP-16) a 60 deg/s turn moves the
    beam by 0.003 degrees, far below the lidar's angular step. The beam's spin azimuth, its time
    and the platform's position are exact per pulse. The sensor sits at ``mount_xyz`` in the
    platform's frame (x forward, y left, z up), turned by ``mount_rotation`` (3, 3), and by a head
    turning about the platform's z at ``head_rad_s`` (0: fixed mount).
    """
    first_sequence = first_pulse // n_beams
    # each beam's direction in the sensor frame at the start of its sequence's spin (its firing
    # offset's turn and its azimuth offset): a pulse's direction is then that turned by the
    # sequence's spin and pose, with no trigonometry per pulse
    beam = np.empty((n_beams, 3))
    for b in range(n_beams):
        turn = rotation_rad_s * firing_offset_s[b] + azimuth_offset[b]
        beam[b, 0] = cos_el[b] * math.cos(turn)
        beam[b, 1] = cos_el[b] * math.sin(turn)
        beam[b, 2] = sin_el[b]
    for q in nb.prange(n // n_beams):
        s = first_sequence + q
        t_seq = t0 + s * cycle_s
        k, lx, ly, lz, w00, w01, w02, w10, w11, w12, w20, w21, w22 = sequence_pose(
            t_seq, track_t, track_ypr, mount_xyz, mount_rotation, head_rad_s)
        # ... then by the spin (R_spin about the sensor's z)
        spin = rotation_rad_s * (s * cycle_s)
        cs, ss = math.cos(spin), math.sin(spin)
        v00, v01 = w00 * cs + w01 * ss, w01 * cs - w00 * ss
        v10, v11 = w10 * cs + w11 * ss, w11 * cs - w10 * ss
        v20, v21 = w20 * cs + w21 * ss, w21 * cs - w20 * ss
        for b in range(n_beams):
            i = q * n_beams + b
            t = t0 + (s * cycle_s + firing_offset_s[b])
            ox, oy, oz = pulse_origin(t, k, track_t, track_xyz, lx, ly, lz)
            # rotations only: the direction stays a unit vector (to 1e-15)
            wx = v00 * beam[b, 0] + v01 * beam[b, 1] + w02 * beam[b, 2]
            wy = v10 * beam[b, 0] + v11 * beam[b, 1] + w12 * beam[b, 2]
            wz = v20 * beam[b, 0] + v21 * beam[b, 1] + w22 * beam[b, 2]
            origin[i, 0] = ox
            origin[i, 1] = oy
            origin[i, 2] = oz
            rays[i, 0] = ox - centre[0]
            rays[i, 1] = oy - centre[1]
            rays[i, 2] = oz - centre[2]
            rays[i, 3] = wx
            rays[i, 4] = wy
            rays[i, 5] = wz
            time[i] = t


@nb.njit(cache=True, parallel=True, fastmath=_FAST)
def finish_moving_hits(t_hit: np.ndarray, triangle: np.ndarray, rays: np.ndarray, origin: np.ndarray,
                       pulse_time: np.ndarray, first_pulse: np.int64, n_beams: np.int64, ring_of_beam: np.ndarray,
                       face_component: np.ndarray, face_label: np.ndarray, face_brightness: np.ndarray,
                       min_range: float, max_range: float, key: np.uint64, range_sigma_m: float,
                       angle_sigma_rad: float, intensity_ref_m: float, pass_id: int,
                       xyz: np.ndarray, label: np.ndarray, component: np.ndarray, station: np.ndarray,
                       intensity: np.ndarray, time: np.ndarray, ring: np.ndarray, sensor: np.ndarray) -> int:
    """Turn a chunk's hits into points (``kernels.finish_hits`` with a beam origin per pulse); returns
    how many of the first rows of the outputs were filled. Noise is drawn per pulse number of the
    pass (the same deviates as a TLS station's pulse of that number), so chunking changes nothing."""
    n = len(t_hit)
    n_faces = len(face_component)
    n_blocks = (n + _BLOCK - 1) // _BLOCK
    counts = np.zeros(n_blocks + 1, dtype=np.int64)
    for blk in nb.prange(n_blocks):
        c = 0
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            if _keep(t_hit[i], triangle[i], n_faces, min_range, max_range):
                c += 1
        counts[blk + 1] = c
    for blk in range(n_blocks):
        counts[blk + 1] += counts[blk]
    noisy = range_sigma_m > 0.0 or angle_sigma_rad > 0.0
    for blk in nb.prange(n_blocks):
        out = counts[blk]
        beam = (first_pulse + blk * _BLOCK) % n_beams - 1  # counted along, not divided per pulse
        for i in range(blk * _BLOCK, min(n, (blk + 1) * _BLOCK)):
            beam = beam + 1 if beam + 1 < n_beams else 0
            t = t_hit[i]
            tri = triangle[i]
            if not _keep(t, tri, n_faces, min_range, max_range):
                continue
            rx, ry, rz, value = hit_point(t, tri, rays, i, first_pulse + i, key, noisy, range_sigma_m,
                                          angle_sigma_rad, intensity_ref_m, face_brightness)
            xyz[out, 0] = origin[i, 0] + rx
            xyz[out, 1] = origin[i, 1] + ry
            xyz[out, 2] = origin[i, 2] + rz
            component[out] = face_component[tri]
            label[out] = face_label[tri]
            intensity[out] = value
            station[out] = pass_id
            time[out] = pulse_time[i]
            ring[out] = ring_of_beam[beam]
            sensor[out, 0] = origin[i, 0]
            sensor[out, 1] = origin[i, 1]
            sensor[out, 2] = origin[i, 2]
            out += 1
    return counts[n_blocks]

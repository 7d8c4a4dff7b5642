"""The pulse sequence of a rotating-mirror TLS station (the polygon-mirror model of HELIOS++).

Pulse ``i`` of a station is fired at ``t = i / pulse_freq``. The polygon mirror advances by
``mirror_sweep * scan_freq / pulse_freq`` degrees per pulse and starts each sweep (line) at
``-mirror_sweep / 2``; only pulses whose mirror angle lies in the elevation window emit, and that
angle is the beam's elevation. The head turns ``head_deg_per_s / pulse_freq`` degrees per pulse,
from ``head_start_deg`` to ``head_stop_deg``. So line ``k`` emits the contiguous pulse indices
``[ceil((k + lo) / dphase), ceil((k + hi) / dphase))`` with ``dphase = scan_freq / pulse_freq``
and ``lo, hi`` the window as fractions of the sweep, and a station emits
``pulse_freq * duration * window / sweep`` pulses (up to rounding at line ends).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from bimscan.scan.device import ScannerModel, ScanSettings


@dataclass(frozen=True)
class LineChunk:
    """The emitting pulses of mirror lines ``first_line .. first_line + L - 1`` (one scan chunk).

    start, stop: (L,) int64 pulse index range [start, stop) of each line; offsets: (L,) int64
    row where each line's rays begin in the chunk; n: rays in all (the sum of stop - start).
    """

    first_line: int
    start: np.ndarray
    stop: np.ndarray
    offsets: np.ndarray
    n: int


# Absorbs float rounding at exact line/window boundaries (a phase of 1/3 computed as 0.333...3).
_EPS = 1e-7


@dataclass(frozen=True)
class PulsePattern:
    """The pulse schedule of one station, independent of the station's position."""

    pulse_freq_hz: float
    dphase: float  # fraction of a sweep per pulse
    window_lo: float  # emitting window as fractions of the sweep
    window_hi: float
    sweep_deg: float
    total_pulses: int  # pulses fired while the head turns (emitting or not)
    head_start_deg: float
    head_deg_per_pulse: float

    @staticmethod
    def of(settings: ScanSettings, scanner: ScannerModel) -> PulsePattern:
        low, high = settings.window(scanner)
        half = scanner.mirror_sweep_deg / 2
        return PulsePattern(
            pulse_freq_hz=settings.pulse_freq_hz,
            dphase=settings.scan_freq_hz / settings.pulse_freq_hz,
            window_lo=(low + half) / scanner.mirror_sweep_deg,
            window_hi=(high + half) / scanner.mirror_sweep_deg,
            sweep_deg=scanner.mirror_sweep_deg,
            total_pulses=int(round(settings.duration_s() * settings.pulse_freq_hz)),
            head_start_deg=settings.head_start_deg,
            head_deg_per_pulse=settings.head_deg_per_s / settings.pulse_freq_hz,
        )

    @property
    def n_lines(self) -> int:
        """Lines that start before the last pulse."""
        return int(math.floor((self.total_pulses - 1) * self.dphase + _EPS)) + 1 if self.total_pulses else 0

    def line_pulses(self, first_line: int, stop_line: int) -> tuple[np.ndarray, np.ndarray]:
        """Emitting pulse index ranges [start, stop) (int64) of lines first_line..stop_line-1."""
        k = np.arange(first_line, stop_line, dtype=np.float64)
        start = np.ceil((k + self.window_lo) / self.dphase - _EPS).astype(np.int64)
        stop = np.ceil((k + self.window_hi) / self.dphase - _EPS).astype(np.int64)
        np.clip(start, 0, self.total_pulses, out=start)
        np.clip(stop, 0, self.total_pulses, out=stop)
        return start, np.maximum(stop, start)

    def count(self) -> int:
        """Emitted pulses of the whole station (exact, line by line)."""
        total = 0
        for first in range(0, self.n_lines, 1 << 20):
            start, stop = self.line_pulses(first, min(self.n_lines, first + (1 << 20)))
            total += int((stop - start).sum())
        return total

    def phase(self, pulse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(line, fraction of the sweep) of pulse indices, with the same boundary rule as line_pulses."""
        shifted = pulse * self.dphase + _EPS * self.dphase
        line = np.floor(shifted)
        return line.astype(np.int64), shifted - line

    def elevation_deg(self, pulse: np.ndarray) -> np.ndarray:
        """Elevation of pulse indices (degrees), from the mirror angle."""
        _, fraction = self.phase(pulse)
        return -self.sweep_deg / 2 + self.sweep_deg * fraction

    def chunks(self, pulses_per_chunk: int) -> list[tuple[int, int]]:
        """Line ranges holding about ``pulses_per_chunk`` emitted pulses each (fixed by the pattern alone)."""
        per_line = max(1.0, (self.window_hi - self.window_lo) / self.dphase)
        lines = max(1, int(pulses_per_chunk // per_line))
        return [(k, min(self.n_lines, k + lines)) for k in range(0, self.n_lines, lines)]

    def line_chunks(self, pulses_per_chunk: int) -> Iterator[LineChunk]:
        """The station's emitting pulses as chunks of lines (``chunks``), each with its lines' pulse
        ranges and row offsets; chunks that emit nothing are left out."""
        for first_line, stop_line in self.chunks(pulses_per_chunk):
            start, stop = self.line_pulses(first_line, stop_line)
            counts = stop - start
            offsets = np.zeros(len(counts), dtype=np.int64)
            np.cumsum(counts[:-1], out=offsets[1:])
            n = int(counts.sum())
            if n:
                yield LineChunk(first_line=first_line, start=start, stop=stop, offsets=offsets, n=n)

    def fill_rays(self, lines: LineChunk, heading_deg: float, origin: np.ndarray, rays: np.ndarray,
                  pulse: np.ndarray) -> None:
        """Fill ``rays`` (n, 6) float32 and ``pulse`` (n,) int64 with the chunk's rays from ``origin``
        (float32, the engine's local frame), as the scanner casts them (``kernels.generate_rays``)."""
        from bimscan.scan.kernels import generate_rays  # here: Numba stays off the settings' import path

        generate_rays(lines.start, lines.stop, lines.offsets, lines.first_line, self.dphase, self.sweep_deg,
                      self.head_start_deg, self.head_deg_per_pulse, heading_deg, origin, rays, pulse)

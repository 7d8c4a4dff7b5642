"""The polygon-mirror pulse sequence: counts, lines, elevations."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from bimscan.scan.pattern import PulsePattern
from bimscan.scan.device import PRESETS, SCANNERS, ScanSettings

VZ400 = SCANNERS["riegl_vz400"]


def test_a_station_emits_pulse_freq_times_duration_times_window_over_sweep():
    # 240 pulses per line, 100 of them in the 100 degree window, 1000 lines in 10 s
    settings = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36)
    pattern = PulsePattern.of(settings, VZ400)
    assert pattern.count() == 100_000 == settings.expected_pulses(VZ400)
    start, stop = pattern.line_pulses(0, 3)
    assert (stop - start).tolist() == [100, 100, 100]
    assert start.tolist() == [80, 320, 560]  # the window opens 80 pulses (80 deg) into each sweep


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_counts_match_the_formula_to_one_pulse_per_phase_period(name):
    # The mirror keeps its phase from line to line, so the emitted count is the number of points
    # of the lattice {i * scan_freq / pulse_freq mod 1} inside the window: exact per repeat
    # period of that lattice up to one pulse.
    from fractions import Fraction

    settings = PRESETS[name]
    pattern = PulsePattern.of(settings, VZ400)
    period = Fraction(int(settings.scan_freq_hz), int(settings.pulse_freq_hz)).denominator
    error = abs(pattern.count() - settings.expected_pulses(VZ400))
    assert error <= pattern.total_pulses / period + 1
    assert error / settings.expected_pulses(VZ400) < 0.005


@hsettings(max_examples=60, deadline=None)
@given(pulse=st.sampled_from([50000, 100000, 300000, 500000]), lines=st.floats(10, 400), head=st.floats(5, 60))
def test_emitting_pulses_are_exactly_those_inside_the_window(pulse, lines, head):
    settings = ScanSettings(pulse_freq_hz=pulse, scan_freq_hz=lines, head_deg_per_s=head, head_stop_deg=20)
    pattern = PulsePattern.of(settings, VZ400)
    start, stop = pattern.line_pulses(0, pattern.n_lines)
    emitted = np.concatenate([np.arange(a, b) for a, b in zip(start, stop)])
    _, fraction = pattern.phase(np.arange(pattern.total_pulses))
    inside = np.flatnonzero((fraction >= pattern.window_lo) & (fraction < pattern.window_hi))
    assert np.array_equal(emitted, inside)


def test_chunks_cover_every_line_once():
    pattern = PulsePattern.of(PRESETS["exp3"], VZ400)
    chunks = pattern.chunks(100_000)
    assert chunks[0][0] == 0 and chunks[-1][1] == pattern.n_lines
    assert all(a[1] == b[0] for a, b in zip(chunks, chunks[1:]))


def test_line_chunks_hold_every_emitting_pulse_once_and_their_rays_are_the_whole_stations():
    settings = ScanSettings(pulse_freq_hz=24000, scan_freq_hz=100, head_deg_per_s=36)
    pattern = PulsePattern.of(settings, VZ400)
    chunks = list(pattern.line_chunks(7_000))
    assert len(chunks) > 1 and sum(c.n for c in chunks) == pattern.count()
    for c in chunks:
        assert c.offsets[0] == 0 and c.n == int((c.stop - c.start).sum())
        assert np.array_equal(c.offsets[1:], np.cumsum(c.stop - c.start)[:-1])
    origin = np.array([0.5, -1.0, 1.6], dtype=np.float32)
    whole = next(pattern.line_chunks(1 << 62))
    assert whole.n == pattern.count()
    rays, pulse = np.empty((whole.n, 6), np.float32), np.empty(whole.n, np.int64)
    pattern.fill_rays(whole, 30.0, origin, rays, pulse)
    parts = []
    for c in chunks:
        part, part_pulse = np.empty((c.n, 6), np.float32), np.empty(c.n, np.int64)
        pattern.fill_rays(c, 30.0, origin, part, part_pulse)
        parts.append(part)
    assert np.array_equal(np.concatenate(parts), rays)  # chunking does not change a ray
    assert np.allclose(rays[:, :3], origin) and np.allclose(np.linalg.norm(rays[:, 3:], axis=1), 1, atol=1e-5)

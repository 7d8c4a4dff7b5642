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

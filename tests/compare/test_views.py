"""Where a station stood, from the order and times of its pulses (``bimscan.compare.views``), and
which parts of a large scan the first look reads (``bimscan.compare.progress._more_runs``)."""

from __future__ import annotations

import numpy as np

from bimscan.compare.progress import STATION_RUNS, _more_runs
from bimscan.compare.views import PulseRun, refine_by_lines

ORIGIN = np.array([2.0, 3.0, 1.6])


def _mirror_lines(headings_deg: np.ndarray, *, pulses: int = 600, step_deg: float = 0.1, noise_deg: float = 0.03,
                  seed: int = 0) -> PulseRun:
    """One run of a rotating-mirror scanner at ``ORIGIN`` in a 12 x 12 x 3 m room: a vertical line of
    ``pulses`` pulses per heading, equally spaced in elevation and time, with angular noise."""
    rng = np.random.default_rng(seed)
    xyz, times = [], []
    for i, heading in enumerate(np.radians(headings_deg)):
        elevation = np.radians(-60 + step_deg * np.arange(pulses)) + np.radians(noise_deg) * rng.standard_normal(pulses)
        direction = np.stack([np.cos(elevation) * np.cos(heading), np.cos(elevation) * np.sin(heading),
                              np.sin(elevation)], axis=1)
        # the nearest of floor (z 0), ceiling (z 3) and the walls at +-6 m around the room's centre
        with np.errstate(divide="ignore"):
            ranges = np.stack([np.where(direction[:, 2] < 0, -ORIGIN[2] / direction[:, 2], np.inf),
                               np.where(direction[:, 2] > 0, (3.0 - ORIGIN[2]) / direction[:, 2], np.inf),
                               np.abs(6.0 / np.where(direction[:, 0] != 0, direction[:, 0], 1e-12)),
                               np.abs(6.0 / np.where(direction[:, 1] != 0, direction[:, 1], 1e-12))], axis=1)
        xyz.append(ORIGIN + direction * ranges.min(axis=1)[:, None])
        times.append(i * 0.01 + np.arange(pulses) * 2e-6)
    return PulseRun(xyz=np.concatenate(xyz), time=np.concatenate(times))


def test_mirror_lines_of_many_headings_place_the_origin_to_millimetres_with_times_and_without():
    runs = [_mirror_lines(np.arange(k * 40.0, k * 40.0 + 2.0, 0.5), seed=k) for k in range(9)]
    timed = refine_by_lines(runs, ORIGIN + [0.3, -0.2, -1.2])
    assert timed is not None
    assert np.abs(timed[0] - ORIGIN).max() < 0.003 and timed[1] > 0.95
    untimed = refine_by_lines([PulseRun(xyz=r.xyz, time=None) for r in runs], ORIGIN + [0.3, -0.2, 0.4])
    assert untimed is not None and np.abs(untimed[0][:2] - ORIGIN[:2]).max() < 0.003


def test_lines_that_agree_on_a_direction_only_do_not_place_the_origin():
    # every mirror line within two degrees of one heading, and one stray straight run elsewhere: the
    # lines cannot say where along that heading the scanner stood
    runs = [_mirror_lines(np.arange(30.0, 32.0, 0.25), seed=1)]
    stray = np.column_stack([np.linspace(-3, 3, 200), np.full(200, -4.0), np.zeros(200)])
    runs.append(PulseRun(xyz=stray, time=np.arange(200) * 2e-6))
    assert refine_by_lines(runs, ORIGIN) is None


def test_a_station_met_in_few_runs_is_looked_at_again_over_its_stretch_of_the_file():
    met = [(0, 100, np.array([0])), (1000, 100, np.array([0, 1])), (2000, 100, np.array([2])),
           (3000, 100, np.array([2]))]
    runs = _more_runs(met, 4000, 100)
    firsts = [a for a, _ in runs]
    assert firsts == sorted(firsts)
    ends = [a + n for a, n in runs]
    assert all(e <= b for e, b in zip(ends, firsts[1:]))  # disjoint
    read = [(a, a + n) for a, n, _ in met]
    assert not any(a < e and s < b for s, e in zip(firsts, ends) for a, b in read)  # none read twice
    # station 1 was met once, in the run at 1000: its new runs lie between its neighbours' runs
    assert sum(1 for s in firsts if 100 <= s < 2000) >= STATION_RUNS - 2
    assert all(n == 100 for _, n in runs) and max(ends) <= 4000

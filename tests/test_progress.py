"""The stage clock sums each step's time over every time it ran, and times a stream's production only."""

from __future__ import annotations

import time

import pytest

from bimscan.progress import StageClock


def test_a_step_sums_its_runs_and_counts_a_run_that_raised():
    clock = StageClock()
    for _ in range(2):
        with clock.step("sleep"):
            time.sleep(0.02)
    with pytest.raises(ValueError), clock.step("failing"):
        time.sleep(0.01)
        raise ValueError("stop")
    assert 0.04 <= clock.seconds["sleep"] < 0.5
    assert 0.01 <= clock.seconds["failing"] < 0.5
    clock.add("sleep", 1.0)
    assert clock.seconds["sleep"] >= 1.04


def test_a_timed_stream_counts_producing_items_not_consuming_them():
    def slow_items():
        for k in range(3):
            time.sleep(0.02)  # producing
            yield k

    clock = StageClock()
    items = []
    for item in clock.timed("produce", slow_items()):
        time.sleep(0.05)  # consuming: not counted
        items.append(item)
    assert items == [0, 1, 2]
    assert 0.06 <= clock.seconds["produce"] < 0.2  # with the consumer's time it would be 0.21 or more

"""The stage clock sums each step's time over every time it ran, and times a stream's production only.

The clock is the test's own (``FakeClock``: time passes when the test says so), so the sums are exact
whatever the machine does meanwhile; a busy machine stretched the sleeps these tests once timed."""

from __future__ import annotations

import time

import pytest

from bimscan.progress import StageClock


class FakeClock:
    """Seconds that pass only by ``advance``."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += seconds


def test_a_step_sums_its_runs_and_counts_a_run_that_raised():
    fake = FakeClock()
    clock = StageClock(clock=fake)
    for seconds in (2.0, 3.0):
        with clock.step("work"):
            fake.advance(seconds)
        fake.advance(50.0)  # between the runs: not the step's
    with pytest.raises(ValueError), clock.step("failing"):
        fake.advance(0.25)
        raise ValueError("stop")
    assert clock.seconds == {"work": 5.0, "failing": 0.25}
    clock.add("work", 1.0)
    assert clock.seconds["work"] == 6.0


def test_a_timed_stream_counts_producing_items_not_consuming_them():
    fake = FakeClock()

    def items():
        for k in range(3):
            fake.advance(2.0)  # producing
            yield k
        fake.advance(0.5)  # finding there is no more

    clock = StageClock(clock=fake)
    seen = []
    for item in clock.timed("produce", items()):
        fake.advance(10.0)  # consuming: not counted
        seen.append(item)
    assert seen == [0, 1, 2]
    assert clock.seconds == {"produce": 6.5}


def test_the_stage_clock_reads_the_performance_counter_unless_given_another():
    assert StageClock().clock is time.perf_counter

"""Executors: what tasks report while they run reaches the driver, per unit, from local workers and Ray tasks."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from bimscan.dataset.executors import make_executor, report_pulses


def _scan_like_a_unit(task: tuple[str, int]) -> None:
    unit, pulses = task
    report_pulses(pulses, unit=unit)


def _reports_reach_the_driver(name: str) -> dict[str, int]:
    pool = make_executor(name, workers=2)
    try:
        handles = [pool.submit(_scan_like_a_unit, task, cpus=1)
                   for task in (("north__dense", 7), ("south__dense", 5), ("north__dense", 4))]
        while handles:
            for handle, _, error in pool.wait(handles, timeout=1.0):
                assert error is None
                handles.remove(handle)
        received: dict[str, int] = {}
        deadline = time.monotonic() + 20  # a Ray actor takes the reports in its own time
        while received != {"north__dense": 11, "south__dense": 5} and time.monotonic() < deadline:
            for unit, n in pool.drain_pulses().items():
                received[unit] = received.get(unit, 0) + n
            time.sleep(0.05)
        return received
    finally:
        pool.close()


def test_local_workers_report_the_pulses_of_each_unit_to_the_driver(session_env, monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).parents[2]))  # spawned workers import this module by name
    assert _reports_reach_the_driver("local") == {"north__dense": 11, "south__dense": 5}


@pytest.mark.slow
def test_ray_tasks_report_the_pulses_of_each_unit_to_the_driver(session_env) -> None:
    ray = pytest.importorskip("ray")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray workers cannot import this test module
    assert _reports_reach_the_driver("ray") == {"north__dense": 11, "south__dense": 5}

"""The learner's benchmark script runs against the current data classes (it once broke silently
when TileSet gained a field: benchmarks are not part of the default run)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_learn.py"


def test_bench_learn_sampling_rows_run() -> None:
    spec = importlib.util.spec_from_file_location("bench_learn", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.sampling_rate(2) > 0
    assert bench.sampling_rate(1, recipe=True) > 0

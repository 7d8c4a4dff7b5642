"""Progress bars and step lines for long work, on stderr, quiet when stderr is not a terminal.

Set ``BIMSCAN_PROGRESS=1`` to force them on (e.g. in CI logs) or ``0`` to force them off.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from tqdm import tqdm


def progress_shown(enabled: bool = True) -> bool:
    """Whether progress is shown: ``BIMSCAN_PROGRESS`` when set, else when stderr is a terminal."""
    setting = os.environ.get("BIMSCAN_PROGRESS", "")
    if not enabled or setting == "0":
        return False
    return setting != "" or sys.stderr.isatty()


def progress_bar(*, total: float | None, desc: str, unit: str = "it", enabled: bool = True, **kwargs: Any) -> tqdm:
    """A tqdm bar on stderr; use as a context manager and call ``update(n)``."""
    setting = os.environ.get("BIMSCAN_PROGRESS", "")
    disable: bool | None = None if setting == "" else setting == "0"
    if not enabled:
        disable = True
    return tqdm(
        total=total, desc=desc, unit=unit, file=sys.stderr, disable=disable, dynamic_ncols=True,
        unit_scale=unit not in ("it", "unit", "scene", "station", "epoch", "room", "level"), leave=False, **kwargs,
    )


@contextmanager
def step_line(text: str, *, enabled: bool = True) -> Iterator[None]:
    """One line on stderr for a step without a count (``text ...``, then its time when done),
    shown as progress bars are."""
    shown = progress_shown(enabled)
    start = time.perf_counter()
    if shown:
        print(f"{text} ...", file=sys.stderr, end="", flush=True)
    try:
        yield
    finally:
        if shown:
            print(f" {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)


class StageClock:
    """Seconds spent per named step, summed over every time the step ran: a profile of a long job
    that costs two clock reads per step (``timings.json`` of a dataset unit, the benchmarks).
    ``clock``: seconds from any fixed start (``time.perf_counter``; a test gives its own)."""

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self.seconds: dict[str, float] = {}
        self.clock = clock

    def add(self, step: str, seconds: float) -> None:
        self.seconds[step] = self.seconds.get(step, 0.0) + seconds

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        """Time the block as step ``name`` (also when it raises)."""
        start = self.clock()
        try:
            yield
        finally:
            self.add(name, self.clock() - start)

    def timed(self, name: str, items: Iterator[Any]) -> Iterator[Any]:
        """``items`` with the time spent producing each item added to step ``name`` (not the time
        the consumer spends between items)."""
        while True:
            start = self.clock()
            try:
                item = next(items)
            except StopIteration:
                self.add(name, self.clock() - start)
                return
            self.add(name, self.clock() - start)
            yield item

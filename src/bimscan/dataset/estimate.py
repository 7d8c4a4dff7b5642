"""What a build will take, known once its scenes are planned: each unit's work, the output's size
against the free space, and the time left while it runs.

Work: a tripod unit fires ``station_pulses(recipe) x stations`` pulses (exact once its scene task
has chosen the stations), and gives ``pulses x points per pulse`` points, the share its scene task
measured on a thinned copy of the pattern (``survey.probe_points_per_pulse``). A mobile unit's
walk is planned by its own task, so until then it counts as the mean tripod unit of the build.

Size: points x bytes a point takes in the spec's formats: what this dataset's finished units
take when there are some, else ``io.LIKELY_BYTES_PER_POINT``; at most every pulse (every echo
with ``returns = "all"``) a point of the formats' largest record (``io.BYTES_PER_POINT``).

Time left: ``elapsed x (1 - f) / f`` with ``f`` the share of the work done (finished units whole,
running ones as far as they have scanned): the rate so far applied to the work left. Units weigh
what they scan, not one each (the paper's presets differ tenfold in pulses per station), plus the
fixed time every unit takes, fitted to the finished units (``WorkProgress``).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bimscan.errors import OutputError

ETA_CHECK_FRACTION = 0.1  # the time left predicted once this share of the work is done is kept and checked at the end


@dataclass(frozen=True)
class UnitWork:
    """What one unit to build will scan: ``pulses`` fired, ``points`` expected, at most
    ``most_points``; ``known`` False: a mobile unit counted as the mean tripod unit."""

    unit: str
    scene: str
    pulses: float
    points: float
    most_points: float
    known: bool = True


def tripod_unit_work(unit: str, scene: str, *, station_pulses: int, stations: int, points_per_pulse: float,
                     echoes: int = 1) -> UnitWork:
    """A tripod unit's work: ``stations`` stations of ``station_pulses`` pulses each, ``echoes``
    points a pulse at most (``SensorModel.max_returns`` with ``returns = "all"``, else 1)."""
    pulses = float(station_pulses) * stations
    return UnitWork(unit=unit, scene=scene, pulses=pulses, points=pulses * points_per_pulse,
                    most_points=pulses * max(1, echoes))


def with_unknown_as_mean(works: Sequence[UnitWork]) -> list[UnitWork]:
    """``works`` with every unit whose work is not known (``known`` False) set to the mean known
    unit; all of them unknown: one pulse and one point each (equal weights, no size)."""
    known = [w for w in works if w.known]
    if not known:
        return [UnitWork(w.unit, w.scene, pulses=1.0, points=0.0, most_points=0.0, known=False) for w in works]
    mean = [sum(getattr(w, name) for w in known) / len(known) for name in ("pulses", "points", "most_points")]
    return [w if w.known else UnitWork(w.unit, w.scene, *mean, known=False) for w in works]


@dataclass(frozen=True)
class SizeEstimate:
    """The output of the units still to build against the free space of the dataset's folder."""

    folder: Path
    formats: tuple[str, ...]
    units: int
    points: float
    bytes: float  # expected
    most_bytes: float  # every pulse (echo) a point, of the largest record
    free_bytes: int
    bytes_per_point: float
    measured_on: int  # finished units the bytes per point were measured on (0: typical figures)
    unknown_units: int  # mobile units counted as the mean tripod unit
    subset: tuple[int, int, int, float]  # (scenes, of scenes, their units, their bytes): the first scenes that fit

    @property
    def fits(self) -> bool:
        return self.bytes <= self.free_bytes

    def line(self) -> str:
        """One line: the expected size, its bound and the free space."""
        if self.units == 0:
            return f"output: nothing to build; {_gb(self.free_bytes)} free in {self.folder}"
        if self.unknown_units == self.units:
            return (f"output: not estimated ({self.units} mobile units: their walks are planned by their own tasks); "
                    f"{_gb(self.free_bytes)} free in {self.folder}")
        source = (f"as this dataset's {self.measured_on} finished units" if self.measured_on
                  else f"typical of {'+'.join(self.formats)}")
        unknown = f"; {self.unknown_units} mobile units counted as the mean unit" if self.unknown_units else ""
        return (f"estimated output: about {_gb(self.bytes)} for {self.units} units ({_count(self.points)} points at "
                f"{self.bytes_per_point:.1f} bytes a point, {source}; at most {_gb(self.most_bytes)}{unknown}); "
                f"{_gb(self.free_bytes)} free in {self.folder}")

    def refusal(self) -> str:
        """One line: why the build does not start, and what to do."""
        scenes, of_scenes, units, subset_bytes = self.subset
        if scenes == 0:
            subset = "not even the first scene's units fit; free space or build into another folder"
        else:
            subset = (f"free space, build into another folder, or build a subset: the first {scenes} of {of_scenes} "
                      f"scenes ({units} units, about {_gb(subset_bytes)}) fit")
        return (f"the build would write about {_gb(self.bytes)} ({self.units} units, {_count(self.points)} points in "
                f"{'+'.join(self.formats)}) but {self.folder} has {_gb(self.free_bytes)} free; {subset}")


def _gb(n_bytes: float) -> str:
    return f"{n_bytes / 1e9:.1f} GB" if n_bytes >= 1e9 else f"{n_bytes / 1e6:.0f} MB"


def _count(n: float) -> str:
    if n >= 1e9:
        return f"{n / 1e9:.2f} billion"
    return f"{n / 1e6:.1f} million" if n >= 1e6 else f"{n:,.0f}"


def estimate_size(works: Sequence[UnitWork], folder: Path, *, formats: Sequence[str],
                  finished: Sequence[tuple[int, int]] = ()) -> SizeEstimate:
    """The size of the units ``works`` will write into ``folder`` (units in spec order, scene by
    scene) against its free space. ``finished``: (bytes, points) of the dataset's finished units;
    their bytes per point is used when they hold points, else ``io.LIKELY_BYTES_PER_POINT``."""
    from bimscan.io import BYTES_PER_POINT, LIKELY_BYTES_PER_POINT

    works = with_unknown_as_mean(works)
    done_bytes, done_points = sum(b for b, _ in finished), sum(p for _, p in finished)
    per_point = (done_bytes / done_points if done_points > 0
                 else float(sum(LIKELY_BYTES_PER_POINT[f] for f in formats)))
    most_per_point = float(sum(BYTES_PER_POINT[f] for f in formats))
    free = shutil.disk_usage(folder).free
    scene_bytes: dict[str, list[float]] = {}  # scene -> [units, bytes], in spec order
    for work in works:
        row = scene_bytes.setdefault(work.scene, [0, 0.0])
        row[0] += 1
        row[1] += work.points * per_point
    fitting, units, total = 0, 0, 0.0
    for count, size in scene_bytes.values():
        if total + size > free:
            break
        fitting, units, total = fitting + 1, units + int(count), total + size
    return SizeEstimate(folder=folder, formats=tuple(formats), units=len(works),
                        points=sum(w.points for w in works), bytes=sum(w.points for w in works) * per_point,
                        most_bytes=sum(w.most_points for w in works) * most_per_point, free_bytes=free,
                        bytes_per_point=per_point, measured_on=len(finished) if done_points > 0 else 0,
                        unknown_units=sum(not w.known for w in works),
                        subset=(fitting, len(scene_bytes), units, total))


def check_output_fits(estimate: SizeEstimate) -> None:
    """Raise OutputError (one line: the estimate, the free space, a subset that fits) when the
    units to build would not fit."""
    if not estimate.fits:
        raise OutputError(estimate.refusal())


@dataclass(frozen=True)
class EtaCheck:
    """The time left predicted once ``fraction`` of the work was done, ``elapsed_s`` into the
    units, against what it took (``actual_left_s``, known at the end)."""

    fraction: float
    elapsed_s: float
    predicted_left_s: float
    actual_left_s: float

    @property
    def error(self) -> float:
        """(predicted - actual) / actual: +0.1 predicted 10 % too long."""
        return (self.predicted_left_s - self.actual_left_s) / max(self.actual_left_s, 1e-9)

    def line(self) -> str:
        return (f"time left predicted after {self.fraction:.0%} of the work ({_duration(self.elapsed_s)} in): "
                f"{_duration(self.predicted_left_s)}; it took {_duration(self.actual_left_s)} ({self.error:+.0%})")


@dataclass
class WorkProgress:
    """The share of a build's work done and the time left, from the units' pulses.

    A unit costs a fixed time (loading its scene, preparing the survey, checking and moving what it
    wrote) plus a time per pulse; both are fitted to the units finished so far (their own seconds
    against their pulses, least squares), so a unit weighs its pulses plus the pulses its fixed time
    is worth (``overhead_pulses``; 0 until three units of different sizes have finished).
    ``scanned`` takes the pulses a running unit reports as it goes (local workers, Ray tasks), a
    running unit counting half its fixed time once it scans; ``finished`` counts a unit whole (done
    or failed: no work is left in it). The clock starts on construction, when the units are handed
    to the workers. The prediction made once ``ETA_CHECK_FRACTION`` of the work is done is kept
    (``checkpoint``) so the end can say how right it was.
    """

    pulses: Mapping[str, float]
    clock: Callable[[], float] = time.monotonic
    # (share done, elapsed s, predicted s left) when the work first passed ETA_CHECK_FRACTION
    checkpoint: tuple[float, float, float] | None = None
    overhead_pulses: float = 0.0
    _start: float = field(init=False)
    _running: dict[str, float] = field(init=False, default_factory=dict)  # unit -> pulses scanned so far
    _finished: set[str] = field(init=False, default_factory=set)
    _timed: list[tuple[float, float]] = field(init=False, default_factory=list)  # (pulses, seconds) of done units

    def __post_init__(self) -> None:
        self._start = self.clock()

    @property
    def total(self) -> float:
        return float(sum(self.pulses.values())) + self.overhead_pulses * len(self.pulses)

    @property
    def done(self) -> float:
        finished = sum(self.pulses[u] for u in self._finished) + self.overhead_pulses * len(self._finished)
        running = sum(min(n, self.pulses[u]) + (self.overhead_pulses / 2 if n > 0 else 0.0)
                      for u, n in self._running.items())
        return finished + running

    @property
    def fraction(self) -> float:
        total = self.total
        return self.done / total if total > 0 else 1.0

    @property
    def units_finished(self) -> int:
        return len(self._finished)

    def elapsed_s(self) -> float:
        return self.clock() - self._start

    def scanned(self, unit: str, pulses: float) -> None:
        if unit in self.pulses and unit not in self._finished:
            self._running[unit] = self._running.get(unit, 0.0) + pulses
            self._check()

    def finished(self, unit: str, *, seconds: float | None = None) -> None:
        """``unit`` is over; ``seconds``: its task's own time when it was built (fits the fixed time)."""
        if unit in self.pulses and unit not in self._finished:
            self._finished.add(unit)
            self._running.pop(unit, None)
            if seconds is not None:
                self._timed.append((self.pulses[unit], seconds))
                self._fit()
            self._check()

    def _fit(self) -> None:
        """The fixed time of a unit in pulses: intercept / slope of seconds against pulses."""
        if len(self._timed) < 3:
            return
        x = [p for p, _ in self._timed]
        y = [t for _, t in self._timed]
        mean_x, mean_y = sum(x) / len(x), sum(y) / len(y)
        spread = sum((v - mean_x) ** 2 for v in x)
        if spread <= 0:
            return  # units of one size: a fixed time cannot be told from a time per pulse
        slope = sum((a - mean_x) * (b - mean_y) for a, b in zip(x, y)) / spread
        if slope > 0:
            self.overhead_pulses = max(0.0, (mean_y - slope * mean_x) / slope)

    def remaining_s(self) -> float | None:
        """Seconds left at the rate so far; None before any work is done."""
        fraction = self.fraction
        if fraction <= 0:
            return None
        return self.elapsed_s() * (1.0 - fraction) / fraction

    def _check(self) -> None:
        fraction = self.fraction
        if self.checkpoint is None and ETA_CHECK_FRACTION <= fraction < 1.0:
            left = self.remaining_s()
            if left is not None:
                self.checkpoint = (fraction, self.elapsed_s(), left)

    def eta_check(self) -> EtaCheck | None:
        """At the end: the checkpoint's prediction against the time it took."""
        if self.checkpoint is None:
            return None
        fraction, elapsed, predicted = self.checkpoint
        return EtaCheck(fraction=fraction, elapsed_s=elapsed, predicted_left_s=predicted,
                        actual_left_s=self.elapsed_s() - elapsed)

    def status(self) -> str:
        """For the progress bar: units finished and the time left."""
        left = self.remaining_s()
        units = f"{self.units_finished}/{len(self.pulses)} units"
        return f"{units}, {'time left: estimating' if left is None else _duration(left) + ' left'}"


def _duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"

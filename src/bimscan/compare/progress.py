"""Scan against model, element by element: built, not built, not visible, or built out of
tolerance, and against the schedule: on time, behind or ahead (``bimscan progress``).

Two streamed passes over the aligned scan:

1. **Look** (``_look``): where each view stood and how fine its pulses are: the stations' positions
   (from the file, a ``--stations`` file, or estimated from their points), a mobile scan's views
   (``views``), a small sample of every view's points for their range limits and a coarse image
   of what they saw.
2. **Compare**: every point is attached to the nearest model surface within ``band_m``
   (``BandDistances``: its element and signed distance), feeds the range evidence of the model's
   surface samples (``evidence``: seen, passed through, hidden), and a bounded sample per element
   is kept for its deviation fit (``deviation``).

Then per element: the visible share of its surface (samples some beam could decide: seen or
passed through), the supported share of that (seen), the status, and for built elements the
deviation, judged against its class's tolerance (``ProgressConfig.tolerances_m``, ACI 117-10).
An element whose visible surface is too small gets "not visible": no verdict without evidence,
so an element no station could see is never "not built".
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba as nb
import numpy as np

from bimscan.compare.config import ProgressConfig
from bimscan.compare.deviation import ElementFit, fit_element
from bimscan.compare.digest import scan_stations, station_field
from bimscan.compare.distance import BandDistances
from bimscan.compare.evidence import Evidence
from bimscan.compare.planes import apply
from bimscan.compare.surfaces import ModelSurfaces
from bimscan.compare.views import MergedStationsError, PulseRun, View, angular_spacing_deg, estimate_origin
from bimscan.errors import CompareError
from bimscan.progress import progress_bar
from bimscan.survey.planning.surface import SurfaceSamples
from bimscan.types import BimScene, BuildDates, PointCloud

STATUSES = ("built", "built out of tolerance", "not built", "not visible")
SCHEDULE_STATES = ("on time", "behind", "ahead", "not due", "unknown")
CHUNK_POINTS = 2_000_000
SAMPLE_POINTS = 1_500_000  # points of a walk sampled in the first pass, at random
RESERVOIR_POINTS = 20_000  # at most 4x this many of them kept per view
RUN_POINTS = 20_000  # the contiguous run of a station's points its pulse spacing is measured on
LOOK_RUNS = 300  # a tripod scan's first pass reads at least this many runs of consecutive points
LOOK_RUN_POINTS = 8000  # of this many points each (about 2.4 million points)
LOOK_GAP_POINTS = 150_000  # and one run in at most this many points: a dense station's runs hold few mirror
                           # lines each, and its origin needs lines of many headings
STATION_RUNS = 16  # a station met in fewer runs is looked at again in this many
MOBILE_CELL_DEG = 2.0  # a walk's views: multi-beam lidars' rings lie about 2 degrees apart
MIN_EXPLAINED_SHARE = 0.8  # an estimated station explaining fewer of its points is not one scanner position
TRANSPARENT = 0.5  # surfaces at least this transparent (glazing) decide nothing
CONTACT_M = 0.01  # a sample this close to another element's surface is on a face the two share
RANGE_MARGIN = 1.5


@dataclass(frozen=True)
class ElementTable:
    """One row per model component (C,), in the scene's component order: the status (one of
    ``STATUSES``), the surface (area_m2) and how much of it the scan could decide (visible_m2:
    seen or passed through) and supported (seen_m2), the points attached to it, its fit (built
    elements), tolerance, and the schedule's expectation (expected: 1 due by ``at``, 0 not due,
    -1 no date) with the verdict against it (``SCHEDULE_STATES``; "" without ``at``)."""

    status: np.ndarray
    area_m2: np.ndarray
    visible_m2: np.ndarray
    seen_m2: np.ndarray
    points: np.ndarray
    fits: tuple[ElementFit, ...]
    tolerance_m: np.ndarray
    expected: np.ndarray
    schedule: np.ndarray

    @property
    def visible_share(self) -> np.ndarray:
        return np.divide(self.visible_m2, self.area_m2, out=np.zeros_like(self.area_m2), where=self.area_m2 > 0)

    @property
    def supported_share(self) -> np.ndarray:
        return np.divide(self.seen_m2, self.visible_m2, out=np.zeros_like(self.area_m2), where=self.visible_m2 > 0)


@dataclass(frozen=True)
class ProgressResult:
    """What ``compare_scan`` found: the element table, the views, the matrix used (scan frame ->
    model frame), the points read, the date judged against, the model's surface samples the
    verdicts were reached on, the points kept for the elements' fits (point_xyz (P, 3) model
    frame, point_signed (P,) metres in front of the model surface), and the time per step."""

    elements: ElementTable
    views: tuple[View, ...]
    matrix: np.ndarray
    points: int
    at: str | None
    config: ProgressConfig
    samples: SurfaceSamples
    point_xyz: np.ndarray
    point_signed: np.ndarray
    seconds: float
    steps: dict[str, float] = field(default_factory=dict)


@dataclass
class _Look:
    """What the first pass gathers per view key (station id, or window index of a walk)."""

    mobile: bool
    sample: dict[int, list[np.ndarray]] = field(default_factory=dict)
    run: dict[int, list[np.ndarray]] = field(default_factory=dict)
    runs: dict[int, list[PulseRun]] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    origin_sums: dict[int, np.ndarray] = field(default_factory=dict)
    t0: float | None = None
    points: int = 0


def _view_keys(chunk: PointCloud, look: _Look, window_s: float) -> np.ndarray:
    """(N,) int64 the view key of every point of a chunk: its station, or its window of the walk."""
    if look.mobile:
        assert chunk.time is not None and look.t0 is not None
        return np.floor((chunk.time - look.t0) / window_s).astype(np.int64)
    if chunk.station is None:
        return np.full(len(chunk), -1, dtype=np.int64)
    return chunk.station.astype(np.int64)


def _look(scan_path: Path, matrix: np.ndarray, config: ProgressConfig, total: int,
          on_points: Callable[[int], None]) -> _Look:
    """The first pass. A tripod scan is looked at in ``LOOK_RUNS`` runs of consecutive points spread
    evenly through the file (a LAS/LAZ file seeks to them, so this costs a fraction of a full read
    however large the scan): every station shows in proportion to its points, each run holds whole
    mirror lines; a station met in fewer than ``STATION_RUNS`` runs is looked at again in that many
    over its stretch of the file (its origin needs mirror lines of many headings). A walk is read
    whole: each second of it needs its beam origins."""
    from bimscan.io import iter_cloud_chunks, iter_cloud_runs

    field_name = station_field(scan_path)
    length = min(LOOK_RUN_POINTS, max(total, 1))
    count = max(1, min(max(LOOK_RUNS, total // LOOK_GAP_POINTS), total // length))
    gap = total // count
    runs = [(i * gap, min(length, total - i * gap)) for i in range(count)] if total else [(0, 0)]
    first = next(iter_cloud_runs(scan_path, runs[:1], station_field=field_name), None)
    if first is None or not len(first[1]):
        raise CompareError(f"{scan_path}: holds no points; pass a scan with points")
    chunk = first[1]
    mobile = chunk.time is not None and chunk.sensor_xyz is not None
    look = _Look(mobile=mobile, t0=float(chunk.time.min()) if mobile else None)  # type: ignore[union-attr]
    rng = np.random.default_rng(config.seed)

    def take(start: int, chunk: PointCloud) -> np.ndarray:
        """Gather a chunk's points by view; its view keys."""
        xyz = apply(matrix, chunk.xyz)
        keys = _view_keys(chunk, look, config.window_s)
        keep = rng.random(len(chunk)) < (min(1.0, SAMPLE_POINTS / max(total, 1)) if mobile else 1.0)
        present = np.unique(keys)
        for key in present:
            if key < 0:
                continue
            mine = keys == key
            k = int(key)
            look.counts[k] = look.counts.get(k, 0) + int(mine.sum())
            held = sum(len(a) for a in look.sample.get(k, []))
            if held < 4 * RESERVOIR_POINTS:
                look.sample.setdefault(k, []).append(xyz[mine & keep][: 4 * RESERVOIR_POINTS - held])
            if not mobile:
                mine_index = np.flatnonzero(mine)
                if sum(len(a) for a in look.run.get(k, [])) < RUN_POINTS // 2:
                    look.run[k] = [xyz[mine_index]]  # a contiguous run of the station: its pulse spacing
                for part in np.split(mine_index, np.flatnonzero(np.diff(mine_index) > 1) + 1):
                    look.runs.setdefault(k, []).append(PulseRun(
                        xyz=xyz[part], time=None if chunk.time is None else chunk.time[part]))
            else:
                origins = apply(matrix, chunk.sensor_xyz[mine])  # type: ignore[index]
                look.origin_sums[k] = look.origin_sums.get(k, np.zeros(3)) + origins.sum(axis=0)
        look.points += len(chunk)
        return present

    if mobile:
        for chunk in iter_cloud_chunks(scan_path, chunk_points=CHUNK_POINTS, labels=False):
            if len(chunk):
                take(look.points, chunk)
                on_points(len(chunk))
        return look
    met: list[tuple[int, int, np.ndarray]] = []
    for start, chunk in iter_cloud_runs(scan_path, runs, station_field=field_name):
        met.append((start, len(chunk), take(start, chunk) if len(chunk) else np.zeros(0, dtype=np.int64)))
        on_points(round(len(chunk) * total / max(count * length, 1)))
    for start, chunk in iter_cloud_runs(scan_path, _more_runs(met, total, length), station_field=field_name):
        if len(chunk):
            take(start, chunk)
    return look


def _more_runs(met: list[tuple[int, int, np.ndarray]], total: int, length: int) -> list[tuple[int, int]]:
    """Runs (first, count) over the stretch of the file of each station met in fewer than
    ``STATION_RUNS`` of the runs ``met`` ((first, count, view keys) in file order): ``STATION_RUNS``
    spread over it, none overlapping the runs read; sorted and disjoint."""
    where: dict[int, list[int]] = {}
    for i, (_, _, keys) in enumerate(met):
        for key in keys.tolist():
            if key >= 0:
                where.setdefault(int(key), []).append(i)
    taken = [(a, a + n) for a, n, _ in met]
    wanted: list[tuple[int, int]] = []
    for key, index in sorted(where.items()):
        if len(index) >= STATION_RUNS:
            continue
        low = taken[index[0] - 1][1] if index[0] > 0 else 0  # from the run before its first to the one after
        high = taken[index[-1] + 1][0] if index[-1] + 1 < len(taken) else total
        for first in np.linspace(low, max(low, high - length), STATION_RUNS).astype(np.int64).tolist():
            wanted.append((first, min(length, high - first)))
    chosen: list[tuple[int, int]] = []
    for first, n in sorted(set(wanted)):
        end = first + n
        if n <= 0 or any(a < end and first < b for a, b in taken):
            continue
        taken.append((first, end))
        chosen.append((first, n))
    return chosen


def _views(look: _Look, scan_path: Path, matrix: np.ndarray, config: ProgressConfig,
           stations: dict[int, np.ndarray] | None, surfaces: ModelSurfaces, distances: BandDistances,
           warn: Callable[[str], None]) -> list[View]:
    """The views of the scan, model frame (see ``bimscan.compare.views``). A station that cannot be
    placed from its points is left out, with a warning, when others can: its points decide nothing."""
    if not look.counts:
        raise CompareError(
            f"{scan_path}: the scan says nothing of where it was scanned from (no station ids, no beam origins); "
            "give the stations with --stations FILE (x,y,z per line in the scan's frame), or pass the scan as E57 "
            "with its scan poses or as a LAS whose point source ids are the stations")
    views = []
    if look.mobile:
        for key in sorted(look.counts):
            origin = look.origin_sums[key] / look.counts[key]
            views.append(View(id=key, origin=origin, source="sensor", points=look.counts[key],
                              cell_deg=config.cell_deg or MOBILE_CELL_DEG))
        return views
    known = {k: apply(matrix, np.asarray(v, dtype=np.float64)[None])[0] for k, v in scan_stations(scan_path).items()}
    given = {k: apply(matrix, v[None])[0] for k, v in (stations or {}).items()}
    unplaced: list[CompareError] = []
    for key in sorted(look.counts):
        sample = np.concatenate(look.sample.get(key, [np.zeros((0, 3))]))
        if key in given:
            origin, source = given[key], "file"
        elif key in known:
            origin, source = known[key], "scan"
        else:
            try:
                origin, explained, lined = estimate_origin(sample, surfaces, distances, look.runs.get(key, []))
            except MergedStationsError as exc:
                raise CompareError(f"{scan_path}: station {key}: {exc}") from exc
            except CompareError as exc:
                unplaced.append(CompareError(f"{scan_path}: station {key}: {exc}"))
                continue
            source = "estimated" if lined else "estimated roughly"
            if not lined and explained < MIN_EXPLAINED_SHARE:
                unplaced.append(CompareError(
                    f"{scan_path}: the points of station {key} do not look like one scanner position (the best place "
                    f"found sees {explained:.0%} of them on the front of an unobstructed surface): a merged cloud "
                    "without station ids, or a poor alignment; give the stations with --stations FILE, or pass the "
                    "scan with its stations (E57 scans, LAS point source ids)"))
                continue
        run = np.concatenate(look.run[key])
        cell = config.cell_deg or float(np.clip(1.5 * angular_spacing_deg(run, origin), 0.05, 2.0))
        views.append(View(id=key, origin=origin, source=source, points=look.counts[key], cell_deg=cell))
    if unplaced and not views:
        raise unplaced[0]
    for problem in unplaced:
        warn(f"{problem} Its points decide nothing here.")
    return views


def _range_limit(view: View, look: _Look) -> float:
    """How far a view may have seen: past its farthest point of the first pass by half again (the
    first pass looked at part of it), and 5 m."""
    sample = np.concatenate(look.sample.get(view.id, [np.zeros((0, 3))]))
    if not len(sample):
        return 0.0
    return float(np.linalg.norm(sample - view.origin, axis=1).max()) * RANGE_MARGIN + 5.0


def _expected(scene: BimScene, at: str | None, schedule: dict[str, BuildDates] | None) -> np.ndarray:
    """(C,) int8: 1 when the schedule has the element standing on ``at``, 0 when not, -1 unknown."""
    expected = np.full(len(scene.components), -1, dtype=np.int8)
    if at is None or schedule is None:
        return expected
    for index, gid in enumerate(scene.components.global_id.tolist()):
        dates = schedule.get(gid)
        if dates is None:
            continue
        standing = (dates.built is None or dates.built <= at) and (dates.removed is None or dates.removed > at)
        expected[index] = 1 if standing else 0
    return expected


def _schedule_states(status: np.ndarray, expected: np.ndarray, at: str | None) -> np.ndarray:
    states = np.full(len(status), "" if at is None else "unknown", dtype=object)
    if at is None:
        return states.astype(str)
    built = np.isin(status, STATUSES[:2])
    decided = status != "not visible"
    states[decided & (expected == 1) & built] = "on time"
    states[decided & (expected == 1) & ~built] = "behind"
    states[decided & (expected == 0) & built] = "ahead"
    states[decided & (expected == 0) & ~built] = "not due"
    return states.astype(str)


def compare_scan(scene: BimScene, scan_path: str | Path, *, matrix: np.ndarray, config: ProgressConfig,
                 at: str | None = None, schedule: dict[str, BuildDates] | None = None,
                 stations: dict[int, np.ndarray] | None = None,
                 supports: Callable[[PointCloud, np.ndarray], np.ndarray] | None = None,
                 on_chunk: Callable[[PointCloud, np.ndarray, np.ndarray, np.ndarray], None] | None = None,
                 surfaces: ModelSurfaces | None = None, warn: Callable[[str], None] | None = None) -> ProgressResult:
    """Compare the scan at ``scan_path`` (placed in the model by ``matrix`` (4, 4), scan frame ->
    model frame) with ``scene``, element by element (see the module docs).

    at / schedule: judge against what the schedule (GlobalId -> BuildDates) has standing on this
    ISO date. stations: station id -> position (3,) scan frame, over what the file says.
    supports(chunk, xyz_model) -> (N,) bool: which points may support an element (None: all; a
    segmentation model's "not Others"). on_chunk(chunk, xyz_model, signed_distance (N,) float64
    (NaN beyond the band), component (N,) int64 (-1 beyond the band)): every chunk as compared
    (to write the per-point distances). warn: receives one line per station left out (its place could
    not be found from its points).
    """
    from bimscan.io import count_points, iter_cloud_chunks

    started = time.perf_counter()
    steps: dict[str, float] = {}
    scan_path = Path(scan_path)
    total = count_points(scan_path)
    mesh = scene.mesh
    surfaces = surfaces or ModelSurfaces(mesh)
    with progress_bar(total=2 * total, desc="progress", unit="pt") as bar:
        clock = time.perf_counter()
        look = _look(scan_path, matrix, config, total, bar.update)
        distances = BandDistances(mesh, band_m=config.band_m)
        views = _views(look, scan_path, matrix, config, stations, surfaces, distances, warn or (lambda line: None))
        steps["look"] = time.perf_counter() - clock

        clock = time.perf_counter()
        samples = surfaces.samples(samples_per_m2=config.samples_per_m2, min_samples=config.min_samples,
                                   seed=config.seed)
        limits = [_range_limit(view, look) for view in views]
        # a sample on a face another element touches (a wall on its slab, a window's frame in its
        # reveal) cannot tell which of the two stands there: it decides nothing
        free = distances.query(samples.xyz, other_than=samples.component).distance > CONTACT_M
        if mesh.face_transparency is not None:  # a laser passes glazing: it decides nothing
            free &= ~(np.nan_to_num(mesh.face_transparency[samples.triangle], nan=0.0) > TRANSPARENT)
        evidence = Evidence.plan(samples, views, support_m=config.support_m, max_incidence_deg=config.max_incidence_deg,
                                 max_range_m=np.array(limits), keep=[free] * len(views))
        steps["plan"] = time.perf_counter() - clock

        clock = time.perf_counter()
        n_components = len(scene.components)
        attached = np.zeros(n_components, dtype=np.int64)
        kept = _ElementSample(n_components, config.fit_points, config.seed)
        view_counts = np.zeros(len(views), dtype=np.int64)
        origins = np.array([v.origin for v in views]) if views else np.zeros((0, 3))
        position_of = {v.id: i for i, v in enumerate(views)}
        lookup_keys = np.array(sorted(position_of), dtype=np.int64)
        lookup_positions = np.array([position_of[k] for k in lookup_keys.tolist()], dtype=np.int64)
        outward = surfaces.outward
        seen_points = 0
        unmet: dict[int, int] = {}
        for chunk in iter_cloud_chunks(scan_path, chunk_points=CHUNK_POINTS, labels=False,
                                       station_field=station_field(scan_path)):
            if not len(chunk):
                continue
            xyz = apply(matrix, chunk.xyz)
            keys = _view_keys(chunk, look, config.window_s)
            slot = np.clip(np.searchsorted(lookup_keys, keys), 0, max(len(lookup_keys) - 1, 0))
            found = (lookup_keys[slot] == keys) if len(lookup_keys) else np.zeros(len(keys), dtype=bool)
            view_position = np.where(found, lookup_positions[slot] if len(lookup_positions) else -1, -1)
            if not look.mobile and not found.all():  # a station the first look never met, between its runs
                missed, count = np.unique(keys[~found & (keys >= 0)], return_counts=True)
                for key, n in zip(missed.tolist(), count.tolist()):
                    if key not in look.counts:
                        unmet[key] = unmet.get(key, 0) + n
            may_support = np.ones(len(chunk), dtype=bool) if supports is None else supports(chunk, xyz)
            answer = distances.query(xyz)
            # a point about as near to another element's surface is on a face the two share: it
            # supports neither
            component, supporting, signed = _attach(answer.triangle, answer.distance, answer.second, answer.point,
                                                    xyz, mesh.face_component, outward, may_support, CONTACT_M)
            evidence.add(xyz, view_position, origins, supporting)
            index = np.flatnonzero(supporting >= 0)
            attached += np.bincount(supporting[index], minlength=n_components)
            kept.add(seen_points, index, xyz, supporting, signed)  # a bounded sample per element for its fit
            view_counts += np.bincount(view_position[view_position >= 0], minlength=len(views))
            if on_chunk is not None:
                on_chunk(chunk, xyz, signed, component)
            seen_points += len(chunk)
            bar.update(len(chunk))
        points_xyz, points_component, points_signed = kept.result()
        for key, n in sorted(unmet.items()):
            (warn or (lambda line: None))(
                f"{scan_path}: station {key} ({n:,} points) lies between the parts of the file the first look read, "
                "so it was not placed: its points decide nothing here; give the stations with --stations FILE")
        views = [dataclasses.replace(v, points=int(c)) for v, c in zip(views, view_counts)]
        steps["compare"] = time.perf_counter() - clock

    clock = time.perf_counter()
    seen, passed = evidence.states(len(samples))
    area = np.bincount(samples.component, weights=samples.area_m2, minlength=n_components)
    seen_m2 = np.bincount(samples.component, weights=samples.area_m2 * seen, minlength=n_components)
    visible_m2 = seen_m2 + np.bincount(samples.component, weights=samples.area_m2 * passed, minlength=n_components)
    visible_share = np.divide(visible_m2, area, out=np.zeros(n_components), where=area > 0)
    supported = np.divide(seen_m2, visible_m2, out=np.zeros(n_components), where=visible_m2 > 0)
    decided = (visible_share >= config.min_visible_share) & (visible_m2 >= config.min_visible_m2)
    status = np.where(~decided, "not visible", np.where(supported >= config.built_share, "built", "not built")).astype("<U22")
    class_names = scene.scheme.names
    tolerance = np.array([config.tolerance_of(class_names.get(int(label), "")) for label in scene.components.label])
    fits: list[ElementFit] = []
    bounds = np.searchsorted(points_component, np.arange(n_components + 1))
    faces_order = np.argsort(mesh.face_component, kind="stable")
    face_bounds = np.searchsorted(mesh.face_component[faces_order], np.arange(n_components + 1))
    for c in range(n_components):
        if status[c] != "built":
            fits.append(ElementFit.unknown(int(bounds[c + 1] - bounds[c])))
            continue
        fit = fit_element(mesh, faces_order[face_bounds[c]:face_bounds[c + 1]], points_xyz[bounds[c]:bounds[c + 1]])
        fits.append(fit)
        if np.isfinite(fit.max_shift_m) and fit.max_shift_m > tolerance[c]:
            status[c] = "built out of tolerance"
    expected = _expected(scene, at, schedule)
    elements = ElementTable(status=status, area_m2=area, visible_m2=visible_m2, seen_m2=seen_m2, points=attached,
                            fits=tuple(fits), tolerance_m=tolerance, expected=expected,
                            schedule=_schedule_states(status, expected, at))
    steps["judge"] = time.perf_counter() - clock
    return ProgressResult(elements=elements, views=tuple(views), matrix=matrix, points=seen_points, at=at,
                          config=config, samples=samples, point_xyz=points_xyz, point_signed=points_signed,
                          seconds=time.perf_counter() - started, steps=steps)


@nb.njit(cache=True, parallel=True)
def _attach(triangle: np.ndarray, distance: np.ndarray, second: np.ndarray, point: np.ndarray, xyz: np.ndarray,
            face_component: np.ndarray, outward: np.ndarray, may_support: np.ndarray,
            contact_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's element (N,) int64 (-1 beyond the band), the element it may support (-1: none;
    or it lies within ``contact_m`` as near to another element's surface, on a face the two share)
    and its signed distance (N,) (in front of the surface: positive; NaN beyond the band)."""
    n = triangle.shape[0]
    component = np.empty(n, dtype=np.int64)
    supporting = np.empty(n, dtype=np.int64)
    signed = np.empty(n)
    for i in nb.prange(n):
        t = triangle[i]
        if t < 0:
            component[i], supporting[i], signed[i] = -1, -1, np.nan
            continue
        c = face_component[t]
        component[i] = c
        supporting[i] = c if may_support[i] and second[i] - distance[i] > contact_m else -1
        signed[i] = ((xyz[i, 0] - point[i, 0]) * outward[t, 0] + (xyz[i, 1] - point[i, 1]) * outward[t, 1]
                     + (xyz[i, 2] - point[i, 2]) * outward[t, 2])
    return component, supporting, signed


class _ElementSample:
    """At most ``per_element`` points of each element: those of lowest priority (a hash of their
    place in the file, so the same points whatever the chunking). Points above an element's current
    cut are turned away at once, so the sample stays small however many points stream by."""

    def __init__(self, n_components: int, per_element: int, seed: int) -> None:
        self.per_element, self.seed = per_element, seed
        self.cut = np.full(n_components, np.iinfo(np.uint64).max, dtype=np.uint64)
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.held = 0

    def add(self, first: int, index: np.ndarray, xyz: np.ndarray, component: np.ndarray, signed: np.ndarray) -> None:
        """Offer the rows ``index`` (K,) of a chunk whose first point is the file's ``first``: xyz (N, 3),
        component (N,), signed distance (N,)."""
        priority, keep = _offer(first, index, component, self.cut, self.seed)
        rows = index[keep]
        self.parts.append((xyz[rows], component[rows], priority[keep], signed[rows]))
        self.held += len(rows)
        if self.held > 2 * self.per_element * len(self.cut) + 1_000_000:
            self._prune()

    def _prune(self) -> None:
        if not self.parts:
            return
        xyz, component, priority, signed = (np.concatenate([p[i] for p in self.parts]) for i in range(4))
        # grouped by element (a radix sort when element numbers fit 16 bits), then each element's
        # per_element lowest priorities by partition: no sort of the 64-bit priorities
        group_key = component.astype(np.uint16) if len(self.cut) <= 1 << 16 else component
        by_element = np.argsort(group_key, kind="stable")
        grouped = component[by_element]
        bounds = np.flatnonzero(np.r_[True, grouped[1:] != grouped[:-1], True])
        keep_parts = []
        for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
            members = by_element[a:b]
            if b - a > self.per_element:
                lowest = np.argpartition(priority[members], self.per_element - 1)[: self.per_element]
                members = members[lowest]
                self.cut[grouped[a]] = priority[members].max()  # its new cut: the highest it keeps
            keep_parts.append(members)
        keep = np.concatenate(keep_parts) if keep_parts else np.zeros(0, dtype=np.int64)
        self.parts = [(xyz[keep], component[keep], priority[keep], signed[keep])]
        self.held = len(keep)

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xyz (P, 3), component (P,), signed (P,)) sorted by component."""
        self._prune()
        if not self.parts:
            return np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0)
        xyz, component, _, signed = self.parts[0]
        order = np.argsort(component, kind="stable")
        return xyz[order], component[order], signed[order]


@nb.njit(cache=True, parallel=True)
def _offer(first: int, index: np.ndarray, component: np.ndarray, cut: np.ndarray,
           seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The priority (K,) uint64 of the rows ``index`` (K,) of a chunk whose first point is the file's
    ``first`` (a reproducible pseudo-random number of the point's place in the file: splitmix64), and
    whether it is below its element's ``cut`` (K,) bool. One pass, no temporaries: 100M points stream by."""
    n = index.shape[0]
    priority = np.empty(n, dtype=np.uint64)
    keep = np.empty(n, dtype=np.bool_)
    mix = np.uint64(0x9E3779B97F4A7C15) * np.uint64(seed + 1)
    for i in nb.prange(n):
        z = np.uint64(first + index[i]) + mix  # uint64 constants throughout: Numba turns uint64-int64 into floats
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
        priority[i] = z
        keep[i] = z < cut[component[index[i]]]
    return priority, keep


def summary(result: ProgressResult, scene: BimScene) -> dict[str, Any]:
    """Counts by status, class and storey; percent complete (built among the decided elements,
    by count and by area), and against the schedule when a date was given."""
    elements = result.elements
    names = scene.scheme.names
    class_of = np.array([names.get(int(label), "") for label in scene.components.label])
    storey = scene.components.storey

    def tally(mask: np.ndarray) -> dict[str, Any]:
        counts = {s: int((elements.status[mask] == s).sum()) for s in STATUSES}
        built = np.isin(elements.status, STATUSES[:2]) & mask
        decided = (elements.status != "not visible") & mask
        entry: dict[str, Any] = {"elements": int(mask.sum()), **counts}
        entry["complete_share"] = round(float(built.sum() / decided.sum()), 4) if decided.any() else None
        area = elements.area_m2
        entry["complete_area_share"] = round(float(area[built].sum() / area[decided].sum()), 4) \
            if area[decided].sum() > 0 else None
        if result.at is not None:
            entry.update({s: int((elements.schedule[mask] == s).sum()) for s in SCHEDULE_STATES})
        return entry

    everything = np.ones(len(class_of), dtype=bool)
    return {
        "all": tally(everything),
        "by_class": {c: tally(class_of == c) for c in sorted(set(class_of.tolist()))},
        "by_storey": {s: tally(storey == s) for s in sorted(set(storey.tolist()))},
        "at": result.at,
        "views": [{"id": v.id, "origin_m": [round(float(x), 4) for x in v.origin], "source": v.source,
                   "points": v.points, "cell_deg": round(v.cell_deg, 4)} for v in result.views],
        "points": result.points,
        "settings": result.config.to_json(),
    }  # no timings: the same scan gives the same bytes

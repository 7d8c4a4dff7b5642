"""Where the scan was seen from: one *view* per tripod station, or per few seconds of a walk.

Visibility is judged along the beams, so every point needs the origin of its beam:

- a tripod station with a known position (a bimscan cloud's header, an E57 scan's pose, or a
  ``--stations`` file): its points' view is the station;
- station ids without positions (another tool's LAS with point source ids, or scans told apart
  by gaps in their GPS time): each station's position is estimated from its own points
  (``estimate_origin``);
- a mobile scan: the points of each ``window_s`` seconds of walk form a view, its origin the mean
  of their beam origins (``sensor_xyz``) or of the walk's trajectory file over that time.

A merged cloud with none of these cannot say where its beams came from; it is refused with the
ways to give the stations.

A station's origin is estimated from what its points are: first returns on the model's surfaces.
Seen from the true origin every point lies on the front of its surface (the side its outward
normal faces) and no built element stands between them; from elsewhere points fall behind walls
and on the backs of surfaces. ``estimate_origin`` scores places by the share of the station's
points they explain so (rays cast through the elements its points lie on: those are built),
on a grid around the densest part of its points (a scanner's density falls with the square of the
range), and refines the best. First, though, it asks the pulses themselves (``refine_by_lines``):
a rotating-mirror scanner's consecutive pulses lie on vertical lines through its origin, equally
spaced in elevation and in time; that places it to millimetres when the lines come from many
headings, and no single line carries the answer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from bimscan.compare.distance import BandDistances
from bimscan.compare.surfaces import ModelSurfaces
from bimscan.survey.planning.surface import triangle_areas
from bimscan.errors import CompareError
from bimscan.scan.probe import Prober
from bimscan.types import SceneMesh

ESTIMATE_CELL_DEG = 1.0  # the angular cells of the hidden-point count
HIDDEN_MARGIN = 0.05  # a point is hidden when it lies this share (plus 5 cm) behind its cell's nearest
SEARCH_RADIUS_M = 6.0
SEARCH_STEP_M = 0.5
COARSE_POINTS = 3000  # points the grid search scores each place with; the refinement takes all the sample
SEARCH_HEIGHTS_M = (0.6, 1.0, 1.4, 1.8)  # beam origin above the station's floor (its lowest points around)
ON_SURFACE_M = 0.05  # a point this near the model lies on it; a ray reaching this near a point reaches it
FACING_COSINE = 0.02  # a surface is seen from its front: the beam meets it from the side its normal faces
LINE_ITERATIONS = 20
MIN_LINE_POINTS = 12
MIN_LINE_EXTENT_M = 0.15  # a piece shorter than this in plan view (up a wall) says nothing of the origin's xy,
MIN_LINE_SHAPE = 50.0  # nor one less than this many times longer than it strays from a straight line
MAX_LINE_RMS_M = 0.01  # a run farther than this from a straight line in plan view is no mirror line
MIN_LINES = 8
LINE_MISS_M = 0.02
MAX_LINE_LEVERAGE = 0.2  # no one mirror line may carry more than this share of where the lines meet
PIECE_POINTS = (64, 512)  # the runs cut into pieces of these many points: pieces of mirror lines for the origin's
                         # xy (a dense scanner's 64 pulses span too little of a small room's floor)
TIMED_HEIGHT_SPAN_M = 4.0  # timed lines search the height this far around the first estimate, in 20 cm steps
TIMED_LINES = 60  # the height search reads at most this many timed lines (the longest)
MIN_RADIUS_M = 0.3  # points this near the origin's vertical say little of their elevation
MIN_TIMED_LINE_POINTS = 30  # a whole mirror line of timed pulses
MIN_LINE_SPAN_DEG = 5.0  # spanning this much elevation says where its pulses come from
LINE_TURN_DEG = 1.0  # consecutive pulses this far apart in heading are on different lines
LINE_JUMP_DEG = 5.0  # or this far apart in elevation (a mirror line's pulses lie a fraction of a degree apart)
LINE_GAP_TICKS = 50  # or this many pulse periods apart in time
LINE_HEIGHT_SPAN_M = 1.0  # the height is searched this far around the first estimate, in 2 cm steps
HEIGHT_LINES = 300  # the height search reads at most this many lines (the longest)
LINE_START_HEIGHT_M = 1.5  # the mirror lines' height search starts this far above the station's floor
LINES_TRUSTED_SHARE = 0.85  # an origin placed by the mirror lines is kept when it explains this much
LINES_TRUSTED_LOSS = 0.02  # or nearly as much as the grid search's best
LINES_CERTAIN = 0.9  # mirror lines this consistent place the origin whatever the model says of it
MIN_LINES_THROUGH = 0.7  # a station whose mirror lines mostly miss their meeting point is several stations
CLEAR_M = 0.01  # a point this much nearer to one element than to any other lies on that one's surface
MIN_BUILT_POINTS = 20  # an element holding this many of a station's points (and MIN_BUILT_SHARE of them)
MIN_BUILT_SHARE = 0.002  # stands, and hides what is behind it, when its points are at least
BUILT_DENSITY_SHARE = 0.1  # this share as dense per square metre as the station's typical element


class MergedStationsError(CompareError):
    """The points under one station id come from several scanner positions (a merged cloud)."""


@dataclass(frozen=True)
class PulseRun:
    """Consecutive points of one station as the scanner fired them: xyz (K, 3) float64 model frame,
    and their times (K,) seconds, None when the file holds none."""

    xyz: np.ndarray
    time: np.ndarray | None


@dataclass(frozen=True)
class View:
    """One origin of beams: its id (the station id, or the window index of a walk), the origin (3,)
    float64 model-frame metres, how it was found ("header", "e57", "file", "estimated",
    "sensor", "trajectory"), its points, and the angular cell of its range evidence (degrees)."""

    id: int
    origin: np.ndarray
    source: str
    points: int
    cell_deg: float


def hidden_share(points: np.ndarray, origin: np.ndarray, *, cell_deg: float = ESTIMATE_CELL_DEG) -> float:
    """The share of ``points`` (N, 3) that lie behind a nearer point of the same angular cell seen
    from ``origin`` (3,): 0 for the scanner's true origin (first returns only)."""
    offset = points - origin
    distance = np.linalg.norm(offset, axis=1)
    ok = distance > 0.3
    offset, distance = offset[ok], distance[ok]
    if not len(distance):
        return 1.0
    cell = np.radians(cell_deg)
    elevation = np.arcsin(np.clip(offset[:, 2] / distance, -1.0, 1.0))
    azimuth = np.arctan2(offset[:, 1], offset[:, 0])
    row = np.floor((elevation + np.pi / 2) / cell).astype(np.int64)
    columns = np.maximum(1, np.floor(2 * np.pi * np.cos((row + 0.5) * cell - np.pi / 2) / cell)).astype(np.int64)
    column = np.floor((azimuth + np.pi) / (2 * np.pi) * columns).astype(np.int64) % columns
    key = row * 100_000 + column
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    first = np.flatnonzero(np.r_[True, key_sorted[1:] != key_sorted[:-1]])
    nearest = np.minimum.reduceat(distance[order], first)
    group = np.cumsum(np.r_[True, key_sorted[1:] != key_sorted[:-1]]) - 1
    hidden = distance[order] > nearest[group] * (1 + HIDDEN_MARGIN) + 0.05
    return float(hidden.mean())


def estimate_origin(points: np.ndarray, surfaces: ModelSurfaces, distances: BandDistances,
                    runs: list[PulseRun]) -> tuple[np.ndarray, float, bool]:
    """The beam origin (3,) of a tripod station from a sample of its points (N, 3) and runs of its
    consecutive points (``runs``), all in the model's frame; the share of the sample it
    explains; whether its mirror lines placed it (to millimetres; else to a grid search's
    decimetres). See the module docs."""
    if len(points) < 100:
        raise CompareError(f"a station holds {len(points)} points, too few to find where it stood; give its "
                           "position with --stations")
    answer = distances.query(points)
    with np.errstate(invalid="ignore"):  # inf - inf: no surface near
        # on one element's surface, clearly nearer to it than to any other (not on a face two share)
        on = (answer.distance < ON_SURFACE_M) & (answer.second - answer.distance > CLEAR_M)
    if on.sum() < 50:
        raise CompareError("a station's points lie off the model's surfaces; check the alignment, or give the "
                           "station's position with --stations")
    mesh = surfaces.mesh
    points, normal = points[on], surfaces.outward[answer.triangle[on]]
    component = mesh.face_component[answer.triangle[on]]
    held = np.bincount(component, minlength=int(mesh.face_component.max()) + 1)
    # built (and so hiding what is behind it): an element holding points as densely as the station
    # covers what it sees, not a few points near an element not yet built (a ceiling's face a few
    # centimetres under the slab's)
    area = np.bincount(mesh.face_component, weights=triangle_areas(mesh), minlength=len(held))
    density = np.divide(held, area, out=np.zeros(len(held)), where=area > 0)
    typical = float(np.percentile(density[held > 0], 75)) if (held > 0).any() else 0.0
    built = np.flatnonzero((held >= max(MIN_BUILT_POINTS, MIN_BUILT_SHARE * len(points)))
                           & (density >= BUILT_DENSITY_SHARE * typical))
    faces = np.isin(mesh.face_component, built)
    prober = Prober(SceneMesh(vertices=mesh.vertices, faces=mesh.faces[faces],
                              face_component=mesh.face_component[faces]))
    rng = np.random.default_rng(0)
    coarse = rng.choice(len(points), size=min(len(points), COARSE_POINTS), replace=False)

    def explained(origin: np.ndarray, index: np.ndarray) -> float:
        offset = points[index] - origin
        distance = np.linalg.norm(offset, axis=1)
        direction = offset / np.maximum(distance, 1e-9)[:, None]
        facing = np.einsum("ij,ij->i", -direction, normal[index]) > FACING_COSINE
        hit, _ = prober.cast(origin, direction)
        return float((facing & (hit >= distance - ON_SURFACE_M) & (distance > 0.3)).mean())

    xy = points[:, :2]
    density, xs, ys = np.histogram2d(xy[:, 0], xy[:, 1], bins=(
        max(1, int(np.ptp(xy[:, 0]) / 0.5) + 1), max(1, int(np.ptp(xy[:, 1]) / 0.5) + 1)))
    i, j = np.unravel_index(int(np.argmax(density)), density.shape)
    centre = np.array([(xs[i] + xs[i + 1]) / 2, (ys[j] + ys[j + 1]) / 2])
    near = np.linalg.norm(xy - centre, axis=1) < SEARCH_RADIUS_M
    floor = float(np.percentile(points[near, 2], 2)) if near.any() else float(points[:, 2].min())
    lined = refine_by_lines(runs, np.array([centre[0], centre[1], floor + LINE_START_HEIGHT_M]))
    if lined is not None:
        origin, through = lined
        if through < MIN_LINES_THROUGH:
            raise MergedStationsError(f"a station's mirror lines meet in no one place (only {through:.0%} of them pass through "
                               "the best): its points come from several scanner positions (a merged cloud under one "
                               "station id); give the stations with --stations FILE, or per-station ids")
        share = explained(origin, np.arange(len(points)))
        if share >= LINES_TRUSTED_SHARE or through >= LINES_CERTAIN:
            return origin, share, True
    steps = np.arange(-SEARCH_RADIUS_M, SEARCH_RADIUS_M + 1e-9, SEARCH_STEP_M)
    best, best_origin = -1.0, np.array([centre[0], centre[1], floor + SEARCH_HEIGHTS_M[1]])
    for dx in steps:
        for dy in steps:
            for height in SEARCH_HEIGHTS_M:
                origin = np.array([centre[0] + dx, centre[1] + dy, floor + height])
                score = explained(origin, coarse)
                if score > best:
                    best, best_origin = score, origin
    every = np.arange(len(points))
    best = explained(best_origin, every)
    step = SEARCH_STEP_M / 2
    while step > 0.01:  # pattern search around the best grid point, on every point
        improved = False
        for axis in range(3):
            for sign in (-1.0, 1.0):
                origin = best_origin.copy()
                origin[axis] += sign * step
                score = explained(origin, every)
                if score > best:
                    best, best_origin, improved = score, origin, True
        if not improved:
            step /= 2
    lined = refine_by_lines(runs, best_origin)
    if lined is not None and explained(lined[0], every) >= best - LINES_TRUSTED_LOSS:
        return lined[0], explained(lined[0], every), True
    return best_origin, best, False


def _piece_lines(runs: list[PulseRun]) -> tuple[list[np.ndarray], np.ndarray, np.ndarray, np.ndarray]:
    """The runs cut into pieces of each of ``PIECE_POINTS`` consecutive points (pieces of mirror
    lines), and those that are straight lines in plan view: (their points, plan-view normals (L, 2),
    offsets (L,) so that normal @ xy = offset on the line, lengths (L,) metres)."""
    segments: list[np.ndarray] = []
    normals, offsets, extents = [], [], []
    for size in PIECE_POINTS:
        for run in runs:
            n = len(run.xyz)
            bounds = [(a, min(a + size, n)) for a in range(0, n, size)]
            for length in {b - a for a, b in bounds}:
                if length < MIN_LINE_POINTS:
                    continue
                starts = np.array([a for a, b in bounds if b - a == length])
                pieces = run.xyz[starts[:, None] + np.arange(length)]  # (m, length, 3)
                centre = pieces[:, :, :2].mean(axis=1)
                centred = pieces[:, :, :2] - centre[:, None, :]
                _, vectors = np.linalg.eigh(np.einsum("mki,mkj->mij", centred, centred) / length)
                along, across = vectors[:, :, 1], vectors[:, :, 0]
                extent = np.ptp(np.einsum("mki,mi->mk", centred, along), axis=1)
                straight = np.sqrt(np.mean(np.einsum("mki,mi->mk", centred, across) ** 2, axis=1))
                good = (extent >= MIN_LINE_EXTENT_M) & (straight <= MAX_LINE_RMS_M) & (extent >= MIN_LINE_SHAPE * straight)
                for i in np.flatnonzero(good).tolist():
                    segments.append(pieces[i])
                normals.append(across[good])
                offsets.append(np.einsum("mi,mi->m", across[good], centre[good]))
                extents.append(extent[good])
    if not segments:
        return [], np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    return segments, np.concatenate(normals), np.concatenate(offsets), np.concatenate(extents)


def refine_by_lines(runs: list[PulseRun], start: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The beam origin (3,) from runs of a station's consecutive points (in the order the scanner
    fired them), starting near ``start``, and the share of the mirror lines' pieces (by weight)
    that pass through it (near 1 for one scanner position; far less for a merged cloud); None when
    the runs show no mirror lines (another tool shuffled the points, or the station saw too little).

    A rotating-mirror scanner fires its pulses along vertical lines: the points of one line lie in
    a vertical half-plane through the beam origin, so in plan view a piece of a run that spans some
    depth (a line across a floor or a ceiling) is a straight line through the origin's xy: the
    origin is their least-squares intersection, each weighed by the square of its length. Along a
    line the pulses are equally spaced in elevation (the mirror turns evenly between pulses): the
    origin's height is where the elevations of each whole line grow most evenly with the pulses'
    times, or where a line's elevation steps are most even when the file has no times.
    """
    segments, normal, offset, extent = _piece_lines(runs)
    weight = extent**2
    if len(segments) < MIN_LINES:
        return None
    use = np.ones(len(normal), dtype=bool)
    origin = np.array(start, dtype=np.float64)
    scale = np.inf
    for _ in range(LINE_ITERATIONS):  # least squares, leaving out the lines that miss the answer by more
        w = weight * use             # than a scale that shrinks towards LINE_MISS_M
        system = (normal * w[:, None]).T @ normal
        if np.linalg.cond(system) > 1e6:
            return None  # every line points one way: the runs saw too little of the round
        origin[:2] = np.linalg.solve(system, (normal * (w * offset)[:, None]).sum(axis=0))
        miss = np.abs(normal @ origin[:2] - offset)
        scale = max(min(scale, float(np.median(miss[use]))), LINE_MISS_M)
        kept = miss <= 3.0 * scale
        if np.array_equal(kept, use) and scale == LINE_MISS_M:
            break
        use = kept
        if not use.any():
            return None
    kept_normal, kept_weight = normal[use], weight[use]
    system = (kept_normal * kept_weight[:, None]).T @ kept_normal
    if np.linalg.cond(system) > 1e6:
        return None
    leverage = kept_weight * np.einsum("ij,jk,ik->i", kept_normal, np.linalg.inv(system), kept_normal)
    if leverage.max() > MAX_LINE_LEVERAGE:
        return None  # one or two lines place the origin (the rest agree on a direction only): not trusted
    timed = _timed_lines(runs, origin)
    if timed is not None:
        height, radius, time, starts = timed
        score = lambda heights: _time_unevenness(height, radius, time, starts, heights)  # noqa: E731
    else:
        kept = np.flatnonzero(use)
        kept = kept[np.argsort(-weight[kept], kind="stable")[:HEIGHT_LINES]]  # the longest pieces say the height
        lines = [segments[i] for i in np.sort(kept)]
        height = np.concatenate([line[:, 2] for line in lines])
        radius = np.concatenate([np.hypot(line[:, 0] - origin[0], line[:, 1] - origin[1]) for line in lines])
        starts = np.concatenate([[0], np.cumsum([len(line) for line in lines])]).astype(np.int64)
        score = lambda heights: _elevation_unevenness(height, radius, starts, heights)  # noqa: E731
    span, steps = (TIMED_HEIGHT_SPAN_M, (0.2, 0.02, 0.002)) if timed is not None else (LINE_HEIGHT_SPAN_M, (0.02, 0.002))
    for step in steps:  # each search finer, around the best of the last
        heights = origin[2] + np.arange(-span, span + 1e-9, step)
        origin[2] = heights[int(np.argmin(score(heights)))]
        span = step
    through = np.abs(normal @ origin[:2] - offset) <= 3.0 * LINE_MISS_M
    return origin, float(weight[through].sum() / weight.sum())


def _timed_lines(runs: list[PulseRun], origin: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """The whole mirror lines of timed runs, seen from ``origin``'s xy: (heights, plan-view
    distances, times, line starts), the longest ``TIMED_LINES`` lines; None when the runs have no
    times (or too few lines). A line ends where the heading from the origin turns (the mirror's other
    side, the next station), where the elevation jumps (the mirror's next face or turn) or where the
    times do not go on (a gap, a file that stores no real times)."""
    if not runs or any(run.time is None for run in runs):
        return None
    lines: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for run in runs:
        offset = run.xyz[:, :2] - origin[:2]
        radius = np.hypot(offset[:, 0], offset[:, 1])
        near = radius > MIN_RADIUS_M
        xyz, radius, time = run.xyz[near], radius[near], np.asarray(run.time, dtype=np.float64)[near]
        if len(xyz) < MIN_TIMED_LINE_POINTS:
            continue
        heading = np.degrees(np.arctan2(xyz[:, 1] - origin[1], xyz[:, 0] - origin[0]))
        elevation = np.degrees(np.arctan2(xyz[:, 2] - origin[2], radius))
        tick = np.diff(time)
        typical = float(np.median(tick))
        if not typical > 0:
            return None  # times that stand still say nothing of the pulses
        breaks = ((np.abs((np.diff(heading) + 180.0) % 360.0 - 180.0) > LINE_TURN_DEG)
                  | (np.abs(np.diff(elevation)) > LINE_JUMP_DEG) | (tick <= 0) | (tick > LINE_GAP_TICKS * typical))
        bounds = np.r_[0, np.flatnonzero(breaks) + 1, len(xyz)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            if b - a >= MIN_TIMED_LINE_POINTS and np.ptp(elevation[a:b]) >= MIN_LINE_SPAN_DEG:
                lines.append((xyz[a:b, 2], radius[a:b], time[a:b]))
    if len(lines) < MIN_LINES:
        return None
    lines.sort(key=lambda line: -len(line[0]))
    lines = lines[:TIMED_LINES]
    starts = np.concatenate([[0], np.cumsum([len(line[0]) for line in lines])]).astype(np.int64)
    return (np.concatenate([line[0] for line in lines]), np.concatenate([line[1] for line in lines]),
            np.concatenate([line[2] - line[2][0] for line in lines]), starts)


@nb.njit(cache=True, parallel=True)
def _time_unevenness(height: np.ndarray, radius: np.ndarray, time: np.ndarray, starts: np.ndarray,
                     heights: np.ndarray) -> np.ndarray:
    """How far the pulses' elevations, seen from each of ``heights``, stray from growing evenly with
    their times: the median over lines (line l: ``[starts[l]:starts[l + 1]]``) of the residual of a
    straight line fitted to elevation against time, relative to the elevations' spread (sqrt(1 - R^2):
    from far above or below, every line's elevations shrink together); inf without lines."""
    out = np.empty(heights.shape[0])
    n_lines = starts.shape[0] - 1
    for h in nb.prange(heights.shape[0]):
        z = heights[h]
        residuals = np.empty(n_lines)
        for line in range(n_lines):
            a, b = starts[line], starts[line + 1]
            n = b - a
            mean_t, mean_e = 0.0, 0.0
            elevation = np.empty(n)
            for k in range(n):
                elevation[k] = np.arctan2(height[a + k] - z, radius[a + k])
                mean_t += time[a + k]
                mean_e += elevation[k]
            mean_t /= n
            mean_e /= n
            stt, ste, see = 0.0, 0.0, 0.0
            for k in range(n):
                stt += (time[a + k] - mean_t) ** 2
                ste += (time[a + k] - mean_t) * (elevation[k] - mean_e)
                see += (elevation[k] - mean_e) ** 2
            slope = ste / stt if stt > 0.0 else 0.0
            total = 0.0
            for k in range(n):
                r = elevation[k] - mean_e - slope * (time[a + k] - mean_t)
                total += r * r
            residuals[line] = np.sqrt(total / see) if see > 0.0 else np.inf
        out[h] = np.median(residuals) if n_lines > 0 else np.inf
    return out


@nb.njit(cache=True, parallel=True)
def _elevation_unevenness(height: np.ndarray, radius: np.ndarray, starts: np.ndarray,
                          heights: np.ndarray) -> np.ndarray:
    """How unevenly the pulses of the lines (line l: heights and plan-view distances
    ``[starts[l]:starts[l + 1]]``) are spaced in elevation seen from each of ``heights``: the
    median over lines of the spread of their elevation steps (median absolute deviation) over the
    median step; inf where no line has steps."""
    out = np.empty(heights.shape[0])
    n_lines = starts.shape[0] - 1
    for h in nb.prange(heights.shape[0]):
        z = heights[h]
        spreads = np.empty(n_lines)
        m = 0
        for line in range(n_lines):
            a, b = starts[line], starts[line + 1]
            if b - a < 2:
                continue
            steps = np.empty(b - a - 1)
            previous = np.arctan2(height[a] - z, radius[a])
            for k in range(a + 1, b):
                elevation = np.arctan2(height[k] - z, radius[k])
                steps[k - a - 1] = abs(elevation - previous)
                previous = elevation
            typical = np.median(steps)
            if typical > 0.0:
                spreads[m] = np.median(np.abs(steps - typical)) / typical
                m += 1
        out[h] = np.median(spreads[:m]) if m else np.inf
    return out


def angular_spacing_deg(points: np.ndarray, origin: np.ndarray) -> float:
    """The angular spacing of a station's pulses (degrees) from a contiguous run of its points: the
    median distance to the 4th nearest neighbour in (azimuth x cos(elevation), elevation), the
    larger of the two steps of a rotating scanner's grid."""
    from scipy.spatial import cKDTree

    offset = points - origin
    distance = np.linalg.norm(offset, axis=1)
    ok = distance > 0.3
    if ok.sum() < 10:
        return 1.0
    offset, distance = offset[ok], distance[ok]
    elevation = np.degrees(np.arcsin(np.clip(offset[:, 2] / distance, -1.0, 1.0)))
    azimuth = np.degrees(np.arctan2(offset[:, 1], offset[:, 0]))
    angles = np.column_stack([azimuth * np.cos(np.radians(elevation)), elevation])
    neighbours = cKDTree(angles).query(angles, k=5)[0][:, 4]
    return float(np.median(neighbours))

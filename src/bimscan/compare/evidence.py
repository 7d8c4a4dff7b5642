"""What the scan's beams say about each surface sample of the model: seen, passed through, hidden,
or nothing (the visibility reasoning of Tuttas et al. 2015, on each station's range image).

A beam from a view's origin towards a model surface sample either

- returned from about the sample's range (within ``support_m``, widened by the spread a cell
  has at grazing incidence) from a point whose nearest model surface is the sample's element:
  the element stands there: the sample is **seen** (supported). (A return nearer to another
  element's surface is that element's: a 19 mm floor finish missing from its slab is not seen
  on the slab's top 19 mm below it; it is simply not decided.);
- returned only from farther away: the beam went through where the surface would be: the
  sample is **passed** (evidence that the element is not there);
- returned from nearer only: something in front hides it (another element, clutter, a person):
  **hidden**, no decision;
- returned nothing, in a direction where the tripod scanner fired all around (its returns fill
  the neighbouring directions) and every return around came from beyond the sample: the beam
  went out through where the surface would be, into the sky or past the scanner's range:
  **passed** as well (an opening with no wall or window in it). A return around at or before the
  sample's range says the surface may well be there and this pulse came back too weak (a dark or
  glossy finish, a grazing angle): nothing is decided. Where it did not fire all around (the edge
  of its field of view, a walk's multi-beam lidar with gaps between its rings), no return decides
  nothing.

Glazing decides nothing either way (a laser passes glass): samples on transparent surfaces are
left out by the caller.

The beams are the scan's points of that view, binned by direction into cells of the view's
``cell_deg`` (about one and a half times its pulse spacing, so no cell between scan lines is
empty). Only the cells some sample looks through are kept: for every (view, sample) pair the
nearest return of its cell and the count of returns within its range window, updated chunk by
chunk as the scan streams, so memory follows the samples and views, never the points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from bimscan.compare.views import View
from bimscan.survey.planning.surface import SurfaceSamples

MIN_RANGE_M = 0.5
FIRED_DEG = 1.0  # the grid of each view's image of its nearest returns by direction
FIRED_ROWS, FIRED_COLUMNS = int(180 / FIRED_DEG), int(360 / FIRED_DEG)
MAX_WINDOW_M = 0.5  # the widest range window at grazing incidence
_VIEW_SHIFT = 40  # a pair's key: view << 40 | cell


@nb.njit(cache=True, nogil=True, inline="always")
def _cells(dx: float, dy: float, dz: float, distance: float, cell: float) -> tuple[int, int]:
    """Direction (dx, dy, dz) of length ``distance``: its cell on the fired images' grid (rows of
    FIRED_DEG in elevation, columns in azimuth) and its angular cell key: rows of ``cell`` radians
    in elevation, each cut into columns of ``cell`` of arc (so cells near the zenith are not slivers)."""
    elevation = np.arcsin(min(max(dz / max(distance, 1e-12), -1.0), 1.0)) + np.pi / 2
    azimuth = np.arctan2(dy, dx) + np.pi
    fired = (min(int(elevation / np.radians(FIRED_DEG)), FIRED_ROWS - 1) * FIRED_COLUMNS
             + min(int(azimuth / np.radians(FIRED_DEG)), FIRED_COLUMNS - 1))
    row = int(np.floor(elevation / cell))
    columns = max(1, int(np.floor(2 * np.pi * np.cos((row + 0.5) * cell - np.pi / 2) / cell)))
    column = int(np.floor(azimuth / (2 * np.pi) * columns)) % columns
    return fired, (row << 20) | column


@nb.njit(cache=True)
def fired_cells(offset: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """(N,) int64 each direction's cell on the fired images' grid."""
    cells = np.empty(offset.shape[0], dtype=np.int64)
    for i in range(offset.shape[0]):
        cells[i] = _cells(offset[i, 0], offset[i, 1], offset[i, 2], distance[i], 1.0)[0]
    return cells


@nb.njit(cache=True)
def cell_keys(offset: np.ndarray, distance: np.ndarray, cell: float) -> np.ndarray:
    """(N,) int64 the angular cell of each direction ``offset`` (N, 3) of length ``distance`` (N,)."""
    keys = np.empty(offset.shape[0], dtype=np.int64)
    for i in range(offset.shape[0]):
        keys[i] = _cells(offset[i, 0], offset[i, 1], offset[i, 2], distance[i], cell)[1]
    return keys


@dataclass
class Evidence:
    """The (view, sample) pairs and what the beams said of each: key (P,) int64 sorted, sample (P,)
    int64, the sample's component (P,) int64, expected range (P,) float64, window (P,) float64 (the support half-width), nearest (P,)
    float64 (the nearest return of the cell, inf: none), support (P,) int64 (returns within the
    window, of points that may support)."""

    key: np.ndarray
    sample: np.ndarray
    component: np.ndarray
    expected: np.ndarray
    window: np.ndarray
    nearest: np.ndarray
    support: np.ndarray
    coarse: np.ndarray  # (P,) int64 the pair's direction on the fired images' grid: row * FIRED_COLUMNS + column
    fired: np.ndarray  # (V, FIRED_ROWS, FIRED_COLUMNS) float32: the view's nearest return in that direction (inf:
                       # none); (0, ...) when no view decides by an empty direction (a walk)
    view_cell_rad: np.ndarray  # (V,) the cell of each view (by position in the views list)
    empty_decides: np.ndarray  # (V,) bool: no return in a fired-all-around direction is a pass (tripods)
    view_index: dict[int, int]  # view id -> position

    @staticmethod
    def plan(samples: SurfaceSamples, views: list[View], *, support_m: float, max_incidence_deg: float,
             max_range_m: np.ndarray, keep: list[np.ndarray | None]) -> Evidence:
        """Pairs of every view with the samples it may see: in its range (``max_range_m`` (V,)), met
        at most ``max_incidence_deg`` from the sample's normal, and allowed by ``keep[v]`` ((S,) bool
        or None) (the caller's coarse look at the view's points)."""
        keys, pair_sample, expected, window, coarse = [], [], [], [], []
        cos_limit = np.cos(np.radians(max_incidence_deg))
        for position, view in enumerate(views):
            offset = samples.xyz - view.origin
            distance = np.linalg.norm(offset, axis=1)
            cosine = np.abs(np.einsum("ij,ij->i", offset, samples.normal)) / np.maximum(distance, 1e-12)
            ok = (distance >= MIN_RANGE_M) & (distance <= max_range_m[position]) & (cosine >= cos_limit)
            if keep[position] is not None:
                ok &= keep[position]  # type: ignore[operator]
            index = np.flatnonzero(ok)
            cell = np.radians(view.cell_deg)
            tangent = np.sqrt(np.maximum(1.0 - cosine[index] ** 2, 0.0)) / np.maximum(cosine[index], 1e-6)
            keys.append((np.int64(position) << _VIEW_SHIFT) | cell_keys(offset[index], distance[index], cell))
            pair_sample.append(index)
            expected.append(distance[index])
            window.append(np.minimum(support_m + distance[index] * cell * tangent, MAX_WINDOW_M))
            coarse.append(fired_cells(offset[index], distance[index]))
        key = np.concatenate(keys) if keys else np.zeros(0, np.int64)
        order = np.argsort(key, kind="stable")
        n = len(key)
        sample = np.concatenate(pair_sample)[order].astype(np.int64) if n else np.zeros(0, np.int64)
        return Evidence(key=key[order], sample=sample, component=samples.component[sample].astype(np.int64),
                        expected=np.concatenate(expected)[order] if n else np.zeros(0),
                        window=np.concatenate(window)[order] if n else np.zeros(0),
                        nearest=np.full(n, np.inf), support=np.zeros(n, dtype=np.int64),
                        coarse=np.concatenate(coarse)[order] if n else np.zeros(0, np.int64),
                        fired=np.full((len(views) if any(v.source != "sensor" for v in views) else 0, FIRED_ROWS,
                                       FIRED_COLUMNS), np.inf, dtype=np.float32),
                        view_cell_rad=np.array([np.radians(v.cell_deg) for v in views]),
                        empty_decides=np.array([v.source != "sensor" for v in views], dtype=np.bool_),
                        view_index={v.id: i for i, v in enumerate(views)})

    def add(self, xyz: np.ndarray, view_position: np.ndarray, origins: np.ndarray, component: np.ndarray) -> None:
        """Take a chunk of points (N, 3) model frame, each with its view's position in the views
        list (N,) int64 (-1: none), the views' origins (V, 3), and the component it may support (N,)
        int64 (its nearest model surface's; -1: none)."""
        if len(self.key):
            _update(self.key, self.component, self.expected, self.window, self.nearest, self.support, self.fired,
                    np.ascontiguousarray(xyz), view_position, origins, self.view_cell_rad, component)

    def states(self, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
        """(seen (S,) bool, passed (S,) bool): a sample is seen when some view's beams returned from
        its range, passed when none did and some view's beams all went beyond it."""
        seen_pair = self.support > 0
        passed_pair = ~seen_pair & np.isfinite(self.nearest) & (self.nearest > self.expected + self.window)
        view = (self.key >> _VIEW_SHIFT).astype(np.int64)
        if len(self.fired) and len(view):
            # the nearest return of each direction and its eight neighbours, and whether all nine returned
            image = self.fired.reshape(len(self.fired), FIRED_ROWS, FIRED_COLUMNS)
            nearest_around = minimum_filter(image, size=(1, 3, 3), mode="wrap").reshape(len(image), -1)
            farthest_around = maximum_filter(image, size=(1, 3, 3), mode="wrap").reshape(len(image), -1)
            fired_all_around = np.isfinite(farthest_around[view, self.coarse])
            beyond = nearest_around[view, self.coarse] > self.expected + self.window
            passed_pair |= ~np.isfinite(self.nearest) & self.empty_decides[view] & fired_all_around & beyond
        seen = np.zeros(n_samples, dtype=bool)
        seen[self.sample[seen_pair]] = True
        passed = np.zeros(n_samples, dtype=bool)
        passed[self.sample[passed_pair]] = True
        return seen, passed & ~seen


@nb.njit(cache=True, parallel=True)
def _locate(pair_key: np.ndarray, xyz: np.ndarray, view_position: np.ndarray, origins: np.ndarray,
            cell_rad: np.ndarray, first: np.ndarray, fired: np.ndarray, distance: np.ndarray) -> None:
    """Each point's beam (from its view's origin): the first pair of its view's cell (``first``, -1:
    none, or no view), its fired-image cell and its range. Read-only on the pairs: parallel."""
    n = pair_key.shape[0]
    for i in nb.prange(xyz.shape[0]):
        v = view_position[i]
        first[i] = -1
        if v < 0:
            continue
        dx, dy, dz = xyz[i, 0] - origins[v, 0], xyz[i, 1] - origins[v, 1], xyz[i, 2] - origins[v, 2]
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        distance[i] = r
        fired[i], key = _cells(dx, dy, dz, r, cell_rad[v])
        k = (np.int64(v) << _VIEW_SHIFT) | key
        j = np.searchsorted(pair_key, k)
        if j < n and pair_key[j] == k:
            first[i] = j


@nb.njit(cache=True, nogil=True)
def _record(pair_key: np.ndarray, pair_component: np.ndarray, expected: np.ndarray, window: np.ndarray,
            nearest: np.ndarray, support: np.ndarray, fired_image: np.ndarray, view_position: np.ndarray,
            component: np.ndarray, first: np.ndarray, fired: np.ndarray, distance: np.ndarray) -> None:
    """Into the pairs ``_locate`` found, in the points' order: the nearest return, and a support when
    it lies in the pair's range window and on the pair's element."""
    n = pair_key.shape[0]
    for i in range(first.shape[0]):
        v = view_position[i]
        if v < 0:
            continue
        if fired_image.shape[0] > 0:
            f = fired[i]
            row, column = f // FIRED_COLUMNS, f % FIRED_COLUMNS
            if distance[i] < fired_image[v, row, column]:
                fired_image[v, row, column] = distance[i]
        j = first[i]
        if j < 0:
            continue
        k = pair_key[j]
        r = distance[i]
        while j < n and pair_key[j] == k:
            if r < nearest[j]:
                nearest[j] = r
            if component[i] == pair_component[j] and abs(r - expected[j]) <= window[j]:
                support[j] += 1
            j += 1


def _update(pair_key: np.ndarray, pair_component: np.ndarray, expected: np.ndarray, window: np.ndarray,
            nearest: np.ndarray, support: np.ndarray, fired: np.ndarray, xyz: np.ndarray, view_position: np.ndarray,
            origins: np.ndarray, cell_rad: np.ndarray, component: np.ndarray) -> None:
    """Each point's beam (from its view's origin) into the pairs of its view's cell: the nearest
    return, and a support when it lies in the pair's range window and on the pair's element. The
    search runs on every core, the updates in the points' order (the same bytes every run)."""
    first = np.empty(len(xyz), dtype=np.int64)
    cells = np.zeros(len(xyz), dtype=np.int64)
    distance = np.zeros(len(xyz))
    _locate(pair_key, xyz, view_position, origins, cell_rad, first, cells, distance)
    _record(pair_key, pair_component, expected, window, nearest, support, fired, view_position, component, first,
            cells, distance)

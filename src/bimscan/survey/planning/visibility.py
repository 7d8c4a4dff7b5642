"""What a station sees, and how densely: the scanner's angular grid cast at every surface sample.

A rotating-mirror TLS fires pulses on a grid of directions: ``vertical_step`` apart in
elevation along a mirror line and ``horizontal_step`` apart in azimuth between lines
(``ScanSettings.vertical_step_deg`` / ``horizontal_step_deg``), inside its elevation window and
range limits. Around a direction at elevation ``el`` one pulse stands for the solid angle
``dv * dh * cos(el)``; at range ``r`` that is the area ``r^2 dv dh cos(el)`` across the beam, and on
a surface met at incidence ``theta`` (from its normal) ``r^2 dv dh cos(el) / cos(theta)``. So the
expected point density on the surface is

    density = cos(theta) / (r^2 * dv * dh * cos(el))   points per square metre

(docs/guide/planning.md derives it and checks it against scans). A sample is **seen** from a
position when the ray from the beam origin to it, cast through the scene's Embree BVH (the
``Prober``, the same engine the station checks use), first meets a surface at the sample's range,
on a triangle in the sample's own plane (within ``ON_PLANE_M``): the ray reaches the sample. A
surface in front of it hides it, and so does the element's own front face when the sample is on
its back face (the two faces of a 6 mm steel flange lie closer than the range tolerance); another
element's face flush with the sample's (a ceiling modelled flush with the slab's underside) does
not, whichever of the two the engine reports. The range lies in the scanner's limits, the
direction in its elevation window (and head rotation, for a partial station), and the incidence
is at most ``VISIBLE_INCIDENCE_DEG``. Its points count towards coverage only within the asked
incidence limit.

Nothing here trusts the winding of the model's triangles: authoring tools wind them either way
(a ceiling exported with its normals into the slab, a face whose triangles disagree), and a
scanner sees a surface from either side. The incidence is taken two-sided, and a hit counts by
the plane it lies in, not by the way its triangle faces. ``facing_stations`` then turns each
sample's normal towards the stations that see it, for what reads a side (the scan's measure,
the plan's ceiling view).

Rays go only where something may be seen: each position first casts a coarse fan
(``COARSE_DIRECTIONS`` over its elevation window, about 1.4 degrees apart) and marks the
(component, 1 m voxel) cells it meets, with their neighbours; samples elsewhere are hidden from it
(behind a wall, on another storey) and get no ray. A patch narrower than the fan's spacing at its
range (25 cm at 10 m) in a cell no coarse ray met can be missed; a station 10 m away puts a tenth
of its density there anyway.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy import sparse

from bimscan.progress import progress_bar
from bimscan.scan.device import ScannerModel, ScanSettings
from bimscan.scan.probe import Prober, sphere_directions
from bimscan.survey.planning.config import VISIBLE_INCIDENCE_DEG
from bimscan.survey.planning.surface import SurfaceSamples

RAYS_PER_CAST = 2_000_000  # rays per call of the engine: ~50 MB of float32 rays
# A ray aimed at a sample counts it seen when it meets the sample's component this close to the
# sample's range: float32 rays are good to ~0.1 mm here, and a thin element's back face lies at
# least its thickness (> 5 mm) behind its front one.
HIT_TOLERANCE_M = 0.005
# ... and on a triangle whose plane passes this close to the sample: its own triangle, another of
# the same face, or a face flush with it, however any is wound (the far face of a 2 mm plate lies
# outside it).
ON_PLANE_M = 0.001
COARSE_DIRECTIONS = 20_000  # the coarse fan of the visibility pre-pass, within the elevation window
CELL_M = 1.0  # its cells: a sample is tested when a coarse ray met its component in its cell or a neighbour


@dataclass(frozen=True)
class BeamGrid:
    """The angular grid of one station's pulses: steps (radians), elevation window (radians),
    head rotation (azimuth start and span from the station's heading, radians) and range limits."""

    vertical_step_rad: float
    horizontal_step_rad: float
    elevation_min_rad: float
    elevation_max_rad: float
    azimuth_start_rad: float
    azimuth_span_rad: float
    min_range_m: float
    max_range_m: float

    @staticmethod
    def of(settings: ScanSettings, scanner: ScannerModel) -> BeamGrid:
        low, high = settings.window(scanner)
        return BeamGrid(vertical_step_rad=math.radians(settings.vertical_step_deg(scanner)),
                        horizontal_step_rad=math.radians(settings.horizontal_step_deg()),
                        elevation_min_rad=math.radians(low), elevation_max_rad=math.radians(high),
                        azimuth_start_rad=math.radians(settings.head_start_deg),
                        azimuth_span_rad=math.radians(settings.head_stop_deg - settings.head_start_deg),
                        min_range_m=scanner.min_range_m, max_range_m=scanner.max_range_m)

    def density(self, range_m: np.ndarray, cos_incidence: np.ndarray, elevation_rad: np.ndarray) -> np.ndarray:
        """Expected points per square metre (see the module docs) at the given ranges, |cos| of the
        incidence angles and beam elevations (arrays of one shape)."""
        return cos_incidence / (range_m**2 * self.vertical_step_rad * self.horizontal_step_rad * np.cos(elevation_rad))

    def reach_m(self, density_pts_m2: float) -> float:
        """The range at which a surface facing the beam on the horizon gets ``density_pts_m2``."""
        return math.sqrt(1.0 / (density_pts_m2 * self.vertical_step_rad * self.horizontal_step_rad))


@dataclass(frozen=True)
class Visibility:
    """Which samples each station position sees, and the density it puts on them.

    sample (P,) int64 and station (P,) int64: the pairs (sample seen from station), grouped by
    station; density_pts_m2 (P,) float32: the expected density there, 0 where the incidence
    exceeds the limit (seen, but its points do not count). n_samples, n_stations: the shape.
    """

    sample: np.ndarray
    station: np.ndarray
    density_pts_m2: np.ndarray
    n_samples: int
    n_stations: int

    @cached_property
    def matrix(self) -> sparse.csc_matrix:
        """(S, K) sparse density matrix (points per square metre), one column per station."""
        return sparse.csc_matrix((self.density_pts_m2.astype(np.float64), (self.sample, self.station)),
                                 shape=(self.n_samples, self.n_stations))

    @cached_property
    def seen(self) -> np.ndarray:
        """(S,) bool: samples seen from at least one station, at any incidence up to ``VISIBLE_INCIDENCE_DEG``."""
        out = np.zeros(self.n_samples, dtype=bool)
        out[self.sample] = True
        return out

    @cached_property
    def reachable(self) -> np.ndarray:
        """(S,) bool: samples seen from at least one station within the incidence limit (the
        denominator of coverage: the surface some station can scan as asked)."""
        out = np.zeros(self.n_samples, dtype=bool)
        out[self.sample[self.density_pts_m2 > 0]] = True
        return out

    def density_of(self, stations: np.ndarray) -> np.ndarray:
        """(S,) float64 summed density of the stations (indices) on every sample."""
        if len(stations) == 0:
            return np.zeros(self.n_samples)
        return np.asarray(self.matrix[:, np.asarray(stations)].sum(axis=1)).ravel()


def compute_visibility(prober: Prober, samples: SurfaceSamples, heads: np.ndarray, grid: BeamGrid, *,
                       max_incidence_deg: float, headings_deg: np.ndarray | None = None,
                       progress: bool = False) -> Visibility:
    """The visibility (see the module docs) of ``samples`` from beam origins ``heads`` (K, 3) world
    metres (with ``headings_deg`` (K,), 0 when None), cast in batches through ``prober``'s engine."""
    k_total = len(heads)
    headings = np.zeros(k_total) if headings_deg is None else np.asarray(headings_deg, dtype=np.float64)
    cos_visible = math.cos(math.radians(VISIBLE_INCIDENCE_DEG))
    cos_limit = math.cos(math.radians(max_incidence_deg))
    full_turn = grid.azimuth_span_rad >= 2 * math.pi - 1e-9
    face_normal = prober.face_normals
    face_corner = prober.mesh.vertices[prober.mesh.faces[:, 0]]
    pairs_sample, pairs_station, pairs_density = [], [], []
    batch: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    batch_rays = 0

    def flush() -> None:
        nonlocal batch, batch_rays
        if not batch:
            return
        origins = np.concatenate([np.broadcast_to(heads[k], (len(idx), 3)) for k, idx, *_ in batch])
        directions = np.concatenate([d for _, _, d, _, _ in batch])
        t, triangle = prober.cast_faces(origins, directions)
        start = 0
        for k, idx, _, r, density in batch:
            end = start + len(idx)
            tri = triangle[start:end]
            safe = np.maximum(tri, 0)
            # the sample's own face (or one flush with it), not the element's other side a few millimetres in front
            off_plane = np.abs(np.einsum("ij,ij->i", face_normal[safe], samples.xyz[idx] - face_corner[safe]))
            seen = (tri >= 0) & (np.abs(t[start:end] - r) <= HIT_TOLERANCE_M) & (off_plane <= ON_PLANE_M)
            pairs_sample.append(idx[seen])
            pairs_station.append(np.full(int(seen.sum()), k, dtype=np.int64))
            pairs_density.append(density[seen])
            start = end
        batch, batch_rays = [], 0

    cells = _CellIndex(samples)
    fan = _coarse_fan(grid)
    with progress_bar(total=k_total, desc="visibility", unit="station", enabled=progress) as bar:
        for k in range(k_total):
            t_fan, component_fan = prober.cast(heads[k], fan)
            met = np.isfinite(t_fan)
            near = cells.samples_near(heads[k] + t_fan[met, None] * fan[met], component_fan[met])
            delta = samples.xyz[near] - heads[k]
            r = np.sqrt(np.einsum("ij,ij->i", delta, delta))
            ok = (r >= grid.min_range_m) & (r <= grid.max_range_m)
            elevation = np.arcsin(np.clip(delta[:, 2] / np.maximum(r, 1e-12), -1.0, 1.0))
            ok &= (elevation >= grid.elevation_min_rad) & (elevation < grid.elevation_max_rad)
            cos_incidence = np.abs(np.einsum("ij,ij->i", delta, samples.normal[near])) / np.maximum(r, 1e-12)
            ok &= cos_incidence >= cos_visible
            if not full_turn:
                azimuth = np.arctan2(delta[:, 1], delta[:, 0]) - math.radians(headings[k]) - grid.azimuth_start_rad
                ok &= np.mod(azimuth, 2 * math.pi) < grid.azimuth_span_rad
            local = np.flatnonzero(ok)
            if len(local):
                direction = (delta[local] / r[local, None]).astype(np.float32)
                density = np.where(cos_incidence[local] >= cos_limit,
                                   grid.density(r[local], cos_incidence[local], elevation[local]), 0.0)
                batch.append((k, near[local], direction, r[local], density.astype(np.float32)))
                batch_rays += len(local)
            if batch_rays >= RAYS_PER_CAST:
                flush()
            bar.update(1)
        flush()
    return Visibility(sample=np.concatenate(pairs_sample) if pairs_sample else np.zeros(0, np.int64),
                      station=np.concatenate(pairs_station) if pairs_station else np.zeros(0, np.int64),
                      density_pts_m2=np.concatenate(pairs_density) if pairs_density else np.zeros(0, np.float32),
                      n_samples=len(samples), n_stations=k_total)


def facing_stations(samples: SurfaceSamples, visibility: Visibility, heads: np.ndarray) -> SurfaceSamples:
    """The samples with each normal turned towards the stations that see it (the side of its
    surface a scan holds points of; the side most of them stand on, by the cosine of each one's
    view), whatever way the model winds its triangles; a sample no station sees keeps its winding's."""
    delta = heads[visibility.station] - samples.xyz[visibility.sample]
    cosine = np.einsum("ij,ij->i", delta, samples.normal[visibility.sample]) / np.maximum(
        np.linalg.norm(delta, axis=1), 1e-12)
    vote = np.bincount(visibility.sample, weights=cosine, minlength=len(samples))
    return dataclasses.replace(samples, normal=np.where((vote < 0)[:, None], -samples.normal, samples.normal))


def _coarse_fan(grid: BeamGrid) -> np.ndarray:
    """(N, 3) float32 unit directions, evenly spread over the elevation window (about
    ``COARSE_DIRECTIONS``); the pre-pass ignores a partial head rotation (it only narrows what is tested)."""
    low, high = math.sin(grid.elevation_min_rad), math.sin(grid.elevation_max_rad)
    share = max((high - low) / 2.0, 1e-3)
    directions = sphere_directions(int(COARSE_DIRECTIONS / share))
    return directions[(directions[:, 2] >= low) & (directions[:, 2] < high)]


class _CellIndex:
    """Samples by (component, cell of ``CELL_M``): which samples lie in the cells a set of hits
    meets, or in their 26 neighbours, on the hit's own component."""

    def __init__(self, samples: SurfaceSamples) -> None:
        # two empty cells of margin all round: a neighbour's key never wraps into another row
        self.origin = (samples.xyz.min(axis=0) if len(samples) else np.zeros(3)) - 2 * CELL_M
        self.n_samples = len(samples)
        cell = self._cells(samples.xyz)
        self.shape = (cell.max(axis=0) + 3) if len(samples) else np.ones(3, dtype=np.int64)
        nx, ny, nz = (int(v) for v in self.shape)
        self.offsets = np.array([(a * ny + b) * nz + c for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)])
        key = self._keys(samples.component, cell)
        self.order = np.argsort(key, kind="stable")
        self.sorted_key = key[self.order]

    def _cells(self, xyz: np.ndarray) -> np.ndarray:
        return np.floor((xyz - self.origin) / CELL_M).astype(np.int64)

    def _keys(self, component: np.ndarray, cell: np.ndarray) -> np.ndarray:
        nx, ny, nz = (int(v) for v in self.shape)
        return ((component.astype(np.int64) * nx + cell[:, 0]) * ny + cell[:, 1]) * nz + cell[:, 2]

    def samples_near(self, points: np.ndarray, component: np.ndarray) -> np.ndarray:
        """Sorted sample indices in the cells of ``points`` (M, 3) on ``component`` (M,), or next to them."""
        if len(points) == 0 or self.n_samples == 0:
            return np.zeros(0, dtype=np.int64)
        cell = self._cells(points)
        inside = np.all((cell >= 1) & (cell < self.shape - 1), axis=1)  # hits off the sampled box meet no sample
        hit = np.unique(self._keys(component[inside], cell[inside]))
        keys = np.unique((hit[:, None] + self.offsets[None]).ravel())
        lo = np.searchsorted(self.sorted_key, keys, side="left")
        count = np.searchsorted(self.sorted_key, keys, side="right") - lo
        lo, count = lo[count > 0], count[count > 0]
        if len(lo) == 0:
            return np.zeros(0, dtype=np.int64)
        # the runs lo[i] .. lo[i] + count[i] of the sorted keys, flattened without a Python loop
        run_start = np.repeat(lo - np.r_[0, np.cumsum(count)[:-1]], count)
        mask = np.zeros(self.n_samples, dtype=bool)
        mask[self.order[run_start + np.arange(int(count.sum()))]] = True
        return np.flatnonzero(mask)

"""The coarse search: which way is up, which heading, which offset, with no starting guess.

Buildings are made of planes, and that is what the search matches:

- **Up.** The scan's floors and ceilings face up and its walls face sideways: up is the
  direction that the horizontal planes' normals share and the vertical planes' normals are
  square to (the largest eigenvector of ``sum_h n n^T - sum_v n n^T``, taken three times with a
  narrowing cone around the previous answer, starting from the scan's z axis).
- **Heading.** The walls' directions, as axial histograms of their normals' azimuths (scan:
  one count per thinned point; model: one per surface sample, so both weigh area), matched by
  circular cross-correlation. Each peak gives a heading and the heading a half turn from it.
- **Offset.** For each heading, the floor plans: the wall points seen from above on a grid of
  ``grid_m``, correlated with the model's walls by FFT (every offset at once); then the
  heights: the floors' and ceilings' heights, correlated with the model's slabs and ceilings.
  The best few offsets per heading are kept.

Every candidate pose is then scored by the share of the scan within reach of the model's
surfaces, and the best go to ICP (``bimscan.compare.icp``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter, gaussian_filter1d, maximum_filter
from scipy.signal import fftconvolve

from bimscan.compare.planes import rotation_between, rotation_z

WALL_NZ = 0.3  # |n_z| below this: a vertical plane (a wall)
FLOOR_NZ = 0.9  # |n_z| above this: a horizontal plane (a floor, a ceiling)
UP_CONES_DEG = (30.0, 12.0, 6.0)
HEADING_SMOOTH_DEG = 1.0
PEAK_SHARE = 0.25  # a secondary peak must reach this share of the highest
HEADING_SEPARATION_DEG = 4.0
OFFSET_SEPARATION_M = 0.6
HEIGHT_BIN_M = 0.02
HEIGHT_SEPARATION_M = 0.1  # height offsets this far apart are different answers (a slab's thickness apart)
MAX_GRID_CELLS = 2048  # per side of a floor-plan image: coarser cells on larger sites


@dataclass(frozen=True)
class Candidate:
    """A coarse pose: rotation (3, 3) and translation (3,) scan-local -> model-local, how it was
    found, and its score (the floor-plan correlation, then the share of the scan near the model)."""

    rotation: np.ndarray
    translation: np.ndarray
    heading_deg: float
    score: float


def estimate_up(normal: np.ndarray, weight: np.ndarray, *, max_tilt_deg: float) -> np.ndarray:
    """(3,) unit up of the scan from its planes' normals (N, 3) with weights (N,), within
    ``max_tilt_deg`` of +z; +z when the planes say nothing clearer."""
    up = np.array([0.0, 0.0, 1.0])
    for cone in UP_CONES_DEG:
        cosine = np.abs(normal @ up)
        horizontal = cosine > np.cos(np.radians(cone))
        vertical = cosine < np.sin(np.radians(cone))
        if weight[horizontal].sum() + weight[vertical].sum() <= 0:
            break
        scatter = (normal[horizontal] * weight[horizontal, None]).T @ normal[horizontal] \
            - (normal[vertical] * weight[vertical, None]).T @ normal[vertical]
        value, vector = np.linalg.eigh(scatter)
        guess = vector[:, -1] * np.sign(vector[2, -1] or 1.0)
        if np.degrees(np.arccos(np.clip(guess[2], -1, 1))) > max_tilt_deg:
            break
        up = guess
    return up


def level(up: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation that turns ``up`` to +z."""
    return rotation_between(up, np.array([0.0, 0.0, 1.0]))


def azimuth_histogram(normal: np.ndarray, weight: np.ndarray, *, step_deg: float) -> np.ndarray:
    """Axial histogram (bins over [0, 180) degrees) of the azimuths of vertical planes' normals,
    smoothed by ``HEADING_SMOOTH_DEG`` (circularly)."""
    bins = int(round(180.0 / step_deg))
    wall = np.abs(normal[:, 2]) < WALL_NZ
    azimuth = np.mod(np.arctan2(normal[wall, 1], normal[wall, 0]), np.pi)
    index = np.minimum((azimuth / np.pi * bins).astype(np.int64), bins - 1)
    histogram = np.bincount(index, weights=weight[wall], minlength=bins).astype(np.float64)
    return gaussian_filter1d(histogram, HEADING_SMOOTH_DEG / step_deg, mode="wrap")


def heading_candidates(scan: np.ndarray, model: np.ndarray, *, step_deg: float, count: int) -> list[float]:
    """Headings (radians, [0, 2 pi)) that turn the scan's wall directions onto the model's: the
    peaks of the circular cross-correlation of their histograms, each with its half turn."""
    correlation = np.real(np.fft.ifft(np.conj(np.fft.fft(scan)) * np.fft.fft(model)))
    bins = len(correlation)
    if correlation.max() <= 0:
        peaks = [0]
    else:
        window = max(1, int(round(HEADING_SEPARATION_DEG / step_deg)))
        local = maximum_filter(correlation, size=2 * window + 1, mode="wrap")
        candidates = np.flatnonzero((correlation >= local) & (correlation >= PEAK_SHARE * correlation.max()))
        peaks = candidates[np.argsort(-correlation[candidates], kind="stable")][:count].tolist()
    headings = []
    for peak in peaks:
        angle = np.radians(peak * 180.0 / bins)
        headings += [angle, angle + np.pi]
    return headings


def _image(xy: np.ndarray, weight: np.ndarray, origin: np.ndarray, shape: tuple[int, int], cell: float) -> np.ndarray:
    index = np.floor((xy - origin) / cell).astype(np.int64)
    inside = (index[:, 0] >= 0) & (index[:, 0] < shape[0]) & (index[:, 1] >= 0) & (index[:, 1] < shape[1])
    image = np.zeros(shape)
    np.add.at(image, (index[inside, 0], index[inside, 1]), weight[inside])
    return gaussian_filter((image > 0).astype(np.float64), 1.0)


def _peaks(values: np.ndarray, *, radius: int, count: int) -> list[tuple[int, ...]]:
    local = maximum_filter(values, size=2 * radius + 1, mode="constant")
    best = float(values.max())
    if best <= 0:
        return []
    index = np.flatnonzero((values >= local) & (values >= PEAK_SHARE * best))
    order = index[np.argsort(-values.ravel()[index], kind="stable")][:count]
    return [tuple(int(v) for v in np.unravel_index(i, values.shape)) for i in order]


def _quadrant(normal: np.ndarray, main: float) -> np.ndarray:
    """(N,) int 0..3: the quadrant of each normal's azimuth, quadrants centred on ``main`` + k 90 degrees."""
    azimuth = np.arctan2(normal[:, 1], normal[:, 0]) - main + np.pi / 4.0
    return (np.floor(azimuth / (np.pi / 2.0)).astype(np.int64) % 4) if len(normal) else np.zeros(0, np.int64)


def plan_offsets(scan_xy: np.ndarray, model_xy: np.ndarray, *, grid_m: float, count: int,
                 scan_side: np.ndarray | None = None, model_side: np.ndarray | None = None) -> list[tuple[np.ndarray, float]]:
    """The xy offsets (2,) that put the scan's walls (scan_xy (N, 2), headed) on the model's
    (model_xy (M, 2)), best first, with their correlation (the walls' cells in common). With
    ``scan_side`` (N,) and ``model_side`` (M,) (the quadrant a wall's face turns to, -1: unknown),
    a wall whose side is known meets only the model's walls facing the same way: a scan's wall is
    put on the face of the model's wall turned the way its scanner saw it, not on the other face a
    wall's thickness away."""
    if len(scan_xy) == 0 or len(model_xy) == 0:
        return []
    extent = max(float(np.ptp(scan_xy, axis=0).max()), float(np.ptp(model_xy, axis=0).max()))
    cell = max(grid_m, extent / MAX_GRID_CELLS)
    scan_origin = scan_xy.min(axis=0) - 2 * cell
    model_origin = model_xy.min(axis=0) - 2 * cell
    scan_shape = tuple(int(v) for v in np.ceil((scan_xy.max(axis=0) - scan_origin) / cell) + 3)
    model_shape = tuple(int(v) for v in np.ceil((model_xy.max(axis=0) - model_origin) / cell) + 3)
    unknown = np.ones(len(scan_xy), bool) if scan_side is None or model_side is None else scan_side < 0
    scan_image = _image(scan_xy[unknown], np.ones(int(unknown.sum())), scan_origin, scan_shape, cell)  # type: ignore[arg-type]
    model_image = _image(model_xy, np.ones(len(model_xy)), model_origin, model_shape, cell)  # type: ignore[arg-type]
    correlation = fftconvolve(model_image, scan_image[::-1, ::-1], mode="full")
    if scan_side is not None and model_side is not None:  # a face whose side is known meets faces turned its way
        for side in range(4):
            mine, theirs = scan_side == side, model_side == side
            if mine.any() and theirs.any():
                correlation += fftconvolve(
                    _image(model_xy[theirs], np.ones(int(theirs.sum())), model_origin, model_shape, cell),  # type: ignore[arg-type]
                    _image(scan_xy[mine], np.ones(int(mine.sum())), scan_origin, scan_shape, cell)[::-1, ::-1],  # type: ignore[arg-type]
                    mode="full")
    lag0 = np.array(scan_shape) - 1
    radius = max(1, int(round(OFFSET_SEPARATION_M / cell)))
    offsets = []
    for peak in _peaks(correlation, radius=radius, count=count):
        lag = np.array(peak) - lag0
        offsets.append((model_origin - scan_origin + lag * cell, float(correlation[peak])))
    return offsets


def height_offsets(scan_z: np.ndarray, model_z: np.ndarray, model_weight: np.ndarray, *, count: int,
                   scan_up: np.ndarray | None = None, model_up: np.ndarray | None = None) -> list[float]:
    """The z offsets that put the scan's floors and ceilings (scan_z (N,)) on the model's horizontal
    surfaces (model_z (M,) with area weights), best first. With ``scan_up`` (N,) (1: the face looks
    up at its viewer, 0: down, -1: unknown) and ``model_up`` (M,) bool (the face's outward normal
    points up), a face whose side is known meets only the model's faces turned the same way: a
    scan's ceiling goes on a slab's underside, not on the top of a suspended ceiling not yet hung
    a few centimetres below it."""
    if len(scan_z) == 0 or len(model_z) == 0:
        return [0.0]
    low = min(float(scan_z.min()), float(model_z.min())) - 1.0
    scan_bins = np.floor((scan_z - scan_z.min()) / HEIGHT_BIN_M).astype(np.int64)
    model_bins = np.floor((model_z - low) / HEIGHT_BIN_M).astype(np.int64)
    scan_size, model_size = int(scan_bins.max()) + 1, int(model_bins.max()) + 1

    def histograms(scan_mask: np.ndarray, model_mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (gaussian_filter1d(np.bincount(scan_bins[scan_mask], minlength=scan_size).astype(np.float64), 1.0),
                gaussian_filter1d(np.bincount(model_bins[model_mask], weights=model_weight[model_mask],
                                              minlength=model_size).astype(np.float64), 1.0))

    unknown = np.ones(len(scan_z), bool) if scan_up is None or model_up is None else scan_up < 0
    scan_histogram, model_histogram = histograms(unknown, np.ones(len(model_z), bool))
    correlation = fftconvolve(model_histogram, scan_histogram[::-1], mode="full")
    if scan_up is not None and model_up is not None:  # a face whose side is known meets faces turned its way only
        for up in (True, False):
            mine, theirs = scan_up == int(up), model_up == up
            if mine.any() and theirs.any():
                scan_side, model_side = histograms(mine, theirs)
                correlation += fftconvolve(model_side, scan_side[::-1], mode="full")
    lag0 = len(scan_histogram) - 1
    radius = max(1, int(round(HEIGHT_SEPARATION_M / HEIGHT_BIN_M)))
    peaks = _peaks(correlation, radius=radius, count=count)
    return [low - float(scan_z.min()) + (peak[0] - lag0) * HEIGHT_BIN_M for peak in peaks] or [0.0]


def coarse_candidates(scan_xyz: np.ndarray, scan_normal: np.ndarray, scan_weight: np.ndarray,
                      model_xyz: np.ndarray, model_normal: np.ndarray, model_weight: np.ndarray, *,
                      levelling: np.ndarray, step_deg: float, grid_m: float, headings: int = 4,
                      offsets: int = 3, heights: int = 4, scan_facing: np.ndarray | None = None) -> list[Candidate]:
    """Coarse poses (scan-local -> model-local) from the scan's planar points (xyz, unit normals,
    weights; scan-local) and the model's surface samples (model-local, outward normals), given the
    levelling rotation. Best floor-plan correlation first. ``scan_facing`` (N, 3): the normals
    turned towards their viewers (zero: unknown), so walls are matched face to face (``plan_offsets``)."""
    levelled_xyz = scan_xyz @ levelling.T
    levelled_normal = scan_normal @ levelling.T
    scan_wall = np.abs(levelled_normal[:, 2]) < WALL_NZ
    scan_floor = np.abs(levelled_normal[:, 2]) > FLOOR_NZ
    model_wall = np.abs(model_normal[:, 2]) < WALL_NZ
    model_floor = np.abs(model_normal[:, 2]) > FLOOR_NZ
    scan_histogram = azimuth_histogram(levelled_normal, scan_weight, step_deg=step_deg)
    model_histogram = azimuth_histogram(model_normal, model_weight, step_deg=step_deg)
    # quadrants of the faces' directions, turned so the model's walls point to the middles of theirs
    folded = np.arctan2(model_normal[model_wall, 1], model_normal[model_wall, 0]) * 4.0
    main = float(np.arctan2(np.sin(folded).sum(), np.cos(folded).sum())) / 4.0 if model_wall.any() else 0.0
    model_side = _quadrant(model_normal[model_wall], main)
    found: list[Candidate] = []
    for heading in heading_candidates(scan_histogram, model_histogram, step_deg=step_deg, count=headings):
        turn = rotation_z(heading)
        rotation = turn @ levelling
        turned = levelled_xyz @ turn.T
        scan_side = None
        if scan_facing is not None:
            facing = (scan_facing[scan_wall] @ levelling.T) @ turn.T
            scan_side = np.where(np.abs(facing).sum(axis=1) > 0, _quadrant(facing, main), -1)
        for xy, score in plan_offsets(turned[scan_wall, :2], model_xyz[model_wall, :2], grid_m=grid_m, count=offsets,
                                      scan_side=scan_side, model_side=model_side):
            # heights: the model's horizontal surfaces under the scan's footprint only
            lo, hi = turned[:, :2].min(axis=0) + xy - 1.0, turned[:, :2].max(axis=0) + xy + 1.0
            under = model_floor & np.all((model_xyz[:, :2] >= lo) & (model_xyz[:, :2] <= hi), axis=1)
            scan_up = None
            if scan_facing is not None:
                facing_z = (scan_facing[scan_floor] @ levelling.T)[:, 2]
                scan_up = np.where(facing_z > 0, 1, np.where(facing_z < 0, 0, -1))
            for z in height_offsets(turned[scan_floor, 2], model_xyz[under, 2], model_weight[under], count=heights,
                                    scan_up=scan_up, model_up=model_normal[under, 2] > 0):
                found.append(Candidate(rotation=rotation, translation=np.array([xy[0], xy[1], z]),
                                       heading_deg=float(np.degrees(heading)) % 360.0, score=score))
    found.sort(key=lambda c: -c.score)
    return found

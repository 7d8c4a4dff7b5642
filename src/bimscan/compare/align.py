"""Align a scan to its model: the rigid transform from the scan's frame to the model's, found
without a starting guess (``bimscan align``).

1. Thin the scan to voxel centroids in one streamed pass (``digest``), and find each centroid's
   local plane (``planes``).
2. Coarse search (``coarse``): up from the planes (or the scan's z with ``levelled``), headings
   from the walls' directions, offsets from the floor plans and the floor heights.
3. Score every coarse pose by the share of the scan within reach of the model, refine the best
   few by a short robust ICP, and the best of those by the full ICP (``icp``), coarse to fine.
4. Report: the 4x4 matrix, the residuals of the inliers, the inlier share, what the fit leaves
   free (a corridor's axis) and any other pose that fits almost as well (a symmetric plan).

A scan that does not show the model (the best pose puts less than ``min_inlier_share`` of it
near the model), or one in millimetres against a model in metres, is refused in one line.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bimscan.compare.coarse import Candidate, coarse_candidates, estimate_up, level
from bimscan.compare.config import AlignConfig
from bimscan.compare.digest import ScanDigest
from bimscan.compare.icp import IcpResult, free_directions, opposed_faces, refine_pose
from bimscan.compare.planes import LocalPlanes, apply, local_planes, rigid, rotation_angle_deg
from bimscan.compare.surfaces import ModelSurfaces
from bimscan.errors import CompareError, number

PLANAR = 0.6  # planarity above which a centroid's plane takes part in the coarse search
PLANE_POINTS = 1_000_000  # centroids whose planes are estimated at most (more: a subset, the radius grown to match)
SCORE_POINTS = 4000  # centroids scoring each coarse pose
SHORTLIST_POINTS = 15_000  # centroids of the short ICP of the best coarse poses
SCORE_REACH_M = 0.2  # a centroid this close to the model counts for a coarse pose
MODEL_SAMPLES_PER_M2 = 16.0
MILLIMETRE_RATIO = 300.0  # a scan this many times larger than its model is in millimetres (or the model in km)
DISTINCT_M = 0.3  # poses farther apart than this (at the scan's extent) or turned more than
DISTINCT_DEG = 2.0  # this are different answers, not the same one found twice
GRAZING_COSINE = 0.1  # a point seen this close to edge-on says nothing of which side its viewer is on
UNRELIABLE_SIDES = 0.25  # more of the chosen pose's inliers than this on faces turned from their viewer: the
                         # viewers are wrong, and the pose is sought again without them
RUNNER_UP = 0.9  # the second shortlisted pose gets the full ICP too when its fit is this close to the best's


@dataclass(frozen=True)
class Alignment:
    """A scan's pose in its model: ``matrix`` (4, 4) float64 maps scan-frame metres to model-frame
    (world) metres. inlier_share: the share of the thinned scan within ``inlier_m`` of the model;
    median_m / p90_m: those inliers' distances; free: motions the surfaces leave free; alternatives:
    other poses that fit almost as well (their matrices and inlier shares); warnings: in words."""

    matrix: np.ndarray
    inlier_share: float
    median_m: float
    p90_m: float
    inlier_m: float
    points: int
    centroids: int
    up_tilt_deg: float
    free: tuple[str, ...]
    alternatives: tuple[dict[str, Any], ...]
    warnings: tuple[str, ...]
    candidates: int
    seconds: float
    steps: dict[str, float] = field(default_factory=dict)
    placed_by: str = "search"  # or "init" (--init), "georeferencing" (the model's IfcMapConversion chose the pose)

    def to_json(self) -> dict[str, Any]:
        return {
            "matrix": [[float(v) for v in row] for row in self.matrix],
            "maps": "scan frame -> model frame (world metres): p_model = matrix @ [p_scan, 1]",
            "inverse": [[float(v) for v in row] for row in np.linalg.inv(self.matrix)],
            "inlier_share": round(self.inlier_share, 6), "inlier_m": self.inlier_m,
            "median_m": round(self.median_m, 6), "p90_m": round(self.p90_m, 6),
            "points": self.points, "centroids": self.centroids, "up_tilt_deg": round(self.up_tilt_deg, 4),
            "free": list(self.free), "alternatives": list(self.alternatives), "warnings": list(self.warnings),
            "candidates": self.candidates, "placed_by": self.placed_by,
        }  # no timings: the same scan gives the same bytes


def check_units(digest: ScanDigest, model: ModelSurfaces) -> None:
    """CompareError when the scan is a thousand times the model's size (millimetres against metres)."""
    lo, hi = model.mesh.bounds()
    model_extent = float(np.max(hi - lo))
    scan_extent = float(np.max(digest.upper - digest.lower))
    if model_extent > 0 and scan_extent > MILLIMETRE_RATIO * model_extent:
        raise CompareError(
            f"{digest.path}: the scan spans {number(scan_extent, 0)} units, the model {number(model_extent, 1)} m: "
            "the scan looks like millimetres; convert it to metres (e.g. scale by 0.001) and run again")
    if scan_extent > 0 and model_extent > MILLIMETRE_RATIO * scan_extent:
        raise CompareError(
            f"{digest.path}: the scan spans {number(scan_extent, 3)} units, the model {number(model_extent, 0)} m: "
            "the scan looks like kilometres, or the model's length unit is wrong (see 'bimscan info', --length-unit)")


def _to_world(local: np.ndarray, digest: ScanDigest, model: ModelSurfaces) -> np.ndarray:
    """scan-local -> model-local (4, 4) as the world matrix scan frame -> model frame."""
    return rigid(np.eye(3), model.centre) @ local @ rigid(np.eye(3), -digest.anchor)


def _to_local(world: np.ndarray, digest: ScanDigest, model: ModelSurfaces) -> np.ndarray:
    return rigid(np.eye(3), -model.centre) @ world @ rigid(np.eye(3), digest.anchor)


def _inliers(result: IcpResult, weights: np.ndarray, inlier_m: float) -> tuple[float, float, float]:
    inlier = result.distance <= inlier_m
    share = float(weights[inlier].sum() / max(weights.sum(), 1e-300))
    if not inlier.any():
        return share, float("nan"), float("nan")
    return share, float(np.median(result.distance[inlier])), float(np.percentile(result.distance[inlier], 90))


def _no_overlap(digest: ScanDigest, candidates: int, share: float, within_m: float, config: AlignConfig) -> CompareError:
    return CompareError(
        f"{digest.path}: could not align the scan to the model: of {candidates} coarse poses (headings from its "
        f"walls, offsets from its floor plan) the best puts {share:.0%} of the scan within {number(within_m * 100, 1)} cm "
        f"of the model (at least {config.min_inlier_share:.0%} needed); check that the scan shows this model, in the "
        "same units, or give --init")


def _fit_score(result: IcpResult, inlier_m: float) -> float:
    """How well a pose fits: the mean of ``s^2 / (s^2 + d^2)`` over the points at ``s`` = half the
    inlier distance (1 on the model, 0.5 at s, falling off beyond): the inlier share made smooth and
    finer, so two poses of a nearly symmetric plan are told apart by their small differences. A
    point on a model face turned away from its viewer fits nowhere (the two faces of a wall)."""
    scale = inlier_m / 2.0
    fit = scale**2 / (scale**2 + result.distance**2)
    if result.opposed is not None:
        fit = fit * ~result.opposed
    return float(np.mean(fit))


def facing_normals(normal: np.ndarray, points: np.ndarray, viewer: np.ndarray | None,
                   planar: np.ndarray) -> np.ndarray | None:
    """(N, 3) each planar point's normal turned towards where it was seen from (``viewer`` (N, 3),
    NaN: unknown), zero where that is unknown, the point not planar, or the view grazing; None when
    no point has a viewer."""
    if viewer is None or not np.isfinite(viewer).any():
        return None
    toward = viewer - points
    length = np.linalg.norm(toward, axis=1)
    with np.errstate(invalid="ignore"):
        cosine = np.einsum("ij,ij->i", normal, toward) / np.maximum(length, 1e-9)
        known = planar & np.isfinite(cosine) & (np.abs(cosine) > GRAZING_COSINE)
    return np.where(known[:, None], normal * np.sign(np.nan_to_num(cosine))[:, None], 0.0)


def _distinct(a: np.ndarray, b: np.ndarray, extent: np.ndarray) -> bool:
    """Whether poses ``a`` and ``b`` (4, 4) place the scan's box (corners at +-extent/2) apart."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * extent / 2.0
    moved = np.linalg.norm(apply(a, corners) - apply(b, corners), axis=1).max()
    turned = rotation_angle_deg(a[:3, :3] @ b[:3, :3].T)
    return bool(moved > DISTINCT_M or turned > DISTINCT_DEG)


def align_digest(digest: ScanDigest, model: ModelSurfaces, config: AlignConfig, *,
                 init: np.ndarray | None = None, georeference: np.ndarray | None = None,
                 sides: bool = True) -> Alignment:
    """Align a digested scan to the model (see the module docs). ``init``: a rough (4, 4) scan frame
    -> model frame to start ICP from instead of the coarse search. ``georeference``: the model's
    map conversion (4, 4) model frame -> map, for a scan in map coordinates: one more candidate,
    and the pose chosen among poses that fit almost alike (a symmetric plan). ``sides``: use where
    the points were seen from (``ScanDigest.viewer``) to keep them off model faces turned away from
    their viewer; dropped by itself when the chosen pose says the viewers are wrong (a merged cloud
    under one station id)."""
    started = time.perf_counter()
    steps: dict[str, float] = {}
    check_units(digest, model)
    rng = np.random.default_rng(config.seed)
    n = len(digest)
    clock = time.perf_counter()
    # each centroid's plane from its neighbours among all the centroids (a registration subset of a
    # large site is too sparse to hold a plane within a few voxels), then the subset
    dense = np.sort(rng.choice(n, size=PLANE_POINTS, replace=False)) if n > PLANE_POINTS else np.arange(n)
    all_planes = local_planes(digest.xyz[dense], radius=3.0 * config.voxel_m * np.sqrt(n / max(len(dense), 1)))
    pick = np.sort(rng.choice(len(dense), size=min(len(dense), config.max_points), replace=False))
    chosen = dense[pick]
    points = digest.xyz[chosen]
    weights = np.ones(len(points))
    planes = LocalPlanes(normal=all_planes.normal[pick], planarity=all_planes.planarity[pick])
    planar = planes.planarity > PLANAR
    facing = facing_normals(planes.normal, points, None if digest.viewer is None else digest.viewer[chosen],
                            planar) if sides else None
    steps["planes"] = time.perf_counter() - clock

    clock = time.perf_counter()
    up = np.array([0.0, 0.0, 1.0]) if config.levelled or init is not None else \
        estimate_up(planes.normal[planar], weights[planar], max_tilt_deg=config.max_tilt_deg)
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    extent = digest.upper - digest.lower
    if init is not None:
        candidates = [Candidate(rotation=_to_local(init, digest, model)[:3, :3],
                                translation=_to_local(init, digest, model)[:3, 3], heading_deg=float("nan"), score=1.0)]
    else:
        samples = model.samples(samples_per_m2=MODEL_SAMPLES_PER_M2, seed=config.seed)
        candidates = coarse_candidates(points[planar], planes.normal[planar], weights[planar],
                                       samples.xyz - model.centre, samples.normal, np.ones(len(samples)),
                                       levelling=level(up), step_deg=config.heading_step_deg, grid_m=config.grid_m,
                                       scan_facing=None if facing is None else facing[planar])
    mapped = None
    if georeference is not None and init is None:  # where the model's georeferencing puts the scan
        mapped = _to_local(np.linalg.inv(georeference), digest, model)
    steps["coarse"] = time.perf_counter() - clock
    if not candidates:
        raise CompareError(f"{digest.path}: the scan holds no walls or floors to align by (no planar surfaces in "
                           f"{n:,} thinned points); check that it is a scan of the building")

    # score every coarse pose on a few thousand centroids, then a short ICP of the best
    clock = time.perf_counter()
    probe = rng.choice(len(points), size=min(len(points), SCORE_POINTS), replace=False)
    scored = []
    for candidate in candidates:
        local = rigid(candidate.rotation, candidate.translation)
        closest = model.closest(apply(local, points[probe]) + model.centre)
        near = closest.distance < SCORE_REACH_M
        opposed = opposed_faces(None if facing is None else facing[probe], local[:3, :3], closest.normal)
        scored.append((float((near if opposed is None else near & ~opposed).mean()), local))
    scored.sort(key=lambda item: -item[0])
    shortlist = [local for _, local in scored[: config.candidates]] + ([] if mapped is None else [mapped])
    if scored[0][0] < config.min_inlier_share / 2 and mapped is None:  # no pose brings the scan near the model
        raise _no_overlap(digest, len(candidates), scored[0][0], SCORE_REACH_M, config)
    order = rng.permutation(len(points))  # ICP's coarse scales take the first points of this order
    points, weights = points[order], weights[order]
    facing = None if facing is None else facing[order]
    short = slice(0, min(len(points), SHORTLIST_POINTS))
    refined: list[tuple[float, np.ndarray]] = []
    georeferenced: np.ndarray | None = None
    for index, local in enumerate(shortlist):
        result = refine_pose(points[short], weights[short], model, local, scales=config.icp_scales_m,
                             iterations=max(3, config.icp_iterations // 5),
                             facing=None if facing is None else facing[short])
        fit = _fit_score(result, config.inlier_m)
        if mapped is not None and index == len(shortlist) - 1:
            georeferenced = result.matrix
        if all(_distinct(result.matrix, other, extent) for _, other in refined):
            refined.append((fit, result.matrix))
    refined.sort(key=lambda item: -item[0])
    steps["shortlist"] = time.perf_counter() - clock

    # the full ICP of the best, and of the runner-up when it comes close (a symmetric plan); of poses
    # that fit almost alike, the one the model's georeferencing gives
    clock = time.perf_counter()
    finals = []
    for fit, local in refined[:2]:
        if finals and fit < RUNNER_UP * refined[0][0]:
            break
        result = refine_pose(points, weights, model, local, scales=config.icp_scales_m,
                             iterations=config.icp_iterations, coarse_points=SHORTLIST_POINTS, facing=facing)
        finals.append((_fit_score(result, config.inlier_m), result))
    if georeferenced is not None and all(_distinct(georeferenced, r.matrix, extent) for _, r in finals):
        result = refine_pose(points, weights, model, georeferenced, scales=config.icp_scales_m[-2:],
                             iterations=config.icp_iterations, facing=facing)
        finals.append((_fit_score(result, config.inlier_m), result))
    finals.sort(key=lambda item: -item[0])
    by_map = False
    if georeferenced is not None:
        best_fit = finals[0][0]
        chosen = next(((fit, r) for fit, r in finals if fit >= config.ambiguity * best_fit
                       and not _distinct(r.matrix, georeferenced, extent)), None)
        if chosen is not None and chosen is not finals[0]:
            finals.remove(chosen)
            finals.insert(0, chosen)
        by_map = chosen is not None
    final = finals[0][1]
    if facing is not None and final.opposed is not None:
        oriented = facing.any(axis=1) & (final.distance <= config.inlier_m)
        if oriented.any() and float(final.opposed[oriented].mean()) > UNRELIABLE_SIDES:
            # the viewers are wrong (station ids that are not stations): align by the surfaces alone
            return align_digest(digest, model, config, init=init, georeference=georeference, sides=False)
    share, median, p90 = _inliers(final, weights, config.inlier_m)
    steps["icp"] = time.perf_counter() - clock
    matrix = _to_world(final.matrix, digest, model)
    if share < config.min_inlier_share:
        raise _no_overlap(digest, len(candidates), share, config.inlier_m, config)

    alternatives, warnings = [], []
    others = [(_inliers(result, weights, config.inlier_m)[0], result.matrix) for _, result in finals[1:]]
    if by_map:
        others = []  # the georeferencing chose among the poses that fit alike
    for other_share, other_local in others:
        if other_share >= config.ambiguity * share and _distinct(other_local, final.matrix, extent):
            other = _to_world(other_local, digest, model)
            turn = rotation_angle_deg(other[:3, :3] @ matrix[:3, :3].T)
            centre = (digest.lower + digest.upper)[None] / 2
            shift = apply(other, centre) - apply(matrix, centre)
            alternatives.append({"matrix": [[float(v) for v in row] for row in other],
                                 "inlier_share": round(other_share, 6), "turned_deg": round(turn, 3),
                                 "moved_m": [round(float(v), 4) for v in shift[0]]})
    if alternatives:
        first = alternatives[0]
        warnings.append(
            f"ambiguous: another pose fits almost as well ({first['inlier_share']:.1%} against {share:.1%} of the "
            f"scan near the model; turned {number(first['turned_deg'], 1)} deg, moved "
            f"{number(float(np.linalg.norm(first['moved_m'])), 2)} m): a symmetric or repeated plan; check the "
            "result or give --init")
    free = free_directions(final.scatter, final.yaw_share, share=config.free_share)
    if free:
        warnings.append(f"the scan's surfaces leave the fit free {' and '.join(free)} (model frame): a corridor or a "
                        "single wall; the position along it is the coarse search's guess; give --init or scan more")
    return Alignment(matrix=matrix, inlier_share=share, median_m=median, p90_m=p90, inlier_m=config.inlier_m,
                     points=digest.points, centroids=n, up_tilt_deg=tilt, free=tuple(free),
                     alternatives=tuple(alternatives), warnings=tuple(warnings), candidates=len(candidates),
                     seconds=time.perf_counter() - started, steps=steps,
                     placed_by="init" if init is not None else "georeferencing" if by_map else "search")

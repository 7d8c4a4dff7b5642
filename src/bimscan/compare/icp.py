"""Robust point-to-plane ICP against the model's triangles, and what the fit leaves free.

Each iteration pairs every scan point with its closest point on the model (``ModelSurfaces``)
and solves the linearised point-to-plane problem (Chen and Medioni 1992; Low 2004) for a small
rotation and translation, weighting each residual ``r`` by Geman-McClure's
``(s^2 / (s^2 + r^2))^2`` and leaving out points farther than ``3 s`` (clutter, temporary works,
elements the model has and the site has not yet, or the reverse), with the scale ``s`` going
from coarse to fine (``AlignConfig.icp_scales_m``). A direction the surfaces do not pin (along a
corridor with no end wall in view) gets no update: it keeps the coarse search's value instead of
drifting, and ``free_directions`` names it (the eigenvalues of the normals' scatter; Gelfand et
al. 2003, "Geometrically stable sampling for the ICP algorithm").

No building stands exactly as modelled: each element sits a little off, out of plumb or out of
level (ACI 117 allows 19 to 25 mm), and its points share its error. Weighted point by point, a
few large elements (a slab holds half the scan) would pull the whole pose by their own tilt.
At the fine scales (``BALANCE_BELOW_M``) each element's points therefore share one element's
weight: the pose is the average over the elements, whose deviations are independent, so it
settles to their mean (about zero) instead of the largest element's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimscan.compare.planes import apply, small_motion
from bimscan.compare.surfaces import ModelSurfaces

_STEP_RAD = 1e-6  # an update smaller than these ends a scale's iterations
_STEP_M = 1e-4
_PINNED = 1e-6  # eigenvalues of the system below this share of the largest are left out of the update
OPPOSED_COSINE = 0.3  # a point's viewer side and its model face's outward side this far apart disagree
BALANCE_BELOW_M = 0.1  # scales at or below this weigh every element alike (see the module docs)


@dataclass(frozen=True)
class IcpResult:
    """The refined pose (4, 4) (scan-local -> model-local), the last iteration's distances (N,)
    float64 and robust weights (N,), and the translation scatter of the normals (3, 3) (weighted
    sum of n n^T over the weight: trace 1) with the yaw share (how much the walls' lever arms pin
    a turn about the vertical, 0..1)."""

    matrix: np.ndarray
    distance: np.ndarray
    weight: np.ndarray
    scatter: np.ndarray
    yaw_share: float
    iterations: int
    opposed: np.ndarray | None = None  # (N,) bool: the point faces its viewer, its model face the other way


def opposed_faces(facing: np.ndarray | None, rotation: np.ndarray, outward: np.ndarray) -> np.ndarray | None:
    """(N,) bool: points whose normal turned towards their viewer (``facing`` (N, 3), zero where
    unknown; scan frame, turned into the model's by ``rotation`` (3, 3)) points away from the
    outward normal of the model face they lie on (``outward`` (N, 3)): a scanner sees the face
    turned towards it, so such a pairing (a wall's inner face put on its outer face) is wrong."""
    if facing is None:
        return None
    return np.einsum("ij,ij->i", facing @ rotation.T, outward) < -OPPOSED_COSINE


def refine_pose(points: np.ndarray, weights: np.ndarray, model: ModelSurfaces, start: np.ndarray, *,
                scales: tuple[float, ...], iterations: int, balance: bool = False,
                coarse_points: int | None = None, facing: np.ndarray | None = None) -> IcpResult:
    """ICP of ``points`` (N, 3) float64 scan-local metres with ``weights`` (N,) onto ``model``,
    starting from ``start`` (4, 4) scan-local -> model-local (model-local = world - model.centre).
    ``balance``: weigh elements alike at the fine scales; ``coarse_points``: the scales above
    ``BALANCE_BELOW_M`` use only the first this many points (the caller's random order);
    ``facing`` (N, 3): each point's normal turned towards its viewer (zero: unknown): a point on a
    model face turned away from its viewer weighs nothing (``opposed_faces``)."""
    matrix = start.copy()
    done = 0
    distance = np.zeros(len(points))
    weight = np.zeros(len(points))
    normal = np.zeros((len(points), 3))
    moved = apply(matrix, points)
    all_points, all_weights, all_facing = points, weights, facing
    opposed = None
    for scale in scales:
        fine = scale <= BALANCE_BELOW_M
        count = len(all_points) if fine or coarse_points is None else min(coarse_points, len(all_points))
        points, weights = all_points[:count], all_weights[:count]
        facing = None if all_facing is None else all_facing[:count]
        for _ in range(iterations):
            moved = apply(matrix, points)
            closest = model.closest(moved + model.centre)
            target = closest.point - model.centre
            normal = closest.normal
            residual = np.einsum("ij,ij->i", moved - target, normal)
            distance = closest.distance
            weight = weights * (scale**2 / (scale**2 + residual**2)) ** 2 * (distance < 3.0 * scale)
            opposed = opposed_faces(facing, matrix[:3, :3], normal)
            if opposed is not None:
                weight = weight * ~opposed
            if balance and fine:
                per_element = np.bincount(closest.component, weights=weight)
                balanced = weight / np.maximum(per_element[closest.component], 1e-300)
                weight = balanced * (weight.sum() / max(float(balanced.sum()), 1e-300))
            done += 1
            if weight.sum() <= 0:
                break
            jacobian = np.hstack([np.cross(moved, normal), normal])
            weighted = jacobian * weight[:, None]
            system = weighted.T @ jacobian
            gradient = weighted.T @ residual
            delta = -_solve_pinned(system, gradient)
            matrix = small_motion(delta) @ matrix
            if np.linalg.norm(delta[:3]) < _STEP_RAD and np.linalg.norm(delta[3:]) < _STEP_M:
                break
    total = float(weight.sum())
    if total > 0:
        scatter = (normal * weight[:, None]).T @ normal / total
        centre = (moved * weight[:, None]).sum(axis=0) / total
        arm = moved - centre
        torque = arm[:, 0] * normal[:, 1] - arm[:, 1] * normal[:, 0]  # (arm x n)_z
        reach = float((weight * (arm[:, 0] ** 2 + arm[:, 1] ** 2)).sum() / total)
        yaw_share = float((weight * torque**2).sum() / total / reach) if reach > 0 else 0.0
    else:
        scatter, yaw_share = np.zeros((3, 3)), 0.0
    return IcpResult(matrix=matrix, distance=distance, weight=weight, scatter=scatter, yaw_share=yaw_share,
                     iterations=done, opposed=opposed)


def _solve_pinned(system: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """The least-squares step within the directions the system pins (no step along the others)."""
    value, vector = np.linalg.eigh(system)
    keep = value > _PINNED * max(float(value[-1]), 1e-300)
    projected = vector.T @ gradient
    step = np.zeros_like(projected)
    step[keep] = projected[keep] / value[keep]
    return vector @ step


def free_directions(scatter: np.ndarray, yaw_share: float, *, share: float) -> list[str]:
    """The motions the fit leaves free, in words ("along (0.99, 0.12, 0.00)", "turning about the
    vertical"): translation directions whose normals' weight is below ``share``, and the yaw when
    its share is below ``share``."""
    free = []
    value, vector = np.linalg.eigh(scatter)
    for v, direction in zip(value, vector.T):
        if v < share:
            d = direction * (1 if direction[np.argmax(np.abs(direction))] > 0 else -1)
            free.append(f"along ({d[0]:.2f}, {d[1]:.2f}, {d[2]:.2f})")
    if yaw_share < share:
        free.append("turning about the vertical")
    return free

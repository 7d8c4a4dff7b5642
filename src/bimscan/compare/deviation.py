"""How far a built element stands from where the model has it: a rigid fit of its own surfaces
to its points.

The element's points (those whose nearest model surface is the element's, within the band) are
fitted by point-to-plane ICP against the element's triangles alone, the motion taken about the
centre of its bounding box: ``p' = R (p - centre) + centre + offset`` (the form of bimscan's
as-built deviations, ``bimscan.scan.asbuilt``, so the two compare directly). What the visible
surfaces cannot pin is not reported: a wall seen from one side and not at its ends pins only its
offset across its face (the other components of ``offset_m`` are NaN), and the turn about an
axis its surfaces do not constrain stays 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bimscan.compare.planes import apply, small_motion
from bimscan.compare.surfaces import outward_normals
from bimscan.types import SceneMesh

PINNED_SHARE = 0.15  # a direction holding less than this share of the normals' weight is not pinned
FIT_SCALE_M = 0.05  # the robust scale of the fit (Geman-McClure)
FIT_ITERATIONS = 12
MIN_FIT_POINTS = 30
OVER_FACE_M = 0.005  # a point whose nearest surface point lies further aside than this is past the face's edge
# a motion the element's points pin with less than this share of their best-pinned motion's weight is
# not fitted: a thin member seen on one or two faces otherwise turns by tens of degrees to fit noise
# and its neighbours' points (measured on the benchmark's roof members: 25-40 mm errors, 8-22 mm without)
MIN_PINNED_WEIGHT = 1e-4


@dataclass(frozen=True)
class ElementFit:
    """A built element's deviation: offset_m (3,) at its centre (NaN along unpinned axes),
    rotation_deg (3,) about x, y, z, median_signed_m the median distance of its points in front of
    (+) or behind (-) its outward surfaces before the fit, rms_m the residual after the fit, and the
    largest displacement of its bounding box's corners under the fit along pinned axes (max_shift_m)."""

    offset_m: np.ndarray
    rotation_deg: np.ndarray
    median_signed_m: float
    rms_m: float
    max_shift_m: float
    points: int

    @staticmethod
    def unknown(points: int = 0, median_signed_m: float = float("nan")) -> ElementFit:
        nan3 = np.full(3, np.nan)
        return ElementFit(offset_m=nan3, rotation_deg=nan3.copy(), median_signed_m=median_signed_m,
                          rms_m=float("nan"), max_shift_m=float("nan"), points=points)


def fit_element(mesh: SceneMesh, faces: np.ndarray, points: np.ndarray) -> ElementFit:
    """Fit the element made of ``faces`` (indices into ``mesh.faces``) to ``points`` (N, 3) model frame."""
    import open3d as o3d

    if len(points) < MIN_FIT_POINTS or not len(faces):
        return ElementFit.unknown(len(points))
    corners = mesh.vertices[mesh.faces[faces]]
    lo, hi = corners.reshape(-1, 3).min(axis=0), corners.reshape(-1, 3).max(axis=0)
    centre = (lo + hi) / 2.0
    outward = outward_normals(SceneMesh(vertices=mesh.vertices, faces=mesh.faces[faces],
                                        face_component=np.zeros(len(faces), dtype=np.int32)))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor((mesh.vertices - centre).astype(np.float32)),
                        o3d.core.Tensor(mesh.faces[faces].astype(np.uint32)))
    local = points - centre

    def closest(moved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        answer = scene.compute_closest_points(o3d.core.Tensor(moved.astype(np.float32)))
        return answer["points"].numpy().astype(np.float64), outward[answer["primitive_ids"].numpy().astype(np.int64)]

    target, normal = closest(local)
    signed = np.einsum("ij,ij->i", local - target, normal)
    median_signed = float(np.median(signed))
    # fit the model's element to the points: move the points by the inverse motion, then invert
    matrix = np.eye(4)
    weight = np.ones(len(points))
    for _ in range(FIT_ITERATIONS):
        moved = apply(matrix, local)
        target, normal = closest(moved)
        weight, residual = _weights(moved, target, normal)
        jacobian = np.hstack([np.cross(moved, normal), normal])
        weighted = jacobian * weight[:, None]
        system = weighted.T @ jacobian
        value, vector = np.linalg.eigh(system)
        keep = value > MIN_PINNED_WEIGHT * max(float(value[-1]), 1e-300)
        projected = vector.T @ (weighted.T @ residual)
        step = np.zeros(6)
        step[keep] = projected[keep] / value[keep]
        delta = -(vector @ step)
        matrix = small_motion(delta) @ matrix
        if np.linalg.norm(delta) < 1e-7:
            break
    moved = apply(matrix, local)
    target, normal = closest(moved)
    weight, residual = _weights(moved, target, normal)
    rms = float(np.sqrt(np.average(residual**2, weights=weight))) if weight.sum() > 0 else float("nan")
    # the element's motion is the inverse of the points' motion
    inverse = np.linalg.inv(matrix)
    scatter = (normal * weight[:, None]).T @ normal / max(float(weight.sum()), 1e-300)
    pinned_axes = np.array([float(axis @ scatter @ axis) >= PINNED_SHARE for axis in np.eye(3)])
    offset = np.where(pinned_axes, inverse[:3, 3], np.nan)
    rotation = inverse[:3, :3]
    angles = np.degrees(np.array([np.arctan2(rotation[2, 1], rotation[2, 2]),
                                  np.arcsin(np.clip(-rotation[2, 0], -1.0, 1.0)),
                                  np.arctan2(rotation[1, 0], rotation[0, 0])]))
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - centre
    shift = apply(inverse, box) - box
    max_shift = float(np.abs(shift[:, pinned_axes]).max()) if pinned_axes.any() else float("nan")
    return ElementFit(offset_m=offset, rotation_deg=angles, median_signed_m=median_signed, rms_m=rms,
                      max_shift_m=max_shift, points=len(points))


def _weights(moved: np.ndarray, target: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Robust weights and signed residuals of points against their nearest surface points. A point
    past a face's edge (its nearest point on the edge, off to the side) weighs nothing: the face's
    plane does not hold it, and it would pin the element along that face's normal (a beam's side
    points past its end pulling on the end face)."""
    gap = moved - target
    residual = np.einsum("ij,ij->i", gap, normal)
    aside = np.linalg.norm(gap - residual[:, None] * normal, axis=1)
    weight = (FIT_SCALE_M**2 / (FIT_SCALE_M**2 + residual**2)) ** 2 * (aside < OVER_FACE_M)
    return weight, residual

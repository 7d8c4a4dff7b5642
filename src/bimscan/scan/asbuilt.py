"""As-built deviations: every component a little out of place, within construction tolerances.

No building is built exactly as modelled. Each component gets one rigid transform, drawn once per
(seed, GlobalId), so every configuration of a scene scans the same as-built building:

- a shift with sigma ``position_tolerance_m / k`` along x and y and ``level_tolerance_m / k``
  along z (k = ``sigmas_per_tolerance``: 2 puts 95 % of the components within tolerance);
- a tilt about the x and y axes through the centre of its bounding box: for vertical elements
  (walls, columns: most of their area faces sideways) sigma ``plumb_tolerance_m / k / height``
  (out of plumb), for the others (slabs, beams) ``level_tolerance_m / k / length`` (not level).

The defaults are ACI 117-10 tolerances (Specification for Tolerances for Concrete Construction
and Materials): lateral alignment of members 25 mm, vertical alignment (plumb) 25 mm for heights
up to 30 m, level alignment (elevation of slabs) 19 mm. The transform of component c maps a
model point p to ``R_c (p - centre_c) + centre_c + shift_c`` with ``R_c = Rx(tilt_x) Ry(tilt_y)``;
the scan sees the moved geometry, each point keeps the component that made it (labels follow),
and ``Deviations.to_json`` goes into the cloud's metadata so the IFC-true geometry stays
measurable against the scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.special import ndtr

from bimscan.scan.kernels import draw_normals, noise_key
from bimscan.scan.sensor import SensorModel
from bimscan.types import SceneMesh

STANDARD = "ACI 117-10: lateral alignment 25 mm, plumb 25 mm (heights up to 30 m), slab elevation 19 mm"
_DRAWS = 6  # shift x, y, z; tilt x, y; waviness phase


@dataclass(frozen=True)
class Deviations:
    """Rigid transforms of C components: global_id (C,) str, centre_m (C, 3), shift_m (C, 3),
    tilt_rad (C, 2) about x then y, vertical (C,) bool, phase (C,) radians (of the waviness)."""

    global_id: np.ndarray
    centre_m: np.ndarray
    shift_m: np.ndarray
    tilt_rad: np.ndarray
    vertical: np.ndarray
    phase: np.ndarray

    def rotations(self) -> np.ndarray:
        """(C, 3, 3) rotation matrices Rx(tilt_x) @ Ry(tilt_y)."""
        cx, sx = np.cos(self.tilt_rad[:, 0]), np.sin(self.tilt_rad[:, 0])
        cy, sy = np.cos(self.tilt_rad[:, 1]), np.sin(self.tilt_rad[:, 1])
        one, zero = np.ones_like(cx), np.zeros_like(cx)
        rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cx, -sx], -1), np.stack([zero, sx, cx], -1)], -2)
        ry = np.stack([np.stack([cy, zero, sy], -1), np.stack([zero, one, zero], -1), np.stack([-sy, zero, cy], -1)], -2)
        return rx @ ry

    def transform(self, points: np.ndarray, component: np.ndarray) -> np.ndarray:
        """Model points (N, 3) of the given components (N,) moved to where the as-built building has them."""
        rotation = self.rotations()[component]
        local = points - self.centre_m[component]
        return np.einsum("nij,nj->ni", rotation, local) + self.centre_m[component] + self.shift_m[component]

    def to_json(self, sensor: SensorModel) -> dict[str, Any]:
        """What a cloud's metadata records: the standard, the sigmas and every component's transform."""
        k = sensor.sigmas_per_tolerance
        return {
            "standard": STANDARD,
            "transform": "p' = Rx(tilt_x) Ry(tilt_y) (p - centre) + centre + shift",
            "sigma_m": {"position": sensor.position_tolerance_m / k, "level": sensor.level_tolerance_m / k,
                        "plumb": sensor.plumb_tolerance_m / k},
            "components": {
                "global_id": [str(g) for g in self.global_id],
                "centre_m": np.round(self.centre_m, 6).tolist(),
                "shift_m": np.round(self.shift_m, 7).tolist(),
                "tilt_deg": np.round(np.degrees(self.tilt_rad), 7).tolist(),
                "vertical": [bool(v) for v in self.vertical],
            },
        }


def sample_deviations(mesh: SceneMesh, global_id: np.ndarray, sensor: SensorModel, seed: int) -> Deviations:
    """One draw per component, keyed by (seed, GlobalId): the same building whatever else changes."""
    n = len(global_id)
    keys = np.array([noise_key(seed, 0, f"as-built {g}") for g in global_id], dtype=np.uint64)
    z = draw_normals(keys, _DRAWS) if n else np.zeros((0, _DRAWS))
    lo, hi, vertical = _component_boxes(mesh, n)
    centre = (lo + hi) / 2.0
    extent = hi - lo
    k = sensor.sigmas_per_tolerance
    shift = np.stack([z[:, 0] * sensor.position_tolerance_m / k, z[:, 1] * sensor.position_tolerance_m / k,
                      z[:, 2] * sensor.level_tolerance_m / k], axis=1)
    height = np.maximum(extent[:, 2], 0.1)
    length = np.maximum(np.maximum(extent[:, 0], extent[:, 1]), 0.1)
    tilt_sigma = np.where(vertical, sensor.plumb_tolerance_m / k / height, sensor.level_tolerance_m / k / length)
    tilt = z[:, 3:5] * tilt_sigma[:, None]
    phase = 2.0 * math.pi * ndtr(z[:, 5])  # uniform in [0, 2 pi): the normal's own CDF
    return Deviations(global_id=np.asarray(global_id), centre_m=centre, shift_m=shift, tilt_rad=tilt,
                      vertical=vertical, phase=phase)


def _component_boxes(mesh: SceneMesh, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bounding box (lo, hi) of each component's triangles and whether most of its area faces sideways."""
    corners = mesh.vertices[mesh.faces]  # (F, 3, 3)
    component = mesh.face_component
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    np.minimum.at(lo, component, corners.min(axis=1))
    np.maximum.at(hi, component, corners.max(axis=1))
    empty = ~np.isfinite(lo[:, 0])
    lo[empty], hi[empty] = 0.0, 0.0
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(cross, axis=1)
    upward = np.bincount(component, weights=np.abs(cross[:, 2]), minlength=n)
    total = np.bincount(component, weights=area, minlength=n)
    vertical = upward < 0.5 * np.maximum(total, 1e-300)
    return lo, hi, vertical


def apply_deviations(mesh: SceneMesh, deviations: Deviations) -> SceneMesh:
    """The mesh with every component moved by its transform (vertices shared between components are split)."""
    corner_component = np.repeat(mesh.face_component, 3)
    pairs = mesh.faces.reshape(-1).astype(np.int64) * max(len(deviations.global_id), 1) + corner_component
    unique, inverse = np.unique(pairs, return_inverse=True)
    vertex = unique // max(len(deviations.global_id), 1)
    component = (unique % max(len(deviations.global_id), 1)).astype(np.int64)
    moved = deviations.transform(mesh.vertices[vertex], component)
    return SceneMesh(vertices=np.ascontiguousarray(moved, dtype=np.float64),
                     faces=inverse.reshape(-1, 3).astype(np.int32), face_component=mesh.face_component,
                     face_transparency=mesh.face_transparency)

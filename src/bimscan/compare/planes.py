"""Local planes of a thinned scan, and the rigid-motion arithmetic registration needs.

Each point's plane is the principal axis of its neighbours within ``radius`` (Open3D's KD-tree
covariances): the normal is the eigenvector of the smallest eigenvalue, and the planarity
``(l1 - l0) / l2`` (eigenvalues ascending; Weinmann et al. 2015) says how flat the
neighbourhood is: about 1 on a wall, 0 on a cable drum or a chair's legs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_NEIGHBOURS = 6


@dataclass(frozen=True)
class LocalPlanes:
    """normal (N, 3) float64 unit (sign arbitrary); planarity (N,) float64 in [0, 1] (0 where fewer
    than ``MIN_NEIGHBOURS`` neighbours were found)."""

    normal: np.ndarray
    planarity: np.ndarray


def local_planes(xyz: np.ndarray, *, radius: float, max_neighbours: int = 30) -> LocalPlanes:
    """The plane through each point's neighbours (``xyz`` (N, 3) float64 metres, local frame)."""
    import open3d as o3d

    if len(xyz) == 0:
        return LocalPlanes(normal=np.zeros((0, 3)), planarity=np.zeros(0))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz, dtype=np.float64)))
    cloud.estimate_covariances(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_neighbours))
    covariance = np.asarray(cloud.covariances)
    value, vector = np.linalg.eigh(covariance)
    value = np.maximum(value, 0.0)
    planarity = np.divide(value[:, 1] - value[:, 0], value[:, 2], out=np.zeros(len(xyz)), where=value[:, 2] > 0)
    # Open3D leaves a point with too few neighbours an identity covariance (flat spectrum: planarity 0)
    return LocalPlanes(normal=vector[:, :, 0], planarity=planarity)


def rotation_z(angle_rad: float) -> np.ndarray:
    """(3, 3) rotation about z by ``angle_rad`` (counter-clockwise seen from above)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector ``a`` to unit vector ``b`` (Rodrigues)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        ortho = np.eye(3)[int(np.argmin(np.abs(a)))]  # a half turn about any axis perpendicular to a
        axis = np.cross(a, ortho)
        return rotation_about(axis / np.linalg.norm(axis), np.pi)
    return rotation_about(axis / s, float(np.arctan2(s, c)))


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_rad`` about unit ``axis`` (Rodrigues' formula)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1.0 - np.cos(angle_rad)) * (k @ k)


def rigid(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(4, 4) homogeneous matrix of ``p -> rotation @ p + translation``."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    matrix[:3, 3] = translation
    return matrix


def apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``points`` (N, 3) moved by the (4, 4) rigid ``matrix``."""
    return points @ matrix[:3, :3].T + matrix[:3, 3]


def small_motion(delta: np.ndarray) -> np.ndarray:
    """(4, 4) the rigid motion of a 6-vector (rotation vector rad, translation m), exactly a rotation."""
    omega = delta[:3]
    angle = float(np.linalg.norm(omega))
    rotation = np.eye(3) if angle < 1e-15 else rotation_about(omega / angle, angle)
    return rigid(rotation, delta[3:])


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """The angle of a rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))))

"""Per-point network inputs beyond XYZ that a real scan has too (never taken from the mesh).

- ``xyz``: the block's coordinates, centred and scaled (:func:`bimscan.learn.blocks.normalize_block`);
  always the first three channels (the paper's input).
- ``height``: z above the floor of the block's scene, in units of ``height_scale_m`` (a storey,
  3 m): a block normalised to [-1, 1] no longer knows whether it is at floor or ceiling
  level, while floors, ceilings and beams are told apart mostly by height. The floor is a low
  percentile (``FLOOR_PERCENTILE``) of the scene's z, robust to a few stray points below it.
- ``normals``: unit normals estimated by PCA of each point's ``normal_neighbours`` nearest
  neighbours among the block's input points (the eigenvector of the smallest eigenvalue of the
  neighbourhood covariance), sign chosen with n_z >= 0 (a scan's normals have no reliable
  sign). Estimated after augmentation from the very points the network sees, identically for
  synthetic and real blocks.
"""

from __future__ import annotations

import numpy as np

FEATURE_CHANNELS = {"xyz": 3, "height": 1, "normals": 3}
FLOOR_PERCENTILE = 0.1


def input_channels(features: tuple[str, ...]) -> int:
    """Channels of the network input for a feature list."""
    return sum(FEATURE_CHANNELS[name] for name in features)


def floor_height(z: np.ndarray) -> float:
    """The scene's floor level from (a sample of) its z values."""
    if len(z) == 0:
        return 0.0
    return float(np.percentile(np.asarray(z, dtype=np.float64), FLOOR_PERCENTILE))


def estimate_normals(xyz: np.ndarray, *, neighbours: int) -> np.ndarray:
    """(M, 3) float32 unit normals of (M, 3) points, n_z >= 0; zeros when M < 3."""
    m = len(xyz)
    if m < 3:
        return np.zeros((m, 3), dtype=np.float32)
    from scipy.spatial import cKDTree

    k = min(neighbours, m)
    _, index = cKDTree(xyz).query(xyz, k=k)
    patch = xyz[index]  # (M, k, 3)
    patch = patch - patch.mean(axis=1, keepdims=True)
    covariance = np.einsum("mki,mkj->mij", patch, patch)
    _, vectors = np.linalg.eigh(covariance)  # ascending eigenvalues
    normals = vectors[:, :, 0]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    return normals.astype(np.float32)


def extra_features(
    xyz: np.ndarray, *, features: tuple[str, ...], floor_z: float, height_scale_m: float, neighbours: int,
) -> np.ndarray | None:
    """(M, E) float32 channels after xyz for (M, 3) absolute-height points, or None for XYZ only.

    ``xyz`` must hold absolute z (x and y may be relative: only their differences matter).
    """
    parts = []
    for name in features[1:]:
        if name == "height":
            parts.append(((xyz[:, 2:3] - floor_z) / height_scale_m).astype(np.float32))
        elif name == "normals":
            parts.append(estimate_normals(xyz, neighbours=neighbours))
    return np.concatenate(parts, axis=1) if parts else None

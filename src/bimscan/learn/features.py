"""Per-point network inputs beyond XYZ that a real scan has too (never taken from the mesh).

- ``xyz``: the block's coordinates, centred and scaled (:func:`bimscan.learn.blocks.normalize_block`);
  always the first three channels (the paper's input).
- ``height``: z above the floor under the point, in units of ``height_scale_m`` (a storey,
  3 m): a block normalised to [-1, 1] no longer knows whether it is at floor or ceiling
  level, while floors, ceilings and beams are told apart mostly by height. The floor is the
  point's own storey's, found from the scene's points (:mod:`bimscan.learn.floors`), so the
  feature means the same on every storey of a building and in a single scanned room.
- ``normals``: unit normals estimated by PCA of each point's ``normal_neighbours`` nearest
  neighbours among the block's input points (the eigenvector of the smallest eigenvalue of the
  neighbourhood covariance), sign chosen with n_z >= 0 (a scan's normals have no reliable
  sign). Estimated after augmentation from the very points the network sees, identically for
  synthetic and real blocks.
- ``shape``: the dimensionality features of the same neighbourhood (Demantke et al. 2011;
  Weinmann et al. 2015, "Semantic point cloud interpretation based on optimal neighborhoods"):
  with the covariance's eigenvalues l1 >= l2 >= l3, linearity (l1 - l2) / l1, planarity
  (l2 - l3) / l1 and scattering l3 / l1 (they sum to 1). A wall or a slab is planar, a chair
  leg or a cable linear, a plant or a heap of clutter scattered: what a normal alone does not
  say. Computed with the normals from one neighbour search.
- ``shape_wide``: the same three features over the ``wide_neighbours`` nearest (about a metre
  across in a recipe block): a second scale, as in Weinmann et al.'s multi-scale features. A
  wall stays planar at the wide scale; a cabinet's side, whose neighbourhood there takes in its
  top and front, does not.
- ``rgb``: the point's colour, each channel / 255 - 0.5 (a scan without colour: mid grey, 0).
  Real scans carry photographs' colours, bimscan's scans their surface styles' (``--rgb``); the
  training augmentation randomises them (:mod:`bimscan.learn.augment`).
"""

from __future__ import annotations

import numpy as np

FEATURE_CHANNELS = {"xyz": 3, "height": 1, "normals": 3, "shape": 3, "shape_wide": 3, "rgb": 3}


def input_channels(features: tuple[str, ...]) -> int:
    """Channels of the network input for a feature list."""
    return sum(FEATURE_CHANNELS[name] for name in features)


def local_geometry(xyz: np.ndarray, *, neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """Normals and dimensionality features of (M, 3) points from their ``neighbours`` nearest.

    Returns (M, 3) float32 unit normals (n_z >= 0) and (M, 3) float32 linearity, planarity,
    scattering; zeros for both when M < 3 (and shape zeros where a neighbourhood is one point).
    """
    return local_geometry_scales(xyz, (neighbours,))[0]


def local_geometry_scales(xyz: np.ndarray, scales: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`local_geometry` at each neighbourhood size of ``scales``, from one neighbour search
    (the largest; a smaller scale takes the nearest of those)."""
    m = len(xyz)
    if m < 3:
        return [(np.zeros((m, 3), dtype=np.float32), np.zeros((m, 3), dtype=np.float32)) for _ in scales]
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(xyz).query(xyz, k=min(max(scales), m), workers=-1)  # parallel; the same result
    return [_geometry(xyz, nearest[:, :min(k, m)]) for k in scales]


def _geometry(xyz: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normals and shape of each point from its neighbours ``index`` (M, k), nearest first."""
    patch = xyz[index]  # (M, k, 3)
    patch = patch - patch.mean(axis=1, keepdims=True)
    covariance = np.matmul(patch.transpose(0, 2, 1), patch)  # a batched matmul: twice einsum's speed
    values, vectors = np.linalg.eigh(covariance)  # ascending eigenvalues
    normals = vectors[:, :, 0]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    smallest, middle, largest = (np.clip(values[:, i], 0.0, None) for i in range(3))
    scale = np.where(largest > 0, largest, 1.0)  # a one-point neighbourhood: all three are 0, and so its shape
    shape = np.stack([(largest - middle) / scale, (middle - smallest) / scale, smallest / scale], axis=1)
    return normals.astype(np.float32), shape.astype(np.float32)


def estimate_normals(xyz: np.ndarray, *, neighbours: int) -> np.ndarray:
    """(M, 3) float32 unit normals of (M, 3) points, n_z >= 0; zeros when M < 3."""
    return local_geometry(xyz, neighbours=neighbours)[0]


def extra_features(
    xyz: np.ndarray, *, features: tuple[str, ...], height_m: np.ndarray | None, height_scale_m: float, neighbours: int,
    wide_neighbours: int = 0, rgb: np.ndarray | None = None,
) -> np.ndarray | None:
    """(M, E) float32 channels after xyz for (M, 3) points, or None for XYZ only.

    ``height_m``: (M,) metres above the floor under each point (needed with ``height``); only
    the differences of ``xyz`` matter. ``wide_neighbours``: the neighbourhood of ``shape_wide``.
    ``rgb``: (M, 3) uint8 colour (with ``rgb``; None: mid grey).
    """
    scales = []  # one neighbour search serves both neighbourhoods
    if "normals" in features or "shape" in features:
        scales.append(neighbours)
    if "shape_wide" in features:
        if wide_neighbours < 3:
            raise ValueError("the shape_wide feature needs wide_neighbours >= 3")
        scales.append(wide_neighbours)
    geometry = dict(zip(scales, local_geometry_scales(xyz, tuple(scales)))) if scales else {}
    parts = []
    for name in features[1:]:
        if name == "height":
            if height_m is None:
                raise ValueError("the height feature needs each point's height above its floor")
            parts.append((np.asarray(height_m, dtype=np.float64)[:, None] / height_scale_m).astype(np.float32))
        elif name in ("normals", "shape"):
            parts.append(geometry[neighbours][0] if name == "normals" else geometry[neighbours][1])
        elif name == "shape_wide":
            parts.append(geometry[wide_neighbours][1])
        elif name == "rgb":
            colour = np.zeros((len(xyz), 3), dtype=np.float32) if rgb is None else \
                np.asarray(rgb, dtype=np.float32) / 255.0 - 0.5
            parts.append(colour.astype(np.float32))
    return np.concatenate(parts, axis=1) if parts else None

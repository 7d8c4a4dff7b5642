"""Training augmentations (Pointcept's indoor set): each seeded by the block's generator, so the
same (seed, epoch, tile) gives the same block; every one keeps labels aligned with points
(only dropout removes points, and it removes their labels with them).

- rotation about z by a uniform angle in [0, 2 pi) (scans are levelled; heading is arbitrary);
- scaling by factors uniform in ``scale_range``, per axis when ``anisotropic`` (storey
  heights and room sizes vary between buildings);
- mirror flips of x and of y, each with ``flip_probability`` (a mirrored building is a building);
- jitter: Gaussian noise of ``jitter_sigma_m`` per coordinate, clipped at ``jitter_clip_m``
  (range noise beyond the simulated one);
- dropout: a random fraction in [0, ``dropout_max``] of the points removed (occlusion, missing
  returns);
- elastic distortion (Pointcept's ``ElasticDistortion``, from Choy et al. 2019): for each
  (granularity, magnitude) pair, Gaussian noise on a grid of cells ``granularity`` metres,
  smoothed by three 3x3x3 box filters, interpolated trilinearly at the points and added times
  ``magnitude`` (walls a little out of plumb, slabs a little out of level: as-built deviation
  at block scale).
"""

from __future__ import annotations

import numpy as np

from bimscan.learn.train_config import AugmentConfig


def augment_points(xyz: np.ndarray, *, config: AugmentConfig,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float]:
    """Augment (M, 3) float64 metres; returns the new (K, 3) points, (K,) int64 indices of the
    input points they came from (K <= M after dropout), in input order, and the factor heights
    were scaled by (heights above a floor scale with z)."""
    xyz = np.array(xyz, dtype=np.float64, copy=True)
    centre = (xyz.min(axis=0) + xyz.max(axis=0)) / 2.0 if len(xyz) else np.zeros(3)
    xyz -= centre
    if config.rotate_z:
        angle = rng.uniform(0.0, 2.0 * np.pi)
        c, s = np.cos(angle), np.sin(angle)
        xyz[:, :2] = xyz[:, :2] @ np.array([[c, s], [-s, c]])
    low, high = config.scale_range
    factors = rng.uniform(low, high, size=3 if config.anisotropic else 1)
    xyz *= factors if config.anisotropic else factors[0]
    flips = rng.random(2) < config.flip_probability
    xyz[:, 0] *= -1.0 if flips[0] else 1.0
    xyz[:, 1] *= -1.0 if flips[1] else 1.0
    for granularity, magnitude in config.elastic:
        xyz = elastic_distortion(xyz, granularity=granularity, magnitude=magnitude, rng=rng)
    if config.jitter_sigma_m > 0:
        noise = rng.normal(0.0, config.jitter_sigma_m, size=xyz.shape)
        xyz += np.clip(noise, -config.jitter_clip_m, config.jitter_clip_m)
    xyz += centre
    keep = np.arange(len(xyz), dtype=np.int64)
    if config.dropout_max > 0 and len(xyz):
        fraction = rng.uniform(0.0, config.dropout_max)
        survive = rng.random(len(xyz)) >= fraction
        if survive.any():  # never drop a whole block
            keep = keep[survive]
    return xyz[keep], keep, float(factors[2] if config.anisotropic else factors[0])


def augment_colour(rgb: np.ndarray, *, config: AugmentConfig, rng: np.random.Generator) -> np.ndarray:
    """Randomise (M, 3) uint8 colours of one block (``AugmentConfig``'s colour keys): a gain and an
    offset per channel, noise per point, at random its grey value or mid grey; returns uint8.
    Draws nothing from ``rng`` when every colour key is 0 (the block's other draws stay as they were)."""
    if not (config.colour_gain_sigma or config.colour_noise or config.colour_grey or config.colour_drop):
        return rgb
    colour = np.asarray(rgb, dtype=np.float64) / 255.0
    gain = rng.normal(1.0, config.colour_gain_sigma, size=3)
    offset = rng.normal(0.0, config.colour_gain_sigma / 2.0, size=3)
    colour = colour * gain + offset + rng.normal(0.0, config.colour_noise, size=colour.shape)
    grey, drop = rng.random(2)
    if grey < config.colour_grey:
        colour = np.repeat(colour @ np.array([[0.299], [0.587], [0.114]]), 3, axis=1)
    if drop < config.colour_drop:
        colour = np.full_like(colour, 128.0 / 255.0)
    return np.clip(np.rint(colour * 255.0), 0, 255).astype(np.uint8)


def elastic_distortion(
    xyz: np.ndarray, *, granularity: float, magnitude: float, rng: np.random.Generator,
) -> np.ndarray:
    """Smooth random displacement of (M, 3) points (see the module docstring)."""
    if len(xyz) == 0 or magnitude == 0:
        return xyz
    from scipy.interpolate import RegularGridInterpolator
    from scipy.ndimage import convolve

    lower = xyz.min(axis=0)
    shape = ((xyz.max(axis=0) - lower) // granularity).astype(int) + 3
    noise = rng.standard_normal((*shape, 3))
    box = np.ones((3, 3, 3, 1)) / 27.0
    for _ in range(3):
        noise = convolve(noise, box, mode="constant", cval=0.0)
    axes = [np.linspace(lower[d] - granularity, lower[d] + granularity * (shape[d] - 2), shape[d]) for d in range(3)]
    interpolate = RegularGridInterpolator(axes, noise, bounds_error=False, fill_value=0.0)
    return xyz + interpolate(xyz) * magnitude

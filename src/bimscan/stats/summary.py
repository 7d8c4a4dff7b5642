"""The dataset's statistics (paper Figs. 4-6) and the stability of extents and class shares.

Per configuration: points (total, mean, min, max over scenes; Fig. 4), mean extent along X,
Y, Z (Fig. 5), class proportions of all its points together (Fig. 6). Per scene: the same
across its configurations, and two stability figures:

- extent spread: for each axis, (largest - smallest extent) / mean extent over the scene's
  configurations; the scene's figure is the largest over the three axes (a fraction; 0 = the
  same extents at every density);
- class spread: for each class, largest - smallest share over the configurations in percentage
  points; the scene's figure is the largest over the classes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bimscan.dataset.layout import ManifestEntry
from bimscan.stats.collect import CollectedDataset, UnitStats

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class ConfigStats:
    config: str
    units: int
    points_total: int
    points_mean: float
    points_min: int
    points_max: int
    size_mean_m: tuple[float, float, float]
    proportions_pct: dict[str, float]  # class -> share of all the configuration's points


@dataclass(frozen=True)
class SceneStats:
    scene: str
    configs: list[str]
    points: dict[str, int]  # config -> points
    size_m: dict[str, tuple[float, float, float]]  # config -> extent along X, Y, Z
    proportions_pct: dict[str, dict[str, float]]  # config -> class -> share
    extent_spread: tuple[float, float, float]  # per axis, relative (see module docs)
    class_spread_pp: dict[str, float]  # class -> percentage points

    @property
    def max_extent_spread(self) -> float:
        return max(self.extent_spread)

    @property
    def max_class_spread_pp(self) -> float:
        return max(self.class_spread_pp.values(), default=0.0)


@dataclass(frozen=True)
class DatasetStats:
    classes: list[str]
    colors: dict[str, str]
    configs: list[ConfigStats]
    scenes: list[SceneStats]
    units: list[UnitStats]
    missing: list[ManifestEntry] = field(default_factory=list)

    def max_extent_spread(self) -> tuple[float, str, str]:
        """(largest relative extent spread, its scene, its axis) over scenes with 2+ configurations."""
        best = (0.0, "", "")
        for scene in self.scenes:
            if len(scene.configs) < 2:
                continue
            axis = int(np.argmax(scene.extent_spread))
            if scene.extent_spread[axis] >= best[0]:
                best = (scene.extent_spread[axis], scene.scene, AXES[axis])
        return best

    def max_class_spread(self) -> tuple[float, str, str]:
        """(largest class share spread in percentage points, its scene, its class)."""
        best = (0.0, "", "")
        for scene in self.scenes:
            if len(scene.configs) < 2:
                continue
            for name, value in scene.class_spread_pp.items():
                if value >= best[0]:
                    best = (value, scene.scene, name)
        return best

    def to_json(self) -> dict[str, Any]:
        """Everything as plain JSON values."""
        extent, extent_scene, extent_axis = self.max_extent_spread()
        share, share_scene, share_class = self.max_class_spread()
        return {
            "classes": self.classes,
            "configs": [vars(c) | {"size_mean_m": list(c.size_mean_m)} for c in self.configs],
            "scenes": [{"scene": s.scene, "configs": s.configs, "points": s.points,
                        "size_m": {k: list(v) for k, v in s.size_m.items()}, "proportions_pct": s.proportions_pct,
                        "extent_spread": list(s.extent_spread), "class_spread_pp": s.class_spread_pp}
                       for s in self.scenes],
            "units": [{"unit": u.unit, "scene": u.scene, "config": u.config, "points": u.points,
                       "min_m": u.minimum.tolist(), "max_m": u.maximum.tolist(), "size_m": u.size.tolist(),
                       "class_counts": u.class_counts} for u in self.units],
            "stability": {"max_extent_spread": extent, "max_extent_spread_scene": extent_scene,
                          "max_extent_spread_axis": extent_axis, "max_class_spread_pp": share,
                          "max_class_spread_scene": share_scene, "max_class_spread_class": share_class},
            "missing_units": [{"id": m.id, "status": m.status, "error": m.error} for m in self.missing],
        }


def summarize_dataset(collected: CollectedDataset) -> DatasetStats:
    """Tables and stability figures of the collected units (see the module docs)."""
    classes = [c.name for c in collected.classes]
    colors = {c.name: c.color for c in collected.classes}
    units = collected.units
    configs = []
    for config in collected.configs:
        members = [u for u in units if u.config == config]
        if not members:
            continue
        points = np.array([u.points for u in members], dtype=np.int64)
        sizes = np.array([u.size for u in members])
        counts = np.array([[u.class_counts.get(c, 0) for c in classes] for u in members], dtype=np.float64).sum(axis=0)
        total = int(points.sum())
        configs.append(ConfigStats(
            config=config, units=len(members), points_total=total, points_mean=float(points.mean()),
            points_min=int(points.min()), points_max=int(points.max()),
            size_mean_m=tuple(float(v) for v in sizes.mean(axis=0)),  # type: ignore[arg-type]
            proportions_pct={c: (100.0 * float(n) / total if total else 0.0) for c, n in zip(classes, counts)}))
    scenes = []
    for scene in collected.scenes:
        members = [u for u in units if u.scene == scene]
        if not members:
            continue
        # a unit without points has no extent or proportions to compare (its count still shows)
        measured = [u for u in members if u.points > 0] or members
        sizes = np.array([u.size for u in measured])
        shares = np.array([u.proportions_pct(classes) for u in measured])
        mean = sizes.mean(axis=0)
        spread = np.where(mean > 0, (sizes.max(axis=0) - sizes.min(axis=0)) / np.where(mean > 0, mean, 1.0), 0.0)
        scenes.append(SceneStats(
            scene=scene, configs=[u.config for u in members], points={u.config: u.points for u in members},
            size_m={u.config: tuple(float(v) for v in u.size) for u in members},  # type: ignore[misc]
            proportions_pct={u.config: dict(zip(classes, (float(v) for v in u.proportions_pct(classes))))
                             for u in members},
            extent_spread=tuple(float(v) for v in spread),  # type: ignore[arg-type]
            class_spread_pp={c: float(shares[:, i].max() - shares[:, i].min()) for i, c in enumerate(classes)}))
    return DatasetStats(classes=classes, colors=colors, configs=configs, scenes=scenes, units=units,
                        missing=collected.missing)

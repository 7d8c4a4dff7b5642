"""The statistics as PNG plots (matplotlib, Agg): paper Figs. 4, 5 and 6.

Each function returns the PNG bytes; the caller writes them (atomically).
"""

from __future__ import annotations

import io
from typing import TYPE_CHECKING

import numpy as np

from bimscan.files import PNG_SOFTWARE
from bimscan.stats.summary import AXES, DatasetStats

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _figure(width_in: float, height_in: float) -> Figure:
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=110, layout="constrained")


def _png(figure: Figure) -> bytes:
    buffer = io.BytesIO()
    # Fixed metadata: the same statistics give the same bytes.
    figure.savefig(buffer, format="png", metadata={"Software": PNG_SOFTWARE})
    return buffer.getvalue()


def _scene_colors(n: int) -> list[tuple[float, float, float, float]]:
    from matplotlib import colormaps

    cmap = colormaps["tab20" if n > 10 else "tab10"]
    return [cmap(i % cmap.N) for i in range(n)]


def plot_points(stats: DatasetStats) -> bytes:
    """Fig. 4: points per scene for every configuration (log scale), and the totals."""
    figure = _figure(11, 4.2)
    left, right = figure.subplots(1, 2, width_ratios=(2.2, 1))
    configs = [c.config for c in stats.configs]
    x = np.arange(len(configs))
    scenes = [s for s in stats.scenes]
    width = 0.8 / max(1, len(scenes))
    for i, (scene, color) in enumerate(zip(scenes, _scene_colors(len(scenes)))):
        values = [scene.points.get(c, np.nan) for c in configs]
        left.bar(x - 0.4 + width * (i + 0.5), values, width=width, color=color, label=scene.scene)
    left.set_yscale("log")
    left.set_xticks(x, configs)
    left.set_ylabel("points per scene")
    left.set_title("Points per scene and configuration")
    if len(scenes) <= 24:
        left.legend(fontsize="small", ncols=max(1, len(scenes) // 12 + 1), title="scene")
    totals = [c.points_total for c in stats.configs]
    right.bar(x, totals, color="#4e79a7")
    right.set_yscale("log")
    right.set_xticks(x, configs)
    right.set_ylabel("points, all scenes")
    right.set_title("Total per configuration")
    for xi, total in zip(x, totals):
        right.annotate(f"{total / 1e6:.1f}M", (xi, total), ha="center", va="bottom", fontsize="small")
    return _png(figure)


def plot_extents(stats: DatasetStats) -> bytes:
    """Fig. 5: each scene's extent along X, Y and Z across the configurations."""
    figure = _figure(11, 3.8)
    axes = figure.subplots(1, 3)
    configs = [c.config for c in stats.configs]
    x = np.arange(len(configs))
    colors = _scene_colors(len(stats.scenes))
    for a, (ax, name) in enumerate(zip(axes, AXES)):
        for scene, color in zip(stats.scenes, colors):
            values = [scene.size_m[c][a] if c in scene.size_m else np.nan for c in configs]
            ax.plot(x, values, marker="o", color=color, label=scene.scene)
        ax.set_xticks(x, configs)
        ax.set_title(f"extent along {name.upper()}")
        ax.set_ylabel("metres")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    if len(stats.scenes) <= 24:
        axes[-1].legend(fontsize="small", title="scene", loc="lower right")
    return _png(figure)


def plot_classes(stats: DatasetStats) -> bytes:
    """Fig. 6: class proportions of each configuration (all scenes together), stacked."""
    figure = _figure(9, 4.4)
    ax = figure.subplots()
    configs = [c.config for c in stats.configs]
    x = np.arange(len(configs))
    bottom = np.zeros(len(configs))
    for name in stats.classes:
        shares = np.array([c.proportions_pct.get(name, 0.0) for c in stats.configs])
        bars = ax.bar(x, shares, bottom=bottom, color=stats.colors.get(name, "#999999"), label=name, width=0.6)
        for bar, share, base in zip(bars, shares, bottom):
            if share >= 4:
                ax.text(bar.get_x() + bar.get_width() / 2, base + share / 2, f"{share:.1f}", ha="center",
                        va="center", fontsize="x-small", color="white")
        bottom += shares
    ax.set_xticks(x, configs)
    ax.set_ylim(0, 100)
    ax.set_ylabel("share of points (%)")
    ax.set_title("Class proportions per configuration")
    ax.legend(fontsize="small", loc="center left", bbox_to_anchor=(1.01, 0.5))
    return _png(figure)

"""Compose rendered panels into one PNG of an exact pixel size: titles above, legend below.

Layout (pixels)::

    +--------------------------------------------------+
    | title                                  TITLE_PX  |
    | panel title      | panel title                   |
    | +-------------+  +-------------+                 |
    | |   panel     |  |   panel     |  ...            |
    | +-------------+  +-------------+                 |
    | [] class  [] class  [] class           LEGEND_PX |
    +--------------------------------------------------+

Panels are copied pixel for pixel (matplotlib's ``figimage``, no resampling), so their colours
are exactly the ones drawn; text never overlaps them. The PNG is written atomically and carries
no timestamp, so the same panels give the same bytes.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import PNG_SOFTWARE, check_replaceable, write_atomic
from bimscan.types import LabelScheme

TITLE_PX = 46
LEGEND_PX = 36
GAP_PX = 8
DPI = 100


@dataclass(frozen=True)
class Panel:
    title: str
    image: np.ndarray  # (H, W, 3) uint8


UNKNOWN_RGB = (150, 150, 150)  # points or faces of a class the scheme does not name


def class_color_table(scheme: LabelScheme) -> np.ndarray:
    """(256, 3) uint8 colour of every class id (the scheme's colours, grey for the rest)."""
    table = np.tile(np.array(UNKNOWN_RGB, dtype=np.uint8), (256, 1))
    for cls in scheme.classes:
        table[cls.id] = cls.rgb
    return table


def panel_origin(index: int, panel_width: int) -> tuple[int, int]:
    """Top-left pixel (x, y) of panel ``index`` in the composed image."""
    return GAP_PX + index * (panel_width + GAP_PX), TITLE_PX


def check_png_output(out: str | Path) -> Path:
    """Raise OutputError now for a picture path that cannot be written (before any slow work)."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise OutputError(f"{out}: pictures are written as PNG; give a path ending in .png")
    if not out.parent.is_dir():
        raise OutputError(f"output folder {out.parent} does not exist; create it first or choose another path")
    check_replaceable(out)  # a PNG bimscan wrote is replaced; a user's picture, a folder, a link are not
    return out


def compose_png(panels: list[Panel], *, legend: list[tuple[str, tuple[int, int, int]]], title: str, out: str | Path,
                width: int, height: int) -> Path:
    """Write the panels side by side with ``title`` and ``legend`` as an exactly width x height PNG."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    out = check_png_output(out)
    canvas = np.full((height, width, 3), 255, dtype=np.uint8)
    figure = Figure(figsize=(width / DPI, height / DPI), dpi=DPI)
    for index, panel in enumerate(panels):
        x, y = panel_origin(index, panel.image.shape[1])
        h, w = panel.image.shape[:2]
        if x + w > width or y + h > height - LEGEND_PX + 1:
            raise ValueError(f"panel {index} ({w}x{h}) does not fit a {width}x{height} image")
        canvas[y:y + h, x:x + w] = panel.image
        figure.text((x + w / 2) / width, 1 - (TITLE_PX - 10) / height, panel.title, ha="center", va="center",
                    fontsize=10)
    figure.figimage(canvas, 0, 0, origin="upper", resize=False)
    figure.text(0.5, 1 - 12 / height, title, ha="center", va="center", fontsize=10, weight="bold")
    if legend:
        handles = [Patch(facecolor=np.array(rgb) / 255, edgecolor="none", label=name) for name, rgb in legend]
        figure.legend(handles=handles, loc="lower center", ncols=min(len(handles), 8), frameon=False, fontsize=9,
                      bbox_to_anchor=(0.5, 2 / height), handlelength=1.2, columnspacing=1.2)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI, metadata={"Software": PNG_SOFTWARE})
    try:
        write_atomic(out, buffer.getvalue())
    except OSError as exc:
        raise OutputError(f"could not write {out} ({exc.strerror}); check the folder and free space") from exc
    return out

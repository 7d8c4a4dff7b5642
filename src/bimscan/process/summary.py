"""Running totals over a stream of labelled chunks: points, extents, class and station histograms.

``CloudSummary`` accumulates them chunk by chunk without holding the stream, for the scan and
dataset reports and the statistics' recount.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from bimscan.types import PointCloud


@nb.njit(cache=True, nogil=True)
def column_extents(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min (3,), max (3,)) of an (N, 3) array in one pass (NumPy's axis-0 reductions over three
    columns are an order of magnitude slower)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(xyz.shape[0]):
        for j in range(3):
            v = xyz[i, j]
            if v < lo[j]:
                lo[j] = v
            if v > hi[j]:
                hi[j] = v
    return lo, hi


@dataclass
class CloudSummary:
    """Running totals over a stream of chunks: points, extents, class and station histograms."""

    points: int = 0
    dropped_invalid: int = 0
    minimum: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    maximum: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    class_counts: np.ndarray = field(default_factory=lambda: np.zeros(256, dtype=np.int64))
    station_counts: dict[int, int] = field(default_factory=dict)

    def add(self, chunk: PointCloud) -> None:
        if len(chunk) == 0:
            return
        self.points += len(chunk)
        lo, hi = column_extents(chunk.xyz)
        np.minimum(self.minimum, lo, out=self.minimum)
        np.maximum(self.maximum, hi, out=self.maximum)
        if chunk.label is not None:
            self.class_counts += np.bincount(chunk.label, minlength=256)[:256]
        if chunk.station is not None:
            counts = np.bincount(chunk.station)
            for i in np.flatnonzero(counts).tolist():
                self.station_counts[i] = self.station_counts.get(i, 0) + int(counts[i])

    def histogram(self, names: dict[int, str]) -> dict[str, int]:
        """Points per class name (every class of the scheme, zeros included)."""
        return {name: int(self.class_counts[i]) for i, name in sorted(names.items())}

    def extents(self) -> dict[str, list[float]]:
        if self.points == 0:
            return {"min": [0.0, 0.0, 0.0], "max": [0.0, 0.0, 0.0], "size": [0.0, 0.0, 0.0]}
        return {"min": [round(float(v), 4) for v in self.minimum], "max": [round(float(v), 4) for v in self.maximum],
                "size": [round(float(v), 4) for v in self.maximum - self.minimum]}

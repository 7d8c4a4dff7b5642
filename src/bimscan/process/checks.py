"""Streaming post-processing of labelled chunks.

``filter_invalid`` drops points that cannot be real returns (non-finite coordinates); the
scanner already drops misses and out-of-range hits, so on a healthy scan it drops nothing and
the count is recorded as a check. ``check_semantics`` verifies every point's component exists and
that its label is the one its component maps to.
"""

from __future__ import annotations

import numpy as np

from bimscan.errors import SemanticError
from bimscan.types import ComponentTable, PointCloud


def filter_invalid(chunk: PointCloud) -> tuple[PointCloud, int]:
    """Drop points with non-finite coordinates; returns the kept chunk and the dropped count."""
    if len(chunk) == 0 or (np.isfinite(chunk.xyz.min()) and np.isfinite(chunk.xyz.max())):
        return chunk, 0  # the common case, checked with two flat reductions (NaN and inf propagate)
    ok = np.isfinite(chunk.xyz).all(axis=1)
    dropped = int(len(ok) - ok.sum())
    return (chunk if dropped == 0 else chunk.take(ok)), dropped


def check_semantics(chunk: PointCloud, components: ComponentTable) -> None:
    """Raise SemanticError unless every point's component exists and carries the component's label."""
    if chunk.component is None or chunk.label is None or len(chunk) == 0:
        return
    if chunk.component.min() < 0 or chunk.component.max() >= len(components):
        bad = chunk.component[(chunk.component < 0) | (chunk.component >= len(components))][0]
        raise SemanticError(f"point with component {bad}, but the table has {len(components)} components")
    expected = components.label[chunk.component]
    mismatch = expected != chunk.label
    if mismatch.any():
        i = int(np.flatnonzero(mismatch)[0])
        raise SemanticError(f"{int(mismatch.sum())} points carry a label other than their component's "
                            f"(first: component {chunk.component[i]} labelled {chunk.label[i]}, maps to {expected[i]})")

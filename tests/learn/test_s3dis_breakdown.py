"""scripts/s3dis_breakdown.py: the per-S3DIS-class table and the walls' context table add up."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "s3dis_breakdown.py"


def _write(path: Path, xyz: np.ndarray) -> None:
    colour = np.full((len(xyz), 3), 128)
    np.savetxt(path, np.hstack([xyz, colour]), fmt="%.4f")


def test_breakdown_counts_every_point_and_bins_walls_by_their_distance_to_furniture(
    tmp_path: Path, trained_run: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    spec = importlib.util.spec_from_file_location("s3dis_breakdown", SCRIPT)
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)

    rng = np.random.default_rng(0)
    notes = tmp_path / "Area_9" / "office_1" / "Annotations"
    notes.mkdir(parents=True)
    grid = np.stack(np.meshgrid(np.arange(0.0, 4.0, 0.1), np.arange(0.0, 3.0, 0.1)), -1).reshape(-1, 2)
    _write(notes / "floor_1.txt", np.c_[grid, np.zeros(len(grid))])
    _write(notes / "ceiling_1.txt", np.c_[grid, np.full(len(grid), 2.8)])
    # a wall at y = 0: 20 points 0.05 m from the chair below, 30 points 1.0-1.2 m from it
    near = np.c_[rng.uniform(0.0, 0.2, 20), np.zeros(20), rng.uniform(0.5, 0.6, 20)]
    far = np.c_[rng.uniform(1.2, 1.4, 30), np.zeros(30), rng.uniform(0.5, 0.6, 30)]
    _write(notes / "wall_1.txt", np.r_[near, far])
    chair = np.c_[rng.uniform(0.0, 0.2, 40), np.full(40, 0.05), rng.uniform(0.5, 0.6, 40)]
    _write(notes / "chair_1.txt", chair)
    # a window right beside the far wall points is not context (it lies in the wall plane)
    _write(notes / "window_1.txt", np.c_[rng.uniform(1.2, 1.4, 10), np.zeros(10), rng.uniform(0.7, 0.8, 10)])

    script.main(str(trained_run / "run" / "last.pt"), str(tmp_path / "Area_9"))
    out = capsys.readouterr().out
    classes, context = out.split("\n\n")
    rows = {line.split()[0]: line.split() for line in classes.splitlines()[1:]}
    assert int(rows["wall"][-1]) == 50 and int(rows["chair"][-1]) == 40 and int(rows["floor"][-1]) == len(grid)
    for row in rows.values():  # every class's points land in some class: its shares sum to 100 %
        assert abs(sum(float(v) for v in row[1:-1]) - 100.0) < 0.5
    assert "window" in context.splitlines()[0]
    bins = {line.split()[0]: int(line.split()[-1]) for line in context.splitlines()[2:]}
    assert bins == {"0.0-0.1": 20, "0.8-1.6": 30}

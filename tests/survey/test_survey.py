"""Surveys: the points a pulse gives, measured on a thinned pattern, against the full scan."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.pipeline import load_scene
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.survey import prepare_survey, probe_points_per_pulse, run_survey
from bimscan.types import BimScene


def _full_scan_points_per_pulse(scene: BimScene, recipe: ScanRecipe, stations: int) -> tuple[float, tuple]:
    survey = prepare_survey(scene, recipe)
    survey = prepare_survey(scene, recipe, scanner=survey.scanner, stations=survey.stations[:stations])
    points = sum(int(np.isfinite(chunk.xyz).all(axis=1).sum()) for chunk in run_survey(survey, reuse_buffers=True))
    return points / survey.pulses(), survey.stations


def test_the_thinned_pattern_gives_the_points_a_pulse_of_the_full_scan_in_a_closed_room(box_room_ifc: Path) -> None:
    scene = load_scene(box_room_ifc)
    recipe = ScanRecipe.resolve(preset="exp3", head_deg_per_s=60.0)
    full, stations = _full_scan_points_per_pulse(scene, recipe, 1)
    assert 0.5 < full < 1.0  # every direction meets a wall, but pulses inside the scanner's minimum range give nothing
    assert probe_points_per_pulse(scene, recipe, stations) == pytest.approx(full, abs=0.02)


@pytest.mark.parametrize("preset, head_deg_per_s", [("exp1", 60.0), ("exp6", 120.0)])
def test_the_thinned_pattern_gives_the_points_a_pulse_of_the_full_scan_in_a_building_with_windows(
        tmp_path: Path, preset: str, head_deg_per_s: float) -> None:
    from bimscan.ifc.generate import make_building

    scene = load_scene(make_building(tmp_path / "office.ifc", seed=2, storeys=2).path)
    recipe = ScanRecipe.resolve(preset=preset, head_deg_per_s=head_deg_per_s)
    full, stations = _full_scan_points_per_pulse(scene, recipe, 4)
    assert full < 0.95  # pulses leave through windows and stairwells: not every pulse gives a point
    assert probe_points_per_pulse(scene, recipe, stations) == pytest.approx(full, abs=0.02)

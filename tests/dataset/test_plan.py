"""Planning a build: the units start largest first, the manifest keeps the spec's order."""

from __future__ import annotations

from pathlib import Path

from bimscan.dataset.layout import DatasetFolder
from bimscan.dataset.plan import generate_scenes, plan_build
from bimscan.dataset.spec import load_spec
from bimscan.survey.survey import station_pulses

from .conftest import UNIT_IDS, write_tiny_spec


def test_units_start_largest_first_and_the_manifest_keeps_the_spec_order(tmp_path: Path, session_env: Path) -> None:
    spec = load_spec(write_tiny_spec(tmp_path))
    folder = DatasetFolder(tmp_path / "out")
    folder.scenes_dir.mkdir(parents=True)
    plan = plan_build(spec, folder, generate_scenes(spec, folder))
    assert [e.id for e in plan.entries] == list(UNIT_IDS)  # sparse before dense, as the spec lists them
    assert list(plan.unit_jobs) == ["north__dense", "south__dense", "north__sparse", "south__sparse"]
    sizes = [station_pulses(job.recipe) for job in plan.unit_jobs.values()]
    assert sizes == sorted(sizes, reverse=True) and sizes[0] > 1.5 * sizes[-1]

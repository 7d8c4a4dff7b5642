"""What a build will take: the time left (on a simulated clock) and the output's size against the free space."""

from __future__ import annotations

import json
import shutil
from collections import namedtuple
from pathlib import Path

import numpy as np
import pytest

from bimscan.dataset.build import build_dataset
from bimscan.dataset.estimate import (
    UnitWork, WorkProgress, check_output_fits, estimate_size, tripod_unit_work, with_unknown_as_mean,
)
from bimscan.dataset.spec import load_spec
from bimscan.errors import OutputError
from bimscan.survey.recipe import ScanRecipe
from bimscan.survey.survey import station_pulses

from .conftest import BuiltDataset

PRESET_PULSES = [station_pulses(ScanRecipe.resolve(preset=f"exp{k}")) for k in range(1, 7)]  # 0.75M .. 7.5M


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _spc_like_units(seed: int, *, growing: bool) -> tuple[list[str], dict[str, float]]:
    """22 scenes x the six presets, in spec order (scene by scene); stations per scene drawn from
    10..40, sorted small to large when ``growing`` (generated buildings of one to four storeys)."""
    rng = np.random.default_rng(seed)
    stations = rng.integers(10, 41, size=22)
    if growing:
        stations = np.sort(stations)
    pulses = {f"s{i:02d}__exp{k + 1}": float(n * PRESET_PULSES[k]) for i, n in enumerate(stations) for k in range(6)}
    return list(pulses), pulses


def _simulate(order: list[str], pulses: dict[str, float], weights: dict[str, float], *, workers: int,
              reports: bool, seed: int) -> tuple[float, float, float]:
    """A build on a simulated clock: ``workers`` take the units in order; a unit takes 2 s to load
    and prepare, then scans at 3 Mpulses/s give or take 15 % (one draw per unit), and is checked
    and moved into place in 1 s. Every 0.5 s the driver reads the pulses scanned (``reports``: the
    local workers; otherwise only finished units count, as on Ray). Returns (share of the work done,
    predicted seconds left, actual seconds left) when the work first passed a tenth."""
    rng = np.random.default_rng(seed)
    clock = FakeClock()
    progress = WorkProgress(weights, clock=clock)
    queue = list(order)
    Running = namedtuple("Running", "unit start scan_start scan_end end")
    running: list[Running] = []
    reported: dict[str, float] = {}
    step = 0.5
    while queue or running:
        while queue and len(running) < workers:
            unit = queue.pop(0)
            rate = 3e6 * rng.uniform(0.85, 1.15)
            scan_start = clock.now + 2.0
            scan_end = scan_start + pulses[unit] / rate
            running.append(Running(unit, clock.now, scan_start, scan_end, scan_end + 1.0))
        clock.now += step
        for job in list(running):
            if clock.now >= job.end:
                running.remove(job)
                progress.finished(job.unit, seconds=job.end - job.start)
            elif reports and clock.now > job.scan_start:
                share = min(1.0, (clock.now - job.scan_start) / (job.scan_end - job.scan_start))
                now_scanned = share * pulses[job.unit]
                progress.scanned(job.unit, now_scanned - reported.get(job.unit, 0.0))
                reported[job.unit] = now_scanned
    check = progress.eta_check()
    assert check is not None
    return check.fraction, check.predicted_left_s, check.actual_left_s


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("growing", [True, False], ids=["scenes-growing", "scenes-mixed"])
@pytest.mark.parametrize("workers", [2, 8])
def test_the_time_left_weighted_by_pulses_is_within_a_fifth_once_a_tenth_of_a_build_of_unequal_units_is_done(
        seed: int, growing: bool, workers: int) -> None:
    order, pulses = _spc_like_units(seed, growing=growing)
    assert max(pulses.values()) / min(pulses.values()) > 20  # units differ a lot
    fraction, predicted, actual = _simulate(order, pulses, pulses, workers=workers, reports=True, seed=seed)
    assert 0.1 <= fraction < 0.11
    assert abs(predicted - actual) <= 0.2 * actual, (predicted, actual)


@pytest.mark.parametrize("workers", [2, 8])
def test_counting_units_instead_of_their_pulses_predicts_the_same_build_wrong(workers: int) -> None:
    # the check above can fail: one weight per unit is far off
    order, pulses = _spc_like_units(0, growing=True)
    _, predicted, actual = _simulate(order, pulses, dict.fromkeys(order, 1.0), workers=workers, reports=True, seed=0)
    assert abs(predicted - actual) > 0.2 * actual, (predicted, actual)


def test_the_fixed_time_of_a_unit_is_fitted_to_the_finished_units_and_weighs_every_unit() -> None:
    clock = FakeClock()
    progress = WorkProgress({"a": 1000.0, "b": 3000.0, "c": 6000.0, "d": 10000.0}, clock=clock)
    progress.finished("a", seconds=3.0)  # 2 s fixed + 1 ms a pulse
    progress.finished("b", seconds=5.0)
    assert progress.overhead_pulses == 0.0 and progress.fraction == pytest.approx(4000 / 20000)  # two: no fit yet
    progress.finished("c", seconds=8.0)
    assert progress.overhead_pulses == pytest.approx(2000.0)  # 2 s worth 2000 pulses
    assert progress.total == pytest.approx(20000 + 4 * 2000)
    assert progress.fraction == pytest.approx((10000 + 3 * 2000) / 28000)
    progress.scanned("d", 5000)  # scanning: half its fixed time and what it scanned are done
    assert progress.done == pytest.approx(10000 + 3 * 2000 + 5000 + 1000)


def test_work_progress_counts_a_running_unit_up_to_its_weight_and_a_finished_one_whole() -> None:
    clock = FakeClock()
    progress = WorkProgress({"a": 100.0, "b": 300.0}, clock=clock)
    assert progress.remaining_s() is None and progress.status() == "0/2 units, time left: estimating"
    clock.now += 10
    progress.scanned("a", 60)
    progress.scanned("a", 60)  # more than its estimate: counted as its weight
    assert progress.done == 100 and progress.fraction == 0.25
    assert progress.remaining_s() == pytest.approx(30.0)  # 10 s for a quarter: 30 s for the rest
    progress.finished("a")
    progress.scanned("a", 50)  # late reports of a finished unit change nothing
    assert progress.done == 100 and progress.units_finished == 1
    progress.finished("b")
    assert progress.fraction == 1.0 and progress.remaining_s() == 0.0


def test_the_check_keeps_the_first_prediction_past_a_tenth_and_compares_it_with_the_end() -> None:
    clock = FakeClock()
    progress = WorkProgress({"a": 1.0, "b": 9.0}, clock=clock)
    clock.now += 5
    progress.finished("a")  # 10 % after 5 s: 45 s predicted
    clock.now += 60
    progress.finished("b")
    check = progress.eta_check()
    assert (check.fraction, check.elapsed_s, check.predicted_left_s, check.actual_left_s) == (0.1, 5.0, 45.0, 60.0)
    assert check.error == pytest.approx(-0.25)
    assert "45 s; it took 60 s (-25%)" in check.line()


def test_a_mobile_unit_whose_walk_is_not_planned_yet_counts_as_the_mean_tripod_unit() -> None:
    works = [tripod_unit_work("s__a", "s", station_pulses=1000, stations=10, points_per_pulse=0.5),
             tripod_unit_work("s__b", "s", station_pulses=3000, stations=10, points_per_pulse=0.5, echoes=4),
             UnitWork("s__walk", "s", pulses=0, points=0, most_points=0, known=False)]
    filled = with_unknown_as_mean(works)
    assert filled[:2] == works[:2]
    assert (filled[2].pulses, filled[2].points, filled[2].most_points, filled[2].known) == (20000, 10000, 65000, False)
    alone = with_unknown_as_mean(works[2:])  # nothing known: equal weights, no size
    assert (alone[0].pulses, alone[0].points) == (1.0, 0.0)
    estimate = estimate_size(works[2:], Path("."), formats=("laz",))
    assert estimate.fits and estimate.line().startswith("output: not estimated (1 mobile units")


def _disk(free: int):
    usage = shutil.disk_usage("/")
    return lambda path: type(usage)(total=usage.total, used=usage.total - free, free=free)


def test_the_size_estimate_refuses_in_one_line_naming_the_size_the_free_space_and_a_subset_that_fits(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    works = [tripod_unit_work(f"{scene}__exp{k}", scene, station_pulses=PRESET_PULSES[k - 1], stations=20,
                              points_per_pulse=0.8) for scene in ("a", "b", "c") for k in (1, 5)]
    per_scene = 20 * 0.8 * (PRESET_PULSES[0] + PRESET_PULSES[4]) * 6.0  # LAZ, typical bytes a point
    monkeypatch.setattr(shutil, "disk_usage", _disk(int(2.5 * per_scene)))
    estimate = estimate_size(works, tmp_path, formats=("laz",))
    assert estimate.bytes == pytest.approx(3 * per_scene) and not estimate.fits
    assert estimate.most_bytes == pytest.approx(3 * per_scene / 0.8 * 12 / 6)
    with pytest.raises(OutputError) as raised:
        check_output_fits(estimate)
    message = str(raised.value)
    assert "\n" not in message
    assert message.startswith(f"the build would write about {3 * per_scene / 1e9:.1f} GB (6 units")
    assert f"{tmp_path} has {2.5 * per_scene / 1e9:.1f} GB free" in message
    assert f"the first 2 of 3 scenes (4 units, about {2 * per_scene / 1e9:.1f} GB) fit" in message
    monkeypatch.setattr(shutil, "disk_usage", _disk(int(3.1 * per_scene)))
    check_output_fits(estimate_size(works, tmp_path, formats=("laz",)))  # fits: no error


def test_finished_units_of_the_dataset_give_the_bytes_a_point_of_the_rest(tmp_path: Path) -> None:
    works = [tripod_unit_work("a__x", "a", station_pulses=1000, stations=2, points_per_pulse=1.0)]
    typical = estimate_size(works, tmp_path, formats=("laz", "npy"))
    assert typical.bytes_per_point == 6.0 + 32 and typical.measured_on == 0
    measured = estimate_size(works, tmp_path, formats=("laz", "npy"), finished=[(4_000, 100), (2_000, 50)])
    assert measured.bytes_per_point == 40.0 and measured.measured_on == 2 and measured.bytes == 2000 * 40.0
    assert "as this dataset's 2 finished units" in measured.line()


def test_a_build_estimates_its_points_and_bytes_close_to_what_it_wrote(reference_dataset: BuiltDataset) -> None:
    estimate = reference_dataset.report.estimate
    units = [json.loads(p.read_text()) for p in sorted(reference_dataset.out.glob("units/*/unit.json"))]
    points, n_bytes = sum(u["points"] for u in units), sum(u["bytes"] for u in units)
    assert estimate.units == 4 and estimate.formats == ("laz", "npy")
    assert estimate.points == pytest.approx(points, rel=0.05)  # the probe's points per pulse
    assert estimate.bytes == pytest.approx(n_bytes, rel=0.25)  # LAZ compresses these sparse scans less than typical
    assert estimate.bytes < n_bytes < estimate.most_bytes


def test_a_build_keeps_the_time_left_it_predicted_after_a_tenth_of_the_work(reference_dataset: BuiltDataset) -> None:
    eta = reference_dataset.report.eta  # local workers report the pulses of each unit as they scan
    assert eta is not None and 0.1 <= eta.fraction < 1.0
    assert eta.predicted_left_s > 0 and eta.actual_left_s > 0
    assert eta.elapsed_s + eta.actual_left_s <= reference_dataset.report.seconds


def _one_scene_spec(folder: Path) -> Path:
    path = folder / "spec.toml"
    path.write_text('formats = ["npy"]\n[[scenes]]\nname = "good"\ngenerate = { seed = 1, storeys = 1 }\n'
                    '[[configs]]\nname = "fast"\npreset = "exp3"\nhead_deg_per_s = 360.0\n')
    return path


def test_a_build_the_disk_cannot_hold_stops_before_any_unit_with_one_line_and_resumes_when_there_is_room(
        tmp_path: Path, session_env: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from bimscan.cli.main import main

    spec, out = _one_scene_spec(tmp_path), tmp_path / "out"
    monkeypatch.setattr(shutil, "disk_usage", _disk(1_000_000))  # 1 MB free: the unit takes about 10
    assert main(["build", str(spec), str(out), "--workers", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-2].startswith("estimated output: about ") and err[-2].endswith(f"1 MB free in {out}")
    assert err[-1].startswith("error: the build would write about ") and "1 MB free" in err[-1]
    assert "not even the first scene's units fit" in err[-1]
    assert [u["status"] for u in json.loads((out / "manifest.json").read_text())["units"]] == ["pending"]
    assert list((out / "units").iterdir()) == []  # nothing half-written
    assert (out / "scenes" / "good.stations.json").is_file()  # the planned stations are kept for the next run
    monkeypatch.undo()
    report = build_dataset(load_spec(spec), out, executor="serial", progress=False)
    assert report.ok and report.built == 1 and report.estimate.fits

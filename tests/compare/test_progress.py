"""Scan against model element by element: statuses, stations, deviations, schedule, outputs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.compare.config import ProgressConfig
from bimscan.compare.progress import compare_scan
from bimscan.errors import CompareError
from bimscan.pipeline import load_scene

from .conftest import STATIONS, motion, move_as_foreign_las, scan


def _statuses(result, scene) -> dict[str, str]:
    return {str(name): str(status) for name, status in zip(scene.components.name, result.elements.status)}


def test_what_stands_is_built_what_does_not_is_not_and_nothing_unseen_is_called_missing(building_ifc, partial_scan):
    scene = load_scene(building_ifc)
    result = compare_scan(scene, partial_scan, matrix=np.eye(4), config=ProgressConfig())
    status = _statuses(result, scene)
    assert status["column"] == "not built" and status["ceiling"] == "not built"
    for name in ("south", "east", "west", "north A", "west B", "north B", "floor A", "floor B", "roof A", "roof B",
                 "beam"):
        assert status[name] == "built", name
    # the stations' views: the scan's own header
    assert [v.source for v in result.views] == ["scan", "scan"]
    assert sum(v.points for v in result.views) == result.points


def test_an_element_no_station_could_see_is_not_visible_never_not_built(building_ifc, tiny_model, tmp_path):
    # a closed box room beside the building, with no station in it: its walls are hidden
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(-0.25, -0.25, -0.3), size=(12.5, 5.5, 0.3), name="floor A")
    model.add_box("IfcWall", origin=(-0.25, -0.25, 0), size=(12.5, 0.25, 3.2), name="south")
    model.add_box("IfcWall", origin=(-0.25, 5, 0), size=(12.5, 0.25, 3.2), name="north")
    model.add_box("IfcWall", origin=(-0.25, 0, 0), size=(0.25, 5, 3.2), name="west")
    model.add_box("IfcWall", origin=(12, 0, 0), size=(0.25, 5, 3.2), name="east")
    model.add_box("IfcSlab", origin=(-0.25, -0.25, 3.2), size=(12.5, 5.5, 0.3), name="roof")
    model.add_box("IfcWall", origin=(3, 20, 0), size=(4, 0.25, 3.2), name="far away, behind walls")
    path = model.write(tmp_path / "closed.ifc")
    cloud = scan(path, tmp_path / "closed.laz", stations_csv="x,y,height\n3.0,2.5,1.5\n9.5,2.5,1.5\n")
    scene = load_scene(path)
    result = compare_scan(scene, cloud, matrix=np.eye(4), config=ProgressConfig())
    assert _statuses(result, scene)["far away, behind walls"] == "not visible"


def test_a_dark_finish_that_returns_few_pulses_is_never_called_not_built(building_ifc, tmp_path):
    # a dense scan (pulses 0.17 degrees apart) in which nine in ten pulses on the column come
    # back too weak to record (a dark, glossy finish): the directions with no return lie among
    # returns from the column itself, so they say nothing of it
    import laspy

    stations = tmp_path / "one.stations.csv"
    stations.write_text("x,y,height\n3.0,2.5,1.5\n")
    dense = tmp_path / "dense.laz"
    assert main(["scan", str(building_ifc), str(dense), "--stations", str(stations), "--preset", "exp5",
                 "--head-speed", "40", "--no-noise"]) == 0
    scene = load_scene(building_ifc)
    column = int(np.flatnonzero(scene.components.name == "column")[0])
    cloud = laspy.read(dense)
    on_column = np.asarray(cloud.component) == column
    cloud.points = cloud.points[~(on_column & (np.random.default_rng(3).random(len(on_column)) < 0.9))]
    dark = tmp_path / "dark.laz"
    cloud.write(dark)
    result = compare_scan(scene, dark, matrix=np.eye(4), config=ProgressConfig())
    assert _statuses(result, scene)["column"] in ("built", "not visible")


def test_stations_are_found_from_their_points_when_the_file_gives_only_their_ids(building_ifc, partial_scan, tmp_path):
    from bimscan.io import read_cloud_header

    moved = motion(11)
    foreign = move_as_foreign_las(partial_scan, tmp_path / "foreign.las", moved)
    scene = load_scene(building_ifc)
    result = compare_scan(scene, foreign, matrix=np.linalg.inv(moved), config=ProgressConfig())
    truth = {s.id: np.array(s.position) for s in read_cloud_header(partial_scan).stations}
    for view in result.views:
        assert view.source == "estimated"
        assert np.linalg.norm(view.origin - truth[view.id]) < 0.05
    assert _statuses(result, scene)["column"] == "not built"


def test_a_dense_scanner_s_stations_are_placed_to_a_centimetre_by_their_pulses_times(building_ifc, tmp_path):
    # 2,083 pulses a mirror line, 0.03 degree angular noise: the steps between pulses are too noisy to
    # say the height; the pulses' times are not
    from bimscan.io import read_cloud_header

    stations = tmp_path / "dense.stations.csv"
    stations.write_text(STATIONS)
    dense = tmp_path / "dense.laz"
    assert main(["scan", str(building_ifc), str(dense), "--stations", str(stations), "--preset", "exp5",
                 "--head-speed", "120"]) == 0
    moved = motion(5)
    foreign = move_as_foreign_las(dense, tmp_path / "foreign.las", moved, times=True)
    result = compare_scan(load_scene(building_ifc), foreign, matrix=np.linalg.inv(moved), config=ProgressConfig())
    truth = {s.id: np.array(s.position) for s in read_cloud_header(dense).stations}
    assert len(result.views) == len(truth)
    for view in result.views:
        assert view.source == "estimated"
        assert np.linalg.norm(view.origin - truth[view.id]) < 0.01, (view.id, view.origin - truth[view.id])


def test_a_station_that_cannot_be_placed_is_left_out_with_a_warning(building_ifc, partial_scan, tmp_path):
    import laspy

    foreign = move_as_foreign_las(partial_scan, tmp_path / "foreign.las", np.eye(4))
    cloud = laspy.read(foreign)  # 40 of station 0's points under a station id of their own
    cloud.point_source_id[:40] = 9
    cloud.write(foreign)
    lines: list[str] = []
    result = compare_scan(load_scene(building_ifc), foreign, matrix=np.eye(4), config=ProgressConfig(),
                          warn=lines.append)
    assert sorted(v.id for v in result.views) == [0, 1]
    assert len(lines) == 1 and "station 9" in lines[0] and "decide nothing" in lines[0]


def test_a_station_the_first_look_never_met_is_named_not_silently_dropped(building_ifc, partial_scan, tmp_path,
                                                                          monkeypatch):
    import laspy

    from bimscan.compare import progress

    foreign = move_as_foreign_las(partial_scan, tmp_path / "foreign.las", np.eye(4))
    cloud = laspy.read(foreign)  # 500 points in the middle of the file under a station id of their own
    middle = len(cloud.points) * 3 // 8  # between the first look's runs at 0, 1/4, 1/2 and 3/4 of the file
    cloud.point_source_id[middle:middle + 500] = 9
    cloud.write(foreign)
    # a first look of four short runs, as on a scan of hundreds of millions of points
    monkeypatch.setattr(progress, "LOOK_RUNS", 4)
    monkeypatch.setattr(progress, "LOOK_RUN_POINTS", 2000)
    monkeypatch.setattr(progress, "LOOK_GAP_POINTS", 10**9)
    monkeypatch.setattr(progress, "STATION_RUNS", 0)  # and no second look
    lines: list[str] = []
    result = compare_scan(load_scene(building_ifc), foreign, matrix=np.eye(4), config=ProgressConfig(),
                          warn=lines.append)
    assert 9 not in {v.id for v in result.views}
    assert any("station 9 (500 points)" in line and "--stations" in line for line in lines), lines


def test_a_merged_cloud_without_stations_is_refused_saying_how_to_give_them(building_ifc, partial_scan, tmp_path):
    foreign = move_as_foreign_las(partial_scan, tmp_path / "merged.las", np.eye(4), stations=False)
    with pytest.raises(CompareError, match="--stations"):
        compare_scan(load_scene(building_ifc), foreign, matrix=np.eye(4), config=ProgressConfig())


def test_a_station_file_places_the_stations(building_ifc, partial_scan, tmp_path):
    from bimscan.compare.report import read_station_file
    from bimscan.io import read_cloud_header

    foreign = move_as_foreign_las(partial_scan, tmp_path / "foreign.las", np.eye(4))
    stations = read_cloud_header(partial_scan).stations
    (tmp_path / "stations.csv").write_text("id,x,y,z\n" + "".join(
        f"{s.id},{s.position[0]},{s.position[1]},{s.position[2]}\n" for s in stations))
    result = compare_scan(load_scene(building_ifc), foreign, matrix=np.eye(4), config=ProgressConfig(),
                          stations=read_station_file(tmp_path / "stations.csv"))
    assert [v.source for v in result.views] == ["file", "file"]


@pytest.mark.slow
def test_deviations_match_the_as_built_offsets_and_a_misplaced_element_is_out_of_tolerance(building_ifc, tmp_path):
    from bimscan.io import read_cloud_header

    # construction tolerances two and a half times ACI 117's: many elements out of tolerance
    sensor = tmp_path / "sensor.toml"
    sensor.write_text("deviations = true\nposition_tolerance_m = 0.0625\nlevel_tolerance_m = 0.0475\n"
                      "plumb_tolerance_m = 0.0\n")
    cloud = scan(building_ifc, tmp_path / "asbuilt.laz", "--sensor", str(sensor), "--seed", "4")
    scene = load_scene(building_ifc)
    result = compare_scan(scene, cloud, matrix=np.eye(4), config=ProgressConfig(band_m=0.3, support_m=0.2))
    components = read_cloud_header(cloud).metadata["as_built"]["components"]
    shift = dict(zip(components["global_id"], np.array(components["shift_m"])))
    checked = 0
    for c, gid in enumerate(scene.components.global_id.tolist()):
        fit = result.elements.fits[c]
        pinned = np.isfinite(fit.offset_m)
        if result.elements.status[c].startswith("built") and pinned.any() and scene.components.name[c] != "ceiling":
            assert np.abs(fit.offset_m[pinned] - shift[gid][pinned]).max() < 0.005, scene.components.name[c]
            checked += 1
    assert checked >= 8
    assert (result.elements.status == "built out of tolerance").sum() >= 3


def test_the_progress_folder_holds_what_a_site_engineer_opens(building_ifc, partial_scan, tmp_path, capsys):
    import ifcopenshell
    import ifcopenshell.util.element

    from bimscan.io import read_cloud
    from bimscan.io.las import iter_las_fields, las_fields

    out = tmp_path / "progress"
    assert main(["progress", str(building_ifc), str(partial_scan), str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Wall&Column" in printed and "files:" in printed
    names = sorted(p.name for p in out.iterdir())
    assert {"elements.csv", "summary.json", "progress.ifc", "points.laz", "transform.json", "transform.txt"} <= set(names)
    assert any(n.startswith("progress_1_") for n in names) and any(n.startswith("deviation_1_") for n in names)
    rows = {r["name"]: r for r in csv.DictReader((out / "elements.csv").open())}
    assert rows["column"]["status"] == "not built" and rows["south"]["status"] == "built"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["kind"] == "bimscan progress" and summary["by_class"]["Wall&Column"]["not built"] == 1
    model = ifcopenshell.open(str(out / "progress.ifc"))
    column = next(e for e in model.by_type("IfcColumn"))
    assert ifcopenshell.util.element.get_psets(column)["bimscan_ScanComparison"]["Status"] == "not built"
    cloud = read_cloud(out / "points.laz")
    fields = las_fields(out / "points.laz")
    distance = np.concatenate([block["distance_m"] for block in iter_las_fields(out / "points.laz", fields)])
    attached = cloud.component >= 0
    assert attached.mean() > 0.9 and np.nanmax(np.abs(distance[attached])) <= ProgressConfig().band_m
    assert np.all(np.isnan(distance[~attached]))


def test_control_point_pairs_place_the_scan_and_a_mistyped_pair_is_named(building_ifc, partial_scan, tmp_path, capsys):
    true = motion(5)  # model -> scan: surveyed targets known in both frames
    moved = move_as_foreign_las(partial_scan, tmp_path / "moved.las", true)
    targets = np.array([[0.5, 0.5, 0.1], [9.5, 0.5, 0.1], [9.5, 7.5, 2.9], [0.5, 7.5, 2.9], [5.0, 4.0, 1.5]])
    in_scan = targets @ true[:3, :3].T + true[:3, 3]
    in_scan[4] += [0.03, 0.0, 0.0]  # a target picked 3 cm off
    pairs = tmp_path / "control.csv"
    pairs.write_text("".join(",".join(f"{v:.4f}" for v in (*s, *m)) + "\n" for s, m in zip(in_scan, targets)))
    out = tmp_path / "progress"
    assert main(["progress", str(building_ifc), str(moved), str(out), "--transform", str(pairs), "--points", "none"]) == 0
    printed = capsys.readouterr()
    assert "placed by 5 point pairs" in printed.out
    assert "point pair 5 lies" in printed.err and printed.err.count("point pair") == 1, printed.err
    document = json.loads((out / "transform.json").read_text())
    assert document["control"]["pairs"] == 5 and max(document["control"]["residual_mm"]) > 10
    found = np.array(document["matrix"])
    assert np.abs(found @ true - np.eye(4))[:3].max() < 0.01  # the pose the pairs agree on: within a centimetre
    rows = {r["name"]: r for r in csv.DictReader((out / "elements.csv").open())}
    assert rows["column"]["status"] == "not built" and rows["south"]["status"] == "built"


def test_control_point_pairs_on_one_line_are_refused(building_ifc, partial_scan, tmp_path, capsys):
    pairs = tmp_path / "line.csv"
    pairs.write_text("".join(f"{x},0,0,{x},0,0\n" for x in (0.0, 1.0, 2.0, 3.0)))
    assert main(["progress", str(building_ifc), str(partial_scan), str(tmp_path / "out"), "--transform", str(pairs)]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "one line" in error
    assert not (tmp_path / "out").exists()


def test_the_same_comparison_gives_the_same_files(building_ifc, partial_scan, tmp_path):
    for name in ("a", "b"):
        assert main(["progress", str(building_ifc), str(partial_scan), str(tmp_path / name), "--points", "none"]) == 0
    for name in ("elements.csv", "summary.json", "progress.ifc", "transform.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name


def test_progress_against_the_schedule_says_on_time_behind_and_ahead(tmp_path):
    from bimscan.ifc.generate import make_building
    from bimscan.ifc.schedule import read_schedule

    building = make_building(tmp_path / "b.ifc", seed=1, storeys=1, style="site", schedule_start="2025-03-03")
    schedule = read_schedule(building.path)
    finishes = sorted({d.built for d in schedule.values() if d.built})
    scanned_at, judged_at = finishes[len(finishes) // 2], finishes[-1]
    cloud = tmp_path / "b.laz"
    assert main(["scan", str(building.path), str(cloud), "--at", scanned_at, "--head-speed", "120", "--no-noise"]) == 0
    scene = load_scene(building.path)
    result = compare_scan(scene, cloud, matrix=np.eye(4), config=ProgressConfig(), at=judged_at, schedule=schedule)
    states = set(result.elements.schedule.tolist())
    assert "behind" in states and "on time" in states
    early = compare_scan(scene, cloud, matrix=np.eye(4), config=ProgressConfig(), at=finishes[0], schedule=schedule)
    assert "ahead" in set(early.elements.schedule.tolist())


def test_progress_refuses_bad_asks_in_one_line(building_ifc, partial_scan, tmp_path, capsys):
    cases = [
        (["--at", "yesterday"], "YYYY-MM-DD"),
        (["--align", "--transform", str(tmp_path / "t.txt")], "give one"),
        (["--at", "2025-01-01"], "work schedule"),
    ]
    for extra, words in cases:
        assert main(["progress", str(building_ifc), str(partial_scan), str(tmp_path / "out"), *extra]) != 0
        error = capsys.readouterr().err
        assert error.count("\n") == 1 and words in error, error
        assert not (tmp_path / "out").exists()


def test_each_element_keeps_the_same_lowest_priority_points_however_the_file_is_chunked():
    from bimscan.compare.progress import _ElementSample, _offer

    # the priority is splitmix64 of the point's place in the file (the reference, step by step in NumPy)
    place = np.array([0, 1, 2, 12_345, 99_999_999, 2**40], dtype=np.int64)
    with np.errstate(over="ignore"):  # splitmix64 multiplies modulo 2**64
        z = place.astype(np.uint64) + np.uint64(0x9E3779B97F4A7C15) * np.uint64(3 + 1)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        reference = z ^ (z >> np.uint64(31))
    cut = np.array([np.uint64(2**63)], dtype=np.uint64)
    offered = [_offer(int(p), np.array([0]), np.zeros(1, dtype=np.int64), cut, 3) for p in place.tolist()]
    priority = np.concatenate([p for p, _ in offered])
    keep = np.concatenate([k for _, k in offered])
    assert np.array_equal(priority, reference)
    assert np.array_equal(keep, reference < np.uint64(2**63))

    rng = np.random.default_rng(5)
    n = 60_000
    xyz = rng.normal(size=(n, 3))
    component = rng.integers(0, 4, n)
    component[component == 3] = -1  # beyond the band: offered to nobody
    signed = rng.normal(size=n)
    kept = []
    for step in (n, 7_001):
        sample = _ElementSample(3, per_element=500, seed=3)
        for first in range(0, n, step):
            part = slice(first, first + step)
            index = np.flatnonzero(component[part] >= 0)
            sample.add(first, index, xyz[part], component[part], signed[part])
        kept.append(sample.result())
    (xyz_a, component_a, signed_a), (xyz_b, component_b, signed_b) = kept
    assert np.bincount(component_a).tolist() == [500, 500, 500]
    order_a, order_b = np.lexsort((signed_a, component_a)), np.lexsort((signed_b, component_b))
    assert np.array_equal(component_a[order_a], component_b[order_b])
    assert np.array_equal(xyz_a[order_a], xyz_b[order_b])
    # and they are each element's 500 points of lowest priority over the whole file
    everything = _offer(0, np.arange(n), np.maximum(component, 0), np.full(3, np.iinfo(np.uint64).max,
                                                                          dtype=np.uint64), 3)[0]
    for c in range(3):
        mine = np.flatnonzero(component == c)
        lowest = np.sort(mine[np.argsort(everything[mine])[:500]])
        assert np.array_equal(np.sort(signed_a[component_a == c]), np.sort(signed[lowest]))

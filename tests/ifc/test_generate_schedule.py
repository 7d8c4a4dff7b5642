"""make_building's work schedule: every element built by one task, storey by storey, reproducibly."""

from __future__ import annotations

import datetime
from pathlib import Path

import ifcopenshell
import ifcopenshell.api.sequence
import ifcopenshell.util.date
import ifcopenshell.util.element
import numpy as np
import pytest

from bimscan.errors import ConfigError
from bimscan.ifc.generate import GeneratedBuilding, build_building_model, make_building
from bimscan.ifc.generate.floor_plan import GABLE_PARTS, floor_slab_name, plan_building
from bimscan.ifc.generate.work_schedule import STOREY_TRADES, _predecessors, schedule_start_date
from bimscan.ifc.schedule import read_schedule
from bimscan.types import BuildDates

START = "2024-03-02"  # a Saturday: works begin on Monday 4 March


@pytest.fixture(scope="module")
def scheduled(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, GeneratedBuilding]:
    """A two-storey office (stair, ceilings, furniture, flat roof) with a work schedule."""
    path = tmp_path_factory.mktemp("schedule") / "office.ifc"
    return path, make_building(path, seed=0, storeys=2, schedule_start=START)


@pytest.fixture(scope="module")
def one_storey() -> dict[str, tuple[str, GeneratedBuilding]]:
    """A one-storey office (file text, summary) without a schedule, with one from START (twice) and
    with one from another day."""
    out = {}
    for name, start in (("none", None), ("start", START), ("again", START), ("later", "2025-06-02")):
        model, building = build_building_model(seed=6, storeys=1, schedule_start=start)
        out[name] = (model.to_string(), building)
    return out


def built_elements(model: ifcopenshell.file) -> list:
    """Every element with a body: what a scan sees (no spaces, no openings)."""
    return [e for e in model.by_type("IfcElement") if e.Representation is not None and not e.is_a("IfcFeatureElement")]


def tasks_building(product) -> list:
    return [task for rel in product.ReferencedBy or () if rel.is_a("IfcRelAssignsToProduct")
            for task in rel.RelatedObjects if task.is_a("IfcTask")]


def test_every_element_with_a_body_is_built_by_exactly_one_task_and_read_schedule_dates_it(scheduled) -> None:
    path, building = scheduled
    model = ifcopenshell.open(str(path))
    elements = built_elements(model)
    schedule = read_schedule(path)
    for element in elements:
        (task,) = tasks_building(element)
        finish = ifcopenshell.util.date.ifc2datetime(task.TaskTime.ScheduleFinish).date().isoformat()
        assert schedule[element.GlobalId] == BuildDates(built=finish), element
    assert not any(tasks_building(space) for space in model.by_type("IfcSpace"))
    assert sum(task.elements for task in building.works) == len(elements) == sum(building.placed.values())
    assert {task.trade for task in building.works} == {*STOREY_TRADES, "roof"}


def test_the_roof_task_builds_the_attic_under_a_gable_roof() -> None:
    seed = next(seed for seed in range(50) if plan_building(seed=seed, storeys=1, style="residential").roof)
    model, _ = build_building_model(seed=seed, storeys=1, style="residential", schedule_start=START)
    tasks = [(element.Name, tasks_building(element)) for element in built_elements(model)]
    assert all(len(building) == 1 for _, building in tasks)
    assert sorted(name for name, (task,) in tasks if task.Name == "Roof") == sorted([floor_slab_name(1), *GABLE_PARTS])


def test_the_structure_rises_storey_by_storey_while_each_storeys_trades_follow_one_another(scheduled) -> None:
    path, building = scheduled
    model, schedule = ifcopenshell.open(str(path)), read_schedule(path)
    frame = {}  # storey elevation -> built dates of its columns and beams, as read_schedule reads them
    for element in [*model.by_type("IfcColumn"), *model.by_type("IfcBeam")]:
        storey = ifcopenshell.util.element.get_container(element)
        frame.setdefault(storey.Elevation, set()).add(schedule[element.GlobalId].built)
    ground, upper = (frame[z] for z in sorted(frame))
    assert len(ground) == len(upper) == 1 and max(ground) < min(upper)  # one structure task a storey, bottom first
    works = {(task.trade, task.storey): task for task in building.works}
    structure = [works["structure", k] for k in (0, 1)]
    assert structure[0].start == "2024-03-04" and structure[0].finish < structure[1].start
    assert structure[1].finish < works["roof", 2].start  # the roof over the top storey comes last
    for k in (0, 1):
        finishes = [works[trade, k].finish for trade in STOREY_TRADES]
        starts = [works[trade, k].start for trade in STOREY_TRADES]
        assert all(f < s for f, s in zip(finishes, starts[1:]))  # each trade after the one before it
    # the next storey's structure goes up as the walls below it do; finishes wait for the slab over them
    assert structure[1].start == works["exterior_walls", 0].start
    assert works["finishes", 0].start > structure[1].finish
    assert works["finishes", 1].start > works["roof", 2].finish
    days = [datetime.date.fromisoformat(d) for task in building.works for d in (task.start, task.finish)]
    assert all(day.weekday() < 5 for day in days)


def test_ifcopenshells_own_cascade_leaves_every_date_as_written(scheduled) -> None:
    path, building = scheduled
    model = ifcopenshell.open(str(path))
    tasks = model.by_type("IfcTask")
    written = {t.id(): (t.TaskTime.ScheduleStart, t.TaskTime.ScheduleFinish) for t in tasks}
    first = next(t for t in tasks if t.Name == "Structure, ground floor")
    ifcopenshell.api.sequence.cascade_schedule(model, task=first)
    assert {t.id(): (t.TaskTime.ScheduleStart, t.TaskTime.ScheduleFinish) for t in tasks} == written
    assert len(model.by_type("IfcRelSequence")) > len(building.works)  # crews move up as well as on
    for task in building.works:  # durations count Monday to Friday
        finish = datetime.date.fromisoformat(task.finish) + datetime.timedelta(days=1)
        assert np.busday_count(task.start, finish.isoformat()) == task.working_days >= 1


def test_the_same_options_give_the_same_bytes_and_a_schedule_only_adds_to_the_building(one_storey) -> None:
    text = {name: file_text for name, (file_text, _) in one_storey.items()}
    assert text["start"] == text["again"] and "IFCTASK(" in text["start"]
    assert "IFCTASK(" not in text["none"] and "IFCWORKSCHEDULE(" not in text["none"]
    # every line of the building without a schedule stands unchanged in it, GlobalIds and all
    assert set(text["none"].splitlines()) <= set(text["start"].splitlines())


def test_the_durations_follow_the_seed_and_the_start_only_moves_the_dates(one_storey) -> None:
    days = {name: [task.working_days for task in building.works] for name, (_, building) in one_storey.items()}
    other_seed = build_building_model(seed=7, storeys=1, schedule_start=START)[1].works
    assert days["start"] == days["later"] != [task.working_days for task in other_seed]
    (_, start), (_, later) = one_storey["start"], one_storey["later"]
    assert start.works[0].start == "2024-03-04" and later.works[0].start == "2025-06-02"
    assert start.schedule_start == START and one_storey["none"][1].works == ()


def test_the_start_is_read_as_the_at_option_reads_a_date() -> None:
    assert schedule_start_date("2024-03-04") == schedule_start_date("20240304") == datetime.date(2024, 3, 4)


@pytest.mark.parametrize("start", ["2024-02-30", "04/03/2024", "2024-3-4", "", 20240304])
def test_a_start_that_is_not_a_date_is_refused_before_anything_is_written(start: object, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^schedule start = .* is not a date; give the first day of works as "
                                          r"YYYY-MM-DD \(e.g. 2024-03-04\)$"):
        make_building(tmp_path / "b.ifc", seed=0, storeys=1, schedule_start=start)  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


def test_a_missing_trade_hands_its_place_to_what_it_follows_and_walls_carry_the_slab_without_columns() -> None:
    # two storeys, no ceilings or furniture anywhere (a site frame), the ground floor without columns
    present = {(trade, k) for k in (0, 1) for trade in STOREY_TRADES[:4]} | {("roof", 2)}
    before = _predecessors(present, top=1, wall_bearing={0})
    assert before["structure", 1] == [("structure", 0), ("exterior_walls", 0)]
    assert before["roof", 2] == [("structure", 1)]
    assert before["windows_doors", 1] == [("windows_doors", 0), ("interior_walls", 1)]
    everything = present | {("finishes", 0), ("furniture", 1)}
    after = _predecessors(everything, top=1, wall_bearing=set())
    assert after["finishes", 0] == [("windows_doors", 0), ("structure", 1)]
    # no finishes on floor 1: its furniture follows what they would have (and the roof over them)
    assert after["furniture", 1] == [("finishes", 0), ("windows_doors", 1), ("roof", 2)]

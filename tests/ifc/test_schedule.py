"""Work schedules read from IFC: tasks, their dates, the elements they build or take down."""

from __future__ import annotations

from pathlib import Path

import pytest

from bimscan.errors import InputFileError
from bimscan.ifc.schedule import read_schedule
from bimscan.types import BuildDates


def scheduled_room(path: Path, tiny_model) -> tuple[Path, dict[str, str]]:
    """A floor slab, a roof slab and three walls: wall A built by 2024-03-10 (a task output), wall B from 2024-04-01
    for five days (assigned to the task), wall C built with the storey (2024-01-15) and demolished
    2024-05-01; the slabs are built with the storey."""
    model = tiny_model()
    run, f = model.api.run, model.file
    slab = model.add_box("IfcSlab", origin=(-0.25, -0.25, -0.3), size=(8.5, 6.5, 0.3), name="slab")
    model.add_box("IfcSlab", origin=(-0.25, -0.25, 3.0), size=(8.5, 6.5, 0.3), name="roof")
    walls = {name: model.add_box("IfcWall", origin=origin, size=size, name=name) for name, origin, size in (
        ("A", (0, 0, 0), (8, 0.25, 3)), ("B", (0, 5.75, 0), (8, 0.25, 3)), ("C", (0, 0.25, 0), (0.25, 5.5, 3)))}
    schedule = run("sequence.add_work_schedule", f, name="build")

    def task(name: str, predefined: str, **times: str):
        t = run("sequence.add_task", f, work_schedule=schedule, name=name, predefined_type=predefined)
        run("sequence.edit_task_time", f, task_time=run("sequence.add_task_time", f, task=t), attributes=times)
        return t

    run("sequence.assign_product", f, relating_product=walls["A"],
        related_object=task("walls A", "CONSTRUCTION", ScheduleStart="2024-03-01", ScheduleFinish="2024-03-10"))
    run("sequence.assign_process", f, relating_process=task("walls B", "CONSTRUCTION", ScheduleStart="2024-04-01",
                                                            ScheduleFinish="2024-04-05"), related_object=walls["B"])
    run("sequence.assign_product", f, relating_product=model.storey,
        related_object=task("ground floor", "CONSTRUCTION", ScheduleStart="2024-01-01", ScheduleFinish="2024-01-15"))
    run("sequence.assign_product", f, relating_product=walls["C"],
        related_object=task("take down C", "DEMOLITION", ScheduleStart="2024-04-20", ScheduleFinish="2024-05-01"))
    return model.write(path), {name: wall.GlobalId for name, wall in walls.items()} | {"slab": slab.GlobalId}


def test_tasks_give_every_element_they_name_its_dates(tmp_path, tiny_model):
    path, gids = scheduled_room(tmp_path / "scheduled.ifc", tiny_model)
    schedule = read_schedule(path)
    assert schedule[gids["A"]] == BuildDates(built="2024-03-10")
    assert schedule[gids["B"]] == BuildDates(built="2024-04-05")
    # C is in the storey (built 2024-01-15, passed on) and has a demolition of its own
    assert schedule[gids["C"]].removed == "2024-05-01"
    assert schedule[gids["slab"]] == BuildDates(built="2024-01-15")  # through the storey that holds it


def test_a_model_without_tasks_has_no_schedule(box_room_ifc):
    assert read_schedule(box_room_ifc) == {}


def test_a_missing_file_is_reported(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        read_schedule(tmp_path / "nope.ifc")


def test_an_element_with_only_a_demolition_task_is_built_with_its_storey(tmp_path, tiny_model):
    path, gids = scheduled_room(tmp_path / "scheduled.ifc", tiny_model)
    # wall C's own task takes it down; it is built when the storey holding it is
    assert read_schedule(path)[gids["C"]] == BuildDates(built="2024-01-15", removed="2024-05-01")


def test_each_date_comes_from_the_element_else_from_its_nearest_dated_holder(tmp_path, tiny_model):
    model = tiny_model()
    run, f = model.api.run, model.file
    stair = run("root.create_entity", f, ifc_class="IfcStair", name="stair")
    run("spatial.assign_container", f, relating_structure=model.storey, products=[stair])
    flight = model.add_box("IfcStairFlight", origin=(1, 1, 0), size=(1, 3, 1.5), contain=False)
    rail = model.add_box("IfcRailing", origin=(2.1, 1, 0), size=(0.05, 3, 1.0), contain=False)
    run("aggregate.assign_object", f, relating_object=stair, products=[flight, rail])
    desk = model.add_box("IfcFurniture", origin=(3, 3, 0), size=(1.2, 0.6, 0.75), name="desk")
    schedule = run("sequence.add_work_schedule", f, name="works")

    def task(name: str, predefined: str, finish: str, product) -> None:
        t = run("sequence.add_task", f, work_schedule=schedule, name=name, predefined_type=predefined)
        run("sequence.edit_task_time", f, task_time=run("sequence.add_task_time", f, task=t),
            attributes={"ScheduleStart": finish, "ScheduleFinish": finish})
        run("sequence.assign_process", f, relating_process=t, related_object=product)

    task("storey", "CONSTRUCTION", "2024-01-15", model.storey)
    task("stair", "CONSTRUCTION", "2024-02-20", stair)
    task("take out the flight", "DEMOLITION", "2024-06-01", flight)
    task("clear the desk away", "REMOVAL", "2024-07-01", desk)
    task("strip the storey", "DISMANTLE", "2024-09-01", model.storey)
    dates = read_schedule(model.write(tmp_path / "works.ifc"))
    assert dates[stair.GlobalId] == BuildDates(built="2024-02-20", removed="2024-09-01")
    assert dates[flight.GlobalId] == BuildDates(built="2024-02-20", removed="2024-06-01")  # the stair is nearer
    assert dates[rail.GlobalId] == BuildDates(built="2024-02-20", removed="2024-09-01")
    assert dates[desk.GlobalId] == BuildDates(built="2024-01-15", removed="2024-07-01")

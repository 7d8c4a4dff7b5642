"""A construction work schedule for a generated building: tasks, their dates, what each one builds.

``add_work_schedule`` writes into a building's IFC4 model, with ``ifcopenshell.api.sequence``, a
PLANNED IfcWorkPlan "Construction" holding one PLANNED IfcWorkSchedule. Its root task nests one summary
task per storey, bottom up, each nesting that storey's trades in the order they follow one
another on site (``STOREY_TRADES``), and the roof:

- structure: the floor slab, the columns, the beams, the stair's flights and landing;
- exterior walls, then interior walls;
- windows and doors;
- finishes: ceiling coverings and railings (the stair's handrail, the guard at the stair void);
- furniture;
- the roof: the flat roof slab, or the attic under a gable roof (its floor, knee and gable walls,
  roof planes).

Every element with a body is the output (``IfcRelAssignsToProduct``, what ``read_schedule`` and
Bonsai's 4D read as "built by") of exactly one task; spaces and openings of none. Tasks are
sequenced finish to start (``IfcRelSequence``) as a line of balance, so the structure of upper
storeys goes up while lower storeys are walled and finished:

- a storey's structure follows the structure below it and, where the storey below has no
  columns, its exterior walls too (they carry the slab); the roof follows the top storey's
  structure the same way;
- every other trade follows the trade before it on its storey and the same trade on the storey
  below (one crew works its way up);
- finishes wait for the slab over the storey (ceilings hang from it, and it keeps the rain
  out): the next storey's structure, or the roof over the top storey.

A trade with nothing to build on a storey (no ceilings in a ``site`` frame) has no task; its
successors follow its predecessors. Durations are working days, Monday to Friday (an
IfcWorkCalendar controls the root task): ``fixed_days + days_per_100m2 * floor area / 100`` of
the trade (``TRADES``), times a factor in [0.8, 1.25) drawn from SHA-256 of the building's key and
the task, rounded, at least one. The same building gives the same durations whatever the start;
the start only moves them. Dates follow IfcOpenShell's own convention, so its ``cascade_schedule``
reproduces them: a task starts at 09:00 on the working day after its last predecessor finishes
(the start itself for the first, moved to a Monday from a weekend) and finishes at 17:00 on its
last working day.
"""

from __future__ import annotations

import datetime
import graphlib
import hashlib
import math
from collections.abc import Iterable
from dataclasses import dataclass

import ifcopenshell
import ifcopenshell.api as api
import ifcopenshell.api.control
import ifcopenshell.api.sequence
import ifcopenshell.util.date
import ifcopenshell.util.element
import ifcopenshell.util.sequence

from bimscan.errors import ConfigError
from bimscan.ifc.generate.floor_plan import BuildingPlan, storey_name

WORKING_WEEKDAYS = (1, 2, 3, 4, 5)  # IfcRecurrencePattern weekdays: Monday 1 .. Sunday 7
DURATION_FACTOR = (0.8, 1.25)  # a task's duration drawn between these multiples of its trade's rate
DURATION_TYPE = "WORKTIME"  # durations count working days of the calendar (IfcTaskDurationEnum)


@dataclass(frozen=True)
class Trade:
    """One kind of task. ``name`` heads its tasks' names; ``predefined_type`` is the
    IfcTaskTypeEnum; a task lasts ``fixed_days + days_per_100m2 * area / 100`` working days (before
    the seeded factor), ``area`` the building's floor area in square metres."""

    name: str
    predefined_type: str
    fixed_days: float
    days_per_100m2: float


# Rates of a small concrete-frame or masonry building with a few crews: a floor cycle (formwork,
# reinforcement, pour) of 1.5-2 weeks for 200-300 m2, a week or so for each fit-out trade.
TRADES: dict[str, Trade] = {
    "structure": Trade("Structure", "CONSTRUCTION", 4.0, 1.5),
    "exterior_walls": Trade("Exterior walls", "CONSTRUCTION", 2.0, 1.2),
    "interior_walls": Trade("Interior walls", "CONSTRUCTION", 2.0, 1.0),
    "windows_doors": Trade("Windows and doors", "INSTALLATION", 1.0, 0.8),
    "finishes": Trade("Finishes", "INSTALLATION", 2.0, 2.0),
    "furniture": Trade("Furniture", "INSTALLATION", 1.0, 0.4),
    "roof": Trade("Roof", "CONSTRUCTION", 3.0, 1.5),
}
STOREY_TRADES = ("structure", "exterior_walls", "interior_walls", "windows_doors", "finishes", "furniture")

# (IFC class, PredefinedType) of an element with a body -> the trade that builds it (below the
# roof; everything in the attic storey is the roof's)
ELEMENT_TRADES: dict[tuple[str, str], str] = {
    ("IfcSlab", "BASESLAB"): "structure",
    ("IfcSlab", "FLOOR"): "structure",
    ("IfcSlab", "LANDING"): "structure",
    ("IfcColumn", "COLUMN"): "structure",
    ("IfcBeam", "BEAM"): "structure",
    ("IfcStairFlight", "STRAIGHT"): "structure",
    ("IfcSlab", "ROOF"): "roof",
    ("IfcWall", "SOLIDWALL"): "exterior_walls",
    ("IfcWall", "PARTITIONING"): "interior_walls",
    ("IfcDoor", "DOOR"): "windows_doors",
    ("IfcWindow", "WINDOW"): "windows_doors",
    ("IfcCovering", "CEILING"): "finishes",
    ("IfcRailing", "HANDRAIL"): "finishes",
    ("IfcRailing", "GUARDRAIL"): "finishes",
    ("IfcFurniture", "TABLE"): "furniture",
    ("IfcFurniture", "FILECABINET"): "furniture",
    ("IfcFurniture", "SHELF"): "furniture",
}

TaskKey = tuple[str, int]  # (trade, storey index); the roof's storey is the one over the top storey


@dataclass(frozen=True)
class BuildTask:
    """One task of a generated building's work schedule that builds elements.

    identification: its WBS code in the file ("1.2.3": root task, storey, trade).
    trade: a key of ``TRADES``. storey: the storey it builds (0 the ground floor; the roof's is
        the number of storeys below the roof).
    start, finish: ISO dates (YYYY-MM-DD) of its first and last working day.
    working_days: its duration. elements: how many elements it builds.
    """

    identification: str
    name: str
    trade: str
    storey: int
    start: str
    finish: str
    working_days: int
    elements: int


def schedule_start_date(value: object) -> datetime.date:
    """The start of works from ``value``, an ISO date ``YYYY-MM-DD`` (or ISO 8601's basic
    ``YYYYMMDD``, as ``--at`` takes it); ConfigError otherwise."""
    text = value.strip() if isinstance(value, str) else None
    try:
        extended = text is not None and len(text) == 10 and text[4] == "-" and text[7] == "-"
        basic = text is not None and len(text) == 8 and text.isdigit()
        if not (extended or basic):
            raise ValueError(text)
        return datetime.date.fromisoformat(text)
    except ValueError as exc:
        raise ConfigError(
            f"schedule start = {value!r} is not a date; give the first day of works as YYYY-MM-DD (e.g. 2024-03-04)"
        ) from exc


def add_work_schedule(
    model: ifcopenshell.file, plan: BuildingPlan, *, start: datetime.date, key: str
) -> tuple[BuildTask, ...]:
    """Write the building's construction schedule (see the module docs) into ``model``, which holds
    the building authored from ``plan``; ``key`` (the building's style, seed and storeys) seeds
    the durations. Returns the tasks that build elements, in WBS order."""
    outputs = _elements_by_task(model, len(plan.storeys))
    area = _polygon_area(plan.outline_m)
    durations = {task: _working_days(TRADES[task[0]], area, key, task) for task in outputs}
    predecessors = _predecessors(set(outputs), top=len(plan.storeys) - 1,
                                 wall_bearing={k for k in range(len(plan.storeys)) if not plan.storey_columns(k)})
    at_midnight = datetime.datetime.combine(start, datetime.time())
    work_plan = api.sequence.add_work_plan(model, name="Construction", predefined_type="PLANNED")
    schedule = api.sequence.add_work_schedule(model, name="Construction schedule", predefined_type="PLANNED",
                                              work_plan=work_plan)
    root = api.sequence.add_task(model, work_schedule=schedule, name="Construction", identification="1")
    calendar = _add_working_week(model)
    api.control.assign_control(model, relating_control=calendar, related_objects=[root])
    tasks, summaries = _add_tasks(model, root, outputs, predecessors)
    _time_tasks(model, tasks, predecessors, durations, first_day=at_midnight, calendar=calendar)
    for summary, nested in [*((summaries[k], [t for t in tasks if t[1] == k and t[0] != "roof"]) for k in summaries),
                            (root, list(tasks))]:
        api.sequence.edit_task_time(model, task_time=api.sequence.add_task_time(model, task=summary), attributes={
            "DurationType": DURATION_TYPE,
            "ScheduleStart": min(_time(tasks[t], "ScheduleStart") for t in nested),
            "ScheduleFinish": max(_time(tasks[t], "ScheduleFinish") for t in nested)})
    # the api stamps the plan and the schedule with the clock; the file's bytes must not depend on it
    for control in (work_plan, schedule):
        control.CreationDate = ifcopenshell.util.date.datetime2ifc(at_midnight, "IfcDateTime")
        control.StartTime = root.TaskTime.ScheduleStart
        control.FinishTime = root.TaskTime.ScheduleFinish
    return tuple(
        BuildTask(identification=tasks[t].Identification, name=tasks[t].Name, trade=t[0], storey=t[1],
                  start=_time(tasks[t], "ScheduleStart").date().isoformat(),
                  finish=_time(tasks[t], "ScheduleFinish").date().isoformat(),
                  working_days=durations[t], elements=len(outputs[t]))
        for t in tasks
    )


def _add_working_week(model: ifcopenshell.file) -> ifcopenshell.entity_instance:
    """An IfcWorkCalendar whose working days are Monday to Friday, every week."""
    calendar = api.sequence.add_work_calendar(model, name="Monday to Friday")
    week = api.sequence.add_work_time(model, work_calendar=calendar, time_type="WorkingTimes")
    week.Name = "Working week"
    pattern = api.sequence.assign_recurrence_pattern(model, parent=week, recurrence_type="WEEKLY")
    api.sequence.edit_recurrence_pattern(model, recurrence_pattern=pattern,
                                         attributes={"WeekdayComponent": list(WORKING_WEEKDAYS)})
    return calendar


def _add_tasks(
    model: ifcopenshell.file, root: ifcopenshell.entity_instance,
    outputs: dict[TaskKey, list[ifcopenshell.entity_instance]], predecessors: dict[TaskKey, list[TaskKey]],
) -> tuple[dict[TaskKey, ifcopenshell.entity_instance], dict[int, ifcopenshell.entity_instance]]:
    """The tasks under ``root`` in WBS order (storeys bottom up, each one's trades in site order
    under a summary task per storey, the roof last), their outputs and their sequences. Returns
    the tasks and the storeys' summary tasks."""
    summaries: dict[int, ifcopenshell.entity_instance] = {}
    tasks: dict[TaskKey, ifcopenshell.entity_instance] = {}
    for task in sorted(outputs, key=_wbs_order):
        trade, storey = task
        if trade != "roof" and storey not in summaries:
            summaries[storey] = api.sequence.add_task(model, parent_task=root, name=storey_name(storey))
        tasks[task] = api.sequence.add_task(model, parent_task=root if trade == "roof" else summaries[storey],
                                            name=_task_name(task), predefined_type=TRADES[trade].predefined_type)
        for element in outputs[task]:
            api.sequence.assign_product(model, relating_product=element, related_object=tasks[task])
    for task in tasks:
        for before in predecessors[task]:
            api.sequence.assign_sequence(model, relating_process=tasks[before], related_process=tasks[task],
                                         sequence_type="FINISH_START")
    return tasks, summaries


def _time_tasks(
    model: ifcopenshell.file, tasks: dict[TaskKey, ifcopenshell.entity_instance],
    predecessors: dict[TaskKey, list[TaskKey]], durations: dict[TaskKey, int], *,
    first_day: datetime.datetime, calendar: ifcopenshell.entity_instance,
) -> None:
    """Date the tasks in dependency order, each once all it follows are: from the working day after
    the last of them finishes (``first_day`` for a task that follows none), for its duration."""
    for task in graphlib.TopologicalSorter({t: predecessors[t] for t in tasks}).static_order():
        begin = first_day if not predecessors[task] else ifcopenshell.util.sequence.offset_date(
            max(_time(tasks[p], "ScheduleFinish") for p in predecessors[task]), datetime.timedelta(days=1),
            DURATION_TYPE, calendar)
        api.sequence.edit_task_time(model, task_time=api.sequence.add_task_time(model, task=tasks[task]), attributes={
            "DurationType": DURATION_TYPE, "ScheduleStart": begin,
            "ScheduleDuration": datetime.timedelta(days=durations[task])})


def _elements_by_task(model: ifcopenshell.file, storeys: int) -> dict[TaskKey, list[ifcopenshell.entity_instance]]:
    """Every element with a body (no spaces, no openings) under the task that builds it, in file order."""
    levels = {s.id(): i for i, s in enumerate(sorted(model.by_type("IfcBuildingStorey"), key=lambda s: s.id()))}
    out: dict[TaskKey, list[ifcopenshell.entity_instance]] = {}
    for element in sorted(model.by_type("IfcElement"), key=lambda e: e.id()):
        if element.Representation is None or element.is_a("IfcFeatureElement"):
            continue
        holder = ifcopenshell.util.element.get_aggregate(element) or element  # a stair's parts: the stair's storey
        storey = levels[ifcopenshell.util.element.get_container(holder).id()]
        if storey == storeys:  # the attic under a gable roof
            trade = "roof"
        else:
            kind = (element.is_a(), str(ifcopenshell.util.element.get_predefined_type(element)))  # a door's: its type's
            trade = ELEMENT_TRADES.get(kind)
            if trade is None:
                raise ValueError(f"no trade builds a {kind[0]} {kind[1]}; add it to ELEMENT_TRADES")
        out.setdefault((trade, storeys if trade == "roof" else storey), []).append(element)
    return out


def _predecessors(present: set[TaskKey], *, top: int, wall_bearing: set[int]) -> dict[TaskKey, list[TaskKey]]:
    """Task -> the tasks it follows (finish to start), in WBS order, over the tasks ``present``:
    a missing task's place is taken by what it would have followed."""

    def planned(task: TaskKey) -> list[TaskKey]:
        trade, k = task
        if trade in ("structure", "roof"):
            below = k - 1
            if below < 0:
                return []
            return [("structure", below)] + ([("exterior_walls", below)] if below in wall_bearing else [])
        out = [(STOREY_TRADES[STOREY_TRADES.index(trade) - 1], k)] + ([(trade, k - 1)] if k > 0 else [])
        if trade == "finishes":
            out.append(("structure", k + 1) if k < top else ("roof", top + 1))
        return out

    def standing_in(task: TaskKey) -> set[TaskKey]:
        return {task} if task in present else {p for q in planned(task) for p in standing_in(q)}

    return {task: sorted({p for q in planned(task) for p in standing_in(q)}, key=_wbs_order)
            for task in sorted(present, key=_wbs_order)}


def _wbs_order(task: TaskKey) -> tuple[int, int]:
    trade, storey = task
    return (storey, STOREY_TRADES.index(trade)) if trade != "roof" else (storey, len(STOREY_TRADES))


def _task_name(task: TaskKey) -> str:
    trade, storey = task
    return TRADES[trade].name if trade == "roof" else f"{TRADES[trade].name}, {storey_name(storey).lower()}"


def _working_days(trade: Trade, area_m2: float, key: str, task: TaskKey) -> int:
    digest = hashlib.sha256(f"bimscan-schedule:{key}:{task[0]}:{task[1]}".encode()).digest()
    low, high = DURATION_FACTOR
    factor = low + (high - low) * int.from_bytes(digest[:8], "big") / 2.0**64
    return max(1, math.floor((trade.fixed_days + trade.days_per_100m2 * area_m2 / 100) * factor + 0.5))


def _polygon_area(points: Iterable[tuple[float, float]]) -> float:
    p = list(points)
    return abs(sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(p, p[1:] + p[:1]))) / 2


def _time(task: ifcopenshell.entity_instance, attribute: str) -> datetime.datetime:
    return ifcopenshell.util.date.ifc2datetime(getattr(task.TaskTime, attribute))

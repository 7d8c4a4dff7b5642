"""Work schedules: when each element of a model is built (or taken down), as plain data.

``read_schedule(path)`` reads the model's tasks (``IfcTask``) and the elements they act on:
their outputs (``IfcRelAssignsToProduct``, the usual link from a construction task to what it
builds) and the products assigned to them (``IfcRelAssignsToProcess``). A task's date is its
finish: actual, else scheduled, else early or late finish, else start plus duration, else the
latest finish of its nested tasks (IFC4/IFC4X3 ``IfcTaskTime``; IFC2X3 ``IfcScheduleTimeControl``
through ``IfcRelAssignsTasks``). Tasks of type DEMOLITION, DISMANTLE or REMOVAL take an element
away; every other task builds it. Dates given to a spatial element or an aggregate (a storey, a
stair) apply to the elements inside it that have none of their own, each kind apart: an element
with only a demolition task is built when its storey is, and taken down by its own task.
"""

from __future__ import annotations

import datetime
import logging
from pathlib import Path

from bimscan.errors import IfcError, InputFileError
from bimscan.types import BuildDates

REMOVING_TASKS = ("DEMOLITION", "DISMANTLE", "REMOVAL")
_FINISH_ATTRIBUTES = ("ActualFinish", "ScheduleFinish", "EarlyFinish", "LateFinish")
_START_ATTRIBUTES = ("ActualStart", "ScheduleStart", "EarlyStart", "LateStart")


def read_schedule(path: str | Path) -> dict[str, BuildDates]:
    """GlobalId -> BuildDates of every element a dated task names (empty when none does).

    Raises InputFileError for a missing file, IfcError when it cannot be parsed.
    """
    model = open_model(path)
    built: dict[int, datetime.date] = {}
    removed: dict[int, datetime.date] = {}
    for task in model.by_type("IfcTask"):
        finish = _finish_date(model, task)
        if finish is None:
            continue
        removing = str(getattr(task, "PredefinedType", None) or "").upper() in REMOVING_TASKS
        for product in _products_of(task):
            target = removed if removing else built
            current = target.get(product.id())
            # built when the last task building it is done; gone when the first taking it away is
            if current is None or (finish < current if removing else finish > current):
                target[product.id()] = finish
    dates = _passed_on(model, built, removed)
    out: dict[str, BuildDates] = {}
    for pid, (b, r) in dates.items():
        entity = model.by_id(pid)
        gid = getattr(entity, "GlobalId", None)
        if gid:
            out[str(gid)] = BuildDates(built=None if b is None else b.isoformat(),
                                       removed=None if r is None else r.isoformat())
    return dict(sorted(out.items()))


def _passed_on(model, built: dict[int, datetime.date],
               removed: dict[int, datetime.date]) -> dict[int, tuple[datetime.date | None, datetime.date | None]]:
    """Entity id -> (built, removed): each element's own dates, and for each kind it has no task of
    its own, the date of the nearest spatial element or aggregate holding it that has one (a wall
    with only a demolition task is built with its storey)."""
    dated = set(built) | set(removed)
    holdings = {pid: {e.id() for e in _contents(model.by_id(pid))} for pid in sorted(dated)}
    dates = {pid: [built.get(pid), removed.get(pid)] for pid in dated}
    # outer holders first (a holder holds more than anything it holds), so the nearest one wins
    for pid in sorted(holdings, key=lambda p: (-len(holdings[p]), p)):
        for inner in sorted(holdings[pid]):
            own = (built.get(inner), removed.get(inner))
            have = dates.setdefault(inner, [None, None])
            for kind in (0, 1):
                if own[kind] is None and dates[pid][kind] is not None:
                    have[kind] = dates[pid][kind]
    return {pid: (b, r) for pid, (b, r) in dates.items()}


def open_model(path: str | Path):  # -> ifcopenshell.file
    """The IFC file at ``path`` opened with IfcOpenShell (for reading its non-geometric data).

    Raises InputFileError for a missing file, IfcError when it cannot be parsed.
    """
    import ifcopenshell

    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such file; check the path")
    logging.getLogger("ifcopenshell").setLevel(logging.CRITICAL)
    try:
        return ifcopenshell.open(str(path))
    except Exception as exc:  # IfcOpenShell raises its own error types with parser messages
        raise IfcError(f"{path}: the IFC file could not be parsed ({exc}); check the export") from exc


def _products_of(task) -> list:  # -> list[entity_instance]
    products = [rel.RelatingProduct for rel in getattr(task, "HasAssignments", None) or ()
                if rel.is_a("IfcRelAssignsToProduct")]
    for rel in getattr(task, "OperatesOn", None) or ():
        products += [o for o in rel.RelatedObjects if o.is_a("IfcProduct")]
    return products


def _contents(entity) -> list:  # -> list[entity_instance]
    import ifcopenshell.util.element as util

    try:
        return [e for e in util.get_decomposition(entity) if e.id() != entity.id()]
    except Exception:  # entities that cannot be decomposed (not products) hold nothing
        return []


def _finish_date(model, task, depth: int = 0) -> datetime.date | None:
    """The task's finish (see the module docs); None when it has no date at all."""
    times = [task.TaskTime] if getattr(task, "TaskTime", None) is not None else []
    if model.schema == "IFC2X3":
        times += [rel.TimeForTask for rel in model.by_type("IfcRelAssignsTasks")
                  if task in (rel.RelatedObjects or ()) and rel.TimeForTask is not None]
    for time in times:
        for name in _FINISH_ATTRIBUTES:
            date = _date(getattr(time, name, None))
            if date is not None:
                return date
        duration = getattr(time, "ScheduleDuration", None)
        for name in _START_ATTRIBUTES:
            start = _date(getattr(time, name, None))
            if start is not None:
                return start + _days(duration)
    if depth < 16:
        import ifcopenshell.util.sequence as sequence

        nested = [d for d in (_finish_date(model, t, depth + 1) for t in sequence.get_nested_tasks(task)) if d]
        if nested:
            return max(nested)
    return None


def _date(value) -> datetime.date | None:
    if value is None:
        return None
    import ifcopenshell.util.date as dates

    try:
        parsed = dates.ifc2datetime(value)
    except Exception:  # an unreadable date counts as no date
        return None
    if isinstance(parsed, datetime.datetime):
        return parsed.date()
    return parsed if isinstance(parsed, datetime.date) else None


def _days(duration) -> datetime.timedelta:
    if not duration:
        return datetime.timedelta(0)
    import ifcopenshell.util.date as dates

    try:
        parsed = dates.ifc2datetime(duration) if not isinstance(duration, str) else dates.parse_duration(duration)
        return parsed if isinstance(parsed, datetime.timedelta) else datetime.timedelta(0)
    except Exception:  # an unreadable duration counts as none
        return datetime.timedelta(0)

"""Writing results into an IFC copy: a property set on each element, so that any BIM viewer shows
them in the element's properties and can filter or colour by them.

``write_property_sets(source, out, values, pset_name=...)`` copies ``source`` with, on every element
that ``values`` names by its STEP instance id (``#n``; bimscan's ``ComponentTable.step_id``, right
even where the file's GlobalId was ``$``), a property set ``pset_name`` holding that element's
values: str -> IfcLabel (IfcText over 255 characters), int -> IfcInteger, float -> IfcReal, bool ->
IfcBoolean; None leaves the property out. Numbers carry no IFC unit: name the unit in the property
(``DeviationMm``). A set of that name the element already has (an earlier run on an annotated copy)
is replaced whole, so no stale value survives and no set is doubled; one shared with other elements
is taken off this element only. Every other instance keeps its id and attributes (IfcOpenShell
writes the file out again, numbers in its own notation). The new sets' GlobalIds derive from the
set's name and the element, so the same input gives the same bytes.

``global_ids`` (STEP id -> GlobalId, e.g. ``dict(zip(table.step_id, table.global_id))`` of the
component table) gives the copy the GlobalIds bimscan used: an element whose GlobalId in the file
is unset (``$``, which bimscan's loader replaces by one derived from the file) or not a valid IFC
GlobalId gets the given one, so that the annotated copy and BCF topics written with the same
table name the same element. A valid GlobalId is never changed.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import atomic_output, mark_ifc_written_by
from bimscan.ifc.guid import derived_global_id, is_global_id
from bimscan.ifc.output import check_ifc_output
from bimscan.ifc.schedule import open_model

PropertyValue = str | float | int | bool | None
LABEL_MAX_CHARS = 255  # IFC's limit for an IfcLabel; longer text is an IfcText
RESERVED_PREFIXES = ("Pset_", "Qto_")  # buildingSMART's standard sets: a tool's own must not use them


@dataclass(frozen=True)
class Annotated:
    """What ``write_property_sets`` did. elements: elements that got the set. cleared: elements
    whose values were all None (they keep no set of that name). missing: the ids of ``values``
    or ``global_ids`` that name no IfcProduct of the file (absent, or another kind of entity),
    sorted. repaired_global_ids: elements whose unset or invalid GlobalId got the one of
    ``global_ids``."""

    elements: int
    cleared: int
    missing: tuple[int, ...]
    repaired_global_ids: int = 0


def check_annotated_output(out: str | Path, *, source: str | Path, overwrite: bool = False) -> Path:
    """``out`` as a Path, or an OutputError now for an annotated copy that cannot be written there
    (``bimscan.ifc.output.check_ifc_output``: not ``.ifc``, the model itself, a missing folder,
    something there without ``overwrite`` or that bimscan may not replace)."""
    return check_ifc_output(out, overwrite=overwrite, source=source, like="annotated.ifc",
                            role="the model being annotated")


def write_property_sets(source: str | Path, out: str | Path,
                        values: Mapping[int, Mapping[str, PropertyValue]], *, pset_name: str,
                        global_ids: Mapping[int, str] | None = None, overwrite: bool = False) -> Annotated:
    """Write the copy of ``source`` annotated with ``values`` (STEP id -> property name -> value)
    to ``out``, atomically, with the unset or invalid GlobalIds of the elements ``global_ids``
    names (STEP id -> GlobalId) set to the given ones. Raises InputFileError / IfcError for a
    missing or unreadable model, OutputError for an output that cannot be written, ValueError for
    a reserved or empty ``pset_name`` or property name, a NaN or infinite number, or a
    ``global_ids`` entry that is no IFC GlobalId, differs from the element's valid one (a table of
    another model) or is another instance's already."""
    if not pset_name or pset_name.startswith(RESERVED_PREFIXES):
        raise ValueError(f"property set name {pset_name!r} is empty or uses a buildingSMART prefix "
                         f"({', '.join(RESERVED_PREFIXES)}); name it like Bimscan_Progress")
    source = Path(source)
    out = check_annotated_output(out, source=source, overwrite=overwrite)
    model = open_model(source)
    mark_ifc_written_by(model, "annotate")
    elements = cleared = 0
    missing: set[int] = set()
    repaired = _set_global_ids(model, {int(k): v for k, v in (global_ids or {}).items()}, missing)
    by_id = {int(k): v for k, v in values.items()}  # NumPy ids (ComponentTable.step_id) as ints
    for step_id in sorted(by_id):
        element = _product(model, step_id)
        if element is None:
            missing.add(step_id)
            continue
        if _annotate(model, element, by_id[step_id], pset_name):
            elements += 1
        else:
            cleared += 1
    try:
        with atomic_output(out) as temp:
            model.write(str(temp))
    except OSError as exc:
        raise OutputError(f"could not write {out}: {exc.strerror or exc}; check the folder and free space") from exc
    return Annotated(elements=elements, cleared=cleared, missing=tuple(sorted(missing)),
                     repaired_global_ids=repaired)


def _set_global_ids(model, global_ids: dict[int, str], missing: set[int]) -> int:
    """Give each element of ``global_ids`` whose GlobalId is unset or invalid the given one; the
    number so set. Ids naming no product go to ``missing``. Every entry is checked before any is set."""
    repairs: dict[str, object] = {}  # GlobalId -> the element (an entity_instance) getting it
    for step_id in sorted(global_ids):
        gid = global_ids[step_id]
        element = _product(model, step_id)
        if element is None:
            missing.add(step_id)
            continue
        current = getattr(element, "GlobalId", None)
        if gid == current:
            continue  # the table holds the file's own (the loader keeps a string of another form as it is)
        if not is_global_id(gid):
            raise ValueError(f"global_ids gives #{step_id} {gid!r}, which is not an IFC GlobalId (22 characters "
                             "of IFC's base 64, the first 0-3); give the component table's global_id")
        if is_global_id(current):
            raise ValueError(f"global_ids gives #{step_id} the GlobalId {gid}, but the file has {current}: "
                             "the ids are of another model; load this model's component table")
        holder = repairs.get(gid)
        if holder is None:
            holder = _holder(model, gid)
        if holder is not None:
            raise ValueError(f"global_ids gives #{step_id} the GlobalId {gid}, which #{holder.id()} has already; "
                             "give each element its own")
        repairs[gid] = element
    for gid, element in repairs.items():
        element.GlobalId = gid
    return len(repairs)


def _holder(model, gid: str):  # -> entity_instance | None
    try:
        return model.by_guid(gid)
    except RuntimeError:  # IfcOpenShell's answer for a GlobalId the file does not hold
        return None


def _product(model, step_id: int):  # -> entity_instance | None
    try:
        entity = model.by_id(step_id)
    except RuntimeError:  # IfcOpenShell's answer for an id the file does not hold
        return None
    return entity if entity.is_a("IfcProduct") else None


def _annotate(model, element, properties: Mapping[str, PropertyValue], pset_name: str) -> bool:
    """Give ``element`` a fresh set ``pset_name`` of ``properties`` (any old one of that name taken
    off first); False when every value is None (no set: IFC allows no empty one)."""
    _take_off(model, element, pset_name)
    singles = []
    for name, value in properties.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"property name {name!r} of #{element.id()} must be a non-empty string")
        if value is not None:
            singles.append(model.create_entity("IfcPropertySingleValue", Name=name,
                                               NominalValue=_nominal_value(model, element, name, value)))
    if not singles:
        return False
    owner = _owner_history(model, element)
    key = (pset_name, getattr(element, "GlobalId", None) or "", element.id())
    pset = model.create_entity("IfcPropertySet", GlobalId=derived_global_id("bimscan-pset", *key),
                               OwnerHistory=owner, Name=pset_name, HasProperties=singles)
    model.create_entity("IfcRelDefinesByProperties", GlobalId=derived_global_id("bimscan-pset-rel", *key),
                        OwnerHistory=owner, RelatedObjects=[element], RelatingPropertyDefinition=pset)
    return True


def _nominal_value(model, element, name: str, value: PropertyValue):  # -> entity_instance (an IfcValue)
    if isinstance(value, bool | np.bool_):  # before int: a bool is an int to Python
        return model.create_entity("IfcBoolean", bool(value))
    if isinstance(value, numbers.Integral):
        return model.create_entity("IfcInteger", int(value))
    if isinstance(value, numbers.Real):
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"property {name!r} of #{element.id()} is {number}; IFC holds finite numbers only: "
                             "leave it out (None) instead")
        return model.create_entity("IfcReal", number)
    if isinstance(value, str):
        return model.create_entity("IfcLabel" if len(value) <= LABEL_MAX_CHARS else "IfcText", value)
    raise ValueError(f"property {name!r} of #{element.id()} is a {type(value).__name__} ({value!r}); "
                     "give a str, int, float, bool or None")


def _owner_history(model, element):  # -> entity_instance | None
    """The element's own owner history (else the project's) for the new entities in IFC2X3, which
    requires one on every rooted entity; none in IFC4 and later, where it is optional (a new one would
    carry the clock's time and break reproducible bytes)."""
    if model.schema != "IFC2X3":
        return None
    owner = getattr(element, "OwnerHistory", None)
    if owner is None:
        project = next(iter(model.by_type("IfcProject")), None)
        owner = getattr(project, "OwnerHistory", None)
    return owner


def _take_off(model, element, pset_name: str) -> None:
    """Remove ``element``'s property sets named ``pset_name`` (a set shared with other elements stays
    theirs: only this element leaves its relation)."""
    import ifcopenshell

    for rel in list(getattr(element, "IsDefinedBy", None) or ()):
        if not rel.is_a("IfcRelDefinesByProperties"):
            continue
        definition = rel.RelatingPropertyDefinition
        if not isinstance(definition, ifcopenshell.entity_instance) or not definition.is_a("IfcPropertySet") \
                or definition.Name != pset_name:
            continue
        others = [o for o in rel.RelatedObjects if o != element]
        if others:
            rel.RelatedObjects = others
            continue
        model.remove(rel)
        if model.get_total_inverses(definition) == 0:
            properties = list(definition.HasProperties or ())
            model.remove(definition)
            _remove_unused(model, properties)


def _remove_unused(model, properties: list) -> None:
    for prop in properties:
        if model.get_total_inverses(prop) != 0:
            continue  # another set holds it too
        nested = list(getattr(prop, "HasProperties", None) or ()) if prop.is_a("IfcComplexProperty") else []
        model.remove(prop)
        _remove_unused(model, nested)

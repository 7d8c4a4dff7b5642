"""Results written into an IFC copy as property sets: typed values every viewer reads, a rerun on
the annotated copy replaces the set, nothing else of the file changes."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import IfcError, OutputError
from bimscan.ifc.annotate import Annotated, write_property_sets

SET = "Bimscan_Progress"
SCHEMAS = ("IFC2X3", "IFC4", "IFC4X3")


def _model(tiny_model, path: Path, schema: str = "IFC4") -> tuple[Path, int, int]:
    """A wall and a door; returns the file and their STEP ids."""
    model = tiny_model(schema)
    wall = model.add_box("IfcWall", size=(4.0, 0.2, 3.0), name="wall")
    door = model.add_box("IfcDoor", origin=(1.0, 0.0, 0.0), size=(0.9, 0.2, 2.1), name="door")
    return model.write(path), wall.id(), door.id()


def _open(path: Path):
    import ifcopenshell

    return ifcopenshell.open(str(path))


def _psets(path: Path, step_id: int) -> dict:
    import ifcopenshell.util.element

    model = _open(path)  # held: an entity does not keep its file alive
    psets = ifcopenshell.util.element.get_psets(model.by_id(step_id))
    for values in psets.values():
        values.pop("id", None)
    return psets


def _statements(path: Path) -> list[str]:
    """Every instance of the file as IfcOpenShell writes it (the same style whoever wrote the file)."""
    return [str(entity) for entity in _open(path)]


@pytest.mark.parametrize("schema", SCHEMAS)
def test_each_schema_gets_the_set_with_typed_values_and_nothing_else_changes(tiny_model, tmp_path, schema):
    source, wall, door = _model(tiny_model, tmp_path / "model.ifc", schema)
    values = {wall: {"Status": "built out of tolerance", "DeviationMm": 23.5, "Points": 1200, "Visible": True,
                     "Note": "n" * 300, "Planned": None},
              door: {"Status": "not built"}}
    done = write_property_sets(source, tmp_path / "out.ifc", values, pset_name=SET)
    assert done == Annotated(elements=2, cleared=0, missing=())
    assert _psets(tmp_path / "out.ifc", wall) == {SET: {"Status": "built out of tolerance", "DeviationMm": 23.5,
                                                        "Points": 1200, "Visible": True, "Note": "n" * 300}}
    assert _psets(tmp_path / "out.ifc", door) == {SET: {"Status": "not built"}}
    model = _open(tmp_path / "out.ifc")
    types = {p.Name: p.NominalValue.is_a() for p in model.by_type("IfcPropertySingleValue")}
    assert types == {"Status": "IfcLabel", "DeviationMm": "IfcReal", "Points": "IfcInteger", "Visible": "IfcBoolean",
                     "Note": "IfcText"}
    # every statement of the model is still there, unchanged; the additions are the 6 values, 2 sets, 2 relations
    before, after = _statements(source), _statements(tmp_path / "out.ifc")
    assert set(before) <= set(after) and len(after) == len(before) + 6 + 2 + 2
    if schema == "IFC2X3":  # a rooted entity must carry an owner history there
        assert all(s.OwnerHistory is not None for s in model.by_type("IfcPropertySet"))


@pytest.mark.parametrize("schema", SCHEMAS)
def test_a_rerun_on_the_annotated_copy_replaces_the_set_without_doubling_it(tiny_model, tmp_path, schema):
    source, wall, door = _model(tiny_model, tmp_path / "model.ifc", schema)
    first = {wall: {"Status": "not built", "DeviationMm": 4.0}, door: {"Status": "built"}}
    write_property_sets(source, tmp_path / "once.ifc", first, pset_name=SET)
    second = {wall: {"Status": "built", "DeviationMm": None, "Points": 7}, door: {"Status": "built"}}
    write_property_sets(tmp_path / "once.ifc", tmp_path / "twice.ifc", second, pset_name=SET)
    assert _psets(tmp_path / "twice.ifc", wall) == {SET: {"Status": "built", "Points": 7}}  # no stale DeviationMm
    assert _psets(tmp_path / "twice.ifc", door) == {SET: {"Status": "built"}}
    model = _open(tmp_path / "twice.ifc")
    assert len(model.by_type("IfcPropertySet")) == 2 and len(model.by_type("IfcRelDefinesByProperties")) == 2
    assert len(model.by_type("IfcPropertySingleValue")) == 3  # the old values are gone, not orphaned
    assert set(_statements(source)) <= set(_statements(tmp_path / "twice.ifc"))


def test_the_same_input_gives_the_same_bytes(tiny_model, tmp_path):
    source, wall, _ = _model(tiny_model, tmp_path / "model.ifc")
    for name in ("a.ifc", "b.ifc"):
        write_property_sets(source, tmp_path / name, {wall: {"Status": "built", "DeviationMm": 1.25}}, pset_name=SET)
    assert (tmp_path / "a.ifc").read_bytes() == (tmp_path / "b.ifc").read_bytes()


def test_ids_not_in_the_file_or_not_products_are_skipped_and_reported(tiny_model, tmp_path):
    source, wall, _ = _model(tiny_model, tmp_path / "model.ifc")
    project = _open(source).by_type("IfcProject")[0].id()
    done = write_property_sets(source, tmp_path / "out.ifc", {wall: {"Status": "built"}, 999_999: {"Status": "x"},
                                                              -1: {"Status": "x"}, project: {"Status": "x"}},
                               pset_name=SET)
    assert done == Annotated(elements=1, cleared=0, missing=tuple(sorted((-1, project, 999_999))))
    assert _psets(tmp_path / "out.ifc", project) == {}


def test_an_element_whose_values_are_all_none_keeps_no_set_of_that_name(tiny_model, tmp_path):
    source, wall, door = _model(tiny_model, tmp_path / "model.ifc")
    write_property_sets(source, tmp_path / "once.ifc", {wall: {"Status": "built"}}, pset_name=SET)
    done = write_property_sets(tmp_path / "once.ifc", tmp_path / "twice.ifc", {wall: {"Status": None}}, pset_name=SET)
    assert done == Annotated(elements=0, cleared=1, missing=())
    assert _psets(tmp_path / "twice.ifc", wall) == {}
    assert not _open(tmp_path / "twice.ifc").by_type("IfcPropertySet")  # IFC allows no empty set


def test_a_set_shared_with_another_element_stays_that_elements_own(tiny_model, tmp_path):
    import ifcopenshell.api

    model = tiny_model("IFC4")
    walls = [model.add_box("IfcWall", origin=(4.0 * i, 0.0, 0.0), size=(4.0, 0.2, 3.0)) for i in range(2)]
    shared = ifcopenshell.api.run("pset.add_pset", model.file, product=walls[0], name=SET)
    ifcopenshell.api.run("pset.edit_pset", model.file, pset=shared, properties={"Status": "by hand"})
    ifcopenshell.api.run("pset.assign_pset", model.file, products=[walls[1]], pset=shared)
    source = model.write(tmp_path / "model.ifc")
    write_property_sets(source, tmp_path / "out.ifc", {walls[0].id(): {"Status": "built"}}, pset_name=SET)
    assert _psets(tmp_path / "out.ifc", walls[0].id()) == {SET: {"Status": "built"}}
    assert _psets(tmp_path / "out.ifc", walls[1].id()) == {SET: {"Status": "by hand"}}


def test_sets_of_other_names_are_kept(tiny_model, tmp_path):
    import ifcopenshell.api

    model = tiny_model("IFC4")
    wall = model.add_box("IfcWall", size=(4.0, 0.2, 3.0))
    common = ifcopenshell.api.run("pset.add_pset", model.file, product=wall, name="Pset_WallCommon")
    ifcopenshell.api.run("pset.edit_pset", model.file, pset=common, properties={"IsExternal": True})
    source = model.write(tmp_path / "model.ifc")
    write_property_sets(source, tmp_path / "out.ifc", {wall.id(): {"Status": "built"}}, pset_name=SET)
    assert _psets(tmp_path / "out.ifc", wall.id()) == {"Pset_WallCommon": {"IsExternal": True},
                                                       SET: {"Status": "built"}}


def test_a_damaged_model_that_opens_is_annotated_by_step_id(tiny_model, tmp_path):
    source, wall, _ = _model(tiny_model, tmp_path / "model.ifc")
    _unset_global_id(source, wall)  # bimscan names elements by STEP id, right also without a GlobalId
    done = write_property_sets(source, tmp_path / "out.ifc", {wall: {"Status": "built"}}, pset_name=SET)
    assert done.elements == 1 and _psets(tmp_path / "out.ifc", wall) == {SET: {"Status": "built"}}


def test_an_unreadable_model_is_one_line_and_writes_nothing(tmp_path):
    source = tmp_path / "model.ifc"
    source.write_bytes(b"ISO-10303-21;\nHEADER;\nthis is no IFC\n")
    with pytest.raises(IfcError) as raised:
        write_property_sets(source, tmp_path / "out.ifc", {1: {"Status": "built"}}, pset_name=SET)
    assert "\n" not in str(raised.value) and "model.ifc" in str(raised.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.ifc"]


def test_outputs_it_may_not_write_are_refused_before_any_work(tiny_model, tmp_path):
    source, wall, _ = _model(tiny_model, tmp_path / "model.ifc")
    values = {wall: {"Status": "built"}}
    with pytest.raises(OutputError, match="must end in .ifc"):
        write_property_sets(source, tmp_path / "out.txt", values, pset_name=SET)
    with pytest.raises(OutputError, match="is the model being annotated"):
        write_property_sets(source, source, values, pset_name=SET, overwrite=True)
    (tmp_path / "out.ifc").write_bytes(b"my notes")
    with pytest.raises(OutputError, match="already exists"):
        write_property_sets(source, tmp_path / "out.ifc", values, pset_name=SET)
    with pytest.raises(OutputError, match="not in the format of a .ifc file"):
        write_property_sets(source, tmp_path / "out.ifc", values, pset_name=SET, overwrite=True)
    assert (tmp_path / "out.ifc").read_bytes() == b"my notes"
    write_property_sets(source, tmp_path / "copy.ifc", values, pset_name=SET)
    write_property_sets(source, tmp_path / "copy.ifc", {wall: {"Status": "again"}}, pset_name=SET, overwrite=True)
    assert _psets(tmp_path / "copy.ifc", wall) == {SET: {"Status": "again"}}


@pytest.mark.parametrize(("pset_name", "properties", "words"), [
    ("Pset_Progress", {"Status": "built"}, "buildingSMART prefix"),
    ("", {"Status": "built"}, "empty"),
    (SET, {"DeviationMm": math.nan}, "finite numbers only"),
    (SET, {"": "built"}, "non-empty string"),
    (SET, {"When": object()}, "give a str, int, float, bool or None"),
])
def test_values_ifc_cannot_hold_are_refused_and_nothing_is_written(tiny_model, tmp_path, pset_name, properties, words):
    source, wall, _ = _model(tiny_model, tmp_path / "model.ifc")
    with pytest.raises(ValueError, match=words):
        write_property_sets(source, tmp_path / "out.ifc", {wall: properties}, pset_name=pset_name)
    assert not (tmp_path / "out.ifc").exists()


def test_every_element_of_a_real_model_is_annotated_and_its_statements_kept(shared_ifc, tmp_path):
    source = shared_ifc("duplex.ifc")  # an IFC2X3 export with owner histories on everything
    elements = [e.id() for e in _open(source).by_type("IfcElement")]
    ids = {np.int64(i): {"Status": "built"} for i in elements}  # as ComponentTable.step_id holds them
    done = write_property_sets(source, tmp_path / "out.ifc", ids, pset_name=SET)
    assert done == Annotated(elements=len(elements), cleared=0, missing=())
    model = _open(tmp_path / "out.ifc")
    ours = [s for s in model.by_type("IfcPropertySet") if s.Name == SET]
    assert len(ours) == len(elements) and all(s.OwnerHistory is not None for s in ours)
    assert set(_statements(source)) <= set(_statements(tmp_path / "out.ifc"))


def _unset_global_id(source: Path, step_id: int, value: str = "$") -> None:
    """The instance's GlobalId replaced by ``value`` (``$``: unset, as some exporters leave it)."""
    text = source.read_text()
    damaged = re.sub(rf"(?m)^(#{step_id}=IFC\w+\()'[^']*'", rf"\g<1>{value}", text)
    assert damaged != text
    source.write_text(damaged)


def test_a_wall_without_a_global_id_gets_the_one_bimscan_derived_and_no_valid_one_changes(tiny_model, tmp_path):
    from bimscan.ifc.load import load_ifc

    source, wall, door = _model(tiny_model, tmp_path / "model.ifc")
    door_gid = _open(source).by_id(door).GlobalId
    _unset_global_id(source, wall)
    table = load_ifc(source, use_cache=False, threads=1, progress=False).components
    global_ids = dict(zip(table.step_id, table.global_id, strict=True))  # as a BCF topic names them
    assert _open(source).by_id(wall).GlobalId is None and global_ids[wall] != door_gid
    done = write_property_sets(source, tmp_path / "out.ifc", {wall: {"Status": "not built"}}, pset_name=SET,
                               global_ids=global_ids)
    assert done == Annotated(elements=1, cleared=0, missing=(), repaired_global_ids=1)
    model = _open(tmp_path / "out.ifc")
    assert model.by_guid(global_ids[wall]).id() == wall and model.by_id(door).GlobalId == door_gid
    assert _psets(tmp_path / "out.ifc", wall) == {SET: {"Status": "not built"}}
    # apart from the wall's GlobalId, every statement is the source's: only the set was added
    before, after = _statements(source), _statements(tmp_path / "out.ifc")
    assert len(set(before) - set(after)) == 1 and len(after) == len(before) + 1 + 1 + 1


def test_a_global_id_that_is_no_ifc_guid_in_the_file_is_replaced_too(tiny_model, tmp_path):
    source, wall, door = _model(tiny_model, tmp_path / "model.ifc")
    _unset_global_id(source, wall, "'{6F9619FF-8B86-D011-B42D-00CF4FC964FF}'")  # a GUID, but not in IFC's form
    given = "0K9jUPgsH3aQPnkTHKpmSo"
    done = write_property_sets(source, tmp_path / "out.ifc", {}, pset_name=SET, global_ids={np.int64(wall): given})
    assert done == Annotated(elements=0, cleared=0, missing=(), repaired_global_ids=1)
    assert _open(tmp_path / "out.ifc").by_id(wall).GlobalId == given


def test_a_table_holding_the_files_own_global_ids_changes_none_even_one_of_another_form(tiny_model, tmp_path):
    source, wall, door = _model(tiny_model, tmp_path / "model.ifc")
    odd = "{6F9619FF-8B86-D011-B42D-00CF4FC964FF}"
    _unset_global_id(source, wall, f"'{odd}'")  # the loader keeps such a string: its table holds it as it is
    door_gid = _open(source).by_id(door).GlobalId
    done = write_property_sets(source, tmp_path / "out.ifc", {door: {"Status": "built"}}, pset_name=SET,
                               global_ids={wall: odd, door: door_gid})
    assert done == Annotated(elements=1, cleared=0, missing=(), repaired_global_ids=0)
    assert _open(tmp_path / "out.ifc").by_id(wall).GlobalId == odd


def test_ids_of_global_ids_not_in_the_file_are_reported_missing(tiny_model, tmp_path):
    source, wall, _ = _model(tiny_model, tmp_path / "model.ifc")
    _unset_global_id(source, wall)
    done = write_property_sets(source, tmp_path / "out.ifc", {wall: {"Status": "built"}}, pset_name=SET,
                               global_ids={wall: "0K9jUPgsH3aQPnkTHKpmSo", 999_999: "1K9jUPgsH3aQPnkTHKpmSo"})
    assert done == Annotated(elements=1, cleared=0, missing=(999_999,), repaired_global_ids=1)


@pytest.mark.parametrize(("entries", "words"), [
    ({"wall": "#12"}, "is not an IFC GlobalId"),
    ({"wall": "4K9jUPgsH3aQPnkTHKpmSo"}, "is not an IFC GlobalId"),  # the first character is 0-3
    ({"door": "0K9jUPgsH3aQPnkTHKpmSo"}, "the file has .*: the ids are of another model"),  # a valid one differs
    ({"wall": "door's"}, "which #\\d+ has already"),  # the door's, in the file
    ({"wall": "0K9jUPgsH3aQPnkTHKpmSo", "window": "0K9jUPgsH3aQPnkTHKpmSo"}, "which #\\d+ has already"),
])
def test_global_ids_that_would_name_elements_wrongly_are_refused_and_nothing_is_written(tiny_model, tmp_path,
                                                                                         entries, words):
    model = tiny_model("IFC4")
    elements = {name: model.add_box(ifc_class, origin=(2.0 * i, 0.0, 0.0), size=(1.0, 0.2, 2.0))
                for i, (name, ifc_class) in enumerate([("wall", "IfcWall"), ("door", "IfcDoor"),
                                                       ("window", "IfcWindow")])}
    source = model.write(tmp_path / "model.ifc")
    door_gid = elements["door"].GlobalId
    for name in ("wall", "window"):
        _unset_global_id(source, elements[name].id())
    global_ids = {elements[name].id(): door_gid if gid == "door's" else gid for name, gid in entries.items()}
    with pytest.raises(ValueError, match=words) as raised:
        write_property_sets(source, tmp_path / "out.ifc", {}, pset_name=SET, global_ids=global_ids)
    assert "\n" not in str(raised.value)
    assert not (tmp_path / "out.ifc").exists()

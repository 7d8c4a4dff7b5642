"""Real-world and hostile IFC input: what viewers accept loads, nothing is lost silently, nothing
crashes or hangs the command (issue 13)."""

from __future__ import annotations

import json
import os
import re
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.errors import ConfigError, IfcError, InputFileError
from bimscan.ifc.load import load_ifc
from bimscan.ifc.step import derived_global_id
from bimscan.ifc.summary import report_document, report_lines
from bimscan.ifc.watchdog import shutdown_workers


def _two_walls_and_a_door(tiny_model, path: Path, *, schema: str = "IFC4", spread_m: float = 0.0) -> Path:
    model = tiny_model(schema)
    model.add_box("IfcWall", size=(4.0, 0.2, 3.0), name="south")
    model.add_box("IfcWall", origin=(0.0, 4.0 + spread_m, 0.0), size=(4.0, 0.2, 3.0), name="north")
    model.add_box("IfcDoor", origin=(1.0, 0.0, 0.0), size=(0.9, 0.2, 2.1), name="door")
    return model.write(path)


def _line(data: bytes, pattern: bytes) -> re.Match[bytes]:
    match = re.search(rb"(?m)^#[0-9]+=" + pattern + rb".*$", data)
    assert match is not None, pattern
    return match


def _edit(path: Path, pattern: bytes, new: bytes | None = None, *, out: Path | None = None) -> Path:
    """Replace the first line matching ``#n=<pattern>`` by ``new`` (None: delete it)."""
    data = path.read_bytes()
    match = _line(data, pattern)
    target = out or path.with_name(path.stem + "-edited.ifc")
    target.write_bytes(data[:match.start()] + (new if new is not None else b"") + data[match.end():])
    return target


def _attributes(line: bytes) -> list[bytes]:
    """Top-level attributes of a simple one-line statement without nested lists (test files only)."""
    inner = line[line.index(b"(") + 1:line.rindex(b")")]
    return re.findall(rb"'[^']*'|\([^()]*\)|[^,]+", inner)


def _with_attributes(line: bytes, values: dict[int, bytes]) -> bytes:
    head = line[:line.index(b"(") + 1]
    attributes = _attributes(line)
    for index, value in values.items():
        attributes[index] = value
    return head + b",".join(attributes) + b");"


def test_stars_in_a_door_are_read_as_unset_and_the_door_loads(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    door = _line(path.read_bytes(), b"IFCDOOR\\(").group()
    star = _edit(path, b"IFCDOOR\\(", _with_attributes(door, {2: b"*", 3: b"*", 4: b"*", 7: b"*"}))
    model = load_ifc(star)
    assert sorted(model.components.ifc_class.tolist()) == ["IfcDoor", "IfcWall", "IfcWall"]
    assert model.failed == ()
    (repair,) = model.report.repairs
    assert (repair.kind, dict(repair.per_class)) == ("derived-attribute", {"IfcDoor": 1})
    assert repair.lines == (star.read_bytes().count(b"\n", 0, star.read_bytes().index(b"=IFCDOOR(")) + 1,)
    assert any("repaired 1 '*'" in line for line in report_lines(model))


def test_a_dollar_global_id_loads_with_a_stable_made_up_one_instead_of_hanging(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    wall = _line(path.read_bytes(), b"IFCWALL\\(").group()
    step_id = int(wall[1:wall.index(b"=")])
    dollar = _edit(path, b"IFCWALL\\(", _with_attributes(wall, {0: b"$"}))
    start = time.perf_counter()
    first = load_ifc(dollar, use_cache=False, element_timeout_s=20)
    second = load_ifc(dollar, use_cache=False, element_timeout_s=20)
    assert time.perf_counter() - start < 30  # without the repair IfcOpenShell's iterator waits forever
    assert first.failed == () and len(first.components) == 3
    made_up = derived_global_id(first.file_sha256, step_id)
    assert made_up in first.components.global_id.tolist()
    assert first.components.global_id.tolist() == second.components.global_id.tolist()
    assert [r.kind for r in first.report.repairs] == ["globalid"]


def test_a_byte_order_mark_is_accepted(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    bom = tmp_path / "bom.ifc"
    bom.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    plain, marked = load_ifc(path), load_ifc(bom)
    assert marked.components.global_id.tolist() == plain.components.global_id.tolist()
    assert np.array_equal(marked.mesh.vertices, plain.mesh.vertices)


def test_an_element_of_an_unknown_entity_is_reported_not_dropped(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    door = _line(path.read_bytes(), b"IFCDOOR\\(").group()
    unknown = _edit(path, b"IFCDOOR\\(", door.replace(b"=IFCDOOR(", b"=IFCDOORX("))
    model = load_ifc(unknown)
    (failure,) = model.failed
    assert (failure.cause, failure.ifc_class) == ("unknown-entity", "IFCDOORX") and failure.line > 0
    assert model.report.declared_elements == 3
    assert "unknown-entity" in {i.kind for i in model.report.issues}


def test_a_dangling_body_reference_is_reported_with_its_line(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    door = _line(path.read_bytes(), b"IFCDOOR\\(").group()
    dangling = _edit(path, b"IFCDOOR\\(", _with_attributes(door, {6: b"#987654"}))
    model = load_ifc(dangling)
    (failure,) = model.failed
    assert failure.cause == "dangling-reference" and "#987654" in failure.reason
    issue = next(i for i in model.report.issues if i.kind == "dangling-reference")
    assert failure.line in issue.lines
    with pytest.raises(IfcError, match="strict"):
        load_ifc(dangling, strict=True)


def test_a_file_cut_midway_with_a_valid_end_appended_reports_every_loss(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    data = path.read_bytes()
    door = _line(data, b"IFCDOOR\\(")
    cut = door.start() + (door.end() - door.start()) // 2  # in the middle of the door's line
    truncated = tmp_path / "cut.ifc"
    truncated.write_bytes(data[:cut] + b"\nENDSEC;\nEND-ISO-10303-21;\n")
    model = load_ifc(truncated)
    assert {i.kind for i in model.report.issues} >= {"syntax"}
    lost = {f.step_id for f in model.failed}
    loaded = set(model.components.step_id.tolist())
    declared = {int(m.group(1)) for m in re.finditer(rb"(?m)^#([0-9]+)=IFC(?:WALL|DOOR)\(", data[:cut])}
    assert declared <= loaded | lost  # every element the cut file still declares: loaded or reported
    assert any(f.cause == "syntax" and f.ifc_class == "IfcDoor" for f in model.failed)
    with pytest.raises(IfcError, match="strict"):
        load_ifc(truncated, strict=True)


def test_a_self_referencing_placement_is_refused_in_one_line(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    data = path.read_bytes()
    match = _line(data, b"IFCLOCALPLACEMENT\\(")
    step_id = match.group()[:match.group().index(b"=")]
    cycle = _edit(path, b"IFCLOCALPLACEMENT\\(", step_id + b"=" + _with_attributes(
        match.group()[match.group().index(b"=") + 1:], {0: step_id}))
    with pytest.raises(IfcError, match=rf"placement {step_id.decode()} \(line \d+\) is placed relative to itself") as error:
        load_ifc(cycle)
    assert "\n" not in str(error.value)


def test_a_representation_map_cycle_that_crashes_the_kernel_costs_one_element(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", size=(4.0, 0.2, 3.0))
    column = model.add_box("IfcColumn", origin=(2.0, 2.0, 0.0), size=(0.3, 0.3, 3.0))
    f = model.file
    # A mapped item whose map's representation holds the mapped item itself: OpenCascade recurses
    # until the stack overflows (SIGSEGV in the geometry kernel).
    representation = column.Representation.Representations[0]
    origin = f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None)
    mapping = f.createIfcRepresentationMap(origin, representation)
    operator = f.createIfcCartesianTransformationOperator3D(None, None, f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None,
                                                            None)
    representation.Items = [f.createIfcMappedItem(mapping, operator)]
    representation.RepresentationType = "MappedRepresentation"
    path = model.write(tmp_path / "cycle.ifc")
    loaded = load_ifc(path, use_cache=False)
    assert loaded.components.ifc_class.tolist() == ["IfcWall"]
    (failure,) = loaded.failed
    assert (failure.ifc_class, failure.step_id, failure.cause) == ("IfcColumn", column.id(), "crash")
    assert "SIGSEGV" in failure.reason or "crashed" in failure.reason
    assert failure.line > 0


@pytest.fixture
def fault(monkeypatch: pytest.MonkeyPatch):
    """Set BIMSCAN_IFC_TEST_FAULT for fresh workers (idle ones started without it are ended)."""
    def set_fault(value: str) -> None:
        monkeypatch.setenv("BIMSCAN_IFC_TEST_FAULT", value)
        shutdown_workers()

    yield set_fault
    monkeypatch.delenv("BIMSCAN_IFC_TEST_FAULT", raising=False)
    shutdown_workers()


@pytest.mark.parametrize("kind, cause", [("hang", "timeout"), ("crash", "crash")])
def test_an_element_that_hangs_or_crashes_the_kernel_is_reported_and_the_rest_loads(kind, cause, fault, tiny_model,
                                                                                   tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    door = _line(path.read_bytes(), b"IFCDOOR\\(").group()
    fault(f"{kind}:{int(door[1:door.index(b'=')])}")
    start = time.perf_counter()
    model = load_ifc(path, use_cache=False, element_timeout_s=2.0)
    assert time.perf_counter() - start < 30
    assert sorted(model.components.ifc_class.tolist()) == ["IfcWall", "IfcWall"]
    (failure,) = model.failed
    assert (failure.ifc_class, failure.cause) == ("IfcDoor", cause)
    assert ("no progress in 2 s" in failure.reason) == (kind == "hang")


def test_a_model_without_a_length_unit_in_millimetres_is_read_as_millimetres_with_a_warning(tiny_model, tmp_path):
    # Authored in millimetres (numbers 1000x metres), then its unit assignment lost.
    model = tiny_model("IFC4")
    model.add_box("IfcWall", size=(4000.0, 200.0, 3000.0))
    model.add_box("IfcColumn", origin=(6000.0, 3000.0, 0.0), size=(300.0, 300.0, 3000.0))
    path = _edit(model.write(tmp_path / "mm.ifc"), b"IFCUNITASSIGNMENT\\(", None)
    loaded = load_ifc(path)
    lo, hi = loaded.mesh.bounds()
    np.testing.assert_allclose(hi - lo, [6.3, 3.3, 3.0], atol=1e-6)
    assert (loaded.report.length_unit_m, loaded.report.length_unit_source) == (0.001, "assumed")
    (issue,) = [i for i in loaded.report.issues if i.kind == "length-unit"]
    assert "millimetres" in issue.example and "km" in issue.example
    with pytest.raises(IfcError, match="length unit|strict"):
        load_ifc(path, strict=True)
    override = load_ifc(path, length_unit="m")  # the user knows better
    lo, hi = override.mesh.bounds()
    np.testing.assert_allclose(hi - lo, [6300.0, 3300.0, 3000.0], atol=1e-3)
    assert override.report.length_unit_source == "override"
    assert {i.kind for i in override.report.issues} == {"dangling-reference"}  # the deleted assignment


def test_a_small_model_without_a_length_unit_is_read_as_metres_with_a_warning(tiny_model, tmp_path):
    path = _edit(_two_walls_and_a_door(tiny_model, tmp_path / "m.ifc"), b"IFCUNITASSIGNMENT\\(", None)
    loaded = load_ifc(path)
    lo, hi = loaded.mesh.bounds()
    np.testing.assert_allclose(hi - lo, [4.0, 4.2, 3.0], atol=1e-6)
    assert loaded.report.length_unit_source == "assumed"
    assert any("read as metres" in i.example for i in loaded.report.issues)


def test_a_dangling_unit_assignment_is_a_dangling_reference_and_an_assumed_unit(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "m.ifc")
    project = _line(path.read_bytes(), b"IFCPROJECT\\(").group()
    dangling = _edit(path, b"IFCPROJECT\\(", _with_attributes(project, {8: b"#987654"}))
    loaded = load_ifc(dangling)
    assert {"dangling-reference", "length-unit"} <= {i.kind for i in loaded.report.issues}
    assert len(loaded.components) == 3


def test_a_length_unit_override_scales_a_model_with_its_own_unit(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "m.ifc")
    feet = load_ifc(path, length_unit="ft")
    metres = load_ifc(path)
    np.testing.assert_allclose(feet.mesh.vertices, metres.mesh.vertices * 0.3048, atol=1e-9)
    assert feet.report.length_unit_m == 0.3048
    with pytest.raises(ConfigError, match="furlong"):
        load_ifc(path, length_unit="furlong")


def test_the_load_report_survives_the_geometry_cache(tiny_model, tmp_path, private_cache):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    door = _line(path.read_bytes(), b"IFCDOOR\\(").group()
    broken = _edit(path, b"IFCDOOR\\(", _with_attributes(door, {2: b"*", 6: b"#987654"}))
    fresh = load_ifc(broken, use_cache=False)
    load_ifc(broken)
    cached = load_ifc(broken)
    assert list((private_cache / "ifc").glob("*.json"))
    assert cached.report == fresh.report and cached.failed == fresh.failed
    assert np.array_equal(cached.components.step_id, fresh.components.step_id)
    with pytest.raises(IfcError, match="strict"):  # strict judges the cached report too
        load_ifc(broken, strict=True)


def test_a_damaged_ifczip_is_one_error_naming_the_archive(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    archive = tmp_path / "house.ifczip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.write(path, "house.ifc")
    data = bytearray(archive.read_bytes())
    start = data.index(b"house.ifc") + len(b"house.ifc")
    for offset in range(start + 40, start + 80):  # inside the deflated stream
        data[offset] ^= 0x5A
    damaged = tmp_path / "damaged.ifczip"
    damaged.write_bytes(bytes(data))
    with pytest.raises(IfcError, match=r"damaged\.ifczip: the \.ifczip archive is damaged") as error:
        load_ifc(damaged)
    assert "\n" not in str(error.value)


def test_errors_about_the_ifc_inside_an_ifczip_name_the_archive(tiny_model, tmp_path):
    path = _two_walls_and_a_door(tiny_model, tmp_path / "house.ifc")
    archive = tmp_path / "cut.ifczip"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("house.ifc", path.read_bytes()[:2000])  # no END-ISO-10303-21
    with pytest.raises(IfcError, match=r"cut\.ifczip: the IFC file is truncated") as error:
        load_ifc(archive)
    assert "bimscan-ifczip" not in str(error.value)


def test_a_fifo_and_a_symlink_loop_are_called_what_they_are(tmp_path):
    fifo = tmp_path / "pipe.ifc"
    os.mkfifo(fifo)
    with pytest.raises(InputFileError, match="FIFO"):
        load_ifc(fifo)
    loop = tmp_path / "loop.ifc"
    loop.symlink_to(loop)
    with pytest.raises(InputFileError, match="symbolic link loop"):
        load_ifc(loop)


def _room(tiny_model, path: Path) -> Path:
    """A closed room 4 x 3 x 2.6 m (inside): a plan's smallest house."""
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(-0.2, -0.2, -0.2), size=(4.4, 3.4, 0.2), predefined_type="FLOOR", name="floor")
    model.add_box("IfcSlab", origin=(-0.2, -0.2, 2.6), size=(4.4, 3.4, 0.2), predefined_type="ROOF", name="roof")
    for name, origin, size in (("south", (-0.2, -0.2, 0.0), (4.4, 0.2, 2.6)),
                               ("north", (-0.2, 3.0, 0.0), (4.4, 0.2, 2.6)),
                               ("west", (-0.2, 0.0, 0.0), (0.2, 3.0, 2.6)), ("east", (4.0, 0.0, 0.0), (0.2, 3.0, 2.6))):
        model.add_box("IfcWall", origin=origin, size=size, name=name)
    return model.write(path)


def _without_a_shape(path: Path) -> Path:
    """The first wall's body emptied: a shape representation without items."""
    data = path.read_bytes()
    shape = _attributes(_line(data, b"IFCWALL\\(").group())[6]
    definition = re.search(rb"(?m)^" + re.escape(shape) + rb"=IFCPRODUCTDEFINITIONSHAPE\(.*\((#[0-9]+)\)\);$", data)
    assert definition is not None
    body = re.search(rb"(?m)^" + re.escape(definition.group(1)) + rb"=IFCSHAPEREPRESENTATION\(.*$", data)
    emptied = re.sub(rb",\(#[0-9]+\)\);$", b",());", body.group())
    target = path.with_name("shapeless.ifc")
    target.write_bytes(data[:body.start()] + emptied + data[body.end():])
    return target


def _cut_in_a_wall(path: Path) -> Path:
    """The file cut in the middle of its last wall's line, a valid end appended."""
    data = path.read_bytes()
    *_, wall = re.finditer(rb"(?m)^#[0-9]+=IFCWALL\(.*$", data)
    target = path.with_name("cut.ifc")
    target.write_bytes(data[:(wall.start() + wall.end()) // 2] + b"\nENDSEC;\nEND-ISO-10303-21;\n")
    return target


DAMAGES = {
    "no unit assignment": lambda path: _edit(path, b"IFCUNITASSIGNMENT\\(", None),
    "a $ GlobalId": lambda path: _edit(path, b"IFCWALL\\(", _with_attributes(_line(path.read_bytes(),
                                                                                   b"IFCWALL\\(").group(), {0: b"$"})),
    "a wall without a shape": _without_a_shape,
    "an unknown entity": lambda path: _edit(
        path, b"IFCWALL\\(", _line(path.read_bytes(), b"IFCWALL\\(").group().replace(b"=IFCWALL(", b"=IFCWALLX(")),
    "a file cut short": _cut_in_a_wall,
}
PLAN_FAST = ["--preset", "exp1", "--head-speed", "60", "--density", "100", "--classes", "Wall&Column",
             "--ladder", "none"]


@pytest.mark.parametrize("damage", DAMAGES)
def test_a_plan_of_a_damaged_model_says_what_loading_repaired_and_names_elements_as_a_scan_does(
        damage, tiny_model, tmp_path, capsys):
    path = DAMAGES[damage](_room(tiny_model, tmp_path / "room.ifc"))
    loaded = load_ifc(path)
    said = report_lines(loaded)
    assert said, damage
    out = tmp_path / "plan"
    assert main(["plan", str(path), str(out), *PLAN_FAST]) == 0
    err = capsys.readouterr().err
    for line in said:  # the warnings 'bimscan info' and 'bimscan scan' give
        assert f"warning: {line}" in err
    summary = json.loads((out / "plan.json").read_text("utf-8"))
    assert summary["load_report"] == json.loads(json.dumps(report_document(loaded.report)))
    assert len(summary["failed"]) == len(loaded.failed)
    # every element coverage.csv names is the file's GlobalId, or the one the repair warning says it was given
    in_file = {m.decode() for m in re.findall(rb"=IFC[A-Z]+\('([0-9A-Za-z_$]{22})'", path.read_bytes())}
    named = set(re.findall(r"\) ([0-9A-Za-z_$]{22})", err))
    rows = (out / "coverage.csv").read_text("utf-8").splitlines()[1:]
    assert rows and {row.split(",")[0] for row in rows} <= in_file | named
    if damage == "a $ GlobalId":
        assert len(named) == 1 and named <= {row.split(",")[0] for row in rows}

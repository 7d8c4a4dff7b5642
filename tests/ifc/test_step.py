"""Reading IFC-SPF text statement by statement: problems tied to lines, repairs, blanking."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bimscan.ifc import step

HEAD = b"ISO-10303-21;\nHEADER;\nFILE_SCHEMA(('IFC4'));\nENDSEC;\nDATA;\n"
TAIL = b"ENDSEC;\nEND-ISO-10303-21;\n"


def spf(*lines: str) -> bytes:
    return HEAD + "".join(line + "\n" for line in lines).encode() + TAIL


def test_a_valid_file_has_no_problems_and_no_edits(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", size=(4.0, 0.2, 3.0))
    data = model.write(tmp_path / "tiny.ifc").read_bytes()
    scan = step.scan_step(data, "IFC4")
    assert scan.problems == [] and scan.edits == []
    assert len(scan.statements) == step.count_statements(data)
    assert step.apply_edits(data, scan.edits, file_sha256="x") == data


def test_statements_record_attribute_kinds_spans_and_references():
    data = spf("#1=IFCCARTESIANPOINT((0.,1.5,-2.E-3));",
               "#2=IFCMEASUREWITHUNIT(IFCPLANEANGLEMEASURE(0.01745),#3);",
               "#3=IFCSIUNIT(*,.PLANEANGLEUNIT.,$,.RADIAN.);",
               "#4=IFCPERSON($,'O''Brien; Jr. (x)',$,$,$,$,$,$); /* a comment; with ( */")
    scan = step.scan_step(data, "IFC4", keep_attributes=True)
    assert scan.problems == []
    unit = scan.statements[3]
    assert unit.entity == "IFCSIUNIT" and unit.kinds == ["*", "enum", "$", "enum"]
    assert [data[a:b] for a, b in unit.attributes] == [b"*", b".PLANEANGLEUNIT.", b"$", b".RADIAN."]
    assert list(scan.statements[2].reference_pairs()) == [(1, 3)] and scan.statements[2].kinds == ["", "ref"]
    assert scan.statements[4].kinds[1] == "str"


@pytest.mark.parametrize("bad, words", [
    ("#2=IFCDIRECTION((1.,0.,0.);", "brackets"),
    ("#2=IFCPERSON($,'unclosed,$,$,$,$,$,$);", "string is not closed"),
    ("#2=IFCDIRECTION((1.,0.,0.))", "cut short"),
    ("#2=IFCDIRECTION((1.,0.,0.)) junk;", "after the closing bracket"),
    ("#2=IFCDIRECTION((1.,\x01,0.));", "unexpected character"),
    ("#2=IFCDIRECTION((1.,,0.));", "unexpected ','"),
    ("garbage without an id;", "does not start with '#n='"),
])
def test_a_statement_that_does_not_parse_is_reported_at_its_line_and_blanked(bad, words):
    data = spf("#1=IFCCARTESIANPOINT((0.,0.,0.));", bad, "#3=IFCCARTESIANPOINT((1.,0.,0.));")
    scan = step.scan_step(data, "IFC4")
    syntax = [p for p in scan.problems if p.kind == "syntax"]
    assert len(syntax) == 1 and syntax[0].line == 7 and words in syntax[0].message
    assert set(scan.statements) == {1, 3}  # the neighbours survive
    repaired = step.apply_edits(data, scan.edits, file_sha256="x")
    assert repaired.count(b"\n") == data.count(b"\n")  # lines stay where they were
    assert b"#1=IFCCARTESIANPOINT" in repaired and b"#3=IFCCARTESIANPOINT" in repaired
    assert step.scan_step(repaired, "IFC4").problems == []


def test_unknown_entities_duplicates_dangling_references_and_attribute_counts_are_found():
    data = spf("#1=IFCCARTESIANPOINTX((0.,0.,0.));",
               "#2=IFCAXIS2PLACEMENT3D(#1,$,$);",
               "#3=IFCLOCALPLACEMENT($,#99);",
               "#2=IFCDIRECTION((1.,0.,0.));",
               "#4=IFCDIRECTION((1.,0.,0.),5);")
    scan = step.scan_step(data, "IFC4")
    kinds = {(p.kind, p.line, p.step_id) for p in scan.problems}
    assert ("unknown-entity", 6, 1) in kinds
    assert ("dangling-reference", 7, 2) in kinds  # #2 refers to the unknown #1
    assert ("dangling-reference", 8, 3) in kinds  # #3 refers to #99, never defined
    assert ("duplicate-id", 9, 2) in kinds
    assert ("attribute-count", 10, 4) in kinds
    assert scan.statements[2].entity == "IFCAXIS2PLACEMENT3D"  # the first definition wins


def test_stars_in_attributes_the_schema_does_not_derive_are_repaired_and_derived_ones_kept():
    data = spf("#1=IFCSIUNIT(*,.LENGTHUNIT.,$,.METRE.);",
               "#2=IFCDOOR('0Tif_$wI1FwAwq$OJt24I8',$,*,*,*,$,$,*,2.2,1.,.DOOR.,.SINGLE_SWING_LEFT.,$);")
    edits = step.quick_repairs(data, "IFC4")
    assert {e.kind for e in edits} == {"derived-attribute"} and {e.step_id for e in edits} == {2}
    repaired = step.apply_edits(data, edits, file_sha256="x")
    assert b"#1=IFCSIUNIT(*,.LENGTHUNIT.,$,.METRE.);" in repaired
    assert b"#2=IFCDOOR('0Tif_$wI1FwAwq$OJt24I8',$,$,$,$,$,$,$,2.2" in repaired
    per_class, lines = step.summarize_repairs(edits)["derived-attribute"]
    assert per_class == {"IfcDoor": 1} and lines == [7]  # one door repaired, on line 7


@pytest.mark.parametrize("value", ["$", "*", "5", ".T.", "IFCLABEL('x')"])
def test_a_global_id_that_is_not_a_string_gets_a_stable_made_up_one(value):
    data = spf(f"#1=IFCWALL({value},$,'w',$,$,$,$,$,$);", "#2=IFCPERSON($,$,$,$,$,$,$,$);")
    scan = step.scan_step(data, "IFC4")
    assert [e.kind for e in scan.edits] == ["globalid"]
    first = step.apply_edits(data, scan.edits, file_sha256="aa")
    again = step.apply_edits(data, scan.edits, file_sha256="aa")
    other = step.apply_edits(data, scan.edits, file_sha256="bb")
    guid = step.derived_global_id("aa", 1)
    assert first == again and f"#1=IFCWALL('{guid}',".encode() in first and len(guid) == 22
    assert first != other
    assert b"#2=IFCPERSON($," in first  # not an IfcRoot: its leading '$' is fine


def test_a_byte_order_mark_is_dropped():
    data = step.BOM + spf("#1=IFCCARTESIANPOINT((0.,0.,0.));")
    assert step.apply_edits(data, [], file_sha256="x") == data[3:]


def test_quick_repairs_find_a_star_in_a_statement_spread_over_lines():
    data = spf("#1=IFCDOOR('0Tif_$wI1FwAwq$OJt24I8',$,", "  *,$,$,$,$,$,2.2,1.,.DOOR.,$,$);")
    edits = step.quick_repairs(data, "IFC4")
    assert [(e.kind, e.line) for e in edits] == [("derived-attribute", 6)]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from([
    "#{i}=IFCCARTESIANPOINT((0.,1.,2.));", "#{i}=IFCDIRECTION((1.,0.,0.);", "#{i}=IFCPERSON($,'a;b',$,$,$,$,$,$);",
    "#{i}=IFCPERSON($,'open,$,$,$,$,$,$);", "junk ((", "#{i}=IFCFOO(1,2);", "", "#{i}=IFCLOCALPLACEMENT(#1,#7777);",
]), min_size=1, max_size=12))
def test_repaired_text_keeps_its_lines_and_reads_without_syntax_problems(templates):
    data = spf(*(t.format(i=i + 1) for i, t in enumerate(templates)))
    scan = step.scan_step(data, "IFC4")
    repaired = step.apply_edits(data, scan.edits, file_sha256="x")
    assert repaired.count(b"\n") == data.count(b"\n")
    rescan = step.scan_step(repaired, "IFC4")
    assert not [p for p in rescan.problems if p.kind == "syntax"]
    assert set(rescan.statements) == set(scan.statements)

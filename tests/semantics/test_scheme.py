"""Label schemes: the default scheme, subclass inheritance, PredefinedType and parent rules, bad schemes."""

from __future__ import annotations


import numpy as np
import pytest

from bimscan.errors import SchemeError
from bimscan.pipeline import load_scene
from bimscan.ifc.schema import class_ancestry, known_classes
from bimscan.semantics import check_rule_classes, load_scheme, map_labels, parse_scheme
from bimscan.site import site_class_names
from bimscan.types import ComponentTable


def table(rows: list[tuple[str, str, str]], schema: str = "IFC4") -> ComponentTable:
    """A component table of (ifc_class, predefined_type, parent_class) rows, ancestry from the schema."""
    classes = sorted({r[0] for r in rows} | {r[2] for r in rows if r[2]})
    n = len(rows)
    return ComponentTable(
        global_id=np.array([f"g{i}" for i in range(n)]), ifc_class=np.array([r[0] for r in rows]),
        predefined_type=np.array([r[1] for r in rows]), name=np.array([""] * n), storey=np.array([""] * n),
        parent_class=np.array([r[2] for r in rows]), label=np.zeros(n, np.uint8),
        class_ancestry={c: class_ancestry(schema, c) for c in classes},
    )


def names_of(components: ComponentTable, scheme) -> list[str]:
    return [scheme.names[int(i)] for i in map_labels(components, scheme).labels]


def test_default_scheme_has_the_papers_five_classes_in_order():
    scheme = load_scheme()
    assert [(c.id, c.name) for c in scheme.classes] == [
        (0, "Wall&Column"), (1, "Beam"), (2, "Covering"), (3, "Slab"), (4, "Others")]
    assert scheme.default_label == "Others"
    check_rule_classes(scheme, known_classes() | site_class_names())


@pytest.mark.parametrize("schema, ifc_class, expected", [
    ("IFC2X3", "IfcWallStandardCase", "Wall&Column"),
    ("IFC4", "IfcWallElementedCase", "Wall&Column"),
    ("IFC4", "IfcColumnStandardCase", "Wall&Column"),
    ("IFC4", "IfcBeamStandardCase", "Beam"),
    ("IFC4", "IfcSlabElementedCase", "Slab"),
    ("IFC4X3_ADD2", "IfcWall", "Wall&Column"),
    ("IFC4", "IfcFurniture", "Others"),
    ("IFC4", "IfcCovering", "Covering"),
])
def test_subclasses_map_through_their_parents(schema, ifc_class, expected):
    assert names_of(table([(ifc_class, "", "")], schema), load_scheme()) == [expected]


def test_predefined_type_and_parent_rules_beat_plain_class_rules():
    rows = [
        ("IfcMember", "RAFTER", ""),       # beam-like member
        ("IfcMember", "POST", ""),         # column-like member
        ("IfcMember", "MULLION", ""),      # falls through
        ("IfcPlate", "", "IfcCurtainWall"),
        ("IfcMember", "", "IfcWindow"),
        ("IfcSlab", "LANDING", "IfcStair"),
        ("IfcMember", "STRINGER", "IfcStair"),
    ]
    assert names_of(table(rows), load_scheme()) == [
        "Beam", "Wall&Column", "Others", "Wall&Column", "Others", "Slab", "Others"]


def test_classes_that_fall_through_to_the_default_are_reported():
    mapping = map_labels(table([("IfcFooting", "", ""), ("IfcFooting", "", ""), ("IfcWall", "", ""), ("IfcDoor", "", "")]), load_scheme())
    assert mapping.unmapped == {"IfcFooting": 2}


def test_a_user_scheme_with_other_classes_and_ids(tmp_path):
    path = tmp_path / "structural.toml"
    path.write_text("""
name = "structural"
default = "non-structural"
[[classes]]
id = 10
name = "structural"
color = "#ff0000"
[[classes]]
id = 20
name = "non-structural"
color = "#00ff00"
[[rules]]
ifc_class = "IfcBuildingElement"
label = "structural"
[[rules]]
ifc_class = "IfcDoor"
label = "non-structural"
""")
    scheme = load_scheme(path)
    components = table([("IfcWallStandardCase", "", ""), ("IfcDoor", "", ""), ("IfcFurniture", "", "")])
    assert map_labels(components, scheme).labels.tolist() == [10, 20, 20]


def test_a_user_scheme_applies_to_a_real_model(shared_ifc, tmp_path):
    path = tmp_path / "two.toml"
    path.write_text('default = "rest"\n[[classes]]\nid = 0\nname = "column"\ncolor = "#000000"\n'
                    '[[classes]]\nid = 1\nname = "rest"\ncolor = "#ffffff"\n'
                    '[[rules]]\nifc_class = "IfcColumn"\nlabel = "column"\n')
    scene = load_scene(shared_ifc("example.ifc"), scheme=path)
    assert int((scene.components.label == 0).sum()) == 42


BAD_SCHEMES = [
    ('default = "a"\n', "at least one"),
    ('default = "b"\n[[classes]]\nid = 0\nname = "a"\n', "'default' must name one of the classes"),
    ('default = "a"\n[[classes]]\nid = 300\nname = "a"\n', "0..254"),
    ('default = "a"\n[[classes]]\nid = 255\nname = "a"\n', "255 means unlabelled"),
    ('default = "a"\n[[classes]]\nid = 0\nname = "a"\n[[classes]]\nid = 0\nname = "b"\n', "appear more than once"),
    ('default = "a"\n[[classes]]\nid = 0\nname = "a"\ncolor = "red"\n', "#rrggbb"),
    ('default = "a"\n[[classes]]\nid = 0\nname = "a"\n[[rules]]\nifc_class = "IfcWall"\nlabel = "zzz"\n', "not one of the classes"),
    ('default = "a"\ncolour = 1\n[[classes]]\nid = 0\nname = "a"\n', "unknown key"),
    ('default = "a"\n[[classes]]\nid = 0\nname = "a"\n[[rules]]\nifc_class = "Ifc Wall"\nlabel = "a"\n', "class name like"),
    ('default = [[[\n', "not valid TOML"),
]


@pytest.mark.parametrize("text, message", BAD_SCHEMES)
def test_invalid_schemes_give_clear_errors(text, message, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    from bimscan.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        load_scheme(path)


def test_a_misspelt_ifc_class_in_a_rule_is_reported():
    scheme = parse_scheme({"default": "a", "classes": [{"id": 0, "name": "a"}],
                           "rules": [{"ifc_class": "IfcWal", "label": "a"}]}, where="test")
    with pytest.raises(SchemeError, match="unknown IFC class 'IfcWal'"):
        check_rule_classes(scheme, known_classes())


def test_an_unknown_scheme_name_is_reported():
    with pytest.raises(SchemeError, match="neither a file nor a built-in scheme"):
        load_scheme("no-such-scheme")

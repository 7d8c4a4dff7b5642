"""``bimscan furnish``: the site written into an IFC copy that other tools (and bimscan) read back."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.files import ifc_authors
from bimscan.pipeline import build_site, load_scene
from bimscan.survey.recipe import ScanRecipe
from bimscan.site import ClutterSettings, SiteModel, StageSettings


@pytest.mark.parametrize("schema", ["IFC4", "IFC2X3"])
def test_the_furnished_copy_holds_the_same_objects_as_the_dressed_scene(tmp_path, tiny_model, schema, capsys):
    from tests.conftest import build_box_room

    source = build_box_room(tmp_path / "room.ifc", schema=schema)
    out = tmp_path / "furnished.ifc"
    assert main(["furnish", str(source), str(out), "--clutter", "0.3", "--clutter-kinds", "office,people",
                 "--seed", "4"]) == 0
    assert "placed" in capsys.readouterr().out
    site = SiteModel(clutter=ClutterSettings(density=0.3, kinds=("office", "people")))
    dressed = build_site(load_scene(source, use_cache=False), ScanRecipe(seed=4, site=site))
    copy = load_scene(out, use_cache=False)
    added = np.char.find(dressed.components.ifc_class.astype(str), ".") > 0
    expected = {"IfcFurniture" if schema == "IFC4" else "IfcFurnishingElement": 0, "IfcBuildingElementProxy": 0}
    for cls in dressed.components.ifc_class[added]:
        expected["IfcBuildingElementProxy" if cls.startswith("Person") else next(iter(expected))] += 1
    for cls, count in expected.items():
        assert int((copy.components.ifc_class == cls).sum()) == count
    # every object keeps its GlobalId, and its triangles land where the scanned scene has them
    for c in np.flatnonzero(added):
        gid = dressed.components.global_id[c]
        (k,) = np.flatnonzero(copy.components.global_id == gid)
        a, b = _corners(dressed, c), _corners(copy, k)
        assert a.shape == b.shape and np.allclose(a, b, atol=1e-5)
        assert (copy.mesh.face_component == k).sum() == (dressed.mesh.face_component == c).sum()
        assert copy.components.label[k] == next(c.id for c in copy.scheme.classes if c.name == "Others")


@pytest.mark.parametrize("schema", ["IFC4", "IFC2X3"])
def test_fixtures_are_written_as_the_schema_s_light_fixtures_and_air_terminals(tmp_path, schema):
    from tests.conftest import build_box_room

    source = build_box_room(tmp_path / "room.ifc", schema=schema)
    for seed in range(4):  # a room goes without fixtures now and then (each kind in a share of the rooms)
        out = tmp_path / f"lit-{seed}.ifc"
        assert main(["furnish", str(source), str(out), "--clutter", "0.1", "--clutter-kinds", "ceiling",
                     "--seed", str(seed)]) == 0
        copy = load_scene(out, use_cache=False)
        added = np.isin(copy.components.ifc_class, ["IfcLightFixture", "IfcAirTerminal", "IfcFlowTerminal"])
        if added.any():
            break
    assert added.any()
    classes = set(copy.components.ifc_class[added].tolist())
    assert classes <= ({"IfcLightFixture", "IfcAirTerminal"} if schema == "IFC4" else {"IfcFlowTerminal"})
    others = next(c.id for c in copy.scheme.classes if c.name == "Others")
    assert (copy.components.label[added] == others).all()
    assert not set(copy.unmapped_classes) & classes  # named by the scheme, not left to its default


def _corners(scene, component: int) -> np.ndarray:
    """The distinct corners of a component's triangles, sorted (to 0.01 mm)."""
    faces = scene.mesh.faces[scene.mesh.face_component == component]
    return np.unique(np.round(scene.mesh.vertices[faces].reshape(-1, 3), 5), axis=0)


def test_a_stage_removes_elements_from_the_copy(tmp_path, capsys):
    from bimscan.ifc.generate import make_building

    source = make_building(tmp_path / "office.ifc", seed=3, storeys=1).path
    out = tmp_path / "structure.ifc"
    assert main(["furnish", str(source), str(out), "--stage", "structure"]) == 0
    classes = set(load_scene(out, use_cache=False).components.ifc_class.tolist())
    assert classes and not classes & {"IfcDoor", "IfcWindow", "IfcCovering", "IfcFurniture"}
    dressed = build_site(load_scene(source), ScanRecipe(site=SiteModel(stage=StageSettings(name="structure"))))
    assert classes == set(dressed.components.ifc_class.tolist())


def test_furnish_without_a_site_is_a_usage_error(box_room_ifc, tmp_path, capsys):
    assert main(["furnish", str(box_room_ifc), str(tmp_path / "same.ifc")]) != 0
    assert "nothing to furnish" in capsys.readouterr().err
    assert not (tmp_path / "same.ifc").exists()


def test_furnish_never_replaces_the_model_or_a_model_bimscan_did_not_write(tmp_path, capsys):
    from tests.conftest import build_box_room

    theirs = build_box_room(tmp_path / "theirs.ifc", schema="IFC4")  # a model another tool wrote
    assert not any(a.startswith("bimscan") for a in ifc_authors(theirs) or ())
    before = theirs.read_bytes()
    # the model itself, even with --overwrite
    assert main(["furnish", str(theirs), str(theirs), "--clutter", "0.3", "--overwrite"]) == 1
    assert "theirs.ifc is the model being furnished; write the copy to another file" in capsys.readouterr().err
    # another of the user's models: kept without --overwrite, refused with it
    from bimscan.ifc.generate import make_building

    source = make_building(tmp_path / "office.ifc", seed=3, storeys=1).path
    assert main(["furnish", str(source), str(theirs), "--clutter", "0.3"]) == 1
    assert "theirs.ifc already exists; pass --overwrite" in capsys.readouterr().err
    assert main(["furnish", str(source), str(theirs), "--clutter", "0.3", "--overwrite"]) == 1
    assert "theirs.ifc is an IFC model bimscan did not write" in capsys.readouterr().err
    assert theirs.read_bytes() == before
    # its own copy: replaced when asked, its header naming bimscan after the model's authors
    out = tmp_path / "furnished.ifc"
    assert main(["furnish", str(source), str(out), "--clutter", "0.3"]) == 0
    assert main(["furnish", str(source), str(out), "--clutter", "0.6", "--overwrite"]) == 0
    assert ifc_authors(out) == ("bimscan make-building", "bimscan furnish")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["furnished.ifc", "office.ifc", "theirs.ifc"]

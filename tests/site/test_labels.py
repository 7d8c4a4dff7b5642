"""Labels of what dressing adds: spc5 maps it to Others; a user scheme can give it classes of its own."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.errors import SchemeError
from bimscan.pipeline import load_label_scheme
from bimscan.semantics import label_model
from bimscan.site import ClutterSettings, SiteModel, dress_scene

OWN_SCHEME = """\
name = "with-chairs"
default = "rest"
[[classes]]
id = 0
name = "structure"
color = "#4e79a7"
[[classes]]
id = 1
name = "chair"
color = "#f28e2b"
[[classes]]
id = 2
name = "temporary"
color = "#59a14f"
[[classes]]
id = 3
name = "furniture"
color = "#9c755f"
[[classes]]
id = 4
name = "rest"
color = "#e15759"
[[rules]]
ifc_class = "IfcWall"
label = "structure"
[[rules]]
ifc_class = "Clutter.Chair"
label = "chair"
[[rules]]
ifc_class = "Temporary"
label = "temporary"
[[rules]]
ifc_class = "IfcFurnishingElement"
label = "furniture"
"""


def added(dressed, original) -> np.ndarray:
    return np.arange(len(original.components), len(dressed.components))


def test_spc5_labels_everything_added_as_others(office_scene, dressed_office):
    new = added(dressed_office, office_scene)
    others = next(c.id for c in dressed_office.scheme.classes if c.name == "Others")
    assert (dressed_office.components.label[new] == others).all()
    assert dressed_office.unmapped_classes == office_scene.unmapped_classes  # no class fell through
    # the model's own components keep their labels
    assert (dressed_office.components.label[:len(office_scene.components)] == office_scene.components.label).all()


def test_a_user_scheme_gives_site_classes_classes_of_their_own(tmp_path, office_scene):
    path = tmp_path / "own.toml"
    path.write_text(OWN_SCHEME)
    scheme = load_label_scheme(path)
    from bimscan.types import ParsedModel

    relabelled = label_model(ParsedModel(
        source=office_scene.source, file_sha256=office_scene.file_sha256, schema=office_scene.schema,
        mesh=office_scene.mesh, components=office_scene.components, storeys=office_scene.storeys,
        spaces=office_scene.spaces, failed=office_scene.failed), scheme)
    site = SiteModel(clutter=ClutterSettings(density=0.3, kinds=("office", "ladder", "person")))
    dressed = dress_scene(relabelled, site, seed=4)
    names = scheme.names
    labels = {cls: {names[int(label)] for label, c in zip(dressed.components.label, dressed.components.ifc_class)
                    if c == cls} for cls in set(dressed.components.ifc_class.tolist())}
    assert labels["Clutter.Chair"] == {"chair"}  # its own rule
    assert labels["Temporary.Ladder"] == {"temporary"}  # the group's rule
    assert labels["Clutter.Desk"] == {"furniture"}  # through the IFC class it would be in a model
    assert labels["IfcFurniture"] == {"furniture"}
    assert labels["Person.Walking"] | labels.get("Person.Standing", set()) == {"rest"}  # the default
    assert "Person.Walking" in dressed.unmapped_classes or "Person.Standing" in dressed.unmapped_classes


def test_a_misspelt_site_class_in_a_scheme_is_refused(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text(OWN_SCHEME.replace('"Clutter.Chair"', '"Clutter.Chiar"'))
    with pytest.raises(SchemeError, match="Clutter.Chiar"):
        load_label_scheme(path)


def test_site_components_appear_in_the_obj_export(tmp_path, office_scene, dressed_office):
    import csv

    from bimscan.io import export_obj

    result = export_obj(dressed_office, tmp_path / "obj")
    rows = list(csv.DictReader(result.index_csv.open()))
    assert len(rows) == len(dressed_office.components)
    site_rows = [r for r in rows if r["ifc_class"].startswith(("Clutter.", "Fixture.", "Person."))]
    assert len(site_rows) == len(added(dressed_office, office_scene))
    assert {r["label_name"] for r in site_rows} == {"Others"} and all(int(r["n_triangles"]) > 0 for r in site_rows)
    assert all((tmp_path / "obj" / r["obj_file"]).is_file() for r in site_rows)


def test_export_obj_takes_the_site_flags(box_room_ifc, tmp_path):
    import csv

    from bimscan.cli.main import main

    assert main(["export-obj", str(box_room_ifc), str(tmp_path / "obj"), "--clutter", "0.3", "--seed", "2"]) == 0
    rows = list(csv.DictReader((tmp_path / "obj" / "index.csv").open()))
    assert sum(r["ifc_class"].startswith(("Clutter.", "Fixture.", "Person.", "Temporary.")) for r in rows) >= 5


def test_added_components_get_valid_ifc_global_ids():
    import ifcopenshell.guid

    from bimscan.ifc.guid import derived_global_id

    ids = {derived_global_id("x", k) for k in range(200)}
    assert len(ids) == 200
    for gid in list(ids)[:20]:
        assert len(gid) == 22 and ifcopenshell.guid.compress(ifcopenshell.guid.expand(gid)) == gid
    assert derived_global_id("x", 1) == derived_global_id("x", 1)

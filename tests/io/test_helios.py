"""HELIOS++ scene export: one objloader part per component file, classes in the materials."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from bimscan.io import export_obj
from bimscan.io.helios import helios_scene_xml
from bimscan.types import BimScene, SceneMesh


@pytest.fixture
def scene(scheme, components) -> BimScene:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3]], dtype=np.int32)
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=np.array([0, 2, 2], dtype=np.int32))
    return BimScene(source="house & garden.ifc", file_sha256="", schema="IFC2X3", mesh=mesh, components=components,
                    scheme=scheme, storeys=(), spaces=(), failed=(), unmapped_classes={})


def test_the_scene_xml_has_one_objloader_part_per_component_file(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj", helios=True)
    root = ET.parse(export.helios_scene).getroot()
    assert root.tag == "document"
    (scene_element,) = root.findall("scene")
    assert scene_element.get("name") == "house & garden.ifc"
    parts = scene_element.findall("part")
    assert sorted(int(p.get("id")) for p in parts) == sorted(export.component_files) == [0, 2]
    for part in parts:
        (loader,) = part.findall("filter")
        assert loader.get("type") == "objloader"
        params = {p.get("key"): p.get("value") for p in loader.findall("param")}
        assert params["up"] == "z"
        # relative to the export folder (HELIOS++ --assets <folder>)
        assert (export.out_dir / params["filepath"]).resolve() == export.component_files[int(part.get("id"))].resolve()


def test_materials_carry_the_class_ids_as_helios_classification(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj")
    text = export.materials.read_text()
    for cls in scene.scheme.classes:
        assert f"newmtl class_{cls.id}\n" in text and f"helios_classification {cls.id}\n" in text
    assert "mtllib ../classes.mtl" in export.component_files[0].read_text()


def test_scene_xml_escapes_names_and_paths():
    document = helios_scene_xml([(3, 'odd "dir"/c3.obj')], scene_id="s", name="<model>")
    scene = ET.fromstring(document).find("scene")
    assert scene.get("name") == "<model>"
    assert scene.find("part/filter/param").get("value") == 'odd "dir"/c3.obj'

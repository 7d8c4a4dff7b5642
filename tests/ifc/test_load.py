"""Loading IFC (load_ifc, labelled by load_scene) on the real sample models, on tiny models built in code, and on bad input."""

from __future__ import annotations

import time
from collections import Counter

import numpy as np
import pytest

from bimscan.errors import EmptyModelError, IfcError, InputFileError
from bimscan.pipeline import load_scene

# Per-class counts of the shared models, from shared/data/ATTRIBUTION.md (elements with a body;
# decomposed IfcRoof/IfcWindow/IfcStair aggregates without their own body are not components).
# duplex.ifc also holds 7 IfcFooting that the attribution table leaves out.
SHARED_EXPECTED = {
    "duplex.ifc": ("IFC2X3", {
        "IfcWall": 1, "IfcWallStandardCase": 56, "IfcBeam": 8, "IfcSlab": 21, "IfcCovering": 13,
        "IfcDoor": 14, "IfcWindow": 24, "IfcStairFlight": 2, "IfcFurnishingElement": 61,
        "IfcRailing": 4, "IfcMember": 4, "IfcFooting": 7,
    }, 21),
    "AC20-FZK-Haus.ifc": ("IFC4", {
        "IfcWallStandardCase": 13, "IfcBeam": 4, "IfcSlab": 4, "IfcDoor": 5, "IfcWindow": 11,
        "IfcStair": 1, "IfcRailing": 2, "IfcMember": 42,
    }, 7),
    "IfcOpenHouse_IFC4.ifc": ("IFC4", {
        "IfcWallStandardCase": 4, "IfcSlab": 2, "IfcDoor": 1, "IfcStairFlight": 1, "IfcMember": 20,
        "IfcPlate": 5, "IfcFooting": 1,
    }, 0),
    "example.ifc": ("IFC2X3", {
        "IfcWallStandardCase": 17, "IfcColumn": 42, "IfcBeam": 43, "IfcSlab": 9, "IfcBuildingElementProxy": 4,
    }, 1),
}

# The default scheme's class for each of those IFC classes (the parent decides for window parts
# and stair stringers, which all land in Others as well).
SPC5 = {
    "IfcWall": "Wall&Column", "IfcWallStandardCase": "Wall&Column", "IfcColumn": "Wall&Column",
    "IfcBeam": "Beam", "IfcCovering": "Covering", "IfcSlab": "Slab",
}


@pytest.mark.parametrize("name", sorted(SHARED_EXPECTED))
def test_shared_models_load_with_the_expected_counts_per_class_and_label(name, shared_ifc):
    schema, per_class, spaces = SHARED_EXPECTED[name]
    scene = load_scene(shared_ifc(name))
    assert scene.schema.startswith(schema)
    assert dict(Counter(scene.components.ifc_class.tolist())) == per_class
    assert len(scene.spaces) == spaces
    assert scene.failed == ()
    assert scene.report.declared_elements == len(scene.components)
    assert not scene.report.repairs and scene.report.length_unit_source == "file"
    # example.ifc really has 4 dangling references (an IfcWindowStyle) and an IfcSpace with 8 of 11 attributes
    expected_issues = {"dangling-reference": 4, "attribute-count": 1} if name == "example.ifc" else {}
    assert {i.kind: i.count for i in scene.report.issues} == expected_issues
    assert len(set(scene.components.step_id.tolist())) == len(scene.components)
    expected_labels = Counter()
    for cls, n in per_class.items():
        expected_labels[SPC5.get(cls, "Others")] += n
    names = scene.scheme.names
    assert Counter(names[int(i)] for i in scene.components.label) == expected_labels
    # every component owns triangles, and every triangle belongs to a component
    assert set(np.unique(scene.mesh.face_component)) == set(range(len(scene.components)))


def test_millimetre_models_come_out_in_metres(shared_ifc):
    scene = load_scene(shared_ifc("example.ifc"))  # authored in millimetres
    lo, hi = scene.mesh.bounds()
    height = hi[2] - lo[2]
    assert 4.0 < height < 8.0, f"a two-storey frame should be a few metres tall, got {height}"
    assert [round(s.elevation_m, 2) for s in scene.storeys] == [0.0, 3.14]


def test_global_ids_are_unique_and_components_are_sorted_deterministically(shared_ifc):
    first = load_scene(shared_ifc("AC20-FZK-Haus.ifc"), use_cache=False)
    second = load_scene(shared_ifc("AC20-FZK-Haus.ifc"), use_cache=False)
    assert len(set(first.components.global_id.tolist())) == len(first.components)
    assert first.components.global_id.tolist() == second.components.global_id.tolist()
    assert np.array_equal(first.mesh.vertices, second.mesh.vertices)
    assert np.array_equal(first.mesh.face_component, second.mesh.face_component)


def test_cached_load_equals_a_fresh_parse_and_skips_the_parse(shared_ifc, private_cache):
    path = shared_ifc("duplex.ifc")
    fresh = load_scene(path, use_cache=False)
    load_scene(path)  # fills the cache
    assert list((private_cache / "ifc").glob("*.npz")), "a cache entry should have been written"
    start = time.perf_counter()
    cached = load_scene(path)
    cached_seconds = time.perf_counter() - start
    assert np.array_equal(cached.mesh.vertices, fresh.mesh.vertices)
    assert np.array_equal(cached.mesh.faces, fresh.mesh.faces)
    assert np.array_equal(cached.mesh.face_transparency, fresh.mesh.face_transparency, equal_nan=True)
    assert cached.components.rows() == fresh.components.rows()
    assert [s.name for s in cached.spaces] == [s.name for s in fresh.spaces]
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(cached.spaces, fresh.spaces))
    assert cached.storeys == fresh.storeys
    assert np.array_equal(cached.components.step_id, fresh.components.step_id)
    assert cached.report == fresh.report
    # not a timing target: a cache hit that parsed again would take seconds on this model
    assert cached_seconds < 1.0


def test_a_damaged_cache_entry_is_parsed_again(shared_ifc, private_cache):
    path = shared_ifc("IfcOpenHouse_IFC4.ifc")
    load_scene(path)
    for entry in (private_cache / "ifc").glob("*.npz"):
        entry.write_bytes(b"not an npz")
    scene = load_scene(path)
    assert len(scene.components) == 34


def test_spaces_stay_out_of_the_scannable_mesh(shared_ifc):
    scene = load_scene(shared_ifc("duplex.ifc"))
    assert "IfcSpace" not in set(scene.components.ifc_class.tolist())
    assert "IfcOpeningElement" not in set(scene.components.ifc_class.tolist())
    assert all(len(s.faces) > 0 for s in scene.spaces)
    assert {s.storey for s in scene.spaces} <= {s.name for s in scene.storeys}
    assert {"Level 1", "Level 2"} <= {s.storey for s in scene.spaces}


@pytest.mark.parametrize("schema", ["IFC2X3", "IFC4", "IFC4X3"])
def test_tiny_models_of_every_schema_load_with_world_coordinates(schema, tiny_model, tmp_path):
    model = tiny_model(schema)
    model.add_box("IfcWall", origin=(10.0, 20.0, 0.0), size=(4.0, 0.2, 3.0))
    model.add_box("IfcSlab", origin=(10.0, 20.0, -0.2), size=(4.0, 4.0, 0.2), predefined_type="FLOOR")
    scene = load_scene(model.write(tmp_path / "tiny.ifc"))
    lo, hi = scene.mesh.bounds()
    np.testing.assert_allclose(lo, [10.0, 20.0, -0.2], atol=1e-6)
    np.testing.assert_allclose(hi, [14.0, 24.0, 3.0], atol=1e-6)
    assert scene.components.storey.tolist() == ["L0", "L0"]
    assert sorted(scene.scheme.names[int(i)] for i in scene.components.label) == ["Slab", "Wall&Column"]


def test_a_model_with_one_broken_element_still_loads_and_reports_it(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_box("IfcWall", size=(4.0, 0.2, 3.0))
    broken = model.add_broken("IfcColumn")
    scene = load_scene(model.write(tmp_path / "broken.ifc"))
    assert scene.components.ifc_class.tolist() == ["IfcWall"]
    assert len(scene.failed) == 1
    failure = scene.failed[0]
    assert (failure.global_id, failure.ifc_class) == (broken.GlobalId, "IfcColumn")
    assert failure.reason and failure.cause == "geometry" and failure.step_id == broken.id() and failure.line > 0


def test_a_model_whose_only_element_is_broken_is_an_empty_model_error(tiny_model, tmp_path):
    model = tiny_model("IFC4")
    model.add_broken("IfcColumn")
    with pytest.raises(EmptyModelError, match="no element produced geometry"):
        load_scene(model.write(tmp_path / "all-broken.ifc"))


def test_a_model_without_geometric_elements_is_an_empty_model_error(tiny_model, tmp_path):
    with pytest.raises(EmptyModelError, match="no building elements with 3D geometry"):
        load_scene(tiny_model("IFC4").write(tmp_path / "empty.ifc"))


def test_a_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputFileError, match="no such file"):
        load_scene(tmp_path / "missing.ifc")


def test_a_folder_is_an_input_error(tmp_path):
    with pytest.raises(InputFileError, match="folder"):
        load_scene(tmp_path)


@pytest.mark.parametrize("content, message", [
    (b"", "empty"),
    (b"\x89PNG\r\n\x1a\n binary", "not an IFC file"),
    (b"hello world\n", "not an IFC file"),
])
def test_files_that_are_not_ifc_are_rejected_clearly(content, message, tmp_path):
    path = tmp_path / "bad.ifc"
    path.write_bytes(content)
    with pytest.raises(IfcError, match=message):
        load_scene(path)


def test_a_truncated_ifc_is_rejected(shared_ifc, tmp_path):
    data = shared_ifc("example.ifc").read_bytes()
    path = tmp_path / "truncated.ifc"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(IfcError, match="truncated"):
        load_scene(path)


def _line_of(data: bytes, offset: int) -> int:
    return data.count(b"\n", 0, offset) + 1


def test_a_garbled_line_is_a_warning_naming_it_and_an_error_under_strict(shared_ifc, tmp_path):
    data = shared_ifc("example.ifc").read_bytes()
    middle = data.index(b"\n#", len(data) // 2) + 1
    path = tmp_path / "garbled.ifc"
    junk = b"#999999=IFCWALL(((garbage;;\n"
    path.write_bytes(data[:middle] + junk + data[middle + len(junk):])
    scene = load_scene(path)
    syntax = [i for i in scene.report.issues if i.kind == "syntax"]
    assert syntax and _line_of(data, middle) in syntax[0].lines
    assert len(scene.components) >= 110  # the rest of the model still loads (115 when nothing is hit)
    with pytest.raises(IfcError, match=f"line {_line_of(data, middle)}.*strict"):
        load_scene(path, strict=True)


def test_binary_noise_inside_an_ifc_loses_only_the_lines_it_hits_and_says_so(shared_ifc, tmp_path):
    data = shared_ifc("example.ifc").read_bytes()
    middle = len(data) // 2
    junk = np.random.default_rng(0).integers(0, 256, 2000, dtype=np.uint8).tobytes()
    path = tmp_path / "noise.ifc"
    path.write_bytes(data[:middle] + junk + data[middle + len(junk):])
    scene = load_scene(path)
    hit = range(_line_of(data, middle), _line_of(data, middle + len(junk)) + 1)
    syntax = [i for i in scene.report.issues if i.kind == "syntax"][0]
    assert set(syntax.lines) <= set(hit) and syntax.count >= 1
    assert len(scene.components) + len(scene.failed) >= 100


def test_an_ifczip_loads_like_the_ifc_inside(shared_ifc, tmp_path):
    import zipfile

    model = shared_ifc("IfcOpenHouse_IFC4.ifc")
    archive = tmp_path / "house.ifczip"
    with zipfile.ZipFile(archive, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.write(model, "IfcOpenHouse_IFC4.ifc")
    scene = load_scene(archive)
    plain = load_scene(model)
    assert scene.source == str(archive)
    assert scene.components.global_id.tolist() == plain.components.global_id.tolist()
    assert np.array_equal(scene.mesh.vertices, plain.mesh.vertices)


def test_a_zip_without_exactly_one_ifc_is_refused(tmp_path):
    import zipfile

    archive = tmp_path / "two.ifczip"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("a.ifc", "ISO-10303-21;")
        z.writestr("b.ifc", "ISO-10303-21;")
    with pytest.raises(IfcError, match="exactly one"):
        load_scene(archive)

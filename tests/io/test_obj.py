"""OBJ export with a component index, and reading it back."""

from __future__ import annotations

import csv
import errno
from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import InputFileError, OutputError
from bimscan.io import export_obj, read_obj
from bimscan.io.obj import INDEX_COLUMNS, group_name
from bimscan.types import BimScene, ComponentTable, LabelScheme, SceneMesh


def box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box: 8 vertices, 12 triangles."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    vertices = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)], dtype=np.float64)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int32)
    return vertices, faces


@pytest.fixture
def scene(scheme: LabelScheme, components: ComponentTable) -> BimScene:
    """Three components: a wall box, a beam box and a two-triangle slab; triangles interleaved."""
    wall_v, wall_f = box((0.0, 0.0, 0.0), (5.0, 0.24, 2.8))
    beam_v, beam_f = box((0.0, 0.0, 2.5), (5.0, 0.2, 2.8))
    slab_v = np.array([[0, 0, 0], [5.123456789, 0, 0], [5.123456789, 4, 0], [0, 4, 0]], dtype=np.float64)
    slab_f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    vertices = np.concatenate([wall_v, beam_v, slab_v]) + np.array([512_300.0, 5_403_100.0, 41.0])
    faces = np.concatenate([wall_f, beam_f + 8, slab_f + 16])
    face_component = np.array([0] * 12 + [1] * 12 + [2] * 2, dtype=np.int32)
    order = np.random.default_rng(1).permutation(len(faces))  # components' triangles interleaved
    mesh = SceneMesh(vertices=vertices, faces=faces[order], face_component=face_component[order])
    return BimScene(
        source="/data/models/Haus.ifc", file_sha256="0" * 64, schema="IFC4", mesh=mesh, components=components,
        scheme=scheme, storeys=(), spaces=(), failed=(), unmapped_classes={},
    )


def triangles_of(scene: BimScene, component: int) -> np.ndarray:
    """(F, 3, 3) corner coordinates of one component's triangles, in mesh order."""
    mesh = scene.mesh
    return mesh.vertices[mesh.faces[mesh.face_component == component]]


def test_model_obj_has_one_group_per_component_with_its_triangles(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj")
    groups = read_obj(export.model_obj)
    table = scene.components
    assert sorted(groups) == sorted(group_name(c, str(table.global_id[c])) for c in range(len(table)))
    for c in range(len(table)):
        vertices, faces = groups[group_name(c, str(table.global_id[c]))]
        assert len(faces) == int(np.sum(scene.mesh.face_component == c))
        assert np.abs(vertices[faces] - triangles_of(scene, c)).max() < 1e-6  # micrometre text
    assert export.n_triangles == scene.mesh.n_triangles


def test_every_component_file_holds_that_components_triangles(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj")
    assert sorted(export.component_files) == [0, 1, 2]
    for c, path in export.component_files.items():
        (vertices, faces), = read_obj(path).values()
        assert np.abs(vertices[faces] - triangles_of(scene, c)).max() < 1e-6
        assert f"usemtl class_{scene.components.label[c]}" in path.read_text()


def test_index_csv_rows_match_the_component_table(tmp_path, scene):
    export = export_obj(scene, tmp_path / "obj")
    with export.index_csv.open(newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    assert tuple(rows[0]) == INDEX_COLUMNS
    names = scene.scheme.names
    for row, expected in zip(rows, scene.components.rows(), strict=True):
        for key in ("global_id", "ifc_class", "predefined_type", "name", "storey"):
            assert row[key] == expected[key]
        assert int(row["component"]) == expected["component"] and int(row["label"]) == expected["label"]
        assert row["label_name"] == names[expected["label"]]
        assert int(row["n_triangles"]) == int(np.sum(scene.mesh.face_component == expected["component"]))
        assert (tmp_path / "obj" / row["obj_file"]).is_file()


def test_components_without_triangles_are_indexed_but_get_no_file(tmp_path, scene):
    mesh = scene.mesh
    keep = mesh.face_component != 1
    bare = BimScene(**{**scene.__dict__, "mesh": SceneMesh(mesh.vertices, mesh.faces[keep], mesh.face_component[keep])})
    export = export_obj(bare, tmp_path / "obj")
    assert sorted(export.component_files) == [0, 2]
    rows = list(csv.DictReader(export.index_csv.open(encoding="utf-8")))
    assert rows[1]["n_triangles"] == "0" and rows[1]["obj_file"] == ""


def test_the_export_is_byte_reproducible(tmp_path, scene):
    a = export_obj(scene, tmp_path / "a", helios=True)
    b = export_obj(scene, tmp_path / "b", helios=True)
    files_a = sorted(p.relative_to(a.out_dir) for p in a.out_dir.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b.out_dir) for p in b.out_dir.rglob("*") if p.is_file())
    assert files_a == files_b
    assert all((a.out_dir / f).read_bytes() == (b.out_dir / f).read_bytes() for f in files_a)


def test_existing_outputs_are_kept_without_overwrite(tmp_path, scene):
    export_obj(scene, tmp_path / "obj")
    before = (tmp_path / "obj" / "model.obj").read_bytes()
    with pytest.raises(OutputError, match="already holds model.obj"):
        export_obj(scene, tmp_path / "obj")
    assert (tmp_path / "obj" / "model.obj").read_bytes() == before
    export_obj(scene, tmp_path / "obj", overwrite=True)
    assert [p.name for p in (tmp_path / "obj").iterdir() if p.name.startswith(".")] == [".bimscan.json"]  # no staging


def test_overwrite_replaces_a_previous_export_with_helios_files_but_never_a_users_folder(tmp_path, scene):
    out = tmp_path / "project"
    export_obj(scene, out, helios=True)
    export_obj(scene, out, helios=True, overwrite=True)  # its own components/ and helios/: replaced
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == [".bimscan.json"]
    (out / "components" / "my_notes.txt").write_text("mine")
    with pytest.raises(OutputError, match=r"components is a folder of bimscan component OBJs that also holds "
                                          r"my_notes.txt, which bimscan did not write"):
        export_obj(scene, out, helios=True, overwrite=True)
    (out / "components" / "my_notes.txt").unlink()
    for child in (out / "helios").iterdir():  # the user's own HELIOS++ scene where the export puts its own
        child.unlink()
    (out / "helios" / "scene.xml").write_text('<?xml version="1.0"?>\n<document><scene id="mine"/></document>\n')
    with pytest.raises(OutputError, match="helios is a folder that is not bimscan's HELIOS.. scene folder"):
        export_obj(scene, out, helios=True, overwrite=True)
    assert (out / "helios" / "scene.xml").read_text().startswith('<?xml version="1.0"?>')
    assert (out / "model.obj").is_file()  # nothing was replaced: the refusal came first


def test_a_missing_parent_folder_is_an_output_error(tmp_path, scene):
    with pytest.raises(OutputError, match="does not exist"):
        export_obj(scene, tmp_path / "missing" / "obj")


def test_read_obj_splits_polygons_and_resolves_relative_and_slashed_indices(tmp_path):
    (tmp_path / "poly.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\nvt 0 0\nvn 0 0 1\n"
        "o quad\nf 1/1/1 2/1/1 3/1/1 4/1/1\ng tri\nf -4//1 -3//1 -1//1\n"
    )
    groups = read_obj(tmp_path / "poly.obj")
    assert groups["quad"][1].tolist() == [[0, 1, 2], [0, 2, 3]]
    vertices, faces = groups["tri"]
    assert vertices[faces].tolist() == [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]]


def test_read_obj_refuses_faces_pointing_past_the_vertices(tmp_path):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n")
    with pytest.raises(InputFileError, match="outside the 3 vertices"):
        read_obj(tmp_path / "bad.obj")


def test_a_disk_full_export_is_an_output_error_and_leaves_no_folder(tmp_path, scene, monkeypatch):
    real_write_text = Path.write_text

    def full(self: Path, *args: object, **kwargs: object) -> int:
        if self.suffix == ".csv":
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write_text(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(OutputError, match="disk full while writing"):
        export_obj(scene, tmp_path / "obj")
    assert list(tmp_path.iterdir()) == []


def test_a_users_files_beside_the_export_are_never_replaced(tmp_path, scene):
    from bimscan.files import OUTPUT_RECORD

    # a folder of the user's: refused before any work, even with overwrite, whatever its names
    users = tmp_path / "survey"
    users.mkdir()
    (users / "index.csv").write_text("sheet,page\n1,2\n")
    (users / "notes.md").write_text("mine")
    for overwrite in (False, True):
        with pytest.raises(OutputError, match="folder bimscan did not make"):
            export_obj(scene, users, overwrite=overwrite)
    assert (users / "index.csv").read_text() == "sheet,page\n1,2\n" and sorted(p.name for p in users.iterdir()) == [
        "index.csv", "notes.md"]
    # an export's folder: the user's file beside it is kept by a rerun, and one at an export's name is refused
    out = tmp_path / "obj"
    export_obj(scene, out)
    (out / "notes.md").write_text("mine")
    export_obj(scene, out, overwrite=True)
    assert (out / "notes.md").read_text() == "mine"
    (out / "classes.mtl").unlink()
    (out / "classes.mtl").write_text("newmtl mine\n")
    record = (out / OUTPUT_RECORD).read_bytes()
    (out / OUTPUT_RECORD).write_bytes(record.replace(b'"classes.mtl",', b""))
    with pytest.raises(OutputError, match="classes.mtl was not written by bimscan"):
        export_obj(scene, out, overwrite=True)
    assert (out / "classes.mtl").read_text() == "newmtl mine\n"


def test_an_export_an_earlier_version_wrote_is_still_replaced(tmp_path, scene):
    from bimscan.files import OUTPUT_RECORD

    out = tmp_path / "obj"
    export_obj(scene, out)
    (out / OUTPUT_RECORD).unlink()  # as an export before output folders had their record
    export_obj(scene, out, overwrite=True)
    assert (out / OUTPUT_RECORD).is_file() and (out / "model.obj").is_file()

"""Aligning a scan to its model without a starting guess."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.compare.config import AlignConfig
from bimscan.compare.planes import apply, rotation_angle_deg
from bimscan.compare.report import format_matrix, read_transform
from bimscan.errors import InputFileError

from .conftest import motion, move_as_foreign_las


def _errors(found: np.ndarray, truth: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> tuple[float, float]:
    centre = ((lower + upper) / 2)[None]
    return rotation_angle_deg(found[:3, :3] @ truth[:3, :3].T), float(np.linalg.norm(apply(found, centre) - apply(truth, centre)))


@pytest.mark.slow
def test_a_scan_in_map_coordinates_turned_and_tilted_is_aligned_without_a_guess(building_ifc, partial_scan, tmp_path,
                                                                                 capsys):
    moved = motion(3, tilt_deg=2.5)
    scan = move_as_foreign_las(partial_scan, tmp_path / "site.las", moved)
    assert main(["align", str(building_ifc), str(scan), str(tmp_path / "out"), "--aligned", "laz"]) == 0
    document = json.loads((tmp_path / "out" / "transform.json").read_text())
    found = np.array(document["matrix"])
    from bimscan.io import read_cloud

    cloud = read_cloud(scan, labels=False)
    rotation, centre = _errors(found, np.linalg.inv(moved), cloud.xyz.min(axis=0), cloud.xyz.max(axis=0))
    assert rotation < 0.05 and centre < 0.01
    assert document["alignment"]["inlier_share"] > 0.9
    assert np.allclose(read_transform(tmp_path / "out" / "transform.txt"), found, atol=1e-6)  # the text file says the same
    aligned = read_cloud(tmp_path / "out" / "aligned.laz", labels=False)
    assert np.abs(aligned.xyz - apply(np.linalg.inv(moved), cloud.xyz)).max() < 0.01
    assert "aligned to building.ifc" in capsys.readouterr().out


def test_a_levelled_scan_and_a_start_from_point_pairs_give_the_same_pose(building_ifc, built_scan, tmp_path):
    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.pipeline import load_scene

    moved = motion(5)
    scan = move_as_foreign_las(built_scan, tmp_path / "site.las", moved)
    surfaces = ModelSurfaces(load_scene(building_ifc).mesh)
    digest = digest_scan(scan, voxel_m=0.05)
    levelled = align_digest(digest, surfaces, AlignConfig(levelled=True))
    model_points = np.array([[0.0, 0.0, 0.0], [12.0, 0.0, 0.0], [12.0, 10.0, 3.0], [7.0, 10.0, 0.0]])
    pairs = tmp_path / "pairs.csv"
    scan_points = apply(moved, model_points) + np.random.default_rng(0).normal(0, 0.05, (4, 3))  # picked by hand: 5 cm off
    pairs.write_text("".join(",".join(f"{v:.4f}" for v in (*s, *m)) + "\n" for s, m in zip(scan_points, model_points)))
    started = align_digest(digest, surfaces, AlignConfig(), init=read_transform(pairs, pairs=True))
    truth = np.linalg.inv(moved)
    for found in (levelled.matrix, started.matrix):
        rotation, centre = _errors(found, truth, digest.lower, digest.upper)
        assert rotation < 0.05 and centre < 0.01


def test_a_scan_in_millimetres_is_refused_in_one_line(building_ifc, built_scan, tmp_path, capsys):
    millimetres = np.eye(4)
    millimetres[:3, :3] *= 1000.0  # the same points, their numbers in millimetres
    scan = move_as_foreign_las(built_scan, tmp_path / "mm.las", millimetres, scale=1.0)
    assert main(["align", str(building_ifc), str(scan), str(tmp_path / "out")]) == 1
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and "millimetres" in error and not (tmp_path / "out").exists()


def test_a_scan_of_something_else_is_refused_naming_the_best_inlier_share(building_ifc, tmp_path, capsys):
    import laspy

    rng = np.random.default_rng(0)  # a rock pile: points on no plane of the building
    xyz = rng.normal(0, 3.0, size=(50_000, 3)) + [500_000, 5_000_000, 100]
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets, header.scales = np.round(xyz.min(axis=0)), np.full(3, 0.001)
    data = laspy.LasData(header)
    data.x, data.y, data.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    data.write(tmp_path / "rocks.las")
    assert main(["align", str(building_ifc), str(tmp_path / "rocks.las"), str(tmp_path / "out")]) == 1
    error = capsys.readouterr().err
    assert error.startswith("error: ") and error.count("\n") == 1
    assert ("could not align" in error and "%" in error) or "no walls or floors" in error


def test_a_symmetric_room_is_reported_ambiguous_and_a_corridor_free_along_its_axis(box_room_ifc, tiny_model, tmp_path):
    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.pipeline import load_scene

    from .conftest import scan

    # the 8 x 6 m box room looks the same turned by a half turn about its centre
    room = scan(box_room_ifc, tmp_path / "room.laz", stations_csv="x,y,height\n2.5,2.0,1.5\n")
    digest = digest_scan(room, voxel_m=0.05)
    result = align_digest(digest, ModelSurfaces(load_scene(box_room_ifc).mesh), AlignConfig())
    assert any("ambiguous" in w for w in result.warnings) and result.alternatives
    # a 40 m corridor with open ends: nothing pins the position along it
    model = tiny_model("IFC4")
    model.add_box("IfcSlab", origin=(0, -0.25, -0.3), size=(40, 2.5, 0.3), name="floor")
    model.add_box("IfcSlab", origin=(0, -0.25, 3.0), size=(40, 2.5, 0.3), name="roof")
    model.add_box("IfcWall", origin=(0, -0.25, 0), size=(40, 0.25, 3.0), name="south")
    model.add_box("IfcWall", origin=(0, 2.0, 0), size=(40, 0.25, 3.0), name="north")
    corridor = model.write(tmp_path / "corridor.ifc")
    stations = tmp_path / "corridor.stations.csv"
    stations.write_text("x,y,height\n20,1,1.5\n")
    assert main(["scan", str(corridor), str(tmp_path / "corridor.laz"), "--stations", str(stations), "--head-speed",
                 "120", "--no-noise"]) == 0
    digest = digest_scan(tmp_path / "corridor.laz", voxel_m=0.05)
    result = align_digest(digest, ModelSurfaces(load_scene(corridor).mesh), AlignConfig(levelled=True))
    assert any("free along (1.00, 0.00, 0.00)" in w for w in result.warnings)


def test_transform_files_are_read_and_checked(tmp_path):
    matrix = motion(7)
    (tmp_path / "m.txt").write_text(format_matrix(matrix))
    assert np.allclose(read_transform(tmp_path / "m.txt"), matrix, atol=1e-6)
    (tmp_path / "m.json").write_text(json.dumps({"matrix": matrix.tolist()}))
    assert np.allclose(read_transform(tmp_path / "m.json"), matrix)
    scaled = matrix.copy()
    scaled[:3, :3] *= 1.1
    (tmp_path / "scaled.txt").write_text(format_matrix(scaled))
    with pytest.raises(InputFileError, match="not a rigid motion"):
        read_transform(tmp_path / "scaled.txt")
    (tmp_path / "short.txt").write_text("1 0 0\n0 1 0\n")
    with pytest.raises(InputFileError, match="4x4"):
        read_transform(tmp_path / "short.txt")
    (tmp_path / "two.csv").write_text("0,0,0,1,1,1\n1,0,0,2,1,1\n")
    with pytest.raises(InputFileError, match="at least three"):
        read_transform(tmp_path / "two.csv", pairs=True)


def test_align_refuses_a_users_folder_and_replaces_only_its_own(building_ifc, built_scan, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["align", str(building_ifc), str(built_scan), str(out), "--levelled"]) == 1
    assert "notes.txt" in capsys.readouterr().err and (out / "notes.txt").read_text() == "mine"
    mine = tmp_path / "mine"
    assert main(["align", str(building_ifc), str(built_scan), str(mine), "--levelled"]) == 0
    assert main(["align", str(building_ifc), str(built_scan), str(mine), "--levelled"]) == 1  # no --overwrite
    assert "--overwrite" in capsys.readouterr().err
    assert main(["align", str(building_ifc), str(built_scan), str(mine), "--levelled", "--overwrite"]) == 0
    assert sorted(p.name for p in mine.iterdir()) == ["transform.json", "transform.txt"]


def test_the_same_scan_gives_the_same_files(building_ifc, built_scan, tmp_path):
    for name in ("a", "b"):
        assert main(["align", str(building_ifc), str(built_scan), str(tmp_path / name)]) == 0
    for name in ("transform.txt", "transform.json"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_the_models_georeferencing_places_a_scan_in_map_coordinates_among_symmetric_poses(box_room_ifc, tmp_path):
    import shutil

    import ifcopenshell.api

    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.ifc.georef import read_map_conversion
    from bimscan.pipeline import load_scene

    from .conftest import scan

    # the symmetric box room, georeferenced: its origin at (512 km, 5401 km), its x axis 30 degrees off east
    path = Path(shutil.copy(box_room_ifc, tmp_path / "room.ifc"))
    model = ifcopenshell.open(str(path))
    ifcopenshell.api.run("georeference.add_georeferencing", model, name="EPSG:32633")
    angle = np.radians(30.0)
    ifcopenshell.api.run("georeference.edit_georeferencing", model, coordinate_operation={
        "Eastings": 512_000.0, "Northings": 5_401_000.0, "OrthogonalHeight": 310.0,
        "XAxisAbscissa": float(np.cos(angle)), "XAxisOrdinate": float(np.sin(angle)), "Scale": 1.0})
    model.write(str(path))
    to_map = read_map_conversion(path)
    assert to_map is not None and np.allclose(to_map[:3, 3], [512_000.0, 5_401_000.0, 310.0])
    room = scan(path, tmp_path / "room.laz", stations_csv="x,y,height\n2.5,2.0,1.5\n")
    mapped = move_as_foreign_las(room, tmp_path / "mapped.las", to_map)
    digest = digest_scan(mapped, voxel_m=0.05)
    surfaces = ModelSurfaces(load_scene(path).mesh)
    result = align_digest(digest, surfaces, AlignConfig(), georeference=to_map)
    assert result.placed_by == "georeferencing" and not result.alternatives
    rotation, centre = _errors(result.matrix, np.linalg.inv(to_map), digest.lower, digest.upper)
    assert rotation < 0.05 and centre < 0.01
    blind = align_digest(digest, surfaces, AlignConfig())  # without it: the half turn fits as well
    assert blind.alternatives


def test_a_wall_seen_from_inside_is_put_on_its_inner_face_not_a_walls_thickness_away(tiny_model, tmp_path):
    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.pipeline import load_scene

    from .conftest import scan

    # a room whose only wall across x is the east one, 0.4 m thick: put its inner face on its outer
    # face and the floor still fits (the slab runs on past the missing west wall); only the side the
    # scanner saw it from tells the two poses apart
    model = tiny_model("IFC4")
    w = 0.4
    model.add_box("IfcSlab", origin=(-2.0, -w, -0.3), size=(8.0 + w, 4.0 + 2 * w, 0.3), predefined_type="FLOOR",
                  name="floor")
    model.add_box("IfcWall", origin=(-2.0, -w, 0), size=(8.0 + w, w, 3.0), name="south")
    model.add_box("IfcWall", origin=(-2.0, 4.0, 0), size=(8.0 + w, w, 3.0), name="north")
    model.add_box("IfcWall", origin=(6.0, 0.0, 0), size=(w, 4.0, 3.0), name="east")
    path = model.write(tmp_path / "room.ifc")
    room = scan(path, tmp_path / "room.laz", stations_csv="x,y,height\n3.0,2.2,1.5\n")
    moved = motion(8)
    site = move_as_foreign_las(room, tmp_path / "site.las", moved)
    digest = digest_scan(site, voxel_m=0.05)
    assert digest.viewer is not None and np.isfinite(digest.viewer).all()  # one station: every centroid's viewer
    result = align_digest(digest, ModelSurfaces(load_scene(path).mesh), AlignConfig())
    rotation, centre = _errors(result.matrix, np.linalg.inv(moved), digest.lower, digest.upper)
    assert rotation < 0.05 and centre < 0.01, (rotation, centre)


def test_a_merged_cloud_under_one_station_id_is_aligned_by_its_surfaces(building_ifc, built_scan, tmp_path):
    from bimscan.compare.align import align_digest
    from bimscan.compare.digest import digest_scan
    from bimscan.compare.surfaces import ModelSurfaces
    from bimscan.pipeline import load_scene

    # both stations' points under id 0: the mean of "its" points is no scanner position, and the
    # sides it gives are wrong for some walls: the pose must not suffer
    moved = motion(11)
    site = move_as_foreign_las(built_scan, tmp_path / "merged.las", moved, stations=False)
    digest = digest_scan(site, voxel_m=0.05)
    result = align_digest(digest, ModelSurfaces(load_scene(building_ifc).mesh), AlignConfig())
    rotation, centre = _errors(result.matrix, np.linalg.inv(moved), digest.lower, digest.upper)
    assert rotation < 0.05 and centre < 0.01, (rotation, centre)

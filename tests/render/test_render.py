"""Pictures: z-buffered kernels, cameras, the storey section, cloud renders and the model figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.render.cloud import panel_size, render_cloud
from bimscan.render.compose import panel_origin
from bimscan.render.raster import fill_triangles, new_canvas, splat_points
from bimscan.render.view import TOP, Camera, find_section
from bimscan.semantics import load_scheme
from bimscan.types import CloudHeader, PointCloud

WHITE = (255, 255, 255)


def _room_cloud(seed: int = 0) -> PointCloud:
    """A 6 x 4 x 3 m room as points: floor (Slab), ceiling (Covering), walls (Wall&Column), a box (Others)."""
    rng = np.random.default_rng(seed)
    parts = []

    def plane(n: int, lo: tuple, hi: tuple, label: int, station: int) -> None:
        parts.append(PointCloud(xyz=rng.uniform(lo, hi, (n, 3)), label=np.full(n, label, np.uint8),
                                station=np.full(n, station, np.uint16),
                                intensity=rng.integers(0, 60000, n).astype(np.uint16)))

    plane(40000, (0, 0, 0), (6, 4, 0), 3, 0)
    plane(40000, (0, 0, 3), (6, 4, 3), 2, 1)
    for lo, hi in (((0, 0, 0), (6, 0, 3)), ((0, 4, 0), (6, 4, 3)), ((0, 0, 0), (0, 4, 3)), ((6, 0, 0), (6, 4, 3))):
        plane(20000, lo, hi, 0, 0)
    plane(5000, (2, 1.5, 0.8), (3, 2.5, 0.8), 4, 1)  # a table top
    return PointCloud.concatenate(parts)


def _write(cloud: PointCloud, path: Path) -> Path:
    from bimscan.io import open_cloud_writer

    with open_cloud_writer(path, header=CloudHeader(scheme=load_scheme())) as writer:
        for start in range(0, len(cloud), 50_000):
            writer.write(cloud.take(slice(start, start + 50_000)))
    return path


def _pixels(png: Path) -> np.ndarray:
    from matplotlib.image import imread

    return (imread(png)[..., :3] * 255).round().astype(np.uint8)


def _panels(image: np.ndarray, n: int) -> list[np.ndarray]:
    height, width = image.shape[:2]
    w, h = panel_size(width, height, panels=n)
    return [image[y:y + h, x:x + w] for x, y in (panel_origin(i, w) for i in range(n))]


def test_splats_keep_the_nearest_point_of_each_pixel() -> None:
    image, zbuffer = new_canvas(4, 3)
    colors = np.array([[255, 0, 0], [0, 0, 255], [0, 255, 0]], dtype=np.uint8)
    # two points on pixel (1, 1): the blue one is nearer whatever the order; one point outside
    splat_points(np.array([1.5, 1.2, 9.0]), np.array([1.5, 1.7, 1.0]), np.array([2.0, 1.0, 0.0]), colors, 0, zbuffer, image)
    assert tuple(image[1, 1]) == (0, 0, 255) and zbuffer[1, 1] == 1.0
    assert (image.reshape(-1, 3) != 255).any(axis=1).sum() == 1


def test_triangles_fill_their_pixels_and_are_cut_at_the_section_height() -> None:
    sx, sy = np.array([0.0, 10.0, 0.0]), np.array([0.0, 0.0, 10.0])
    faces = np.array([[0, 1, 2]], dtype=np.int32)
    color = np.array([[10, 20, 30]], dtype=np.uint8)
    image, zbuffer = new_canvas(10, 10)
    written = fill_triangles(sx, sy, np.zeros(3), np.zeros(3), faces, color, np.inf, zbuffer, image)
    assert written == 55  # pixel centres on or below the diagonal x + y = 10: px + py <= 9
    assert tuple(image[0, 0]) == (10, 20, 30) and tuple(image[9, 9]) == WHITE
    image, zbuffer = new_canvas(10, 10)
    # world height rises with screen x: cutting at 5 keeps the left half of the triangle
    fill_triangles(sx, sy, np.zeros(3), np.array([0.0, 10.0, 0.0]), faces, color, 5.0, zbuffer, image)
    assert tuple(image[0, 2]) == (10, 20, 30) and tuple(image[0, 7]) == WHITE


def test_the_top_view_puts_x_right_and_y_up_and_fits_the_box() -> None:
    camera = Camera.fit(np.zeros(3), np.array([10.0, 5.0, 3.0]), azimuth_deg=TOP[0], elevation_deg=TOP[1],
                        width=400, height=300)
    sx, sy, depth = camera.project(np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 0.0], [5.0, 2.5, 3.0]]))
    assert sx[1] > sx[0] and sy[1] < sy[0]  # +x to the right, +y up the screen
    assert np.all((sx >= 0) & (sx <= 400) & (sy >= 0) & (sy <= 300))
    assert depth[2] < depth[0]  # higher is nearer from above
    assert sx[1] - sx[0] == pytest.approx(400 * 0.92, rel=1e-6)  # the box's width spans the usable width


def test_the_section_opens_the_top_storey_of_a_two_storey_cloud() -> None:
    rng = np.random.default_rng(1)
    layers = [rng.normal(z, 0.004, 20000) for z in (0.0, 2.7, 3.0, 5.7)]  # floor, ceiling, floor, ceiling
    walls = rng.uniform(0.0, 5.7, 30000)
    section = find_section(np.concatenate([*layers, walls]))
    assert section is not None
    assert section.floor_z == pytest.approx(3.0, abs=0.05)
    assert section.plan_z == pytest.approx(4.5, abs=0.05)
    assert section.ceiling_z == pytest.approx(5.6, abs=0.1)
    assert find_section(rng.uniform(0, 1.0, 5000)) is None  # too flat to have storeys


def test_render_writes_a_png_of_the_requested_size_in_the_class_colours(tmp_path: Path) -> None:
    cloud = _write(_room_cloud(), tmp_path / "room.laz")
    result = render_cloud(cloud, tmp_path / "room.png", width=900, height=500, max_points=150_000)
    image = _pixels(tmp_path / "room.png")
    assert image.shape == (500, 900, 3)
    assert result.total_points == len(_room_cloud()) and result.drawn_points == 150_000
    palette = {c.rgb: c.name for c in load_scheme().classes}
    for panel in _panels(image, 2):
        colours = {tuple(int(v) for v in p) for p in np.unique(panel.reshape(-1, 3), axis=0)}
        assert colours - {WHITE} <= set(palette), "every drawn pixel has a class colour"
        drawn = (panel != 255).any(axis=2).mean()
        assert drawn > 0.2
    assert result.section is not None and result.section.floor_z == pytest.approx(0.0, abs=0.05)
    top, oblique = _panels(image, 2)
    top_names = {palette[c] for c in {tuple(int(v) for v in p) for p in top.reshape(-1, 3)} if c in palette}
    assert top_names == {"Slab", "Wall&Column", "Others"}  # a floor plan: floor, cut walls, the table
    oblique_names = {palette[c] for c in {tuple(int(v) for v in p) for p in oblique.reshape(-1, 3)} if c in palette}
    assert "Covering" not in oblique_names and "Wall&Column" in oblique_names  # the ceiling is cut away


def test_render_colours_by_station_and_reads_foreign_files(tmp_path: Path) -> None:
    import laspy

    cloud = _room_cloud()
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales, header.offsets = (0.001, 0.001, 0.001), (0.0, 0.0, 0.0)
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.classification = cloud.label
    las.write(tmp_path / "foreign.las")
    render_cloud(tmp_path / "foreign.las", tmp_path / "foreign.png", width=600, height=400, max_points=50_000)
    image = _pixels(tmp_path / "foreign.png")
    assert image.shape == (400, 600, 3)
    colours = {tuple(int(v) for v in p) for panel in _panels(image, 2)
               for p in np.unique(panel.reshape(-1, 3), axis=0)} - {WHITE}
    # a foreign file's class ids are not bimscan's classes: one neutral colour per id (floor, walls, table
    # under the cut), none of them a bimscan class colour
    assert len(colours) == 3 and not colours & {c.rgb for c in load_scheme().classes}
    _write(cloud, tmp_path / "ours.ply")
    render_cloud(tmp_path / "ours.ply", tmp_path / "stations.png", color="station", width=600, height=400,
                 max_points=50_000, cut="none")
    colours = {tuple(int(v) for v in p) for panel in _panels(_pixels(tmp_path / "stations.png"), 2)
               for p in np.unique(panel.reshape(-1, 3), axis=0)} - {WHITE}
    assert len(colours) == 2  # two stations, one colour each


def test_render_draws_the_points_own_colours_with_color_rgb(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    room = _room_cloud()
    painted = {0: (200, 40, 40), 2: (40, 200, 40), 3: (40, 40, 200), 4: (250, 200, 0)}  # by class: walls, ceiling, ...
    rgb = np.array([painted[int(label)] for label in room.label], dtype=np.uint8)
    _write(PointCloud(xyz=room.xyz, label=room.label, rgb=rgb), tmp_path / "painted.ply")
    assert main(["render", str(tmp_path / "painted.ply"), str(tmp_path / "rgb.png"), "--color", "rgb",
                 "--size", "600x400", "--cut", "none"]) == 0
    colours = {tuple(int(v) for v in p) for panel in _panels(_pixels(tmp_path / "rgb.png"), 2)
               for p in np.unique(panel.reshape(-1, 3), axis=0)} - {WHITE}
    assert colours and colours <= set(painted.values()) and (40, 200, 40) in colours
    _write(room, tmp_path / "plain.ply")
    assert main(["render", str(tmp_path / "plain.ply"), str(tmp_path / "none.png"), "--color", "rgb"]) != 0
    assert "has no rgb column" in capsys.readouterr().err and not (tmp_path / "none.png").exists()


def test_the_same_cloud_renders_to_the_same_bytes(tmp_path: Path) -> None:
    cloud = _write(_room_cloud(), tmp_path / "room")
    render_cloud(cloud, tmp_path / "a.png", width=400, height=300, max_points=20_000)
    render_cloud(cloud, tmp_path / "b.png", width=400, height=300, max_points=20_000)
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_the_figure_shows_the_model_and_its_scan_side_by_side(tmp_path: Path, box_room_ifc: Path) -> None:
    from bimscan.pipeline import load_scene
    from bimscan.render.figure import render_figure

    scene = load_scene(box_room_ifc)
    cloud = _write(_room_cloud(), tmp_path / "room.laz")
    render_figure(scene.mesh, scene.components.label, scene.scheme, cloud, tmp_path / "fig.png", real=cloud,
                  width=900, height=360, max_points=60_000)
    image = _pixels(tmp_path / "fig.png")
    assert image.shape == (360, 900, 3)
    model, synthetic, real = _panels(image, 3)
    assert (model != 255).any(axis=2).mean() > 0.2 and (synthetic != 255).any(axis=2).mean() > 0.1
    # the model is shaded: its two classes (walls, slabs) show in several shades each
    assert len(np.unique(model.reshape(-1, 3), axis=0)) - 1 > 2
    # the real scan is framed on its own points (the model's frame holds the synthetic scan): it fills more
    assert (real != 255).any(axis=2).mean() > (synthetic != 255).any(axis=2).mean()
    palette = {c.rgb for c in load_scheme().classes}
    assert {tuple(int(v) for v in p) for p in np.unique(real.reshape(-1, 3), axis=0)} - {WHITE} <= palette


def test_render_and_figure_refuse_bad_input_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["render", str(tmp_path / "missing.laz"), str(tmp_path / "x.png")]) == 1
    assert "no such file" in capsys.readouterr().err
    cloud = _write(_room_cloud(), tmp_path / "room.laz")
    assert main(["render", str(cloud), str(tmp_path / "x.png"), "--size", "10x10"]) == 1
    assert "image size 10x10 is impossible" in capsys.readouterr().err
    assert main(["render", str(cloud), str(tmp_path / "x.jpg")]) == 1
    assert "ending in .png" in capsys.readouterr().err
    assert main(["figure", str(tmp_path / "missing.ifc"), str(tmp_path / "nothing"), str(tmp_path / "f.png")]) == 1
    assert "no such file" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.png")) and not list(tmp_path.glob(".*"))


@pytest.mark.parametrize("name", ["empty.laz", "empty.ply", "empty"])
def test_render_says_an_empty_cloud_is_empty_and_draws_nothing(name: str, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    # it drew a blank picture (--color height) or said the cloud had no label column (issue 50)
    cloud = _write(PointCloud(xyz=np.zeros((0, 3)), label=np.zeros(0, np.uint8)), tmp_path / name)
    for color in ("label", "height"):
        assert main(["render", str(cloud), str(tmp_path / "x.png"), "--color", color]) == 1
        assert capsys.readouterr().err.splitlines() == [
            f"error: {cloud}: the cloud is empty (0 points); there is nothing to draw, pass a cloud with points"]
    assert not list(tmp_path.glob("*.png")) and not list(tmp_path.glob(".*.png*"))


def test_the_figure_says_an_empty_scan_is_empty(tmp_path: Path, box_room_ifc: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    cloud = _write(PointCloud(xyz=np.zeros((0, 3)), label=np.zeros(0, np.uint8)), tmp_path / "empty.laz")
    assert main(["figure", str(box_room_ifc), str(cloud), str(tmp_path / "f.png")]) == 1
    assert "the cloud is empty (0 points)" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.png"))


def test_shading_leaves_the_callers_light_vector_alone():
    import numpy as np

    from bimscan.render.mesh import face_colors
    from bimscan.semantics import load_scheme
    from bimscan.types import SceneMesh

    mesh = SceneMesh(vertices=np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), faces=np.array([[0, 1, 2]], np.int32),
                     face_component=np.zeros(1, np.int32))
    light = np.array([0.0, 0.0, 2.0])
    colors = face_colors(mesh, np.zeros(1, np.uint8), load_scheme(), light_towards=light)
    assert light.tolist() == [0.0, 0.0, 2.0]
    assert tuple(colors[0]) == load_scheme().classes[0].rgb  # facing the light: full colour


def test_a_walk_is_drawn_and_named_in_the_legend_only_where_it_lies_in_the_picture(tmp_path: Path,
                                                                                   capsys: pytest.CaptureFixture[str]):
    from bimscan.survey.trajectory import Trajectory, write_trajectory

    cloud = _write(_room_cloud(), tmp_path / "room.laz")
    t = np.linspace(0.0, 8.0, 9)
    inside = Trajectory(t=t, xyz=np.column_stack([0.5 + 0.6 * t, np.full(9, 2.0), np.zeros(9)]), roll=np.zeros(9),
                        pitch=np.zeros(9), yaw=np.zeros(9), pass_id=np.zeros(9, dtype=np.int32))
    far = Trajectory(t=t, xyz=inside.xyz + [300.0, 0.0, 0.0], roll=inside.roll, pitch=inside.pitch, yaw=inside.yaw,
                     pass_id=inside.pass_id)
    size = {"width": 400, "height": 300}
    plain = render_cloud(cloud, tmp_path / "plain.png", **size)
    drawn = render_cloud(cloud, tmp_path / "drawn.png", trajectory=inside, **size)
    missed = render_cloud(cloud, tmp_path / "missed.png", trajectory=far, **size)
    assert drawn.walk_drawn and not missed.walk_drawn and not plain.walk_drawn
    assert (tmp_path / "drawn.png").read_bytes() != (tmp_path / "plain.png").read_bytes()
    # a walk off the picture adds nothing: no line, no legend entry, no title; the very bytes of the plain render
    assert (tmp_path / "missed.png").read_bytes() == (tmp_path / "plain.png").read_bytes()
    walk = write_trajectory(tmp_path / "elsewhere.csv", far)
    assert main(["render", str(cloud), str(tmp_path / "cli.png"), "--size", "400x300", "--trajectory", str(walk)]) == 0
    err = capsys.readouterr().err
    assert f"warning: the walk of {walk} lies outside" in err and "not drawn and not in the legend" in err
    assert (tmp_path / "cli.png").read_bytes() == (tmp_path / "plain.png").read_bytes()

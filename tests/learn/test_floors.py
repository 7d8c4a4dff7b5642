"""The floor under every point, from the points: every storey its own floor, ceilings and tables
never taken for one, the same map however the scene is streamed or where it lies."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.learn.floors import FloorMapBuilder

SHARED_REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "s3dis_area6"


def _plane(rng, x, y, z, n):
    return np.column_stack([rng.uniform(*x, n), rng.uniform(*y, n), np.full(n, z) + rng.normal(0, 0.003, n)])


def _wall(rng, x, y, z, n):
    return np.column_stack([rng.uniform(*x, n), rng.uniform(*y, n), rng.uniform(*z, n)])


def _outer_walls(rng, size, z, n=8_000):
    """The four walls around a (sx, sy) footprint, from z[0] to z[1]."""
    sx, sy = size
    return [_wall(rng, x, y, z, n) for x, y in (((0, sx), (0, 0.05)), ((0, sx), (sy - 0.05, sy)), ((0, 0.05), (0, sy)),
                                                  ((sx - 0.05, sx), (0, sy)))]


def _two_storeys(rng, *, ceiling_m, period_m, strips, upper_floor_m, upper_ceiling_m, size=(12.0, 8.0)):
    """Points of a two-storey box scanned inside: the ground floor at 0 and its ceiling, in every
    ``period_m`` across x the upper storey's ``strips`` ((start, stop) within the period, height,
    points) where its floor or what hides it shows, the upper ceiling, and both storeys' walls."""
    sx, sy = size
    parts = [_plane(rng, (0, sx), (0, sy), 0.0, 40_000), _plane(rng, (0, sx), (0, sy), ceiling_m, 40_000)]
    for x0 in np.arange(0.0, sx, period_m):
        for start, stop, z, n in strips:
            parts.append(_plane(rng, (x0 + start, x0 + stop), (0, sy), z, n))
    parts.append(_plane(rng, (0, sx), (0, sy), upper_ceiling_m, 40_000))
    for base, top in ((0.0, ceiling_m), (upper_floor_m, upper_ceiling_m)):
        parts.extend(_outer_walls(rng, size, (base, top)))
    return np.concatenate(parts)


def building(rng, *, storeys=3, storey_m=3.6, ceiling_m=2.8, size=(12.0, 8.0), table=True):
    """Points of a building scanned inside: per storey a floor, a ceiling under the next slab,
    the walls between them, and (optionally) a big table; returns points and the floor of each."""
    parts, floors = [], []
    sx, sy = size
    for k in range(storeys):
        base = k * storey_m
        parts.append(_plane(rng, (0, sx), (0, sy), base, 40_000))
        parts.append(_plane(rng, (0, sx), (0, sy), base + ceiling_m, 40_000))
        parts.extend(_outer_walls(rng, size, (base, base + ceiling_m)))
        if table:
            parts.append(_plane(rng, (1.0, 4.0), (1.0, 3.5), base + 0.75, 8_000))  # a big table
        floors.append(base)
    return np.concatenate(parts), floors


def floor_of(xyz, origin=None):
    builder = FloorMapBuilder(origin=origin)
    for start in range(0, len(xyz), 50_000):
        builder.add(xyz[start:start + 50_000])
    return builder.build()


def test_every_storey_gets_its_own_floor_and_ceilings_and_tables_are_not_floors():
    rng = np.random.default_rng(0)
    xyz, floors = building(rng)
    floor_map = floor_of(xyz)
    assert np.allclose(floor_map.scene_floors, floors, atol=0.06)
    height = xyz[:, 2] - floor_map.floor_under(xyz)
    storey = np.floor(xyz[:, 2] / 3.6 + 0.01)
    for k in range(3):
        in_storey = (storey == k) & (xyz[:, 2] > k * 3.6 - 0.1)
        assert np.all(height[in_storey] > -0.1) and np.all(height[in_storey] < 2.9)
    ceiling = np.abs(xyz[:, 2] % 3.6 - 2.8) < 0.02
    assert np.allclose(height[ceiling], 2.8, atol=0.08)  # a ceiling is 2.8 m above its own storey's floor


def test_the_map_is_the_same_however_the_scene_is_streamed_or_where_it_lies():
    rng = np.random.default_rng(1)
    xyz, _ = building(rng, storeys=2)
    origin = xyz.min(axis=0)  # the scene's origin (labelling takes its first chunk's corner)
    streamed = floor_of(xyz[rng.permutation(len(xyz))], origin)
    by_tiles = FloorMapBuilder(origin=origin)
    tile = np.floor(xyz[:, 0] / 2.0)
    for t in np.unique(tile):  # whole tile columns at a time, as labelling reads its stripes
        by_tiles.add_tiles(xyz[tile == t])
    by_tiles = by_tiles.build()
    assert np.array_equal(streamed.floor_under(xyz), by_tiles.floor_under(xyz))
    offset = np.array([512_345.678, 5_421_000.25, 312.0])  # georeferenced
    moved = floor_of(xyz + offset, origin + offset)
    difference = np.abs(moved.floor_under(xyz + offset) - offset[2] - streamed.floor_under(xyz))
    assert difference.max() < 1e-6  # counted from the scene's own origin, an offset moves nothing


def test_a_split_level_keeps_its_own_floor_and_a_scene_without_layers_falls_back():
    rng = np.random.default_rng(2)
    low = _plane(rng, (0, 6), (0, 8), 0.0, 30_000)
    high = _plane(rng, (6, 12), (0, 8), 1.2, 30_000)
    ceiling = _plane(rng, (0, 12), (0, 8), 3.8, 60_000)
    walls = _wall(rng, (0, 12), (0, 0.05), (0, 3.8), 20_000)
    step = _wall(rng, (5.98, 6.0), (0, 8), (0, 1.2), 5_000)
    # what stands on each level (cabinets, chairs): rises from its floor
    stuff = [_wall(rng, (x, x + 0.5), (y, y + 0.5), (z, z + 0.9), 400)
             for x in np.arange(0.5, 12, 1.5) for y in np.arange(0.5, 8, 1.5) for z in [0.0 if x < 6 else 1.2]]
    xyz = np.concatenate([low, high, ceiling, walls, step, *stuff])
    floor_map = floor_of(xyz)
    assert np.allclose(floor_map.floor_under(np.array([[3.0, 4.0, 1.0], [9.0, 4.0, 2.0]])), [0.0, 1.2], atol=0.06)
    scatter = rng.uniform(0, 5, (2_000, 3))  # no surface at all
    assert len(floor_of(scatter).floor_under(scatter)) == 2_000


def test_a_furnished_storey_over_a_thin_slab_gets_its_floor_and_the_ceiling_under_it_is_none():
    """A house: the upper floor 0.25 m over the ceiling under it (one run of dense bins), and
    most of it hidden by beds and cupboards (a quarter of the footprint shows)."""
    rng = np.random.default_rng(3)
    # upper storey: per 2 m strip, 0.5 m of floor shows and a bed hides the rest
    xyz = _two_storeys(rng, ceiling_m=2.8, period_m=2.0, strips=[(0.0, 0.5, 3.05, 3_000), (0.5, 2.0, 3.6, 6_000)],
                       upper_floor_m=3.05, upper_ceiling_m=5.85)
    floor_map = floor_of(xyz)
    assert np.allclose(floor_map.scene_floors, [0.0, 3.05], atol=0.06)
    floor = floor_map.floor_under(xyz)
    lower_ceiling = np.abs(xyz[:, 2] - 2.8) < 0.02
    upper = xyz[:, 2] > 3.0
    assert np.allclose(floor[lower_ceiling], 0.0, atol=0.06)  # a ceiling is no floor, however thin the slab over it
    assert np.allclose(floor[upper], 3.05, atol=0.06)  # beds, ceiling and walls upstairs stand on the upper floor


def test_a_slab_seen_from_both_sides_gives_its_top_as_the_floor():
    """A timber floor 0.3 m thick over a suspended ceiling 0.2 m under it: from below, the rays reach
    the slab's underside past the ceiling in some places; from above, the floor shows in others (a
    tripod sees little of a floor). Both look like a surface with room air over it and a ceiling just
    under it; the floor is the slab's top."""
    rng = np.random.default_rng(5)
    # per 3 m: the underside shows over 1 m, the floor top over 1.2 m
    xyz = _two_storeys(rng, ceiling_m=2.6, period_m=3.0, strips=[(0.0, 1.0, 2.9, 4_000), (1.6, 2.8, 3.2, 4_000)],
                       upper_floor_m=3.2, upper_ceiling_m=6.0)
    floor_map = floor_of(xyz)
    assert np.allclose(floor_map.scene_floors, [0.0, 3.2], atol=0.06)
    floor = floor_map.floor_under(xyz)
    upper = xyz[:, 2] > 3.1
    assert np.allclose(floor[upper], 3.2, atol=0.06)
    assert np.allclose(floor[np.abs(xyz[:, 2] - 2.9) < 0.02], 0.0, atol=0.06)  # the underside is the storey below's


def test_a_roof_terrace_is_a_floor_and_a_ceiling_over_lamps_is_not():
    rng = np.random.default_rng(4)
    parts = [_plane(rng, (0, 12), (0, 8), 0.0, 40_000), _plane(rng, (0, 12), (0, 8), 2.8, 40_000),
             _plane(rng, (0, 6), (0, 8), 3.2, 20_000)]  # the roof's top over half the storey, seen from a roof station
    for x in np.arange(7.0, 12.0, 2.0):  # lamps hanging under the ceiling of the other half
        for y in np.arange(1.0, 8.0, 2.0):
            parts.append(_plane(rng, (x, x + 0.6), (y, y + 0.6), 2.6, 300))
    parts.append(_wall(rng, (0, 12), (0, 0.05), (0.0, 2.8), 10_000))
    xyz = np.concatenate(parts)
    floor_map = floor_of(xyz)
    assert np.allclose(floor_map.scene_floors, [0.0, 3.2], atol=0.06)
    floor = floor_map.floor_under(xyz)
    ceiling = np.abs(xyz[:, 2] - 2.8) < 0.02
    roof = np.abs(xyz[:, 2] - 3.2) < 0.02
    assert np.allclose(floor[ceiling], 0.0, atol=0.06)
    assert np.allclose(floor[roof], 3.2, atol=0.06)


@pytest.mark.skipif(not SHARED_REAL.is_dir(), reason="the shared real rooms are absent (../shared/data/real)")
def test_real_rooms_get_their_floor_under_every_point():
    from bimscan.learn.data import iter_scene_chunks, list_scenes
    from bimscan.learn.train_config import DEFAULT_CLASS_NAMES

    slab = DEFAULT_CLASS_NAMES.index("Slab")
    covering = DEFAULT_CLASS_NAMES.index("Covering")
    for source in list_scenes([SHARED_REAL])[:4]:
        chunks = list(iter_scene_chunks(source, class_names=DEFAULT_CLASS_NAMES))
        xyz = np.concatenate([c.xyz for c in chunks])
        label = np.concatenate([c.label for c in chunks])
        height = xyz[:, 2] - floor_of(xyz).floor_under(xyz)
        assert abs(np.median(height[label == slab])) < 0.08, source.name
        assert 2.3 < np.median(height[label == covering]) < 3.2, source.name


def test_a_scanned_two_storey_house_gets_each_storeys_floor(tmp_path):
    """bimscan's own tripod scan of a furnished two-storey house: nearly every point takes the floor
    of the storey it is in (the floors the stations stood on), the upper storey's included."""
    import json

    from bimscan.ifc.generate import make_building
    from bimscan.pipeline import scan_model
    from bimscan.survey.recipe import ScanRecipe

    model = make_building(tmp_path / "house.ifc", seed=303, storeys=2, style="residential").path
    out = tmp_path / "scan"
    scan_model(model, out, ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0), progress=False)
    meta = json.loads((out / "meta.json").read_text())
    xyz = np.load(out / "coord.npy").astype(np.float64)
    station_floors = np.array([s["floor_z"] for s in meta["stations"]]) - meta["origin_m"][2]
    levels, count = np.unique(np.round(station_floors, 1), return_counts=True)
    storeys = levels[count >= 2]  # a landing's single station is no storey
    assert len(storeys) == 2
    truth = storeys[np.maximum(np.searchsorted(storeys, xyz[:, 2] + 0.15, side="right") - 1, 0)]
    found = floor_of(xyz).floor_under(xyz)
    assert np.mean(np.abs(found - truth) < 0.3) > 0.95


@pytest.mark.parametrize("roof_over_ceiling_m", [0.12, 0.15, 0.4])
def test_a_ceiling_just_under_a_roof_seen_from_above_keeps_the_floor_of_its_room(roof_over_ceiling_m: float):
    """A one-storey house with a station on its flat roof: the roof's top is a floor (what stands
    on it stands on it), and the ceiling a thin roof slab above it is the room's below, however
    close under the roof's top it lies: its height stays its room's, and it stays in its storey."""
    from bimscan.learn.floors import storey_of

    rng = np.random.default_rng(7)
    ceiling_m = 2.6
    roof_m = ceiling_m + roof_over_ceiling_m
    parts = [_plane(rng, (0, 12), (0, 8), 0.0, 40_000), _plane(rng, (0, 12), (0, 8), ceiling_m, 40_000),
             _plane(rng, (0, 12), (0, 8), roof_m, 30_000)]  # the roof's top, from the roof station
    parts.extend(_outer_walls(rng, (12.0, 8.0), (0.0, ceiling_m)))
    parts.append(_wall(rng, (0, 12), (-0.05, 0.0), (ceiling_m, roof_m + 0.9), 4_000))  # a parapet
    xyz = np.concatenate(parts)
    floor_map = floor_of(xyz)
    floor = floor_map.floor_under(xyz)
    ceiling = np.abs(xyz[:, 2] - ceiling_m) < 0.02
    roof = np.abs(xyz[:, 2] - roof_m) < 0.02
    walls = (xyz[:, 2] > 0.1) & (xyz[:, 2] < ceiling_m - 0.1)
    assert np.allclose(floor[ceiling], 0.0, atol=0.06)  # 2.6 m above its floor, not 0.1 under the roof
    assert np.allclose(floor[walls], 0.0, atol=0.06)
    assert np.allclose(floor[roof], roof_m, atol=0.06)
    storey = storey_of(floor_map, floor)
    assert (storey[ceiling] == storey[walls][0]).all()  # cut into the room's blocks, not the roof's


@pytest.mark.slow
def test_a_scanned_house_with_a_station_on_its_flat_roof_keeps_every_rooms_floor(tmp_path):
    """bimscan's scan of a one-storey house from every room and from its flat roof: the roof's top
    takes the roof as its floor, and the rooms' ceilings, walls and furniture keep the ground
    floor, exactly as they do without the roof station."""
    from bimscan.ifc.generate import make_building
    from bimscan.io import read_cloud, read_cloud_header
    from bimscan.pipeline import load_scene, scan_model
    from bimscan.survey.recipe import ScanRecipe

    model = make_building(tmp_path / "house.ifc", seed=11, storeys=1, style="residential").path
    scene = load_scene(model)
    roof = next(i for i, name in enumerate(scene.components.name) if name == "Roof slab")
    top = float(scene.mesh.vertices[scene.mesh.faces[scene.mesh.face_component == roof]].reshape(-1, 3)[:, 2].max())
    rooms = tmp_path / "rooms.laz"
    scan_model(model, rooms, ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0), progress=False)
    stations = [s.position for s in read_cloud_header(rooms).stations]
    csv = tmp_path / "stations.csv"
    centre = scene.mesh.vertices.mean(axis=0)
    csv.write_text("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in stations) + f"{centre[0]},{centre[1]},{top + 1.7}\n")
    both = tmp_path / "both.laz"
    scan_model(model, both, ScanRecipe.resolve(preset="exp1", head_deg_per_s=60.0, stations_from=str(csv)),
               progress=False)
    cloud = read_cloud(both)
    on_roof = cloud.station == len(stations)
    inside = ~on_roof
    origin = cloud.xyz.min(axis=0)
    found = floor_of(cloud.xyz, origin).floor_under(cloud.xyz)
    alone = floor_of(cloud.xyz[inside], origin).floor_under(cloud.xyz)  # the rooms' scan only
    roof_top = on_roof & (cloud.component == roof) & (np.abs(cloud.xyz[:, 2] - top) < 0.05)
    assert roof_top.sum() > 1000 and np.mean(np.abs(found[roof_top] - top) < 0.1) > 0.95
    assert np.mean(np.abs(found[inside] - alone[inside]) < 0.06) > 0.99

"""The clutter library: sizes within the cited ranges, closed meshes, variety by seed."""

from __future__ import annotations

import numpy as np
import pytest

from bimscan.errors import ConfigError
from bimscan.site.library import CLUTTER_KINDS, check_kinds, select_kinds
from bimscan.site.shapes import MeshBuilder, is_closed

KINDS = sorted(CLUTTER_KINDS)
HEADROOMS_M = (2.6, 3.0, 4.5)


def draws(kind: str, seeds: range = range(8)):
    """Objects of ``kind`` over seeds, headrooms and wall/free placements (None where it does not fit)."""
    for seed in seeds:
        for headroom in HEADROOMS_M:
            for against_wall in (False, True):
                yield CLUTTER_KINDS[kind].make(np.random.default_rng(seed), headroom, against_wall), headroom


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_keeps_to_its_cited_size_ranges(kind):
    ranges = np.array(CLUTTER_KINDS[kind].size_ranges_m)
    made = 0
    for obj, headroom in draws(kind):
        if obj is None:
            continue
        made += 1
        size = np.array(obj.size_m)
        assert (size >= ranges[:, 0] - 1e-9).all() and (size <= ranges[:, 1] + 1e-9).all(), (kind, size)
        assert size[2] <= headroom, (kind, size[2], headroom)
        lo, hi = obj.vertices.min(axis=0), obj.vertices.max(axis=0)
        assert np.allclose(lo[:2], -hi[:2]) and hi[2] == pytest.approx(size[2])  # footprint centred; top
        hung = obj.class_name == "Clutter.Whiteboard" and lo[2] > 0.5  # a board on a wall
        assert lo[2] == pytest.approx(0.0) or hung  # everything else stands on the floor
        assert obj.class_name in CLUTTER_KINDS[kind].class_names
    assert made >= 20


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_is_made_of_closed_consistently_oriented_shells(kind):
    for obj, _ in draws(kind, range(4)):
        if obj is not None:
            assert is_closed(obj.faces)
            assert obj.faces.dtype == np.int32 and obj.vertices.dtype == np.float64
            # outward winding: the signed volume of closed outward shells is positive
            v = obj.vertices[obj.faces]
            assert np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() > 0


def test_the_closedness_check_finds_a_hole():
    b = MeshBuilder()
    b.box((0, 0, 0), (1, 1, 1))
    _, faces = b.build()
    assert is_closed(faces) and not is_closed(faces[1:])  # a missing triangle
    assert not is_closed(np.concatenate([faces[:6], faces[6:, ::-1]]))  # half the sides turned inside out


@pytest.mark.parametrize("kind", KINDS)
def test_objects_vary_in_size_and_proportions_with_the_seed(kind):
    sizes = {tuple(np.round(obj.size_m, 3)) for obj, _ in draws(kind) if obj is not None}
    if kind == "prop":  # a prop's height is the headroom; its tubes' proportions vary
        shapes = {obj.vertices.round(4).tobytes() for obj, h in draws(kind) if obj is not None and h == 3.0}
        assert len(shapes) > 5
    else:
        assert len(sizes) > 5


@pytest.mark.parametrize("kind", KINDS)
def test_the_same_seed_gives_the_same_object(kind):
    a = CLUTTER_KINDS[kind].make(np.random.default_rng(7), 3.0, True)
    b = CLUTTER_KINDS[kind].make(np.random.default_rng(7), 3.0, True)
    assert (a is None) == (b is None)
    if a is not None:
        assert a.vertices.tobytes() == b.vertices.tobytes() and a.faces.tobytes() == b.faces.tobytes()


@pytest.mark.parametrize("kind, headroom", [("scaffold_tower", 1.5), ("person", 1.4), ("shelf", 0.8), ("prop", 0.9)])
def test_objects_that_cannot_stand_under_the_headroom_are_not_made(kind, headroom):
    assert all(CLUTTER_KINDS[kind].make(np.random.default_rng(s), headroom, False) is None for s in range(10))


def test_props_reach_just_below_the_soffit():
    prop = CLUTTER_KINDS["prop"].make(np.random.default_rng(0), 2.84, False)
    assert prop.size_m[2] == pytest.approx(2.835)


def test_people_are_standing_or_walking_and_walkers_stride():
    poses = {}
    for seed in range(20):
        person = CLUTTER_KINDS["person"].make(np.random.default_rng(seed), 3.0, False)
        poses.setdefault(person.class_name, []).append(person.size_m[1])
    assert set(poses) == {"Person.Standing", "Person.Walking"}
    assert min(poses["Person.Walking"]) > max(poses["Person.Standing"])  # a stride is longer than a foot


def test_kinds_and_groups_are_checked_and_expanded():
    assert {k.name for k in select_kinds(("office",))} == {"desk", "chair", "sofa", "shelf", "cabinet", "whiteboard"}
    assert {k.name for k in select_kinds(("people", "ladder"))} == {"person", "ladder"}
    with pytest.raises(ConfigError, match="unknown clutter kind 'chiar'"):
        check_kinds(("chiar",))


CEILING_KINDS = [k for k in KINDS if CLUTTER_KINDS[k].mount == "ceiling"]


@pytest.mark.parametrize("kind", CEILING_KINDS)
def test_nothing_under_a_ceiling_hangs_lower_than_the_clear_height(kind):
    from bimscan.site.library import MIN_CLEAR_UNDER_FIXTURE_M

    made = 0
    for seed in range(30):
        for headroom in (2.2, 2.5, 2.7, 3.0, 4.5):
            obj = CLUTTER_KINDS[kind].make(np.random.default_rng(seed), headroom, False)
            if obj is not None:
                made += 1
                assert headroom - obj.size_m[2] >= MIN_CLEAR_UNDER_FIXTURE_M - 1e-9, (kind, headroom, obj.size_m)
        assert CLUTTER_KINDS[kind].make(np.random.default_rng(seed), MIN_CLEAR_UNDER_FIXTURE_M, False) is None
    assert made >= 100


def test_ceiling_lights_are_grid_panels_or_pendants_that_hang_lower_under_higher_ceilings():
    from bimscan.site.library import CEILING_MODULES_M

    drops = {2.5: [], 3.5: []}
    panels = 0
    for seed in range(60):
        for headroom in drops:
            obj = CLUTTER_KINDS["ceiling_light"].make(np.random.default_rng(seed), headroom, False)
            if obj.size_m[2] > 0.2:  # a pendant: cables above the body
                drops[headroom].append(obj.size_m[2])
            else:
                panels += 1
                assert tuple(np.round(obj.size_m[:2], 4)) in {tuple(m) for m in CEILING_MODULES_M}
    assert panels > 30 and len(drops[3.5]) > 10
    assert not drops[2.5] or max(drops[2.5]) <= 0.4 + 1e-9  # 2.5 m leaves 0.4 m above the clear height
    assert np.mean(drops[3.5]) > 0.4


def test_the_ceiling_group_holds_the_fixtures_and_is_laid_out_not_drawn():
    assert {k.name for k in select_kinds(("ceiling",))} == {"ceiling_light", "downlight", "air_terminal"}
    for kind in select_kinds(("ceiling",)):
        low, high = kind.spacing_m
        assert 0 < low < high and 0 < kind.room_probability <= 1 and kind.mount == "ceiling"
    assert all(k.mount == "floor" for k in select_kinds(("office", "site", "people")))

"""``dress_scene``: a labelled scene turned into the scene as the site looks when scanned.

Order: the construction stage first (components not built are dropped; ceilings opened), then
props under the slabs of a fraction of the rooms (``props_fraction``), then clutter at the
requested density in every room, then the ceiling kinds (luminaires, air terminals) on a grid in
their share of the rooms, each object a new component (own GlobalId, a class of
``site.classes``, labelled by the scene's scheme). Stations are planned afterwards, on the
dressed scene, so they see the clutter (a tripod spot is kept clear in every room, and doors and
stairs stay clear).

Everything is seeded: the stage by GlobalIds and the seed; every room by its own generator
(the seed, the model's content hash and the room's GlobalId), so the same inputs give the same
bytes and one room's clutter does not depend on another's.
"""

from __future__ import annotations

import dataclasses
import time
import zlib
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bimscan.errors import ConfigError
from bimscan.ifc.guid import derived_global_id
from bimscan.progress import progress_bar
from bimscan.site.classes import SITE_CLASSES, site_class_ancestry
from bimscan.scan.probe import Prober
from bimscan.site.floor import component_mask, find_room_floors, keep_out_zones
from bimscan.site.library import CLUTTER_KINDS, ClutterKind, select_kinds
from bimscan.site.model import SiteModel, site_settings
from bimscan.site.placement import PlacedObject, RoomPlacer
from bimscan.site.stage import built_components, ceiling_coverings, cut_openings, open_ceilings
from bimscan.types import BimScene, BuildDates, ComponentSurfaces, ComponentTable, SceneMesh, SiteState

FULL_AFTER_MISSES = 8


@dataclass(frozen=True)
class DressTimings:
    """Seconds spent dressing a scene (not reproducible: kept out of the scene and its metadata)."""

    stage_s: float = 0.0
    floor_s: float = 0.0  # probing the free floor of every room
    placement_s: float = 0.0  # placing the objects
    rooms: int = 0
    cut_s: float = 0.0  # cutting the ceiling tiles where lay-in fittings sit
    # per room, in order: (name, objects placed, seconds placing them)
    per_room: tuple[tuple[str, int, float], ...] = ()

    @property
    def total_s(self) -> float:
        return self.stage_s + self.floor_s + self.placement_s + self.cut_s


def default_kinds(site: SiteModel) -> tuple[str, ...]:
    """The clutter kinds used when none are named: by the construction stage."""
    if site.clutter.kinds:
        return site.clutter.kinds
    return ("office", "ceiling", "people") if site.stage.name == "finished" else ("site", "people")


def dress_scene(scene: BimScene, site: SiteModel, *, seed: int, schedule: Mapping[str, BuildDates] | None = None,
                keep_clear: Sequence[tuple[float, float, float]] = (), threads: int = 0) -> BimScene:
    """The scene at ``site``'s construction stage with its clutter placed (see the module docs).

    schedule: GlobalId -> BuildDates from the model's work schedule (needed for ``stage.at``).
    keep_clear: spots (x, y, floor z) to keep free of clutter (stations given in a file). A bare
    site model (finished, no clutter) returns ``scene`` itself.
    """
    return dress_scene_timed(scene, site, seed=seed, schedule=schedule, keep_clear=keep_clear, threads=threads)[0]


def dress_scene_timed(scene: BimScene, site: SiteModel, *, seed: int,
                      schedule: Mapping[str, BuildDates] | None = None,
                      keep_clear: Sequence[tuple[float, float, float]] = (),
                      threads: int = 0, progress: bool = False) -> tuple[BimScene, DressTimings]:
    """``dress_scene`` and how long its parts took (``progress``: a bar over the rooms on a terminal)."""
    if site.is_bare:
        return scene, DressTimings()
    start = time.perf_counter()
    stage = site.stage
    keep = built_components(scene, stage, seed=seed, schedule=schedule)
    if not keep.any():
        raise ConfigError(f"{scene.source}: nothing of the model stands at stage {stage.name!r}"
                          + (f" on {stage.at}" if stage.at else "") + "; choose a later stage or date")
    mesh = open_ceilings(scene, keep, stage.ceilings_open_fraction, seed)
    staged = _subset(dataclasses.replace(scene, mesh=mesh), keep)
    removed = Counter(scene.components.ifc_class[~keep].tolist())
    stage_s = time.perf_counter() - start

    placed: list[PlacedObject] = []
    floor_s = placement_s = cut_s = 0.0
    per_room: list[tuple[str, int, float]] = []
    rooms_count, free_floor = 0, 0.0
    wants_props = stage.props_fraction > 0
    kinds = select_kinds(default_kinds(site)) if site.clutter.density > 0 else ()
    if wants_props or kinds:
        t0 = time.perf_counter()
        prober = Prober(staged.mesh, threads=threads)
        rooms = find_room_floors(staged, prober, zones=keep_out_zones(scene), keep_clear=keep_clear)
        floor_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        slabs = component_mask(staged, ("IfcSlab", "IfcRoof"))
        soffits = component_mask(staged, ("IfcSlab", "IfcRoof", "IfcCovering"))
        coverings = ceiling_coverings(staged)
        on_floor = tuple(k for k in kinds if k.mount == "floor")
        on_ceiling = tuple(k for k in kinds if k.mount == "ceiling")
        rooms_count = len(rooms)
        bar = progress_bar(total=len(rooms), desc="dressing rooms", unit="room", enabled=progress)
        for room in rooms:
            bar.update(1)
            room_start = time.perf_counter()
            free_floor += room.free_area_m2()
            rng = np.random.default_rng(np.random.SeedSequence(
                [seed, zlib.crc32(scene.file_sha256.encode()), zlib.crc32(room.key.encode())]))
            placer = RoomPlacer(room, prober, rng)
            if wants_props and rng.random() < stage.props_fraction:
                placer.place_prop_grid(CLUTTER_KINDS["prop"], slabs)
            if on_floor:
                _place_clutter(placer, on_floor, site.clutter.density * room.free_area_m2(), rng)
            for kind in on_ceiling:
                if rng.random() < kind.room_probability:
                    placer.place_ceiling_grid(kind, soffits, coverings)
            placed += placer.placed
            per_room.append((room.name, len(placer.placed), time.perf_counter() - room_start))
        bar.close()
        placement_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        openings = [p.footprint for p in placed if p.opening]
        if openings:  # lay-in fittings: the ceiling tiles are cut where they sit
            staged = dataclasses.replace(staged, mesh=cut_openings(staged.mesh, coverings, openings))
        cut_s = time.perf_counter() - t0
    if site.ground_margin_m > 0:
        from bimscan.site.ground import ground_patch, yard_objects

        placed.append(ground_patch(staged, site.ground_margin_m))
        if site.yard_density > 0:
            placed += yard_objects(staged, site.ground_margin_m, site.yard_density, seed)
    state = SiteState(settings=site_settings(site, seed), removed=dict(sorted(removed.items())),
                      placed=dict(sorted(Counter(p.class_name for p in placed).items())), rooms=rooms_count,
                      free_floor_m2=free_floor)
    dressed = _append(staged, placed, seed=seed)
    return dataclasses.replace(dressed, site=state), DressTimings(stage_s, floor_s, placement_s, rooms_count, cut_s,
                                                                  tuple(per_room))


def _place_clutter(placer: RoomPlacer, kinds: tuple[ClutterKind, ...], expected: float,
                   rng: np.random.Generator) -> None:
    """About ``expected`` objects (its fraction rounded at random), kinds drawn by weight, until the
    room is full (``FULL_AFTER_MISSES`` objects in a row found no place)."""
    target = int(expected) + int(rng.random() < expected - int(expected))
    weights = np.array([k.weight for k in kinds])
    weights = weights / weights.sum()
    misses = 0  # in a row: a room that refuses that many objects running is full
    while len(placer.placed) < target and misses < FULL_AFTER_MISSES:
        kind = kinds[int(rng.choice(len(kinds), p=weights))]
        misses = misses + 1 if placer.place_kind(kind) is None else 0


def _subset(scene: BimScene, keep: np.ndarray) -> BimScene:
    """The scene with only the components in ``keep`` (ids renumbered densely, unused vertices dropped)."""
    if keep.all():
        return scene
    new_id = np.cumsum(keep) - 1
    mesh = scene.mesh
    faces_kept = keep[mesh.face_component]
    faces = mesh.faces[faces_kept]
    used, inverse = np.unique(faces, return_inverse=True)
    table = scene.components
    columns = {f.name: None if getattr(table, f.name) is None else getattr(table, f.name)[keep]
               for f in dataclasses.fields(table) if f.name != "class_ancestry"}
    surfaces = scene.surfaces
    if surfaces is not None:
        surfaces = ComponentSurfaces(color=surfaces.color[keep], transparency=surfaces.transparency[keep],
                                     style=surfaces.style[keep], material=surfaces.material[keep])
    return dataclasses.replace(
        scene,
        mesh=SceneMesh(vertices=mesh.vertices[used], faces=inverse.reshape(-1, 3).astype(np.int32),
                       face_component=new_id[mesh.face_component[faces_kept]].astype(np.int32),
                       face_transparency=mesh.face_transparency_for(faces_kept)),
        components=ComponentTable(**columns, class_ancestry=table.class_ancestry), surfaces=surfaces,
    )


def _append(scene: BimScene, placed: list[PlacedObject], *, seed: int) -> BimScene:
    """The scene with every placed object as a new component, labelled by the scene's scheme."""
    from bimscan.semantics import map_labels

    if not placed:
        return scene
    table, mesh = scene.components, scene.mesh
    first = len(table)
    names: Counter[tuple[str, str]] = Counter()
    in_room: Counter[str] = Counter()
    rows: list[tuple[str, str, str, str, str]] = []
    for obj in placed:
        names[(obj.room, obj.kind)] += 1
        in_room[obj.room_key] += 1  # GlobalIds by room and rank in it: other rooms' objects do not move them
        global_id = derived_global_id("bimscan-site", scene.file_sha256, seed, obj.room_key, in_room[obj.room_key])
        name = f"{obj.kind} {names[(obj.room, obj.kind)]} in {obj.room}".strip()
        rows.append((global_id, obj.class_name, obj.kind, name, obj.storey))
    gid, cls, kind, name, storey = (np.array(c, dtype=str) for c in zip(*rows))
    ifc_ancestry = {c: table.class_ancestry.get(c, (c,)) for s in SITE_CLASSES.values() for c in s.ifc_classes}
    if any(len(v) == 1 for v in ifc_ancestry.values()):
        from bimscan.ifc.schema import class_ancestry

        ifc_ancestry = {c: class_ancestry(scene.schema, c) for c in ifc_ancestry}
    ancestry = dict(table.class_ancestry) | {c: site_class_ancestry(c, ifc_ancestry) for c in sorted(set(cls))}
    added = ComponentTable(global_id=gid, ifc_class=cls, predefined_type=np.char.upper(kind), name=name,
                           storey=storey, parent_class=np.full(len(rows), "", dtype=str),
                           label=np.zeros(len(rows), dtype=np.uint8), class_ancestry=ancestry)
    mapping = map_labels(added, scene.scheme)
    columns = {}
    for f in dataclasses.fields(table):
        if f.name == "class_ancestry":
            continue
        if getattr(table, f.name) is None:  # an optional column the model does not have (STEP ids)
            columns[f.name] = None
            continue
        values = mapping.labels if f.name == "label" else getattr(added, f.name)
        if values is None:  # STEP ids: the objects are not in the IFC file
            values = np.full(len(rows), -1, dtype=getattr(table, f.name).dtype)
        columns[f.name] = np.concatenate([getattr(table, f.name), values])
    offsets = np.cumsum([0] + [len(p.vertices) for p in placed]) + len(mesh.vertices)
    vertices = np.concatenate([mesh.vertices] + [p.vertices for p in placed])
    faces = np.concatenate([mesh.faces] + [p.faces + offsets[k] for k, p in enumerate(placed)]).astype(np.int32)
    face_component = np.concatenate([mesh.face_component] + [np.full(len(p.faces), first + k, dtype=np.int32)
                                                             for k, p in enumerate(placed)])
    unmapped = Counter(dict(scene.unmapped_classes))
    unmapped.update(mapping.unmapped)
    surfaces = scene.surfaces
    if surfaces is not None:  # the objects have no style: the sensor's material table goes by their IFC class
        more = ComponentSurfaces.unknown(len(placed))
        surfaces = ComponentSurfaces(
            color=np.concatenate([surfaces.color, more.color]),
            transparency=np.concatenate([surfaces.transparency, more.transparency]),
            style=np.concatenate([surfaces.style, more.style]), material=np.concatenate([surfaces.material, more.material]))
    mesh = SceneMesh(vertices=vertices, faces=faces, face_component=face_component,
                     face_transparency=mesh.face_transparency_for(added=len(faces) - len(mesh.faces)))
    return dataclasses.replace(scene, mesh=mesh,
                               components=ComponentTable(**columns, class_ancestry=ancestry),
                               unmapped_classes=dict(sorted(unmapped.items())), surfaces=surfaces)

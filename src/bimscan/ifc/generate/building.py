"""Procedural demo buildings as valid IFC4 files: ``make_building``.

The embedded default of bimscan: the quickstart, the demo dataset and most tests scan these
buildings. Each is a seeded double-loaded corridor block (see ``layout.py`` for the
plan rules) authored with ``ifcopenshell.api``: project, site, building, storeys in metres;
exterior and interior walls with door and window openings cut by IfcOpeningElements and filled
with parametric doors and windows; a column grid with downstand beams under every slab; floor,
base and roof slabs; a half-turn stair (flights, landing, railings) through a slab opening;
ceiling coverings under the slabs; furniture; and one IfcSpace per room for station planning.
Shapes the api has no function for (stair flights, furniture, railings) are built with
IfcOpenShell's ShapeBuilder, as the api itself does.

Every GlobalId derives from (seed, storeys, counter) and the header timestamp is fixed, so the
same options give the same bytes.
"""

from __future__ import annotations

import contextlib

import hashlib
import uuid
from collections import Counter
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import ifcopenshell
import ifcopenshell.api as api
import ifcopenshell.api.aggregate
import ifcopenshell.api.context
import ifcopenshell.api.feature
import ifcopenshell.api.geometry
import ifcopenshell.api.profile
import ifcopenshell.api.project
import ifcopenshell.api.root
import ifcopenshell.api.spatial
import ifcopenshell.api.unit
import ifcopenshell.guid
import numpy as np
from ifcopenshell.util.shape_builder import ShapeBuilder

from bimscan.files import atomic_output
from bimscan.errors import ConfigError, OutputError
from bimscan.ifc.generate.layout import (
    CEILING_M,
    LANDING_DEPTH_M,
    MAX_STOREYS,
    MIN_STOREYS,
    BuildingPlan,
    FurniturePlan,
    OpeningPlan,
    Rect,
    RoomPlan,
    StairPlan,
    StoreyPlan,
    WallPlan,
    plan_building,
)

# Fixed header fields: the file's bytes must not depend on when or where it was made.
HEADER_TIMESTAMP = "2024-01-01T00:00:00"
HEADER_ORGANISATION = "bimscan"
MAX_SEED = 2**63 - 1


@dataclass(frozen=True)
class GeneratedBuilding:
    """What ``make_building`` produced.

    placed: exact IFC class -> number of instances placed with body geometry (IfcSpace and
        IfcOpeningElement excluded), e.g. {"IfcWall": 40, "IfcSlab": 5, ...}.
    rooms_per_storey: IfcSpace count per storey, bottom up.
    storey_elevations_m: floor slab top of each storey, world Z in metres.
    footprint_m: (xmin, ymin, xmax, ymax) of the exterior walls' outer faces, metres.
    height_m: top of the roof slab, world Z in metres (ground floor slab top at 0).
    """

    path: Path | None
    seed: int
    storeys: int
    placed: Mapping[str, int]
    rooms_per_storey: tuple[int, ...]
    storey_elevations_m: tuple[float, ...]
    footprint_m: tuple[float, float, float, float]
    height_m: float


def check_building_options(*, seed: int, storeys: int) -> None:
    """Raise ConfigError unless ``seed`` is an integer in [0, 2**63) and ``storeys`` in 1..10."""
    if not _is_int(seed) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"seed must be an integer from 0 to {MAX_SEED}, got {seed!r}; pass a non-negative integer")
    if not _is_int(storeys) or not MIN_STOREYS <= storeys <= MAX_STOREYS:
        raise ConfigError(
            f"storeys must be an integer in {MIN_STOREYS}..{MAX_STOREYS}, got {storeys!r}; "
            f"pick a number of storeys in that range"
        )


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def make_building(path: str | Path | None = None, *, seed: int = 0, storeys: int = 2) -> GeneratedBuilding:
    """Generate a seeded demo building; write it as IFC4 to ``path`` when given.

    The file is written atomically (a temporary file in the same folder, then renamed), so a
    failure never leaves a half-written file. Same (seed, storeys) -> same bytes.

    Raises ConfigError for a bad seed or storey count, OutputError when ``path``'s folder is
    missing, ``path`` does not end in ``.ifc``, or the file cannot be written.
    """
    check_building_options(seed=seed, storeys=storeys)
    target = Path(path) if path is not None else None
    if target is not None:
        _check_output_path(target)
    model, building = build_building_model(seed=seed, storeys=storeys)
    if target is None:
        return building
    _write_atomically(target, model.to_string())
    return replace(building, path=target)


def build_building_model(*, seed: int = 0, storeys: int = 2) -> tuple[ifcopenshell.file, GeneratedBuilding]:
    """The seeded building as an in-memory ``ifcopenshell.file`` plus its summary (path None)."""
    check_building_options(seed=seed, storeys=storeys)
    seed, storeys = int(seed), int(storeys)
    plan = plan_building(seed=seed, storeys=storeys)
    with _no_owner_history():
        author = _Author(plan, name=f"bimscan-building-seed{seed}-storeys{storeys}")
        author.add_building()
    author.sort_unordered_sets()
    author.assign_global_ids(seed=seed, storeys=storeys)
    summary = GeneratedBuilding(
        path=None,
        seed=seed,
        storeys=storeys,
        placed=author.count_placed(),
        rooms_per_storey=tuple(len(s.rooms) for s in plan.storeys),
        storey_elevations_m=tuple(s.elevation_m for s in plan.storeys),
        footprint_m=(0.0, 0.0, plan.width_m, plan.depth_m),
        height_m=round(plan.height_m, 6),
    )
    return author.model, summary


@contextlib.contextmanager
def _no_owner_history() -> Iterator[None]:
    """Author without IfcOwnerHistory even if the process configured ifcopenshell.api's owner
    callbacks (they stamp the current time into the file, which would break same seed, same bytes)."""
    import ifcopenshell.api.owner.settings as owner

    saved = owner.get_user, owner.get_application
    owner.get_user = owner.get_application = lambda file: None
    try:
        yield
    finally:
        owner.get_user, owner.get_application = saved


def _check_output_path(target: Path) -> None:
    if target.suffix.lower() != ".ifc":
        raise OutputError(f"output file must end in .ifc, got {str(target)!r}; name it like building.ifc")
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise OutputError(f"output folder {str(folder)!r} does not exist; create it first or choose another path")
    if target.is_dir():
        raise OutputError(f"output path {str(target)!r} is a folder; give a file name ending in .ifc")


def _write_atomically(target: Path, text: str) -> None:
    """Write to a fresh temporary name beside ``target``, then rename over it."""
    try:
        with atomic_output(target) as temp, temp.open("x", encoding="utf-8", newline="\n") as out:
            out.write(text)
    except OSError as exc:
        raise OutputError(
            f"could not write {str(target)!r}: {exc.strerror or exc}; check the folder's permissions and free space"
        ) from exc


def _frame(origin: Sequence[float], x_axis: Sequence[float] = (1.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 placement matrix: Z up, local X along ``x_axis`` (horizontal), at ``origin`` (metres)."""
    x = np.asarray(x_axis, dtype=float)
    z = np.array([0.0, 0.0, 1.0])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, origin
    return m


def _translate(matrix: np.ndarray, local: Sequence[float]) -> np.ndarray:
    """``matrix`` moved by ``local`` (metres) along its own axes."""
    out = matrix.copy()
    out[:3, 3] = matrix[:3, :3] @ np.asarray(local, dtype=float) + matrix[:3, 3]
    return out


Box = tuple[float, float, float, float, float, float]  # x, y, z, size_x, size_y, size_z (metres)


def _rect_polyline(width: float, depth: float) -> list[tuple[float, float]]:
    return [(0.0, 0.0), (width, 0.0), (width, depth), (0.0, depth), (0.0, 0.0)]


class _Author:
    """Writes one BuildingPlan into a fresh IFC4 model, element by element, via ifcopenshell.api."""

    def __init__(self, plan: BuildingPlan, *, name: str) -> None:
        self.plan = plan
        model = api.project.create_file(version="IFC4")
        header = model.header.file_name
        header.name = f"{name}.ifc"
        header.time_stamp = HEADER_TIMESTAMP
        header.author = ("bimscan make-building",)
        header.organization = (HEADER_ORGANISATION,)
        header.authorization = "none"
        self.model = model
        self.builder = ShapeBuilder(model)
        self.project = api.root.create_entity(model, ifc_class="IfcProject", name="bimscan demo building")
        units = [
            api.unit.add_si_unit(model, unit_type="LENGTHUNIT"),
            api.unit.add_si_unit(model, unit_type="AREAUNIT"),
            api.unit.add_si_unit(model, unit_type="VOLUMEUNIT"),
            api.unit.add_si_unit(model, unit_type="PLANEANGLEUNIT"),
        ]
        api.unit.assign_unit(model, units=units)
        model3d = api.context.add_context(model, context_type="Model")
        self.body = api.context.add_context(
            model, context_type="Model", context_identifier="Body", target_view="MODEL_VIEW", parent=model3d
        )
        self._column_profile: ifcopenshell.entity_instance | None = None
        self._beam_profile: ifcopenshell.entity_instance | None = None

    # -- generic helpers ------------------------------------------------------------------

    def _element(
        self,
        ifc_class: str,
        *,
        name: str,
        matrix: np.ndarray,
        predefined_type: str | None = None,
        representation: ifcopenshell.entity_instance | None = None,
        container: ifcopenshell.entity_instance | None = None,
        whole: ifcopenshell.entity_instance | None = None,
    ) -> ifcopenshell.entity_instance:
        """Create a product, give it a body, relate it (container or aggregate), then place it.

        Placement comes last because the api places a product relative to its container.
        """
        element = api.root.create_entity(self.model, ifc_class=ifc_class, predefined_type=predefined_type, name=name)
        if representation is not None:
            api.geometry.assign_representation(self.model, product=element, representation=representation)
        if container is not None:
            api.spatial.assign_container(self.model, products=[element], relating_structure=container)
        if whole is not None:
            api.aggregate.assign_object(self.model, products=[element], relating_object=whole)
        api.geometry.edit_object_placement(self.model, product=element, matrix=matrix)
        return element

    def _boxes(self, boxes: Sequence[Box]) -> ifcopenshell.entity_instance:
        """One body of axis-aligned boxes (x, y, z, size_x, size_y, size_z) in local metres."""
        items = []
        for x, y, z, sx, sy, sz in boxes:
            rect = self.builder.rectangle(size=(sx, sy), position=(x, y))
            items.append(self.builder.extrude(rect, sz, position=(0.0, 0.0, z)))
        return self.builder.get_representation(self.body, items)

    def _slab_body(self, width: float, depth: float, thickness: float) -> ifcopenshell.entity_instance:
        return api.geometry.add_slab_representation(
            self.model, context=self.body, depth=thickness, polyline=_rect_polyline(width, depth)
        )

    # -- the building ---------------------------------------------------------------------

    def add_building(self) -> None:
        plan = self.plan
        site = self._element("IfcSite", name="Site", matrix=np.eye(4), whole=self.project)
        building = self._element("IfcBuilding", name="Demo building", matrix=np.eye(4), whole=site)
        storeys = []
        for storey_plan in plan.storeys:
            z = storey_plan.elevation_m
            name = _storey_name(storey_plan.index)
            storey = self._element("IfcBuildingStorey", name=name, matrix=_frame((0, 0, z)), whole=building)
            storey.Elevation = z
            storeys.append(storey)
        for storey, storey_plan in zip(storeys, plan.storeys):
            self.add_storey(storey, storey_plan)
        top = plan.storeys[-1]
        self._element(
            "IfcSlab",
            name="Roof slab",
            predefined_type="ROOF",
            representation=self._slab_body(plan.width_m, plan.depth_m, plan.slab_m),
            matrix=_frame((0.0, 0.0, plan.height_m - plan.slab_m)),
            container=storeys[-1],
        )
        if plan.stair is not None:
            self.add_guard(storeys[-1], plan.stair, top.elevation_m)

    def add_storey(self, storey: ifcopenshell.entity_instance, sp: StoreyPlan) -> None:
        plan = self.plan
        z = sp.elevation_m
        ceiling_z = z + plan.clear_height_m  # underside of the slab above
        slab = self._element(
            "IfcSlab",
            name=f"Floor slab {sp.index}",
            predefined_type="BASESLAB" if sp.index == 0 else "FLOOR",
            representation=self._slab_body(plan.width_m, plan.depth_m, plan.slab_m),
            matrix=_frame((0.0, 0.0, z - plan.slab_m)),
            container=storey,
        )
        if sp.index > 0 and plan.stair is not None:
            self.add_slab_opening(slab, plan.stair.opening, z)
        for wall in sp.walls:
            self.add_wall(storey, wall, z)
        for i, rect in enumerate(plan.column_rects()):
            self.add_column(storey, rect, z, name=f"Column {sp.index}.{i:02d}")
        for i, rect in enumerate(plan.beam_rects()):
            self.add_beam(storey, rect, ceiling_z, name=f"Beam {sp.index}.{i:02d}")
        for room in sp.rooms:
            self.add_space(storey, room, z)
            if room.has_ceiling:
                self.add_ceiling(storey, room, ceiling_z)
        for piece in sp.furniture:
            self.add_furniture(storey, piece, z)
        if plan.stair is not None and sp.index < len(plan.storeys) - 1:
            self.add_stair(storey, plan.stair, z, index=sp.index)

    def add_wall(self, storey: ifcopenshell.entity_instance, wall: WallPlan, z: float) -> None:
        start, end = np.array(wall.start), np.array(wall.end)
        direction = (end - start) / wall.length_m
        normal = np.array([-direction[1], direction[0]])
        # The api's wall body spans local y in [0, thickness]: shift the frame by half the
        # thickness so the plan's centre line is the wall's centre line.
        origin = start - normal * wall.thickness_m / 2
        matrix = _frame((origin[0], origin[1], z), (direction[0], direction[1], 0.0))
        body = api.geometry.add_wall_representation(
            self.model,
            context=self.body,
            length=wall.length_m,
            height=self.plan.clear_height_m,
            thickness=wall.thickness_m,
        )
        element = self._element(
            "IfcWall",
            name=f"Wall {wall.name}",
            predefined_type="SOLIDWALL" if wall.exterior else "PARTITIONING",
            representation=body,
            matrix=matrix,
            container=storey,
        )
        for opening in wall.openings:
            self.add_filled_opening(storey, element, opening, matrix, wall.thickness_m)

    def add_filled_opening(
        self,
        storey: ifcopenshell.entity_instance,
        wall: ifcopenshell.entity_instance,
        opening: OpeningPlan,
        wall_matrix: np.ndarray,
        thickness: float,
    ) -> None:
        """Cut ``opening`` out of ``wall`` and fill it with a parametric door or window."""

        # The void overshoots the wall on both faces (and below the floor line for doors), so the
        # boolean never leaves a skin of coplanar faces.
        below = 0.05 if opening.sill_m == 0.0 else 0.0
        void_body = api.geometry.add_wall_representation(
            self.model,
            context=self.body,
            length=opening.width_m,
            height=opening.height_m + below,
            thickness=thickness + 0.2,
            offset=-0.1,
        )
        void = api.root.create_entity(
            self.model, ifc_class="IfcOpeningElement", predefined_type="OPENING", name=f"Opening for {opening.name}"
        )
        api.geometry.assign_representation(self.model, product=void, representation=void_body)
        api.feature.add_feature(self.model, feature=void, element=wall)
        api.geometry.edit_object_placement(
            self.model, product=void, matrix=_translate(wall_matrix, (opening.offset_m, 0.0, opening.sill_m - below))
        )
        if opening.kind == "door":
            body = api.geometry.add_door_representation(
                self.model,
                context=self.body,
                overall_width=opening.width_m,
                overall_height=opening.height_m,
                operation_type="SINGLE_SWING_LEFT",
                # The lining wraps the whole wall; its casings stand 5 mm proud of both faces.
                lining_properties={"LiningDepth": thickness, "LiningToPanelOffsetY": 0.04},
            )
            ifc_class, predefined = "IfcDoor", "DOOR"
        else:
            # A frame 0.1 m deep in the middle of the wall leaves reveals on both faces; wide
            # windows get a central mullion and two panels.
            depth, panels = 0.1, 2 if opening.width_m > 1.5 else 1
            body = api.geometry.add_window_representation(
                self.model,
                context=self.body,
                overall_width=opening.width_m,
                overall_height=opening.height_m,
                partition_type="DOUBLE_PANEL_VERTICAL" if panels == 2 else "SINGLE_PANEL",
                lining_properties={
                    "LiningDepth": depth,
                    "LiningOffset": (thickness - depth) / 2,
                    "FirstMullionOffset": opening.width_m / 2,
                },
                panel_properties=[{} for _ in range(panels)],
            )
            ifc_class, predefined = "IfcWindow", "WINDOW"
        filling = api.root.create_entity(
            self.model, ifc_class=ifc_class, predefined_type=predefined, name=opening.name.capitalize()
        )
        filling.OverallWidth = opening.width_m
        filling.OverallHeight = opening.height_m
        api.geometry.assign_representation(self.model, product=filling, representation=body)
        api.spatial.assign_container(self.model, products=[filling], relating_structure=storey)
        api.feature.add_filling(self.model, opening=void, element=filling)
        api.geometry.edit_object_placement(
            self.model, product=filling, matrix=_translate(wall_matrix, (opening.offset_m, 0.0, opening.sill_m))
        )

    def add_slab_opening(self, slab: ifcopenshell.entity_instance, rect: Rect, z: float) -> None:
        void = api.root.create_entity(
            self.model, ifc_class="IfcOpeningElement", predefined_type="OPENING", name="Stair opening"
        )
        body = self._slab_body(rect.width, rect.depth, self.plan.slab_m + 0.2)
        api.geometry.assign_representation(self.model, product=void, representation=body)
        api.feature.add_feature(self.model, feature=void, element=slab)
        matrix = _frame((rect.x0, rect.y0, z - self.plan.slab_m - 0.1))
        api.geometry.edit_object_placement(self.model, product=void, matrix=matrix)

    def add_column(self, storey: ifcopenshell.entity_instance, rect: Rect, z: float, *, name: str) -> None:
        if self._column_profile is None:
            profile = api.profile.add_parameterized_profile(self.model, ifc_class="IfcRectangleProfileDef")
            profile.ProfileName = f"{self.plan.column_m:.2f} x {self.plan.column_m:.2f} column"
            profile.XDim = profile.YDim = self.plan.column_m
            self._column_profile = profile
        body = api.geometry.add_profile_representation(
            self.model, context=self.body, profile=self._column_profile, depth=self.plan.clear_height_m
        )
        cx, cy = rect.centre
        matrix = _frame((cx, cy, z))
        self._element(
            "IfcColumn", name=name, predefined_type="COLUMN", representation=body, matrix=matrix, container=storey
        )

    def add_beam(self, storey: ifcopenshell.entity_instance, rect: Rect, ceiling_z: float, *, name: str) -> None:
        """A downstand beam along Y hanging from the slab underside at ``ceiling_z``."""

        plan = self.plan
        if self._beam_profile is None:
            profile = api.profile.add_parameterized_profile(self.model, ifc_class="IfcRectangleProfileDef")
            profile.ProfileName = f"{plan.beam_width_m:.2f} x {plan.beam_depth_m:.2f} beam"
            profile.XDim, profile.YDim = plan.beam_width_m, plan.beam_depth_m
            self._beam_profile = profile
        body = api.geometry.add_profile_representation(
            self.model, context=self.body, profile=self._beam_profile, depth=rect.depth
        )
        # Local Z (the extrusion) runs along the beam (+Y), local X across it (+X); the profile
        # is centred on the axis, which sits half a beam depth below the slab.
        matrix = np.eye(4)
        matrix[:3, 0] = (1.0, 0.0, 0.0)
        matrix[:3, 1] = (0.0, 0.0, -1.0)
        matrix[:3, 2] = (0.0, 1.0, 0.0)
        matrix[:3, 3] = (rect.centre[0], rect.y0, ceiling_z - plan.beam_depth_m / 2)
        self._element(
            "IfcBeam", name=name, predefined_type="BEAM", representation=body, matrix=matrix, container=storey
        )

    def add_space(self, storey: ifcopenshell.entity_instance, room: RoomPlan, z: float) -> None:
        space = self._element(
            "IfcSpace",
            name=room.number,
            predefined_type="INTERNAL",
            representation=self._slab_body(room.rect.width, room.rect.depth, self.plan.clear_height_m),
            matrix=_frame((room.rect.x0, room.rect.y0, z)),
            whole=storey,
        )
        space.LongName = room.kind.capitalize()

    def add_ceiling(self, storey: ifcopenshell.entity_instance, room: RoomPlan, ceiling_z: float) -> None:
        """A thin finish layer directly under the slab: beams below it stay in view."""
        self._element(
            "IfcCovering",
            name=f"Ceiling {room.number}",
            predefined_type="CEILING",
            representation=self._slab_body(room.rect.width, room.rect.depth, CEILING_M),
            matrix=_frame((room.rect.x0, room.rect.y0, ceiling_z - CEILING_M)),
            container=storey,
        )

    def add_furniture(self, storey: ifcopenshell.entity_instance, piece: FurniturePlan, z: float) -> None:
        """A table, cabinet or shelf as boxes, its front towards ``piece.facing``."""
        fx, fy = piece.facing
        r = piece.rect
        width, deep = (r.width, r.depth) if fy != 0 else (r.depth, r.width)
        boxes = _furniture_boxes(piece.kind, width, deep, piece.height_m)
        # Local +y points from the front to the back, local x = y cross z.
        back = np.array([-fx, -fy, 0.0])
        x_axis = np.cross(back, (0.0, 0.0, 1.0))
        corners = np.array([[0, 0], [width, 0], [0, deep], [width, deep]], dtype=float)
        world = corners[:, :1] * x_axis[:2] + corners[:, 1:] * back[:2]
        origin = np.array([r.x0, r.y0]) - world.min(axis=0)
        predefined = {"table": "TABLE", "cabinet": "FILECABINET", "shelf": "SHELF"}[piece.kind]
        self._element(
            "IfcFurniture",
            name=piece.name.capitalize(),
            predefined_type=predefined,
            representation=self._boxes(boxes),
            matrix=_frame((origin[0], origin[1], z), tuple(x_axis)),
            container=storey,
        )

    def add_stair(self, storey: ifcopenshell.entity_instance, stair: StairPlan, z: float, *, index: int) -> None:
        """The half-turn stair from this storey to the next: two flights, a landing, a railing."""
        plan = self.plan
        half = plan.storey_height_m / 2
        whole = self._element(
            "IfcStair",
            name=f"Stair {index}",
            predefined_type="HALF_TURN_STAIR",
            matrix=_frame((0, 0, z)),
            container=storey,
        )
        r, h, g = stair.risers_per_flight, stair.riser_m, stair.going_m
        w1 = stair.flight1_y[1] - stair.flight1_y[0]
        w2 = stair.flight2_y[1] - stair.flight2_y[0]
        flight1 = self._flight_body(r, h, g, w1)
        self._element(
            "IfcStairFlight",
            name=f"Stair {index} flight 1",
            predefined_type="STRAIGHT",
            representation=flight1,
            matrix=_frame((stair.x_start_m, stair.flight1_y[0], z)),
            whole=whole,
        )
        # Flight 2 runs back along -X; its local y (z cross x) then points to -Y.
        flight2 = self._flight_body(r, h, g, w2)
        self._element(
            "IfcStairFlight",
            name=f"Stair {index} flight 2",
            predefined_type="STRAIGHT",
            representation=flight2,
            matrix=_frame((stair.x_landing_m, stair.flight2_y[1], z + half), (-1.0, 0.0, 0.0)),
            whole=whole,
        )
        landing = stair.opening
        self._element(
            "IfcSlab",
            name=f"Stair {index} landing",
            predefined_type="LANDING",
            representation=self._slab_body(stair.x_end_m - stair.x_landing_m, landing.depth, LANDING_DEPTH_M),
            matrix=_frame((stair.x_landing_m, landing.y0, z + half - LANDING_DEPTH_M)),
            whole=whole,
        )
        self._element(
            "IfcRailing",
            name=f"Stair {index} handrail",
            predefined_type="HANDRAIL",
            representation=self._handrail_body(stair),
            matrix=_frame((0.0, 0.0, z)),
            whole=whole,
        )

    def _flight_body(self, risers: int, riser: float, going: float, width: float) -> ifcopenshell.entity_instance:
        """Stepped solid of one straight flight of ``risers`` risers; local X up the flight,
        extruded along local +Y by ``width``.

        The flight holds ``risers - 1`` risers and treads; its last riser is the front edge of the
        landing or slab it steps onto (both are deeper than a riser). A sloping soffit runs
        ``waist`` below the inner corners of the steps.
        """
        waist = 0.18  # vertical depth of the structure below the inner corners of the steps
        points = [(0.0, 0.0)]
        for i in range(risers - 1):
            points += [(i * going, (i + 1) * riser), ((i + 1) * going, (i + 1) * riser)]
        last = (risers - 1) * going
        points += [(last, (risers - 1) * riser - waist), (waist * going / riser, 0.0)]
        profile = self.builder.polyline(points, closed=True)
        solid = self.builder.extrude(profile, width, **self.builder.extrude_kwargs("Y"))
        return self.builder.get_representation(self.body, [solid])

    def _handrail_body(self, stair: StairPlan) -> ifcopenshell.entity_instance:
        """Posts and a sloping rail along the inner edge of each flight (the gap between them),
        in world X/Y and Z relative to the storey floor."""
        r, h, g = stair.risers_per_flight, stair.riser_m, stair.going_m
        half = r * h
        rail, post = 0.05, 0.04
        items = []
        for y_edge, x0, sign, z0 in (
            (stair.flight1_y[0] + 0.02, stair.x_start_m, 1.0, 0.0),
            (stair.flight2_y[1] - 0.02 - post, stair.x_landing_m, -1.0, half),
        ):
            # Rail top 0.9 m above the nosing line z = h + (distance up the flight) * h / g.
            def top(distance: float) -> float:
                return z0 + h + distance * h / g + 0.9

            run = (r - 1) * g
            xa, xb = x0, x0 + sign * run
            xs = sorted((xa, xb))
            za, zb = (top(0.0), top(run)) if sign > 0 else (top(run), top(0.0))
            bar = self.builder.polyline(
                [(xs[0], za - rail), (xs[1], zb - rail), (xs[1], zb), (xs[0], za)], closed=True
            )
            items.append(self.builder.extrude(bar, post, position=(0.0, y_edge, 0.0), **_y_extrusion()))
            for step in sorted({0, (r - 2) // 2, r - 2}):
                distance = step * g + g / 2
                x = x0 + sign * distance - post / 2
                floor = z0 + (step + 1) * h
                rect = self.builder.rectangle(size=(post, post), position=(x, y_edge))
                height = top(distance) - rail - floor + 0.01  # into the rail, so post and rail join
                items.append(self.builder.extrude(rect, height, position=(0.0, 0.0, floor)))
        return self.builder.get_representation(self.body, items)

    def add_guard(self, storey: ifcopenshell.entity_instance, stair: StairPlan, z: float) -> None:
        """Guard rail on the top storey where the stair void of flight 1 meets the floor."""
        y0, y1 = stair.flight2_y[1], stair.flight1_y[1]
        x = stair.x_start_m - 0.05
        posts = [(x, y, 0.0, 0.04, 0.04, 1.0) for y in (y0, (y0 + y1) / 2 - 0.02, y1 - 0.04)]
        rails = [(x, y0, 0.96, 0.05, y1 - y0, 0.05), (x, y0, 0.5, 0.04, y1 - y0, 0.03)]
        boxes = posts + rails
        self._element(
            "IfcRailing",
            name="Stair void guard",
            predefined_type="GUARDRAIL",
            representation=self._boxes(boxes),
            matrix=_frame((0.0, 0.0, z)),
            container=storey,
        )

    # -- finishing ------------------------------------------------------------------------

    def sort_unordered_sets(self) -> None:
        """Order the members of relationships and the unit assignment by entity id.

        The api collects these through Python sets, whose order changes from run to run; IFC
        defines them as unordered SETs, so sorting loses nothing and makes the bytes stable.
        """
        for entity in [*self.model.by_type("IfcRelationship"), *self.model.by_type("IfcUnitAssignment")]:
            for index in range(len(entity)):
                value = entity[index]
                if not isinstance(value, tuple) or len(value) < 2:
                    continue
                if all(isinstance(v, ifcopenshell.entity_instance) for v in value):
                    entity[index] = sorted(value, key=lambda v: v.id())

    def assign_global_ids(self, *, seed: int, storeys: int) -> None:
        """Replace the api's random GlobalIds by ones derived from (seed, storeys, counter).

        Entities are numbered in creation order, which the plan fixes, so the ids are stable.
        """

        for counter, entity in enumerate(sorted(self.model.by_type("IfcRoot"), key=lambda e: e.id())):
            digest = hashlib.sha256(f"bimscan-building:{seed}:{storeys}:{counter}".encode()).hexdigest()
            entity.GlobalId = ifcopenshell.guid.compress(uuid.UUID(hex=digest[:32], version=4).hex)

    def count_placed(self) -> dict[str, int]:
        """Exact IFC class -> instances with a body (spaces and openings are not scannable)."""
        counts: Counter[str] = Counter()
        for element in self.model.by_type("IfcElement"):
            if element.Representation is None or element.is_a("IfcFeatureElement"):
                continue
            counts[element.is_a()] += 1
        return dict(sorted(counts.items()))


def _y_extrusion() -> dict[str, tuple[float, float, float]]:
    """ShapeBuilder.extrude arguments: profile drawn in the XZ plane, extruded along +Y."""
    return {"position_x_axis": (1, 0, 0), "position_z_axis": (0, -1, 0), "extrusion_vector": (0, 0, -1)}


def _furniture_boxes(kind: str, width: float, deep: float, height: float) -> list[Box]:
    """Boxes (x, y, z, sx, sy, sz) of one piece in its own frame: x along its width, y from the
    front (0) to the back (``deep``), z up from the floor. Metres."""
    if kind == "table":
        top, leg, inset = 0.04, 0.05, 0.03
        legs = [
            (x, y, 0.0, leg, leg, height - top)
            for x in (inset, width - inset - leg)
            for y in (inset, deep - inset - leg)
        ]
        return [(0.0, 0.0, height - top, width, deep, top), *legs]
    if kind == "cabinet":
        plinth = 0.08
        return [(0.03, 0.03, 0.0, width - 0.06, deep - 0.03, plinth), (0.0, 0.0, plinth, width, deep, height - plinth)]
    # An open shelf: two sides, a back, and boards about every 0.38 m.
    board = 0.02
    boxes = [(0.0, 0.0, 0.0, board, deep, height), (width - board, 0.0, 0.0, board, deep, height)]
    boxes.append((board, deep - 0.01, 0.0, width - 2 * board, 0.01, height))
    n_boards = max(2, round(height / 0.38))
    for i in range(n_boards + 1):
        z = 0.05 + i * (height - 0.05 - board) / n_boards
        boxes.append((board, 0.0, z, width - 2 * board, deep - 0.01, board))
    return boxes


def _storey_name(index: int) -> str:
    return "Ground floor" if index == 0 else f"Floor {index}"

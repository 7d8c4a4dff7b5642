"""Procedural buildings as valid IFC4 files: ``make_building``.

The embedded default of bimscan: the quickstart, the demo dataset and most tests scan these
buildings. Each is a seeded corridor block of one style (``office``, ``residential``, ``site``;
see ``floor_plan.py`` for the plan rules and ``styles.py`` for every number they draw from)
authored with ``ifcopenshell.api``: project, site, building, storeys in metres; exterior walls
along a rectilinear outline and interior walls, with door and window openings cut by
IfcOpeningElements and filled with parametric doors and windows (one IfcDoorType or
IfcWindowType per size, occurrences mapping its body); a column grid with beams under every
slab; floor, base and roof slabs (or, over most rectangular homes, an attic under a gable roof:
knee and gable walls, two pitched roof slabs); a half-turn stair (flights, landing, railings)
through a slab opening; a double-height hall under an opening in the floor above it (some
multi-storey buildings); ceiling coverings cut around columns and downstand beams; furniture;
and one IfcSpace per room for station planning. Shapes the api has no function for (stair flights, furniture,
railings, coverings of several pieces) are built with IfcOpenShell's ShapeBuilder, as the api
itself does. On request, a construction work schedule whose tasks build the elements storey by
storey (``work_schedule.py``).

Every GlobalId derives from (style, seed, storeys, counter) and the header timestamp is fixed,
so the same options give the same bytes. The work schedule is written after the building, so an
element has the same GlobalId with a schedule and without one.
"""

from __future__ import annotations

import contextlib

import hashlib
import math
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
import ifcopenshell.api.type
import ifcopenshell.api.unit
import ifcopenshell.guid
import numpy as np
from ifcopenshell.util.shape_builder import ShapeBuilder

from bimscan.files import atomic_output
from bimscan.errors import ConfigError, OutputError
from bimscan.ifc.generate.floor_plan import (
    ATTIC_NAME,
    FURNITURE_TYPES,
    GABLE_PARTS,
    ROOF_SLAB_NAME,
    STAIR_GUARD_NAME,
    BeamPlan,
    BuildingPlan,
    CeilingPlan,
    FurniturePlan,
    OpeningPlan,
    Rect,
    RoofPlan,
    RoomPlan,
    StairPlan,
    StoreyPlan,
    WallPlan,
    beam_name,
    column_name,
    floor_slab_name,
    plan_building,
    stair_part_names,
    storey_name,
)
from bimscan.ifc.generate.styles import (
    DEFAULT_STYLE,
    LANDING_DEPTH_M,
    MAX_STOREYS,
    MIN_STOREYS,
    STYLES,
    WINDOW_PANEL_M,
)
from bimscan.ifc.generate.work_schedule import BuildTask, add_work_schedule, schedule_start_date
from bimscan.ifc.output import check_ifc_output

# Fixed header fields: the file's bytes must not depend on when or where it was made.
HEADER_TIMESTAMP = "2024-01-01T00:00:00"
HEADER_ORGANISATION = "bimscan"
MAX_SEED = 2**63 - 1


@dataclass(frozen=True)
class GeneratedBuilding:
    """What ``make_building`` produced.

    placed: exact IFC class -> number of instances placed with body geometry (IfcSpace and
        IfcOpeningElement excluded), e.g. {"IfcWall": 40, "IfcSlab": 5, ...}.
    rooms_per_storey: IfcSpace count per IfcBuildingStorey, bottom up (an attic under a gable
        roof is the last, with one).
    storey_elevations_m: floor slab top of each IfcBuildingStorey, world Z in metres.
    footprint_m: (xmin, ymin, xmax, ymax) of the exterior walls' outer faces, metres.
    height_m: top of the building (flat roof slab or gable ridge), world Z in metres (ground
        floor slab top at 0).
    plan: the plan the file was authored from (``floor_plan.planned_elements(plan)`` lists what it holds).
    schedule_start: the first day of the work schedule (YYYY-MM-DD), None without one.
    works: the work schedule's tasks that build elements, in WBS order (empty without one).
    """

    path: Path | None
    seed: int
    storeys: int
    style: str
    placed: Mapping[str, int]
    rooms_per_storey: tuple[int, ...]
    storey_elevations_m: tuple[float, ...]
    footprint_m: tuple[float, float, float, float]
    height_m: float
    plan: BuildingPlan
    schedule_start: str | None = None
    works: tuple[BuildTask, ...] = ()


def check_building_options(
    *, seed: int, storeys: int, style: str = DEFAULT_STYLE, schedule_start: str | None = None
) -> None:
    """Raise ConfigError unless ``seed`` is an integer in [0, 2**63), ``storeys`` in 1..10,
    ``style`` one of ``STYLES`` and ``schedule_start`` None or a date YYYY-MM-DD."""
    if not _is_int(seed) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"seed must be an integer from 0 to {MAX_SEED}, got {seed!r}; pass a non-negative integer")
    if not _is_int(storeys) or not MIN_STOREYS <= storeys <= MAX_STOREYS:
        raise ConfigError(
            f"storeys must be an integer in {MIN_STOREYS}..{MAX_STOREYS}, got {storeys!r}; "
            f"pick a number of storeys in that range"
        )
    if not isinstance(style, str) or style not in STYLES:
        raise ConfigError(f"style must be one of {', '.join(STYLES)}, got {style!r}; pick one of those")
    if schedule_start is not None:
        schedule_start_date(schedule_start)


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def make_building(
    path: str | Path | None = None,
    *,
    seed: int = 0,
    storeys: int = 2,
    style: str = DEFAULT_STYLE,
    schedule_start: str | None = None,
    overwrite: bool = True,
) -> GeneratedBuilding:
    """Generate a seeded building of ``style``; write it as IFC4 to ``path`` when given.

    With ``schedule_start`` (YYYY-MM-DD) the file holds a construction work schedule from that day
    whose tasks build every element (``work_schedule.py``); without it, none.

    The file is written atomically (a temporary file in the same folder, then renamed), so a
    failure never leaves a half-written file. Same (style, seed, storeys, schedule_start) -> same
    bytes.

    Raises ConfigError for a bad seed, storey count, style or start, OutputError when ``path``'s
    folder is missing, ``path`` does not end in ``.ifc``, something is there (without ``overwrite``;
    with it, anything but an IFC bimscan wrote: ``bimscan.ifc.output.check_ifc_output``), or the
    file cannot be written.
    """
    check_building_options(seed=seed, storeys=storeys, style=style, schedule_start=schedule_start)
    target = Path(path) if path is not None else None
    if target is not None:
        check_ifc_output(target, overwrite=overwrite, like="building.ifc")
    model, building = build_building_model(seed=seed, storeys=storeys, style=style, schedule_start=schedule_start)
    if target is None:
        return building
    _write_atomically(target, model.to_string())
    return replace(building, path=target)


def build_building_model(
    *, seed: int = 0, storeys: int = 2, style: str = DEFAULT_STYLE, schedule_start: str | None = None
) -> tuple[ifcopenshell.file, GeneratedBuilding]:
    """The seeded building as an in-memory ``ifcopenshell.file`` plus its summary (path None)."""
    check_building_options(seed=seed, storeys=storeys, style=style, schedule_start=schedule_start)
    seed, storeys = int(seed), int(storeys)
    key = f"{style}:{seed}:{storeys}"
    plan = plan_building(seed=seed, storeys=storeys, style=style)
    start = None if schedule_start is None else schedule_start_date(schedule_start)
    with _no_owner_history():
        author = _Author(plan, name=f"bimscan-{style}-seed{seed}-storeys{storeys}")
        author.add_building()
        works = () if start is None else add_work_schedule(author.model, plan, start=start, key=key)
    author.sort_unordered_sets()
    author.assign_global_ids(key=key)
    summary = GeneratedBuilding(
        path=None,
        seed=seed,
        storeys=storeys,
        style=style,
        placed=author.count_placed(),
        rooms_per_storey=tuple(len(s.rooms) for s in plan.storeys) + ((1,) if plan.roof is not None else ()),
        storey_elevations_m=tuple(s.elevation_m for s in plan.storeys)
        + ((plan.roof_base_m,) if plan.roof is not None else ()),
        footprint_m=(0.0, 0.0, plan.width_m, plan.depth_m),
        height_m=plan.height_m,
        plan=plan,
        schedule_start=None if start is None else start.isoformat(),
        works=works,
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


def _mm(value: float) -> float:
    """Round to a tenth of a millimetre: the file holds tidy numbers and no float noise."""
    return round(float(value), 4)


def _closed(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    return [*points, points[0]]


def _rect_polyline(width: float, depth: float) -> list[tuple[float, float]]:
    return _closed([(0.0, 0.0), (width, 0.0), (width, depth), (0.0, depth)])


class _Author:
    """Writes one BuildingPlan into a fresh IFC4 model, element by element, via ifcopenshell.api.

    Two things are written directly rather than through the api, for speed (a 2-storey office
    holds several hundred products): object placements (an IfcLocalPlacement relative to the
    container's, as the api writes them) and the containment relationships (one per storey,
    written once all its products exist).
    """

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
        self.project = api.root.create_entity(model, ifc_class="IfcProject", name=f"bimscan {plan.style} building")
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
        self._profiles: dict[tuple[str, float, float], ifcopenshell.entity_instance] = {}
        self._types: dict[tuple, ifcopenshell.entity_instance] = {}
        self._typed: dict[int, list[ifcopenshell.entity_instance]] = {}
        self._contained: dict[int, list[ifcopenshell.entity_instance]] = {}
        self._world: dict[int, np.ndarray] = {}  # placement matrix of every placed product, by entity id
        self._directions: dict[tuple[float, float, float], ifcopenshell.entity_instance] = {}

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
        relative_to: ifcopenshell.entity_instance | None = None,
    ) -> ifcopenshell.entity_instance:
        """Create a product with a body, placed at ``matrix`` (world) relative to its container,
        its whole, or ``relative_to``; contained in ``container`` or aggregated into ``whole``."""
        element = api.root.create_entity(self.model, ifc_class=ifc_class, predefined_type=predefined_type, name=name)
        if representation is not None:
            element.Representation = self.model.createIfcProductDefinitionShape(None, None, [representation])
        if container is not None:
            self._contained.setdefault(container.id(), []).append(element)
        if whole is not None:
            api.aggregate.assign_object(self.model, products=[element], relating_object=whole)
        self._place(element, matrix, relative_to or container or whole)
        return element

    def _place(
        self, product: ifcopenshell.entity_instance, matrix: np.ndarray, parent: ifcopenshell.entity_instance | None
    ) -> None:
        """Give ``product`` an IfcLocalPlacement at ``matrix`` (world), relative to ``parent``'s."""
        parent_matrix = self._world.get(parent.id()) if parent is not None else None
        local = matrix if parent_matrix is None else np.linalg.solve(parent_matrix, matrix)
        local = np.where(np.abs(local) < 1e-12, 0.0, np.round(local, 9))  # no -0.0, no float noise
        model = self.model
        axes = model.createIfcAxis2Placement3D(
            model.createIfcCartesianPoint([float(v) for v in local[:3, 3]]),
            model.createIfcDirection([float(v) for v in local[:3, 2]]),
            model.createIfcDirection([float(v) for v in local[:3, 0]]),
        )
        relative = parent.ObjectPlacement if parent_matrix is not None else None
        product.ObjectPlacement = model.createIfcLocalPlacement(relative, axes)
        self._world[product.id()] = matrix

    def _contain_all(self) -> None:
        """Write the spatial containment of every storey's products, one relationship each.

        Written directly: the api's assign_container recomputes every product's placement,
        which the products, placed relative to their storey already, do not need.
        """
        for container_id, products in self._contained.items():
            self.model.createIfcRelContainedInSpatialStructure(
                ifcopenshell.guid.new(), None, None, None, products, self.model.by_id(container_id)
            )

    def _boxes(self, boxes: Sequence[Box]) -> ifcopenshell.entity_instance:
        """One body of axis-aligned boxes (x, y, z, size_x, size_y, size_z) in local metres:
        rectangle profiles extruded upwards (written directly; ShapeBuilder's polylines cost
        several times as much to create)."""
        model = self.model
        up = self._direction((0.0, 0.0, 1.0))
        items = []
        for x, y, z, sx, sy, sz in boxes:
            centre = model.createIfcAxis2Placement2D(model.createIfcCartesianPoint([x + sx / 2, y + sy / 2]))
            profile = model.createIfcRectangleProfileDef("AREA", None, centre, sx, sy)
            position = model.createIfcAxis2Placement3D(model.createIfcCartesianPoint([0.0, 0.0, z]))
            items.append(model.createIfcExtrudedAreaSolid(profile, position, up, sz))
        return model.createIfcShapeRepresentation(self.body, "Body", "SweptSolid", items)

    def _section_body(self, section: Sequence[tuple[float, float]], length: float) -> ifcopenshell.entity_instance:
        """A polygon in the local YZ plane ((y, z) pairs, metres) extruded ``length`` along local X."""
        model = self.model
        points = [model.createIfcCartesianPoint([_mm(y), _mm(z)]) for y, z in _closed(list(section))]
        profile = model.createIfcArbitraryClosedProfileDef("AREA", None, model.createIfcPolyline(points))
        # Profile X -> local Y, profile Y -> local Z; the extrusion runs along local X.
        position = model.createIfcAxis2Placement3D(model.createIfcCartesianPoint([0.0, 0.0, 0.0]),
                                                   self._direction((1.0, 0.0, 0.0)), self._direction((0.0, 1.0, 0.0)))
        solid = model.createIfcExtrudedAreaSolid(profile, position, self._direction((0.0, 0.0, 1.0)), _mm(length))
        return model.createIfcShapeRepresentation(self.body, "Body", "SweptSolid", [solid])

    def _direction(self, xyz: tuple[float, float, float]) -> ifcopenshell.entity_instance:
        if xyz not in self._directions:
            self._directions[xyz] = self.model.createIfcDirection(list(xyz))
        return self._directions[xyz]

    def _slab_body(self, polyline: Sequence[tuple[float, float]], thickness: float) -> ifcopenshell.entity_instance:
        return api.geometry.add_slab_representation(self.model, context=self.body, depth=thickness, polyline=polyline)

    def _profile(self, kind: str, x_dim: float, y_dim: float) -> ifcopenshell.entity_instance:
        """A rectangle profile, shared by every column or beam of that size."""
        key = (kind, x_dim, y_dim)
        if key not in self._profiles:
            profile = api.profile.add_parameterized_profile(self.model, ifc_class="IfcRectangleProfileDef")
            profile.ProfileName = f"{x_dim:.2f} x {y_dim:.2f} {kind}"
            profile.XDim, profile.YDim = x_dim, y_dim
            self._profiles[key] = profile
        return self._profiles[key]

    # -- the building ---------------------------------------------------------------------

    def add_building(self) -> None:
        plan = self.plan
        site = self._element("IfcSite", name="Site", matrix=np.eye(4), whole=self.project)
        building = self._element("IfcBuilding", name=f"{plan.style.capitalize()} building", matrix=np.eye(4),
                                 whole=site)
        storeys = []
        for storey_plan in plan.storeys:
            z = storey_plan.elevation_m
            name = storey_name(storey_plan.index)
            storey = self._element("IfcBuildingStorey", name=name, matrix=_frame((0, 0, z)), whole=building)
            storey.Elevation = z
            storeys.append(storey)
        for storey, storey_plan in zip(storeys, plan.storeys):
            self.add_storey(storey, storey_plan)
        top = plan.storeys[-1]
        if plan.roof is None:
            self._element(
                "IfcSlab",
                name=ROOF_SLAB_NAME,
                predefined_type="ROOF",
                representation=self._slab_body(_closed(plan.outline_m), plan.slab_m),
                matrix=_frame((0.0, 0.0, plan.roof_base_m - plan.slab_m)),
                container=storeys[-1],
            )
        if plan.stair is not None:
            self.add_guard(storeys[-1], plan.stair, top.elevation_m)
        if plan.roof is not None:
            self.add_attic(building, plan.roof)
        self._contain_all()
        self._assign_types()

    def add_attic(self, building: ifcopenshell.entity_instance, roof: RoofPlan) -> None:
        """The storey over the top slab: its floor, knee and gable walls, the two roof planes and
        one space. Every part is a section in the YZ plane extruded along X."""
        plan = self.plan
        index = len(plan.storeys)
        z = plan.roof_base_m
        storey = self._element("IfcBuildingStorey", name=storey_name(index), matrix=_frame((0, 0, z)), whole=building)
        storey.Elevation = z
        storey.LongName = ATTIC_NAME
        self._element(
            "IfcSlab",
            name=floor_slab_name(index),
            predefined_type="FLOOR",
            representation=self._slab_body(_closed(plan.outline_m), plan.slab_m),
            matrix=_frame((0.0, 0.0, z - plan.slab_m)),
            container=storey,
        )
        d, w, e = plan.depth_m, plan.width_m, plan.exterior_wall_m
        knee, ridge, thick = roof.knee_m, roof.ridge_m(d), roof.vertical_thickness_m()
        rise = math.tan(math.radians(roof.pitch_deg))  # per metre in Y
        gable = [(0.0, 0.0), (d, 0.0), (d, knee), (d / 2, ridge), (0.0, knee)]
        sections = {  # name -> (section (y, z above the attic floor), x start, length along X)
            "Wall gable west": (gable, 0.0, e),
            "Wall gable east": (gable, w - e, e),
            "Wall knee south": ([(0.0, 0.0), (e, 0.0), (e, knee + e * rise), (0.0, knee)], e, w - 2 * e),
            "Wall knee north": ([(d - e, 0.0), (d, 0.0), (d, knee), (d - e, knee + e * rise)], e, w - 2 * e),
            "Roof slab south": ([(0.0, knee), (d / 2, ridge), (d / 2, ridge + thick), (0.0, knee + thick)], 0.0, w),
            "Roof slab north": ([(d / 2, ridge), (d, knee), (d, knee + thick), (d / 2, ridge + thick)], 0.0, w),
        }
        for name, (section, x0, length) in sections.items():
            ifc_class, predefined, _ = GABLE_PARTS[name]
            self._element(ifc_class, name=name, predefined_type=predefined, matrix=_frame((x0, 0.0, z)),
                          representation=self._section_body(section, length), container=storey)
        room = plan.attic_room
        assert room is not None
        self.add_space(storey, room, z)

    def add_storey(self, storey: ifcopenshell.entity_instance, sp: StoreyPlan) -> None:
        plan = self.plan
        z = sp.elevation_m
        slab = self._element(
            "IfcSlab",
            name=floor_slab_name(sp.index),
            predefined_type="BASESLAB" if sp.index == 0 else "FLOOR",
            representation=self._slab_body(_closed(plan.outline_m), plan.slab_m),
            matrix=_frame((0.0, 0.0, z - plan.slab_m)),
            container=storey,
        )
        if sp.index > 0 and plan.stair is not None:
            self.add_slab_opening(slab, plan.stair.opening, z, name="Stair opening")
        if plan.hall is not None and sp.index == plan.hall.storey + 1:
            self.add_slab_opening(slab, plan.hall.rect, z, name="Hall opening")
        for wall in sp.walls:
            self.add_wall(storey, wall, z)
        for i, rect, height in plan.storey_columns(sp.index):
            self.add_column(storey, rect.centre, z, name=column_name(sp.index, i), height_m=height)
        for i, beam in plan.storey_beams(sp.index):
            self.add_beam(storey, beam, z + plan.soffit_m, name=beam_name(sp.index, i))
        for room in sp.rooms:
            self.add_space(storey, room, z)
        for ceiling in sp.ceilings:
            self.add_ceiling(storey, ceiling, z)
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
            height=wall.height_m,
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
        """Cut ``opening`` out of ``wall`` and fill it with a door or window of the matching type."""

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
        void.Representation = self.model.createIfcProductDefinitionShape(None, None, [void_body])
        api.feature.add_feature(self.model, feature=void, element=wall)
        self._place(void, _translate(wall_matrix, (opening.offset_m, 0.0, opening.sill_m - below)), wall)
        ifc_class = "IfcDoor" if opening.kind == "door" else "IfcWindow"
        filling = api.root.create_entity(
            self.model, ifc_class=ifc_class, predefined_type=opening.kind.upper(), name=opening.name.capitalize()
        )
        filling.OverallWidth = opening.width_m
        filling.OverallHeight = opening.height_m
        self._contained.setdefault(storey.id(), []).append(filling)
        api.feature.add_filling(self.model, opening=void, element=filling)
        self._place(filling, _translate(wall_matrix, (opening.offset_m, 0.0, opening.sill_m)), storey)
        kind_type = self._filling_type(opening, thickness)
        self._typed.setdefault(kind_type.id(), []).append(filling)

    def _filling_type(self, opening: OpeningPlan, thickness: float) -> ifcopenshell.entity_instance:
        """The IfcDoorType or IfcWindowType of ``opening``'s size in a wall of ``thickness``; its
        body is the api's parametric door or window, mapped into every occurrence."""
        key = (opening.kind, opening.width_m, opening.height_m, thickness)
        if key in self._types:
            return self._types[key]
        size = f"{opening.width_m:.2f} x {opening.height_m:.2f} m in {thickness:.2f} m"
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
            kind_type = api.root.create_entity(self.model, ifc_class="IfcDoorType", predefined_type="DOOR",
                                               name=f"Door {size}")
            kind_type.OperationType = "SINGLE_SWING_LEFT"
        else:
            # A frame 0.1 m deep in the middle of the wall leaves reveals on both faces; wide
            # windows get mullions between equal panels (bands: up to three).
            depth = 0.1
            panels = min(3, math.ceil(opening.width_m / WINDOW_PANEL_M - 1e-9))
            partition = ("SINGLE_PANEL", "DOUBLE_PANEL_VERTICAL", "TRIPLE_PANEL_VERTICAL")[panels - 1]
            body = api.geometry.add_window_representation(
                self.model,
                context=self.body,
                overall_width=opening.width_m,
                overall_height=opening.height_m,
                partition_type=partition,
                lining_properties={
                    "LiningDepth": depth,
                    "LiningOffset": (thickness - depth) / 2,
                    "FirstMullionOffset": opening.width_m / panels,
                    "SecondMullionOffset": 2 * opening.width_m / panels,
                },
                panel_properties=[{} for _ in range(panels)],
            )
            kind_type = api.root.create_entity(self.model, ifc_class="IfcWindowType", predefined_type="WINDOW",
                                               name=f"Window {size}")
            kind_type.PartitioningType = partition
        api.geometry.assign_representation(self.model, product=kind_type, representation=body)
        self._types[key] = kind_type
        return kind_type

    def _assign_types(self) -> None:
        """Type every door and window; the api maps the type's body into each occurrence.

        One occurrence at a time: given several, the api maps them in set order, which would
        number the mapped bodies differently from run to run.
        """
        for type_id, occurrences in self._typed.items():
            relating = self.model.by_id(type_id)
            for occurrence in occurrences:
                api.type.assign_type(self.model, related_objects=[occurrence], relating_type=relating)

    def add_slab_opening(self, slab: ifcopenshell.entity_instance, rect: Rect, z: float, *, name: str) -> None:
        """Cut ``rect`` (plan) out of the floor slab whose top is at ``z``."""
        void = api.root.create_entity(
            self.model, ifc_class="IfcOpeningElement", predefined_type="OPENING", name=name
        )
        body = self._slab_body(_rect_polyline(rect.width, rect.depth), self.plan.slab_m + 0.2)
        void.Representation = self.model.createIfcProductDefinitionShape(None, None, [body])
        api.feature.add_feature(self.model, feature=void, element=slab)
        self._place(void, _frame((rect.x0, rect.y0, z - self.plan.slab_m - 0.1)), slab)

    def add_column(self, storey: ifcopenshell.entity_instance, centre: tuple[float, float], z: float, *,
                   name: str, height_m: float) -> None:
        plan = self.plan
        profile = self._profile("column", plan.column_m, plan.column_m)
        body = api.geometry.add_profile_representation(
            self.model, context=self.body, profile=profile, depth=height_m
        )
        self._element(
            "IfcColumn", name=name, predefined_type="COLUMN", representation=body,
            matrix=_frame((centre[0], centre[1], z)), container=storey,
        )

    def add_beam(self, storey: ifcopenshell.entity_instance, beam: BeamPlan, soffit_z: float, *, name: str) -> None:
        """A beam hanging from the slab underside at ``soffit_z`` down to the plan's beam bottom."""
        plan = self.plan
        depth = plan.beam_depth_m
        profile = self._profile("beam", plan.beam_width_m, depth)
        body = api.geometry.add_profile_representation(
            self.model, context=self.body, profile=profile, depth=beam.length_m
        )
        # Local Z (the extrusion) runs along the beam, local X across it, local Y down; the
        # profile is centred on the axis, which sits half a beam depth below the slab.
        r = beam.rect
        matrix = np.eye(4)
        if beam.along == "y":
            matrix[:3, 0], matrix[:3, 2] = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
            matrix[:3, 3] = (r.centre[0], r.y0, soffit_z - depth / 2)
        else:
            matrix[:3, 0], matrix[:3, 2] = (0.0, -1.0, 0.0), (1.0, 0.0, 0.0)
            matrix[:3, 3] = (r.x0, r.centre[1], soffit_z - depth / 2)
        matrix[:3, 1] = (0.0, 0.0, -1.0)
        self._element(
            "IfcBeam", name=name, predefined_type="BEAM", representation=body, matrix=matrix, container=storey
        )

    def add_space(self, storey: ifcopenshell.entity_instance, room: RoomPlan, z: float) -> None:
        space = self._element(
            "IfcSpace",
            name=room.number,
            predefined_type="INTERNAL",
            representation=self._slab_body(_rect_polyline(room.rect.width, room.rect.depth), room.height_m),
            matrix=_frame((room.rect.x0, room.rect.y0, z)),
            whole=storey,
        )
        space.LongName = room.kind.capitalize()

    def add_ceiling(self, storey: ifcopenshell.entity_instance, ceiling: CeilingPlan, z: float) -> None:
        """A ceiling covering of one or more boards (the room less columns and visible beams)."""
        boxes = [(r.x0, r.y0, 0.0, r.width, r.depth, ceiling.thickness_m) for r in ceiling.rects]
        self._element(
            "IfcCovering",
            name=ceiling.name,
            predefined_type="CEILING",
            representation=self._boxes(boxes),
            matrix=_frame((0.0, 0.0, z + ceiling.bottom_m)),
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
        self._element(
            "IfcFurniture",
            name=piece.name.capitalize(),
            predefined_type=FURNITURE_TYPES[piece.kind],
            representation=self._boxes(boxes),
            matrix=_frame((origin[0], origin[1], z), tuple(x_axis)),
            container=storey,
        )

    def add_stair(self, storey: ifcopenshell.entity_instance, stair: StairPlan, z: float, *, index: int) -> None:
        """The half-turn stair from this storey to the next: two flights, a landing, a railing."""
        plan = self.plan
        half = plan.storey_height_m / 2
        names = stair_part_names(index)
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
            name=names["flight1"],
            predefined_type="STRAIGHT",
            representation=flight1,
            matrix=_frame((stair.x_start_m, stair.flight1_y[0], z)),
            whole=whole,
        )
        # Flight 2 runs back along -X; its local y (z cross x) then points to -Y.
        flight2 = self._flight_body(r, h, g, w2)
        self._element(
            "IfcStairFlight",
            name=names["flight2"],
            predefined_type="STRAIGHT",
            representation=flight2,
            matrix=_frame((stair.x_landing_m, stair.flight2_y[1], z + half), (-1.0, 0.0, 0.0)),
            whole=whole,
        )
        landing = stair.opening
        self._element(
            "IfcSlab",
            name=names["landing"],
            predefined_type="LANDING",
            representation=self._slab_body(_rect_polyline(stair.x_end_m - stair.x_landing_m, landing.depth),
                                           LANDING_DEPTH_M),
            matrix=_frame((stair.x_landing_m, landing.y0, z + half - LANDING_DEPTH_M)),
            whole=whole,
        )
        self._element(
            "IfcRailing",
            name=names["handrail"],
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
            name=STAIR_GUARD_NAME,
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

    def assign_global_ids(self, *, key: str) -> None:
        """Replace the api's random GlobalIds by ones derived from ``key`` and a counter.

        Entities are numbered in creation order, which the plan fixes, so the ids are stable.
        """

        for counter, entity in enumerate(sorted(self.model.by_type("IfcRoot"), key=lambda e: e.id())):
            digest = hashlib.sha256(f"bimscan-building:{key}:{counter}".encode()).hexdigest()
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

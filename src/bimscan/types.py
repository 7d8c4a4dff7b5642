"""Small typed data passed between pipeline stages.

Frozen dataclasses of NumPy columns; shapes and dtypes are checked once, on construction. Field
names are the same everywhere in the package (``xyz``, ``label``, ``component``, ``station``,
``intensity``, ``time``); only the format edges rename them (LAS names in ``io/las.py``,
Pointcept names in ``io/npdir.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from bimscan.ifc.report import FailedElement, IfcLoadReport

UNLABELLED = 255  # label id of points without ground truth (skipped by losses and metrics); no scheme class may use it


def _check(name: str, array: np.ndarray | None, dtype: str, shape: tuple[int | None, ...]) -> None:
    if array is None:
        return
    if not isinstance(array, np.ndarray):
        raise TypeError(f"{name} must be a NumPy array, got {type(array).__name__}")
    if array.dtype != np.dtype(dtype):
        raise TypeError(f"{name} must have dtype {dtype}, got {array.dtype}")
    if array.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, array.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} must have shape {want}, got {array.shape}")


def _check_rows(owner: str, n: int, **columns: np.ndarray | None) -> None:
    for name, column in columns.items():
        if column is not None and len(column) != n:
            raise ValueError(f"{owner}.{name} has {len(column)} rows, expected {n}")


@dataclass(frozen=True)
class SceneMesh:
    """All scannable triangles of a model merged into one mesh.

    vertices: (V, 3) float64, world coordinates in metres, Z up.
    faces: (F, 3) int32, indices into ``vertices``.
    face_component: (F,) int32, the dense component id of each triangle.
    face_transparency: (F,) float32 in [0, 1], the transparency of each triangle's own surface
    style in the model (a window's pane and its frame told apart), NaN where the triangle has no
    style; None when the mesh carries no per-triangle styles (a model built in memory, clutter).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_component: np.ndarray
    face_transparency: np.ndarray | None = None

    def __post_init__(self) -> None:
        _check("vertices", self.vertices, "float64", (None, 3))
        _check("faces", self.faces, "int32", (None, 3))
        _check("face_component", self.face_component, "int32", (None,))
        _check("face_transparency", self.face_transparency, "float32", (None,))
        _check_rows("SceneMesh", len(self.faces), face_component=self.face_component,
                    face_transparency=self.face_transparency)
        if self.face_transparency is not None and np.any((self.face_transparency < 0) | (self.face_transparency > 1)):
            raise ValueError("face_transparency must lie in [0, 1] (NaN: no style)")
        if len(self.faces) and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError("faces index vertices out of range")

    @property
    def n_triangles(self) -> int:
        return int(len(self.faces))

    def face_transparency_for(self, kept: np.ndarray | None = None, added: int = 0) -> np.ndarray | None:
        """``face_transparency`` of the ``kept`` triangles ((F,) bool; None: all), followed by ``added``
        new triangles without a style (NaN), for a mesh derived from this one; None stays None."""
        if self.face_transparency is None:
            return None
        alpha = self.face_transparency if kept is None else self.face_transparency[kept]
        return np.concatenate([alpha, np.full(added, np.nan, dtype=np.float32)]) if added else alpha

    @cached_property
    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if len(self.faces):
            used_mask = np.zeros(len(self.vertices), dtype=bool)
            used_mask[self.faces.ravel()] = True
            used = self.vertices[used_mask]
        else:
            used = self.vertices
        if len(used) == 0:
            return np.zeros(3), np.zeros(3)
        return used.min(axis=0), used.max(axis=0)

    def face_normals(self) -> np.ndarray:
        """(F, 3) float64 unit normals of the triangles, from their winding (zero for degenerate ones)."""
        v, f = self.vertices, self.faces
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min xyz, max xyz) in metres of the vertices that faces use (computed once)."""
        lo, hi = self._bounds
        return lo.copy(), hi.copy()


@dataclass(frozen=True)
class ComponentTable:
    """One row per component (a building element with geometry), indexed by dense component id.

    All columns are (C,) arrays; strings are NumPy unicode arrays. ``label`` holds the semantic
    class id under ``scheme_name``. ``class_ancestry`` maps every IFC class present to its chain
    of supertypes in the file's schema, nearest first and starting with the class itself.
    """

    global_id: np.ndarray
    ifc_class: np.ndarray
    predefined_type: np.ndarray
    name: np.ndarray
    storey: np.ndarray
    parent_class: np.ndarray
    label: np.ndarray
    class_ancestry: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    step_id: np.ndarray | None = None  # (C,) int64 STEP instance id (#n) in the source file; -1 for components not in it (site objects); None when unknown

    def __post_init__(self) -> None:
        n = len(self.global_id)
        for column in ("global_id", "ifc_class", "predefined_type", "name", "storey", "parent_class"):
            array = getattr(self, column)
            if not isinstance(array, np.ndarray) or array.dtype.kind != "U" or array.ndim != 1:
                raise TypeError(f"ComponentTable.{column} must be a 1-D NumPy unicode array")
        _check("label", self.label, "uint8", (None,))
        _check("step_id", self.step_id, "int64", (None,))
        _check_rows(
            "ComponentTable", n, ifc_class=self.ifc_class, predefined_type=self.predefined_type,
            name=self.name, storey=self.storey, parent_class=self.parent_class, label=self.label,
            step_id=self.step_id,
        )

    def __len__(self) -> int:
        return int(len(self.global_id))

    def descends_from(self, classes: Sequence[str], *, parents: bool = False) -> np.ndarray:
        """(C,) bool: components whose class (or, with ``parents``, whose aggregate's class) is one
        of ``classes`` or a subclass of one (by ``class_ancestry``; names compared case-insensitively)."""
        wanted = {c.lower() for c in classes}
        cache: dict[str, bool] = {}

        def hits(cls: str) -> bool:
            if cls not in cache:
                cache[cls] = bool(cls) and any(a.lower() in wanted for a in self.class_ancestry.get(cls, (cls,)))
            return cache[cls]

        own = np.array([hits(c) for c in self.ifc_class.tolist()], dtype=bool)
        if not parents:
            return own
        return own | np.array([hits(c) for c in self.parent_class.tolist()], dtype=bool)

    def rows(self) -> list[dict[str, object]]:
        """The table as a list of plain dicts (for JSON, CSV and index files)."""
        return [
            {
                "component": i,
                "global_id": str(self.global_id[i]),
                "ifc_class": str(self.ifc_class[i]),
                "predefined_type": str(self.predefined_type[i]),
                "name": str(self.name[i]),
                "storey": str(self.storey[i]),
                "parent_class": str(self.parent_class[i]),
                "label": int(self.label[i]),
            }
            for i in range(len(self))
        ]


@dataclass(frozen=True)
class LabelClass:
    """One semantic class of a label scheme."""

    id: int
    name: str
    color: str  # "#rrggbb", used by renders and plots

    @property
    def rgb(self) -> tuple[int, int, int]:
        """The colour as (r, g, b) integers 0..255."""
        text = self.color.lstrip("#")
        return int(text[0:2], 16), int(text[2:4], 16), int(text[4:6], 16)


@dataclass(frozen=True)
class LabelRule:
    """Map elements of ``ifc_class`` (and its subclasses) to the class named ``label``.

    Optional filters: ``predefined_types`` (any of, upper case), ``parent_class`` (the IFC class
    of the aggregate the element is part of, subclasses included).
    """

    ifc_class: str
    label: str
    predefined_types: tuple[str, ...] = ()
    parent_class: str | None = None


@dataclass(frozen=True)
class LabelScheme:
    """Semantic classes and the rules mapping IFC classes onto them; data, not code."""

    name: str
    classes: tuple[LabelClass, ...]
    rules: tuple[LabelRule, ...]
    default_label: str

    @property
    def names(self) -> dict[int, str]:
        return {c.id: c.name for c in self.classes}


@dataclass(frozen=True)
class Storey:
    """A building storey: its name and the elevation of its placement in metres (world Z)."""

    name: str
    elevation_m: float


@dataclass(frozen=True)
class Space:
    """A room volume (IfcSpace), kept aside from the scannable mesh for station planning.

    vertices: (V, 3) float64 metres; faces: (F, 3) int32.
    """

    global_id: str
    name: str
    storey: str
    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self) -> None:
        _check("vertices", self.vertices, "float64", (None, 3))
        _check("faces", self.faces, "int32", (None, 3))

    def contains(self, points: np.ndarray, *, below_m: float = 0.6) -> np.ndarray:
        """(N,) bool: points (N, 3) metres whose xy falls inside the room's footprint (its triangles
        seen from above) and whose z lies between ``below_m`` under its floor and its top."""
        v, f = self.vertices, self.faces
        z0, z1 = float(v[:, 2].min()), float(v[:, 2].max())
        inside = np.zeros(len(points), dtype=bool)
        a, b, c = v[f[:, 0], :2], v[f[:, 1], :2], v[f[:, 2], :2]
        area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        keep = np.abs(area) > 1e-9  # vertical faces project to lines
        a, b, c, area = a[keep], b[keep], c[keep], area[keep]
        p = points[:, :2]
        for start in range(0, len(p), 4096):  # (4096 x faces) barycentric tests at a time: bounded memory
            q = p[start:start + 4096, None, :]
            w0 = ((b[:, 0] - q[..., 0]) * (c[:, 1] - q[..., 1]) - (c[:, 0] - q[..., 0]) * (b[:, 1] - q[..., 1])) / area
            w1 = ((c[:, 0] - q[..., 0]) * (a[:, 1] - q[..., 1]) - (a[:, 0] - q[..., 0]) * (c[:, 1] - q[..., 1])) / area
            inside[start:start + 4096] = ((w0 >= 0) & (w1 >= 0) & (w0 + w1 <= 1)).any(axis=1)
        return inside & (points[:, 2] > z0 - below_m) & (points[:, 2] < z1)


@dataclass(frozen=True)
class BuildDates:
    """When a building element stands on site, from the model's work schedule (ISO dates, or None).

    built: the finish of the task that constructs or installs it (None: no such task, it is there
    from the start); removed: the finish of a task that demolishes or dismantles it (None: never).
    """

    built: str | None = None
    removed: str | None = None


@dataclass(frozen=True)
class SiteState:
    """How a scene was changed to look as the site does when scanned (``bimscan.site``).

    settings: the site model and seed it was dressed with (``site.site_settings``); removed: IFC
    class -> components the construction stage took out; placed: class name (``Clutter.Chair``,
    ...) -> objects added; rooms: rooms (or free floor areas) dressed; free_floor_m2: their free
    floor before anything was placed.
    """

    settings: Mapping[str, object]
    removed: Mapping[str, int] = field(default_factory=dict)
    placed: Mapping[str, int] = field(default_factory=dict)
    rooms: int = 0
    free_floor_m2: float = 0.0

    def to_json(self) -> dict[str, object]:
        return {"removed": dict(self.removed), "placed": dict(self.placed), "rooms": self.rooms,
                "free_floor_m2": round(self.free_floor_m2, 3)}


@dataclass(frozen=True)
class ComponentSurfaces:
    """What the IFC model says about each component's surface, one row per component (C,).

    color: (C, 3) float32 linear RGB in [0, 1] of its surface style (IfcSurfaceStyleShading /
    Rendering ``SurfaceColour``), NaN where the model gives none. transparency: (C,) float32 in
    [0, 1] (0 opaque), the highest of its styles (a window with glazing is transparent).
    style: (C,) unicode, the style's name; material: (C,) unicode, the names of its materials
    joined by "; " (IfcMaterial, layer and constituent sets). Empty strings where absent.
    """

    color: np.ndarray
    transparency: np.ndarray
    style: np.ndarray
    material: np.ndarray

    def __post_init__(self) -> None:
        _check("color", self.color, "float32", (None, 3))
        _check("transparency", self.transparency, "float32", (None,))
        for column in ("style", "material"):
            array = getattr(self, column)
            if not isinstance(array, np.ndarray) or array.dtype.kind != "U" or array.ndim != 1:
                raise TypeError(f"ComponentSurfaces.{column} must be a 1-D NumPy unicode array")
        _check_rows("ComponentSurfaces", len(self.color), transparency=self.transparency, style=self.style,
                    material=self.material)

    def __len__(self) -> int:
        return int(len(self.color))

    @staticmethod
    def unknown(n: int) -> ComponentSurfaces:
        """n components the model says nothing about (no colour, opaque, no names)."""
        return ComponentSurfaces(color=np.full((n, 3), np.nan, dtype=np.float32), transparency=np.zeros(n, np.float32),
                                 style=np.full(n, "", dtype="<U1"), material=np.full(n, "", dtype="<U1"))


@dataclass(frozen=True, kw_only=True)
class ParsedModel:
    """Stage 1's output: an IFC model's scannable mesh, component table, storeys, spaces,
    failures and load report, before any label scheme (``components.label`` is all zeros).
    ``surfaces``: the components' surface styles and materials (None: not read, e.g. a model
    built in memory). Fields are keyword-only (a labelled ``BimScene`` adds its own after these
    defaults)."""

    source: str
    file_sha256: str
    schema: str
    mesh: SceneMesh
    components: ComponentTable
    storeys: tuple[Storey, ...]
    spaces: tuple[Space, ...]
    failed: tuple[FailedElement, ...]
    surfaces: ComponentSurfaces | None = None
    report: IfcLoadReport = field(default_factory=IfcLoadReport)


@dataclass(frozen=True, kw_only=True)
class BimScene(ParsedModel):
    """A parsed IFC model with its components labelled under ``scheme`` (``components.label``)."""

    scheme: LabelScheme
    unmapped_classes: Mapping[str, int]  # IFC class -> components that fell to the default class
    site: SiteState | None = None  # set when bimscan.site dressed the scene (stage, clutter)

    def __post_init__(self) -> None:
        if len(self.mesh.face_component) and self.mesh.face_component.max() >= len(self.components):
            raise ValueError("mesh.face_component refers to components beyond the component table")
        if self.surfaces is not None and len(self.surfaces) != len(self.components):
            raise ValueError(f"surfaces has {len(self.surfaces)} rows for {len(self.components)} components")


@dataclass(frozen=True)
class Station:
    """A scan station: the laser's beam origin in world metres, heading and floor height.

    ``position`` is where the beam leaves the instrument (floor + tripod + beam offset).
    """

    id: int
    position: tuple[float, float, float]
    heading_deg: float = 0.0
    floor_z: float | None = None
    storey: str = ""
    room: str = ""

    @staticmethod
    def from_dict(data: Mapping[str, object]) -> Station:
        """The inverse of ``dataclasses.asdict`` (as stored in JSON); KeyError/TypeError/ValueError if damaged."""
        floor_z = data.get("floor_z")
        return Station(id=int(data["id"]), position=tuple(float(v) for v in data["position"]),  # type: ignore[arg-type, attr-defined]
                       heading_deg=float(data.get("heading_deg", 0.0)),  # type: ignore[arg-type]
                       floor_z=None if floor_z is None else float(floor_z),  # type: ignore[arg-type]
                       storey=str(data.get("storey", "")), room=str(data.get("room", "")))


@dataclass(frozen=True)
class PointCloud:
    """A (chunk of a) labelled point cloud; every column has N rows.

    xyz: (N, 3) float64 metres. label: (N,) uint8 semantic class id. component: (N,) int32
    component id. station: (N,) uint16. intensity: (N,) uint16.
    time: (N,) float64 seconds since the start of the survey. return_number / number_of_returns:
    (N,) uint8, which echo of its pulse a point is (1-based) and how many echoes the pulse gave
    (scans with the beam footprint; LAS names them the same). rgb: (N, 3) uint8 colour (scans
    with colour, or a foreign file's red/green/blue). Mobile scans add ring: (N,) uint8 the beam's
    ring (rank by elevation), channel: (N,) uint8 which lidar of the platform, and sensor_xyz:
    (N, 3) float64 the beam origin at the pulse's time (as registered, drift included). Only
    ``xyz`` is required (real scans may lack the rest).
    """

    xyz: np.ndarray
    label: np.ndarray | None = None
    component: np.ndarray | None = None
    station: np.ndarray | None = None
    intensity: np.ndarray | None = None
    time: np.ndarray | None = None
    return_number: np.ndarray | None = None
    number_of_returns: np.ndarray | None = None
    rgb: np.ndarray | None = None
    ring: np.ndarray | None = None
    channel: np.ndarray | None = None
    sensor_xyz: np.ndarray | None = None

    def __post_init__(self) -> None:
        _check("xyz", self.xyz, "float64", (None, 3))
        _check("ring", self.ring, "uint8", (None,))
        _check("channel", self.channel, "uint8", (None,))
        _check("sensor_xyz", self.sensor_xyz, "float64", (None, 3))
        _check("label", self.label, "uint8", (None,))
        _check("component", self.component, "int32", (None,))
        _check("station", self.station, "uint16", (None,))
        _check("intensity", self.intensity, "uint16", (None,))
        _check("time", self.time, "float64", (None,))
        _check("return_number", self.return_number, "uint8", (None,))
        _check("number_of_returns", self.number_of_returns, "uint8", (None,))
        _check("rgb", self.rgb, "uint8", (None, 3))
        _check_rows(
            "PointCloud", len(self.xyz), label=self.label, component=self.component,
            station=self.station, intensity=self.intensity, time=self.time, return_number=self.return_number,
            number_of_returns=self.number_of_returns, rgb=self.rgb, ring=self.ring, channel=self.channel,
            sensor_xyz=self.sensor_xyz,
        )

    def __len__(self) -> int:
        return int(len(self.xyz))

    # Column order of writers and headers; columns added later go last, so older files keep their bytes.
    COLUMNS = ("xyz", "label", "component", "station", "intensity", "time", "return_number", "number_of_returns", "rgb",
               "ring", "channel", "sensor_xyz")

    def take(self, index: np.ndarray) -> PointCloud:
        """The rows selected by a boolean mask or an index array."""
        return PointCloud(**{c: None if getattr(self, c) is None else getattr(self, c)[index] for c in self.COLUMNS})

    @staticmethod
    def concatenate(parts: list[PointCloud]) -> PointCloud:
        """Join chunks that carry the same columns."""
        if not parts:
            return PointCloud(xyz=np.empty((0, 3)))
        columns = {}
        for c in PointCloud.COLUMNS:
            values = [getattr(p, c) for p in parts]
            columns[c] = None if any(v is None for v in values) else np.concatenate(values)
        return PointCloud(**columns)


@dataclass(frozen=True)
class CloudHeader:
    """What a cloud writer stores beside the points, so a file explains itself.

    ``origin`` (metres) is the local origin for formats that store coordinates relative to it
    (the LAS offset, the NumPy folder's float32 ``coord``); choose it from the model's bounds.
    ``metadata`` is JSON-able (scanner, settings, seed, software version, ...).
    """

    scheme: LabelScheme
    components: ComponentTable | None = None
    stations: tuple[Station, ...] = ()
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    metadata: Mapping[str, object] = field(default_factory=dict)

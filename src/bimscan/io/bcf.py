"""BCF issues: topics about model components that BIM tools open beside the IFC model.

``write_bcf(out, topics, project_name=...)`` writes a BCF 2.1 file (BIM Collaboration Format, a zip
of XML files: the version BIMcollab, Solibri, Navisworks and Bonsai import) through IfcOpenShell's
``bcf-client`` (import name ``bcf``). Every ``BcfTopic`` becomes a topic with one viewpoint: a
perspective camera, the topic's components selected (by IFC GlobalId), every component visible,
and optionally the selected ones coloured and a PNG snapshot. Coordinates are the IFC model's
world coordinates in metres, as BCF requires.

The bytes are reproducible: topic and viewpoint GUIDs are name-based UUIDs (version 5) of the
project name, title and GlobalIds; dates are ``SOURCE_DATE_EPOCH`` when set, else 1970-01-01; zip
members carry fixed times. ``camera_looking_at(lower, upper)`` gives a camera framing a bounding box.
"""

from __future__ import annotations

import datetime as dt
import io
import math
import uuid
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import write_atomic
from bimscan.ifc.guid import IFC_BASE64
from bimscan.io._writer import check_output_path, output_error, source_date_epoch

Vector = tuple[float, float, float]

BCF_VERSION = "2.1"
BCF_SUFFIXES = (".bcf", ".bcfzip")
SNAPSHOT_NAME = "snapshot.png"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_NAMESPACE = uuid.UUID("5b0d2e8e-6f1c-4d0b-8c52-9f4b7c1e2a63")  # bimscan's BCF GUIDs
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the earliest time a zip member can carry


@dataclass(frozen=True)
class BcfTopic:
    """One issue. global_ids: IFC GlobalIds of the components it is about (selected, and coloured
    with ``color``, in its viewpoint). camera_*: the viewpoint's camera in the model's world metres;
    the direction need not be a unit vector and the up vector need not be square to it (both are
    made so on writing), but they must not be parallel. field_of_view_deg: the camera's vertical
    angle (BCF 2.1 asks viewers for 45-60 degrees; 1-170 is accepted). color: "RRGGBB" or
    "AARRGGBB" hex. snapshot_png: a PNG image of the view, stored as the viewpoint's snapshot."""

    title: str
    description: str
    global_ids: tuple[str, ...]
    camera_position: Vector
    camera_direction: Vector
    camera_up: Vector = (0.0, 0.0, 1.0)
    field_of_view_deg: float = 60.0
    topic_type: str = "Issue"
    status: str = "Open"
    priority: str | None = None
    labels: tuple[str, ...] = ()
    color: str | None = None
    snapshot_png: bytes | None = None

    def __post_init__(self) -> None:
        if not self.title.strip():
            raise ValueError("a BCF topic needs a title")
        for gid in self.global_ids:
            if len(gid) != 22 or gid[0] not in "0123" or any(c not in IFC_BASE64 for c in gid):
                raise ValueError(f"{gid!r} in topic {self.title!r} is not an IFC GlobalId (22 characters of IFC's "
                                 "base 64, the first 0-3)")
        _unit(self.camera_direction, "camera_direction")
        _camera_up(self.camera_direction, self.camera_up)
        _finite(self.camera_position, "camera_position")
        if not 1.0 <= self.field_of_view_deg <= 170.0:
            raise ValueError(f"field_of_view_deg {self.field_of_view_deg} is outside 1-170 degrees")
        if self.color is not None and (len(self.color) not in (6, 8)
                                       or any(c not in "0123456789abcdefABCDEF" for c in self.color)):
            raise ValueError(f"color {self.color!r} is not 6 (RGB) or 8 (ARGB) hex digits")
        if self.snapshot_png is not None and not self.snapshot_png.startswith(PNG_SIGNATURE):
            raise ValueError(f"the snapshot of topic {self.title!r} is not a PNG image")


def camera_looking_at(lower: np.ndarray, upper: np.ndarray, *,
                      field_of_view_deg: float = 60.0) -> tuple[Vector, Vector, Vector]:
    """(position, direction, up) of a camera that frames the box ``lower``-``upper`` ((3,) world
    metres): from the south-west and above (35 degrees down, the isometric view), at the distance
    where the box's bounding sphere (at least 0.5 m across) fills the ``field_of_view_deg`` with a
    10 % margin. ``direction`` and ``up`` are unit vectors square to each other."""
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    if lower.shape != (3,) or upper.shape != (3,) or not (np.isfinite(lower).all() and np.isfinite(upper).all()) \
            or (lower > upper).any():
        raise ValueError(f"the box {lower.tolist()}-{upper.tolist()} is not two finite (3,) corners, lower <= upper")
    centre = (lower + upper) / 2.0
    radius = max(float(np.linalg.norm(upper - lower)) / 2.0, 0.25)
    distance = 1.1 * radius / math.sin(math.radians(field_of_view_deg) / 2.0)
    direction = np.array([1.0, 1.0, -1.0]) / math.sqrt(3.0)
    up = np.array([1.0, 1.0, 2.0]) / math.sqrt(6.0)  # in the vertical plane of the view, square to it
    position = centre - distance * direction
    return _vector(position), _vector(direction), _vector(up)


def check_bcf_output(out: str | Path, *, overwrite: bool = False) -> Path:
    """``out`` as a Path, or an OutputError now for a BCF file that cannot be written there: another
    suffix than ``.bcf`` / ``.bcfzip``, a missing or read-only folder, something there without
    ``overwrite``, or something there bimscan may not replace (another format's file)."""
    out = Path(out)
    if out.suffix.lower() not in BCF_SUFFIXES:
        raise OutputError(f"a BCF file must end in {' or '.join(BCF_SUFFIXES)}, got {str(out)!r}; "
                          "name it like issues.bcf")
    check_output_path(out, overwrite=overwrite)
    return out


def write_bcf(out: str | Path, topics: Sequence[BcfTopic], *, project_name: str, author: str = "bimscan",
              overwrite: bool = False) -> Path:
    """Write ``topics`` as a BCF 2.1 file at ``out`` (atomically); returns its path. Raises
    OutputError for an output that cannot be written (see ``check_bcf_output``)."""
    out = check_bcf_output(out, overwrite=overwrite)
    data = _bcf_bytes(topics, project_name=project_name, author=author)
    try:
        write_atomic(out, data)
    except OSError as exc:
        raise output_error(exc, out) from exc
    return out


def _bcf_bytes(topics: Sequence[BcfTopic], *, project_name: str, author: str = "bimscan") -> bytes:
    """The bytes of the BCF 2.1 file ``write_bcf`` writes."""
    import bcf.v2.model as mdl
    from bcf.v2.topic import TopicHandler
    from bcf.v2.visinfo import VisualizationInfoHandler
    from bcf.xml_parser import XmlParserSerializer
    from xsdata.models.datatype import XmlDateTime

    xml = XmlParserSerializer()
    epoch = source_date_epoch()
    created = XmlDateTime.from_datetime(dt.datetime.fromtimestamp(epoch or 0, tz=dt.UTC))
    members: dict[str, bytes] = {}
    project = mdl.ProjectExtension(
        project=mdl.Project(name=project_name, project_id=str(uuid.uuid5(_NAMESPACE, f"project:{project_name}"))),
        extension_schema="")
    members["bcf.version"] = xml.serialize(mdl.Version(version_id=BCF_VERSION, detailed_version=BCF_VERSION)).encode()
    members["project.bcfp"] = xml.serialize(project).encode()
    seen: dict[str, int] = {}
    for topic in topics:
        guid = _topic_guid(project_name, topic, seen)
        handler = TopicHandler(topic_dir=Path(guid), xml_handler=xml)  # a Path, as bcf-client's own
        handler.markup = mdl.Markup(topic=mdl.Topic(
            guid=guid, title=topic.title, description=topic.description, creation_author=author,
            creation_date=created, topic_type=topic.topic_type, topic_status=topic.status,
            priority=topic.priority, labels=list(topic.labels)))
        viewpoint = VisualizationInfoHandler(_visualization_info(topic, guid), snapshot=topic.snapshot_png,
                                             xml_handler=xml)
        handler.add_visinfo_handler(viewpoint, SNAPSHOT_NAME if topic.snapshot_png is not None else None)
        handler.save(_Members(members))
    return _zip(members)


def _visualization_info(topic: BcfTopic, topic_guid: str):  # -> bcf.v2.model.VisualizationInfo
    """The topic's viewpoint: its camera, its components selected (and coloured), all others shown."""
    import bcf.v2.model as mdl

    direction = _unit(topic.camera_direction, "camera_direction")
    up = _camera_up(topic.camera_direction, topic.camera_up)
    selected = [mdl.Component(ifc_guid=gid) for gid in topic.global_ids]
    coloring = None
    if topic.color is not None and selected:
        coloring = mdl.ComponentColoring(color=[mdl.ComponentColoringColor(
            color=topic.color.upper(), component=[mdl.Component(ifc_guid=gid) for gid in topic.global_ids])])
    return mdl.VisualizationInfo(
        guid=str(uuid.uuid5(_NAMESPACE, f"viewpoint:{topic_guid}")),
        components=mdl.Components(
            view_setup_hints=mdl.ViewSetupHints(spaces_visible=False, space_boundaries_visible=False,
                                                openings_visible=False),
            selection=mdl.ComponentSelection(component=selected) if selected else None,
            visibility=mdl.ComponentVisibility(default_visibility=True),
            coloring=coloring),
        perspective_camera=mdl.PerspectiveCamera(
            camera_view_point=mdl.Point(x=float(topic.camera_position[0]), y=float(topic.camera_position[1]),
                                        z=float(topic.camera_position[2])),
            camera_direction=mdl.Direction(x=direction[0], y=direction[1], z=direction[2]),
            camera_up_vector=mdl.Direction(x=up[0], y=up[1], z=up[2]),
            field_of_view=float(topic.field_of_view_deg)))


def _topic_guid(project_name: str, topic: BcfTopic, seen: dict[str, int]) -> str:
    """A name-based GUID of the project, title and GlobalIds; a topic repeating an earlier one's
    gets its ordinal among them too, so that every topic's GUID is its own."""
    key = "\n".join([project_name, topic.title, *topic.global_ids])
    count = seen.get(key, 0)
    seen[key] = count + 1
    return str(uuid.uuid5(_NAMESPACE, f"topic:{key}" + (f"\n#{count}" if count else "")))


class _Members:
    """The zip-like object bcf-client saves a topic into: its members, kept in order, as bytes."""

    def __init__(self, members: dict[str, bytes]) -> None:
        self.members = members

    def writestr(self, name: str, content: bytes | str) -> None:
        self.members[name] = content.encode() if isinstance(content, str) else content


def _zip(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, content in members.items():
            info = zipfile.ZipInfo(name, date_time=_ZIP_TIME)
            info.create_system = 3  # Unix, whatever the platform, for the same bytes everywhere
            folder = name.endswith("/")
            info.external_attr = ((0o40755 if folder else 0o100644) << 16) | (0x10 if folder else 0)
            info.compress_type = zipfile.ZIP_STORED if folder else zipfile.ZIP_DEFLATED
            archive.writestr(info, content, compresslevel=9)
    return buffer.getvalue()


def _finite(vector: Sequence[float], name: str) -> np.ndarray:
    array = np.asarray(vector, dtype=np.float64)
    if array.shape != (3,) or not np.isfinite(array).all():
        raise ValueError(f"{name} {tuple(vector)!r} is not three finite numbers")
    return array


def _unit(vector: Sequence[float], name: str) -> Vector:
    array = _finite(vector, name)
    length = float(np.linalg.norm(array))
    if length < 1e-9:
        raise ValueError(f"{name} {tuple(vector)!r} has no length")
    return _vector(array / length)


def _camera_up(direction: Sequence[float], up: Sequence[float]) -> Vector:
    """``up`` made square to ``direction`` (its part along the view removed) and of unit length."""
    d = np.asarray(_unit(direction, "camera_direction"))
    u = _finite(up, "camera_up")
    square = u - float(u @ d) * d
    if float(np.linalg.norm(square)) < 1e-6 * max(float(np.linalg.norm(u)), 1e-300):
        raise ValueError(f"camera_up {tuple(up)!r} is zero or parallel to camera_direction {tuple(direction)!r}")
    return _vector(square / np.linalg.norm(square))


def _vector(array: np.ndarray) -> Vector:
    return (float(array[0]), float(array[1]), float(array[2]))

"""BCF issues: topics about model components that BIM tools open beside the IFC model.

``write_bcf(out, topics, project_name=...)`` writes a BCF 2.1 file (BIM Collaboration Format, a zip
of XML files: the version BIMcollab, Solibri, Navisworks and Bonsai import) with the standard
library alone, following buildingSMART's 2.1 schemas (version.xsd, project.xsd, markup.xsd,
visinfo.xsd: their element order, the FieldOfView range 45-60, upper-case colours). Every
``BcfTopic`` becomes a topic folder with ``markup.bcf`` and one viewpoint, ``viewpoint.bcfv`` (the
name BCF 2.1 asks one viewpoint of every topic to have): a perspective camera, the topic's components selected (by IFC
GlobalId), every component visible, and optionally the selected ones coloured and a
``snapshot.png``. Coordinates are the IFC model's world coordinates in metres, as BCF requires.

The bytes are reproducible: topic and viewpoint GUIDs are name-based UUIDs (version 5) of the
project name, title and GlobalIds; dates are ``SOURCE_DATE_EPOCH`` when set, else 1970-01-01; zip
members carry fixed times. ``camera_looking_at(lower, upper)`` gives a camera framing a bounding box.
"""

from __future__ import annotations

import datetime as dt
import io
import math
import re
import uuid
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import write_atomic
from bimscan.ifc.guid import is_global_id
from bimscan.io._writer import check_output_path, output_error, source_date_epoch

Vector = tuple[float, float, float]

BCF_VERSION = "2.1"
BCF_SUFFIXES = (".bcf", ".bcfzip")
VIEWPOINT_NAME = "viewpoint.bcfv"
SNAPSHOT_NAME = "snapshot.png"
FIELD_OF_VIEW_DEG = (45.0, 60.0)  # visinfo.xsd 2.1 restricts PerspectiveCamera/FieldOfView to this
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_NAMESPACE = uuid.UUID("5b0d2e8e-6f1c-4d0b-8c52-9f4b7c1e2a63")  # bimscan's BCF GUIDs
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the earliest time a zip member can carry
_NOT_XML = re.compile("[^\t\n\r\u0020-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")  # outside XML 1.0's Char


@dataclass(frozen=True)
class BcfTopic:
    """One issue. global_ids: IFC GlobalIds of the components it is about (selected, and coloured
    with ``color``, in its viewpoint). camera_*: the viewpoint's camera in the model's world metres;
    the direction need not be a unit vector and the up vector need not be square to it (both are
    made so on writing), but they must not be parallel. field_of_view_deg: the camera's vertical
    angle, 45-60 degrees (the range BCF 2.1's schema allows). color: "RRGGBB" or "AARRGGBB" hex
    (BCF 2.1's ARGB, the alpha first; written upper-case). snapshot_png: a PNG image of the view, stored as
    the viewpoint's snapshot. Text must hold only characters XML 1.0 can carry."""

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
        for name in ("title", "description", "topic_type", "status", "priority"):
            if getattr(self, name) is not None:
                _xml_text(getattr(self, name), name)
        for label in self.labels:
            _xml_text(label, "label")
        for gid in self.global_ids:
            if not is_global_id(gid):
                raise ValueError(f"{gid!r} in topic {self.title!r} is not an IFC GlobalId (22 characters of IFC's "
                                 "base 64, the first 0-3)")
        _unit(self.camera_direction, "camera_direction")
        _camera_up(self.camera_direction, self.camera_up)
        _finite(self.camera_position, "camera_position")
        low, high = FIELD_OF_VIEW_DEG
        if not low <= self.field_of_view_deg <= high:
            raise ValueError(f"field_of_view_deg {self.field_of_view_deg} is outside {low:g}-{high:g} degrees, the "
                             "range BCF 2.1 allows; move the camera instead")
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
    """The bytes of the BCF 2.1 file ``write_bcf`` writes: ``bcf.version``, ``project.bcfp``, then a
    folder per topic (its GUID) with ``markup.bcf``, ``viewpoint.bcfv`` and maybe ``snapshot.png``."""
    _xml_text(project_name, "project_name")
    _xml_text(author, "author")
    epoch = source_date_epoch()
    created = dt.datetime.fromtimestamp(epoch or 0, tz=dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    version = ET.Element("Version", VersionId=BCF_VERSION)
    _child(version, "DetailedVersion", BCF_VERSION)
    project = ET.Element("ProjectExtension")
    _child(_child(project, "Project", ProjectId=str(uuid.uuid5(_NAMESPACE, f"project:{project_name}"))),
           "Name", project_name)
    _child(project, "ExtensionSchema", "")  # required; empty: bimscan defines no extensions
    members = {"bcf.version": _xml_bytes(version), "project.bcfp": _xml_bytes(project)}
    seen: dict[str, int] = {}
    for topic in topics:
        guid = _topic_guid(project_name, topic, seen)
        viewpoint_guid = str(uuid.uuid5(_NAMESPACE, f"viewpoint:{guid}"))
        members[f"{guid}/"] = b""
        members[f"{guid}/markup.bcf"] = _xml_bytes(_markup(topic, guid, viewpoint_guid, created, author))
        members[f"{guid}/{VIEWPOINT_NAME}"] = _xml_bytes(_visualization_info(topic, viewpoint_guid))
        if topic.snapshot_png is not None:
            members[f"{guid}/{SNAPSHOT_NAME}"] = topic.snapshot_png
    return _zip(members)


def _markup(topic: BcfTopic, guid: str, viewpoint_guid: str, created: str, author: str) -> ET.Element:
    """markup.bcf: the topic and its one viewpoint (children in markup.xsd's sequence order)."""
    markup = ET.Element("Markup")
    element = _child(markup, "Topic", Guid=guid, TopicType=topic.topic_type, TopicStatus=topic.status)
    _child(element, "Title", topic.title)
    if topic.priority is not None:
        _child(element, "Priority", topic.priority)
    for label in topic.labels:
        _child(element, "Labels", label)
    _child(element, "CreationDate", created)
    _child(element, "CreationAuthor", author)
    _child(element, "Description", topic.description)
    viewpoints = _child(markup, "Viewpoints", Guid=viewpoint_guid)
    _child(viewpoints, "Viewpoint", VIEWPOINT_NAME)
    if topic.snapshot_png is not None:
        _child(viewpoints, "Snapshot", SNAPSHOT_NAME)
    return markup


def _visualization_info(topic: BcfTopic, viewpoint_guid: str) -> ET.Element:
    """viewpoint.bcfv: the topic's camera, its components selected (and coloured), all others shown
    (children in visinfo.xsd's sequence order)."""
    info = ET.Element("VisualizationInfo", Guid=viewpoint_guid)
    components = _child(info, "Components")
    _child(components, "ViewSetupHints", SpacesVisible="false", SpaceBoundariesVisible="false",
           OpeningsVisible="false")
    if topic.global_ids:
        selection = _child(components, "Selection")
        for gid in topic.global_ids:
            _child(selection, "Component", IfcGuid=gid)
    _child(components, "Visibility", DefaultVisibility="true")
    if topic.color is not None and topic.global_ids:
        color = _child(_child(components, "Coloring"), "Color", Color=topic.color.upper())
        for gid in topic.global_ids:
            _child(color, "Component", IfcGuid=gid)
    camera = _child(info, "PerspectiveCamera")
    for name, vector in (("CameraViewPoint", _vector(_finite(topic.camera_position, "camera_position"))),
                         ("CameraDirection", _unit(topic.camera_direction, "camera_direction")),
                         ("CameraUpVector", _camera_up(topic.camera_direction, topic.camera_up))):
        point = _child(camera, name)
        for axis, value in zip("XYZ", vector, strict=True):
            _child(point, axis, repr(value))  # the shortest text that reads back as the same double
    _child(camera, "FieldOfView", repr(float(topic.field_of_view_deg)))
    return info


def _child(parent: ET.Element, tag: str, text: str | None = None, **attributes: str) -> ET.Element:
    element = ET.SubElement(parent, tag, attributes)
    element.text = text
    return element


def _xml_bytes(root: ET.Element) -> bytes:
    """A UTF-8 XML document: ElementTree escapes text and attributes, attributes keep their order."""
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode").encode("utf-8") + b"\n"


def _xml_text(text: str, name: str) -> str:
    """``text``, or a ValueError for a character XML 1.0 cannot carry (control characters other than
    tab and line breaks, lone surrogates, U+FFFE/U+FFFF): ElementTree would write them unescaped."""
    bad = _NOT_XML.search(text)
    if bad is not None:
        raise ValueError(f"{name} {text!r} holds the character U+{ord(bad.group()):04X}, which XML cannot carry; "
                         "remove it")
    return text


def _topic_guid(project_name: str, topic: BcfTopic, seen: dict[str, int]) -> str:
    """A name-based GUID of the project, title and GlobalIds; a topic repeating an earlier one's
    gets its ordinal among them too, so that every topic's GUID is its own."""
    key = "\n".join([project_name, topic.title, *topic.global_ids])
    count = seen.get(key, 0)
    seen[key] = count + 1
    return str(uuid.uuid5(_NAMESPACE, f"topic:{key}" + (f"\n#{count}" if count else "")))


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

"""BIM-to-OBJ export with a component index, and an OBJ reader to check it.

``export_obj(scene, out_dir)`` writes into ``out_dir``:

- ``model.obj``: the whole scene, one group per component named ``c<id>_<GlobalId>``
  (``g`` line), each group's vertices followed by its triangles (1-based, file-global indices).
- ``components/c<id>.obj``: one OBJ per component with triangles (HELIOS++ loads one scene part
  per file and ignores groups). Components without triangles get no file.
- ``classes.mtl``: one material ``class_<id>`` per semantic class (diffuse colour = class
  colour, ``helios_classification <id>`` so HELIOS++ writes the class into its output); every
  group/file says ``usemtl class_<label>``.
- ``index.csv``: component, global_id, ifc_class, predefined_type, name, storey, label,
  label_name, n_triangles, obj_file (one row per row of the component table).
- with ``helios=True``: ``helios/scene.xml``, and ``helios/survey.xml`` when the caller passes
  the survey's XML (``bimscan.io.helios.helios_survey_xml``; see ``bimscan.io.helios``).

Coordinates are written in metres with 6 decimals (1 micrometre). Text is formatted with one
``%`` operation per component block, which writes a 2.4M-triangle model in seconds. Everything
is built in a hidden staging folder inside ``out_dir`` and moved into place at the end; a failure
leaves ``out_dir`` as it was. ``out_dir`` is an output folder as every command's
(``bimscan.files.prepare_output_folder``): new, empty, or one bimscan made (its record lists what
bimscan wrote there; an earlier version's export is recognised by its ``index.csv``). With
``overwrite``, an output already in ``out_dir`` is replaced only when the record lists it and it
is what this export writes there (``bimscan.files.check_replaceable``): a ``components/`` folder of
bimscan component OBJs only (``FOLDER_OUTPUTS["obj-components"]``) and a ``helios/`` folder of
bimscan's HELIOS++ files only (``FOLDER_OUTPUTS["helios"]``). Files the user put beside them are
never touched.
"""

from __future__ import annotations

import csv
import io
import re
import shutil
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.errors import InputFileError, OutputError
from bimscan.files import (
    FOLDER_OUTPUTS,
    FolderOutput,
    check_output_folder,
    check_replaceable,
    file_head,
    folder_entries,
    prepare_output_folder,
    read_marker,
    temp_path,
)
from bimscan.io._writer import commit_output, output_error
from bimscan.io.helios import HELIOS_DIR, SCENE_FILE, SURVEY_FILE, helios_scene_id, write_helios_scene
from bimscan.types import BimScene

COORD_FORMAT = "%.6f"
INDEX_COLUMNS = (
    "component", "global_id", "ifc_class", "predefined_type", "name", "storey", "label", "label_name",
    "n_triangles", "obj_file",
)
MATERIALS_NAME = "classes.mtl"
COMPONENTS_DIR = "components"
_COMPONENT_FILE = re.compile(r"c[0-9]+\.obj")
_COMPONENT_HEAD = b"# bimscan component "
_HELIOS_FILE = re.compile(r"scene\.xml|survey\.xml|survey_mount[0-9]+\.xml|trajectory_mount[0-9]+\.trj")
_XML_HEAD = b'<?xml version="1.0" encoding="UTF-8"?>\n<document>\n'
_SCENE_PART = re.compile(rb'key="filepath" value="([^"]*)"')
_SCENE_PART_PATH = re.compile(rb"components/c[0-9]+\.obj")


def _foreign_components(folder: Path) -> list[str] | None:
    """None unless ``folder`` holds bimscan component OBJs (``c<id>.obj`` starting with bimscan's
    comment); then its other entries."""
    names = folder_entries(folder)
    ours = [n for n in names if _COMPONENT_FILE.fullmatch(n)
            and (file_head(folder / n, len(_COMPONENT_HEAD)) or b"").startswith(_COMPONENT_HEAD)]
    return [n for n in names if n not in ours] if ours else None


def _foreign_helios(folder: Path) -> list[str] | None:
    """None unless ``folder`` holds bimscan's HELIOS++ scene (``scene.xml`` whose parts are all
    ``components/c<id>.obj``); then the entries bimscan does not write there."""
    scene = read_marker(folder / "scene.xml")
    if scene is None or not scene.startswith(_XML_HEAD) or \
            not all(_SCENE_PART_PATH.fullmatch(part) for part in _SCENE_PART.findall(scene)):
        return None
    foreign = []
    for name in folder_entries(folder):
        head = (file_head(folder / name, len(_XML_HEAD)) or b"") if _HELIOS_FILE.fullmatch(name) else b""
        if not head.startswith(_XML_HEAD if name.endswith(".xml") else b"#TIME_COLUMN: 0\n"):
            foreign.append(name)
    return foreign


FOLDER_OUTPUTS["obj-components"] = FolderOutput(what="a folder of bimscan component OBJs", foreign=_foreign_components)
FOLDER_OUTPUTS["helios"] = FolderOutput(what="bimscan's HELIOS++ scene folder", foreign=_foreign_helios)
# what export_obj writes into out_dir, and the folder kind of those that are folders
_FOLDER_KINDS = {COMPONENTS_DIR: "obj-components", HELIOS_DIR: "helios"}


@dataclass(frozen=True)
class ObjExport:
    """What ``export_obj`` wrote (absolute paths inside ``out_dir``).

    component_files maps component id -> its OBJ (components with triangles only);
    n_triangles is the total written to ``model.obj``.
    """

    out_dir: Path
    model_obj: Path
    materials: Path
    index_csv: Path
    component_files: dict[int, Path]
    helios_scene: Path | None
    n_triangles: int
    helios_survey: Path | None = None


def group_name(component: int, global_id: str) -> str:
    """The OBJ group name of a component: ``c<id>_<GlobalId>`` (no spaces)."""
    return f"c{component}_{global_id}".replace(" ", "_")


def _materials_text(scene: BimScene) -> str:
    lines = ["# bimscan semantic classes; helios_classification is read by HELIOS++"]
    labels = {c.id: c for c in scene.scheme.classes}
    for label in sorted(set(labels) | {int(v) for v in scene.components.label}):
        cls = labels.get(label)
        r, g, b = (v / 255.0 for v in cls.rgb) if cls else (0.5, 0.5, 0.5)
        lines += [
            "", f"newmtl class_{label}", f"# {cls.name if cls else 'unknown class'}",
            "Ka 0.0 0.0 0.0", f"Kd {r:.4f} {g:.4f} {b:.4f}", "Ks 0.0 0.0 0.0",
            f"helios_classification {label}",
        ]
    return "\n".join(lines) + "\n"


def _block(fmt: str, values: np.ndarray) -> str:
    """Rows of ``values`` formatted with ``fmt`` (one line per row), in one C-level operation."""
    if len(values) == 0:
        return ""
    return (fmt * len(values)) % tuple(values.ravel().tolist())


def _exported_here(folder: Path) -> bool:
    """Whether ``folder`` holds an export an earlier bimscan wrote (before output folders had
    their record): its ``index.csv`` starts with the index's header."""
    head = file_head(folder / "index.csv", 256)
    return head is not None and head.startswith(",".join(INDEX_COLUMNS).encode())


def export_obj(scene: BimScene, out_dir: str | Path, *, helios: bool = False, helios_survey: bytes | None = None,
               helios_files: Mapping[str, bytes] | None = None,
               overwrite: bool = False) -> ObjExport:
    """Write the scene as OBJ files with a component index into ``out_dir`` (created if missing).

    ``helios``: also the HELIOS++ scene; ``helios_survey``: the HELIOS++ survey document to
    store beside it (needs ``helios``); ``helios_files``: more HELIOS++ files by path relative to
    ``out_dir`` (a mobile survey's surveys and trajectories, ``io.helios.helios_mobile_files``). Raises OutputError when ``out_dir``'s parent is missing,
    when an output already exists and ``overwrite`` is False, or when the disk fills up.
    """
    if (helios_survey is not None or helios_files) and not helios:
        raise ValueError("a HELIOS++ survey needs the HELIOS++ scene: pass helios=True")
    out_dir = Path(out_dir)
    if not out_dir.parent.is_dir():
        raise OutputError(f"folder {out_dir.parent} does not exist; create it first or choose another output folder")
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir} is a file, not a folder; choose another output folder")
    names = ["model.obj", MATERIALS_NAME, COMPONENTS_DIR, "index.csv"] + ([HELIOS_DIR] if helios else [])
    folder_names = [name + "/" if name in _FOLDER_KINDS else name for name in names]
    check_output_folder(out_dir, names=folder_names, made_by=_exported_here)
    existing = [n for n in names if (out_dir / n).exists() or (out_dir / n).is_symlink()]
    if existing and not overwrite:
        raise OutputError(f"{out_dir} already holds {', '.join(existing)}; pass --overwrite to replace them or choose "
                          "another folder")
    for name in existing:
        check_replaceable(out_dir / name, kind=_FOLDER_KINDS.get(name))
    mesh = scene.mesh
    if len(mesh.face_component) and mesh.face_component.min() < 0:
        raise OutputError(f"scene {scene.source}: some triangles have a negative component id; the scene mesh is invalid")
    created = not out_dir.exists()
    stage = temp_path(out_dir / "obj-export")
    done = False
    try:
        prepare_output_folder(out_dir, names=folder_names, made_by=_exported_here)
        stage.mkdir()
        files = _write_all(scene, stage, helios=helios)
        if helios_survey is not None:
            (stage / SURVEY_FILE).write_bytes(helios_survey)
        for relative, data in (helios_files or {}).items():  # a mobile survey: surveys and trajectories
            (stage / relative).write_bytes(data)
        for name in names:
            commit_output(stage / name, out_dir / name, overwrite=True, kind=_FOLDER_KINDS.get(name))
        done = True
    except OSError as exc:
        raise output_error(exc, out_dir) from exc
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if created and not done:
            shutil.rmtree(out_dir, ignore_errors=True)  # a folder we made holds nothing finished
    return ObjExport(
        out_dir=out_dir,
        model_obj=out_dir / "model.obj",
        materials=out_dir / MATERIALS_NAME,
        index_csv=out_dir / "index.csv",
        component_files={c: out_dir / COMPONENTS_DIR / f"c{c}.obj" for c in files},
        helios_scene=(out_dir / SCENE_FILE) if helios else None,
        n_triangles=mesh.n_triangles,
        helios_survey=(out_dir / SURVEY_FILE) if helios_survey is not None or helios_files else None,
    )


def _write_all(scene: BimScene, stage: Path, *, helios: bool) -> list[int]:
    """Write every output into ``stage``; returns the ids of components that got a file."""
    mesh, table = scene.mesh, scene.components
    n_components = len(table)
    # Group triangles by component (stable, so the order within a component is the mesh's), and
    # give each component its own copy of the vertices it uses, in ascending original order.
    order = np.argsort(mesh.face_component, kind="stable")
    faces = mesh.faces[order]
    face_component = mesh.face_component[order].astype(np.int64)
    vertices, global_faces, vertex_component = _split_vertices(mesh.vertices, faces, face_component)
    face_counts = np.bincount(face_component, minlength=n_components)
    vertex_counts = np.bincount(vertex_component, minlength=n_components)
    face_starts = np.concatenate([[0], np.cumsum(face_counts)])
    vertex_starts = np.concatenate([[0], np.cumsum(vertex_counts)])

    labels = scene.scheme.names
    source = Path(scene.source).name
    (stage / COMPONENTS_DIR).mkdir()
    (stage / MATERIALS_NAME).write_text(_materials_text(scene), encoding="utf-8")
    vertex_format = f"v {COORD_FORMAT} {COORD_FORMAT} {COORD_FORMAT}\n"
    written: list[int] = []
    with (stage / "model.obj").open("w", encoding="utf-8", newline="\n") as model:
        model.write(f"# bimscan OBJ export of {source}: one group per component, c<id>_<GlobalId>\n")
        model.write(f"mtllib {MATERIALS_NAME}\n")
        for component in range(n_components):
            f0, f1 = face_starts[component], face_starts[component + 1]
            if f1 == f0:
                continue
            v0, v1 = vertex_starts[component], vertex_starts[component + 1]
            name = group_name(component, str(table.global_id[component]))
            label = int(table.label[component])
            vertex_text = _block(vertex_format, vertices[v0:v1])
            head = f"g {name}\nusemtl class_{label}\n"
            model.write(head + vertex_text + _block("f %d %d %d\n", global_faces[f0:f1] + 1))
            part = (
                f"# bimscan component {component} {table.global_id[component]} {table.ifc_class[component]} of {source}\n"
                f"mtllib ../{MATERIALS_NAME}\n"
                + head + vertex_text + _block("f %d %d %d\n", global_faces[f0:f1] - v0 + 1)
            )
            (stage / COMPONENTS_DIR / f"c{component}.obj").write_text(part, encoding="utf-8")
            written.append(component)

    has_file = set(written)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(INDEX_COLUMNS)
    for row in table.rows():
        component = int(row["component"])  # type: ignore[call-overload]
        writer.writerow([
            component, row["global_id"], row["ifc_class"], row["predefined_type"], row["name"], row["storey"],
            row["label"], labels.get(int(row["label"]), ""),  # type: ignore[call-overload]
            int(face_counts[component]) if component < len(face_counts) else 0,
            f"components/c{component}.obj" if component in has_file else "",
        ])
    (stage / "index.csv").write_text(buffer.getvalue(), encoding="utf-8")

    if helios:
        (stage / HELIOS_DIR).mkdir()
        write_helios_scene(
            stage / SCENE_FILE, parts=[(c, f"components/c{c}.obj") for c in written],
            scene_id=helios_scene_id(source), name=source,
        )
    return written


def _split_vertices(
    vertices: np.ndarray, faces: np.ndarray, face_component: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-component vertex copies for faces sorted by component.

    Returns (vertices (V',3) f8 grouped by component, faces (F,3) i8 indexing them, the
    component of each new vertex). Vertices shared between components are duplicated.
    """
    n_vertices = max(len(vertices), 1)
    owner = np.full(n_vertices, -1, dtype=np.int64)
    owner[faces.ravel()] = np.repeat(face_component, 3)
    if np.array_equal(owner[faces], np.broadcast_to(face_component[:, None], faces.shape)):
        # Fast path (IFC elements rarely share vertices): a stable sort of the owners groups the
        # vertices by component, ascending within each, with no sort of (component, vertex) keys.
        used = np.flatnonzero(owner >= 0)
        kept = used[np.argsort(owner[used], kind="stable")]
        new_index = np.empty(n_vertices, dtype=np.int64)
        new_index[kept] = np.arange(len(kept))
        return vertices[kept], new_index[faces], owner[kept]
    keys = (face_component[:, None] * n_vertices + faces).ravel()
    unique_keys, inverse = np.unique(keys, return_inverse=True)
    return vertices[unique_keys % n_vertices], inverse.reshape(-1, 3).astype(np.int64), unique_keys // n_vertices


# -- reading ------------------------------------------------------------------------------------

def _parse_numbers(text: bytes, dtype: type, count: int) -> np.ndarray | None:
    """``count`` whitespace-separated numbers parsed in C, or None when the text holds others."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy warns, not raises, on junk
        try:
            values = np.fromstring(text, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    return values if len(values) == count else None


def _parse_index(token: bytes, n_vertices: int) -> int:
    value = int(token.split(b"/", 1)[0])
    return value - 1 if value > 0 else n_vertices + value  # OBJ: 1-based, negative = relative


def read_obj(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Read an OBJ file as {group name: (vertices (V,3) f8, faces (F,3) i4)}.

    Each group gets the vertices its faces use (in ascending file order) and faces indexing
    them; polygons are split into triangle fans; ``o`` counts as a group; faces before any
    group go to ``"default"``. Texture/normal indices and vertex colours are ignored.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such OBJ file; check the path")
    vertex_lines: list[bytes] = []
    groups: dict[str, list[bytes]] = {}
    current = groups.setdefault("default", [])
    with path.open("rb") as handle:
        for line in handle.read().splitlines():
            head = line[:2]
            if head == b"v ":
                vertex_lines.append(line[2:])
            elif head == b"f ":
                current.append(line[2:])
            elif head in (b"g ", b"o "):
                current = groups.setdefault(line[2:].decode("utf-8", "replace").strip() or "default", [])
    where = str(path)
    flat = _parse_numbers(b" ".join(vertex_lines), np.float64, 3 * len(vertex_lines))
    if flat is None:  # vertex colours or w: keep the first three numbers of every line
        try:
            flat = np.array([line.split()[:3] for line in vertex_lines], dtype=np.float64)
        except ValueError as exc:
            raise InputFileError(f"{where}: unreadable OBJ vertex line ({exc}); check the file") from exc
    vertices = flat.reshape(-1, 3)
    result: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, lines in groups.items():
        if not lines:
            continue
        triangles = _parse_faces(lines, len(vertices), where=where)
        if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(vertices)):
            raise InputFileError(f"{where}: group {name!r} has face indices outside the {len(vertices)} vertices")
        used, local = np.unique(triangles, return_inverse=True)
        result[name] = (vertices[used], local.reshape(-1, 3).astype(np.int32))
    return result


def _parse_faces(lines: list[bytes], n_vertices: int, *, where: str) -> np.ndarray:
    text = b" ".join(lines)
    if b"/" not in text:  # fast path: plain triangles
        values = _parse_numbers(text, np.int64, 3 * len(lines))
        if values is not None:
            values = values.reshape(-1, 3)
            return np.where(values > 0, values - 1, n_vertices + values)
    triangles: list[tuple[int, int, int]] = []
    for line in lines:
        try:
            corners = [_parse_index(t, n_vertices) for t in line.split()]
        except ValueError as exc:
            raise InputFileError(f"{where}: unreadable OBJ face line {line.strip()!r}; check the file") from exc
        triangles.extend((corners[0], corners[i], corners[i + 1]) for i in range(1, len(corners) - 1))
    return np.array(triangles, dtype=np.int64).reshape(-1, 3)


__all__ = ["COORD_FORMAT", "INDEX_COLUMNS", "ObjExport", "export_obj", "group_name", "read_obj"]

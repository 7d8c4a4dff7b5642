"""The folders ``bimscan align`` and ``bimscan progress`` write, and the one place that knows
their layout.

Alignment folder:

- ``transform.json``: the 4x4 matrix (scan frame -> model frame), its inverse, the residuals,
  the inlier share, what the fit leaves free, the alternatives, the settings;
- ``transform.txt``: the matrix alone, four lines of four numbers (CloudCompare's "Apply
  transformation" and PDAL's ``filters.transformation`` read it);
- ``aligned.<format>`` with ``--aligned``: the scan moved into the model's frame.

Progress folder: ``transform.json`` / ``transform.txt`` (the matrix used) and

- ``elements.csv``: one row per model element: GlobalId, IFC class, class, storey, name, status,
  visible and supported shares, areas, points, deviation, tolerance, schedule;
- ``summary.json``: counts and percent complete by class and storey, the views, the settings;
- ``progress.ifc``: the model with a property set ``bimscan_ScanComparison`` on every element;
- ``points.<format>``: the scan in the model's frame, each point with its element (``component``,
  its class as ``label``) and its signed distance to the model (extra field ``distance_m``);
- ``issues.bcf``: a BCF topic per element out of tolerance or behind schedule;
- ``progress_<n>_<storey>.png`` and ``deviation_<n>_<storey>.png``: the pictures.

Both folders are written under a temporary name and renamed when complete; an existing OUT is
replaced only with ``overwrite`` and only when it is such a folder bimscan wrote
(``FOLDER_OUTPUTS``), holding nothing else.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.compare.planes import apply
from bimscan.errors import InputFileError
from bimscan.files import (
    FOLDER_OUTPUTS,
    FolderOutput,
    check_input_file,
    dump_json,
    folder_entries,
    read_marker,
    remove_path,
    replace_path,
    temp_path,
)

TRANSFORM_JSON = "transform.json"
TRANSFORM_TEXT = "transform.txt"
# a control point pair further than this from where the pose all pairs agree on puts it is named in a
# warning: a mismatched or mistyped target (survey control for scan registration: a few millimetres)
CONTROL_RESIDUAL_M = 0.01
ELEMENTS_FILE = "elements.csv"
SUMMARY_FILE = "summary.json"
IFC_FILE = "progress.ifc"
BCF_FILE = "issues.bcf"
POINTS_STEM = "points"
ALIGNED_STEM = "aligned"
PSET_NAME = "bimscan_ScanComparison"
ALIGN_KIND = "bimscan align"
PROGRESS_KIND = "bimscan progress"
ELEMENT_COLUMNS = (
    "global_id", "ifc_class", "class", "storey", "name", "status", "visible_share", "supported_share", "area_m2",
    "visible_m2", "points", "deviation_mm", "offset_x_mm", "offset_y_mm", "offset_z_mm", "rotation_x_deg",
    "rotation_y_deg", "rotation_z_deg", "max_shift_mm", "tolerance_mm", "expected", "schedule",
)


def _is_output(name: str, stems: tuple[str, ...], files: tuple[str, ...], pictures: bool) -> bool:
    return name in files or any(name.startswith(stem + ".") for stem in stems) or (
        pictures and name.endswith(".png") and name.split("_", 1)[0] in ("progress", "deviation"))


def _foreign(kind: str, stems: tuple[str, ...], files: tuple[str, ...], pictures: bool, marker: str):
    def foreign(folder: Path) -> list[str] | None:
        data = read_marker(folder / marker)
        try:
            if data is None or json.loads(data).get("kind") != kind:
                return None
        except (ValueError, AttributeError):
            return None
        return [name for name in folder_entries(folder) if not _is_output(name, stems, files, pictures)]
    return foreign


FOLDER_OUTPUTS["alignment"] = FolderOutput(
    what="a bimscan alignment folder",
    foreign=_foreign(ALIGN_KIND, (ALIGNED_STEM,), (TRANSFORM_JSON, TRANSFORM_TEXT), False, TRANSFORM_JSON))
FOLDER_OUTPUTS["progress"] = FolderOutput(
    what="a bimscan progress folder",
    foreign=_foreign(PROGRESS_KIND, (POINTS_STEM,), (TRANSFORM_JSON, TRANSFORM_TEXT, ELEMENTS_FILE, SUMMARY_FILE,
                                                     IFC_FILE, BCF_FILE), True, SUMMARY_FILE))


class StagedFolder:
    """A folder written under a temporary name beside ``out`` and renamed over it by ``commit``
    (``kind``: its ``FOLDER_OUTPUTS`` kind); removed by ``discard`` when the work fails. As a
    context manager: committed when the block ends normally, discarded when it raises."""

    def __init__(self, out: Path, *, kind: str) -> None:
        self.out, self.kind = out, kind
        self.path = temp_path(out)
        self.path.mkdir()

    def commit(self) -> Path:
        replace_path(self.path, self.out, kind=self.kind)
        return self.out

    def discard(self) -> None:
        remove_path(self.path)

    def __enter__(self) -> StagedFolder:
        return self

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        """Put the folder in place when the block ends normally; remove it when it raises."""
        try:
            if kind is None:
                self.commit()
        finally:
            if kind is not None or self.path.exists():
                self.discard()


def format_matrix(matrix: np.ndarray) -> str:
    """The matrix as four lines of four numbers (CloudCompare's and PDAL's text form), with enough
    digits for millimetres at map coordinates."""
    return "".join(" ".join(f"{v:.12g}" if abs(v) < 1e4 else f"{v:.6f}" for v in row) + "\n" for row in matrix)


def _rigid_from_pairs(scan: np.ndarray, model: np.ndarray) -> np.ndarray:
    """The rigid motion (4, 4) that best maps points ``scan`` (N, 3) onto ``model`` (N, 3) (Kabsch)."""
    cs, cm = scan.mean(axis=0), model.mean(axis=0)
    u, _, vt = np.linalg.svd((scan - cs).T @ (model - cm))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    matrix[:3, 3] = cm - rotation @ cs
    return matrix


def _rows(text: str) -> list[list[str]]:
    """The values of a matrix or point-pair file, line by line (commas or blanks; # comments)."""
    return [line.replace(",", " ").split() for line in text.splitlines()
            if line.strip() and not line.lstrip().startswith("#")]


def read_transform(path: str | Path, *, pairs: bool = False) -> np.ndarray:
    """A 4x4 scan -> model matrix from ``path``: an alignment's ``transform.json``, or four lines of four
    numbers (``transform.txt``, CloudCompare's matrix file); with ``pairs`` also a CSV of three or more
    point pairs ``scan_x,scan_y,scan_z,model_x,model_y,model_z`` (solved by Kabsch)."""
    return read_pose(path, pairs=pairs)[0]


def read_pose(path: str | Path, *, pairs: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """``read_transform``'s matrix and, when the file held point pairs, those pairs (N, 6)."""
    path = check_input_file(path, what="a transform file")
    try:
        text = path.read_text("utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: not a readable text file ({exc}); pass a transform.json or a 4x4 matrix") from exc
    if text.lstrip().startswith("{"):
        try:
            matrix = np.array(json.loads(text)["matrix"], dtype=np.float64)
        except (ValueError, KeyError, TypeError) as exc:
            raise InputFileError(f"{path}: not a bimscan transform.json (no 4x4 'matrix'); pass the file "
                                 "'bimscan align' wrote") from exc
    else:
        rows = _rows(text)
        try:
            numbers = [[float(v) for v in row] for row in rows]
        except ValueError as exc:
            raise InputFileError(f"{path}: holds text that is not numbers ({exc}); pass four lines of four numbers"
                                 + (" or lines of point pairs" if pairs else "")) from exc
        if pairs and numbers and all(len(r) == 6 for r in numbers):
            if len(numbers) < 3:
                raise InputFileError(f"{path}: {len(numbers)} point pairs; give at least three, not on one line")
            data = np.array(numbers)
            if not np.all(np.isfinite(data)) or np.linalg.matrix_rank(data[:, :3] - data[:, :3].mean(axis=0),
                                                                     tol=1e-3) < 2:
                raise InputFileError(f"{path}: the point pairs' scan points lie on one line (or are not finite "
                                     "numbers); give three or more points spread over the site")
            return _rigid_from_pairs(data[:, :3], data[:, 3:]), data
        matrix = np.array(numbers, dtype=np.float64) if numbers and all(len(r) == 4 for r in numbers) else np.zeros(0)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise InputFileError(f"{path}: not a 4x4 matrix of finite numbers; pass four lines of four numbers"
                             + (" or lines of point pairs scan_x,scan_y,scan_z,model_x,model_y,model_z" if pairs else ""))
    rotation = matrix[:3, :3]
    if not np.allclose(matrix[3], [0, 0, 0, 1], atol=1e-9) or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4) \
            or np.linalg.det(rotation) < 0:
        raise InputFileError(f"{path}: the matrix is not a rigid motion (a rotation and a translation, last row "
                             "0 0 0 1); bimscan aligns without scaling or mirroring")
    return matrix, None


def pair_residuals_m(pairs: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Where ``matrix`` leaves each point pair (N, 6) scan -> model (its distances, metres): how well
    control points agree with the pose."""
    return np.linalg.norm(apply(matrix, pairs[:, :3]) - pairs[:, 3:], axis=1)


def transform_document(matrix: np.ndarray, *, kind: str, model: Path, scan: Path,
                       alignment: dict[str, Any] | None, control: dict[str, Any] | None = None) -> dict[str, Any]:
    """What ``transform.json`` holds."""
    document: dict[str, Any] = {"kind": kind, "model": str(model), "scan": str(scan),
                                "matrix": [[float(v) for v in row] for row in matrix],
                                "maps": "scan frame -> model frame (world metres): p_model = matrix @ [p_scan, 1]"}
    if alignment is not None:
        document["alignment"] = alignment
    if control is not None:
        document["control"] = control
    return document


def control_document(path: Path, residuals_m: np.ndarray) -> dict[str, Any]:
    """What a pose from control point pairs records: the file, the pairs' residuals (mm)."""
    return {"file": str(path), "pairs": len(residuals_m), "residual_mm": [round(float(r) * 1000, 2) for r in residuals_m],
            "median_mm": round(float(np.median(residuals_m)) * 1000, 2), "max_mm": round(float(residuals_m.max()) * 1000, 2)}


def _finite(value: float, scale: float = 1.0, digits: int = 1) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value * scale:.{digits}f}"


def element_rows(result: Any, scene: Any) -> list[dict[str, str]]:
    """The rows of ``elements.csv`` (``ELEMENT_COLUMNS``), in the model's component order."""
    elements = result.elements
    names = scene.scheme.names
    components = scene.components
    visible, supported = elements.visible_share, elements.supported_share
    rows = []
    for c in range(len(components)):
        fit = elements.fits[c]
        expected = int(elements.expected[c])
        rows.append({
            "global_id": str(components.global_id[c]), "ifc_class": str(components.ifc_class[c]),
            "class": names.get(int(components.label[c]), ""), "storey": str(components.storey[c]),
            "name": str(components.name[c]), "status": str(elements.status[c]),
            "visible_share": f"{visible[c]:.4f}", "supported_share": f"{supported[c]:.4f}",
            "area_m2": f"{elements.area_m2[c]:.3f}", "visible_m2": f"{elements.visible_m2[c]:.3f}",
            "points": str(int(elements.points[c])), "deviation_mm": _finite(fit.median_signed_m, 1000.0),
            "offset_x_mm": _finite(fit.offset_m[0], 1000.0), "offset_y_mm": _finite(fit.offset_m[1], 1000.0),
            "offset_z_mm": _finite(fit.offset_m[2], 1000.0), "rotation_x_deg": _finite(fit.rotation_deg[0], 1.0, 4),
            "rotation_y_deg": _finite(fit.rotation_deg[1], 1.0, 4), "rotation_z_deg": _finite(fit.rotation_deg[2], 1.0, 4),
            "max_shift_mm": _finite(fit.max_shift_m, 1000.0), "tolerance_mm": _finite(elements.tolerance_m[c], 1000.0),
            "expected": {1: "yes", 0: "no"}.get(expected, ""), "schedule": str(elements.schedule[c]),
        })
    return rows


def property_values(result: Any, scene: Any) -> dict[int, dict[str, str | float | None]]:
    """STEP id -> the properties of ``PSET_NAME`` for every element the file holds."""
    step_ids = scene.components.step_id
    if step_ids is None:
        return {}
    elements = result.elements
    visible, supported = elements.visible_share, elements.supported_share
    values: dict[int, dict[str, str | float | None]] = {}
    for c, step in enumerate(step_ids.tolist()):
        if step < 0:
            continue
        fit = elements.fits[c]

        def mm(value: float) -> float | None:
            return round(float(value) * 1000.0, 1) if math.isfinite(value) else None

        values[int(step)] = {
            "Status": str(elements.status[c]), "VisibleShare": round(float(visible[c]), 4),
            "SupportedShare": round(float(supported[c]), 4), "DeviationMm": mm(fit.median_signed_m),
            "MaxShiftMm": mm(fit.max_shift_m), "ToleranceMm": mm(elements.tolerance_m[c]),
            "Schedule": str(elements.schedule[c]) or None,
        }
    return values


def write_json(path: Path, document: dict[str, Any]) -> None:
    path.write_bytes(dump_json(document))


def read_station_file(path: str | Path) -> dict[int, np.ndarray]:
    """Station id -> position (3,) in the scan's frame, from a CSV file of lines ``id,x,y,z`` (a header
    line is skipped)."""
    path = check_input_file(path, what="a station file (id,x,y,z per line)")
    stations: dict[int, np.ndarray] = {}
    try:
        lines = path.read_text("utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{path}: not a readable text file ({exc}); pass a CSV of id,x,y,z lines") from exc
    for number, line in enumerate(lines, start=1):
        fields = [f.strip() for f in line.split(",")]
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            station, x, y, z = int(fields[0]), float(fields[1]), float(fields[2]), float(fields[3])
        except (ValueError, IndexError):
            if number == 1 or not stations and fields and not fields[0].lstrip("-").isdigit():
                continue  # a header line
            raise InputFileError(f"{path}, line {number}: {line.strip()!r} is not id,x,y,z; give one station a line") \
                from None
        if station in stations:
            raise InputFileError(f"{path}, line {number}: station {station} is given twice; give each once")
        stations[station] = np.array([x, y, z])
    if not stations:
        raise InputFileError(f"{path}: no stations (lines id,x,y,z); give one station a line")
    return stations


class PointsWriter:
    """The scan in the model's frame, each point with its element and its signed distance to the
    model, written chunk by chunk as the comparison streams (``compare_scan``'s ``on_chunk``)."""

    def __init__(self, path: Path, *, scene: Any, origin: np.ndarray, matrix: np.ndarray, scan: Path) -> None:
        from bimscan.io import open_cloud_writer
        from bimscan.io._labelled import ExtraField
        from bimscan.types import CloudHeader

        self.path = path
        self.fields = (ExtraField("distance_m", "<f4", "signed distance to the model surface (m)"),)
        header = CloudHeader(scheme=scene.scheme, components=scene.components,
                             origin=tuple(float(v) for v in np.round(origin)),  # type: ignore[arg-type]
                             metadata={"compared": {"scan": str(scan), "model": scene.source,
                                                    "matrix": [[float(v) for v in row] for row in matrix]}})
        self._labels = scene.components.label
        self._matrix = matrix
        self._writer = open_cloud_writer(path, header=header, fields=self.fields)

    def write(self, chunk: Any, xyz: np.ndarray, signed: np.ndarray, component: np.ndarray) -> None:
        import dataclasses

        from bimscan.compare.planes import apply
        from bimscan.io._labelled import field_values_dtype
        from bimscan.types import UNLABELLED

        on = component >= 0
        label = np.full(len(chunk), UNLABELLED, dtype=np.uint8)
        label[on] = self._labels[component[on]]
        moved = dataclasses.replace(chunk, xyz=xyz, label=label, component=component.astype(np.int32),
                                    sensor_xyz=None if chunk.sensor_xyz is None else apply(self._matrix, chunk.sensor_xyz))
        values = np.empty(len(chunk), dtype=field_values_dtype(self.fields))
        values["distance_m"] = signed
        self._writer.write(moved, values)

    def close(self) -> str:
        self._writer.close()
        return self.path.name

    def abort(self) -> None:
        self._writer.abort()


def points_writer(folder: Path, stem: str, fmt: str, *, scene: Any, origin: np.ndarray, matrix: np.ndarray,
                  scan: Path) -> PointsWriter:
    name = stem if fmt == "npy" else f"{stem}.{fmt}"
    return PointsWriter(folder / name, scene=scene, origin=origin, matrix=matrix, scan=scan)


def bcf_topics(result: Any, scene: Any) -> list[Any]:
    """A BCF topic per element out of tolerance or behind schedule, its viewpoint on the element."""
    from bimscan.ifc.guid import is_global_id
    from bimscan.io.bcf import BcfTopic, camera_looking_at

    elements = result.elements
    mesh = scene.mesh
    names = scene.scheme.names
    topics = []
    named = np.array([is_global_id(g) for g in scene.components.global_id.tolist()], dtype=bool)
    wanted = np.flatnonzero(((elements.status == "built out of tolerance") | (elements.schedule == "behind")) & named)
    if not len(wanted):
        return []
    corners = mesh.vertices[mesh.faces]
    lower = np.full((len(scene.components), 3), np.inf)
    upper = np.full((len(scene.components), 3), -np.inf)
    np.minimum.at(lower, mesh.face_component, corners.min(axis=1))
    np.maximum.at(upper, mesh.face_component, corners.max(axis=1))
    for c in wanted.tolist():
        components = scene.components
        what = f"{names.get(int(components.label[c]), '')} {components.ifc_class[c]} '{components.name[c]}'".strip()
        lines = [f"GlobalId {components.global_id[c]}, storey {components.storey[c] or '-'}."]
        if elements.status[c] == "built out of tolerance":
            fit = elements.fits[c]
            title = f"{what}: out of tolerance by {fit.max_shift_m * 1000:.0f} mm"
            lines.append(f"Built {fit.max_shift_m * 1000:.0f} mm from the model (tolerance "
                         f"{elements.tolerance_m[c] * 1000:.0f} mm); offset at its centre "
                         + ", ".join(f"{a} {v * 1000:.0f} mm" for a, v in zip("xyz", fit.offset_m) if math.isfinite(v))
                         + "; rotation " + ", ".join(f"{a} {v:.2f} deg" for a, v in zip("xyz", fit.rotation_deg)) + ".")
        else:
            title = f"{what}: behind schedule"
            lines.append(f"Due by {result.at} in the work schedule; the scan shows it {elements.status[c]}.")
        lines.append(f"Visible share {elements.visible_share[c]:.0%}, supported share {elements.supported_share[c]:.0%}.")
        position, direction, up = camera_looking_at(lower[c], upper[c])
        topics.append(BcfTopic(title=title, description=" ".join(lines), global_ids=(str(components.global_id[c]),),
                               camera_position=position, camera_direction=direction, camera_up=up,
                               labels=(str(elements.status[c]),) + (("behind schedule",) if elements.schedule[c] == "behind" else ())))
    return topics

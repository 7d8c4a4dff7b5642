"""The parse proper: one IFC-SPF file -> ``ParsedModel``, run inside the watchdog's worker process.

``parse_model`` reads the file (repairing what viewers accept, see ``bimscan.ifc.step``), checks
what would crash or mislead the geometry (placement cycles, missing length unit), triangulates
every declared element through IfcOpenShell's geometry iterator on all cores, and reports every
declared element that produced no geometry with its cause. It tells the watchdog how far it got
through ``emit(kind, payload)``:

- ``("phase", name)``: reading, checking, elements, spaces, assembling;
- ``("pending", ids)``: the STEP ids the current triangulation phase will try;
- ``("done", ids)``: ids finished (with or without geometry), sent at most every 0.1 s;
- ``("begin", (id, global_id, ifc_class))``: an element tried alone (after a crash, or a failure
  in the iterator), so a crash or a hang can be pinned on it.

The watchdog (``bimscan.ifc.watchdog``) restarts the parse after a crash or a hang with the
suspects in ``ParseRequest.isolate`` and the culprits in ``ParseRequest.skip``.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.errors import EmptyModelError, IfcError
from bimscan.ifc import step
from bimscan.ifc.materials import read_surfaces
from bimscan.ifc.schema import SUPPORTED_SCHEMAS, class_ancestry
from bimscan.ifc.units import GUESS_MM_ABOVE_M
from bimscan.ifc.report import FailedElement, IfcIssue, IfcLoadReport, IfcRepair
from bimscan.types import ComponentTable, ParsedModel, SceneMesh, Space, Storey

Emit = Callable[[str, Any], None]
# One element's triangles: vertices (V, 3) float64, faces (F, 3) int32, each face's style transparency (F,) float32.
Shape = tuple[np.ndarray, np.ndarray, np.ndarray]

# Representation identifiers that are never the element's solid body.
_NON_BODY_IDENTIFIERS = {
    "axis", "footprint", "box", "annotation", "reference", "profile", "clearance", "lighting", "cog",
    "survey", "plan",
}
# Context types of 3D bodies, as IfcOpenShell's iterator reads them (ArchiCAD writes "Design",
# AutoCAD Architecture "MODEL"); plans, outlines and sketches are 2D.
_BODY_CONTEXT_TYPES = {"", "model", "design", "model view", "detail view"}
_NON_BODY_TYPES = ("Curve2D", "GeometricCurveSet", "Annotation2D", "Point", "PointCloud")
# IfcOpenShell log messages that bimscan's own reading of the text reports better (with lines).
_COVERED = re.compile(r"Instance reference #\d+ used by|not found in schema|Expected \d+ attribute values|^\[SYN|"
                      r"Inconsistent aggregate valuation")
_OFFSET = re.compile(r"at offset (\d+)")
_INSTANCE = re.compile(r"instance #(\d+)")
_DONE_EVERY_S = 0.1


@dataclass(frozen=True)
class ParseRequest:
    """What to parse and how.

    path: the IFC-SPF file. name: how messages name it (the user's path; the archive for an
    .ifczip). length_unit_m: metres per model unit, overriding the file's (None: the file's).
    isolate: STEP ids triangulated one at a time, announced (suspects of an earlier crash or
    hang). skip: STEP ids not tried again, reported as given (they crashed or hung).
    """

    path: str
    name: str
    file_sha256: str
    threads: int = 1
    length_unit_m: float | None = None
    isolate: frozenset[int] = frozenset()
    skip: Mapping[int, FailedElement] = field(default_factory=dict)


def parse_model(request: ParseRequest, emit: Emit = lambda kind, payload: None) -> ParsedModel:
    """Parse ``request.path`` (see the module docstring). Raises IfcError / EmptyModelError."""
    import ifcopenshell.util.unit

    # IfcOpenShell logs every failed element itself; they are collected and reported instead.
    logging.getLogger("ifcopenshell").setLevel(logging.CRITICAL)
    name = request.name
    emit("phase", "reading")
    data = Path(request.path).read_bytes()
    with _readable_text(data, request) as (model, scan, problems, repairs):
        emit("phase", "checking")
        schema = model.schema_identifier
        lines = InstanceLines(data, scan)  # the repairs keep every line where it was
        _refuse_placement_cycles(model, lines, name)
        elements, declared_failed = _declared_elements(model, scan, schema, data)
        unit_m, unit_source, unit_issue = _choose_length_unit(model, elements, request.length_unit_m)
        if not elements and not declared_failed:
            raise EmptyModelError(f"{name}: the model has no building elements with 3D geometry; nothing to scan")
        shapes, failed = _triangulate(model, elements, request, emit, phase="elements", lines=lines, scan=scan)
        failed = sorted([*failed, *declared_failed], key=lambda f: f.step_id)
        components = [e for e in elements if e.id() in shapes]
        if not components:
            first = failed[0]
            raise EmptyModelError(
                f"{name}: no element produced geometry ({len(failed)} failed, e.g. {first.ifc_class} "
                f"#{first.step_id} {first.global_id}: {first.reason}); check the model in an IFC viewer"
            )
        emit("phase", "assembling")
        mesh = _merge(components, shapes)
        factor = unit_m / (_file_length_unit(model) or 1.0)  # 1 unless the unit could not be assigned
        if unit_source == "assumed" and unit_m == 1.0:
            lo, hi = mesh.bounds()
            extent = float(np.max(hi - lo))
            if extent > GUESS_MM_ABOVE_M:  # placements looked small, the geometry is not
                factor, unit_m, unit_issue = factor * 0.001, 0.001, _mm_words(extent, "the geometry")
        if factor != 1.0:
            mesh = replace(mesh, vertices=mesh.vertices * factor)
        if unit_issue:
            problems.append(step.Problem("length-unit", 0, 0, unit_issue))
        storeys = _storeys(model, ifcopenshell.util.unit.calculate_unit_scale(model) * factor)
        table = _component_table(components, schema)
        surfaces = read_surfaces(components)
        spaces = _spaces(model, request, emit, factor, lines=lines, scan=scan)
        report = IfcLoadReport(
            declared_elements=len(elements) + len(declared_failed), length_unit_m=unit_m,
            length_unit_source=unit_source, repairs=repairs,
            issues=_issues(problems),
        )
    return ParsedModel(source=name, file_sha256=request.file_sha256, schema=schema, mesh=mesh, components=table,
                       storeys=storeys, spaces=spaces, failed=tuple(failed), report=report, surfaces=surfaces)


# -- reading the text -------------------------------------------------------------------------------

@contextmanager
def _readable_text(data: bytes, request: ParseRequest) -> Iterator[tuple[Any, step.StepScan | None,
                                                                          list[step.Problem], tuple[IfcRepair, ...]]]:
    """The model as IfcOpenShell reads the repaired text, the scan of every statement (None when
    IfcOpenShell read the file without complaint), the file's problems and the repairs made."""
    name = request.name
    schema = step.header_schema(data) or ""
    renamed = step.schema_edit(data)  # an older or newer schema read as its closest one
    if renamed is not None:
        schema = renamed.text.decode("ascii")
    known = schema in SUPPORTED_SCHEMAS or schema == "IFC4X3"
    edits = ([renamed] if renamed is not None else []) + (step.quick_repairs(data, _schema_name(schema)) if known else [])
    text = step.apply_edits(data, edits, file_sha256=request.file_sha256) if edits or data.startswith(step.BOM) else data
    with _staged(text, data, request.path) as source:
        try:
            model, messages = _open(source, name)
        except IfcError:
            if not known:
                raise
            model = None  # a syntax error IfcOpenShell gives up on: the statements tell where
        else:
            _check_schema(model, name)
            if not messages and len(model.entity_names()) == step.count_statements(data):
                yield model, None, [], _repairs(edits)
                return
    # IfcOpenShell complained or lost instances: read every statement to learn what and where.
    schema = model.schema_identifier if model is not None else _schema_name(schema)
    scan = step.scan_step(data, schema)
    all_edits = ([renamed] if renamed is not None else []) + scan.edits
    repaired = step.apply_edits(data, all_edits, file_sha256=request.file_sha256)
    with _staged(repaired, data, request.path) as source:
        model, messages = _open(source, name)
        _check_schema(model, name)
        problems = scan.problems + _log_problems(messages, repaired, scan)
        yield model, scan, problems, _repairs(all_edits)


def _check_schema(model: Any, name: str) -> None:
    if model.schema_identifier not in SUPPORTED_SCHEMAS:
        raise IfcError(f"{name}: schema {model.schema_identifier} is not supported; export as one of "
                       f"{', '.join(SUPPORTED_SCHEMAS)}")


def _schema_name(schema: str) -> str:
    return "IFC4X3_ADD2" if schema.startswith("IFC4X3") else schema


@contextmanager
def _staged(text: bytes, original: bytes, path: str) -> Iterator[Path]:
    """``path`` itself when ``text`` is its content, else a temporary copy of ``text``."""
    if text is original:
        yield Path(path)
        return
    with tempfile.TemporaryDirectory(prefix="bimscan-ifc-") as folder:
        staged = Path(folder) / "repaired.ifc"
        staged.write_bytes(text)
        yield staged


def _open(path: Path, name: str) -> tuple[Any, list[str]]:
    """The model IfcOpenShell reads from ``path``, and its parser's log messages."""
    import ifcopenshell

    log = ifcopenshell.ifcopenshell_wrapper.logger()
    log.output_format(ifcopenshell.ifcopenshell_wrapper.logger.FMT_INMEMORY)
    try:
        model = ifcopenshell.open(str(path), format=".ifc", logger=log)
    except Exception as exc:  # IfcOpenShell raises its own Error types with parser messages
        why = str(exc).replace(", check logs", "")
        first = next((str(m.message) for m in log.log_messages()), "")
        offset = _OFFSET.search(first)
        if offset:
            text = path.read_bytes()
            first = f"{_OFFSET.sub('', first).strip()} on line {step.LineIndex(text).line_of(int(offset.group(1)))}"
        if step.data_section(path.read_bytes())[0] == path.stat().st_size:
            first = "the file has no DATA; section"
        raise IfcError(f"{name}: the IFC file could not be parsed ({why}{': ' + first if first else ''}); check the "
                       "export or repair the file") from exc
    # Copied now: a message's text does not outlive the logger.
    return model, [str(message.message) for message in log.log_messages()]


def _log_problems(messages: list[str], text: bytes, scan: step.StepScan) -> list[step.Problem]:
    """Problems IfcOpenShell found that the statement reading does not cover (invalid values)."""
    lines = step.LineIndex(text)
    out = []
    for words in messages:
        if _COVERED.search(words):
            continue
        offset, instance = _OFFSET.search(words), _INSTANCE.search(words)
        step_id = int(instance.group(1)) if instance else 0
        if offset:
            line = lines.line_of(int(offset.group(1)))
        elif step_id in scan.statements:
            line = lines.line_of(scan.statements[step_id].start)
        else:
            line = 0
        out.append(step.Problem("invalid-attribute", line, step_id, _OFFSET.sub("", words).strip().rstrip(".")))
    return out


def _repairs(edits: list[step.Edit]) -> tuple[IfcRepair, ...]:
    summary = step.summarize_repairs(edits)
    return tuple(IfcRepair(kind=kind, per_class=dict(sorted(per_class.items())), lines=tuple(lines[:IfcIssue.MAX_LINES]))
                 for kind, (per_class, lines) in sorted(summary.items()))


def _issues(problems: list[step.Problem]) -> tuple[IfcIssue, ...]:
    by_kind: dict[str, list[step.Problem]] = {}
    for problem in problems:
        by_kind.setdefault(problem.kind, []).append(problem)
    return tuple(
        IfcIssue(kind=kind, count=len(group), lines=tuple(sorted({p.line for p in group if p.line}))[:IfcIssue.MAX_LINES],
                 example=(f"line {group[0].line}: " if group[0].line else "") + group[0].message)
        for kind, group in sorted(by_kind.items())
    )


class InstanceLines:
    """STEP id -> 1-based line of its definition (0 when not found), looked up when asked (only
    failures and refusals ask): from the scan when there is one, else by searching the text."""

    def __init__(self, text: bytes, scan: step.StepScan | None) -> None:
        """``text``: the file's bytes (those ``scan`` read, when given)."""
        self.text = text
        self.scan = scan
        self._index: step.LineIndex | None = None

    def __call__(self, step_id: int) -> int:
        if self._index is None:
            self._index = step.LineIndex(self.text)
        if self.scan is not None:
            statement = self.scan.statements.get(step_id)
            return self._index.line_of(statement.start) if statement is not None else 0
        match = re.search(rb"(?m)^[ \t]*#%d[ \t]*=" % step_id, self.text)
        return self._index.line_of(match.start()) if match else 0


# -- checks before the geometry ---------------------------------------------------------------------

def _refuse_placement_cycles(model: Any, lines: InstanceLines, name: str) -> None:
    """IfcOpenShell recurses along PlacementRelTo without end (and crashes) on a cycle: refuse it."""
    settled: set[int] = set()
    for placement in model.by_type("IfcObjectPlacement"):
        chain: list[int] = []
        current = placement
        while current is not None and current.id() not in settled:
            if current.id() in chain:
                cycle = chain[chain.index(current.id()):] + [current.id()]
                raise IfcError(
                    f"{name}: placement #{current.id()} (line {lines(current.id())}) is placed "
                    f"relative to itself ({' -> '.join(f'#{i}' for i in cycle)}); the model cannot be placed: "
                    "fix PlacementRelTo in the file or export it again"
                )
            chain.append(current.id())
            current = _entity(current, "PlacementRelTo")
            if current is not None and not current.is_a("IfcObjectPlacement"):
                current = None
        settled.update(chain)


def _attribute(instance: Any, attribute: str, default: Any = None) -> Any:
    """An attribute of an instance, or ``default`` when the file holds a value of the wrong type."""
    try:
        value = getattr(instance, attribute, default)
    except (RuntimeError, ValueError, TypeError, AttributeError):
        return default
    return default if value is None else value


def _entity(instance: Any, attribute: str) -> Any:
    """An attribute that should hold an instance, or None when it holds anything else."""
    import ifcopenshell

    value = _attribute(instance, attribute) if instance is not None else None
    return value if isinstance(value, ifcopenshell.entity_instance) else None


def _file_length_unit(model: Any) -> float | None:
    """Metres per model length unit from the project's unit assignment, None when it has none."""
    import ifcopenshell.util.unit

    try:
        if ifcopenshell.util.unit.get_project_unit(model, "LENGTHUNIT") is None:
            return None
        scale = float(ifcopenshell.util.unit.calculate_unit_scale(model))
    except (RuntimeError, ValueError, TypeError, AttributeError, IndexError, ZeroDivisionError):
        return None
    return scale if np.isfinite(scale) and scale > 0 else None


def _choose_length_unit(model: Any, elements: list[Any], override_m: float | None) -> tuple[float, str, str | None]:
    """(metres per model length unit, its source, issue or None), assigned to the model in memory
    when it is not the file's: the geometry kernel's tolerances then fit the model's numbers, and
    IfcOpenShell's iterator, which refuses a project without units, runs."""
    file_unit_m = _file_length_unit(model)
    if override_m is not None:
        if file_unit_m is None or abs(file_unit_m - override_m) > 1e-12:
            _assign_length_unit(model, override_m)
        return override_m, "override", None
    if file_unit_m is not None:
        return file_unit_m, "file", None
    extent = _placement_extent(model, elements)
    if extent > GUESS_MM_ABOVE_M:
        unit_m, issue = 0.001, _mm_words(extent, "the elements' placements")
    else:
        unit_m, issue = 1.0, (f"the file assigns no length unit; read as metres (the elements' placements span "
                              f"{extent:.1f} m; pass --length-unit to choose)")
    _assign_length_unit(model, unit_m)
    return unit_m, "assumed", issue


def _mm_words(extent: float, what: str) -> str:
    return (f"the file assigns no length unit; read as millimetres, since in metres {what} would span "
            f"{extent / 1000:.6g} km (pass --length-unit to choose)")


def _assign_length_unit(model: Any, metres: float) -> None:
    """Make ``metres`` per unit every project's length unit, in memory (an SI metre with a prefix,
    or a conversion-based unit)."""
    prefixes = {1.0: None, 0.01: "CENTI", 0.001: "MILLI"}
    try:
        if metres in prefixes:
            unit = model.create_entity("IfcSIUnit", UnitType="LENGTHUNIT", Prefix=prefixes[metres], Name="METRE")
        else:
            metre = model.create_entity("IfcSIUnit", UnitType="LENGTHUNIT", Name="METRE")
            factor = model.create_entity("IfcMeasureWithUnit", ValueComponent=model.create_entity("IfcLengthMeasure", metres),
                                         UnitComponent=metre)
            dimensions = model.create_entity("IfcDimensionalExponents", 1, 0, 0, 0, 0, 0, 0)
            unit = model.create_entity("IfcConversionBasedUnit", Dimensions=dimensions, UnitType="LENGTHUNIT",
                                       Name=f"{metres:g} m", ConversionFactor=factor)
        for project in model.by_type("IfcProject"):
            assignment = _entity(project, "UnitsInContext")
            if assignment is None or not assignment.is_a("IfcUnitAssignment"):
                project.UnitsInContext = model.create_entity("IfcUnitAssignment", Units=[unit])
            else:
                kept = [u for u in (_attribute(assignment, "Units", ()) or ()) if u is not None
                        and _attribute(u, "UnitType") != "LENGTHUNIT"]
                assignment.Units = [*kept, unit]
    except (RuntimeError, ValueError, TypeError, AttributeError):
        pass  # a project beyond repair: lengths are then scaled after the geometry


def _placement_extent(model: Any, elements: list[Any]) -> float:
    """The largest side of the box around the elements' placement origins, in model units."""
    import ifcopenshell.util.placement

    matrices: dict[int, np.ndarray] = {}

    def world(placement: Any) -> np.ndarray:
        chain = []
        while placement is not None and placement.id() not in matrices and placement.is_a("IfcLocalPlacement"):
            chain.append(placement)
            placement = _entity(placement, "PlacementRelTo")
        matrix = matrices.get(placement.id(), np.eye(4)) if placement is not None else np.eye(4)
        for local in reversed(chain):
            relative = _entity(local, "RelativePlacement")
            try:
                step_matrix = ifcopenshell.util.placement.get_axis2placement(relative) if relative is not None else np.eye(4)
            except (RuntimeError, ValueError, TypeError, AttributeError, IndexError):
                step_matrix = np.eye(4)
            matrix = matrix @ step_matrix
            matrices[local.id()] = matrix
        return matrix

    with np.errstate(all="ignore"):  # a zero-length axis gives NaN: such origins are left out below
        origins = [world(_entity(e, "ObjectPlacement"))[:3, 3] for e in elements]
    origins = [o for o in origins if np.isfinite(o).all()]
    return float(np.max(np.ptp(np.array(origins), axis=0))) if len(origins) > 1 else 0.0


def _declared_elements(model: Any, scan: step.StepScan | None, schema: str, data: bytes
                       ) -> tuple[list[Any], list[FailedElement]]:
    """Elements to triangulate (scannable, with a body), sorted by STEP id, and declared elements
    that cannot be tried: their body is a dangling reference, their entity name is unknown, or
    their line does not parse."""
    elements = []
    failed: list[FailedElement] = []
    dangling_body = _dangling_bodies(scan, schema) if scan is not None else {}
    for element in model.by_type("IfcElement"):
        if any(element.is_a(t) for t in step.NOT_SCANNABLE):
            continue
        if element.id() in dangling_body:
            line, target = dangling_body[element.id()]
            failed.append(FailedElement(global_id=_global_id(element), ifc_class=element.is_a(),
                                        reason=f"its body (Representation) is #{target}, which the file does not define",
                                        step_id=element.id(), line=line, cause="dangling-reference"))
        elif _has_body(element):
            elements.append(element)
    if scan is not None:
        unknown_lines = {p.step_id: p.line for p in scan.problems if p.kind == "unknown-entity"}
        for step_id, statement in sorted(scan.unknown.items()):
            if _looks_like_element(statement, scan):
                failed.append(FailedElement(
                    global_id=_string_at(data, statement, 0), ifc_class=statement.entity, step_id=step_id,
                    cause="unknown-entity",
                    line=unknown_lines.get(step_id, 0),
                    reason=f"{statement.entity} is not an entity of {schema}; the element is skipped"))
        for step_id, (entity, line) in sorted(scan.broken.items()):
            if step.is_scannable_class(schema, entity):
                failed.append(FailedElement(global_id="", ifc_class=class_ancestry(schema, entity)[0], step_id=step_id,
                                            line=line, cause="syntax", reason="its line does not parse; skipped"))
        for statement, line in scan.duplicates:
            if step.is_scannable_class(schema, statement.entity):
                first = scan.statements.get(statement.step_id) or scan.unknown.get(statement.step_id)
                failed.append(FailedElement(
                    global_id=_string_at(data, statement, 0), ifc_class=class_ancestry(schema, statement.entity)[0],
                    step_id=statement.step_id, line=line, cause="duplicate-id",
                    reason=f"its id is taken by an earlier {first.entity if first else 'instance'}; skipped"))
    return sorted(elements, key=lambda e: e.id()), failed


def _dangling_bodies(scan: step.StepScan, schema: str) -> dict[int, tuple[int, int]]:
    """Scannable elements whose Representation attribute refers to an instance the model lacks:
    STEP id -> (line, missing id)."""
    out = {}
    for problem in scan.problems:
        if problem.kind != "dangling-reference" or not step.is_scannable_class(schema, problem.entity):
            continue
        statement = scan.statements[problem.step_id]
        index = _representation_index(schema, statement.entity)
        for attribute, target in statement.reference_pairs():
            if attribute == index and target not in scan.statements:
                out[problem.step_id] = (problem.line, target)
    return out


def _representation_index(schema: str, entity: str) -> int:
    import ifcopenshell.ifcopenshell_wrapper as wrapper

    try:
        return int(wrapper.schema_by_name(schema).declaration_by_name(entity).attribute_index("Representation"))
    except (RuntimeError, IndexError):
        return -1


def _looks_like_element(statement: step.Statement, scan: step.StepScan) -> bool:
    """An instance of an unknown entity shaped like a product with a body: a GlobalId string first
    and, seventh, a reference to an IfcProductDefinitionShape."""
    if len(statement.kinds) < 7 or statement.kinds[0] != "str" or statement.kinds[6] != "ref":
        return False
    targets = [t for a, t in statement.reference_pairs() if a == 6]
    shape = scan.statements.get(targets[0]) if targets else None
    return shape is not None and shape.entity == "IFCPRODUCTDEFINITIONSHAPE"


def _string_at(data: bytes, statement: step.Statement, index: int) -> str:
    """The string value of a statement's attribute ``index``, "" when it is not a string."""
    if index >= len(statement.kinds) or statement.kinds[index] != "str":
        return ""
    start, end = statement.attributes[index]
    return data[start + 1:end - 1].decode("latin-1")


def _global_id(element: Any) -> str:
    value = _attribute(element, "GlobalId", "")
    return value if isinstance(value, str) else ""


def _has_body(element: Any) -> bool:
    """Whether an element has a 3D body representation (a representation that cannot be read
    counts: it is then reported as a failure rather than silently left out)."""
    representation = _entity(element, "Representation")
    if representation is None:
        return False
    try:
        representations = [r for r in _attribute(representation, "Representations", ()) or () if r is not None]
        if not representations:
            return True  # a shape whose representations are all missing: declared, and reported as failed
        for rep in representations:
            context = _entity(rep, "ContextOfItems")
            context_type = _attribute(context, "ContextType") or _attribute(_entity(context, "ParentContext"), "ContextType")
            if str(context_type or "").lower() not in _BODY_CONTEXT_TYPES:
                continue
            if (_attribute(rep, "RepresentationIdentifier", "") or "").lower() in _NON_BODY_IDENTIFIERS:
                continue
            if (_attribute(rep, "RepresentationType", "") or "") in _NON_BODY_TYPES:
                continue
            return True
    except (RuntimeError, ValueError, TypeError, AttributeError):
        return True
    return False


# -- geometry -----------------------------------------------------------------------------------------

def _triangulate(model: Any, elements: list[Any], request: ParseRequest, emit: Emit, *, phase: str,
                 lines: InstanceLines, scan: step.StepScan | None) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], list[FailedElement]]:
    """Triangles of each element in world coordinates (the model's length unit converted to metres),
    and the elements that produced none, with the reason."""
    import ifcopenshell.geom

    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    shapes: dict[int, Shape] = {}
    reasons: dict[int, str] = {}
    emit("phase", phase)
    emit("pending", [e.id() for e in elements])
    together = [e for e in elements if e.id() not in request.isolate and e.id() not in request.skip]
    if together:
        try:
            iterator = ifcopenshell.geom.iterator(settings, model, max(1, request.threads), include=together)
            started = iterator.initialize()
        except (RuntimeError, ValueError, TypeError) as exc:  # the whole iteration refused: try one by one
            started, reasons = False, {e.id(): _short_reason(exc) for e in together}
        finished: list[int] = []
        last = time.monotonic()
        try:
            while started:
                shape = iterator.get()
                _inject_fault(shape.id)
                arrays = _shape_arrays(shape.geometry)
                if len(arrays[1]):
                    shapes[shape.id] = arrays
                finished.append(shape.id)
                if time.monotonic() - last > _DONE_EVERY_S:
                    emit("done", finished)
                    finished, last = [], time.monotonic()
                if not iterator.next():
                    break
        except (RuntimeError, ValueError, TypeError):
            pass  # the iteration gave up part way ("No elements processed"): the rest are tried one by one
        emit("done", finished)
    failed = []
    for element in elements:
        step_id = element.id()
        if step_id in shapes:
            continue
        if step_id in request.skip:
            failed.append(replace(request.skip[step_id], line=lines(step_id)))
            continue
        # The iterator drops failures silently (and isolated elements were left out of it):
        # triangulate alone, announced, to learn why or recover.
        emit("begin", (step_id, _global_id(element), element.is_a()))
        _inject_fault(step_id)
        try:
            shape = ifcopenshell.geom.create_shape(settings, element)
            arrays = _shape_arrays(shape.geometry)
            reason = "geometry produced no triangles" if not len(arrays[1]) else ""
        except Exception as exc:  # IfcOpenShell raises RuntimeError or its own errors per element
            reason = _short_reason(exc)
        emit("done", [step_id])
        if not reason:
            shapes[step_id] = arrays
            continue
        cause, reason = _failure_cause(model, element, scan, reason)
        failed.append(FailedElement(global_id=_global_id(element), ifc_class=element.is_a(), reason=reason,
                                    step_id=step_id, line=lines(step_id), cause=cause))
    return shapes, failed


def _inject_fault(step_id: int) -> None:
    """For the watchdog's own tests: ``BIMSCAN_IFC_TEST_FAULT=hang:<id>`` or ``crash:<id>`` makes
    this worker hang or die (SIGSEGV) on element ``#id``, as IfcOpenShell does on some files."""
    fault = os.environ.get("BIMSCAN_IFC_TEST_FAULT", "")
    if not fault or fault.partition(":")[2] != str(step_id):
        return
    if fault.startswith("hang:"):
        while True:
            time.sleep(60)
    if fault.startswith("crash:"):
        os.kill(os.getpid(), signal.SIGSEGV)


def _failure_cause(model: Any, element: Any, scan: step.StepScan | None, reason: str) -> tuple[str, str]:
    """("dangling-reference", why) when the element's geometry needs an instance the file lacks."""
    if scan is None:
        return "geometry", reason
    dangling = {p.step_id: p for p in scan.problems if p.kind == "dangling-reference"}
    if not dangling:
        return "geometry", reason
    reachable = {element.id()}
    for attribute in ("ObjectPlacement", "Representation"):  # what its geometry reads
        start = _entity(element, attribute)
        try:
            reachable.update(i.id() for i in (model.traverse(start) if start is not None else ()))
        except (RuntimeError, ValueError, TypeError):
            continue
    for step_id in sorted(reachable & dangling.keys()):
        problem = dangling[step_id]
        return "dangling-reference", f"{problem.message} (line {problem.line}); IfcOpenShell: {reason}"
    return "geometry", reason


def _short_reason(exc: Exception) -> str:
    """IfcOpenShell's message without the product dump (GlobalId and class are reported apart)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    text = re.sub(r"Product: #\d+=[^,]*\([^)]*\),\s*", "", text)
    return text if len(text) <= 300 else text[:297] + "..."


def _shape_arrays(geometry: Any) -> Shape:
    vertices = np.frombuffer(geometry.verts_buffer, dtype=np.float64).reshape(-1, 3)
    faces = np.frombuffer(geometry.faces_buffer, dtype=np.int32).reshape(-1, 3)
    if len(faces) and (faces.min() < 0 or faces.max() >= len(vertices) or not np.isfinite(vertices).all()):
        return vertices[:0], faces[:0], np.zeros(0, np.float32)
    return vertices.copy(), faces.copy(), _face_transparency(geometry, len(faces))


def _face_transparency(geometry: Any, n_faces: int) -> np.ndarray:
    """(F,) float32: the transparency of each triangle's surface style, as IfcOpenShell resolved it
    per item (a window's glazing and its frame are separate items), NaN for a triangle without one.
    IfcOpenShell's own defaults (a semi-transparent IfcWindow, say) are not the model's: NaN too."""
    out = np.full(n_faces, np.nan, dtype=np.float32)
    try:
        ids = np.asarray(geometry.material_ids, dtype=np.int64)
        styles = geometry.materials
        alpha = np.array([float(s.transparency) if s.instance_id() > 0 and s.has_transparency() else np.nan
                          for s in styles], dtype=np.float64)
    except (AttributeError, RuntimeError, TypeError, ValueError):  # another IfcOpenShell: no per-item styles
        return out
    if len(ids) != n_faces or not len(alpha):
        return out
    valid = (ids >= 0) & (ids < len(alpha))
    with np.errstate(invalid="ignore"):
        out[valid] = np.clip(alpha[ids[valid]], 0.0, 1.0)
    return out


def _merge(components: list[Any], shapes: dict[int, Shape]) -> SceneMesh:
    vertices, faces, face_component, face_transparency = [], [], [], []
    offset = 0
    for cid, element in enumerate(components):
        v, f, alpha = shapes[element.id()]
        vertices.append(v)
        faces.append(f + offset)
        face_component.append(np.full(len(f), cid, dtype=np.int32))
        face_transparency.append(alpha)
        offset += len(v)
    return SceneMesh(
        vertices=np.ascontiguousarray(np.concatenate(vertices), dtype=np.float64),
        faces=np.ascontiguousarray(np.concatenate(faces), dtype=np.int32),
        face_component=np.concatenate(face_component),
        face_transparency=np.concatenate(face_transparency).astype(np.float32),
    )


# -- tables ---------------------------------------------------------------------------------------------

def _text(value: Any) -> str:
    return value if isinstance(value, str) else ""


def _storey_of(element: Any) -> str:
    import ifcopenshell.util.element as util

    seen = 0
    current = element
    try:
        while current is not None and seen < 16:
            if current.is_a("IfcBuildingStorey"):
                return _text(_attribute(current, "Name", ""))
            current = util.get_container(current) or util.get_aggregate(current) or _host_of_filling(current)
            seen += 1
    except (RuntimeError, ValueError, TypeError, AttributeError, IndexError):
        return ""
    return ""


def _host_of_filling(element: Any) -> Any:
    """The wall a door or window sits in (through its opening), if any."""
    for fills in _attribute(element, "FillsVoids", ()) or ():
        opening = _entity(fills, "RelatingOpeningElement")
        for voids in _attribute(opening, "VoidsElements", ()) or ():
            return _entity(voids, "RelatingBuildingElement")
    return None


def _component_table(components: list[Any], schema: str) -> ComponentTable:
    import ifcopenshell.util.element as util

    rows = []
    for element in components:
        try:
            parent = util.get_aggregate(element)
        except (RuntimeError, ValueError, TypeError, AttributeError, IndexError):
            parent = None
        try:
            predefined = _text(util.get_predefined_type(element) or "")
        except (RuntimeError, ValueError, TypeError, AttributeError, IndexError):
            predefined = ""
        rows.append((
            _global_id(element), element.is_a(), predefined, _text(_attribute(element, "Name", "")),
            _storey_of(element), parent.is_a() if parent is not None else "", element.id(),
        ))
    columns = list(zip(*rows))
    ancestry = {cls: class_ancestry(schema, cls) for cls in sorted(set(columns[1]) | set(columns[5]) - {""})}
    return ComponentTable(
        global_id=np.array(columns[0], dtype=str),
        ifc_class=np.array(columns[1], dtype=str),
        predefined_type=np.array(columns[2], dtype=str),
        name=np.array(columns[3], dtype=str),
        storey=np.array(columns[4], dtype=str),
        parent_class=np.array(columns[5], dtype=str),
        label=np.zeros(len(rows), dtype=np.uint8),
        class_ancestry=ancestry,
        step_id=np.array(columns[6], dtype=np.int64),
    )


def _storeys(model: Any, unit_scale: float) -> tuple[Storey, ...]:
    import ifcopenshell.util.placement as placement

    storeys = []
    for storey in model.by_type("IfcBuildingStorey"):
        z = None
        local = _entity(storey, "ObjectPlacement")
        if local is not None:
            try:
                z = float(placement.get_local_placement(local)[2][3])
            except (RuntimeError, ValueError, TypeError, AttributeError, IndexError, RecursionError):
                z = None
        if z is None:
            elevation = _attribute(storey, "Elevation", 0.0)
            z = float(elevation) if isinstance(elevation, int | float) else 0.0
        z *= unit_scale
        storeys.append(Storey(name=_text(_attribute(storey, "Name", "")), elevation_m=round(z, 6) if np.isfinite(z) else 0.0))
    return tuple(sorted(storeys, key=lambda s: (s.elevation_m, s.name)))


def _spaces(model: Any, request: ParseRequest, emit: Emit, factor: float, *, lines: InstanceLines,
            scan: step.StepScan | None) -> tuple[Space, ...]:
    spaces = sorted((s for s in model.by_type("IfcSpace") if _has_body(s)), key=lambda s: s.id())
    if not spaces:
        return ()
    shapes, _ = _triangulate(model, spaces, request, emit, phase="spaces", lines=lines, scan=scan)
    out = []
    for space in spaces:
        if space.id() not in shapes:
            continue  # a room without usable geometry only costs the station planner a hint
        v, f, _ = shapes[space.id()]
        name = " ".join(filter(None, (_text(_attribute(space, "Name", "")), _text(_attribute(space, "LongName", "")))))
        out.append(Space(global_id=_global_id(space), name=name or _global_id(space), storey=_storey_of(space),
                         vertices=v * factor if factor != 1.0 else v, faces=f))
    return tuple(out)


__all__ = ["Emit", "ParseRequest", "InstanceLines", "parse_model"]

"""What loading an IFC file repaired, assumed, found wrong and lost: the load report that travels
with a parsed model (``ParsedModel.report`` and ``failed``), for ``bimscan info`` and the
warnings of every command that reads a model. Plain data; nothing here reads IFC.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

# Why a declared element (an IfcElement with a body) is not in the mesh.
FAILURE_CAUSES = ("geometry", "crash", "timeout", "dangling-reference", "unknown-entity", "syntax", "duplicate-id")


@dataclass(frozen=True)
class FailedElement:
    """A declared element that produced no geometry; reported and skipped.

    cause: one of ``FAILURE_CAUSES`` (geometry: IfcOpenShell could not triangulate it; crash /
    timeout: the geometry kernel died or ran past the watchdog's limit on it; dangling-reference:
    it needs an instance the file does not define; unknown-entity: its entity name is not in the
    schema; syntax: its line is garbled; duplicate-id: an earlier instance has its id). step_id: its ``#n`` in the file; line: 1-based line of
    its definition (0 when unknown).
    """

    global_id: str
    ifc_class: str
    reason: str
    step_id: int = 0
    line: int = 0
    cause: str = "geometry"


# Kinds of IFC file problems (``IfcIssue.kind``); each is a warning, and an error under strict.
ISSUE_KINDS = ("syntax", "unknown-entity", "duplicate-id", "dangling-reference", "attribute-count",
               "invalid-attribute", "length-unit")
# Kinds of repairs made to content viewers accept (``IfcRepair.kind``).
REPAIR_KINDS = ("schema", "derived-attribute", "globalid")


@dataclass(frozen=True)
class IfcIssue:
    """One kind of problem found in an IFC file, with how often it occurs and where.

    lines: 1-based lines of the first occurrences (at most ``MAX_LINES``); example: the first
    occurrence in words.
    """

    kind: str
    count: int
    lines: tuple[int, ...]
    example: str

    MAX_LINES = 20


@dataclass(frozen=True)
class IfcRepair:
    """One kind of repair made before the geometry: instances repaired per IFC class, first lines."""

    kind: str
    per_class: Mapping[str, int]
    lines: tuple[int, ...]

    @property
    def count(self) -> int:
        return int(sum(self.per_class.values()))


@dataclass(frozen=True)
class IfcLoadReport:
    """What loading an IFC file repaired, assumed and found wrong (JSON-able via ``dataclasses.asdict``).

    declared_elements: IfcElements with a body representation the file declares (by STEP id),
    failed ones included. length_unit_m: metres per model length unit as used; length_unit_source:
    "file" (the project's unit assignment), "assumed" (none usable: guessed, see the
    ``length-unit`` issue) or "override" (given by the caller).
    """

    declared_elements: int = 0
    length_unit_m: float = 1.0
    length_unit_source: str = "file"
    repairs: tuple[IfcRepair, ...] = ()
    issues: tuple[IfcIssue, ...] = ()

    @property
    def clean(self) -> bool:
        """True when nothing was repaired, assumed or found wrong."""
        return not self.repairs and not self.issues


__all__ = ["FAILURE_CAUSES", "ISSUE_KINDS", "REPAIR_KINDS", "FailedElement", "IfcIssue", "IfcLoadReport", "IfcRepair"]

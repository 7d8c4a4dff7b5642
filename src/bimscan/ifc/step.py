"""The text of an IFC-SPF (ISO 10303-21) file, read statement by statement, before IfcOpenShell.

IfcOpenShell's parser drops what it cannot read without naming the element that was lost, and one
unbalanced bracket makes it swallow the rest of the file into a single instance. Real exports
also write values viewers accept but the schema does not (``*`` where a value belongs). This
module reads the DATA section as statements (one starts on every line beginning with ``#n=``; a
statement's lines are joined up to its ``;``), ties every problem to a line, and rewrites the text
so that IfcOpenShell reads what a viewer would show:

- a statement that does not parse (a bad character, unbalanced brackets, cut short) is blanked
  out (spaces; its line breaks are kept, so lines stay those of the file) and reported;
- repairs: ``*`` (derived) in an attribute the schema does not derive becomes ``$`` (unset);
  a GlobalId of an IfcRoot that is not a string (``$``, ``*``, a number) becomes one derived from
  the file's SHA-256 and the instance id (the same on every run): IfcOpenShell's geometry
  iterator waits forever on such an element;
- reported, not changed: entity names the schema does not know, an id defined twice (the later
  definition is blanked), references to instances the file does not define (dangling), wrong
  attribute counts.

``quick_repairs`` looks only at the few statements holding ``*`` or a leading ``$`` first (the usual case,
milliseconds); ``scan_step`` reads every statement (the slow path, taken when IfcOpenShell
reports trouble). Offsets are byte offsets into the file; lines are 1-based.
"""

from __future__ import annotations

import re
import sys
from array import array
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from functools import cache

import numpy as np

from bimscan.ifc import guid
from bimscan.ifc.schema import class_ancestry

BOM = b"\xef\xbb\xbf"
# Entities that are scannable elements when their class descends from IfcElement but not from these.
NOT_SCANNABLE = ("IfcFeatureElement", "IfcVirtualElement")

_STATEMENT_START = re.compile(rb"(?m)^[ \t]*(?:#[0-9]+[ \t]*=|ENDSEC[ \t]*;)")
_INSTANCE_START = re.compile(rb"(?m)^[ \t]*#[0-9]+[ \t]*=")
_DATA_START = re.compile(rb"(?m)^[ \t]*DATA[ \t]*(?:\([^;]*\))?[ \t]*;")
_SCHEMA = re.compile(rb"FILE_SCHEMA\s*\(\s*\(\s*'([^']*)'", re.I)
_TOKEN = re.compile(
    rb"""(?P<ws>[ \t\r\n]+)
    |(?P<comment>/\*.*?\*/)
    |(?P<str>'(?:[^'\x00]|'')*')
    |(?P<ref>\#[0-9]+)
    |(?P<num>[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)
    |(?P<enum>\.[A-Za-z_][A-Za-z0-9_]*\.)
    |(?P<kw>!?[A-Za-z_][A-Za-z0-9_]*)
    |(?P<bin>"[0-9A-Fa-f]*")
    |(?P<punct>[(),=;$*])
    |(?P<bad>.)""",
    re.X | re.S,
)
_HEAD_BEFORE = re.compile(rb"=\s*([A-Za-z_][A-Za-z0-9_]*)\s*\Z")  # "=ENTITY" just before a '('
_VALUE_KINDS = frozenset(("str", "ref", "num", "enum", "bin"))


def _well_formed_statement(depth: int) -> re.Pattern[bytes]:
    """A regex for one whole well-formed simple statement ``#n=ENTITY(...);`` whose values nest at
    most ``depth`` lists (or typed values) deep: the fast path of ``scan_step``. Each level holds
    the one below once, so the pattern grows linearly with ``depth``; every alternative starts with
    its own character, so matching never backtracks far. (A typed value with several values
    passes: IfcOpenShell reports that one.)"""
    value = (rb"'(?:[^'\x00]|'')*'|\#[0-9]+|[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
             rb"|\.[A-Za-z_][A-Za-z0-9_]*\.|\$|\*|\"[0-9A-Fa-f]*\"")

    def listed(item: bytes) -> bytes:  # (item, item, ...) without a leading or trailing comma
        return rb"\(\s*(?:(?:" + item + rb")\s*(?:,\s*(?!\))|(?=\))))*\)"

    item = value
    for _ in range(depth):
        item = value + rb"|(?:[A-Za-z_][A-Za-z0-9_]*\s*)?" + listed(item)
    return re.compile(rb"\s*\#([0-9]+)\s*=\s*([A-Za-z_][A-Za-z0-9_]*)\s*\(\s*((?:(?:" + item
                      + rb")\s*(?:,\s*(?!\))|(?=\))))*)\)\s*;\s*")


_WELL_FORMED = _well_formed_statement(5)
_REFERENCE = re.compile(rb"#([0-9]+)")
_STRING = re.compile(rb"'(?:[^']|'')*'")
_INNERMOST = re.compile(rb"\([^()]*\)")


class LineIndex:
    """Byte offset -> 1-based line number of a file's bytes."""

    def __init__(self, data: bytes) -> None:
        self._newlines = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10)

    def line_of(self, offset: int) -> int:
        return int(np.searchsorted(self._newlines, offset, side="left")) + 1


@dataclass(slots=True)
class Statement:
    """One parsed instance: ``#step_id=ENTITY(attributes);`` (entity "" for a complex instance).

    attributes: byte spans of the top-level attribute values; kinds: their token kind when the
    value is one token ("$", "*", "str", "ref", ...), else "" (lists, typed values); both are
    dropped once checked (``scan_step``), to keep the memory of a large file's scan small.
    references: flat (top-level attribute index, referenced id) pairs for every ``#n`` inside
    (index -1 when the statement was read by the fast path; ``scan_step`` resolves it where a
    reference dangles).
    """

    step_id: int
    entity: str
    start: int
    end: int
    attributes: list[tuple[int, int]] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    references: array = field(default_factory=lambda: array("q"))

    def reference_pairs(self) -> Iterator[tuple[int, int]]:
        """(top-level attribute index, referenced id) of every reference."""
        pairs = self.references
        return zip(pairs[0::2], pairs[1::2])


@dataclass(frozen=True)
class Problem:
    """A problem at a place in the file (kind: one of ``bimscan.ifc.report.ISSUE_KINDS``)."""

    kind: str
    line: int
    step_id: int
    message: str
    entity: str = ""  # the instance's entity name as written, when known


@dataclass(frozen=True)
class Edit:
    """Replace ``data[start:end]`` by ``text``; kind: "blank" or a ``REPAIR_KINDS`` entry.

    entity: the schema's name of the instance's class (as written when the schema lacks it).
    """

    start: int
    end: int
    text: bytes
    kind: str
    entity: str
    line: int
    step_id: int = 0


@dataclass
class StepScan:
    """What reading the statements found: kept statements, problems, edits to apply."""

    statements: dict[int, Statement] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    edits: list[Edit] = field(default_factory=list)
    # Statements that did not parse but whose head ``#n=ENTITY(`` did: id -> (entity, line)
    broken: dict[int, tuple[str, int]] = field(default_factory=dict)
    unknown: dict[int, Statement] = field(default_factory=dict)  # statements of entities the schema lacks
    duplicates: list[tuple[Statement, int]] = field(default_factory=list)  # later definitions of an id, with lines


def header_schema(data: bytes) -> str | None:
    """The schema named in FILE_SCHEMA, upper case, or None."""
    match = _SCHEMA.search(data, 0, 1 << 16)
    return match.group(1).decode("ascii", "replace").strip().upper() if match else None


# Schemas IfcOpenShell does not read, and the one it reads that each is closest to: IFC2x and
# IFC2x2 grew into IFC2X3 (the same entities for buildings, a few attributes added), IFC4 Addendum
# releases, IFC4X1/IFC4X2 and the IFC4X3 candidates into IFC4X3_ADD2.
NEAREST_SCHEMA = {
    "IFC2X": "IFC2X3", "IFC2X_FINAL": "IFC2X3", "IFC2X2": "IFC2X3", "IFC2X2_FINAL": "IFC2X3",
    "IFC2X3_TC1": "IFC2X3", "IFC4_ADD1": "IFC4", "IFC4_ADD2": "IFC4", "IFC4_ADD2_TC1": "IFC4",
    "IFC4X1": "IFC4X3_ADD2", "IFC4X2": "IFC4X3_ADD2", "IFC4X3_RC1": "IFC4X3_ADD2", "IFC4X3_RC2": "IFC4X3_ADD2",
    "IFC4X3_RC3": "IFC4X3_ADD2", "IFC4X3_RC4": "IFC4X3_ADD2", "IFC4X3_TC1": "IFC4X3_ADD2",
    "IFC4X3_ADD1": "IFC4X3_ADD2",
}


def schema_edit(data: bytes) -> Edit | None:
    """The edit that names a schema IfcOpenShell reads in FILE_SCHEMA, when the file names one it
    does not but that has a close successor (``NEAREST_SCHEMA``); None otherwise. Its entity is
    the schema the file named."""
    match = _SCHEMA.search(data, 0, 1 << 16)
    if match is None:
        return None
    written = match.group(1).decode("ascii", "replace").strip().upper()
    nearest = NEAREST_SCHEMA.get(written)
    if nearest is None:
        return None
    line = data.count(b"\n", 0, match.start(1)) + 1
    return Edit(start=match.start(1), end=match.end(1), text=nearest.encode("ascii"), kind="schema",
                entity=f"{written} as {nearest}", line=line)


def count_statements(data: bytes) -> int:
    """Instance definitions that start a line (what a well-formed export holds)."""
    return len(_INSTANCE_START.findall(data))


def data_section(data: bytes) -> tuple[int, int]:
    """Byte span of the first DATA section's content (after ``DATA;``, up to its ``ENDSEC;``)."""
    match = _DATA_START.search(data)
    if match is None:
        return len(data), len(data)
    position = match.end()
    while (position := data.find(b"ENDSEC", position)) >= 0:  # bytes.find: memchr speed on large files
        line_start = data.rfind(b"\n", 0, position) + 1
        if not data[line_start:position].strip() and data[position + 6:position + 32].lstrip(b" \t")[:1] == b";":
            return match.end(), line_start
        position += 6
    return match.end(), len(data)


@cache
def _declaration(schema: str, entity: str):  # -> ifcopenshell entity declaration | None
    import ifcopenshell.ifcopenshell_wrapper as wrapper

    try:
        declaration = wrapper.schema_by_name(schema).declaration_by_name(entity)
    except (RuntimeError, IndexError):
        return None
    return declaration.as_entity()


@cache
def _derived(schema: str, entity: str) -> tuple[bool, ...] | None:
    declaration = _declaration(schema, entity)
    return None if declaration is None else tuple(declaration.derived())


@cache
def _attribute_count(schema: str, entity: str) -> int:
    declaration = _declaration(schema, entity)
    return 0 if declaration is None else int(declaration.attribute_count())


@cache
def is_a(schema: str, entity: str, supertype: str) -> bool:
    """Whether ``entity`` (any case) is ``supertype`` or one of its subtypes in ``schema``."""
    if _declaration(schema, entity) is None:
        return False
    return supertype.lower() in (c.lower() for c in class_ancestry(schema, entity))


def is_scannable_class(schema: str, entity: str) -> bool:
    """An IfcElement that is neither a feature (opening) nor a virtual element."""
    return is_a(schema, entity, "IfcElement") and not any(is_a(schema, entity, t) for t in NOT_SCANNABLE)


def derived_global_id(file_sha256: str, step_id: int) -> str:
    """A GlobalId for instance ``step_id`` of a file that gave it none: stable across runs."""
    return guid.derived_global_id(f"{file_sha256}#{step_id}")


# -- statements -----------------------------------------------------------------------------------

class _SyntaxProblem(Exception):
    pass


def _tokens(data: bytes, start: int, end: int) -> list[tuple[str, int, int]]:
    """(kind, start, end) of the tokens in data[start:end], whitespace and comments dropped."""
    out = []
    for match in _TOKEN.finditer(data, start, end):
        kind = match.lastgroup
        if kind in ("ws", "comment"):
            continue
        out.append((kind if kind != "punct" else match.group().decode(), match.start(), match.end()))
    return out


def _parse_statement(data: bytes, tokens: list[tuple[str, int, int]]) -> Statement:
    """A statement from its tokens (the ';' excluded); _SyntaxProblem with what is wrong."""
    if len(tokens) < 4 or tokens[0][0] != "ref" or tokens[1][0] != "=":
        raise _SyntaxProblem("does not start with '#n='")
    step_id = int(data[tokens[0][1] + 1:tokens[0][2]])
    if tokens[2][0] == "kw":
        entity = sys.intern(data[tokens[2][1]:tokens[2][2]].decode("ascii").upper())
        statement = Statement(step_id=step_id, entity=entity, start=tokens[0][1], end=tokens[-1][2])
        if tokens[3][0] != "(":
            raise _SyntaxProblem(f"{entity} is not followed by '('")
        stop = _parse_parameters(data, tokens, 4, statement, top=True)
        if stop != len(tokens):
            raise _SyntaxProblem(f"text after the closing bracket of {entity}")
        return statement
    if tokens[2][0] == "(":  # a complex instance: (ENTITY(...) ENTITY(...))
        statement = Statement(step_id=step_id, entity="", start=tokens[0][1], end=tokens[-1][2])
        position = 3
        while position < len(tokens) and tokens[position][0] == "kw":
            if position + 1 >= len(tokens) or tokens[position + 1][0] != "(":
                raise _SyntaxProblem("a partial entity of a complex instance is not followed by '('")
            position = _parse_parameters(data, tokens, position + 2, statement, top=False)
        if position != len(tokens) - 1 or tokens[position][0] != ")":
            raise _SyntaxProblem("a complex instance is not closed")
        return statement
    raise _SyntaxProblem("no entity name after '='")


def _parse_parameters(data: bytes, tokens: list[tuple[str, int, int]], position: int, statement: Statement,
                      *, top: bool) -> int:
    """Read parameters from just after an opening '(' to its ')'; returns the index after it.

    With ``top``, records the top-level attribute spans, kinds and references of ``statement``.
    """
    depth = 1
    attribute = 0
    expect = "value_or_close"
    attribute_start = None
    single_kind = ""
    n_values = 0  # values seen in the current top-level attribute (1 token value => its kind)
    while position < len(tokens):
        kind, start, end = tokens[position]
        position += 1
        if expect in ("value", "value_or_close"):
            if kind == ")" and expect == "value_or_close":
                depth -= 1
                if depth == 0:
                    return position  # an empty list (or no attributes)
                expect = "separator"
                continue
            if depth == 1 and attribute_start is None:
                attribute_start, n_values, single_kind = start, 0, ""
            n_values += 1
            if kind in _VALUE_KINDS or kind in ("$", "*"):
                if depth == 1:
                    single_kind = kind
                if kind == "ref" and top:
                    statement.references.extend((attribute, int(data[start + 1:end])))
                expect = "separator"
            elif kind == "kw":  # a typed value: NAME(value)
                if position >= len(tokens) or tokens[position][0] != "(":
                    raise _SyntaxProblem(f"unexpected word {data[start:end].decode('ascii', 'replace')!r}")
                position += 1
                depth += 1
                expect = "value"
            elif kind == "(":
                depth += 1
                expect = "value_or_close"
            else:
                raise _SyntaxProblem(_unexpected(data, kind, start, end))
            if depth > 1:
                single_kind = ""
        else:  # expect a separator
            if kind == ",":
                if depth == 1:
                    _close_attribute(statement, top, attribute_start, tokens[position - 2][2], single_kind, n_values)
                    attribute += 1
                    attribute_start = None
                expect = "value"
            elif kind == ")":
                depth -= 1
                if depth == 0:
                    _close_attribute(statement, top, attribute_start, tokens[position - 2][2], single_kind, n_values)
                    return position
            else:
                raise _SyntaxProblem(_unexpected(data, kind, start, end))
    raise _SyntaxProblem("brackets are not closed")


def _close_attribute(statement: Statement, top: bool, start: int | None, end: int, kind: str, n_values: int) -> None:
    if top and start is not None:
        statement.attributes.append((start, end))
        statement.kinds.append(kind if n_values == 1 else "")


def _unexpected(data: bytes, kind: str, start: int, end: int) -> str:
    text = data[start:end].decode("latin-1")
    if kind == "bad" and text == "'":
        return "a string is not closed"
    return f"unexpected {text!r}" if kind != "bad" else f"unexpected character {text!r}"


def _split_statements(data: bytes, start: int, end: int) -> Iterable[tuple[list[tuple[str, int, int]], bool]]:
    """Token lists of the statements in data[start:end] (split at ';' outside brackets), each with
    whether it was ended by ';'."""
    current: list[tuple[str, int, int]] = []
    depth = 0
    for token in _tokens(data, start, end):
        if token[0] == ";" and depth <= 0:
            yield current, True
            current, depth = [], 0
            continue
        if token[0] == "(":
            depth += 1
        elif token[0] == ")":
            depth -= 1
        current.append(token)
    if current:
        yield current, False


def _chunks(data: bytes, start: int, end: int) -> Iterable[tuple[int, int]]:
    """Byte spans of the line groups in data[start:end]: each from a line starting a statement to
    the next one (text before the first start is a group of its own)."""
    previous = start
    for match in _STATEMENT_START.finditer(data, start, end):
        if match.start() > previous:
            yield previous, match.start()
        previous = match.start()
    if previous < end:
        yield previous, end


def _read_well_formed(data: bytes, span: tuple[int, int], schema: str, lines: LineIndex, scan: StepScan) -> bool:
    """The fast path: a chunk holding one well-formed statement of a known entity that needs no
    repair, read with a few regular expressions (no tokens). False: the chunk needs the full read."""
    match = _WELL_FORMED.fullmatch(data, *span)
    if match is None:
        return False
    entity = sys.intern(match.group(2).decode("ascii").upper())
    step_id = int(match.group(1))
    body = match.group(3) or b""
    if (_declaration(schema, entity) is None or step_id in scan.statements or step_id in scan.unknown
            or b"*" in body or (body[:1] != b"'" and is_a(schema, entity, "IfcRoot"))):
        return False  # unknown, duplicate or maybe to repair: the full read keeps what those need
    statement = Statement(step_id=step_id, entity=entity, start=match.start(1) - 1, end=span[0] + len(match.group(0).rstrip()))
    flat = _STRING.sub(b"s", body) if b"'" in body else body
    if b"#" in flat:
        targets = array("q", map(int, _REFERENCE.findall(flat)))
        statement.references = array("q", (-1,)) * (2 * len(targets))  # attribute indices: resolved if needed
        statement.references[1::2] = targets
    while b"(" in flat:
        flat = _INNERMOST.sub(b"l", flat)
    count = flat.count(b",") + 1 if flat.strip() else 0
    expected = _attribute_count(schema, entity)
    if count != expected:
        scan.problems.append(Problem(
            "attribute-count", lines.line_of(statement.start), step_id,
            f"#{step_id} ({entity}) has {count} attributes, {schema} defines {expected}", entity))
    scan.statements[step_id] = statement
    return True


def _read_chunk(data: bytes, span: tuple[int, int], schema: str, lines: LineIndex, scan: StepScan, *,
                keep_attributes: bool) -> None:
    if not keep_attributes and _read_well_formed(data, span, schema, lines, scan):
        return
    for tokens, ended in _split_statements(data, *span):
        if not tokens:
            continue
        first = tokens[0][1]
        line = lines.line_of(first)
        try:
            if not ended:
                raise _SyntaxProblem("its brackets do not balance" if any(t[0] == ";" for t in tokens)
                                     else "it is cut short (no ';' at its end)")
            statement = _parse_statement(data, tokens)
        except _SyntaxProblem as problem:
            step_id, entity = _head(data, tokens)
            label = f"#{step_id}" + (f" ({entity})" if entity else "") if step_id else "text"
            scan.problems.append(Problem("syntax", line, step_id, f"{label} does not parse: {problem}; skipped",
                                         entity))
            scan.edits.append(_blank(data, first, _statement_end(data, tokens, ended), line, entity))
            if step_id and entity:
                scan.broken.setdefault(step_id, (entity, line))
            continue
        statement.end = _statement_end(data, tokens, ended)
        if statement.step_id in scan.statements or statement.step_id in scan.unknown:
            scan.problems.append(Problem("duplicate-id", line, statement.step_id,
                                         f"#{statement.step_id} is defined again; the later definition is skipped",
                                         statement.entity))
            scan.edits.append(_blank(data, statement.start, statement.end, line, statement.entity))
            scan.duplicates.append((statement, line))
            continue
        if statement.entity and _declaration(schema, statement.entity) is None:
            scan.unknown[statement.step_id] = statement
            scan.problems.append(Problem("unknown-entity", line, statement.step_id,
                                         f"#{statement.step_id} is of entity {statement.entity}, which {schema} does not "
                                         "define; skipped", statement.entity))
            continue
        scan.statements[statement.step_id] = statement
        _check_statement(data, statement, schema, line, scan)
        if not keep_attributes:
            statement.attributes, statement.kinds = [], []


def _statement_end(data: bytes, tokens: list[tuple[str, int, int]], ended: bool) -> int:
    end = tokens[-1][2]
    if ended:
        semicolon = data.find(b";", end)
        end = semicolon + 1 if semicolon >= 0 else end
    return end


def _head(data: bytes, tokens: list[tuple[str, int, int]]) -> tuple[int, str]:
    """The id and entity name of a statement that does not parse, as far as they can be read."""
    step_id, entity = 0, ""
    if tokens and tokens[0][0] == "ref":
        step_id = int(data[tokens[0][1] + 1:tokens[0][2]])
        if len(tokens) > 2 and tokens[1][0] == "=" and tokens[2][0] == "kw":
            entity = data[tokens[2][1]:tokens[2][2]].decode("ascii").upper()
    return step_id, entity


def _blank(data: bytes, start: int, end: int, line: int, entity: str) -> Edit:
    """Spaces for data[start:end], its line breaks kept (so line numbers stay the file's)."""
    text = bytes(b if b in (10, 13) else 32 for b in data[start:end])
    return Edit(start, end, text, "blank", entity, line)


def _check_statement(data: bytes, statement: Statement, schema: str, line: int, scan: StepScan) -> None:
    """Attribute count; '*' where the schema does not derive; '$' GlobalIds (edits added to ``scan``)."""
    entity = statement.entity
    if not entity:
        return
    expected = _attribute_count(schema, entity)
    if len(statement.attributes) != expected:
        scan.problems.append(Problem(
            "attribute-count", line, statement.step_id,
            f"#{statement.step_id} ({entity}) has {len(statement.attributes)} attributes, {schema} defines {expected}",
            entity))
    scan.edits.extend(_repairs(statement, schema, line))


def _repairs(statement: Statement, schema: str, line: int) -> list[Edit]:
    derived = _derived(schema, statement.entity) or ()
    name = class_ancestry(schema, statement.entity)[0]
    edits = []
    for index, ((start, end), kind) in enumerate(zip(statement.attributes, statement.kinds)):
        if index == 0 and kind != "str" and is_a(schema, statement.entity, "IfcRoot"):
            # '$', '*', a number...: IfcOpenShell's geometry waits forever on such an element. The
            # GlobalId is made up in apply_edits, from the file's hash.
            edits.append(Edit(start, end, b"", "globalid", name, line, statement.step_id))
        elif kind == "*" and index < len(derived) and not derived[index]:
            edits.append(Edit(start, end, b"$", "derived-attribute", name, line, statement.step_id))
    return edits


# -- whole-file reads ---------------------------------------------------------------------------

def scan_step(data: bytes, schema: str, *, keep_attributes: bool = False) -> StepScan:
    """Read every statement of the DATA section (see the module docstring). ``keep_attributes``:
    keep the attribute spans and kinds of every statement (else only of unknown entities and
    duplicates, which the element report reads)."""
    lines = LineIndex(data)
    scan = StepScan()
    start, end = data_section(data)
    for span in _chunks(data, start, end):
        _read_chunk(data, span, schema, lines, scan, keep_attributes=keep_attributes)
    defined = scan.statements
    for statement in defined.values():
        if all(target in defined for target in statement.references[1::2]):
            continue
        if statement.references and statement.references[0] < 0:  # read by the fast path: learn the attributes
            tokens = next(iter(_split_statements(data, statement.start, statement.end)))[0]
            statement.references = _parse_statement(data, tokens).references
        for attribute, target in statement.reference_pairs():
            if target in defined:
                continue
            line = lines.line_of(statement.start)
            why = (f"of entity {scan.unknown[target].entity}, unknown to {schema}" if target in scan.unknown
                   else "garbled" if target in scan.broken else "not defined in the file")
            scan.problems.append(Problem(
                "dangling-reference", line, statement.step_id,
                f"#{statement.step_id} ({statement.entity or 'complex instance'}) attribute {attribute + 1} refers to "
                f"#{target}, which is {why}", statement.entity))
    return scan


def quick_repairs(data: bytes, schema: str) -> list[Edit]:
    """The repair edits of the statements that hold a '*' or an IfcRoot with a '$' GlobalId (only
    those are read). Statements that do not parse, and GlobalIds of other kinds (IfcOpenShell
    complains of those), are left to ``scan_step``."""
    lines: LineIndex | None = None
    seen: set[int] = set()
    edits: list[Edit] = []
    start, end = data_section(data)
    for candidate in _repair_candidates(data, start, end, schema):
        chunk_start = data.rfind(b"\n", start, candidate) + 1
        while chunk_start > start and not _STATEMENT_START.match(data, chunk_start):
            chunk_start = data.rfind(b"\n", start, chunk_start - 1) + 1  # a statement spread over lines
        chunk_start = max(chunk_start, start)
        if chunk_start in seen:
            continue
        seen.add(chunk_start)
        following = _STATEMENT_START.search(data, candidate + 1, end)
        chunk_end = following.start() if following else end
        for tokens, ended in _split_statements(data, chunk_start, chunk_end):
            try:
                statement = _parse_statement(data, tokens) if ended else None
            except _SyntaxProblem:
                statement = None
            if statement is None or not statement.entity or _declaration(schema, statement.entity) is None:
                continue
            lines = lines or LineIndex(data)
            edits.extend(_repairs(statement, schema, lines.line_of(statement.start)))
    return edits


def _repair_candidates(data: bytes, start: int, end: int, schema: str) -> Iterator[int]:
    """Offsets of every '*' and of every '($' that opens an IfcRoot's attributes (a '$' GlobalId),
    found with bytes.find (a regular expression over the whole file would cost more than the rest)."""
    position = data.find(b"*", start, end)
    while position >= 0:
        yield position
        position = data.find(b"*", position + 1, end)
    position = data.find(b"($", start, end)
    while position >= 0:
        head = _HEAD_BEFORE.search(data, max(start, position - 128), position)
        if head is not None and is_a(schema, head.group(1).decode("ascii"), "IfcRoot"):
            yield position
        position = data.find(b"($", position + 2, end)


def apply_edits(data: bytes, edits: list[Edit], *, file_sha256: str) -> bytes:
    """``data`` with ``edits`` applied and a BOM dropped; ``missing-globalid`` edits get a GlobalId
    made from ``file_sha256`` and the instance id."""
    out = []
    position = 3 if data.startswith(BOM) else 0
    for edit in sorted(edits, key=lambda e: e.start):
        if edit.start < position:
            continue  # inside a statement already blanked
        out.append(data[position:edit.start])
        text = edit.text
        if edit.kind == "globalid":
            text = f"'{derived_global_id(file_sha256, edit.step_id)}'".encode("ascii")
        out.append(text)
        position = edit.end
    out.append(data[position:])
    return b"".join(out)


def summarize_repairs(edits: list[Edit]) -> dict[str, tuple[Counter, list[int]]]:
    """kind -> (instances repaired per class, their lines) of the repair edits."""
    out: dict[str, tuple[Counter, list[int]]] = {}
    seen: set[tuple[str, int]] = set()
    for edit in sorted(edits, key=lambda e: e.start):
        if edit.kind == "blank" or (edit.kind, edit.step_id) in seen:
            continue
        seen.add((edit.kind, edit.step_id))
        per_class, lines = out.setdefault(edit.kind, (Counter(), []))
        per_class[edit.entity] += 1
        lines.append(edit.line)
    return out


__all__ = [
    "BOM", "Edit", "LineIndex", "NEAREST_SCHEMA", "Problem", "StepScan", "Statement", "apply_edits",
    "count_statements", "data_section", "derived_global_id", "header_schema", "is_a", "is_scannable_class",
    "quick_repairs", "scan_step", "schema_edit", "summarize_repairs",
]

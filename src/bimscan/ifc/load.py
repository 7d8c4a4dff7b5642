"""Stage 1: parse an IFC model into one scannable mesh plus a component table.

``load_ifc`` reads IFC2X3, IFC4 and IFC4X3 (``.ifc``, or ``.ifczip``) through IfcOpenShell's
geometry iterator on all cores, in world coordinates, metres, Z up, openings cut from their hosts.
Every building element with 3D geometry becomes one component (dense id, GlobalId, IFC class,
PredefinedType, name, storey, STEP id). Labels are applied afterwards, by a scheme
(``bimscan.semantics.label_model``). Room volumes (IfcSpace) are kept aside for station planning;
openings, virtual elements, annotations and grids are not scannable.

Real exports are read as a viewer shows them, and nothing is lost silently
(``ParsedModel.report``, ``ParsedModel.failed``):

- repaired before the geometry (``bimscan.ifc.step``): ``*`` in attributes the schema does not
  derive (-> unset), ``$`` GlobalIds (-> a stable made-up one), a byte-order mark;
- reported with their lines: statements that do not parse (skipped), unknown entity names,
  ids defined twice, dangling references, wrong attribute counts, invalid values, a missing
  length unit (then millimetres are assumed when the model would be over 1 km across in metres,
  else metres; ``length_unit`` overrides);
- every declared element (an IfcElement with a body representation, by STEP id) that produced no
  geometry is in ``failed`` with its cause;
- refused: placement cycles (they crash the geometry kernel), a model with nothing to scan;
- the parse runs in a watched worker process (``bimscan.ifc.watchdog``): an element that crashes
  or hangs the geometry kernel is reported and skipped, never the end of the command.

With ``strict``, any repair, problem or failed element is an ``IfcError`` instead. Parsed
geometry is cached by file content hash (and length unit override).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from bimscan.errors import ConfigError, IfcError, InputFileError
from bimscan.files import check_input_file, file_sha256
from bimscan.ifc import cache as geometry_cache
from bimscan.ifc.units import LENGTH_UNITS
from bimscan.types import ParsedModel

# Bumped whenever what the parse produces changes, so stale cache entries are never used.
# 2: repairs and load report, STEP ids of components, failure causes, length-unit handling;
# 3: component surface styles and materials (ifc/materials.py); 4: bodies in "Design" and
# upper-case "MODEL" contexts (ArchiCAD, AutoCAD exports); 5: each triangle's surface-style
# transparency (a window's pane apart from its frame).
LOADER_VERSION = 5


def load_ifc(path: str | Path, *, use_cache: bool = True, threads: int | None = None, strict: bool = False,
             length_unit: str | None = None, element_timeout_s: float | None = None,
             progress: bool = True) -> ParsedModel:
    """Parse an IFC file into a ParsedModel (no labels yet; see the module docstring).

    path: an IFC-SPF file (.ifc) or a zip of one (.ifczip). use_cache: reuse geometry parsed
    before (keyed by file content hash, loader version and ``length_unit``; folder
    ``$BIMSCAN_CACHE_DIR`` or ``~/.cache/bimscan``). threads: geometry threads (all cores).
    strict: refuse a file that needed any repair, has any problem or loses any element.
    length_unit: read lengths in this unit (a ``LENGTH_UNITS`` name: m, cm, mm, ft, in) whatever
    the file says. element_timeout_s: the watchdog's limit per element (see ``bimscan.ifc.watchdog``).
    Raises InputFileError (missing, unreadable, not a regular file), IfcError (not IFC, truncated,
    unsupported schema, placement cycle, damaged archive, strict refusals), EmptyModelError (no
    element with geometry), ConfigError (unknown length unit).
    """
    from bimscan.ifc.watchdog import element_timeout

    path = Path(path)
    if length_unit is not None and length_unit not in LENGTH_UNITS:
        raise ConfigError(f"length unit {length_unit!r} is unknown; use one of {', '.join(LENGTH_UNITS)}")
    timeout_s = element_timeout(element_timeout_s)
    check_input_file(path, what="an IFC file (.ifc or .ifczip)")
    with _spf_file(path) as spf:
        _check_ifc_file(spf, str(path))
        digest = file_sha256(spf)
        key = f"{digest}-v{LOADER_VERSION}" + (f"-{length_unit}" if length_unit else "")
        parsed = geometry_cache.load_parsed(key) if use_cache else None
        if parsed is None:
            parsed = _parse(spf, name=str(path), digest=digest, threads=threads or os.cpu_count() or 1,
                            length_unit=length_unit, timeout_s=timeout_s, progress=progress)
            if use_cache:
                geometry_cache.store_parsed(key, parsed)
    parsed = replace(parsed, source=str(path), file_sha256=digest)
    if strict:
        refuse_unless_clean(parsed)
    return parsed


def refuse_unless_clean(parsed: ParsedModel) -> None:
    """IfcError (one line) when the model needed a repair, has a problem or lost an element."""
    from bimscan.ifc.summary import report_lines

    lines = report_lines(parsed)
    if lines:
        more = f" (and {len(lines) - 1} more kinds of problem)" if len(lines) > 1 else ""
        raise IfcError(f"{lines[0]}{more}; refused under strict checking: fix the file, or run without --strict "
                       "to load what a viewer shows")


def _parse(path: Path, *, name: str, digest: str, threads: int, length_unit: str | None, timeout_s: float,
           progress: bool) -> ParsedModel:
    from bimscan.ifc.parse import ParseRequest
    from bimscan.ifc.watchdog import run_parse

    request = ParseRequest(path=str(path), name=name, file_sha256=digest, threads=threads,
                           length_unit_m=LENGTH_UNITS[length_unit] if length_unit else None)
    return run_parse(request, timeout_s=timeout_s, file_bytes=path.stat().st_size, progress=progress)


@contextmanager
def _spf_file(path: Path) -> Iterator[Path]:
    """The IFC-SPF file to read: ``path``, or the one inside a zip archive, extracted to a
    temporary folder (errors name the archive)."""
    try:
        is_zip = zipfile.is_zipfile(path)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot be read ({exc.strerror or exc}); check its permissions") from exc
    if not is_zip:
        yield path
        return
    with tempfile.TemporaryDirectory(prefix="bimscan-ifczip-") as folder:
        extracted = Path(folder) / "model.ifc"
        try:
            with zipfile.ZipFile(path) as archive:
                members = [m for m in archive.namelist() if m.lower().endswith(".ifc") and not m.endswith("/")]
                if len(members) != 1:
                    raise IfcError(f"{path}: a zip archive with {len(members)} .ifc files; an .ifczip must hold "
                                   "exactly one")
                with archive.open(members[0]) as source, extracted.open("wb") as target:
                    shutil.copyfileobj(source, target, 8 << 20)
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError, ValueError) as exc:
            raise IfcError(f"{path}: the .ifczip archive is damaged ({' '.join(str(exc).split()) or type(exc).__name__}); "
                           "copy or export it again") from exc
        except OSError as exc:
            if exc.filename is not None and str(exc.filename) == str(extracted):
                raise IfcError(f"{path}: cannot extract the archive to {tempfile.gettempdir()} ({exc.strerror or exc}); "
                               "free space there or set TMPDIR") from exc
            raise IfcError(f"{path}: the .ifczip archive cannot be read ({exc.strerror or exc}); copy or export it "
                           "again") from exc
        yield extracted


def check_ifc_file(path: str | Path) -> None:
    """The checks ``load_ifc`` makes before it parses, in milliseconds, for commands and specs that
    parse later: a regular file that is an IFC-SPF file (header, end) or a zip archive of one .ifc."""
    path = check_input_file(path, what="an IFC file (.ifc or .ifczip)")
    try:
        if zipfile.is_zipfile(path):
            with zipfile.ZipFile(path) as archive:
                members = [m for m in archive.namelist() if m.lower().endswith(".ifc") and not m.endswith("/")]
            if len(members) != 1:
                raise IfcError(f"{path}: a zip archive with {len(members)} .ifc files; an .ifczip must hold exactly one")
            return
    except (OSError, zipfile.BadZipFile) as exc:
        raise IfcError(f"{path}: the .ifczip archive cannot be read ({exc}); copy or export it again") from exc
    _check_ifc_file(path, str(path))


def _check_ifc_file(path: Path, name: str) -> None:
    """Clear errors for an empty, non-IFC or truncated file before IfcOpenShell sees it."""
    try:
        with path.open("rb") as handle:
            head = handle.read(4096)
            handle.seek(max(0, path.stat().st_size - 4096))
            tail = handle.read()
    except OSError as exc:
        raise InputFileError(f"{name}: cannot be read ({exc.strerror}); check its permissions") from exc
    if not head.strip():
        raise IfcError(f"{name}: the file is empty; export the model again")
    if not head.lstrip(b"\xef\xbb\xbf \t\r\n").upper().startswith(b"ISO-10303-21"):
        raise IfcError(f"{name}: not an IFC file (no ISO-10303-21 STEP header); pass an IFC-SPF (.ifc) export")
    if b"END-ISO-10303-21" not in tail.upper():
        raise IfcError(f"{name}: the IFC file is truncated (no END-ISO-10303-21; at its end); copy or export it again")


__all__ = ["LOADER_VERSION", "check_ifc_file", "load_ifc", "refuse_unless_clean"]

"""File plumbing every stage shares: atomic outputs (temporary name + rename), what an output may
replace, and content hashes.

An output is written under a hidden temporary name in its destination folder and renamed into
place only when complete, so a reader never sees half a file, whatever stopped the writer.

An existing output is replaced (``replace_path``, and so every writer, with ``overwrite`` or on a
rerun) only when it is what bimscan writes there (``check_replaceable``): a regular file in the
format its suffix names (``FILE_SIGNATURES``), or a folder of a kind bimscan writes whole
(``FOLDER_OUTPUTS``: a NumPy cloud, a data unit, ...), recognised by its marker and holding
nothing else. A user's folder, a symbolic link or another format's file is refused in one line,
whatever the options: bimscan never removes what it did not write.

A folder bimscan writes several outputs into (a dataset, a training run, an evaluation, the
statistics, an experiment: an *output folder*) is one it made or an empty one
(``prepare_output_folder``); its record ``.bimscan.json`` lists what bimscan wrote there, and
inside it only those are replaced (``check_replaceable`` reads the record of the folder a path is
in, and ``replace_path`` adds the names it moves in). A user's file beside them is never touched;
one at a name bimscan is about to write is refused before any work (``check_output_folder``).
"""

from __future__ import annotations

import csv
import errno
import fcntl
import hashlib
import io
import json
import os
import re
import secrets
import shutil
import stat
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.errors import InputFileError, OutputError


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes, read in 8 MiB blocks."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        while block := handle.read(8 << 20):
            digest.update(block)
    return digest.hexdigest()


def path_kind(path: str | Path) -> str | None:
    """What ``path`` is when it is not a regular file, in words ("a folder", "a FIFO (named pipe)",
    "a symbolic link loop", "no such file", ...); None for a regular file (or a link to one)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "a broken symbolic link" if os.path.islink(path) else "no such file"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symbolic link loop"
        if exc.errno == errno.ENAMETOOLONG:
            return "a name too long for the file system"
        if exc.errno == errno.ENOTDIR:
            return "no such file (a part of the path is not a folder)"
        return f"not accessible ({exc.strerror or exc})"
    for test, words in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                        (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                        (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return words
    return None if stat.S_ISREG(mode) else "not a regular file"


# Temporary names: ".<name>.<pid>-<12 hex>.tmp" (the writer's process id, so that a later run can
# tell a dead writer's leftovers from a live one's); ".<name>.<12 hex>.tmp" from older versions.
_TEMP_SUFFIX = re.compile(r"(?:(?P<pid>[0-9]+)-)?[0-9a-f]{12}\.tmp")


def check_input_file(path: str | Path, *, what: str, folders: bool = False) -> Path:
    """``path`` when it is a regular file (or a folder, with ``folders``), else an InputFileError
    that says what it is: "no such file", "a FIFO (named pipe)", "a symbolic link loop", ...
    (reading a FIFO or a device would block or never end)."""
    kind = path_kind(path)
    if kind is None or (folders and kind == "a folder"):
        return Path(path)
    if kind.startswith("no such file"):
        raise InputFileError(f"{path}: {kind}{' or folder' if folders and kind == 'no such file' else ''}; "
                             "check the path")
    raise InputFileError(f"{path}: is {kind}, not {what}; pass a regular file")


def temp_path(final: str | Path) -> Path:
    """A hidden, unique sibling name for staging ``final`` (``.<name>.<pid>-<random>.tmp``).

    Temporaries of the same ``final`` left by writers that died (killed, power cut) are removed
    first (see ``remove_stale_temps``).
    """
    final = Path(final)
    if final.name in ("", ".", ".."):
        raise OutputError(f"{final} names a folder, not an output inside one; give the output a name of its own")
    remove_stale_temps(final)
    return final.with_name(f".{final.name}.{os.getpid()}-{secrets.token_hex(6)}.tmp")


@contextmanager
def work_folder(beside: str | Path) -> Iterator[Path]:
    """A fresh hidden folder for temporary work, named for ``beside`` as ``temp_path`` names
    temporaries (so the next run removes it when this process is killed before it could), and
    removed when the block ends."""
    folder = temp_path(beside)
    folder.mkdir()
    try:
        yield folder
    finally:
        try:
            remove_path(folder)
        except OSError:
            pass  # best effort: a failing clean-up must not hide what the block raised


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # someone else's live process (or a number we cannot check): keep its file
    return True


def _remove_dead(folder: Path, names: list[str], prefix_of: Callable[[str], int | None]) -> int:
    """Remove the temporaries among ``names`` (in ``folder``) whose writer is gone; ``prefix_of``
    gives the length of a name's ``.<output name>.`` part, None for names that are no temporary."""
    removed = 0
    for name in names:
        start = prefix_of(name)
        match = None if start is None else _TEMP_SUFFIX.fullmatch(name[start:])
        if match is None or (match.group("pid") and _process_alive(int(match.group("pid")))):
            continue
        try:
            remove_path(folder / name)
            removed += 1
        except OSError:
            continue  # not ours to delete after all (permissions): leave it
    return removed


def remove_stale_temps(final: str | Path) -> int:
    """Delete the temporaries of ``final`` whose writer process is gone; returns how many.

    A temporary of a live process on this machine is kept. (A writer on another machine sharing
    the folder cannot be seen: two machines writing the same output at once is not supported.)
    """
    final = Path(final)
    prefix = f".{final.name}."
    try:
        names = [n for n in os.listdir(final.parent) if n.startswith(prefix)]
    except OSError:
        return 0
    return _remove_dead(final.parent, names, lambda name: len(prefix))


def remove_dead_temps(folder: str | Path) -> int:
    """Delete every temporary in ``folder`` (``.<name>.<pid>-<random>.tmp``, whatever the output)
    whose writer process is gone, e.g. those of the workers a stopped command has just ended;
    returns how many. Live processes' temporaries are kept."""
    folder = Path(folder)
    try:
        names = [n for n in os.listdir(folder) if n.startswith(".") and n.endswith(".tmp")]
    except OSError:
        return 0

    def prefix_of(name: str) -> int | None:
        # the output's name may hold dots: the temporary part follows the last dot before "<pid>-"
        match = re.search(r"\.(?=(?:[0-9]+-)?[0-9a-f]{12}\.tmp$)", name)
        return None if match is None or match.start() == 0 else match.end()

    return _remove_dead(folder, names, prefix_of)


def remove_path(path: Path) -> None:
    """Delete a file or a folder tree; absent is fine. Only for bimscan's own temporaries: an
    existing output is replaced through ``replace_path``, which checks what it is first."""
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    except FileNotFoundError:
        pass


# -- what an output may replace -----------------------------------------------------------------

# The first bytes of the files bimscan writes at paths a user names, by the end of their name (the
# longest that matches): an existing file of such a name is replaced only when it starts with them;
# any regular file is, for names without an entry (JSON, Markdown, plain CSV, and bimscan's own
# caches and checkpoints, which it rewrites when they are damaged).
FILE_SIGNATURES: dict[str, tuple[bytes, ...]] = {
    ".las": (b"LASF",),
    ".laz": (b"LASF",),
    ".ply": (b"ply\n", b"ply\r\n"),
    ".ply.json": (b"{",),  # a PLY cloud's header sidecar
    ".e57": (b"ASTM-E57",),
    ".png": (b"\x89PNG\r\n\x1a\n",),
    ".ifc": (b"ISO-10303-21;",),
    ".bcf": (b"PK\x03\x04",),  # a BCF file is a zip
    ".bcfzip": (b"PK\x03\x04",),
    ".trajectory.csv": (b"t,x,y,z,roll,pitch,yaw,pass\n",),  # the walk beside a mobile scan
}


def file_signatures(path: str | Path) -> tuple[str, tuple[bytes, ...]] | None:
    """(the name ending, its signatures) of ``FILE_SIGNATURES`` that applies to ``path``, or None."""
    name = Path(path).name.lower()
    ending = max((e for e in FILE_SIGNATURES if name.endswith(e) and len(name) > len(e)), key=len, default=None)
    return None if ending is None else (ending, FILE_SIGNATURES[ending])


@dataclass(frozen=True)
class FolderOutput:
    """A kind of folder bimscan writes whole, and so may replace whole.

    what: its name in messages ("a bimscan NumPy cloud"). foreign: for an existing folder, the
    names of the entries in it that bimscan did not write (sub-folders as ``name/``), or None
    when the folder is not of this kind at all (its marker is missing or not bimscan's).
    """

    what: str
    foreign: Callable[[Path], list[str] | None]


# Filled where each kind is written: "npy" (bimscan.io.npdir), "unit" (bimscan.dataset.layout),
# "obj-components" and "helios" (bimscan.io.obj).
FOLDER_OUTPUTS: dict[str, FolderOutput] = {}


def folder_entries(folder: Path) -> list[str]:
    """The names in ``folder``, sorted, sub-folders (not links to them) as ``name/``."""
    names = []
    for entry in os.scandir(folder):
        names.append(entry.name + "/" if entry.is_dir(follow_symlinks=False) else entry.name)
    return sorted(names)


def _shown(names: list[str], limit: int = 5) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def read_marker(path: Path, *, limit: int = 1 << 26) -> bytes | None:
    """The bytes of a marker file when ``path`` is a regular file (not a link) of at most
    ``limit`` bytes; None otherwise (then it marks nothing)."""
    try:
        info = os.lstat(path)
        if not stat.S_ISREG(info.st_mode) or info.st_size > limit:
            return None
        return path.read_bytes()
    except OSError:
        return None


def file_head(path: Path, size: int) -> bytes | None:
    """The first ``size`` bytes of ``path`` when it is a regular file (not a link); None otherwise."""
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return None
        with path.open("rb") as handle:
            return handle.read(size)
    except OSError:
        return None


def json_marker(data: bytes | None, key: str, value: object = None) -> bool:
    """Whether ``data`` is a JSON object with ``key`` (equal to ``value`` unless None)."""
    if data is None:
        return False
    try:
        document = json.loads(data)
    except (ValueError, UnicodeDecodeError):
        return False
    return isinstance(document, dict) and key in document and (value is None or document[key] == value)


_REPLACE_ADVICE = "bimscan replaces only what it wrote: choose another output or remove it yourself"


# An IFC file names who wrote it in its header (FILE_NAME's author list): bimscan's IFC outputs add
# an author starting with this (make-building's building, furnish's and progress's copies), so that a
# user's own model, which an IFC's first bytes cannot tell from bimscan's, is never replaced.
IFC_AUTHOR_PREFIX = "bimscan "
_HEADER_BYTES = 1 << 16


def ifc_authors(path: str | Path) -> tuple[str, ...] | None:
    """The author list of the FILE_NAME of the IFC (STEP) file at ``path``'s header, or None when
    its first 64 KiB hold no readable FILE_NAME."""
    head = file_head(Path(path), _HEADER_BYTES)
    if head is None:
        return None
    text = head.decode("latin-1")
    end = text.find("ENDSEC;")
    match = re.search(r"FILE_NAME\s*\(\s*'(?:[^']|'')*'\s*,\s*'(?:[^']|'')*'\s*,\s*\(([^)]*)\)",
                      text[: end if end >= 0 else len(text)])
    if match is None:
        return None
    return tuple(item.replace("''", "'") for item in re.findall(r"'((?:[^']|'')*)'", match.group(1)))


def mark_ifc_written_by(model: Any, command: str) -> None:
    """Add the author "bimscan COMMAND" to the FILE_NAME of an IfcOpenShell ``model``'s header,
    after the model's own authors (``IFC_AUTHOR_PREFIX``: what lets bimscan replace it later)."""
    header = model.header.file_name
    mine = IFC_AUTHOR_PREFIX + command
    authors = tuple(a for a in header.author if a)
    if mine not in authors:
        header.author = authors + (mine,)


# A PNG bimscan writes says so in a tEXt chunk (matplotlib's metadata), fixed so that the same
# picture gives the same bytes: a user's picture, which a PNG's first bytes cannot tell from
# bimscan's, is never replaced.
PNG_SOFTWARE = "bimscan"


def save_png(figure: Any, path: str | Path, *, dpi: float) -> None:
    """Write a matplotlib ``figure`` as a PNG at ``path``, atomically, with the fixed Software text
    ``PNG_SOFTWARE`` (not matplotlib's version: the same figure gives the same bytes, and bimscan may
    replace the file later)."""
    with atomic_output(path) as temp:
        figure.savefig(temp, format="png", dpi=dpi, metadata={"Software": PNG_SOFTWARE})


def png_software(path: str | Path) -> str | None:
    """The ``Software`` text of the PNG at ``path`` (a tEXt chunk before its image data), or None."""
    head = file_head(Path(path), _HEADER_BYTES)
    if head is None or not head.startswith(b"\x89PNG\r\n\x1a\n"):
        return None
    at = 8
    while at + 8 <= len(head):
        length, kind = int.from_bytes(head[at:at + 4], "big"), head[at + 4:at + 8]
        if kind in (b"IDAT", b"IEND"):
            return None
        data = head[at + 8:at + 8 + length]
        if kind == b"tEXt" and data.startswith(b"Software\0"):
            return data[len(b"Software\0"):].decode("latin-1")
        at += 12 + length
    return None


def _file_problem(path: Path, *, recorded: bool = False) -> str | None:
    """Why the regular file at ``path`` is not an output bimscan may replace, or None. ``recorded``:
    its folder's record lists it (bimscan wrote it there), so an IFC's or a PNG's mark is not asked for."""
    found = file_signatures(path)
    if found is None:
        return None
    ending, signatures = found
    try:
        with path.open("rb") as handle:
            head = handle.read(max(len(s) for s in signatures))
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if not any(head.startswith(s) for s in signatures):
        return f"is a file not in the format of a {ending} file" + (" (it is empty)" if not head else "")
    if recorded:
        return None
    if ending == ".ifc" and not any(a.startswith(IFC_AUTHOR_PREFIX) for a in ifc_authors(path) or ()):
        return "is an IFC model bimscan did not write (no author in its header's FILE_NAME is bimscan)"
    if ending == ".png" and png_software(path) != PNG_SOFTWARE:
        return "is a picture bimscan did not write (its PNG names no bimscan software)"
    return None


def replace_problem(path: str | Path, *, kind: str | None = None) -> str | None:
    """Why bimscan may not replace what is at ``path`` with a new output, in words that follow the
    path ("is a folder that is not a bimscan NumPy cloud (it holds thesis.txt, sub/)"); None when
    it may: nothing is there, or (``kind`` None: a file output) a regular file in the format its
    suffix names, or (``kind``: a ``FOLDER_OUTPUTS`` key) a folder of that kind holding nothing else,
    and, in an output folder, only what its record lists (``read_output_record``)."""
    path = Path(path)
    if not os.path.lexists(path):
        return None
    listed = read_output_record(path.parent)
    if listed is not None and path.name != OUTPUT_RECORD and not {path.name, path.name + "/"} & listed:
        return (f"was not written by bimscan: {path.parent} is a folder bimscan made, and its record "
                f"{OUTPUT_RECORD} does not list {path.name}")
    if path.is_symlink():
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"is a symbolic link (to {target})"
    wanted = None if kind is None else FOLDER_OUTPUTS[kind]
    what = path_kind(path)
    if what is None:  # a regular file
        if wanted is not None:
            return f"is a file, not {wanted.what}"
        return _file_problem(path, recorded=listed is not None and path.name in listed)
    if what != "a folder":
        return f"is {what}"
    try:
        names = folder_entries(path)
    except OSError as exc:
        return f"is a folder that cannot be read ({exc.strerror or exc})"
    holds = f"it holds {_shown(names)}" if names else "it is empty"
    if wanted is None:
        return f"is a folder, not {f'a {path.suffix} file' if path.suffix else 'a file'} ({holds})"
    try:
        foreign = wanted.foreign(path)
    except OSError as exc:
        return f"is a folder that cannot be read ({exc.strerror or exc})"
    if foreign is None:
        return f"is a folder that is not {wanted.what} ({holds})"
    if foreign:
        return f"is {wanted.what} that also holds {_shown(foreign)}, which bimscan did not write"
    return None


def check_replaceable(path: str | Path, *, kind: str | None = None) -> None:
    """Raise OutputError unless bimscan may replace what is at ``path`` (see ``replace_problem``):
    the one rule every output that replaces another goes through (and so every output folder,
    ``check_output_folder``)."""
    problem = replace_problem(path, kind=kind)
    if problem is not None:
        raise OutputError(f"{path} {problem}; {_REPLACE_ADVICE}")


def replace_path(staged: Path, final: Path, *, kind: str | None = None) -> None:
    """Move ``staged`` (a file, or a folder of ``FOLDER_OUTPUTS[kind]``) to ``final``, replacing what
    is there only when ``check_replaceable`` allows it (OutputError otherwise, and nothing moves).

    ``os.replace`` cannot put a folder over a non-empty folder: the old output is moved aside
    first and dropped once the new one is in place.
    """
    if os.path.lexists(final):
        check_replaceable(final, kind=kind)
    record_output(final, folder=staged.is_dir())
    if kind is not None and final.is_dir():
        trash = temp_path(final)
        os.replace(final, trash)
        os.replace(staged, final)
        remove_path(trash)
    else:
        os.replace(staged, final)


def remove_output(path: str | Path) -> bool:
    """Remove the output bimscan wrote at ``path`` (a stale sidecar, say); OutputError when what
    is there is not bimscan's (``check_replaceable``). Returns whether something was removed."""
    path = Path(path)
    if not os.path.lexists(path):
        return False
    check_replaceable(path)
    remove_path(path)
    return True


# -- folders bimscan writes into ---------------------------------------------------------------

# An output folder's record: the names bimscan wrote in it, sub-folders as "name/" (hidden, so that
# it stays out of the way of what the user looks for in the folder).
OUTPUT_RECORD = ".bimscan.json"
OUTPUT_RECORD_FORMAT = "bimscan-output-folder"
OUTPUT_RECORD_VERSION = 1
_RECORD_LIMIT = 1 << 20


def read_output_record(folder: str | Path) -> frozenset[str] | None:
    """The names (sub-folders as ``name/``) the record of ``folder`` lists as bimscan's; None when
    ``folder`` has no record (not a folder bimscan made, or one an earlier version made)."""
    data = read_marker(Path(folder) / OUTPUT_RECORD, limit=_RECORD_LIMIT)
    if not json_marker(data, "format", OUTPUT_RECORD_FORMAT):
        return None
    names = json.loads(data or b"{}").get("files")
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        return None
    return frozenset(names)


def _write_record(folder: Path, names: Iterable[str]) -> None:
    document = {"format": OUTPUT_RECORD_FORMAT, "version": OUTPUT_RECORD_VERSION, "files": sorted(set(names))}
    temp = temp_path(folder / OUTPUT_RECORD)
    try:
        temp.write_bytes(dump_json(document))
        os.replace(temp, folder / OUTPUT_RECORD)  # the record itself is never a user's: see read_output_record
    finally:
        remove_path(temp)


@contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``folder`` while its record is read and rewritten, so that two
    writers in one folder do not drop each other's names (best effort: where the file system
    cannot lock a folder, a lost name only makes a later run refuse that file, never replace it)."""
    try:
        handle = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX)
        except OSError:
            pass
        yield
    finally:
        os.close(handle)


def record_output(path: str | Path, *, folder: bool = False) -> None:
    """Add ``path`` (a ``folder`` or a file) to the record of the output folder it is in, if it is
    in one; nothing otherwise. Called before the output appears, so the record never misses it."""
    path = Path(path)
    name = path.name + ("/" if folder else "")
    if path.name == OUTPUT_RECORD:
        return
    listed = read_output_record(path.parent)
    if listed is None or name in listed:
        return
    with _folder_lock(path.parent):
        listed = read_output_record(path.parent)
        if listed is not None and name not in listed:
            _write_record(path.parent, listed | {name})


def _output_folder_problem(folder: Path, names: Iterable[str], made_by: Callable[[Path], bool] | None) -> str | None:
    """The one-line message (naming the path at fault) when bimscan may not write ``names`` into
    ``folder``; None when it may."""
    if not os.path.lexists(folder):
        return None
    kind = path_kind(folder)  # a link to a folder is written through
    if kind != "a folder":
        return f"{folder} is {kind or 'a file'}, not a folder; {_REPLACE_ADVICE}"
    try:
        entries = folder_entries(folder)
    except OSError as exc:
        return f"{folder} is a folder that cannot be read ({exc.strerror or exc}); check its permissions"
    listed = read_output_record(folder)
    if listed is None:
        if not entries:
            return None
        if made_by is None or not made_by(folder) or os.path.lexists(folder / OUTPUT_RECORD):  # not our record
            return (f"{folder} is a folder bimscan did not make (it holds {_shown(entries)}); bimscan writes only into "
                    "a new or empty folder, or one it made: choose another")
        listed = frozenset(name for name in names if os.path.lexists(folder / name.rstrip("/")))  # an earlier version's
    for name in names:
        path = folder / name.rstrip("/")
        if not os.path.lexists(path):
            continue
        if name not in listed:
            return (f"{path} was not written by bimscan (the record {OUTPUT_RECORD} of the folder does not list it) "
                    "and bimscan writes that name there; move it away or choose another folder")
        if name.endswith("/"):
            if path.is_symlink() or not path.is_dir():
                return f"{path} is {path_kind(path) or 'a file'}, not the folder bimscan made there; {_REPLACE_ADVICE}"
        elif (problem := replace_problem(path)) is not None:
            return f"{path} {problem}; {_REPLACE_ADVICE}"
    return None


def check_output_folder(folder: str | Path, *, names: Iterable[str] = (),
                        made_by: Callable[[Path], bool] | None = None) -> None:
    """Raise OutputError, naming the folder or file at fault, unless bimscan may write ``names``
    (sub-folders as ``name/``) into ``folder``: it is missing, empty, or a folder bimscan made (its
    record; or, for one an earlier version made, ``made_by(folder)``: its marker, e.g. a dataset's
    manifest), and each name is missing there or one bimscan wrote. Checks only: call it before
    slow work, ``prepare_output_folder`` when about to write."""
    problem = _output_folder_problem(Path(folder), list(names), made_by)
    if problem is not None:
        raise OutputError(problem)


def prepare_output_folder(folder: str | Path, *, names: Iterable[str] = (),
                          made_by: Callable[[Path], bool] | None = None) -> Path:
    """``folder`` checked (``check_output_folder``), made when missing (with its parents), and
    given its record when it has none (an empty folder: nothing listed; an earlier version's:
    those of ``names`` it holds). A folder made inside another output folder is added to that
    one's record. Returns the folder."""
    folder = Path(folder)
    names = list(names)
    check_output_folder(folder, names=names, made_by=made_by)
    if not os.path.lexists(folder):
        record_output(folder, folder=True)
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create the folder {folder} ({exc.strerror or exc}); check the path") from exc
    if read_output_record(folder) is None:
        with _folder_lock(folder):
            if read_output_record(folder) is None:
                _write_record(folder, (name for name in names if os.path.lexists(folder / name.rstrip("/"))))
    return folder


def claim_output(folder: str | Path, name: str) -> Path:
    """``folder / name`` recorded as bimscan's in the record of ``folder`` (a prepared output
    folder), for outputs that are not moved in by ``replace_path``: a sub-folder (``name/``, made
    here when missing) or a file opened in place (a lock). OutputError when something bimscan did
    not write is there."""
    folder = Path(folder)
    path = folder / name.rstrip("/")
    if os.path.lexists(path):
        check_output_folder(folder, names=[name])
    record_output(path, folder=name.endswith("/"))
    if name.endswith("/"):
        path.mkdir(exist_ok=True)
    return path


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; it is renamed to ``path`` when the
    block ends normally and removed when it raises."""
    path = Path(path)
    temp = temp_path(path)
    try:
        yield temp
        replace_path(temp, path)
    finally:
        remove_path(temp)  # gone already when the rename succeeded


def write_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_output(path) as temp:
        temp.write_bytes(data)


def _json_default(value: object) -> object:
    # Metadata often carries NumPy scalars/arrays, paths and tuples: store them as plain JSON values.
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, set | frozenset):
        return sorted(value)
    raise TypeError(f"{type(value).__name__} {value!r} is not JSON-able")


def csv_bytes(rows: Iterable[Mapping[str, object]], columns: Sequence[str]) -> bytes:
    """UTF-8 CSV bytes: a header of ``columns``, then one line per row (``\n`` line ends)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return out.getvalue().encode("utf-8")


def dump_json(document: Any, *, indent: int | None = 1) -> bytes:
    """Canonical UTF-8 JSON bytes (sorted keys, finite numbers only), for byte-identical outputs.

    ``indent=None`` writes compact JSON; otherwise indented with a final newline. Raises
    TypeError/ValueError for values JSON cannot hold.
    """
    separators = (",", ": ") if indent is not None else (",", ":")
    text = json.dumps(document, sort_keys=True, indent=indent, separators=separators, ensure_ascii=False,
                      allow_nan=False, default=_json_default)
    return text.encode("utf-8") + (b"\n" if indent is not None else b"")

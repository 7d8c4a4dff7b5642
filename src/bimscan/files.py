"""File plumbing every stage shares: atomic outputs (temporary name + rename) and content hashes.

An output is written under a hidden temporary name in its destination folder and renamed into
place only when complete, so a reader never sees half a file, whatever stopped the writer.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from bimscan.errors import InputFileError


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
    remove_stale_temps(final)
    return final.with_name(f".{final.name}.{os.getpid()}-{secrets.token_hex(6)}.tmp")


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


def remove_stale_temps(final: str | Path) -> int:
    """Delete the temporaries of ``final`` whose writer process is gone; returns how many.

    A temporary of a live process on this machine is kept. (A writer on another machine sharing
    the folder cannot be seen: two machines writing the same output at once is not supported.)
    """
    final = Path(final)
    prefix = f".{final.name}."
    removed = 0
    try:
        names = [n for n in os.listdir(final.parent) if n.startswith(prefix)]
    except OSError:
        return 0
    for name in names:
        match = _TEMP_SUFFIX.fullmatch(name[len(prefix):])
        if match is None or (match.group("pid") and _process_alive(int(match.group("pid")))):
            continue
        try:
            remove_path(final.parent / name)
            removed += 1
        except OSError:
            continue  # not ours to delete after all (permissions): leave it
    return removed


def remove_path(path: Path) -> None:
    """Delete a file or a folder tree; absent is fine."""
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
    except FileNotFoundError:
        pass


def replace_path(staged: Path, final: Path) -> None:
    """Move ``staged`` (a file or a folder) to ``final``, replacing what is there.

    ``os.replace`` cannot put a folder over a non-empty folder (or a file over a folder): the old
    output is moved aside first and dropped once the new one is in place.
    """
    if (final.exists() or final.is_symlink()) and (staged.is_dir() or final.is_dir()):
        trash = temp_path(final)
        os.replace(final, trash)
        os.replace(staged, final)
        remove_path(trash)
    else:
        os.replace(staged, final)


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


def dump_json(document: Any, *, indent: int | None = 1) -> bytes:
    """Canonical UTF-8 JSON bytes (sorted keys, finite numbers only), for byte-identical outputs.

    ``indent=None`` writes compact JSON; otherwise indented with a final newline. Raises
    TypeError/ValueError for values JSON cannot hold.
    """
    separators = (",", ": ") if indent is not None else (",", ":")
    text = json.dumps(document, sort_keys=True, indent=indent, separators=separators, ensure_ascii=False,
                      allow_nan=False, default=_json_default)
    return text.encode("utf-8") + (b"\n" if indent is not None else b"")

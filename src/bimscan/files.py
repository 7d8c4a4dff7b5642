"""File plumbing every stage shares: atomic outputs (temporary name + rename) and content hashes.

An output is written under a hidden temporary name in its destination folder and renamed into
place only when complete, so a reader never sees half a file, whatever stopped the writer.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import secrets
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


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


def temp_path(final: str | Path) -> Path:
    """A hidden, unique sibling name for staging ``final`` (``.<name>.<random>.tmp``)."""
    final = Path(final)
    return final.with_name(f".{final.name}.{secrets.token_hex(6)}.tmp")


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

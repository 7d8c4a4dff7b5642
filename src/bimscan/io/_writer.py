"""What every cloud writer shares: temporary outputs renamed at close, column checks, errors.

A writer stages its output under a hidden temporary name in the destination folder
(``.<name>.<pid>-<random>.tmp``, see ``bimscan.files.temp_path``), streams chunks into it and, at ``close()``, finishes the headers and
renames it into place with ``os.replace`` (atomic for a file on one file system). Any failure,
and ``abort()``, removes the temporary output; a reader never sees a half-written cloud. The
temporary name is random but never part of the output bytes. With ``overwrite`` an existing
output is replaced only when it is one bimscan writes there (``bimscan.files.check_replaceable``:
a cloud file in the format its suffix names, a NumPy cloud folder with its ``meta.json``); anything
else is refused before any work.

Outputs are not fsync'ed: the rename protects against interrupted and failed runs, not against
power loss before the operating system has written its cache.
"""

from __future__ import annotations

import datetime as dt
import errno
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import BinaryIO, Protocol, Self

import numpy as np

from bimscan.errors import OutputError
from bimscan.files import check_input_file, check_replaceable, file_sha256, remove_path, replace_path, temp_path
from bimscan.io._header import dump_json, header_to_document, present_columns
from bimscan.io._labelled import ExtraField
from bimscan.progress import StageClock
from bimscan.types import CloudHeader, PointCloud

BLOCK_POINTS = 1_000_000  # rows encoded per step: bounds a writer's memory whatever the chunk size


@dataclass(frozen=True)
class WrittenCloud:
    """A finished cloud output.

    path: the file or folder written. n_points: rows written. files: every file written (the
    folder's members for a NumPy folder, the sidecar for PLY). sha256: hex digest per file, keyed
    by the path relative to ``path.parent`` (empty when the writer ran with ``checksum=False``).
    n_bytes: total size of ``files``.
    """

    path: Path
    n_points: int
    files: tuple[Path, ...]
    sha256: Mapping[str, str] = field(default_factory=dict)
    n_bytes: int = 0


class CloudWriter(Protocol):
    """A streamed cloud writer; use it as a context manager (an exception inside aborts)."""

    def write(self, chunk: PointCloud, values: np.ndarray | None = None) -> None: ...
    def close(self) -> WrittenCloud: ...
    def abort(self) -> None: ...
    def __enter__(self) -> Self: ...
    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None: ...


def output_error(exc: OSError, path: Path) -> OutputError:
    """The one-line OutputError for an OSError met while writing ``path``."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return OutputError(f"disk full while writing {path}; free space and run again")
    reason = exc.strerror or str(exc)
    return OutputError(f"could not write {path} ({reason}); check the folder and its permissions and run again")


def folder_writable(folder: Path) -> bool:
    """Whether this process may create files in ``folder``."""
    return os.access(folder, os.W_OK | os.X_OK)


def check_output_path(path: Path, *, overwrite: bool, extra: tuple[Path, ...] = (), kind: str | None = None) -> None:
    """Refuse outputs that cannot be written: a path that names no output of its own (``.``, ``..``,
    ``/``), a missing or read-only parent folder, an existing output (without ``overwrite``), or,
    with ``overwrite``, anything there that bimscan may not replace (``check_replaceable``; ``kind``:
    the ``FOLDER_OUTPUTS`` kind of a folder output, None for a file; ``extra`` are files)."""
    if Path(path).name in ("", ".", ".."):
        raise OutputError(f"{path} names a folder ({Path(path).resolve()}), not an output inside one; give the "
                          "output a name of its own")
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"output folder {parent} does not exist; create it first or choose another path")
    if not folder_writable(parent):
        raise OutputError(f"output folder {parent} is not writable; check its permissions or choose another path")
    for target in (path, *extra):
        if not (target.exists() or target.is_symlink()):
            continue
        if not overwrite:
            raise OutputError(f"{target} already exists; pass --overwrite to replace it or choose another path")
        check_replaceable(target, kind=kind if target == path else None)


def source_date_epoch() -> int | None:
    """``SOURCE_DATE_EPOCH`` (Unix seconds) when set: the date reproducible outputs record."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    if not epoch:
        return None
    try:
        value = int(epoch)
        dt.datetime.fromtimestamp(value, tz=dt.UTC)
    except (ValueError, OverflowError, OSError) as exc:
        raise OutputError(f"SOURCE_DATE_EPOCH={epoch!r} is not a Unix time in seconds; fix or unset it") from exc
    return value


def check_input_path(path: str | Path) -> Path:
    """``path`` as a Path to a regular file or a folder, or an InputFileError saying what it is."""
    return check_input_file(path, what="a point cloud file or folder", folders=True)


class WatchedFile:
    """A binary file that remembers the OSError any of its methods raised.

    lazrs turns a failing ``write``/``seek`` of the Python file it writes to into
    ``LazrsError: IoError`` and drops the OSError (and with it ENOSPC); the writers look the
    original up here. Buffered data may also fail only at ``flush``/``seek``/``close`` time.
    """

    def __init__(self, raw: BinaryIO) -> None:
        self.raw = raw
        self.error: OSError | None = None

    def write(self, data: bytes | memoryview) -> int:
        try:
            return self.raw.write(data)
        except OSError as exc:
            self.error = exc
            raise

    def __getattr__(self, name: str) -> object:
        attribute = getattr(self.raw, name)
        if not callable(attribute):
            return attribute

        def watched(*args: object, **kwargs: object) -> object:
            try:
                return attribute(*args, **kwargs)
            except OSError as exc:
                self.error = exc
                raise

        return watched


def commit_output(temp: Path, final: Path, *, overwrite: bool, kind: str | None = None) -> None:
    """Move ``temp`` to ``final``; an existing ``final`` is replaced only with ``overwrite``, and only
    when bimscan may replace it (``replace_path``; ``kind`` as in ``check_output_path``)."""
    if (final.exists() or final.is_symlink()) and not overwrite:
        raise OutputError(f"{final} appeared while writing it; pass --overwrite to replace it or choose another path")
    replace_path(temp, final, kind=kind)


def commit_staged(
    staged: list[tuple[Path, Path, str | None]], path: Path, *, n_points: int, overwrite: bool, checksum: bool,
    clock: StageClock | None = None,
) -> WrittenCloud:
    """Move every staged (temporary, final, folder kind) output into place, in order, and say what
    was written (``path``: the main output; with ``checksum`` the SHA-256 of every file, read
    before the renames). The caller removes the temporaries when this raises."""
    files: list[Path] = []
    sha256: dict[str, str] = {}
    n_bytes = 0
    clock = clock or StageClock()
    for temp, final, _ in staged:
        members = sorted(p for p in temp.rglob("*") if p.is_file()) if temp.is_dir() else [temp]
        for member in members:
            name = (final / member.relative_to(temp)) if temp.is_dir() else final
            files.append(name)
            n_bytes += member.stat().st_size
            if checksum:
                with clock.step("checksum"):
                    sha256[name.relative_to(path.parent).as_posix()] = file_sha256(member)
    for temp, final, kind in staged:
        commit_output(temp, final, overwrite=overwrite, kind=kind)
    files.sort(key=lambda f: not (f == path or path in f.parents))  # main output first
    return WrittenCloud(path=path, n_points=n_points, files=tuple(files), sha256=sha256, n_bytes=n_bytes)


class StagedOutput:
    """The temporary files of one output that is not written chunk by chunk through a
    ``StreamingCloudWriter`` (a labelled copy of a cloud), moved into place together by
    ``commit`` (see ``commit_staged``). Use it as a context manager: an exception inside removes
    every temporary, and an OSError of writing becomes a one-line OutputError.

    ``extra``: further outputs beside ``path`` (a PLY's sidecar); ``kind``: the
    ``FOLDER_OUTPUTS`` kind of a folder output (checked as ``check_output_path`` does).
    """

    def __init__(self, path: Path, *, overwrite: bool, checksum: bool = True, extra: tuple[Path, ...] = (),
                 kind: str | None = None) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        self.checksum = checksum
        self.clock = StageClock()
        self._staged: list[tuple[Path, Path, str | None]] = []
        self._handles: list[WatchedFile] = []
        self._done = False
        check_output_path(self.path, overwrite=overwrite, extra=extra, kind=kind)

    def file(self, final: Path) -> Path:
        """Stage ``final``: its (created, empty) temporary file, moved into place at commit."""
        temp = temp_path(final)
        os.close(os.open(temp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        self._staged.append((temp, final, None))
        return temp

    def folder(self, final: Path, *, kind: str) -> Path:
        """Stage the folder ``final`` (of ``FOLDER_OUTPUTS[kind]``): its temporary folder."""
        temp = temp_path(final)
        temp.mkdir()
        self._staged.append((temp, final, kind))
        return temp

    def open(self, path: Path) -> WatchedFile:
        """``path`` (a staged file, or a file inside a staged folder) opened for binary writing."""
        handle = WatchedFile(path.open("w+b"))
        self._handles.append(handle)
        return handle

    def commit(self, *, n_points: int) -> WrittenCloud:
        """Close the files and move every staged output into place."""
        for handle in self._handles:
            handle.close()
        result = commit_staged(self._staged, self.path, n_points=n_points, overwrite=self.overwrite,
                               checksum=self.checksum, clock=self.clock)
        self._done = True
        return result

    def abort(self) -> None:
        """Remove every temporary; a no-op after ``commit``."""
        if self._done:
            return
        self._done = True
        for handle in self._handles:
            try:
                handle.close()
            except (OSError, ValueError):
                pass  # the output is being discarded; a failing close changes nothing
        for temp, _, _ in self._staged:
            try:
                remove_path(temp)
            except OSError:
                pass  # best effort: an undeletable temporary must not hide the original error

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            return
        self.abort()
        # an OSError of the output's files (recorded by their handles, or a full disk) is the output's
        cause = next((h.error for h in self._handles if h.error is not None), None)
        if cause is None and isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            cause = exc
        if cause is not None and not isinstance(exc, OutputError):
            raise output_error(cause, self.path) from exc


class StreamingCloudWriter:
    """Base of the format writers: staging, column checks, error handling, context manager.

    Subclasses implement ``_begin(columns)`` (open temporary outputs once the first chunk shows
    which columns the cloud has), ``_append(chunk)`` (at most ``BLOCK_POINTS`` rows at a time),
    ``_finish()`` (complete headers and sidecars) and may extend ``_release()`` (drop buffers;
    must be idempotent). They stage outputs with ``_open_file``/``_stage_dir`` + ``_watch``.
    ``FOLDER_KIND``: the ``bimscan.files.FOLDER_OUTPUTS`` kind of a writer whose output is a folder.
    """

    FOLDER_KIND: str | None = None

    def __init__(self, path: Path, *, header: CloudHeader, overwrite: bool = False, checksum: bool = True,
                 fields: tuple[ExtraField, ...] = ()) -> None:
        self.path = Path(path)
        self.header = header
        self.fields = tuple(fields)  # per-point fields beyond the columns, given with every chunk (see write)
        self.overwrite = overwrite
        self.checksum = checksum
        self.columns: tuple[str, ...] | None = None
        self.n_points = 0
        self._staged: list[tuple[Path, Path, str | None]] = []  # (temporary, final, folder kind), in commit order
        self._state = "open"
        self._result: WrittenCloud | None = None
        self._handles: list[WatchedFile] = []
        self.clock = StageClock()  # the format's own steps (LAS/LAZ: "encode", "compress" or "store"), "checksum"
        check_output_path(self.path, overwrite=overwrite, extra=self._outputs()[1:], kind=self.FOLDER_KIND)
        dump_json(header_to_document(header, columns=(), n_points=0))  # fail now, not after the points

    def _outputs(self) -> tuple[Path, ...]:
        """Every path this writer creates, the main output first (PLY adds its sidecar)."""
        return (self.path,)

    # -- staging helpers for subclasses -------------------------------------------------------
    def _stage_file(self, final: Path) -> Path:
        temp = temp_path(final)
        os.close(os.open(temp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        self._staged.append((temp, final, None))
        return temp

    def _open_file(self, final: Path) -> WatchedFile:
        """Stage ``final`` and open its temporary file for binary writing (and seeking)."""
        return self._watch(self._stage_file(final))

    def _watch(self, path: Path) -> WatchedFile:
        """Open ``path`` (inside a staged output) for binary writing; its errors are tracked."""
        handle = WatchedFile(path.open("w+b"))
        self._handles.append(handle)
        return handle

    def _failure(self, exc: Exception) -> Exception:
        """Abort and return the exception to raise for ``exc`` (an OutputError for I/O errors)."""
        self.abort()
        cause = exc if isinstance(exc, OSError) else next((h.error for h in self._handles if h.error), None)
        return output_error(cause, self.path) if cause is not None else exc

    def _stage_dir(self, final: Path) -> Path:
        temp = temp_path(final)
        temp.mkdir()
        self._staged.append((temp, final, self.FOLDER_KIND))
        return temp

    # -- hooks ----------------------------------------------------------------------------------
    def _begin(self, columns: tuple[str, ...]) -> None:
        raise NotImplementedError

    def _append(self, chunk: PointCloud, values: np.ndarray | None) -> None:
        """Encode ``chunk`` (and ``values`` of ``self.fields``, None without fields)."""
        raise NotImplementedError

    def _finish(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        """Close every file opened through ``_watch``; subclasses also drop their buffers."""
        for handle in self._handles:
            handle.close()

    # -- public API ----------------------------------------------------------------------------
    def write(self, chunk: PointCloud, values: np.ndarray | None = None) -> None:
        """Append a chunk; every chunk must carry the same columns as the first. ``values``: the
        chunk's records of ``self.fields`` (``field_values_dtype``), required when it has fields."""
        if self._state != "open":
            raise OutputError(f"the writer of {self.path} is already {self._state}; open a new writer")
        columns = present_columns(chunk)
        try:
            if self.columns is None:
                self.columns = columns
                self._begin(columns)
            elif columns != self.columns:
                raise OutputError(
                    f"a chunk for {self.path} carries columns {', '.join(columns)} but earlier chunks "
                    f"carried {', '.join(self.columns)}; pass the same columns in every chunk"
                )
            if bool(self.fields) != (values is not None) or (values is not None and len(values) != len(chunk)):
                raise ValueError(f"{self.path}: a chunk of {len(chunk)} points needs {len(chunk)} records of the "
                                 f"writer's {len(self.fields)} extra fields, got "
                                 f"{'none' if values is None else len(values)}")
            for start in range(0, len(chunk), BLOCK_POINTS):
                stop = min(start + BLOCK_POINTS, len(chunk))
                whole = (start, stop) == (0, len(chunk))
                self._append(chunk if whole else chunk.take(slice(start, stop)),
                             None if values is None else values[start:stop])
                self.n_points += stop - start
        except Exception as exc:
            error = self._failure(exc)
            if error is exc:
                raise
            raise error from exc

    def close(self) -> WrittenCloud:
        """Finish the output and move it into place; returns what was written."""
        if self._result is not None:
            return self._result
        if self._state != "open":
            raise OutputError(f"the writer of {self.path} was {self._state}; nothing to close")
        try:
            if self.columns is None:  # no chunk at all: an empty cloud with xyz only
                self.columns = ("xyz",)
                self._begin(self.columns)
            self._finish()
            self._release()
            self._result = commit_staged(self._staged, self.path, n_points=self.n_points, overwrite=self.overwrite,
                                         checksum=self.checksum, clock=self.clock)
        except Exception as exc:
            error = self._failure(exc)
            if error is exc:
                raise
            raise error from exc
        self._state = "closed"
        return self._result

    def abort(self) -> None:
        """Drop the temporary output; a no-op after a successful close."""
        if self._state == "closed":
            return
        self._state = "aborted"
        try:
            self._release()
        except (OSError, ValueError):
            pass  # the output is being discarded; a failing close changes nothing
        for temp, _, _ in self._staged:
            try:
                remove_path(temp)
            except OSError:
                pass  # best effort: an undeletable temporary must not hide the original error

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            self.abort()
        elif self._state == "open":
            self.close()

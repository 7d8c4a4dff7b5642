"""The geometry runs in a worker process, so a native crash or hang cannot take the command down.

IfcOpenShell's geometry kernel (OpenCascade) can crash the process (a segmentation fault on
a damaged file) or loop forever on one element. ``run_parse`` sends the parse
(``bimscan.ifc.parse.parse_model``) to a worker process and watches it:

- the worker reports its progress (phase, elements finished, the element it tries alone);
- a worker that dies (a signal, an abort) or stays silent for longer than the time limit per
  element (``element_timeout_s``, default ``ELEMENT_TIMEOUT_S`` or ``$BIMSCAN_ELEMENT_TIMEOUT_S``)
  is killed; the elements of that run it had not finished are then tried one at a time in a
  fresh worker, so the culprit is named, reported as failed (cause ``crash`` or ``timeout``) and
  skipped, and the rest of the model still loads;
- a crash or hang outside the geometry (reading the file: limit ``MIN_WHOLE_FILE_S`` or the time
  limit per element, whichever is longer, plus ``READ_S_PER_MB`` per MB) is an ``IfcError``
  naming the phase.

The worker is a plain ``python -c`` process (no re-import of the caller's ``__main__``) that
ignores SIGINT (Ctrl-C reaches the whole process group; the parent decides) and dies with its
parent. One idle worker is kept for the next load, so a process that loads many models pays the
start-up (about 0.3 s of imports) once; commands start it first thing (``prestart_worker``), so
that it loads IfcOpenShell while they load their own libraries.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from typing import Any

from bimscan.errors import BimscanError, ConfigError, IfcError
from bimscan.processes import die_with_parent
from bimscan.progress import progress_bar
from bimscan.ifc.report import FailedElement
from bimscan.types import ParsedModel

ELEMENT_TIMEOUT_S = 120.0  # longest a single element may take (OpenCascade booleans on big walls take seconds)
READ_S_PER_MB = 2.0  # extra allowance for the phases that read the whole file (IfcOpenShell reads ~50 MB/s)
MIN_WHOLE_FILE_S = 60.0  # at least this for starting the worker (imports) and each whole-file phase
MAX_CULPRITS = 32  # elements that crash or hang before a model is given up as a whole
_ELEMENT_PHASES = ("elements", "spaces")
_PHASE_WORDS = {"reading": "reading the file", "checking": "checking the model", "assembling": "assembling the mesh",
                "elements": "triangulating elements", "spaces": "triangulating spaces", "starting": "starting"}
_BOOT = ("import json, sys; sys.path[:0] = json.loads(sys.argv[1]); "
         "from bimscan.ifc.watchdog import serve; serve(int(sys.argv[2]))")


def element_timeout(value: float | None = None) -> float:
    """The time limit per element in seconds: ``value``, else ``$BIMSCAN_ELEMENT_TIMEOUT_S``, else the default."""
    if value is None:
        text = os.environ.get("BIMSCAN_ELEMENT_TIMEOUT_S", "").strip()
        if not text:
            return ELEMENT_TIMEOUT_S
        try:
            value = float(text)
        except ValueError as exc:
            raise ConfigError(f"BIMSCAN_ELEMENT_TIMEOUT_S={text!r} is not a number of seconds; fix or unset it") from exc
    if not (value > 0 and value < float("inf")):
        raise ConfigError(f"the time limit per element must be a positive number of seconds, got {value!r}")
    return float(value)


def run_parse(request: Any, *, timeout_s: float, file_bytes: int, progress: bool = True) -> ParsedModel:
    """Parse ``request`` (a ``ParseRequest``) in a worker process under the watchdog (see the module)."""
    skip: dict[int, FailedElement] = dict(request.skip)
    isolate: set[int] = set(request.isolate)
    read_limit = max(timeout_s, MIN_WHOLE_FILE_S) + READ_S_PER_MB * file_bytes / 1e6
    while True:
        attempt = replace(request, isolate=frozenset(isolate), skip=dict(skip))
        worker = _take_worker()
        try:
            outcome = worker.run(attempt, element_limit=timeout_s, read_limit=read_limit, progress=progress)
        except BaseException:
            worker.kill()  # Ctrl-C, SIGTERM, a bug: never leave the worker behind
            raise
        if outcome.kind in ("result", "error", "internal"):
            _release_worker(worker)
            if outcome.kind == "result":
                return outcome.payload
            if outcome.kind == "error":
                raise outcome.payload
            raise IfcError(f"{request.name}: internal error while {_PHASE_WORDS.get(outcome.phase, outcome.phase)} "
                           f"({outcome.payload}); please report it with the file")
        worker.kill()
        what = outcome.describe(timeout_s if outcome.phase in _ELEMENT_PHASES else read_limit)
        if outcome.phase not in _ELEMENT_PHASES:
            raise IfcError(f"{request.name}: IfcOpenShell {what} while {_PHASE_WORDS.get(outcome.phase, outcome.phase)}; "
                           "the file cannot be read safely: check it in an IFC viewer or export it again")
        if outcome.in_flight is not None:
            step_id, global_id, ifc_class = outcome.in_flight
            cause = "timeout" if outcome.kind == "stalled" else "crash"
            skip[step_id] = FailedElement(global_id=global_id, ifc_class=ifc_class, step_id=step_id,
                                          reason=f"the geometry kernel {what} on it; skipped", cause=cause)
            if len(skip) > MAX_CULPRITS:
                raise IfcError(f"{request.name}: more than {MAX_CULPRITS} elements crash or hang the geometry kernel "
                               f"(the last: {ifc_class} #{step_id}); check the model in an IFC viewer or export it again")
        else:
            suspects = outcome.pending - outcome.done - isolate - skip.keys()
            if not suspects:
                raise IfcError(f"{request.name}: IfcOpenShell {what} while {_PHASE_WORDS[outcome.phase]}, outside any "
                               "element; check the model in an IFC viewer or export it again")
            isolate |= suspects


@dataclass
class _Outcome:
    """How a run ended: result / error / internal (payload), or died / stalled (with progress)."""

    kind: str
    payload: Any = None
    phase: str = "starting"
    pending: set[int] = field(default_factory=set)
    done: set[int] = field(default_factory=set)
    in_flight: tuple[int, str, str] | None = None
    signal_name: str = ""

    def describe(self, limit_s: float) -> str:
        if self.kind == "stalled":
            return f"stopped responding (no progress in {limit_s:g} s)"
        return f"crashed ({self.signal_name})" if self.signal_name else "crashed"


class _Worker:
    """One worker process and the socket to it."""

    def __init__(self) -> None:
        parent_end, child_end = socket.socketpair()
        try:
            self.process = subprocess.Popen(
                [sys.executable, "-c", _BOOT, json.dumps(sys.path), str(child_end.fileno())],
                pass_fds=(child_end.fileno(),), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            )
        except OSError as exc:
            parent_end.close()
            raise IfcError(f"cannot start the IFC geometry worker ({exc.strerror or exc}); check free memory "
                           "and process limits") from exc
        finally:
            child_end.close()
        self.connection = Connection(parent_end.detach())

    def alive(self) -> bool:
        return self.process.poll() is None

    def run(self, request: Any, *, element_limit: float, read_limit: float, progress: bool) -> _Outcome:
        outcome = _Outcome(kind="died")
        try:
            self.connection.send(request)
        except OSError:
            return self._died(outcome)
        last = time.monotonic()
        with contextlib.ExitStack() as bars:
            bar = None
            while True:
                limit = element_limit if outcome.phase in _ELEMENT_PHASES else read_limit
                wait = max(0.0, last + limit - time.monotonic())
                if not self.connection.poll(min(wait, 1.0)):
                    if not self.alive():
                        return self._died(outcome)
                    if time.monotonic() - last > limit:
                        outcome.kind = "stalled"
                        return outcome
                    continue
                try:
                    kind, payload = self.connection.recv()
                except (EOFError, OSError):
                    return self._died(outcome)
                last = time.monotonic()
                if kind in ("result", "error", "internal"):
                    outcome.kind, outcome.payload = kind, payload
                    return outcome
                if kind == "phase":
                    outcome.phase, outcome.in_flight = payload, None
                    bars.close()
                    bar = None
                elif kind == "pending":
                    outcome.pending, outcome.done = set(payload), set()
                    bar = bars.enter_context(progress_bar(total=len(payload), desc=_PHASE_WORDS[outcome.phase],
                                                          unit="it", enabled=progress))
                elif kind == "begin":
                    outcome.in_flight = payload
                elif kind == "done":
                    outcome.done.update(payload)
                    if outcome.in_flight is not None and outcome.in_flight[0] in payload:
                        outcome.in_flight = None
                    if bar is not None:
                        bar.update(len(payload))

    def _died(self, outcome: _Outcome) -> _Outcome:
        try:
            code = self.process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            code = None
        if code is not None and code < 0:
            try:
                outcome.signal_name = signal.Signals(-code).name
            except ValueError:
                outcome.signal_name = f"signal {-code}"
        elif code:
            outcome.signal_name = f"exit status {code}"
        outcome.kind = "died"
        return outcome

    def kill(self) -> None:
        with contextlib.suppress(OSError):
            self.connection.close()
        if self.alive():
            with contextlib.suppress(OSError):
                self.process.kill()
        with contextlib.suppress(subprocess.TimeoutExpired, OSError):
            self.process.wait(timeout=5)


_IDLE: list[_Worker] = []
_LOCK = threading.Lock()


def _take_worker() -> _Worker:
    with _LOCK:
        while _IDLE:
            worker = _IDLE.pop()
            if worker.alive():
                return worker
            worker.kill()
    return _Worker()


def _release_worker(worker: _Worker) -> None:
    with _LOCK:
        if not _IDLE and worker.alive():
            _IDLE.append(worker)
            return
    worker.kill()


def prestart_worker() -> None:
    """Start a worker now, so that its start-up (imports) overlaps the caller's own; it waits idle
    for the next parse (a command calls this first when it will parse a model)."""
    with _LOCK:
        if any(worker.alive() for worker in _IDLE):
            return
    try:
        worker = _Worker()
    except IfcError:
        return  # the parse will say why, if it comes to that
    _release_worker(worker)


@atexit.register
def shutdown_workers() -> None:
    """End the idle workers (they also end by themselves when this process goes). A Ctrl-C that lands
    here, while the process ends, is let go: the workers die with their parent, and the user's line
    ('error: interrupted; ...') was printed already."""
    try:
        with _LOCK:
            workers, _IDLE[:] = list(_IDLE), []
        for worker in workers:
            worker.kill()
    except KeyboardInterrupt:
        pass


# -- the worker's side --------------------------------------------------------------------------------

def serve(fd: int) -> None:
    """The worker's loop: parse each request received on ``fd``, report progress and the outcome."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.simplefilter("ignore")  # NumPy noise from degenerate placements; what matters is reported
    die_with_parent()
    connection = Connection(fd)
    # Everything the parse needs, imported once per worker (while it waits, when started early).
    import ifcopenshell.geom  # noqa: F401
    import ifcopenshell.util.element  # noqa: F401
    import ifcopenshell.util.placement  # noqa: F401
    import ifcopenshell.util.unit  # noqa: F401

    from bimscan.ifc.parse import parse_model

    def emit(kind: str, payload: Any) -> None:
        connection.send((kind, payload))

    while True:
        try:
            request = connection.recv()
        except (EOFError, OSError):
            return
        try:
            try:
                model = parse_model(request, emit)
            except BimscanError as exc:
                emit("error", exc)
            except Exception as exc:  # a bug or an IfcOpenShell error nobody expected: one line upstream
                emit("internal", f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}")
                if os.environ.get("BIMSCAN_DEBUG"):
                    traceback.print_exc()
            else:
                emit("result", model)
        except (OSError, EOFError):
            return  # the parent is gone


__all__ = ["ELEMENT_TIMEOUT_S", "element_timeout", "prestart_worker", "run_parse", "serve", "shutdown_workers"]

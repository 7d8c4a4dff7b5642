"""Processes and signals: child processes that end with their parent, signals held while foreign
code runs, and a resource tracker that cleans up without a word.

Workers (the IFC geometry worker, dataset build workers, training data loader workers) must not
outlive the command that started them, even when it is killed outright (``kill -9``, an out-of-
memory kill), where no clean-up of its own runs.

Ctrl-C and SIGTERM stop a command by an exception its Python signal handler raises (see
``bimscan.cli.main``). A handler runs at the next Python instruction of the main thread, which,
while a library in Rust or C++ runs, is often a Python callback of that library (lazrs writes
a LAZ file through the file object's ``write``); lazrs turns the exception into its own error
("IoError: Failed to call write") and the stop would read as a failed write. ``signals_held``
keeps the handlers from running inside such calls: a signal that arrives meanwhile is handled as
soon as the call returns.

The ``multiprocessing`` resource tracker removes the named semaphores and shared memory of a
command killed with ``kill -9`` (the process pools' queues and locks), and then warns about them
on stderr; ``quiet_resource_tracker`` keeps the clean-up and drops the raw warning.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any


def die_with_parent(*_: object) -> None:
    """Ask Linux to kill this process when its parent dies (``PR_SET_PDEATHSIG``); best effort on
    other systems. Takes and ignores arguments, so it serves as a worker initialiser too."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the parent died before prctl took effect
        os._exit(1)


HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def signals_held() -> Iterator[None]:
    """Run the block with the Python handlers of SIGINT and SIGTERM held back: a signal that arrives
    inside is handed to its handler when the block ends (so its exception is raised there, not
    inside a library's callback). Outside the main thread, or for signals without a Python
    handler, nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived: list[int] = []

    def note(number: int, frame: FrameType | None) -> None:
        del frame
        arrived.append(number)

    handlers: dict[int, Any] = {}
    try:
        for number in HELD_SIGNALS:
            handler = signal.getsignal(number)
            if callable(handler):
                handlers[number] = handler
                signal.signal(number, note)
        yield
    finally:
        for number, handler in handlers.items():
            signal.signal(number, handler)
        for number in dict.fromkeys(arrived):  # each signal once, in the order they came
            handlers[number](number, None)


# A filter the resource tracker gets on its command line (it is started with this interpreter's
# warning options): its "leaked semaphore/shared_memory objects" warnings after a kill -9.
_TRACKER_FILTER = "ignore:resource_tracker:UserWarning:multiprocessing.resource_tracker"


def quiet_resource_tracker() -> None:
    """Have the resource tracker, when this process starts it, ignore its own warnings: after a
    ``kill -9`` it still removes the semaphores and shared memory the killed command held, without
    the raw ``UserWarning`` on stderr. Takes effect when called before the first spawned process,
    process pool or queue (the tracker starts with the first; the CLI calls it first thing)."""
    if _TRACKER_FILTER not in sys.warnoptions:
        sys.warnoptions.append(_TRACKER_FILTER)

"""Child processes that end with their parent.

Workers (the IFC geometry worker, dataset build workers, training data loader workers) must not
outlive the command that started them, even when it is killed outright (``kill -9``, an out-of-
memory kill), where no clean-up of its own runs.
"""

from __future__ import annotations

import os
import signal
import sys


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

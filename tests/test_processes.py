"""Workers end with the command that started them, even when it is killed outright.

The test waits on events, not on time: the worker says when it has asked for its signal (a line on
the pipe), and its end is awaited on a process file descriptor (``pidfd_open``), so a busy machine
makes the test slower, never wrong (a fixed sleep was the worker's time to start)."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys

import pytest

PARENT = """
import subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c",
    "from bimscan.processes import die_with_parent; die_with_parent(); print('armed', flush=True); "
    "import time; time.sleep(120)"])
print(child.pid, flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as handle:  # a zombie waits for its reaper, but runs no more
        return handle.read().split(")")[-1].split()[0] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux") or not hasattr(os, "pidfd_open"),
                    reason="PR_SET_PDEATHSIG and pidfd_open are Linux's")
def test_a_worker_dies_when_its_parent_is_killed_outright():
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    try:
        lines = {parent.stdout.readline().strip() for _ in range(2)}  # the parent's line and the worker's
        assert "armed" in lines, lines  # the worker has asked to die with its parent
        child = int((lines - {"armed"}).pop())
        worker = os.pidfd_open(child)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        parent.stdout.close()
    try:
        readable, _, _ = select.select([worker], [], [], 60.0)  # readable once the worker has ended
    finally:
        os.close(worker)
    assert readable and not _alive(child)

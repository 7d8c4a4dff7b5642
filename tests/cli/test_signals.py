"""Stopping a command: SIGTERM like Ctrl-C (clean-up, one line, exit 143), Ctrl-C while libraries
load or while lazrs compresses a mobile scan, library warnings as one line each (issues 13, 41)."""

from __future__ import annotations

import logging
import os
import random
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from bimscan.cli.main import main
from bimscan.errors import IfcError

COMMAND = [sys.executable, "-c", "import sys; from bimscan.cli.main import main; sys.exit(main())"]


def _start(args: list[str], cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([*COMMAND, *args], cwd=cwd, env={**os.environ, "BIMSCAN_PROGRESS": "0"},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(condition, process: subprocess.Popen[str], limit_s: float = 240.0) -> None:
    start = time.monotonic()
    while not condition():
        assert process.poll() is None, process.communicate()
        assert time.monotonic() - start < limit_s, "the condition never came"
        time.sleep(0.01)


@pytest.mark.slow
def test_sigterm_during_a_scan_removes_the_temporary_output_and_exits_143(box_room_ifc, tmp_path):
    process = _start(["scan", str(box_room_ifc), "out.laz", "--preset", "exp1", "--head-speed", "1"], tmp_path)
    _wait_for(lambda: any(p.name.startswith(".out.laz.") for p in tmp_path.iterdir()), process)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 143, err
    assert err.splitlines()[-1].startswith("error: terminated") and "Traceback" not in err
    assert "resume" not in err  # a scan does not resume: it promises nothing of the kind
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no output, no temporary


@pytest.mark.slow
def test_sigterm_and_ctrl_c_at_random_moments_of_a_mobile_scan_to_laz_say_so_and_leave_nothing(box_room_ifc, tmp_path):
    # A mobile scan spends about half its time in lazrs, whose write callback swallowed the signal's exception
    # ("could not write ...laz (IoError: Failed to call write); check the disk", exit 1, 5 tries in 8)
    moments = random.Random(41)
    finished = 0
    for attempt in range(8):
        number = (signal.SIGTERM, signal.SIGINT)[attempt % 2]
        folder = tmp_path / str(attempt)
        folder.mkdir()
        process = _start(["scan", str(box_room_ifc), "walk.laz", "--platform", "backpack"], folder)
        _wait_for(lambda: any(p.name.startswith(".walk.laz.") for p in folder.iterdir()), process)
        time.sleep(moments.uniform(0.0, 1.0))
        process.send_signal(number)
        if attempt % 4 == 3:  # pressed twice
            time.sleep(moments.uniform(0.0, 0.3))
            process.send_signal(number)
        _, err = process.communicate(timeout=120)
        if process.returncode == 0:  # the scan finished before the signal came: nothing to test this time
            finished += 1
            assert finished <= 2, "the scans finish before the signals: give them more to do"
            continue
        what, status = ("terminated", 143) if number == signal.SIGTERM else ("interrupted", 130)
        # (a second signal that lands after the line, while Python shuts down, ends the process by that signal:
        # the shell shows the same status, 128 + the signal's number)
        assert process.returncode in (status, -number), (attempt, err)
        assert err.splitlines()[-1] == f"error: {what}; no partial output was left behind", (attempt, err)
        assert "Traceback" not in err and "could not write" not in err
        assert list(folder.iterdir()) == []  # no cloud, no trajectory, no temporary


@pytest.mark.slow
def test_ctrl_c_while_open3d_loads_is_one_line(box_room_ifc, tmp_path):
    process = _start(["scan", str(box_room_ifc), "out.laz"], tmp_path)
    maps = Path(f"/proc/{process.pid}/maps")
    if not maps.exists():
        process.kill()
        pytest.skip("needs /proc to see when Open3D loads")
    _wait_for(lambda: "open3d" in maps.read_text(), process)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    assert "Traceback" not in err and err.splitlines()[-1].startswith("error: interrupted")
    assert [line for line in err.splitlines() if not line.startswith("warning: ")] == [err.splitlines()[-1]]
    assert not list(tmp_path.iterdir())


def test_library_warnings_and_log_records_print_as_warning_lines(monkeypatch, capsys):
    def noisy_load(*args, **kwargs):
        warnings.warn("a library\nwarning", UserWarning, stacklevel=1)
        logging.getLogger("laspy").warning("a library log record")
        raise IfcError("model.ifc: stop here")

    monkeypatch.setattr("bimscan.pipeline.load_scene", noisy_load)
    monkeypatch.setattr(logging.getLogger(), "handlers", [])  # as in a console run (pytest adds its own)
    assert main(["info", "model.ifc"]) == 1
    assert capsys.readouterr().err.splitlines() == [
        "warning: a library warning", "warning: a library log record", "error: model.ifc: stop here"]


@pytest.mark.parametrize("command, promise", [("build", "run the same command to resume"),
                                              ("train", "add --resume"), ("predict", "no partial output")])
def test_a_stopped_command_says_what_it_keeps_as_that_command_does(command, promise, monkeypatch, capsys):
    import bimscan.cli.main as cli_main

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_main.cli, "invoke", stop)
    assert main([command, "x"]) == 130
    assert promise in capsys.readouterr().err.splitlines()[-1]

"""Stopping a command: SIGTERM like Ctrl-C (clean-up, one line, exit 143), Ctrl-C while the command
line or libraries load or while lazrs compresses a mobile scan, library warnings as one line each
(issues 13, 41, 50)."""

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


# The console script's own code (``from bimscan.cli.main import main; sys.exit(main())``), with the
# signal sent by this process to itself the moment ``STOP_AT`` starts to load: as a Ctrl-C that lands
# there, at a point the test chooses rather than after a sleep that a busy machine stretches.
SIGNAL_ON_IMPORT = """
import os, sys

class SignalOnImport:
    def find_spec(self, name, path=None, target=None):
        if name == os.environ["STOP_AT"]:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), int(os.environ["STOP_WITH"]))
        return None

sys.meta_path.insert(0, SignalOnImport())
from bimscan.cli.main import main
sys.exit(main())
"""


@pytest.mark.parametrize("command, number, module", [
    # while the commands load (NumPy, SciPy, Numba: a second or more on a busy machine), before main() ran:
    # a traceback (train, plan) or a silent exit (predict, scan), issue 50
    (["train", "run.toml"], signal.SIGINT, "bimscan.cli.dataset_commands"),
    (["plan", "model.ifc", "plan"], signal.SIGTERM, "bimscan.cli.dataset_commands"),
    (["predict", "model.pt", "cloud.laz", "out.laz"], signal.SIGTERM, "scipy"),
    (["scan", "model.ifc", "out.laz"], signal.SIGINT, "numba"),
    (["train", "run.toml"], signal.SIGTERM, "torch"),  # inside the command, as it loads its libraries
])
def test_a_stop_while_a_command_starts_is_one_line_and_the_signal_s_status(command, number, module, tmp_path):
    process = subprocess.run([sys.executable, "-c", SIGNAL_ON_IMPORT, *command], cwd=tmp_path, capture_output=True,
                             text=True, timeout=120, env={**os.environ, "BIMSCAN_PROGRESS": "0", "STOP_AT": module,
                                                          "STOP_WITH": str(int(number))})
    what, status = ("terminated", 143) if number == signal.SIGTERM else ("interrupted", 130)
    assert process.returncode == status, process.stderr
    line = process.stderr.splitlines()[-1] if process.stderr else ""
    assert line.startswith(f"error: {what}; ") and "Traceback" not in process.stderr
    if module != "torch":  # stopped before the command began: it left nothing, whatever it would keep later
        assert process.stderr.splitlines() == [f"error: {what}; no partial output was left behind"]
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
    import bimscan.cli.commands as cli_commands

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_commands.cli, "invoke", stop)
    assert main([command, "x"]) == 130
    assert promise in capsys.readouterr().err.splitlines()[-1]

"""Shared file plumbing: stale temporaries of an output are swept, live ones kept; work folders carry
the writer's process id; input kinds named."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from bimscan.errors import InputFileError, OutputError
from bimscan.files import (
    check_input_file,
    path_kind,
    remove_dead_temps,
    remove_stale_temps,
    temp_path,
    work_folder,
    write_atomic,
)


@pytest.fixture(scope="module")
def dead_pid() -> int:
    """The id of a process that has ended."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_staging_an_output_sweeps_temporaries_of_dead_writers_and_keeps_live_ones(tmp_path, dead_pid):
    out = tmp_path / "o.laz"
    dead = tmp_path / f".o.laz.{dead_pid}-0123456789ab.tmp"
    old_style = tmp_path / ".o.laz.0123456789ab.tmp"  # written before temporaries carried a process id
    live = tmp_path / f".o.laz.{os.getppid()}-0123456789ab.tmp"  # our parent is alive
    sidecar = tmp_path / f".o.laz.json.{dead_pid}-0123456789ab.tmp"  # another output's temporary
    folder = tmp_path / f".o.laz.{dead_pid}-ba9876543210.tmp"
    for path in (dead, old_style, live, sidecar):
        path.write_bytes(b"x" * 100)
    folder.mkdir()
    (folder / "coord.npy").write_bytes(b"x")
    staged = temp_path(out)
    assert staged.name.startswith(f".o.laz.{os.getpid()}-") and staged.name.endswith(".tmp")
    assert not dead.exists() and not old_style.exists() and not folder.exists()
    assert live.exists() and sidecar.exists()


def test_an_atomic_write_leaves_no_temporary_and_sweeps_a_killed_run(tmp_path, dead_pid):
    out = tmp_path / "unit.json"
    stale = tmp_path / f".unit.json.{dead_pid}-aaaaaaaaaaaa.tmp"
    stale.write_bytes(b"{half")
    write_atomic(out, b"{}")
    assert out.read_bytes() == b"{}" and sorted(p.name for p in tmp_path.iterdir()) == ["unit.json"]
    assert remove_stale_temps(out) == 0


def test_input_paths_are_named_for_what_they_are(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    broken = tmp_path / "broken"
    broken.symlink_to(tmp_path / "nowhere")
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(tmp_path / "sock"))
    try:
        assert path_kind(fifo) == "a FIFO (named pipe)"
        assert path_kind(loop) == "a symbolic link loop"
        assert path_kind(broken) == "a broken symbolic link"
        assert path_kind(tmp_path / "sock") == "a socket"
        assert path_kind("/dev/null") == "a character device"
        assert path_kind(tmp_path) == "a folder"
        assert path_kind(tmp_path / "missing") == "no such file"
    finally:
        server.close()
    (tmp_path / "file").write_text("x")
    assert path_kind(tmp_path / "file") is None
    with pytest.raises(InputFileError, match="is a FIFO \\(named pipe\\), not a TOML file"):
        check_input_file(fifo, what="a TOML file")
    assert check_input_file(tmp_path, what="a cloud", folders=True) == Path(tmp_path)


def test_a_work_folder_carries_the_writers_pid_is_removed_after_and_sweeps_a_killed_runs(tmp_path, dead_pid):
    out = tmp_path / "labelled.laz"
    killed = tmp_path / f".labelled.laz.{dead_pid}-0123456789ab.tmp"  # a predict killed with kill -9
    (killed / "stripes").mkdir(parents=True)
    (killed / "stripes" / "0.bin").write_bytes(b"x" * 64)
    live = tmp_path / f".labelled.laz.{os.getppid()}-0123456789ab.tmp"  # another run, still going
    live.mkdir()
    with work_folder(out) as folder:
        assert folder.is_dir() and folder.name.startswith(f".labelled.laz.{os.getpid()}-")
        (folder / "labels.u1").write_bytes(b"\x00")
        assert not killed.exists() and live.is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == [live.name]


def test_dead_writers_temporaries_are_swept_from_a_folder_whatever_their_output(tmp_path, dead_pid):
    dead = [tmp_path / f".a__b.{dead_pid}-0123456789ab.tmp", tmp_path / f".scan.v2.laz.{dead_pid}-abcdefabcdef.tmp"]
    dead[0].mkdir()
    (dead[0] / "cloud.laz").write_bytes(b"half")
    dead[1].write_bytes(b"half")
    live = tmp_path / f".a__c.{os.getppid()}-0123456789ab.tmp"
    live.mkdir()
    users = [tmp_path / ".hidden.tmp", tmp_path / "notes.0123456789ab.tmp", tmp_path / f".{dead_pid}-0123456789ab.tmp"]
    for path in users:
        path.write_text("mine")
    assert remove_dead_temps(tmp_path) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in [live, *users])


@pytest.mark.parametrize("name", [".", "..", "/"])
def test_a_path_that_names_a_folder_gets_no_temporary_name(name):
    with pytest.raises(OutputError, match="names a folder, not an output inside one"):
        temp_path(name)

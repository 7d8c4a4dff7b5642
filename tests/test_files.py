"""Shared file plumbing: stale temporaries of an output are swept, live ones kept; work folders carry
the writer's process id; input kinds named; output folders are bimscan's or empty, and inside them
only what their record lists is replaced (issue 50)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bimscan.errors import InputFileError, OutputError
from bimscan.files import (
    OUTPUT_RECORD,
    check_input_file,
    check_output_folder,
    claim_output,
    path_kind,
    prepare_output_folder,
    read_output_record,
    remove_dead_temps,
    remove_output,
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


# -- output folders ------------------------------------------------------------------------------

PNG = b"\x89PNG\r\n\x1a\n"
RUN = ("metrics.csv", "curves.png", "last.pt", "tile-cache/")  # what a run of some command writes there


def _snapshot(root: Path) -> dict[str, bytes | None]:
    """Every file (its bytes) and folder (None) under ``root``."""
    found: dict[str, bytes | None] = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(folder, name)
            found[path.relative_to(root).as_posix()] = None if path.is_dir() else path.read_bytes()
    return found


def _run(folder: Path, *, made_by=None) -> None:
    """What a command writing ``RUN`` into ``folder`` does."""
    prepare_output_folder(folder, names=RUN, made_by=made_by)
    write_atomic(folder / "metrics.csv", b"epoch,loss\n1,0.5\n")
    write_atomic(folder / "curves.png", PNG + b"curves")
    claim_output(folder, "tile-cache/")


def test_an_output_folder_is_made_with_a_record_of_what_bimscan_wrote_there(tmp_path):
    run = tmp_path / "runs" / "one"
    _run(run)
    assert read_output_record(run) == {"metrics.csv", "curves.png", "tile-cache/"}
    assert json.loads((run / OUTPUT_RECORD).read_text())["format"] == "bimscan-output-folder"
    (run / "notes.md").write_text("what I tried")  # a user's file beside bimscan's
    _run(run)  # the rerun replaces its own files and leaves the user's alone
    assert (run / "notes.md").read_text() == "what I tried" and "notes.md" not in read_output_record(run)
    empty = tmp_path / "empty"
    empty.mkdir()
    _run(empty)
    assert (empty / "curves.png").read_bytes() == PNG + b"curves"


@pytest.mark.parametrize("names", [["metrics.csv"], ["curves.png", "evaluation.md"], ["tile-cache/", "mine/"]])
def test_a_folder_bimscan_did_not_make_is_refused_before_any_write_and_kept_as_it_was(tmp_path, names):
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in names:
        if name.endswith("/"):
            (mine / name).mkdir()
            (mine / name / "data.bin").write_bytes(b"three years")
        else:
            (mine / name).write_bytes(b"mine: " + name.encode())
    before = _snapshot(tmp_path)
    with pytest.raises(OutputError) as caught:
        _run(mine)
    message = str(caught.value)
    assert message.startswith(f"{mine} is a folder bimscan did not make (it holds ") and "\n" not in message
    assert "new or empty folder" in message
    assert _snapshot(tmp_path) == before


def test_a_users_file_at_a_name_bimscan_writes_in_its_own_folder_is_refused_naming_it(tmp_path):
    run = tmp_path / "run"
    prepare_output_folder(run, names=RUN)
    (run / "curves.png").write_bytes(PNG + b"the user's own")  # put there by hand: the record does not list it
    with pytest.raises(OutputError) as caught:
        check_output_folder(run, names=RUN)
    assert str(caught.value) == (f"{run / 'curves.png'} was not written by bimscan (the record {OUTPUT_RECORD} of the "
                                 "folder does not list it) and bimscan writes that name there; move it away or choose "
                                 "another folder")
    with pytest.raises(OutputError, match="its record .bimscan.json does not list curves.png"):
        write_atomic(run / "curves.png", PNG + b"bimscan's")  # every writer keeps to the record, checked or not
    assert (run / "curves.png").read_bytes() == PNG + b"the user's own"
    with pytest.raises(OutputError, match="was not written by bimscan"):
        remove_output(run / "curves.png")
    assert (run / "curves.png").exists()


def test_a_folder_an_earlier_version_made_is_taken_by_its_marker_with_only_its_own_names(tmp_path):
    old = tmp_path / "old"
    old.mkdir()
    (old / "last.pt").write_bytes(b"checkpoint")
    (old / "metrics.csv").write_text("epoch\n1\n")
    (old / "notes.md").write_text("mine")
    with pytest.raises(OutputError, match="bimscan did not make"):
        check_output_folder(old, names=RUN)  # no marker test: not taken
    _run(old, made_by=lambda folder: (folder / "last.pt").is_file())
    assert read_output_record(old) == {"last.pt", "metrics.csv", "curves.png", "tile-cache/"}
    assert (old / "notes.md").read_text() == "mine"


def test_a_folder_made_inside_an_output_folder_is_recorded_there(tmp_path):
    out = prepare_output_folder(tmp_path / "experiment", names=("variants/",))
    prepare_output_folder(out / "eval")
    claim_output(out, "variants/")
    assert read_output_record(out) == {"eval/", "variants/"} and (out / "variants").is_dir()
    (out / "cache").mkdir()
    with pytest.raises(OutputError, match="cache was not written by bimscan"):
        claim_output(out, "cache/")


def test_a_file_or_link_where_an_output_folder_goes_is_refused(tmp_path):
    (tmp_path / "run").write_text("a file")
    with pytest.raises(OutputError, match="run is a file, not a folder"):
        prepare_output_folder(tmp_path / "run")
    with pytest.raises(OutputError, match="not the folder bimscan made there"):
        out = prepare_output_folder(tmp_path / "out", names=("tile-cache/",))
        claim_output(out, "tile-cache/")
        (out / "tile-cache").rmdir()
        (out / "tile-cache").symlink_to(tmp_path)
        check_output_folder(out, names=("tile-cache/",))


OUTPUT_NAMES = st.sampled_from(["metrics.csv", "curves.png", "report.md", "manifest.json", "data.laz", "cache/"])
USER_NAMES = st.sampled_from(["metrics.csv", "curves.png", "report.md", "manifest.json", "notes.txt", "data.laz",
                              "cache/", OUTPUT_RECORD])
CONTENT = {".png": PNG, ".laz": b"LASF", ".csv": b"a,b\n", ".md": b"# ", ".json": b"{}", ".txt": b""}


def _content(name: str, tail: bytes) -> bytes:
    return next((head for ending, head in CONTENT.items() if name.endswith(ending)), b"") + tail


def _write_as_bimscan(folder: Path, names: list[str], tail: bytes) -> None:
    for name in names:
        if name.endswith("/"):
            claim_output(folder, name)
            write_atomic(folder / name / "part.bin", tail)
        else:
            write_atomic(folder / name, _content(name, tail))


@settings(max_examples=150, deadline=None)
@given(written=st.lists(OUTPUT_NAMES, min_size=1, max_size=4, unique=True),
       before=st.dictionaries(USER_NAMES, st.binary(max_size=8), max_size=3),
       after=st.dictionaries(USER_NAMES, st.binary(max_size=8), max_size=3),
       earlier_version=st.booleans())
def test_a_users_files_in_an_output_folder_are_never_modified_or_removed(written, before, after, earlier_version):
    """Random user files put into a folder before a run and between two runs (a record of their own
    included) are never changed: each run either writes beside them or is refused before writing."""
    with tempfile.TemporaryDirectory() as temp:
        folder = Path(temp) / "out"
        folder.mkdir()
        if earlier_version:  # a folder an older bimscan wrote the outputs into, before records
            for name in written:
                (folder / name.rstrip("/")).mkdir() if name.endswith("/") else (folder / name).write_bytes(
                    _content(name, b"old"))
        made_by = (lambda f: (f / written[0].rstrip("/")).exists()) if earlier_version else None

        def place(files: dict[str, bytes]) -> set[str]:
            placed = set()
            for name, data in files.items():
                path = folder / name.rstrip("/")
                if os.path.lexists(path):
                    continue  # bimscan's already: the user does not write over it here
                if name.endswith("/"):
                    path.mkdir()
                    (path / "mine.bin").write_bytes(data)
                else:
                    path.write_bytes(_content(name, data) + b"user")
                placed.add(name.rstrip("/"))
            return placed

        def users_files(placed: set[str]) -> dict[str, bytes | None]:
            return {k: v for k, v in _snapshot(folder).items() if k.split("/")[0] in placed}

        placed = place(before)
        for run, tail in enumerate((b"first", b"second")):
            kept = users_files(placed)
            try:
                prepare_output_folder(folder, names=written, made_by=made_by)
                _write_as_bimscan(folder, written, tail)
                assert not {n.rstrip("/") for n in written} & placed  # only ever allowed when no name clashes
            except OutputError as exc:
                assert "\n" not in str(exc)
            assert users_files(placed) == kept
            if run == 0:
                placed |= place(after)


def test_an_ifc_model_or_a_picture_bimscan_did_not_write_is_never_replaced_one_it_wrote_is(tmp_path):
    """An IFC's and a PNG's first bytes cannot tell a user's file from bimscan's: the IFC header's
    FILE_NAME authors and the PNG's Software text can."""
    from bimscan.files import check_replaceable, ifc_authors, png_software, record_output, replace_problem

    def ifc(name: str, authors: str) -> Path:
        path = tmp_path / name
        path.write_text("ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('ViewDefinition [CoordinationView]'),'2;1');\n"
                        f"FILE_NAME('m.ifc','2020-01-01T00:00:00',({authors}),('Office (Main)'),'x','y','');\n"
                        "FILE_SCHEMA(('IFC4'));\nENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n")
        return path

    theirs = ifc("theirs.ifc", "'Architect','O''Brien'")
    ours = ifc("ours.ifc", "'Architect','bimscan furnish'")
    assert ifc_authors(theirs) == ("Architect", "O'Brien") and ifc_authors(ours) == ("Architect", "bimscan furnish")
    assert "is an IFC model bimscan did not write" in replace_problem(theirs)
    assert replace_problem(ours) is None

    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    photo, picture = tmp_path / "photo.png", tmp_path / "picture.png"
    Figure(figsize=(1, 1)).savefig(photo, format="png")  # matplotlib's own Software text
    Figure(figsize=(1, 1)).savefig(picture, format="png", metadata={"Software": "bimscan"})
    assert png_software(picture) == "bimscan" and png_software(photo).startswith("Matplotlib")
    assert "is a picture bimscan did not write" in replace_problem(photo)
    assert replace_problem(picture) is None
    with pytest.raises(OutputError, match="bimscan replaces only what it wrote"):
        check_replaceable(photo)

    # in a folder bimscan made, a file its record lists is bimscan's whatever its header says
    folder = prepare_output_folder(tmp_path / "run")
    listed = folder / "curves.png"
    Figure(figsize=(1, 1)).savefig(listed, format="png")
    record_output(listed)
    assert replace_problem(listed) is None

"""What --overwrite may replace: what bimscan wrote there (a cloud file of the format its suffix names,
a NumPy cloud folder with bimscan's meta.json, a mobile scan's trajectory), never anything else:
a user's folder or file, a link, a folder with a stray coord.npy (issue 41)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bimscan.errors import OutputError
from bimscan.files import FILE_SIGNATURES, replace_path, write_atomic
from bimscan.io import check_cloud_output, open_cloud_writer, read_cloud
from bimscan.io.npdir import NPDIR_NAMES
from bimscan.survey.trajectory import Trajectory, read_trajectory, trajectory_csv, write_trajectory
from bimscan.types import CloudHeader, PointCloud

SUFFIXES = {"npy": "", "laz": ".laz", "las": ".las", "ply": ".ply", "e57": ".e57", "trajectory": ".trajectory.csv"}
# what can stand at the output path before the run
EXISTING = ("nothing", "ours", "ours of another format", "user file", "user file with a cloud name's bytes",
            "user folder", "empty folder", "stray coord.npy folder", "foreign meta.json folder",
            "ours plus a user file", "link to a user file", "link to a user folder", "link to ours", "broken link")
NAME = st.text(alphabet="abcdefghij_-0123456789", min_size=1, max_size=6)
ENTRY_NAME = st.text(alphabet="abcdefghij_-.0123456789", min_size=1, max_size=10).filter(lambda n: n not in (".", ".."))
TREE = st.recursive(st.binary(max_size=40), lambda children: st.dictionaries(ENTRY_NAME, children, max_size=3),
                    max_leaves=6)
USER_FOLDER = st.dictionaries(ENTRY_NAME, TREE, min_size=1, max_size=4)


def _cloud(n: int, origin: tuple[float, float, float]) -> PointCloud:
    rng = np.random.default_rng(n)
    return PointCloud(xyz=np.asarray(origin) + rng.uniform(0.0, 5.0, (n, 3)), label=rng.integers(0, 5, n).astype(np.uint8),
                      intensity=rng.integers(0, 60_000, n).astype(np.uint16))


def _trajectory(n: int) -> Trajectory:
    t = np.arange(n, dtype=np.float64)
    zeros = np.zeros(n)
    return Trajectory(t=t, xyz=np.column_stack([t, zeros + 1.0, zeros + 1.5]), roll=zeros, pitch=zeros, yaw=zeros,
                      pass_id=np.zeros(n, dtype=np.int32))


def _write(kind: str, path: Path, header: CloudHeader, n: int, *, overwrite: bool) -> None:
    """Write an output of ``kind`` with ``n`` points (poses) to ``path`` as bimscan does, checks first."""
    if kind == "trajectory":
        if os.path.lexists(path):
            assert overwrite
        write_trajectory(path, _trajectory(n))
        return
    check_cloud_output(path, overwrite=overwrite)
    with open_cloud_writer(path, header=header, overwrite=overwrite) as writer:
        writer.write(_cloud(n, header.origin))


def _count(kind: str, path: Path) -> int:
    return len(read_trajectory(path).t) if kind == "trajectory" else len(read_cloud(path))


def _make_tree(path: Path, tree: dict | bytes) -> None:
    if isinstance(tree, bytes):
        path.write_bytes(tree)
        return
    path.mkdir()
    for name, child in tree.items():
        _make_tree(path / name, child)


def _snapshot(root: Path) -> dict[str, object]:
    """Every entry under ``root`` (links not followed): its kind and bytes, or where it points."""
    found: dict[str, object] = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(folder, name)
            key = path.relative_to(root).as_posix()
            if path.is_symlink():
                found[key] = ("link", os.readlink(path))
            elif path.is_dir():
                found[key] = ("folder",)
            else:
                found[key] = ("file", path.read_bytes())
    return found


def _not_a_signature(kind: str):
    signatures = FILE_SIGNATURES.get(SUFFIXES[kind]) or ()
    return st.binary(max_size=60).filter(lambda data: not any(data.startswith(s) for s in signatures))


@st.composite
def scenarios(draw):
    kind = draw(st.sampled_from(sorted(SUFFIXES)))
    existing = draw(st.sampled_from(EXISTING))
    other = draw(st.sampled_from([k for k in SUFFIXES if k != kind and {k, kind} != {"las", "laz"}]))
    return (kind, draw(NAME) + SUFFIXES[kind], existing, other, draw(USER_FOLDER), draw(_not_a_signature(kind)),
            draw(st.sampled_from(sorted(NPDIR_NAMES))))


def _prepare(root: Path, kind: str, name: str, existing: str, other: str, user_folder: dict, user_bytes: bytes,
             npdir_member: str, header: CloudHeader) -> Path:
    """Put ``existing`` at ``root/out/name`` (link targets go to ``root/elsewhere``); returns the path."""
    out, elsewhere = root / "out", root / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    path = out / name
    if existing in ("ours", "ours plus a user file"):
        _write(kind, path, header, 7, overwrite=False)
        if existing == "ours plus a user file":
            if path.is_dir():
                (path / "notes.txt").write_bytes(user_bytes)
            else:  # a file output: the user's file sits beside it instead, and must stay
                (out / "notes.txt").write_bytes(user_bytes)
    elif existing == "ours of another format":
        _write(other, elsewhere / ("x" + SUFFIXES[other]), header, 7, overwrite=False)
        os.replace(elsewhere / ("x" + SUFFIXES[other]), path)
    elif existing == "user file":
        path.write_bytes(user_bytes)
    elif existing == "user file with a cloud name's bytes":  # e.g. a text file that happens to be called x.laz
        path.write_bytes(b"not a cloud, " + user_bytes)
    elif existing == "user folder":
        _make_tree(path, user_folder)
    elif existing == "empty folder":
        path.mkdir()
    elif existing == "stray coord.npy folder":  # a Pointcept folder of someone else's: no bimscan meta.json
        path.mkdir()
        np.save(path / "coord.npy", np.zeros((3, 3), dtype=np.float32))
        (path / npdir_member).write_bytes(user_bytes)
    elif existing == "foreign meta.json folder":
        path.mkdir()
        np.save(path / "coord.npy", np.zeros((3, 3), dtype=np.float32))
        (path / "meta.json").write_text('{"source": "my own converter"}')
    elif existing == "link to a user file":
        (elsewhere / "mine.bin").write_bytes(user_bytes)
        path.symlink_to(elsewhere / "mine.bin")
    elif existing == "link to a user folder":
        _make_tree(elsewhere / "mine", user_folder)
        path.symlink_to(elsewhere / "mine", target_is_directory=True)
    elif existing == "link to ours":
        _write(kind, elsewhere / name, header, 7, overwrite=False)
        path.symlink_to(elsewhere / name, target_is_directory=kind == "npy")
    elif existing == "broken link":
        path.symlink_to(elsewhere / "gone")
    return path


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(scenario=scenarios())
def test_overwrite_never_removes_what_bimscan_did_not_write_and_replaces_what_it_wrote(scenario, header):
    kind, name, existing, other, user_folder, user_bytes, npdir_member = scenario
    with tempfile.TemporaryDirectory() as temp:
        root = Path(temp)
        path = _prepare(root, kind, name, existing, other, user_folder, user_bytes, npdir_member, header)
        before = _snapshot(root)
        ours = existing in ("nothing", "ours") or (existing == "ours plus a user file" and not path.is_dir())
        try:
            _write(kind, path, header, 11, overwrite=True)
        except OutputError as exc:
            assert not ours, f"{existing}: {exc}"
            assert str(exc).startswith(str(path)) and "\n" not in str(exc)
            assert _snapshot(root) == before  # nothing moved, nothing removed, no temporary left
            return
        assert ours, f"{existing} at {name} was replaced"
        assert _count(kind, path) == 11
        after = _snapshot(root)
        kept = {k: v for k, v in before.items() if not (k == f"out/{name}" or k.startswith(f"out/{name}/")
                                                         or (kind == "ply" and k.startswith(f"out/{name}.json")))}
        assert {k: after.get(k) for k in kept} == kept  # everything else as it was
        assert not [k for k in after if Path(k).name.endswith(".tmp")]


@pytest.mark.parametrize("kind", sorted(set(SUFFIXES) - {"trajectory"}))
def test_bimscans_own_output_is_kept_without_overwrite_and_replaced_with_it(kind, tmp_path, header):
    path = tmp_path / f"scan{SUFFIXES[kind]}"
    _write(kind, path, header, 5, overwrite=False)
    with pytest.raises(OutputError, match="already exists; pass --overwrite to replace it"):
        check_cloud_output(path)
    _write(kind, path, header, 9, overwrite=True)
    assert _count(kind, path) == 9
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_users_folder_at_a_numpy_output_is_refused_naming_what_it_holds(tmp_path, header):
    mydata = tmp_path / "mydata"
    (mydata / "sub").mkdir(parents=True)
    (mydata / "thesis.txt").write_text("three years of work")
    with pytest.raises(OutputError) as caught:
        check_cloud_output(mydata, overwrite=True)
    assert str(caught.value) == (f"{mydata} is a folder that is not a bimscan NumPy cloud (it holds sub/, thesis.txt); "
                                 "bimscan replaces only what it wrote: choose another output or remove it yourself")
    with pytest.raises(OutputError, match="not a bimscan NumPy cloud"):  # the writer (the API) refuses it too
        open_cloud_writer(mydata, header=header, overwrite=True)
    assert (mydata / "thesis.txt").read_text() == "three years of work" and (mydata / "sub").is_dir()


def test_a_numpy_cloud_with_a_file_added_by_hand_is_refused_naming_the_file(tmp_path, header):
    path = tmp_path / "scan"
    _write("npy", path, header, 5, overwrite=False)
    (path / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="is a bimscan NumPy cloud that also holds notes.txt, which bimscan did not"):
        check_cloud_output(path, overwrite=True)


def test_a_folder_named_like_a_cloud_file_is_refused(tmp_path):
    (tmp_path / "x.laz").mkdir()
    (tmp_path / "x.laz" / "keep.me").write_text("x")
    with pytest.raises(OutputError, match=r"x.laz is a folder, not a .laz file \(it holds keep.me\)"):
        check_cloud_output(tmp_path / "x.laz", overwrite=True)


def test_a_folder_that_appears_at_the_output_while_writing_is_left_alone(tmp_path, header):
    path = tmp_path / "scan"
    writer = open_cloud_writer(path, header=header, overwrite=True)
    writer.write(_cloud(5, header.origin))
    (path / "sub").mkdir(parents=True)  # made by someone else while the scan ran
    with pytest.raises(OutputError, match="not a bimscan NumPy cloud"):
        writer.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan"] and (path / "sub").is_dir()


def test_the_rule_holds_for_every_atomic_write_too(tmp_path):
    folder = tmp_path / "report.png"
    folder.mkdir()
    (folder / "mine.txt").write_text("x")
    with pytest.raises(OutputError, match="is a folder, not a .png file"):
        write_atomic(folder, b"\x89PNG\r\n\x1a\n...")
    staged = tmp_path / "staged"
    staged.mkdir()
    with pytest.raises(OutputError, match="is a folder, not a .png file"):  # replacing a folder takes its kind
        replace_path(staged, tmp_path / "report.png")
    assert (folder / "mine.txt").read_text() == "x"
    write_atomic(tmp_path / "a.trajectory.csv", trajectory_csv(_trajectory(2)))
    write_atomic(tmp_path / "a.trajectory.csv", trajectory_csv(_trajectory(3)))  # its own: replaced
    (tmp_path / "b.trajectory.csv").write_text("t,x,y,z,roll,pitch,yaw\n0,1,2,3,0,0,0\n")  # a user's walk
    with pytest.raises(OutputError, match="not in the format of a .trajectory.csv file"):
        write_atomic(tmp_path / "b.trajectory.csv", trajectory_csv(_trajectory(3)))

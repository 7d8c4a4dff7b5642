"""S3DIS rooms: read from Annotations/<class>_<n>.txt, instances as components, and the
shipped mapping onto the five SPC classes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import InputFileError
from bimscan.io.s3dis import S3DIS_CLASSES, is_s3dis_room, list_s3dis_rooms, read_s3dis_room
from bimscan.learn.data import read_labelled_cloud

# (file name, points, expected S3DIS class id, expected 5-class id)
ROOM = [
    ("beam_1.txt", 4, 3, 1),
    ("board_1.txt", 2, 11, 4),
    ("ceiling_1.txt", 5, 0, 2),
    ("chair_2.txt", 3, 8, 4),
    ("clutter_1.txt", 2, 12, 4),
    ("column_1.txt", 3, 4, 0),
    ("door_1.txt", 2, 6, 4),
    ("floor_1.txt", 6, 1, 3),
    ("stairs_1.txt", 2, 12, 4),  # read as clutter
    ("wall_1.txt", 4, 2, 0),
    ("wall_2.txt", 3, 2, 0),
    ("window_1.txt", 2, 5, 4),
]


def make_room(folder: Path, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    annotations = folder / "Annotations"
    annotations.mkdir(parents=True)
    for name, n, _, _ in ROOM:
        xyz = rng.random((n, 3)) * 5.0
        rgb = rng.integers(0, 256, (n, 3))
        lines = [f"{x:.3f} {y:.3f} {z:.3f} {r} {g} {b}" for (x, y, z), (r, g, b) in zip(xyz, rgb, strict=True)]
        (annotations / name).write_text("\n".join(lines) + "\n")
    (folder / f"{folder.name}.txt").write_text("0 0 0 0 0 0\n")  # the room's whole cloud: ignored
    return folder


def test_room_reads_with_s3dis_class_ids_and_one_component_per_instance(tmp_path: Path) -> None:
    room = make_room(tmp_path / "office_1")

    cloud = read_s3dis_room(room)

    expected_label = np.concatenate([np.full(n, s3dis) for _, n, s3dis, _ in ROOM])
    expected_component = np.concatenate([np.full(n, i) for i, (_, n, _, _) in enumerate(ROOM)])
    np.testing.assert_array_equal(cloud.label, expected_label)
    np.testing.assert_array_equal(cloud.component, expected_component)
    assert len(cloud) == sum(n for _, n, _, _ in ROOM)
    assert S3DIS_CLASSES[cloud.label[0]] == "beam"


def test_shipped_mapping_sends_s3dis_classes_to_the_five_classes(tmp_path: Path) -> None:
    room = make_room(tmp_path / "office_1")

    cloud = read_labelled_cloud(room)

    expected = np.concatenate([np.full(n, five) for _, n, _, five in ROOM])
    np.testing.assert_array_equal(cloud.label, expected)


def test_area_folder_lists_its_rooms_in_order(tmp_path: Path) -> None:
    for name in ("office_2", "hallway_1", "office_10"):
        make_room(tmp_path / "Area_1" / name)
    (tmp_path / "Area_1" / "notes").mkdir()

    rooms = list_s3dis_rooms(tmp_path)

    assert [r.name for r in rooms] == ["hallway_1", "office_10", "office_2"]
    assert all(is_s3dis_room(r) for r in rooms)
    assert not is_s3dis_room(tmp_path / "Area_1")


def test_unknown_class_file_is_a_one_line_error(tmp_path: Path) -> None:
    room = make_room(tmp_path / "office_1")
    (room / "Annotations" / "robot_1.txt").write_text("1 2 3 4 5 6\n")

    with pytest.raises(InputFileError, match="unknown S3DIS class 'robot'"):
        read_s3dis_room(room)


def test_broken_point_line_names_the_file(tmp_path: Path) -> None:
    room = make_room(tmp_path / "office_1")
    (room / "Annotations" / "wall_3.txt").write_text("1 2 3 4 5 6\n1 2 \x10 4 5 6\n1 2\n")  # cut short

    with pytest.raises(InputFileError, match="wall_3.txt: unreadable point line") as caught:
        read_s3dis_room(room)
    assert "usecols" not in str(caught.value)  # NumPy's advice on its API is not the user's


def test_a_stray_byte_is_read_as_the_files_other_lines_read_and_reported(tmp_path: Path) -> None:
    """The release's own slip (a NUL in a few Area_5 lines): inside a number it is dropped
    (103.0\\x000000: 103.0), between two it separates them (3.1\\x00145); each line in its place,
    with a warning; a line that reads neither way is skipped."""
    room = make_room(tmp_path / "hallway_6")
    ceiling = room / "Annotations" / "ceiling_1.txt"
    clean = read_s3dis_room(room)
    lines = ceiling.read_text().splitlines()
    lines[2] = "103.0\x000000 " + " ".join(lines[2].split()[1:])
    x, y, z, r, g, b = lines[3].split()
    lines[3] = f"{x} {y} {z}\x00{r} {g} {b}"
    ceiling.write_text("\n".join([*lines, "1.0 2.0 \x00 4 5"]) + "\n")

    with pytest.warns(UserWarning, match=r"ceiling_1.txt: 2 line\(s\) read without their stray bytes \(line 3: "
                                         r"'103.0\\x000000 .*'\); 1 unreadable line\(s\) skipped \(line 6: "):
        repaired = read_s3dis_room(room)

    assert len(repaired) == len(clean)
    changed = np.flatnonzero((repaired.xyz != clean.xyz).any(axis=1))
    assert len(changed) == 1 and repaired.xyz[changed[0], 0] == 103.0  # in its place, the rest as it was
    np.testing.assert_array_equal(np.delete(repaired.xyz, changed, axis=0), np.delete(clean.xyz, changed, axis=0))
    np.testing.assert_array_equal(repaired.rgb, clean.rgb)  # the separated line's colour too


def test_a_file_of_many_stray_bytes_is_refused_as_damaged(tmp_path: Path) -> None:
    room = make_room(tmp_path / "office_1")
    (room / "Annotations" / "wall_3.txt").write_text("".join(f"1 2 3 4 5 {i}\x00\n" for i in range(20)))

    with pytest.raises(InputFileError, match=r"wall_3.txt: 20 of 20 lines hold stray bytes \(line 1: "
                                             r"'1 2 3 4 5 0\\x00'\); the file is damaged: download it again"):
        read_s3dis_room(room)

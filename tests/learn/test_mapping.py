"""Label mappings: data files from source classes (names or ids) to the training classes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bimscan.errors import ConfigError, LearnError
from bimscan.io.s3dis import S3DIS_CLASSES
from bimscan.learn.train_config import DEFAULT_CLASS_NAMES
from bimscan.learn.mapping import (
    UNMAPPED, apply_label_table, build_label_table, load_label_mapping, load_s3dis_mapping,
)


def test_shipped_s3dis_mapping_covers_every_s3dis_class_as_the_brief_says() -> None:
    table = build_label_table(
        class_names=DEFAULT_CLASS_NAMES, mapping=load_s3dis_mapping(), source_names=dict(enumerate(S3DIS_CLASSES)),
    )

    mapped = {name: DEFAULT_CLASS_NAMES[table[i]] for i, name in enumerate(S3DIS_CLASSES)}
    assert mapped["ceiling"] == "Covering"
    assert mapped["floor"] == "Slab"
    assert mapped["wall"] == mapped["column"] == "Wall&Column"
    assert mapped["beam"] == "Beam"
    rest = set(S3DIS_CLASSES) - {"ceiling", "floor", "wall", "column", "beam"}
    assert {mapped[name] for name in rest} == {"Others"}


def test_mapping_file_maps_numeric_ids_and_sends_the_rest_to_the_default(tmp_path: Path) -> None:
    path = tmp_path / "site.toml"
    path.write_text('name = "site"\ndefault = "Others"\n[classes]\n"6" = "Wall&Column"\n"2" = "slab"\n')

    table = build_label_table(class_names=DEFAULT_CLASS_NAMES, mapping=load_label_mapping(path))

    labels = apply_label_table(np.array([6, 2, 1, 200, 255], dtype=np.uint8), table, where="scan")
    assert labels.tolist() == [0, 3, 4, 4, 255]  # names match case-insensitively; 255 stays unlabelled


def test_mapping_without_default_leaves_unlisted_classes_unlabelled(tmp_path: Path) -> None:
    path = tmp_path / "site.toml"
    path.write_text('name = "site"\n[classes]\n"6" = "Beam"\n')

    table = build_label_table(class_names=DEFAULT_CLASS_NAMES, mapping=load_label_mapping(path))

    assert apply_label_table(np.array([6, 7], dtype=np.uint8), table, where="scan").tolist() == [1, 255]


def test_stored_class_names_are_matched_by_name_without_a_mapping() -> None:
    # a cloud whose scheme lists the same classes in another order
    names = {0: "Slab", 1: "Others", 2: "Wall&Column", 3: "Beam", 4: "Covering"}

    table = build_label_table(class_names=DEFAULT_CLASS_NAMES, source_names=names)

    assert table[:5].tolist() == [3, 4, 0, 1, 2]
    assert table[5] == UNMAPPED


def test_labels_outside_the_classes_without_a_mapping_are_a_one_line_error() -> None:
    table = build_label_table(class_names=DEFAULT_CLASS_NAMES)

    with pytest.raises(LearnError, match="labels 7, 9 are not training classes") as caught:
        apply_label_table(np.array([0, 7, 9, 7], dtype=np.uint8), table, where="scan.laz")
    assert "\n" not in str(caught.value)


def test_mapping_to_an_unknown_target_class_is_a_config_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\n[classes]\nwall = "Walls"\n')

    with pytest.raises(ConfigError, match="maps to 'Walls', which is not a training class"):
        build_label_table(class_names=DEFAULT_CLASS_NAMES, mapping=load_label_mapping(path))


def test_mapping_file_with_an_unknown_key_is_a_config_error(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text('name = "bad"\ntargets = []\n')

    with pytest.raises(ConfigError, match="unknown key"):
        load_label_mapping(path)


def test_a_mapping_whose_class_maps_to_a_number_is_refused_naming_the_file_and_the_source(tmp_path: Path) -> None:
    path = tmp_path / "ids.toml"
    path.write_text('name = "ids"\n[classes]\nwall = 0\n')

    with pytest.raises(ConfigError, match=r"ids.toml: \[classes\] 'wall' must map to a class name \(text\), got 0") \
            as caught:
        load_label_mapping(path)
    assert "\n" not in str(caught.value)

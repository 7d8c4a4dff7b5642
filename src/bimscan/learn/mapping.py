"""Label mappings: data files that send a scene's source classes onto the training classes.

A mapping TOML holds ``name``, an optional ``default`` target and a ``[classes]`` table of
``source = "target"`` pairs. Sources are class names (``wall``, as in S3DIS file names or a
cloud's stored scheme) or integer label ids written as text (``"6"``, for foreign LAS files).
Matching of names ignores case. Sources not listed go to ``default``; without a default they
become unlabelled (id 255), which the loss and the metrics skip. The S3DIS -> 5-class mapping
ships as ``mappings/s3dis_to_spc5.toml``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bimscan.constraints import Checked
from bimscan.toml_files import build_dataclass, load_toml
from bimscan.errors import ConfigError, LearnError
from bimscan.learn.train_config import IGNORE_LABEL

MAPPINGS_DIR = Path(__file__).resolve().parent / "mappings"
S3DIS_MAPPING_PATH = MAPPINGS_DIR / "s3dis_to_spc5.toml"
UNMAPPED = -1  # marks source ids a table does not accept


@dataclass(frozen=True)
class LabelMapping(Checked):
    """Source class (name or id as text) -> target class name; ``default`` for the rest."""

    name: str
    classes: dict[str, str] = field(default_factory=dict)
    default: str | None = None
    source: str = ""  # the file it came from, for messages

    def check(self) -> None:
        for key, value in self.classes.items():
            if not isinstance(value, str):
                raise ConfigError(f"{self.source or self.name}: [classes] {key!r} must map to a class name (text), got {value!r}")


def load_label_mapping(path: str | Path) -> LabelMapping:
    """Read a mapping TOML (see the module docstring)."""
    path = Path(path)
    data = dict(load_toml(path))
    data.setdefault("source", str(path))
    return build_dataclass(LabelMapping, data, where=str(path))


def load_s3dis_mapping() -> LabelMapping:
    """The shipped S3DIS (13 classes) -> Wall&Column/Beam/Covering/Slab/Others mapping."""
    return load_label_mapping(S3DIS_MAPPING_PATH)


def build_label_table(
    *, class_names: Sequence[str], mapping: LabelMapping | None = None,
    source_names: Mapping[int, str] | None = None,
) -> np.ndarray:
    """A (256,) int16 lookup table from a scene's label ids to training ids.

    Entries are 0..C-1, ``IGNORE_LABEL`` (255, unlabelled) or ``UNMAPPED`` (-1, an error when
    a point carries that id). ``source_names`` names the scene's ids (S3DIS classes, a stored
    scheme). Without a mapping, named ids map by name onto ``class_names`` (case-insensitive)
    and unnamed ids 0..C-1 map to themselves; 255 is always unlabelled.
    """
    targets = {name.lower(): i for i, name in enumerate(class_names)}
    table = np.full(256, UNMAPPED, dtype=np.int16)
    table[IGNORE_LABEL] = IGNORE_LABEL
    names = {int(k): str(v) for k, v in (source_names or {}).items()}
    if mapping is None:
        for value in range(255):
            if value in names:
                table[value] = targets.get(names[value].lower(), UNMAPPED)
            elif not names and value < len(class_names):
                table[value] = value
        return table

    def target_id(target: str, what: str) -> int:
        if target.lower() not in targets:
            raise ConfigError(
                f"{mapping.source or mapping.name}: {what} maps to {target!r}, which is not a training class "
                f"({', '.join(class_names)}); fix the mapping or the class names"
            )
        return targets[target.lower()]

    rules = {key.lower(): target_id(value, f"source {key!r}") for key, value in mapping.classes.items()}
    default = IGNORE_LABEL if mapping.default is None else target_id(mapping.default, "'default'")
    for value in range(255):
        name = names.get(value)
        if name is not None and name.lower() in rules:
            table[value] = rules[name.lower()]
        elif str(value) in rules:
            table[value] = rules[str(value)]
        else:
            table[value] = default
    return table


def apply_label_table(label: np.ndarray, table: np.ndarray, *, where: str) -> np.ndarray:
    """Map (N,) uint8 source labels through ``table``; (N,) uint8 training labels.

    Raises LearnError naming the offending source ids when a label has no target.
    """
    mapped = table[label]
    if (mapped == UNMAPPED).any():
        bad = np.unique(label[mapped == UNMAPPED])
        shown = ", ".join(str(int(v)) for v in bad[:10]) + (" ..." if len(bad) > 10 else "")
        raise LearnError(
            f"{where}: labels {shown} are not training classes; pass a mapping file (--mapping / "
            "a scene set's mapping) that sends them to a class or leave them as 255 (unlabelled)"
        )
    return mapped.astype(np.uint8)

"""Per-unit figures of a built dataset: point count, extents, class counts.

``collect_units`` reads them from each finished unit's ``unit.json`` (counted while the unit
was written), or, with ``from_clouds``, recounts them by streaming the unit's cloud file (the one
``ManifestEntry.cloud_file`` chooses) in chunks: never a whole cloud in memory.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bimscan.dataset.layout import DatasetFolder, ManifestEntry, UnitRecord, verify_unit
from bimscan.errors import DatasetError
from bimscan.types import LabelClass


@dataclass(frozen=True)
class UnitStats:
    """One unit's figures. minimum/maximum: (3,) float64 metres; class_counts: class name -> points."""

    unit: str
    scene: str
    config: str
    points: int
    minimum: np.ndarray
    maximum: np.ndarray
    class_counts: dict[str, int]

    @property
    def size(self) -> np.ndarray:
        """(3,) extent along X, Y, Z in metres."""
        return self.maximum - self.minimum

    def proportions_pct(self, classes: list[str]) -> np.ndarray:
        """(len(classes),) share of each class in percent (zeros for an empty unit)."""
        counts = np.array([self.class_counts.get(c, 0) for c in classes], dtype=np.float64)
        return 100.0 * counts / self.points if self.points else np.zeros(len(classes))


@dataclass(frozen=True)
class CollectedDataset:
    """The finished units of a dataset, its classes (with colours) and the units left out."""

    units: list[UnitStats]
    classes: list[LabelClass]
    missing: list[ManifestEntry]  # manifest rows of units not done (status, error)
    configs: list[str]  # in manifest order
    scenes: list[str]


def collect_units(dataset_dir: str | Path, *, from_clouds: bool = False, chunk_points: int = 2_000_000,
                  verify: bool = False) -> CollectedDataset:
    """Figures of every finished unit of the dataset in ``dataset_dir`` (see the module docs).

    ``verify``: first check each finished unit's files against the SHA-256 checksums its unit.json
    recorded at build time; a damaged or missing file is a DatasetError naming the unit.
    """
    folder = DatasetFolder(dataset_dir)
    manifest = folder.read_manifest()
    units: list[UnitStats] = []
    missing: list[ManifestEntry] = []
    classes: list[LabelClass] = []
    configs: list[str] = []
    scenes: list[str] = []
    for entry in manifest.units:
        if entry.config not in configs:
            configs.append(entry.config)
        if entry.scene not in scenes:
            scenes.append(entry.scene)
        if entry.status != "done":
            missing.append(entry)
            continue
        record = folder.read_unit(entry.id)
        if verify:
            damage = verify_unit(folder.unit_dir(entry.id), expected_fingerprint=record.fingerprint)
            if damage is not None:
                raise DatasetError(f"unit {entry.id}: {damage}; run 'bimscan build' with the dataset's spec again "
                                   "to rebuild it")
        unit_classes = _classes_of(record, where=str(folder.unit_record_path(entry.id)))
        if not classes:
            classes = unit_classes
        elif [c.name for c in unit_classes] != [c.name for c in classes]:
            raise DatasetError(f"unit {entry.id} uses classes {[c.name for c in unit_classes]}, other units "
                               f"{[c.name for c in classes]}; statistics need one label scheme per dataset")
        if from_clouds:
            units.append(_recount(folder, entry, unit_classes, chunk_points=chunk_points))
        else:
            units.append(_from_record(entry, record))
    return CollectedDataset(units=units, classes=classes, missing=missing, configs=configs, scenes=scenes)


def _classes_of(record: UnitRecord, *, where: str) -> list[LabelClass]:
    try:
        return [LabelClass(id=int(c["id"]), name=str(c["name"]), color=str(c["color"])) for c in record.scheme_classes()]
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{where}: no label scheme in the unit metadata ({exc}); rebuild the unit") from exc


def _from_record(entry: ManifestEntry, record: UnitRecord) -> UnitStats:
    try:
        return UnitStats(unit=entry.id, scene=entry.scene, config=entry.config, points=record.points,
                         minimum=np.asarray(record.extents["min"], dtype=np.float64),
                         maximum=np.asarray(record.extents["max"], dtype=np.float64),
                         class_counts={str(k): int(v) for k, v in record.class_histogram.items()})
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"unit {entry.id}: unit.json lacks counts or extents ({exc}); rebuild the unit") from exc


def _recount(folder: DatasetFolder, entry: ManifestEntry, classes: list[LabelClass], *, chunk_points: int) -> UnitStats:
    from bimscan.io import iter_cloud_chunks
    from bimscan.process.summary import CloudSummary

    summary = CloudSummary()
    for chunk in iter_cloud_chunks(entry.cloud_file(folder.root), chunk_points=chunk_points):
        summary.add(chunk)
    points, counts = summary.points, summary.class_counts
    low, high = (summary.minimum, summary.maximum) if points else (np.zeros(3), np.zeros(3))
    return UnitStats(unit=entry.id, scene=entry.scene, config=entry.config, points=points, minimum=low,
                     maximum=high, class_counts={c.name: int(counts[c.id]) for c in classes})

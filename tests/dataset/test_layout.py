"""The dataset folder on disk: canonical atomic JSON, typed records, which file to read, unit verification."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from bimscan.dataset.layout import (
    DatasetFolder,
    Manifest,
    ManifestEntry,
    UnitRecord,
    verify_unit,
    write_json,
    write_unit_record,
)
from bimscan.dataset.plan import fingerprint
from bimscan.errors import DatasetError, InputFileError
from bimscan.files import replace_path
from bimscan.types import Station


def _record(key: str, checksums: dict[str, str]) -> UnitRecord:
    return UnitRecord(id="a__b", scene="a", config="b", fingerprint=key, inputs={"scheme": {"classes": []}},
                      ifc_schema="IFC4", stations=(Station(id=0, position=(1.0, 2.0, 3.0), floor_z=1.3),),
                      device_warnings=("too fast",), points=6, points_scanned=7, dropped_invalid=1, dropped_by_voxel=0,
                      extents={"min": [0.0] * 3, "max": [1.0] * 3, "size": [1.0] * 3}, class_histogram={"Wall": 6},
                      station_counts={"0": 6}, files={"laz": "cloud.laz", "npy": "cloud"}, checksums=checksums, bytes=12)


def _unit(folder: Path, *, key: str = "abc") -> Path:
    folder.mkdir(parents=True)
    (folder / "cloud.laz").write_bytes(b"points")
    (folder / "cloud").mkdir()
    (folder / "cloud" / "coord.npy").write_bytes(b"coords")
    checksums = {name: hashlib.sha256((folder / name).read_bytes()).hexdigest() for name in ("cloud.laz", "cloud/coord.npy")}
    write_unit_record(folder, _record(key, checksums))
    return folder


def test_json_is_canonical_so_equal_documents_give_equal_bytes(tmp_path: Path) -> None:
    write_json(tmp_path / "a.json", {"b": 1, "a": [1, 2], "c": {"z": None, "y": "é"}})
    write_json(tmp_path / "b.json", {"c": {"y": "é", "z": None}, "a": [1, 2], "b": 1})
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json"]  # no temporary file left
    assert fingerprint({"x": 1, "y": 2}) == fingerprint({"y": 2, "x": 1}) != fingerprint({"x": 1, "y": 3})


def test_a_manifest_round_trips_and_a_foreign_or_malformed_one_is_refused(tmp_path: Path) -> None:
    folder = DatasetFolder(tmp_path)
    manifest = Manifest(units=(
        ManifestEntry(id="a__b", scene="a", config="b", status="done", points=5, files={"npy": "units/a__b/cloud"}),
        ManifestEntry(id="a__c", scene="a", config="c", status="failed", error="disk full")))
    folder.write_manifest(manifest)
    assert folder.read_manifest() == manifest and folder.read_manifest().done() == [manifest.units[0]]
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "something-else", "version": 1, "units": []}))
    with pytest.raises(DatasetError, match="not a bimscan-dataset manifest"):
        folder.read_manifest()
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "bimscan-dataset", "version": 1,
                                                         "units": [{"id": "a__b", "status": "done"}]}))
    with pytest.raises(DatasetError, match="malformed unit entry"):
        folder.read_manifest()
    with pytest.raises(InputFileError, match="no such dataset folder"):
        DatasetFolder(tmp_path / "missing").read_manifest()
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFileError, match="no manifest.json"):
        DatasetFolder(tmp_path / "empty").read_manifest()
    with pytest.raises(ValueError, match="status"):
        ManifestEntry(id="x", scene="x", config="y", status="half-done")


def test_a_unit_record_round_trips_through_unit_json(tmp_path: Path) -> None:
    record = _record("abc", {"cloud.laz": "00"})
    (tmp_path / "u").mkdir()
    write_unit_record(tmp_path / "u", record)
    assert UnitRecord.from_json(json.loads((tmp_path / "u" / "unit.json").read_text()), where="u") == record
    document = record.to_json()
    del document["points"]
    with pytest.raises(DatasetError, match="unit.json is incomplete"):
        UnitRecord.from_json(document, where="u")


def test_one_rule_chooses_the_unit_file_a_reader_takes(tmp_path: Path) -> None:
    (tmp_path / "units" / "a__b" / "cloud").mkdir(parents=True)
    (tmp_path / "units" / "a__b" / "cloud.laz").write_bytes(b"")
    entry = ManifestEntry(id="a__b", scene="a", config="b", status="done",
                          files={"laz": "units/a__b/cloud.laz", "npy": "units/a__b/cloud"})
    assert entry.cloud_file(tmp_path) == tmp_path / "units" / "a__b" / "cloud"  # NumPy reads fastest
    only_laz = ManifestEntry(id="a__b", scene="a", config="b", status="done", files={"laz": "units/a__b/cloud.laz"})
    assert only_laz.cloud_file(tmp_path).name == "cloud.laz"
    with pytest.raises(InputFileError, match="lists no cloud"):
        ManifestEntry(id="a__b", scene="a", config="b", status="done").cloud_file(tmp_path)


def test_a_finished_unit_verifies_and_any_change_is_caught(tmp_path: Path) -> None:
    folder = _unit(tmp_path / "units" / "a__b")
    assert verify_unit(folder, expected_fingerprint="abc") is None
    assert "other inputs" in verify_unit(folder, expected_fingerprint="def")
    (folder / "cloud" / "coord.npy").write_bytes(b"coordz")
    assert verify_unit(folder, expected_fingerprint="abc") == "cloud/coord.npy does not match its checksum"
    (folder / "cloud.laz").unlink()
    assert verify_unit(folder, expected_fingerprint="abc") == "cloud.laz is missing"
    (folder / "unit.json").write_text("{half")
    assert "not readable JSON" in verify_unit(folder, expected_fingerprint="abc")


def test_committing_a_unit_replaces_a_stale_one_and_leftovers_are_swept(tmp_path: Path) -> None:
    units = tmp_path / "units"
    stale = _unit(units / "a__b", key="old")
    staged = _unit(units / ".a__b.123.tmp", key="new")
    (units / ".a__c.456.tmp").mkdir()
    (tmp_path / ".manifest.json.789.tmp").write_text("{")
    replace_path(staged, stale, kind="unit")
    assert json.loads((units / "a__b" / "unit.json").read_text())["fingerprint"] == "new"
    assert DatasetFolder(tmp_path).remove_leftovers() == 2
    assert sorted(p.name for p in units.iterdir()) == ["a__b"] and not list(tmp_path.glob(".*.tmp"))

"""The dataset folder on disk: canonical atomic JSON, manifest checks, unit verification."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from bimscan.files import replace_path
from bimscan.dataset.manifest import (
    UNIT_FORMAT,
    UNIT_VERSION,
    fingerprint,
    manifest_entry,
    read_manifest,
    remove_leftovers,
    verify_unit,
    write_json,
    write_manifest,
)
from bimscan.errors import DatasetError, InputFileError


def _unit(folder: Path, *, key: str = "abc") -> Path:
    folder.mkdir(parents=True)
    (folder / "cloud.laz").write_bytes(b"points")
    (folder / "cloud").mkdir()
    (folder / "cloud" / "coord.npy").write_bytes(b"coords")
    checksums = {name: hashlib.sha256((folder / name).read_bytes()).hexdigest() for name in ("cloud.laz", "cloud/coord.npy")}
    write_json(folder / "unit.json", {"format": UNIT_FORMAT, "version": UNIT_VERSION, "fingerprint": key,
                                      "files": {"laz": "cloud.laz", "npy": "cloud"}, "checksums": checksums})
    return folder


def test_json_is_canonical_so_equal_documents_give_equal_bytes(tmp_path: Path) -> None:
    write_json(tmp_path / "a.json", {"b": 1, "a": [1, 2], "c": {"z": None, "y": "é"}})
    write_json(tmp_path / "b.json", {"c": {"y": "é", "z": None}, "a": [1, 2], "b": 1})
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json"]  # no temporary file left
    assert fingerprint({"x": 1, "y": 2}) == fingerprint({"y": 2, "x": 1}) != fingerprint({"x": 1, "y": 3})


def test_a_manifest_round_trips_and_a_foreign_one_is_refused(tmp_path: Path) -> None:
    entries = [manifest_entry(unit="a__b", scene="a", config="b", status="done", points=5, files={"npy": "units/a__b/cloud"}),
               manifest_entry(unit="a__c", scene="a", config="c", status="failed", error="disk full")]
    write_manifest(tmp_path, entries)
    assert read_manifest(tmp_path)["units"] == entries
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "something-else", "version": 1, "units": []}))
    with pytest.raises(DatasetError, match="not a bimscan-dataset manifest"):
        read_manifest(tmp_path)
    with pytest.raises(InputFileError, match="no such dataset folder"):
        read_manifest(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFileError, match="no manifest.json"):
        read_manifest(tmp_path / "empty")
    with pytest.raises(ValueError, match="status"):
        manifest_entry(unit="x", scene="x", config="y", status="half-done")


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
    replace_path(staged, stale)
    assert json.loads((units / "a__b" / "unit.json").read_text())["fingerprint"] == "new"
    assert remove_leftovers(tmp_path) == 2
    assert sorted(p.name for p in units.iterdir()) == ["a__b"] and not list(tmp_path.glob(".*.tmp"))

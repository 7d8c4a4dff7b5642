"""Dataset statistics on a small dataset of chosen figures, written through the dataset layout's
own records: the numbers, the files, the report."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from bimscan.cli.main import main
from bimscan.dataset.layout import DatasetFolder, Manifest, ManifestEntry, UnitRecord, write_unit_record
from bimscan.stats.collect import collect_units
from bimscan.stats.report import write_stats
from bimscan.stats.summary import summarize_dataset

CLASSES = [{"id": 0, "name": "Wall", "color": "#ff0000"}, {"id": 1, "name": "Slab", "color": "#00ff00"},
           {"id": 2, "name": "Other", "color": "#0000ff"}]
# unit -> (points, min, max, [Wall, Slab, Other])
UNITS = {
    "A__c1": (100, (0, 0, 0), (10, 5, 3.0), [50, 30, 20]),
    "A__c2": (300, (0, 0, 0), (10, 5, 3.3), [147, 96, 57]),
    "B__c1": (200, (1, 1, 0), (5, 9, 6.0), [100, 100, 0]),
    "B__c2": (400, (1, 1, 0), (5, 9, 6.0), [200, 200, 0]),
}


def _write_dataset(path: Path) -> Path:
    folder = DatasetFolder(path)
    entries = []
    for uid, (points, low, high, counts) in UNITS.items():
        scene, config = uid.split("__")
        folder.unit_dir(uid).mkdir(parents=True)
        write_unit_record(folder.unit_dir(uid), UnitRecord(
            id=uid, scene=scene, config=config, fingerprint="f", inputs={"scheme": {"classes": CLASSES}},
            ifc_schema="IFC4", stations=(), device_warnings=(), points=points, points_scanned=points, dropped_invalid=0,
            dropped_by_voxel=0, extents={"min": list(low), "max": list(high),
                                         "size": [h - lo for lo, h in zip(low, high)]},
            class_histogram={c["name"]: n for c, n in zip(CLASSES, counts)}, station_counts={"0": points},
            files={"npy": "cloud"}, checksums={}, bytes=0))
        entries.append(ManifestEntry(id=uid, scene=scene, config=config, status="done", points=points,
                                     files=folder.unit_files(uid, {"npy": "cloud"})))
    entries.append(ManifestEntry(id="B__c3", scene="B", config="c3", status="failed", error="disk full"))
    folder.write_manifest(Manifest(units=tuple(entries)))
    return path


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    return _write_dataset(tmp_path / "dataset")


def test_statistics_equal_the_hand_computed_values(dataset: Path) -> None:
    stats = summarize_dataset(collect_units(dataset))
    assert stats.classes == ["Wall", "Slab", "Other"]
    c1, c2 = stats.configs  # c3 has no finished unit
    assert (c1.config, c1.units, c1.points_total, c1.points_mean, c1.points_min, c1.points_max) == ("c1", 2, 300, 150, 100, 200)
    assert c2.points_total == 700 and c2.points_mean == 350
    np.testing.assert_allclose(c1.size_mean_m, (7.0, 6.5, 4.5))
    np.testing.assert_allclose(c2.size_mean_m, (7.0, 6.5, 4.65))
    assert c1.proportions_pct == pytest.approx({"Wall": 50.0, "Slab": 130 / 3, "Other": 20 / 3})
    assert c2.proportions_pct == pytest.approx({"Wall": 34700 / 700, "Slab": 29600 / 700, "Other": 5700 / 700})
    a, b = stats.scenes
    assert a.points == {"c1": 100, "c2": 300}
    np.testing.assert_allclose(a.extent_spread, (0.0, 0.0, 0.3 / 3.15))
    assert a.class_spread_pp == pytest.approx({"Wall": 1.0, "Slab": 2.0, "Other": 1.0})
    assert b.max_extent_spread == 0.0 and b.max_class_spread_pp == 0.0
    assert stats.max_extent_spread() == pytest.approx((0.3 / 3.15, "A", "z"))
    assert stats.max_class_spread() == pytest.approx((2.0, "A", "Slab"))
    assert [m.id for m in stats.missing] == ["B__c3"]


def test_stats_writes_tables_plots_and_a_report_that_states_stability_in_numbers(dataset: Path, tmp_path: Path) -> None:
    result = write_stats(dataset, tmp_path / "stats")
    names = sorted(p.name for p in (tmp_path / "stats").iterdir())
    written = sorted(["units.csv", "configs.csv", "scenes.csv", "stats.json", "points.png", "extents.png",
                      "classes.png", "report.md"])
    assert names == [".bimscan.json", *written]  # its record lists what bimscan wrote there
    assert json.loads((tmp_path / "stats" / ".bimscan.json").read_text())["files"] == written
    for plot in ("points.png", "extents.png", "classes.png"):
        data = (tmp_path / "stats" / plot).read_bytes()
        assert data.startswith(b"\x89PNG\r\n\x1a\n") and len(data) > 10_000
    rows = list(csv.DictReader((tmp_path / "stats" / "configs.csv").open()))
    assert [r["config"] for r in rows] == ["c1", "c2"] and rows[1]["points_total"] == "700"
    assert float(rows[0]["pct_Slab"]) == pytest.approx(43.333, abs=1e-3)
    units = list(csv.DictReader((tmp_path / "stats" / "units.csv").open()))
    assert len(units) == 4 and units[1]["size_z_m"] == "3.3000" and units[1]["count_Other"] == "57"
    report = (tmp_path / "stats" / "report.md").read_text()
    assert "9.52 % (scene A, axis Z), so extents do NOT stay stable" in report
    assert "2.00 percentage points (scene A, class Slab), so proportions stay stable" in report
    assert "![points per configuration](points.png)" in report and "B__c3 (failed: disk full)" in report
    document = json.loads((tmp_path / "stats" / "stats.json").read_text())
    assert document["stability"]["max_class_spread_class"] == "Slab"
    assert result.stats.configs[0].points_total == 300


def test_statistics_are_written_again_to_the_same_bytes(dataset: Path, tmp_path: Path) -> None:
    write_stats(dataset, tmp_path / "one")
    write_stats(dataset, tmp_path / "two")
    for path in (tmp_path / "one").iterdir():
        assert path.read_bytes() == (tmp_path / "two" / path.name).read_bytes(), path.name


def test_statistics_into_a_users_folder_are_refused_before_the_units_are_read_and_keep_it(
        dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from bimscan.errors import OutputError

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "report.md").write_text("# my report")
    monkeypatch.setattr("bimscan.stats.report.collect_units", lambda *a, **k: pytest.fail("units read"))
    with pytest.raises(OutputError, match=r"mine is a folder bimscan did not make \(it holds report.md\)"):
        write_stats(dataset, mine)
    assert [p.name for p in mine.iterdir()] == ["report.md"] and (mine / "report.md").read_text() == "# my report"


def test_statistics_written_before_folders_had_records_are_written_again_beside_the_users_notes(
        dataset: Path, tmp_path: Path) -> None:
    write_stats(dataset, tmp_path / "stats")
    (tmp_path / "stats" / ".bimscan.json").unlink()  # as an earlier version left it
    (tmp_path / "stats" / "notes.md").write_text("mine")
    write_stats(dataset, tmp_path / "stats")
    assert (tmp_path / "stats" / "notes.md").read_text() == "mine"
    assert "notes.md" not in json.loads((tmp_path / "stats" / ".bimscan.json").read_text())["files"]


def test_stats_can_recount_units_by_streaming_their_clouds(tmp_path: Path) -> None:
    from bimscan.io import open_cloud_writer
    from bimscan.types import CloudHeader, LabelClass, LabelScheme, PointCloud

    dataset = _write_dataset(tmp_path / "dataset")
    scheme = LabelScheme(name="three", classes=tuple(LabelClass(**c) for c in CLASSES), rules=(), default_label="Other")
    rng = np.random.default_rng(0)
    expected = {}
    for uid in UNITS:
        n = int(rng.integers(3000, 6000))
        xyz = rng.uniform(-2.0, 7.0, (n, 3))
        label = rng.integers(0, 3, n).astype(np.uint8)
        with open_cloud_writer(dataset / "units" / uid / "cloud", header=CloudHeader(scheme=scheme)) as writer:
            for start in range(0, n, 1000):  # several chunks, as a scan writes them
                writer.write(PointCloud(xyz=xyz[start:start + 1000], label=label[start:start + 1000]))
        expected[uid] = (n, xyz.min(axis=0), xyz.max(axis=0), np.bincount(label, minlength=3))
    collected = collect_units(dataset, from_clouds=True, chunk_points=700)
    for unit in collected.units:
        n, low, high, counts = expected[unit.unit]
        assert unit.points == n
        np.testing.assert_allclose(unit.minimum, low, atol=1e-5)  # float32 storage in the NumPy folder
        np.testing.assert_allclose(unit.maximum, high, atol=1e-5)
        assert [unit.class_counts[c["name"]] for c in CLASSES] == counts.tolist()


def test_the_stats_command_writes_beside_the_dataset_and_refuses_a_folder_without_a_manifest(
        dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["stats", str(dataset)]) == 0
    assert (dataset / "stats" / "report.md").is_file()
    assert "largest extent spread across configurations: 9.52 % (A, Z)" in capsys.readouterr().out
    (tmp_path / "nothing").mkdir()
    assert main(["stats", str(tmp_path / "nothing")]) == 1
    assert "no manifest.json" in capsys.readouterr().err


def _checksummed(dataset: Path) -> Path:
    """Give unit A__c1 a cloud file and the checksums a build records; the other units leave the
    manifest (only this one carries files here)."""
    import dataclasses

    from bimscan.files import file_sha256

    folder = DatasetFolder(dataset)
    manifest = folder.read_manifest()
    folder.write_manifest(Manifest(units=tuple(u for u in manifest.units if u.id in ("A__c1", "B__c3"))))
    unit = folder.unit_dir("A__c1")
    (unit / "cloud").mkdir()
    (unit / "cloud" / "coord.npy").write_bytes(b"\x93NUMPY fake but checksummed")
    record = folder.read_unit("A__c1")
    write_unit_record(unit, dataclasses.replace(
        record, checksums={"cloud/coord.npy": file_sha256(unit / "cloud" / "coord.npy")}))
    return unit


def test_verify_checks_unit_files_against_their_checksums(dataset: Path, capsys) -> None:
    unit = _checksummed(dataset)
    assert main(["stats", str(dataset), "--verify"]) == 0
    assert "unit files verified against their checksums" in capsys.readouterr().out
    (unit / "cloud" / "coord.npy").write_bytes(b"\x93NUMPY damaged on disk")
    assert main(["stats", str(dataset), "--verify"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "A__c1: cloud/coord.npy does not match its checksum" in err
    assert main(["stats", str(dataset)]) == 0  # without --verify it says it did not check
    assert "not verified against their checksums (pass --verify" in capsys.readouterr().out

"""Building datasets: units, metadata, manifest, checksums; resuming, killing, failing, Ray."""

from __future__ import annotations

import errno
import hashlib
import json
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bimscan.dataset.build import build_dataset
from bimscan.dataset.spec import load_spec
from bimscan.dataset.tasks import UNIT_STAGES
from bimscan.io import read_cloud

from .conftest import UNIT_IDS, BuiltDataset, reproducible_files


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _manifest(out: Path) -> dict:
    return json.loads((out / "manifest.json").read_text())


def test_a_build_writes_one_unit_per_scene_and_configuration_with_the_manifest_shape(reference_dataset: BuiltDataset) -> None:
    out = reference_dataset.out
    manifest = _manifest(out)
    assert manifest["format"] == "bimscan-dataset" and manifest["version"] == 1
    assert [u["id"] for u in manifest["units"]] == list(UNIT_IDS)
    for unit in manifest["units"]:
        assert set(unit) == {"id", "scene", "config", "status", "error", "points", "files"}
        assert unit["status"] == "done" and unit["error"] is None
        assert unit["id"] == f"{unit['scene']}__{unit['config']}"
        assert unit["files"] == {"laz": f"units/{unit['id']}/cloud.laz", "npy": f"units/{unit['id']}/cloud"}
        assert (out / unit["files"]["laz"]).is_file() and (out / unit["files"]["npy"]).is_dir()
    assert reference_dataset.report.ok and reference_dataset.report.built == 4


def test_unit_metadata_records_inputs_counts_and_checksums_that_match_the_files(reference_dataset: BuiltDataset) -> None:
    out = reference_dataset.out
    for entry in _manifest(out)["units"]:
        folder = out / "units" / entry["id"]
        meta = json.loads((folder / "unit.json").read_text())
        assert meta["scene"] == entry["scene"] and meta["config"] == entry["config"]
        assert meta["inputs"]["recipe"]["seed"] == 3
        assert meta["inputs"]["recipe"]["noise"]["range_sigma_m"] == 0.005 and meta["inputs"]["recipe"]["noise"]["angle_sigma_deg"] == 0.03
        assert meta["inputs"]["recipe"]["settings"]["head_deg_per_s"] == 360.0
        assert meta["inputs"]["scene"]["sha256"] == _sha256(out / "scenes" / f"{entry['scene']}.ifc")
        assert meta["ifc_schema"] == "IFC4" and meta["inputs"]["software"].startswith("bimscan ")
        assert meta["ifc"]["failed"] == [] and meta["ifc"]["report"]["declared_elements"] > 0  # what the IFC needed
        assert len(meta["stations"]) >= 2
        assert meta["points"] == entry["points"] > 10_000
        assert sum(meta["class_histogram"].values()) == meta["points"]
        assert sum(meta["station_counts"].values()) == meta["points"]
        assert meta["points_scanned"] == meta["points"] and meta["dropped_invalid"] == 0
        # every written file is listed with its real SHA-256
        listed = {name: digest for name, digest in meta["checksums"].items()}
        on_disk = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()} - {"unit.json", "timings.json"}
        assert set(listed) == on_disk
        for name, digest in listed.items():
            assert _sha256(folder / name) == digest
        # both formats hold the same labelled points
        laz, npy = read_cloud(folder / "cloud.laz"), read_cloud(folder / "cloud")
        assert len(laz) == len(npy) == meta["points"]
        np.testing.assert_array_equal(laz.label, npy.label)
        np.testing.assert_allclose(laz.xyz, npy.xyz, atol=2e-4)
        names = [c["name"] for c in meta["inputs"]["scheme"]["classes"]]
        assert [meta["class_histogram"][n] for n in names] == np.bincount(laz.label, minlength=len(names)).tolist()
        np.testing.assert_allclose(meta["extents"]["min"], laz.xyz.min(axis=0), atol=1e-3)
        timings = json.loads((folder / "timings.json").read_text())
        assert timings["total_s"] > 0
        assert timings["host"] == socket.gethostname() and "ray_node" not in timings  # where it was built
        # where the unit's time went, step by step: every step named, the steps add up to the whole
        stages = timings["stages_s"]
        assert set(stages) == set(UNIT_STAGES) and min(stages.values()) >= 0
        assert sum(stages.values()) == pytest.approx(timings["total_s"], abs=0.02)
        assert stages["cast"] > 0 and stages["compress"] > 0 and stages["checksum"] > 0
        assert timings["pulses"] >= meta["points"]


def test_every_configuration_of_a_scene_scans_from_the_same_stations(reference_dataset: BuiltDataset) -> None:
    out = reference_dataset.out
    for scene in ("north", "south"):
        sparse = json.loads((out / "units" / f"{scene}__sparse" / "unit.json").read_text())
        dense = json.loads((out / "units" / f"{scene}__dense" / "unit.json").read_text())
        assert sparse["stations"] == dense["stations"]
        assert dense["points"] > 1.5 * sparse["points"]  # twice the pulse rate


def test_a_second_run_builds_nothing_and_touches_no_unit(reference_dataset: BuiltDataset) -> None:
    out = reference_dataset.out
    before = {p: p.stat().st_mtime_ns for p in (out / "units").rglob("*")}
    manifest = (out / "manifest.json").read_bytes()
    report = build_dataset(load_spec(reference_dataset.spec), out, workers=2, progress=False)
    assert (report.built, report.reused, report.failed) == (0, 4, 0)
    assert {p: p.stat().st_mtime_ns for p in (out / "units").rglob("*")} == before
    assert (out / "manifest.json").read_bytes() == manifest


def test_a_unit_whose_file_changed_is_rebuilt_to_the_same_bytes(reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    out = tmp_path / "copy"
    shutil.copytree(reference_dataset.out, out)
    damaged = out / "units" / "south__dense" / "cloud" / "segment.npy"
    data = bytearray(damaged.read_bytes())
    data[-1] ^= 0xFF
    damaged.write_bytes(bytes(data))
    (out / "units" / "north__sparse" / "cloud.laz").unlink()
    report = build_dataset(load_spec(reference_dataset.spec), out, executor="serial", progress=False)
    assert (report.built, report.reused) == (2, 2)
    assert reproducible_files(out) == reproducible_files(reference_dataset.out)


def test_a_changed_spec_rebuilds_the_units_it_changes(reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    out = tmp_path / "copy"
    shutil.copytree(reference_dataset.out, out)
    spec_text = reference_dataset.spec.read_text().replace('preset = "exp3"', 'preset = "exp4"')
    spec = tmp_path / "changed.toml"
    spec.write_text(spec_text)
    report = build_dataset(load_spec(spec), out, executor="serial", progress=False)
    assert (report.built, report.reused) == (2, 2)  # the two "dense" units
    meta = json.loads((out / "units" / "north__dense" / "unit.json").read_text())
    assert meta["inputs"]["recipe"]["preset"] == "exp4"


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # the process ended while we looked
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _kill_at(out: Path, spec: Path, delay_s: float) -> tuple[float, str]:
    """Start `bimscan build SPEC OUT --workers 1` and kill -9 it ``delay_s`` after it started, or
    as soon as its last unit to build is being written, whichever comes first (a moment with work
    left). Checks that its orphaned worker ends itself. Returns the moment and what it was doing."""
    command = [sys.executable, "-m", "bimscan.cli.main", "build", str(spec), str(out), "--workers", "1"]
    process = subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    start = time.monotonic()
    units = out / "units"
    leftovers = {n for n in os.listdir(units) if n.endswith(".tmp")} if units.is_dir() else set()  # a killed run's
    workers: list[int] = []
    doing = "starting"
    try:
        while time.monotonic() - start < delay_s and process.poll() is None:
            names = set(os.listdir(units)) if units.is_dir() else set()
            finished = [n for n in names if not n.startswith(".")]
            staging = [n for n in names - leftovers if n.endswith(".tmp")]
            doing = f"{'writing a unit' if staging else 'starting, planning or between units'}, " \
                    f"{len(finished)} finished"
            if staging and len(finished) == len(UNIT_IDS) - 1:
                break  # the last unit: kill now or never
            time.sleep(0.005)
        workers = _children(process.pid)
        process.send_signal(signal.SIGKILL)
    finally:
        if process.poll() is None and not workers:
            os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=60)
    moment = time.monotonic() - start
    assert process.returncode == -signal.SIGKILL, f"the build ended before it could be killed: {process.stderr.read()}"
    # the orphaned worker notices its driver is gone and ends itself, mid-unit
    end = time.monotonic() + 10
    while time.monotonic() < end and any(Path(f"/proc/{pid}").exists() for pid in workers):
        time.sleep(0.05)
    alive = [pid for pid in workers if Path(f"/proc/{pid}").exists()]
    for pid in alive:
        os.kill(pid, signal.SIGKILL)  # do not leave them behind if the test fails
    assert not alive, "worker processes outlived their killed driver"
    # the resource tracker removes the killed build's semaphores, without its raw "leaked semaphore" UserWarning
    _, err = process.communicate(timeout=60)
    assert "resource_tracker" not in err.decode() and "leaked" not in err.decode(), err.decode()
    return moment, doing


@pytest.mark.slow
def test_a_build_killed_twice_at_random_moments_resumes_to_identical_outputs(
        reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    from bimscan.cli.main import main
    from bimscan.dataset.layout import DatasetFolder, verify_unit

    rng = random.Random(44)
    uninterrupted_s = reference_dataset.report.seconds + 3  # its build, plus starting Python
    out = tmp_path / "killed"
    kills = []
    for kill in range(2):
        folder = DatasetFolder(out)
        pending = 1.0 if kill == 0 else sum(u["status"] != "done" for u in _manifest(out)["units"]) / len(UNIT_IDS)
        moment, doing = _kill_at(out, reference_dataset.spec, rng.uniform(0.1, 0.9) * uninterrupted_s * pending + 1)
        kills.append(f"{moment:.1f} s, {doing}")
        # what a killed build leaves is consistent: a readable manifest saying what is unfinished, and every
        # unit folder in place whole (its files match their checksums)
        if (out / "manifest.json").is_file():
            statuses = [u["status"] for u in _manifest(out)["units"]]
            assert "pending" in statuses, kills
        for unit in (folder.unit_dir(u) for u in UNIT_IDS):
            if unit.exists():
                record = json.loads((unit / "unit.json").read_text())
                assert verify_unit(unit, expected_fingerprint=record["fingerprint"]) is None, kills

    report = build_dataset(load_spec(reference_dataset.spec), out, workers=1, progress=False)
    assert report.ok and report.reused + report.built == len(UNIT_IDS) and report.built >= 1, kills
    assert not [p for p in (out / "units").iterdir() if p.name.startswith(".")]
    assert reproducible_files(out) == reproducible_files(reference_dataset.out), kills
    assert main(["stats", str(out), "--verify", "--out", str(tmp_path / "stats")]) == 0


@pytest.mark.slow
def test_a_build_stopped_by_sigterm_removes_its_workers_staging_on_the_way_out(
    reference_dataset: BuiltDataset, tmp_path: Path,
) -> None:
    out = tmp_path / "stopped"
    command = [sys.executable, "-m", "bimscan.cli.main", "build", str(reference_dataset.spec), str(out), "--workers", "2"]
    process = subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 240
    try:
        # wait until the workers are writing units, then stop the build as a batch system does
        while time.monotonic() < deadline and process.poll() is None:
            units = out / "units"
            if units.is_dir() and [p for p in units.iterdir() if p.name.endswith(".tmp")]:
                process.send_signal(signal.SIGTERM)
                break
            time.sleep(0.005)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    lines = err.decode().strip().splitlines()
    assert process.returncode == 143, lines
    assert lines[-1] == "error: terminated; finished work is kept, run the same command to resume"
    left = [p.relative_to(out).as_posix() for folder in (out, out / "units", out / "scenes") for p in folder.iterdir()
            if p.name.endswith(".tmp")]
    assert left == []  # the ended workers' staging folders went with the build, not at the next resume


@pytest.mark.slow
def test_the_ray_executor_writes_the_same_bytes_as_the_local_one(reference_dataset: BuiltDataset, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    report = build_dataset(load_spec(reference_dataset.spec), out, executor="ray", workers=2, progress=False)
    assert report.ok and report.built == 4
    assert reproducible_files(out) == reproducible_files(reference_dataset.out)


ONE_SCENE = """\
formats = ["npy"]
{extra}
[[scenes]]
name = "good"
generate = {{ seed = 1, storeys = 1 }}
{scenes}
[[configs]]
name = "fast"
preset = "exp3"
head_deg_per_s = 360.0
"""


def _small_spec(folder: Path, *, extra: str = "", scenes: str = "") -> Path:
    path = folder / "spec.toml"
    path.write_text(ONE_SCENE.format(extra=extra, scenes=scenes))
    return path


# An IFC file that reads but holds nothing to scan: it fails only when its unit parses it.
EMPTY_IFC = """ISO-10303-21;
HEADER;
FILE_DESCRIPTION(('ViewDefinition [CoordinationView]'),'2;1');
FILE_NAME('empty.ifc','2024-01-01T00:00:00',(''),(''),'','','');
FILE_SCHEMA(('IFC4'));
ENDSEC;
DATA;
ENDSEC;
END-ISO-10303-21;
"""


def test_a_scene_that_is_not_an_ifc_file_is_refused_with_the_spec_before_any_unit(tmp_path: Path) -> None:
    from bimscan.errors import IfcError

    (tmp_path / "broken.ifc").write_text("this is not a model\n")
    spec = _small_spec(tmp_path, scenes='[[scenes]]\nname = "broken"\nifc = "broken.ifc"\n')
    with pytest.raises(IfcError, match=r"\('broken'\): .*broken.ifc: not an IFC file"):
        load_spec(spec)


def test_a_bad_scene_fails_its_units_and_the_others_are_built(tmp_path: Path, session_env: Path) -> None:
    (tmp_path / "broken.ifc").write_text(EMPTY_IFC)
    spec = _small_spec(tmp_path, scenes='[[scenes]]\nname = "broken"\nifc = "broken.ifc"\n')
    report = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    rows = {u["id"]: u for u in _manifest(tmp_path / "out")["units"]}
    assert rows["good__fast"]["status"] == "done" and rows["good__fast"]["points"] > 0
    assert rows["broken__fast"]["status"] == "failed"
    assert "nothing to scan" in rows["broken__fast"]["error"] and "\n" not in rows["broken__fast"]["error"]
    assert rows["broken__fast"]["points"] == 0 and rows["broken__fast"]["files"] == {}
    assert not report.ok and "1 failed" in report.summary()
    assert not (tmp_path / "out" / "units" / "broken__fast").exists()


def test_a_full_disk_fails_the_unit_with_a_clear_reason_and_leaves_no_partial_unit(
        tmp_path: Path, session_env: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from bimscan.io import npdir

    original = npdir.NpdirCloudWriter._append
    calls = {"n": 0}

    def full_disk(self, chunk, values):  # the third chunk written hits a full disk
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(errno.ENOSPC, "No space left on device", str(self.path))
        return original(self, chunk, values)

    monkeypatch.setattr(npdir.NpdirCloudWriter, "_append", full_disk)
    spec = _small_spec(tmp_path)
    report = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False, chunk_pulses=20_000)
    (row,) = _manifest(tmp_path / "out")["units"]
    assert report.failed == 1 and row["status"] == "failed"
    assert row["error"].startswith("disk full while writing") and "free space" in row["error"]
    assert list((tmp_path / "out" / "units").iterdir()) == []  # no unit, no staging folder left
    monkeypatch.undo()
    report = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    assert report.ok and report.built == 1  # space freed: the same command finishes it


def test_voxel_subsampling_thins_a_unit_and_is_recorded(tmp_path: Path, session_env: Path) -> None:
    from bimscan.io import read_cloud_header

    spec = _small_spec(tmp_path, extra="voxel_size_m = 0.1")
    build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    folder = tmp_path / "out" / "units" / "good__fast"
    meta = json.loads((folder / "unit.json").read_text())
    assert 0 < meta["points"] < meta["points_scanned"] / 2
    assert meta["dropped_by_voxel"] == meta["points_scanned"] - meta["points"]
    cloud = read_cloud(folder / "cloud")
    origin = np.asarray(read_cloud_header(folder / "cloud").origin)
    keys = np.floor((cloud.xyz - origin) / 0.1).astype(np.int64)
    # one point per 10 cm voxel of the grid anchored at the cloud's origin (float32 storage can move
    # a point sitting on a voxel face by a micrometre)
    assert len(np.unique(keys, axis=0)) >= len(cloud) - 10


def test_the_build_command_exits_non_zero_with_a_summary_when_a_unit_failed(
        tmp_path: Path, session_env: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bimscan.cli.main import main

    (tmp_path / "broken.ifc").write_text(EMPTY_IFC)
    spec = _small_spec(tmp_path, scenes='[[scenes]]\nname = "broken"\nifc = "broken.ifc"\n')
    assert main(["build", str(spec), str(tmp_path / "out"), "--workers", "1"]) == 1
    captured = capsys.readouterr()
    assert "2 units: 1 built, 0 already done, 1 failed" in captured.out
    lines = captured.err.strip().splitlines()
    assert lines[0].startswith("warning: configuration 'fast': scan_freq_hz = 240")  # exp3 exceeds the device
    (failure,) = [line for line in lines if line.startswith("failed: ")]
    assert failure.startswith("failed: broken__fast: ") and "nothing to scan" in failure
    assert lines[-1].startswith("error: 1 of 2 units failed;") and "run the same command again" in lines[-1]


def test_a_generated_scene_follows_its_seed_and_one_edited_by_hand_is_made_again(
        tmp_path: Path, session_env: Path) -> None:
    spec = _small_spec(tmp_path)
    first = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    scene = tmp_path / "out" / "scenes" / "good.ifc"
    original = scene.read_bytes()
    assert first.ok and first.notes == ()
    spec.write_text(spec.read_text().replace("seed = 1,", "seed = 2,"))
    second = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    assert second.built == 1 and scene.read_bytes() != original  # the new seed's building, not the old file
    meta = json.loads((tmp_path / "out" / "units" / "good__fast" / "unit.json").read_text())
    assert meta["inputs"]["scene"]["generated"]["seed"] == 2 and meta["inputs"]["scene"]["sha256"] == _sha256(scene)
    regenerated = scene.read_bytes()
    scene.write_bytes(regenerated + b"/* edited */\n")
    third = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    assert scene.read_bytes() == regenerated and third.reused == 1 and third.built == 0
    assert len(third.notes) == 1 and "was changed since it was generated" in third.notes[0]


def test_a_scene_made_by_an_older_generator_is_made_again(tmp_path: Path, session_env: Path) -> None:
    spec = _small_spec(tmp_path)
    assert build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False).ok
    scene, record = tmp_path / "out" / "scenes" / "good.ifc", tmp_path / "out" / "scenes" / "good.generated.json"
    current = scene.read_bytes()
    scene.write_bytes(current + b"/* what an older generator made */\n")  # the record vouches for these bytes,
    old = json.loads(record.read_text()) | {"sha256": _sha256(scene), "generator": 1}  # under another version
    record.write_text(json.dumps(old))
    again = build_dataset(load_spec(spec), tmp_path / "out", executor="serial", progress=False)
    assert scene.read_bytes() == current and again.notes == ()
    assert json.loads(record.read_text())["generator"] > 1 and again.reused == 1  # same building, unit kept


@pytest.mark.parametrize("edit", [
    lambda t: t.replace("head_deg_per_s = 360.0", "head_deg_per_s = nan"),
    lambda t: t.replace("head_deg_per_s = 360.0", "head_deg_per_s = inf"),
    lambda t: t.replace('formats = ["npy"]', 'formats = ["npy"]\nvoxel_size_m = nan'),
    lambda t: t.replace('formats = ["npy"]', 'formats = ["npy"]\n[noise]\nrange_sigma_m = inf'),
])
def test_nan_or_inf_in_a_spec_is_one_line_and_leaves_no_dataset_folder(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], edit) -> None:
    from bimscan.cli.main import main

    spec = _small_spec(tmp_path)
    spec.write_text(edit(spec.read_text()))
    assert main(["build", str(spec), str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {spec}")
    assert re.search(r"must be a number .*, got (nan|inf)", err[0]), err[0]
    assert not (tmp_path / "out").exists()

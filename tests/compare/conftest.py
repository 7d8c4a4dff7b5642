"""Fixtures of the scan-against-model tests: a small building with every class, scanned by bimscan
(so every answer is known), and moved into map coordinates as another tool would store it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

# Two stations in the L-shaped building's two wings, 0.2 m beam offset included by the scanner.
STATIONS = "x,y,height\n3.0,2.5,1.5\n9.5,7.0,1.5\n"
FAST = ("--head-speed", "120", "--no-noise")


def build_building(path: Path, tiny_model: type) -> Path:
    """An L-shaped storey (a 12 x 5 m wing and a 5 x 5 m wing), walls 0.25 m, a floor and a roof
    slab, a column, a beam under the roof and a suspended ceiling over part of the long wing: every
    class of the spc5 scheme, and no symmetry that would make its alignment ambiguous."""
    model = tiny_model("IFC4")
    w, h, s = 0.25, 3.2, 0.3
    model.add_box("IfcSlab", origin=(-w, -w, -s), size=(12 + 2 * w, 5 + 2 * w, s), predefined_type="FLOOR", name="floor A")
    model.add_box("IfcSlab", origin=(7 - w, 5 + w, -s), size=(5 + 2 * w, 5, s), predefined_type="FLOOR", name="floor B")
    model.add_box("IfcSlab", origin=(-w, -w, h), size=(12 + 2 * w, 5 + 2 * w, s), predefined_type="ROOF", name="roof A")
    model.add_box("IfcSlab", origin=(7 - w, 5 + w, h), size=(5 + 2 * w, 5, s), predefined_type="ROOF", name="roof B")
    model.add_box("IfcWall", origin=(-w, -w, 0), size=(12 + 2 * w, w, h), name="south")
    model.add_box("IfcWall", origin=(-w, 5, 0), size=(7, w, h), name="north A")
    model.add_box("IfcWall", origin=(-w, 0, 0), size=(w, 5, h), name="west")
    model.add_box("IfcWall", origin=(12, 0, 0), size=(w, 10 + w, h), name="east")
    model.add_box("IfcWall", origin=(7 - w, 5 + w, 0), size=(w, 5, h), name="west B")
    model.add_box("IfcWall", origin=(7 - w, 10, 0), size=(5 + 2 * w, w, h), name="north B")
    model.add_box("IfcColumn", origin=(4.6, 3.4, 0), size=(0.3, 0.3, h), name="column")
    model.add_box("IfcBeam", origin=(0, 2.4, h - 0.4), size=(12, 0.2, 0.4), name="beam")
    model.add_box("IfcCovering", origin=(0.5, 0.3, 2.6), size=(3.5, 1.8, 0.05), predefined_type="CEILING",
                  name="ceiling")
    fixed_global_ids(model)
    return model.write(path)


def fixed_global_ids(model) -> None:
    """GlobalIds from each entity's place in the file: IfcOpenShell draws them at random, and the
    as-built deviations a scan draws follow the GlobalId (the same test would scan differently
    each session)."""
    import uuid

    import ifcopenshell.guid

    for index, entity in enumerate(model.file.by_type("IfcRoot")):
        entity.GlobalId = ifcopenshell.guid.compress(uuid.uuid5(uuid.NAMESPACE_URL, f"bimscan-test/{index}").hex)


@pytest.fixture(scope="session")
def building_ifc(tmp_path_factory: pytest.TempPathFactory, tiny_model: type) -> Path:
    return build_building(tmp_path_factory.mktemp("compare") / "building.ifc", tiny_model)


def scan(model: Path, out: Path, *args: str, stations_csv: str = STATIONS) -> Path:
    from bimscan.cli.main import main

    stations = out.with_suffix(".stations.csv")
    stations.write_text(stations_csv)
    status = main(["scan", str(model), str(out), "--stations", str(stations), *FAST, *args])
    assert status == 0, f"scan {args} failed"
    return out


@pytest.fixture(scope="session")
def built_scan(building_ifc: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The building scanned whole."""
    return scan(building_ifc, tmp_path_factory.mktemp("compare") / "built.laz")


@pytest.fixture(scope="session")
def partial_scan(building_ifc: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The building scanned with its column and its ceiling not yet built."""
    return scan(building_ifc, tmp_path_factory.mktemp("compare") / "partial.laz", "--stage-exclude",
                "IfcColumn,IfcCovering")


def motion(seed: int, *, tilt_deg: float = 0.0) -> np.ndarray:
    """A rigid motion (4, 4) model frame -> scan frame: a heading, a map-like offset, a tilt."""
    from bimscan.compare.planes import rigid, rotation_about, rotation_z

    rng = np.random.default_rng(seed)
    rotation = rotation_z(rng.uniform(0, 2 * np.pi))
    if tilt_deg:
        rotation = rotation @ rotation_about(np.array([0.6, 0.8, 0.0]), np.radians(tilt_deg))
    return rigid(rotation, np.array([rng.uniform(-4e5, 4e5), rng.uniform(4.0e6, 5.5e6), 212.0]))


def move_as_foreign_las(scan_path: Path, out: Path, matrix: np.ndarray, *, scale: float = 0.001,
                        stations: bool = True, times: bool = False) -> Path:
    """The scan moved by ``matrix``, as another tool's LAS: 1 mm steps around a map offset, station ids
    in point_source_id (or none), the pulses' GPS times when asked, no bimscan header."""
    import laspy

    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets = np.round(matrix[:3, 3])
    header.scales = np.full(3, scale)
    with laspy.open(scan_path) as reader, laspy.open(out, mode="w", header=header) as writer:
        for points in reader.chunk_iterator(1_000_000):
            xyz = np.stack([points.x, points.y, points.z], axis=1) @ matrix[:3, :3].T + matrix[:3, 3]
            record = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
            record.x, record.y, record.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            if stations:
                record.point_source_id = points.station
            if times:
                record.gps_time = points.gps_time
            writer.write_points(record)
    return out

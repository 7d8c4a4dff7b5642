"""Fixtures for the io tests: a label scheme, a cloud header and seeded scan-like clouds."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from bimscan.types import (
    CloudHeader,
    ComponentTable,
    LabelClass,
    LabelRule,
    LabelScheme,
    PointCloud,
    Station,
)

ORIGIN = (512_300.25, 5_403_100.5, 41.0)  # a projected-coordinate origin, as real sites have


@pytest.fixture
def scheme() -> LabelScheme:
    names = ("Wall&Column", "Beam", "Covering", "Slab", "Others")
    colors = ("#c0504d", "#4f81bd", "#9bbb59", "#8064a2", "#f79646")
    return LabelScheme(
        name="spc5",
        classes=tuple(LabelClass(id=i, name=n, color=c) for i, (n, c) in enumerate(zip(names, colors, strict=True))),
        rules=(LabelRule(ifc_class="IfcWall", label="Wall&Column"), LabelRule(ifc_class="IfcSlab", label="Slab", predefined_types=("FLOOR",))),
        default_label="Others",
    )


@pytest.fixture
def components() -> ComponentTable:
    return ComponentTable(
        global_id=np.array(["2O2Fr$t4X7Zf8NOew3FLOH", "1hOSvn6df7F8_7GcBWlS2A", "0BTBFw6f90Nfh9rP1dlXr2"]),
        ifc_class=np.array(["IfcWall", "IfcBeam", "IfcSlab"]),
        predefined_type=np.array(["", "BEAM", "FLOOR"]),
        name=np.array(["Außenwand 1", "Träger, Achse B", ""]),
        storey=np.array(["EG", "EG", "OG 1"]),
        parent_class=np.array(["", "", ""]),
        label=np.array([0, 1, 3], dtype=np.uint8),
        class_ancestry={"IfcWall": ("IfcWall", "IfcBuiltElement", "IfcElement")},
    )


@pytest.fixture
def header(scheme: LabelScheme, components: ComponentTable) -> CloudHeader:
    return CloudHeader(
        scheme=scheme,
        components=components,
        stations=(Station(id=0, position=(ORIGIN[0] + 1.0, ORIGIN[1] + 2.0, ORIGIN[2] + 1.7), floor_z=ORIGIN[2], storey="EG"),
                  Station(id=1, position=(ORIGIN[0] + 9.5, ORIGIN[1] + 2.0, ORIGIN[2] + 1.7), heading_deg=90.0)),
        origin=ORIGIN,
        metadata={"scanner": "riegl_vz400", "seed": 7, "settings": {"pulse_freq_hz": 100_000.0}},
    )


# The columns of a paper-style scan (no returns, no colour): what most writer tests exercise.
SCAN_COLUMNS = ("xyz", "label", "component", "station", "intensity", "time")


def make_cloud(n: int, *, seed: int, columns: tuple[str, ...] = SCAN_COLUMNS) -> PointCloud:
    """A seeded scan-like cloud: points on the walls of a 20 x 12 x 3 m room around ORIGIN.

    ``columns``: which PointCloud columns it carries (``PointCloud.COLUMNS`` for all of them:
    return numbers of up to 4 echoes per pulse and RGB colour included).
    """
    rng = np.random.default_rng(seed)
    azimuth = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    elevation = np.tile(np.linspace(-0.7, 1.0, 97), n // 97 + 1)[:n]
    direction = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], 1)
    half = np.array([10.0, 6.0, 1.5])
    t = np.min(np.abs(half / np.where(direction == 0, 1e-12, direction)), axis=1)
    xyz = np.asarray(ORIGIN) + direction * t[:, None] + rng.normal(0.0, 0.005, (n, 3))
    cloud = PointCloud(
        xyz=xyz,
        label=rng.integers(0, 5, n).astype(np.uint8),
        component=rng.integers(-1, 3, n).astype(np.int32),
        station=(np.arange(n) * 2 // max(n, 1)).astype(np.uint16),  # station 0 then 1, as a survey streams them
        intensity=rng.integers(0, 65536, n).astype(np.uint16),
        time=np.cumsum(rng.uniform(0.0, 1e-5, n)),
    )
    extra_rng = np.random.default_rng(seed + 1_000)  # drawn apart, so the older columns keep their values
    count = extra_rng.integers(1, 5, n).astype(np.uint8)
    extra = {"number_of_returns": count, "return_number": (1 + extra_rng.integers(0, 4, n) % count).astype(np.uint8),
             "rgb": extra_rng.integers(0, 256, (n, 3)).astype(np.uint8)}
    mobile_rng = np.random.default_rng(seed + 2_000)  # a mobile scan's columns: ring, lidar, beam origin
    extra |= {"ring": mobile_rng.integers(0, 128, n).astype(np.uint8),
              "channel": mobile_rng.integers(0, 4, n).astype(np.uint8),
              "sensor_xyz": np.asarray(ORIGIN) + mobile_rng.uniform(-5.0, 5.0, (n, 3))}
    cloud = PointCloud(**{c: getattr(cloud, c) for c in SCAN_COLUMNS}, **extra)
    return PointCloud(xyz=cloud.xyz, **{c: getattr(cloud, c) for c in columns if c != "xyz"})


@pytest.fixture
def cloud_factory() -> Callable[..., PointCloud]:
    return make_cloud


def split_cloud(cloud: PointCloud, *, seed: int, low: int, high: int) -> list[PointCloud]:
    """``cloud`` cut into consecutive chunks of seeded random sizes in [low, high)."""
    rng = np.random.default_rng(seed)
    chunks, start = [], 0
    while start < len(cloud):
        stop = min(len(cloud), start + int(rng.integers(low, high)))
        chunks.append(cloud.take(slice(start, stop)))
        start = stop
    return chunks


@pytest.fixture
def chunk_splitter() -> Callable[..., list[PointCloud]]:
    return split_cloud

"""Fixtures for the learn tests: small synthetic labelled rooms made with a seeded generator,
tiny training configurations, and one tiny trained checkpoint shared by the session.

A room is a box: floor slab (Slab, 3) at z = 0, ceiling covering (Covering, 2) at the room
height, four walls (Wall&Column, 0), a downstand beam (Beam, 1) across the ceiling and two
pieces of furniture (Others, 4). Points are sampled uniformly on the surfaces with 2 mm noise,
so the classes are separable from geometry alone, like a scanned room.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch

from bimscan.io.text import write_text_cloud
from bimscan.types import PointCloud

WALL, BEAM, COVERING, SLAB, OTHERS = range(5)


def _plane(rng: np.random.Generator, n: int, origin: tuple[float, float, float],
           u: tuple[float, float, float], v: tuple[float, float, float]) -> np.ndarray:
    a, b = rng.random((n, 1)), rng.random((n, 1))
    return np.asarray(origin) + a * np.asarray(u) + b * np.asarray(v)


def _box(rng: np.random.Generator, n: int, lower: tuple[float, float, float],
         upper: tuple[float, float, float]) -> np.ndarray:
    lo, hi = np.asarray(lower), np.asarray(upper)
    size = hi - lo
    faces = [
        (lo, (size[0], 0, 0), (0, size[1], 0)), ((lo[0], lo[1], hi[2]), (size[0], 0, 0), (0, size[1], 0)),
        (lo, (size[0], 0, 0), (0, 0, size[2])), ((lo[0], hi[1], lo[2]), (size[0], 0, 0), (0, 0, size[2])),
        (lo, (0, size[1], 0), (0, 0, size[2])), ((hi[0], lo[1], lo[2]), (0, size[1], 0), (0, 0, size[2])),
    ]
    parts = [_plane(rng, n // 6 + (i < n % 6), tuple(o), u, v) for i, (o, u, v) in enumerate(faces)]
    return np.concatenate(parts)


def denormals_kept() -> bool:
    """False while this thread flushes denormal floats to zero (NumPy sees the same CPU flag as PyTorch)."""
    return bool((np.array([1e-310]) * 1.0)[0] != 0.0)


def make_room(seed: int, *, size_m: tuple[float, float] = (6.0, 4.0), height_m: float = 3.0,
              points_per_m2: float = 120.0, origin: tuple[float, float] = (0.0, 0.0)) -> PointCloud:
    """A labelled room point cloud (xyz float64 metres, label uint8 in the 5 default classes)."""
    rng = np.random.default_rng(seed)
    sx, sy = size_m
    ox, oy = origin
    h = height_m
    parts: list[tuple[np.ndarray, int]] = []

    def add(points: np.ndarray, label: int) -> None:
        parts.append((points, label))

    area = sx * sy
    add(_plane(rng, int(area * points_per_m2), (ox, oy, 0.0), (sx, 0, 0), (0, sy, 0)), SLAB)
    add(_plane(rng, int(area * points_per_m2), (ox, oy, h), (sx, 0, 0), (0, sy, 0)), COVERING)
    for origin_w, u in (((ox, oy, 0.0), (sx, 0, 0)), ((ox, oy + sy, 0.0), (sx, 0, 0)),
                        ((ox, oy, 0.0), (0, sy, 0)), ((ox + sx, oy, 0.0), (0, sy, 0))):
        length = float(np.linalg.norm(u))
        add(_plane(rng, int(length * h * points_per_m2), origin_w, u, (0, 0, h)), WALL)
    beam_y = oy + sy * (0.35 + 0.3 * rng.random())
    add(_box(rng, int(sx * 1.2 * points_per_m2), (ox, beam_y, h - 0.45), (ox + sx, beam_y + 0.3, h)), BEAM)
    for _ in range(2):
        fx = ox + 0.5 + rng.random() * (sx - 2.0)
        fy = oy + 0.5 + rng.random() * (sy - 1.5)
        add(_box(rng, int(4.0 * points_per_m2), (fx, fy, 0.0), (fx + 1.2, fy + 0.7, 0.75)), OTHERS)
    xyz = np.concatenate([p for p, _ in parts])
    label = np.concatenate([np.full(len(p), c, dtype=np.uint8) for p, c in parts])
    xyz = xyz + rng.normal(scale=0.002, size=xyz.shape)
    order = rng.permutation(len(xyz))  # scans are not sorted by class
    return PointCloud(xyz=np.ascontiguousarray(xyz[order]), label=label[order])


def write_foreign_las(path: Path, cloud: PointCloud, *, classification: int | None = None) -> Path:
    """A LAS 1.4 as another tool writes it (no bimscan header): the labels in an extra dimension
    ``gt``; ``classification`` holds the labels too, or the one ASPRS class given (1 =
    unclassified) on every point."""
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.floor(cloud.xyz.min(axis=0))
    header.scales = np.array([0.001, 0.001, 0.001])
    header.add_extra_dim(laspy.ExtraBytesParams(name="gt", type=np.uint8))
    las = laspy.LasData(header)
    las.x, las.y, las.z = cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]
    las.gt = cloud.label
    las.classification = cloud.label if classification is None else np.full(len(cloud), classification, np.uint8)
    las.write(path)
    return path


TINY_CONFIG = """\
[data]
train = [{train}]
val = [{val}]

[blocks]
size_m = 2.0
points = {points}
min_points = 32
cache_points = {cache}

[eval]
stride_m = 1.0

[model]
embed_dim = 16
attention_layers = 2
fuse_dim = 32
head_dims = [32, 16]
dropout = 0.1

[train]
epochs = {epochs}
batch_size = 2
accumulation_steps = {accumulation}
max_lr = 0.01
num_workers = 0
seed = {seed}
out_dir = "{out_dir}"
"""


def write_tiny_config(
    folder: Path, *, train: list[str], val: list[str], epochs: int = 2, accumulation: int = 2,
    out_dir: str = "run", points: int = 128, seed: int = 0, name: str = "train.toml",
) -> Path:
    """A tiny-model training TOML (CPU-fast) in ``folder``; scene paths relative to it."""
    quoted = lambda paths: ", ".join(f'"{p}"' for p in paths)  # noqa: E731
    path = folder / name
    path.write_text(TINY_CONFIG.format(
        train=quoted(train), val=quoted(val), epochs=epochs, accumulation=accumulation, out_dir=out_dir,
        points=points, cache=2 * points, seed=seed,
    ), encoding="utf-8")
    return path


@pytest.fixture(autouse=True)
def single_thread_torch() -> None:
    """One torch thread: the 2-core CI machine is shared, and oversubscribed OpenMP threads
    slow the tiny models by an order of magnitude (results do not depend on it)."""
    torch.set_num_threads(1)


@pytest.fixture
def room() -> Callable[..., PointCloud]:
    """The room generator (see ``make_room``)."""
    return make_room


@pytest.fixture
def room_files(tmp_path: Path) -> dict[str, list[str]]:
    """Three training rooms and one validation room as text clouds in ``tmp_path``."""
    train = []
    for i in range(3):
        name = f"room{i}.txt"
        write_text_cloud(tmp_path / name, make_room(i, size_m=(4.0 + i, 3.0), origin=(20.0 * i, 5.0), points_per_m2=40))
        train.append(name)
    write_text_cloud(tmp_path / "real.txt", make_room(100, size_m=(4.0, 4.0), points_per_m2=40))
    return {"train": train, "val": ["real.txt"]}


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One tiny model trained for 3 epochs on three rooms (shared; read-only for tests)."""
    from bimscan.learn.train_config import load_train_config
    from bimscan.learn.train import train_model

    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("trained")
    train = []
    for i in range(3):
        write_text_cloud(folder / f"room{i}.txt", make_room(i, size_m=(4.0 + i, 3.0), points_per_m2=40))
        train.append(f"room{i}.txt")
    write_text_cloud(folder / "real.txt", make_room(100, size_m=(4.0, 4.0), points_per_m2=40))
    config, base = load_train_config(write_tiny_config(folder, train=train, val=["real.txt"], epochs=3))
    train_model(config, base_dir=base, log=lambda text: None)
    return folder


@pytest.fixture
def foreign_las() -> Callable[..., Path]:
    """The foreign LAS writer (see ``write_foreign_las``)."""
    return write_foreign_las


@pytest.fixture
def tiny_config() -> Callable[..., Path]:
    """The tiny-config writer (see ``write_tiny_config``)."""
    return write_tiny_config

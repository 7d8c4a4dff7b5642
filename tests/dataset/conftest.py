"""Fixtures for dataset tests: tiny specs and one reference build shared by the session."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

# Two one-storey generated buildings x two configurations, at a head speed that scans a
# station in one second: a few hundred thousand points per unit.
TINY_SPEC = """\
name = "tiny"
seed = 3
formats = ["laz", "npy"]
{extra}
[[scenes]]
name = "north"
generate = {{ seed = 1, storeys = 1 }}

[[scenes]]
name = "south"
generate = {{ seed = 2, storeys = 1 }}

[[configs]]
name = "sparse"
preset = "exp1"
head_deg_per_s = 360.0

[[configs]]
name = "dense"
preset = "exp3"
head_deg_per_s = 360.0
"""
UNIT_IDS = ("north__sparse", "north__dense", "south__sparse", "south__dense")


def write_tiny_spec(folder: Path, *, extra: str = "", name: str = "spec.toml") -> Path:
    """The tiny spec in ``folder`` (``extra``: more top-level TOML lines)."""
    path = folder / name
    path.write_text(TINY_SPEC.format(extra=extra), encoding="utf-8")
    return path


@dataclass(frozen=True)
class BuiltDataset:
    spec: Path
    out: Path
    report: object  # bimscan.dataset.build.BuildReport


@pytest.fixture(scope="session")
def session_env(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The session's private geometry cache (as ``private_cache``), set for session-scoped builds."""
    cache = tmp_path_factory.getbasetemp() / "bimscan-cache"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("BIMSCAN_CACHE_DIR", str(cache))
        patch.setenv("BIMSCAN_PROGRESS", "0")
        yield cache


@pytest.fixture(scope="session")
def reference_dataset(tmp_path_factory: pytest.TempPathFactory, session_env: Path) -> BuiltDataset:
    """The tiny dataset built once, uninterrupted, by the default (local, spawned) executor."""
    from bimscan.dataset.build import build_dataset
    from bimscan.dataset.spec import load_spec

    folder = tmp_path_factory.mktemp("reference")
    spec = write_tiny_spec(folder)
    report = build_dataset(load_spec(spec), folder / "out", workers=2, progress=False)
    return BuiltDataset(spec=spec, out=folder / "out", report=report)


def reproducible_files(out: Path) -> dict[str, bytes]:
    """Every file of a dataset whose bytes must not depend on the run (timings and the lock aside)."""
    files = {}
    for path in sorted(out.rglob("*")):
        if path.is_file() and path.name not in ("timings.json", ".lock", "dataset.json"):
            files[path.relative_to(out).as_posix()] = path.read_bytes()
    return files

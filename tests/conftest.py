"""Shared test fixtures: paths to the shared sample models, a private geometry cache."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_IFC = Path(__file__).resolve().parents[2] / "shared" / "data" / "ifc"


def shared_model(name: str) -> Path:
    """Path of a shared sample IFC model; skips the test when the shared folder is absent."""
    path = SHARED_IFC / name
    if not path.is_file():
        pytest.skip(f"shared sample model {path} is absent (needs ../shared/data/ifc beside the checkout)")
    return path


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Every test session gets its own geometry cache, so tests never see a stale user cache."""
    cache = tmp_path_factory.getbasetemp() / "bimscan-cache"
    monkeypatch.setenv("BIMSCAN_CACHE_DIR", str(cache))
    return cache

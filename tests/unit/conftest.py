"""Fixtures shared by the unit tests of the service and the workers: settings in a temp dir, a real SQLite
store, small clips."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from backend.settings import Settings
from backend.store import Store


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data", max_upload_mb=1, lease_s=5, max_attempts=2)


@pytest.fixture
def store(settings: Settings) -> Store:
    settings.data_path.mkdir(parents=True, exist_ok=True)
    s = Store(settings.effective_database_url, lease_s=settings.lease_s, max_attempts=settings.max_attempts)
    s.create_schema()
    yield s
    s.dispose()


@pytest.fixture
def small_clip(tmp_path: Path) -> Path:
    from workers.pipeline.clipio import write_npz

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (16, 32, 48, 3), dtype=np.uint8)
    return write_npz(tmp_path / "small.npz", rgb, fps=25.0, intrinsics=(40.0, 40.0, 24.0, 16.0))

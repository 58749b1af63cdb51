"""Contract tests share the live-service harness of the integration tests."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration"))

import service_harness as h


@pytest.fixture(scope="session")
def truth_clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A small synthetic clip and its truth (see ``service_harness.SMALL_CLIP``)."""
    path = tmp_path_factory.mktemp("clips") / "spring.npz"
    return path, h.synth_clip(path, **h.SMALL_CLIP)

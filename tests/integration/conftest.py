"""Fixtures for the integration tests: live services in each deployment mode and a ground-truth clip."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import service_harness as h


@pytest.fixture(scope="session")
def truth_clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A small synthetic clip (64 frames, 160x120, 4 Hz, 0.5 kg, held by 5 N) and its truth."""
    path = tmp_path_factory.mktemp("clips") / "spring.npz"
    truth = h.synth_clip(path, **h.SMALL_CLIP)
    return path, truth


@pytest.fixture(scope="module")
def embedded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """``eigenscope serve`` with no external server: embedded broker, SQLite job store."""
    service = h.start_embedded(tmp_path_factory.mktemp("embedded"), max_upload_mb="8")
    yield service
    service.stop()

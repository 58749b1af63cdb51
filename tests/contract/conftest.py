"""Contract tests share the live-service harness of the integration tests, and one live server.

The tests that drive a live ``eigenscope serve`` (the generated Python client, the TypeScript client under
node, the AsyncAPI client) are in the xdist group ``contract-live``: they run on one worker and share
:func:`live_service` (started once, when the first of them needs it).
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration"))

import service_harness as h

#: The mark of the tests that use :func:`live_service`.
LIVE = pytest.mark.xdist_group("contract-live")


@pytest.fixture(scope="session")
def truth_clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A small synthetic clip and its truth (see ``service_harness.SMALL_CLIP``)."""
    path = tmp_path_factory.mktemp("clips") / "spring.npz"
    return path, h.synth_clip(path, **h.SMALL_CLIP)


@pytest.fixture(scope="session")
def live_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """``eigenscope serve`` (embedded broker, SQLite, no keys) shared by the live contract tests."""
    service = h.start_embedded(tmp_path_factory.mktemp("contract-live"))
    try:
        yield service
    finally:
        service.stop()

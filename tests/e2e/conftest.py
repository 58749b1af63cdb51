"""Browser tests: Playwright for Python driving the system's Chromium (Debian's ``chromium`` package).

Nothing is downloaded: there is no ``playwright install``; ``./run test`` installs ``chromium`` with apt when
it is missing (``scripts/test_prerequisites.sh``). Without a browser the tests fail in CI (``CI=true``) and
skip visibly elsewhere.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration"))

import service_harness as h

REPO = Path(__file__).resolve().parents[2]
#: Screenshots and traces of the browser tests (gitignored; CI keeps them as artefacts).
ARTIFACTS = REPO / "test-artifacts"

CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def chromium_path() -> str | None:
    """``EIGENSCOPE_TEST_CHROMIUM``, else ``/usr/bin/chromium``, else ``chromium`` on PATH."""
    configured = os.environ.get("EIGENSCOPE_TEST_CHROMIUM")
    if configured:
        return configured if Path(configured).is_file() else None
    if Path("/usr/bin/chromium").is_file():
        return "/usr/bin/chromium"
    return shutil.which("chromium")


def _missing(what: str) -> None:
    if h.in_ci():
        pytest.fail(f"CI requires {what} (`./run test` installs it with apt)", pytrace=False)
    pytest.skip(f"{what} is missing")


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """A headless Chromium, shared by the session."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _missing("the Python package playwright (pip install -e '.[dev]')")
    executable = chromium_path()
    if executable is None:
        _missing("Chromium at /usr/bin/chromium (apt-get install -y chromium)")
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS, headless=True)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture(scope="session")
def artifacts_dir() -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS


@pytest.fixture(scope="session")
def page_clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    """A synthetic ground-truth clip (64 frames, 320x240, held by a known force) and its truth JSON."""
    path = tmp_path_factory.mktemp("clips") / "spring.npz"
    return path, h.synth_clip(path, frames=64, width=320, height=240)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[h.LiveService]:
    """``eigenscope serve`` (embedded broker, SQLite) in a temp data directory, on a free port."""
    service = h.start_embedded(tmp_path_factory.mktemp("page"), max_upload_mb="64")
    yield service
    service.stop()

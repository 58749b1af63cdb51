"""Shared pytest configuration: seeded randomness and the shared data folder."""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from pathlib import Path

# isort: off
import eigenscope  # noqa: F401 - before numpy, as in every entry point: one BLAS thread (see its __init__)

# isort: on
import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(autouse=True)
def _seeded() -> None:
    """Every test starts from the same random state."""
    random.seed(1234)
    np.random.seed(1234)  # noqa: NPY002 - legacy global state, for third-party code that uses it


@pytest.fixture(scope="session", autouse=True)
def _own_cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The command line's cache (rendered strings of figures) in a folder of the test session's, for
    every command the tests run: never the user's ``~/.cache``."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("EIGENSCOPE_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` beside the checkout. Missing in CI is a failure, locally a visible skip."""
    if not SHARED.is_dir():
        if os.environ.get("CI") == "true":
            pytest.fail(f"shared data folder {SHARED} is missing in CI")
        pytest.skip(f"shared data folder {SHARED} is missing")
    return SHARED


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Print the ground-truth accuracy table collected by the pipeline tests."""
    try:
        from tests.unit.pipeline.conftest import ACCURACY_ROWS
    except ImportError:
        return
    if not ACCURACY_ROWS:
        return
    tr = terminalreporter
    tr.section("ground-truth accuracy (relative errors; default vs the paper's recipe)")
    groups: dict[tuple[str, ...], list[dict[str, object]]] = {}
    for row in ACCURACY_ROWS:
        groups.setdefault(tuple(row), []).append(row)
    for cols, rows in groups.items():
        tr.write_line(" | ".join(f"{c:>14}" for c in cols))
        for row in rows:
            cells = []
            for c in cols:
                v = row.get(c)
                cells.append(f"{v:>14.4g}" if isinstance(v, float) else f"{v!s:>14}")
            tr.write_line(" | ".join(cells))
        tr.write_line("")

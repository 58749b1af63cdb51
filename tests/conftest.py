"""Shared pytest configuration: seeded randomness, the shared data folder, the command line run in a fresh
process, and each test's tier (from its folder)."""

from __future__ import annotations

import os
import random
import subprocess
import sys
from collections.abc import Callable, Iterator
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


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` beside the checkout. Missing in CI is a failure, locally a visible skip."""
    if not SHARED.is_dir():
        if os.environ.get("CI") == "true":
            pytest.fail(f"shared data folder {SHARED} is missing in CI")
        pytest.skip(f"shared data folder {SHARED} is missing (the real-footage tests need ../shared)")
    return SHARED


def _run_eigenscope(*args: object, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "eigenscope", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        check=False,
    )


@pytest.fixture(scope="session")
def run_eigenscope() -> Callable[..., subprocess.CompletedProcess[str]]:
    """``run_eigenscope(*args, cwd=None)``: ``python -m eigenscope ARGS`` in a fresh process, its output
    captured as text, whatever its exit status."""
    return _run_eigenscope


@pytest.fixture(scope="session")
def cli_clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A clip made by ``eigenscope synth`` (64 frames of 320x240, seed 3; its ground truth beside it in
    ``clip.truth.json``): the command line's own test clip, for the unit and the accuracy tier."""
    out = tmp_path_factory.mktemp("cli") / "clip.npz"
    done = _run_eigenscope(
        "synth", "--out", out, "--frames", 64, "--width", 320, "--height", 240, "--seed", 3
    )
    assert done.returncode == 0, done.stderr
    return out


#: Tiers by folder (``./run test --tier NAME`` or ``pytest -m NAME``): whole analyses of ground-truth scenes
#: and footage live in ``tests/accuracy``, never in ``tests/unit`` (a test there marked ``accuracy`` is an
#: error: move it).
TIERS = {
    "unit": "unit",
    "accuracy": "accuracy",
    "contract": "contract",
    "integration": "integration",
    "e2e": "e2e",
    "fuzz": "fuzz",
}
#: Under pytest-xdist (``-n 2 --dist loadgroup``, as ``scripts/test.sh`` runs it) the tests of a module that
#: starts services stay on one worker (its module-scoped services are started once), and the modules
#: that use the shared Redis test database (which the harness flushes) share one worker.
SERVICE_TIERS = ("integration", "contract", "e2e")
SHARED_REDIS = "shared-redis"


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Give each test exactly one tier marker, from its folder, dropping any other tier marker a module
    declared (the contract tests that start services were marked ``integration``): ``-m TIER`` selects
    every test once. A unit test marked ``accuracy`` stops the run: accuracy tests live in
    ``tests/accuracy``. Group the service tiers' tests by module for pytest-xdist."""
    root = Path(__file__).resolve().parent
    tiers: dict[int, str] = {}
    misplaced: list[str] = []
    for i, item in enumerate(items):
        try:
            where = item.path.resolve().relative_to(root)
        except ValueError:
            continue
        tier = TIERS.get(where.parts[0])
        if tier is None:
            continue
        if tier == "unit" and item.get_closest_marker("accuracy") is not None:
            misplaced.append(item.nodeid)
        tiers[i] = tier
        if tier in SERVICE_TIERS and item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(where.as_posix()))
    if misplaced:
        raise pytest.UsageError(
            "tests under tests/unit marked accuracy (whole analyses belong to the accuracy tier): move them "
            "to the same place under tests/accuracy, which marks its tests itself: " + ", ".join(misplaced)
        )
    names = set(TIERS.values())
    for i in tiers:
        for node in items[i].listchain():
            node.own_markers[:] = [m for m in node.own_markers if m.name not in names]
    for i, tier in tiers.items():
        items[i].add_marker(getattr(pytest.mark, tier))
        items[i].user_properties.append(("tier", tier))  # for scripts/test_report.py, via the JUnit report


#: The accuracy rows of the tests that ran, as their reports carried them (from xdist workers too).
_REPORTED_ROWS: list[dict[str, object]] = []
_ROWS_PROPERTY = "eigenscope_accuracy_row"
_rows_seen = 0


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """Hand the accuracy rows a test added (in any phase) to its report."""
    global _rows_seen
    outcome = yield
    scenes = sys.modules.get("tests.scenes")  # imported by the tests that add rows
    if scenes is None:
        return
    report = outcome.get_result()
    for row in scenes.ACCURACY_ROWS[_rows_seen:]:
        report.user_properties.append((_ROWS_PROPERTY, row))
    _rows_seen = len(scenes.ACCURACY_ROWS)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _REPORTED_ROWS.extend(value for name, value in report.user_properties if name == _ROWS_PROPERTY)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Print the ground-truth accuracy table collected by the accuracy tests."""
    if not _REPORTED_ROWS:
        return
    tr = terminalreporter
    tr.section("ground-truth accuracy (relative errors; default vs the paper's recipe)")
    groups: dict[tuple[str, ...], list[dict[str, object]]] = {}
    for row in _REPORTED_ROWS:
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

"""Fixtures of the accuracy tier (``tests/accuracy``, marked ``accuracy`` by ``tests/conftest.py``): the
``run_scene`` fixture, :func:`tests.scenes.run_scene` with the session's scene folder (each scene is
rendered and analysed once per session, by all the xdist workers together, and shared). ``shared_dir``
(real footage) and the command line's ``run_eigenscope`` and ``cli_clip``, which the unit tier uses
too, are in ``tests/conftest.py``."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tests import scenes
from tests.scenes import SceneRun


@pytest.fixture(scope="session")
def scene_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's scene folder: under pytest-xdist one for all its workers (the parent of each
    worker's base folder is the session's), so that a scene is rendered and analysed once in all."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent
    folder = base / "scenes"
    folder.mkdir(exist_ok=True)
    return folder


@pytest.fixture
def run_scene(scene_folder) -> Callable[..., SceneRun]:
    def run(scene: Any, **options: Any) -> SceneRun:
        return scenes.run_scene(scene, scene_folder, **options)

    return run

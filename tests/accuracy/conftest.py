"""Fixtures of the accuracy tier (``tests/accuracy``, marked ``accuracy`` by ``tests/conftest.py``): the
``run_scene`` fixture, :func:`tests.scenes.run_scene` with the session's scene folder (each scene is
rendered and analysed once per session and shared). ``shared_dir`` (real footage) and the command line's
``run_eigenscope`` and ``cli_clip``, which the unit tier uses too, are in ``tests/conftest.py``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from tests import scenes
from tests.scenes import SceneRun


@pytest.fixture(scope="session")
def scene_folder(tmp_path_factory: pytest.TempPathFactory):
    return tmp_path_factory.mktemp("scenes")


@pytest.fixture
def run_scene(scene_folder) -> Callable[..., SceneRun]:
    def run(scene: Any, **options: Any) -> SceneRun:
        return scenes.run_scene(scene, scene_folder, **options)

    return run

"""The ``run_scene`` fixture of the pipeline's accuracy tests: :func:`tests.scenes.run_scene` with the
session's scene folder (each scene is rendered and analysed once per session and shared)."""

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

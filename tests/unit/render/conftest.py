"""Analyses of synthetic clips to render: one object, two objects, none, and the paper's method.

Each analysis runs once per session; ``analysis_seconds`` keeps how long it took (the shortest of the
runs made), for the render-cost test.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import matplotlib.text
import pytest

from workers.pipeline.analysis import Analysis, AnalysisConfig, Excitation, analyze
from workers.pipeline.clipio import open_clip, write_npz
from workers.pipeline.synth import Scene, SceneObject, render

ONE_OBJECT = Scene(objects=(SceneObject(release_frame=8),), seed=11)
TWO_OBJECTS = Scene(
    objects=(
        SceneObject(center_px=(180.0, 240.0), size_px=(120.0, 100.0), frequency_hz=4.0, release_frame=6),
        SceneObject(
            center_px=(470.0, 240.0),
            size_px=(110.0, 120.0),
            frequency_hz=7.0,
            shape="ellipse",
            excitation="impulse",
            impulse_ns=0.3,
        ),
    ),
    seed=12,
)
NO_OBJECT = Scene(width=320, height=240, frames=64, objects=(), seed=13)
SMALL = Scene(
    width=320,
    height=240,
    frames=64,
    objects=(SceneObject(center_px=(160.0, 120.0), size_px=(80.0, 60.0)),),
    seed=14,
)


@dataclass
class Analysed:
    scene: Scene
    analysis: Analysis
    clip_path: Path
    analysis_seconds: float


def _analyse(
    scene: Scene,
    directory: Path,
    *,
    config: AnalysisConfig | None = None,
    excitation: Excitation | None = None,
    repeats: int = 1,
) -> Analysed:
    clip = render(scene)
    path = directory / f"scene-{scene.seed}.npz"
    write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
    best = float("inf")
    analysis = None
    for _ in range(repeats):
        started = time.perf_counter()
        with open_clip(path) as reader:
            analysis = analyze(reader, config=config, excitation=excitation)
        best = min(best, time.perf_counter() - started)
    assert analysis is not None
    return Analysed(scene=scene, analysis=analysis, clip_path=path, analysis_seconds=best)


@pytest.fixture(scope="session")
def one_object(tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    """640x480, 128 frames, one step-released object."""
    return _analyse(
        ONE_OBJECT, tmp_path_factory.mktemp("one"), excitation=Excitation(kind="step_release", value=10.0)
    )


@pytest.fixture(scope="session")
def two_objects(tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    """640x480: object 1 at 4 Hz (step release, with k and m), object 2 at 7 Hz (impulse)."""
    return _analyse(
        TWO_OBJECTS, tmp_path_factory.mktemp("two"), excitation=Excitation(kind="step_release", value=10.0)
    )


@pytest.fixture(scope="session")
def no_object(tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    """320x240 background only: nothing vibrates."""
    return _analyse(NO_OBJECT, tmp_path_factory.mktemp("none"))


@pytest.fixture(scope="session")
def paper(tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    """320x240 with the paper's recipe: objects carry no displacement series."""
    return _analyse(
        SMALL,
        tmp_path_factory.mktemp("paper"),
        config=AnalysisConfig(method="paper"),
        excitation=Excitation(kind="step_release", value=10.0),
    )


@pytest.fixture(scope="session")
def small(tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    """320x240 with the default method and no excitation (k and m unknown): upscaled overlay."""
    return _analyse(SMALL, tmp_path_factory.mktemp("small"))


@pytest.fixture
def texts(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every string matplotlib lays out while the test runs (every figure is drawn in this process)."""
    seen: list[str] = []
    original = matplotlib.text.Text.set_text

    def spy(self: matplotlib.text.Text, s: object) -> None:
        seen.append(str(s))
        original(self, s)

    monkeypatch.setattr(matplotlib.text.Text, "set_text", spy)
    return seen

"""Ground-truth scene runner shared by the pipeline tests."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from workers.pipeline.analysis import Analysis, AnalysisConfig, Excitation, analyze
from workers.pipeline.clipio import open_clip, write_npz
from workers.pipeline.synth import Scene, SyntheticClip, render

#: Rows printed at the end of the session (see tests/conftest.py::pytest_terminal_summary).
ACCURACY_ROWS: list[dict[str, Any]] = []


@dataclass
class SceneRun:
    clip: SyntheticClip
    analysis: Analysis
    path: Path

    def iou(self, label: int = 1, true_label: int = 1) -> float:
        ours = self.analysis.labels == label
        truth = self.clip.mask == true_label
        return float((ours & truth).sum() / max((ours | truth).sum(), 1))

    def rel(self, key: str, obj: int = 1, true_obj: int | None = None) -> float:
        truth = self.clip.truth["objects"][(true_obj or obj) - 1][key]
        ours = getattr(self.analysis.objects[obj - 1], key)
        return abs(ours - truth) / abs(truth)


def excitation_of(scene: Scene, index: int = 0) -> Excitation:
    obj = scene.objects[index]
    if obj.excitation == "impulse":
        return Excitation(kind="impulse", value=obj.impulse_ns)
    return Excitation(kind="step_release", value=obj.force_n)


@pytest.fixture
def run_scene(tmp_path: Path) -> Callable[..., SceneRun]:
    def run(
        scene: Scene,
        *,
        config: AnalysisConfig | None = None,
        excitation: Excitation | str | None = "truth",
        clip: SyntheticClip | None = None,
    ) -> SceneRun:
        clip = clip or render(scene)
        path = tmp_path / f"scene-{scene.seed}-{np.random.default_rng().integers(1 << 30)}.npz"
        write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
        exc = excitation_of(scene) if excitation == "truth" else excitation
        assert not isinstance(exc, str)
        with open_clip(path) as reader:
            analysis = analyze(reader, config=config, excitation=exc)
        return SceneRun(clip=clip, analysis=analysis, path=path)

    return run

"""Shared ground truth for the clip I/O tests: one small synthetic RGB-D scene."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from numpy.typing import NDArray

from workers.pipeline.synth import Scene, SceneObject, render

FPS = 30.0
T0_NS = 1_700_000_000_000_000_000


@dataclass(frozen=True)
class Truth:
    rgb: NDArray[np.uint8]
    depth: NDArray[np.uint16]  # millimetres
    fps: float
    intrinsics: tuple[float, float, float, float]

    @property
    def stamps_ns(self) -> NDArray[np.int64]:
        ticks = np.rint(np.arange(len(self.rgb)) * 1e9 / self.fps).astype(np.int64)
        stamps: NDArray[np.int64] = ticks + np.int64(T0_NS)
        return stamps


@pytest.fixture(scope="session")
def truth() -> Truth:
    scene = Scene(
        width=96,
        height=80,
        frames=24,
        fps=FPS,
        objects=(SceneObject(center_px=(48.0, 40.0), size_px=(30.0, 24.0), depth_m=0.8),),
        seed=3,
    )
    clip = render(scene)
    return Truth(clip.rgb, clip.depth, clip.fps, clip.intrinsics)

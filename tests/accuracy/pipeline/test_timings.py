"""An analysis reports where its time went: one entry per stage, the frame stream split into the reader's
decoding and the rest, adding up to the analysis's own time (the web page and the benchmarks sum them)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from workers.pipeline.analysis import AnalysisConfig, analyze
from workers.pipeline.clipio import open_clip, write_npz
from workers.pipeline.synth import Scene, SceneObject, render


@pytest.mark.parametrize("method", ["default", "paper"])
def test_stage_times_add_up_to_the_analysis(method: str, tmp_path: Path):
    scene = Scene(
        width=160, height=120, frames=48, objects=(SceneObject(center_px=(80, 60), size_px=(50, 40)),)
    )
    clip = render(scene)
    path = tmp_path / "clip.npz"
    write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
    with open_clip(path) as reader:
        started = time.perf_counter()
        result = analyze(reader, config=AnalysisConfig(method=method))
        elapsed = time.perf_counter() - started
    timings = result.timings_s
    assert {"decode", "flow", "spectrum", "segmentation", "mechanics"} <= set(timings)
    assert list(timings).index("decode") == list(timings).index("flow") - 1
    assert all(t >= 0 for t in timings.values()), timings
    assert timings["decode"] > 0
    assert sum(timings.values()) == pytest.approx(elapsed, abs=0.05)

"""Rendering every image costs less than a tenth of the analysis of the same clip.

The clip: 640x480, one object, 256 frames (the analysis window the pipeline uses by default,
``DEFAULT_MAX_FRAMES``; 8.5 s at 30 fps). Both sides are measured warm, as a worker process runs
them: the analysis is the faster of two runs, rendering the fastest of three after one warm-up call
(which pays matplotlib's one-off font loading), with the process's drawing process started and ready,
as it is in a worker from its second job on. The figures are printed, with the same ratio for the
128-frame clip of the other tests (for information: rendering costs the same, the analysis half).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import pytest

from tests.unit.render.conftest import ONE_OBJECT, Analysed, _analyse
from workers.pipeline.analysis import DEFAULT_MAX_FRAMES, Analysis, Excitation
from workers.pipeline.render import render_all, start_drawing_process


def render_seconds(analysis: Analysis, out: Path) -> tuple[float, float]:
    """(fastest of three warm runs, first run) of :func:`render_all`, seconds."""
    started = time.perf_counter()
    render_all(analysis, out / "warm-up")
    first = time.perf_counter() - started
    assert start_drawing_process(wait_s=60.0), "the drawing process did not start"
    render_all(analysis, out / "warm-up-2")  # the drawing process's first figures
    runs = []
    for i in range(3):
        started = time.perf_counter()
        render_all(analysis, out / f"run{i}")
        runs.append(time.perf_counter() - started)
    return min(runs), first


@pytest.mark.slow
def test_rendering_costs_under_a_tenth_of_the_analysis(
    one_object: Analysed, tmp_path: Path, tmp_path_factory: pytest.TempPathFactory
):
    clip = _analyse(
        replace(ONE_OBJECT, frames=DEFAULT_MAX_FRAMES),
        tmp_path_factory.mktemp("cost"),
        excitation=Excitation(kind="step_release", value=10.0),
        repeats=2,
    )
    a = clip.analysis
    assert a.labels.shape == (480, 640)
    assert a.frames_used == (0, DEFAULT_MAX_FRAMES)
    assert len(a.objects) == 1
    render_s, first_s = render_seconds(a, tmp_path / "256")
    ratio = render_s / clip.analysis_seconds
    short_s, _ = render_seconds(one_object.analysis, tmp_path / "128")
    print(
        f"\n256 frames: render {render_s:.3f} s (first call {first_s:.3f} s), "
        f"analysis {clip.analysis_seconds:.3f} s, ratio {ratio:.3f}"
        f"\n128 frames: render {short_s:.3f} s, analysis {one_object.analysis_seconds:.3f} s (one run), "
        f"ratio {short_s / one_object.analysis_seconds:.3f}"
    )
    assert ratio < 0.1, f"rendering took {render_s:.3f} s, analysis {clip.analysis_seconds:.3f} s"

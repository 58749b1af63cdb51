"""Benchmark: drawing every image of an analysis against the analysis itself, warm, as a worker runs them.

The clip: 640x480, one object, 256 frames (the default analysis window, 8.5 s at 30 fps). The analysis is
the faster of two runs; drawing (:func:`workers.drawing.draw_all`) the fastest of three after one warm-up
call (which pays matplotlib's import and font loading). Prints both and their ratio (it was a test that
asserted ratio < 0.1 until issue 18 moved timings out of the tests).

    python bench/render_cost.py

Timing never fails anything: this prints figures, it does not assert them.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import eigenscope  # noqa: F401 - thread settings before numpy and cv2 load


def main() -> None:
    from workers.drawing import draw_all
    from workers.pipeline.analysis import DEFAULT_MAX_FRAMES, Excitation, analyze
    from workers.pipeline.clipio import open_clip, write_npz
    from workers.pipeline.synth import Scene, SceneObject, render

    scene = Scene(objects=(SceneObject(release_frame=8),), seed=11, frames=DEFAULT_MAX_FRAMES)
    with tempfile.TemporaryDirectory(prefix="eigenscope-render-cost-") as name:
        tmp = Path(name)
        clip = render(scene)
        path = tmp / "clip.npz"
        write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
        analysis_s, analysis = float("inf"), None
        for _ in range(2):
            started = time.perf_counter()
            with open_clip(path) as reader:
                analysis = analyze(reader, excitation=Excitation(kind="step_release", value=10.0))
            analysis_s = min(analysis_s, time.perf_counter() - started)
        assert analysis is not None
        started = time.perf_counter()
        draw_all(analysis, tmp / "warm-up")
        first_s = time.perf_counter() - started
        runs = []
        for i in range(3):
            started = time.perf_counter()
            draw_all(analysis, tmp / f"run{i}")
            runs.append(time.perf_counter() - started)
    render_s = min(runs)
    print(
        f"640x480x{DEFAULT_MAX_FRAMES}: images {render_s:.3f} s (first call {first_s:.3f} s), "
        f"analysis {analysis_s:.3f} s, ratio {render_s / analysis_s:.3f}"
    )


if __name__ == "__main__":
    main()

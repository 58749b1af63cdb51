"""What drawing every image costs beside the analysis of the same clip, warm, as a worker runs them.

    python bench/render_cost.py [--frames 256]

The clip: 640x480, one object (the scene of ``tests/unit/render``), 256 frames by default (the analysis
window the pipeline uses, ``DEFAULT_MAX_FRAMES``). The analysis is the faster of two runs; drawing, the
fastest of three calls of ``render_all`` after a warm-up call (matplotlib's one-off font loading) and
with the process's drawing process started and ready, as in a worker from its second job on. Prints both
and their ratio (the issue's bound: images under a tenth of the analysis). The figure was a test
(``tests/unit/render/test_cost.py``); timings belong here, measured in one run, never failing on them.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import eigenscope  # noqa: E402, F401 - one BLAS thread, as in every entry point
from workers.pipeline.analysis import DEFAULT_MAX_FRAMES, Excitation, analyze  # noqa: E402
from workers.pipeline.clipio import open_clip, write_npz  # noqa: E402
from workers.pipeline.render import render_all, start_drawing_process  # noqa: E402
from workers.pipeline.synth import Scene, SceneObject, render  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--frames", type=int, default=DEFAULT_MAX_FRAMES)
    args = parser.parse_args(argv)
    scene = Scene(objects=(SceneObject(release_frame=8),), seed=11, frames=args.frames)
    with tempfile.TemporaryDirectory(prefix="eigenscope-render-cost-") as tmp:
        folder = Path(tmp)
        clip = render(scene)
        path = write_npz(
            folder / "clip.npz", clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics
        )
        del clip
        analysis_s = float("inf")
        for _ in range(2):
            started = time.perf_counter()
            with open_clip(path) as reader:
                analysis = analyze(reader, excitation=Excitation(kind="step_release", value=10.0))
            analysis_s = min(analysis_s, time.perf_counter() - started)
        started = time.perf_counter()
        render_all(analysis, folder / "warm-up")
        first_s = time.perf_counter() - started
        if not start_drawing_process(wait_s=60.0):
            raise SystemExit("the drawing process did not start")
        render_all(analysis, folder / "warm-up-2")  # the drawing process's first figures
        runs = []
        for i in range(3):
            started = time.perf_counter()
            render_all(analysis, folder / f"run{i}")
            runs.append(time.perf_counter() - started)
    render_s = min(runs)
    print(
        f"640x480x{args.frames}: images {render_s:.3f} s (first call {first_s:.3f} s), "
        f"analysis {analysis_s:.3f} s, ratio {render_s / analysis_s:.3f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

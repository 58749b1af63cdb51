"""The look's coarse flow (the first pass, ``workers.pipeline.look``) by DIS, as the pipeline computes it,
against a dense one-step Lucas-Kanade with a brightness offset per window, 13x cheaper a pair: a measuring
tool for issue 26's next step, not a test (it never fails, and the pipeline does not use the second flow).

    python bench/look_flow.py [--bars 8] [--rng 7] [--first-seed 100] [--no-real] [--null] [--window 5]

For each clip, both flows in turn (the look's flow swapped in this process): the objects found (frequency,
false-alarm probability per clip, pixels) and the analysis' time. Clips: random thin-bar draws as
``bench/thin_bars.py`` makes them (its :func:`draw`), the 640 x 480 x 256 scene of ``bench/pipeline.py``
and the shared 32 Hz and 128 Hz forks; with ``--null``, ``bench/null_corpus.py`` run once with each flow.

Lucas-Kanade here: the mean of the two grey frames' Sobel gradients, their change, and over each 5 x 5
window the sums of the gradients' products and of gradient times change, with the window's means taken out
(a brightness offset per window, as DIS normalises its patches' means: without it a codec's brightness
changes read as motion), then the 2 x 2 solve per pixel. One step holds for motion under about a grid
pixel. Measured 2026-12-07 night: see bench/README.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import runpy
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# isort: off
import eigenscope  # noqa: E402,F401  (thread settings before numpy's and OpenCV's pools start)

# isort: on
import cv2  # noqa: E402
import numpy as np  # noqa: E402

from bench.thin_bars import draw  # noqa: E402
from workers.pipeline import look  # noqa: E402
from workers.pipeline.analysis import analyze  # noqa: E402
from workers.pipeline.clipio import ClipOverrides, open_clip  # noqa: E402
from workers.pipeline.synth_corpus import encode, thin_bar  # noqa: E402

DIS = look._coarse_dis
FORKS = ROOT.parent / "shared" / "data" / "real" / "tuning-forks"


class LucasKanade:
    """One Gauss-Newton step of Lucas-Kanade at every pixel, with a brightness offset per window: the
    ``calc`` of an OpenCV flow (grey uint8 frames in, (h, w, 2) float32 pixels out)."""

    WINDOW = (5, 5)

    def calc(self, first: np.ndarray, second: np.ndarray, _flow: object = None) -> np.ndarray:
        a, b = first.astype(np.float32), second.astype(np.float32)
        mean = 0.5 * (a + b)
        ix = cv2.Sobel(mean, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
        iy = cv2.Sobel(mean, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
        it = b - a

        def box(x: np.ndarray) -> np.ndarray:
            return np.asarray(cv2.boxFilter(x, -1, self.WINDOW), np.float32)

        mx, my, mt = box(ix), box(iy), box(it)
        jxx, jxy, jyy = box(ix * ix) - mx * mx, box(ix * iy) - mx * my, box(iy * iy) - my * my
        bx, by = box(ix * it) - mx * mt, box(iy * it) - my * mt
        det = jxx * jyy - jxy * jxy + np.float32(1e-3)
        out = np.empty((*a.shape, 2), np.float32)
        out[..., 0] = -(jyy * bx - jxy * by) / det
        out[..., 1] = -(jxx * by - jxy * bx) / det
        return out


def use(flow: str) -> None:
    look._coarse_dis = DIS if flow == "dis" else LucasKanade  # type: ignore[assignment]


def measure(path: Path, **options: object) -> str:
    rows = []
    for flow in ("dis", "lk"):
        use(flow)
        start = time.perf_counter()
        with open_clip(path, **options) as reader:  # type: ignore[arg-type]
            analysis = analyze(reader)
        seconds = time.perf_counter() - start
        found = [
            (round(o.eigenfrequency_hz, 3), f"{o.false_alarm_probability:.1e}", o.pixel_count)
            for o in analysis.objects[:2]
        ]
        rows.append(f"{flow}: {found} {seconds:.2f} s")
    use("dis")
    return " | ".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--bars", type=int, default=8)
    parser.add_argument("--rng", type=int, default=7)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--no-real", action="store_true")
    parser.add_argument("--null", action="store_true", help="bench/null_corpus.py with each flow")
    parser.add_argument("--window", type=int, default=5, help="Lucas-Kanade's window side, grid pixels")
    args = parser.parse_args()
    LucasKanade.WINDOW = (args.window, args.window)
    folder = Path(tempfile.mkdtemp(prefix="look-flow-"))
    rng = np.random.default_rng(args.rng)
    for i in range(args.bars):
        fps, f, amplitude, codec, rate, gop, seed = draw(rng, i, first_seed=args.first_seed)
        scene = thin_bar(fps=fps, frequency_hz=f, amplitude_px=amplitude, seed=seed)
        path = encode(scene, folder / f"bar-{i}.mp4", codec=codec, bit_rate=rate, keyframe_every=gop)
        print(f"bar {fps:.0f} fps {f:.3f} Hz {amplitude:.2f} px {codec}: {measure(path)}", flush=True)
    if not args.no_real:
        clip = folder / "640x480x256.npz"
        render_clip = runpy.run_path(str(ROOT / "bench" / "pipeline.py"), run_name="bench")["_render_clip"]
        with contextlib.redirect_stdout(io.StringIO()):  # it prints the scene's truth
            render_clip("640x480x256", str(clip))
        print(f"640x480x256 (5 Hz): {measure(clip)}", flush=True)
        for f, fps in ((32, 1000), (128, 500)):
            path = FORKS / f"tuning_hz{f}_fps{fps}_50-1_640x420.mp4"
            if path.is_file():
                found = measure(path, overrides=ClipOverrides(fps=fps))
                print(f"fork {f} Hz at {fps} fps: {found}", flush=True)
    if args.null:
        for flow in ("dis", "lk"):
            print(f"\n== bench/null_corpus.py, the look's flow by {flow}", flush=True)
            use(flow)
            sys.argv = ["bench/null_corpus.py"]
            runpy.run_path(str(ROOT / "bench" / "null_corpus.py"), run_name="__main__")
        use("dis")


if __name__ == "__main__":
    main()

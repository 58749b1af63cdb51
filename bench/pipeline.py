"""Benchmark: the seed recipe (``--method paper``) against the default method, end to end.

Renders ground-truth clips of several sizes, writes them as uncompressed npz bundles, then runs
``eigenscope analyze`` on each in a fresh process (start-up, decoding and images included) and prints one
table measured in this run: wall time, real-time factor (clip duration / wall time), per-stage times, peak
memory and accuracy, for three methods per clip:

- ``default``: the default method;
- ``seed recipe``: the paper's recipe as the issue measured it (Farnebäck at full resolution one frame
  pair at a time, numpy FFT, argmax): ``--method paper --flow-threads 1``;
- ``paper, 2 flow threads``: the same recipe with its flow spread over both cores, as ``--method paper``
  runs by default here (one of this project's speed-ups, so a stricter baseline).

Each method runs ``--repeat`` times (3 by default) on each clip, one after the other; its row shows the run of
median wall time (with that run's stages and memory) and the range of all its runs, since one run on a
shared two-core machine can be a quarter off. The ratios of both paper rows' median
times to the default's are printed below each clip.

    python bench/pipeline.py                       # 320x240x64, 640x480x256, 1280x720x128
    python bench/pipeline.py --sizes 640x480x256   # the issue's target only
    python bench/pipeline.py --sizes 640x480x1024  # memory must not grow with clip length
    python bench/pipeline.py --repeat 1            # one run each, a third of the time

Timing never fails anything: this prints figures, it does not assert them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


#: Row name -> extra ``eigenscope analyze`` arguments.
RUNS = {
    "default": ["--method", "default"],
    "seed recipe": ["--method", "paper", "--flow-threads", "1"],
    "paper, 2 flow threads": ["--method", "paper"],
}


def run_analyze(clip: Path, out: Path, extra: list[str], force: float) -> dict[str, object]:
    """``eigenscope analyze`` in a fresh process, exactly as a user runs it: wall time (until the command
    exits), peak memory (the command's own maximum resident set, from ``wait4``) and the result JSON."""
    cmd = [sys.executable, "-m", "eigenscope", "analyze", str(clip), "--force-n", str(force)]
    cmd += ["--out", str(out), *extra, "--json"]
    with tempfile.TemporaryFile("w+") as stdout, tempfile.TemporaryFile("w+") as stderr:
        start = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=stdout, stderr=stderr, cwd=ROOT)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        stdout.seek(0)
        stderr.seek(0)
        text, errors = stdout.read(), stderr.read()
    if proc.returncode != 0:
        raise SystemExit(f"bench: analyze failed ({' '.join(extra)}): {errors.strip().splitlines()[-1:]}")
    result = json.loads(text)
    return {"wall_s": wall, "peak_mb": usage.ru_maxrss / 1024, "result": result}


def _write_clip(spec: str, path: Path) -> tuple[dict[str, float], float]:
    """Render the ground-truth clip ``WxHxFRAMES`` into ``path`` in a child process; (its main object's
    truth, fps). Not here: a process started by this one inherits this one's peak resident set as its
    own starting maximum (Linux keeps the high-water mark across fork and exec), so a large clip
    rendered here would show as every later analysis's peak memory."""
    done = subprocess.run(
        [sys.executable, __file__, "--write-clip", spec, str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    if done.returncode != 0:
        raise SystemExit(f"bench: rendering {spec} failed: {done.stderr.strip().splitlines()[-1:]}")
    written = json.loads(done.stdout)
    return written["truth"], float(written["fps"])


def _render_clip(spec: str, path: str) -> None:
    from workers.pipeline.clipio import write_npz
    from workers.pipeline.synth import Scene, SceneObject, render

    w, h, frames = (int(v) for v in spec.lower().split("x"))
    scale = w / 640
    obj = SceneObject(
        center_px=(w / 2, h / 2),
        size_px=(140 * scale, 110 * scale),
        frequency_hz=5.0,
        mass_kg=0.5,
        force_n=10.0,
        release_frame=10,
    )
    scene = Scene(width=w, height=h, frames=frames, objects=(obj,), seed=1)
    clip = render(scene)
    write_npz(path, clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)
    print(json.dumps({"truth": scene.truth()["objects"][0], "fps": scene.fps}))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sizes", default="320x240x64,640x480x256,1280x720x128", help="WxHxFRAMES,...")
    parser.add_argument("--no-paper", action="store_true", help="skip the seed recipe")
    parser.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="runs per method and clip; the table shows the run of median wall time and the range",
    )
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error(f"--repeat={args.repeat} must be at least 1")

    rows = []
    with tempfile.TemporaryDirectory(prefix="eigenscope-bench-") as tmp:
        for spec in args.sizes.split(","):
            path = Path(tmp) / f"clip-{spec}.npz"
            truth, fps = _write_clip(spec, path)
            frames = int(spec.lower().split("x")[2])
            duration = frames / fps
            measured = {}
            spread = {}
            for i, (name, extra) in enumerate(RUNS.items()):
                if args.no_paper and name != "default":
                    continue
                runs = [
                    run_analyze(path, Path(tmp) / f"out-{spec}-{i}-{r}", extra, 10.0)
                    for r in range(args.repeat)
                ]
                # The run of median wall time stands for the method (its stages and memory with it).
                runs.sort(key=lambda m: float(m["wall_s"]))  # type: ignore[arg-type]
                measured[name] = runs[len(runs) // 2]
                spread[name] = (float(runs[0]["wall_s"]), float(runs[-1]["wall_s"]))  # type: ignore[arg-type]
            for method, m in measured.items():
                result = m["result"]
                assert isinstance(result, dict)
                objects = result["objects"]
                obj0 = objects[0] if objects else {}
                f = obj0.get("eigenfrequency_hz")
                k = obj0.get("stiffness_n_per_m")
                row = {
                    "clip": spec,
                    "method": method,
                    "wall_s": m["wall_s"],
                    "wall_range_s": "{:.2f}-{:.2f}".format(*spread[method]),
                    "x_realtime": duration / float(m["wall_s"]),  # type: ignore[arg-type]
                    "peak_mb": m["peak_mb"],
                    "f_err_%": abs(f / truth["eigenfrequency_hz"] - 1) * 100 if f else float("nan"),
                    "k_err_%": abs(k / truth["stiffness_n_per_m"] - 1) * 100 if k else float("nan"),
                    **{f"{stage}_s": t for stage, t in result["timings_s"].items()},
                }
                rows.append(row)
            base = float(measured["default"]["wall_s"])  # type: ignore[arg-type]
            for name in ("seed recipe", "paper, 2 flow threads"):
                if name in measured:
                    ratio = float(measured[name]["wall_s"]) / base  # type: ignore[arg-type]
                    rows.append({"clip": spec, "method": f"{name} / default = {ratio:.1f}x (median runs)"})

    columns: list[str] = []
    for row in rows:
        for key in row:
            if key not in columns:
                columns.append(key)
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for row in rows:
        cells = []
        for c in columns:
            v = row.get(c, "")
            cells.append(f"{v:.3g}" if isinstance(v, float) else str(v))
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--write-clip"]:
        _render_clip(sys.argv[2], sys.argv[3])
    else:
        main()

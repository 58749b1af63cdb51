"""Benchmark: does each performance device pay its way on a figure a user sees?

Two figures, each measured in fresh processes, alternating the variants round by round (this VM is noisy:
compare medians of one run, never figures of different runs):

- ``worker``: an analysis plus its images in a warm worker: one process calls
  :func:`workers.runner.run_analysis` twice and the second call is timed;
- ``cli``: ``eigenscope analyze CLIP --out DIR`` end to end (a fresh interpreter per run, as a user runs it;
  the figure-text cache folder is warm, as on a user's second run).

A device is measured as (figure without it) / (figure with it), everything else as shipped; it pays when
it saves at least 10 % (ratio >= 1.11). Devices:

- ``drawing_process``: figures drawn by a long-lived helper process (vs all in this process);
- ``forked_children``: a child forked per render draws two figures (vs all in this process);
- ``text_cache``: the Agg canvas that composites cached bitmaps of rendered strings (vs matplotlib's);
- ``text_cache_file``: the command line's drawing process keeps its strings in a file between runs;
- ``mallopt``: glibc malloc tuning (``workers/allocator.py``);
- ``fftpack_block``: ``sys.modules["scipy.fftpack"] = None`` while pyfftw imports;
- ``hugepage_off``: ``NUMPY_MADVISE_HUGEPAGE=0``;
- ``os_exit``: the command line leaves with ``os._exit`` instead of the interpreter's teardown;
- ``drawing_child``: the command line forks a child that imports matplotlib and draws the images
  (``workers/drawing_child.py`` of commit 310e125, since removed) vs drawing them itself;
- ``gc_freeze``: the command line moves every object alive after its imports, and again after the
  analysis, out of the cyclic collector's reach (``eigenscope/_heap.py``): the collector's passes over
  the imports' objects during the analysis and the interpreter's teardown are skipped.

The bench applies the toggles itself (monkeypatching the code where the device lives, or redoing what the
device does where the code no longer has it). "shipped" is the code as it is: the removed devices
(``mallopt``, ``fftpack_block``, ``os_exit``) are off in it, and their variants add them back; a variant
that needs machinery the code does not have is reported as ``n/a``. (Until 2026-12-08 this bench's
command line left through ``os._exit`` unless a variant said otherwise, long after the command itself
stopped: its ``cli`` figures of that time measured the other devices against the command with that
device; the command as shipped was ``no_os_exit``.)

    python bench/devices.py                         # both figures, 5 rounds, 640x480x256
    python bench/devices.py --figures cli --rounds 7
    python bench/devices.py --size 320x240x128      # quicker
    python bench/devices.py --report run1.txt run2.txt  # earlier runs' tables, and all their rounds together

Timing never fails anything: this prints figures, it does not assert them.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

#: Variant name -> what it changes against "shipped" (the code as it is).
#: draw: "shipped" | "here" (every figure in the calling process) | "forked" (a forked child draws two).
VARIANTS: dict[str, dict[str, Any]] = {
    "shipped": {},
    "here": {"draw": "here"},
    "forked": {"draw": "forked"},
    "here_no_text_cache": {"draw": "here", "text_cache": False},
    "no_text_cache_file": {"cache_file": False},
    "mallopt_on": {"mallopt": True},
    "fftpack_blocked": {"fftpack_block": True},
    "hugepage_on": {"hugepage_off": False},
    "os_exit_on": {"os_exit": True},
    "no_drawing_child": {"drawing_child": False},
    "gc_thawed": {"gc_freeze": False},
}

#: Device -> (variant with it, variant without it, figures it applies to).
DEVICES: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "drawing_process": ("shipped", "here", ("worker", "cli")),
    "forked_children": ("forked", "here", ("worker", "cli")),
    "text_cache": ("here", "here_no_text_cache", ("worker", "cli")),
    "text_cache_file": ("shipped", "no_text_cache_file", ("cli",)),
    # Removed devices (issue 18): the bench adds them back to measure them again.
    "mallopt": ("mallopt_on", "shipped", ("worker", "cli")),
    # A warm worker imported pyfftw in its first analysis: the block cannot change its second one.
    "fftpack_block": ("fftpack_blocked", "shipped", ("cli",)),
    "hugepage_off": ("shipped", "hugepage_on", ("worker", "cli")),
    "os_exit": ("os_exit_on", "shipped", ("cli",)),
    "drawing_child": ("shipped", "no_drawing_child", ("cli",)),
    "gc_freeze": ("shipped", "gc_thawed", ("cli",)),
}


#: Device -> (variant with it, variant without it) in runs made while the code still had it (their variants
#: were named after the toggle that turned the device off).
_LEGACY: dict[str, tuple[str, str]] = {
    "mallopt": ("shipped", "no_mallopt"),
    "fftpack_block": ("shipped", "fftpack_loaded"),
    "os_exit": ("shipped", "no_os_exit"),
    # measured (2026-12-08) before the device was in the code, while this bench's command line still
    # left through os._exit unless told otherwise: the command without the device was "no_os_exit"
    "gc_freeze": ("gc_frozen", "no_os_exit"),
}


class UnavailableError(Exception):
    """The code no longer has what a variant toggles."""


# ------------------------------------------------------------------------------------- in the child


def _mallopt() -> None:
    """What ``workers/allocator.py`` did: serve blocks up to 32 MiB from the heap, keep 512 MiB freed."""
    import ctypes
    import ctypes.util

    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    for param, value in ((-3, 32 * 2**20), (-1, 512 * 2**20), (-2, 64 * 2**20)):
        libc.mallopt(param, value)


def _fftw_importer(block: bool) -> Any:
    import functools

    @functools.cache
    def _fftw() -> Any:
        hide = block and "scipy.fftpack" not in sys.modules
        if hide:
            sys.modules["scipy.fftpack"] = None  # type: ignore[assignment]
        try:
            import pyfftw.builders
        except ImportError:  # pragma: no cover
            return None
        finally:
            if hide and sys.modules.get("scipy.fftpack", False) is None:
                del sys.modules["scipy.fftpack"]
        return pyfftw

    return _fftw


def _apply(variant: dict[str, Any], figure: str) -> dict[str, Any]:
    """Patch this process for ``variant``; returns the keyword arguments for ``run_analysis``."""
    import importlib

    import eigenscope  # noqa: F401 - the thread settings, as every entry point
    import workers.pipeline.fft as fft

    options: dict[str, Any] = {}
    # Every process gets the bench's own copies of the small devices, so that it runs on code without them.
    with_allocator = importlib.util.find_spec("workers.allocator") is not None
    if with_allocator:
        import workers.allocator as allocator

        allocator.tune_malloc = lambda: False  # type: ignore[assignment]
    if variant.get("mallopt", False):
        _mallopt()
    if hasattr(fft, "_fftw"):
        fft._fftw = _fftw_importer(variant.get("fftpack_block", False))

    if not variant.get("drawing_child", True):
        if importlib.util.find_spec("workers.drawing_child") is None:
            raise UnavailableError("the code has no drawing child")
        from workers.drawing_child import DrawingChild

        DrawingChild.fork = classmethod(lambda cls: None)  # type: ignore[method-assign,assignment]

    draw = variant.get("draw", "shipped")
    text_cache = variant.get("text_cache", True)
    try:
        render: Any = importlib.import_module("workers.pipeline.render")
    except ImportError:
        render = None
    old = render is not None and hasattr(render, "start_drawing_process")
    if draw in ("here", "forked") or not text_cache:
        if not old:
            raise UnavailableError("the code draws every figure in the calling process, without text cache")
        else:
            if draw == "here":
                render._fork_drawer = lambda *a, **k: None
            if not text_cache:
                from matplotlib.backends.backend_agg import FigureCanvasAgg

                render.caching_canvas = lambda: FigureCanvasAgg
            import workers.runner as runner

            plain = runner.run_analysis

            def run_analysis(*args: Any, **kwargs: Any) -> Any:
                kwargs.update(drawing_process=False, draw_elsewhere=False)
                return plain(*args, **kwargs)

            runner.run_analysis = run_analysis  # type: ignore[assignment]
            render.start_drawing_process = lambda **kw: False
    return options


def _child(figure: str, name: str, clip: str, out: str, cache_dir: str) -> None:
    variant = VARIANTS[name]
    try:
        _apply(variant, figure)
    except UnavailableError as exc:
        print(json.dumps({"unavailable": str(exc)}), flush=True)
        return
    if figure == "worker":
        import workers.runner as runner

        seconds = 0.0
        for i in range(2):
            started = time.perf_counter()
            runner.run_analysis(clip, Path(out) / str(i))
            seconds = time.perf_counter() - started
        print(json.dumps({"seconds": seconds}), flush=True)
        return
    from eigenscope import cli

    try:
        from eigenscope import _heap
    except ImportError:  # code from before the device
        if not variant.get("gc_freeze", True):
            print(json.dumps({"unavailable": "no eigenscope._heap"}), flush=True)
            return
        _heap = None
    if _heap is not None and variant.get("gc_freeze", True):
        _heap.for_this_process()  # as the executable does (eigenscope.cli.console_main)
    code = cli.main(["analyze", clip, "--out", out])
    if _heap is not None:
        _heap.settle()
    sys.stdout.flush()
    if code != 0:
        raise SystemExit(code)
    if variant.get("os_exit", False):
        import logging

        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    # The interpreter's teardown: every module and array freed.
    raise SystemExit(code)


# ------------------------------------------------------------------------------------- the parent


def _run(figure: str, name: str, clip: Path, tmp: Path, cache_dir: Path) -> float | None:
    variant = VARIANTS[name]
    out = tmp / f"out-{figure}-{name}"
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ)
    env["NUMPY_MADVISE_HUGEPAGE"] = "0" if variant.get("hugepage_off", True) else "1"
    env["EIGENSCOPE_CACHE_DIR"] = str(cache_dir) if variant.get("cache_file", True) else ""
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH", "")) if p)
    argv = [sys.executable, str(Path(__file__).resolve()), "--child", figure, name, str(clip), str(out)]
    argv.append(str(cache_dir))
    started = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, env=env, check=False, cwd=tmp)
    wall = time.perf_counter() - started
    shutil.rmtree(out, ignore_errors=True)
    if done.returncode != 0:
        raise SystemExit(f"bench: {figure}/{name} failed: {done.stderr.strip()[-2000:]}")
    if figure == "cli":
        if done.stdout.startswith('{"unavailable"'):
            return None
        return wall
    reply = json.loads(done.stdout.strip().splitlines()[-1])
    return None if "unavailable" in reply else float(reply["seconds"])


def make_clip(spec: str, path: Path) -> None:
    """Render the benchmark's clip of one object (``WxHxFRAMES``) as an npz at ``path``."""
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); import eigenscope\n"
        "from workers.pipeline.clipio import write_npz\n"
        "from workers.pipeline.synth import Scene, SceneObject, render\n"
        "w, h, n = (int(v) for v in sys.argv[2].split('x'))\n"
        "s = w / 640\n"
        "obj = SceneObject(center_px=(w / 2, h / 2), size_px=(140 * s, 110 * s), frequency_hz=5.0,"
        " mass_kg=0.5, force_n=10.0, release_frame=10)\n"
        "clip = render(Scene(width=w, height=h, frames=n, objects=(obj,), seed=1))\n"
        "write_npz(sys.argv[3], clip.rgb, fps=clip.fps, depth=clip.depth, intrinsics=clip.intrinsics)\n"
    )
    subprocess.run([sys.executable, "-c", code, str(ROOT), spec, str(path)], check=True)


def _ratios(times: dict[str, list[float]], on: str, off: str) -> list[float]:
    """Per-round ratios (without / with) of a device: both runs of a round were made back to back."""
    return [b / a for a, b in zip(times[on], times[off], strict=False)]


def _report(
    figure: str,
    size: str,
    rounds: int,
    wanted: list[str],
    times: dict[str, list[float]],
    missing: set[str],
    pairs: dict[str, tuple[str, str]] | None = None,
) -> None:
    """One row per device: median seconds with and without it, and the median of the per-round ratios
    (without / with): the load of a shared machine drifts over a run, and a ratio within a round cancels
    most of that drift."""
    print(f"\n{figure} ({size}, {rounds} rounds; seconds are medians, ratio the median of per-round ratios):")
    print(f"{'device':<18}{'with':>8}{'without':>9}{'ratio':>8}{'saves':>8}  verdict")
    for d in wanted:
        on, off = pairs[d] if pairs else DEVICES[d][:2]
        if on in missing or off in missing:
            print(f"{d:<18}{'n/a':>8}{'n/a':>9}{'':>8}{'':>8}  not in this code")
            continue
        ratio = statistics.median(_ratios(times, on, off))
        a, b = statistics.median(times[on]), statistics.median(times[off])
        print(f"{d:<18}{a:8.3f}{b:9.3f}{ratio:8.3f}{1 - 1 / ratio:8.1%}  {_verdict(ratio)}")


def _verdict(ratio: float) -> str:
    return "pays (>= 10 %)" if 1 - 1 / ratio >= 0.10 else "does not pay"


def _report_files(paths: list[str]) -> None:
    """The tables of earlier runs again, from their ``raw`` lines, and per figure and device the median of
    the per-round ratios of all those runs together (more rounds, the same pairing)."""
    pooled: dict[tuple[str, str], list[float]] = {}
    for path in paths:
        for line in Path(path).read_text().splitlines():
            if not line.startswith("raw "):
                continue
            _, figure, size, rounds, data = line.split(" ", 4)
            times = json.loads(data)
            pairs = {d: (on, off) for d, (on, off, figs) in DEVICES.items() if figure in figs}
            for d, legacy in _LEGACY.items():  # runs made while the code still had the device
                if legacy[1] in times and d in pairs:
                    pairs[d] = legacy
            wanted = [d for d, (on, off) in pairs.items() if on in times and off in times]
            _report(figure, size, int(rounds), wanted, times, set(), pairs)
            for d in wanted:
                pooled.setdefault((figure, d), []).extend(_ratios(times, *pairs[d]))
    print("\nall runs together (median of every per-round ratio):")
    for (figure, d), ratios in pooled.items():
        ratio = statistics.median(ratios)
        print(f"{figure:<7}{d:<18}{len(ratios):>4} rounds{ratio:8.3f}{1 - 1 / ratio:8.1%}  {_verdict(ratio)}")


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--report":  # bench/devices.py --report RUN.txt [RUN2.txt ...]
        _report_files(sys.argv[2:])
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        _child(*sys.argv[2:7])
        return
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--figures", default="worker,cli", help="worker and/or cli, comma-separated")
    parser.add_argument(
        "--devices", default=",".join(DEVICES), help="comma-separated, of: " + ", ".join(DEVICES)
    )
    parser.add_argument("--rounds", type=int, default=5, help="runs of every variant, alternating (>= 5)")
    parser.add_argument("--size", default="640x480x256", help="clip WxHxFRAMES")
    args = parser.parse_args()
    figures = [f for f in args.figures.split(",") if f]
    devices = [d for d in args.devices.split(",") if d]
    unknown = [d for d in devices if d not in DEVICES] + [f for f in figures if f not in ("worker", "cli")]
    if unknown:
        parser.error(
            f"unknown {', '.join(unknown)}; devices are {', '.join(DEVICES)}, figures worker and cli"
        )
    with tempfile.TemporaryDirectory(prefix="eigenscope-devices-") as name:
        tmp = Path(name)
        clip = tmp / "clip.npz"
        make_clip(args.size, clip)
        cache_dir = tmp / "cache"
        cache_dir.mkdir()
        for figure in figures:
            wanted = [d for d in devices if figure in DEVICES[d][2]]
            variants = sorted({v for d in wanted for v in DEVICES[d][:2]}, key=list(VARIANTS).index)
            _run(figure, "shipped", clip, tmp, cache_dir)  # warms the page cache and the text-cache file
            times: dict[str, list[float]] = {v: [] for v in variants}
            missing: set[str] = set()
            for r in range(args.rounds):
                order = variants if r % 2 == 0 else variants[::-1]  # alternate the order round by round
                for v in order:
                    if v in missing:
                        continue
                    seconds = _run(figure, v, clip, tmp, cache_dir)
                    print(f"  {figure} {v}: {seconds}", file=sys.stderr, flush=True)
                    if seconds is None:
                        missing.add(v)
                    else:
                        times[v].append(seconds)
                print(f"{figure} round {r + 1}/{args.rounds} done", file=sys.stderr, flush=True)
            _report(figure, args.size, args.rounds, wanted, times, missing)
            raw = json.dumps({v: [round(t, 3) for t in ts] for v, ts in times.items()})
            print(f"raw {figure} {args.size} {args.rounds} {raw}", flush=True)


if __name__ == "__main__":
    main()

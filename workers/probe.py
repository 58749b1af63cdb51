"""Validate a clip in a short-lived, resource-limited process: ``python -m workers.probe PATH``.

The API never opens clips itself (it must not load the readers' native libraries, and a hostile file
must not take the API down): it runs this module with a timeout. On success it prints the clip's
:class:`~workers.pipeline.clipio.ClipInfo` as one JSON object and exits 0; on failure it prints
``{"code": ..., "detail": ...}`` and exits 3 (the clip is bad) or 4 (the probe itself failed).

Resource limits (address space, CPU seconds, file size) are applied before anything heavy is imported.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from typing import Any

EXIT_BAD_CLIP = 3
EXIT_PROBE_FAILED = 4


def _limit(which: int, value: int) -> None:
    _soft, hard = resource.getrlimit(which)
    if hard != resource.RLIM_INFINITY:
        value = min(value, hard)
    resource.setrlimit(which, (value, hard if hard != resource.RLIM_INFINITY else value))


#: Largest file the probe may write when it is given no unpacking cap (it writes none but a zipped ROS 2
#: bag's storage file, unpacked for reading).
DEFAULT_FILE_CAP = 16 * 1024 * 1024


def apply_limits(*, memory_mb: int | None, cpu_s: int | None, file_bytes: int | None = None) -> None:
    """Cap this process: address space (MiB), CPU time (s), largest file written (``file_bytes``, by
    default 16 MiB; a zipped ROS 2 bag is unpacked under the same cap as in an analysis), 256 open
    files."""
    if memory_mb:
        _limit(resource.RLIMIT_AS, memory_mb * 1024 * 1024)
    if cpu_s:
        _limit(resource.RLIMIT_CPU, cpu_s)
    _limit(resource.RLIMIT_FSIZE, file_bytes or DEFAULT_FILE_CAP)
    _limit(resource.RLIMIT_NOFILE, 256)
    _limit(resource.RLIMIT_CORE, 0)


def _emit(doc: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(doc) + "\n")
    sys.stdout.flush()


def probe(path: str, args: argparse.Namespace) -> dict[str, Any]:
    """Open the clip, read its first frame and describe it as a JSON-able dict."""
    from workers.pipeline.clipio import ClipOverrides, ReadLimits, open_clip

    overrides = ClipOverrides(
        fps=args.fps, fx=args.fx, fy=args.fy, cx=args.cx, cy=args.cy, depth_scale=args.depth_scale
    )
    caps: dict[str, Any] = {}
    if args.max_frames:
        caps["max_frames"] = args.max_frames
    if args.max_pixels:
        caps["max_pixels_per_frame"] = args.max_pixels
    if args.max_decoded_mb:
        caps["max_decoded_bytes"] = args.max_decoded_mb * 1024 * 1024
    if args.max_unpacked_mb:
        caps["max_uncompressed_bytes"] = args.max_unpacked_mb * 1024 * 1024
    if args.max_inflation_ratio:
        caps["max_inflation_ratio"] = args.max_inflation_ratio
    if args.inflation_floor_mb:
        caps["inflation_floor_bytes"] = args.inflation_floor_mb * 1024 * 1024
    limits = ReadLimits(**caps)
    with open_clip(path, overrides=overrides, limits=limits, scratch_dir=args.scratch_dir) as reader:
        info = reader.info
        for _frame in reader.frames(0, 1):
            break
    k = info.intrinsics
    return {
        "format": info.format,
        "frames": int(info.frames),
        "width": int(info.width),
        "height": int(info.height),
        "fps": info.fps,
        "fps_source": info.fps_source,
        "has_depth": bool(info.has_depth),
        "depth_scale": info.depth_scale,
        "intrinsics": None if k is None else {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
        "duration_s": info.duration_s,
        "dropped_frames": int(info.dropped_frames),
        "streams": [str(s) for s in info.streams],
    }


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m workers.probe", description=__doc__.splitlines()[0])
    parser.add_argument("path")
    for name in ("fps", "fx", "fy", "cx", "cy"):
        parser.add_argument(f"--{name}", type=float, default=None)
    parser.add_argument("--depth-scale", type=float, default=None)
    parser.add_argument("--max-frames", type=int, default=None, help="most frames a clip may hold")
    parser.add_argument("--max-pixels", type=int, default=None, help="largest frame, width x height")
    parser.add_argument("--max-decoded-mb", type=int, default=None, help="most a clip may decode to, MiB")
    parser.add_argument(
        "--max-unpacked-mb", type=int, default=None, help="most a zip may expand to (and unpack), MiB"
    )
    parser.add_argument("--max-inflation-ratio", type=float, default=None, help="decompression ratio cap")
    parser.add_argument("--inflation-floor-mb", type=int, default=None, help="ratio-checked above this, MiB")
    parser.add_argument("--scratch-dir", default=None, help="where a zipped ROS 2 bag is unpacked")
    parser.add_argument("--memory-mb", type=int, default=None, help="address-space cap, MiB")
    parser.add_argument("--cpu-s", type=int, default=None, help="CPU time cap, seconds")
    parser.add_argument("--nice", type=int, default=0, help="lower this process's CPU priority by this much")
    parser.add_argument(
        "--parent-pid", type=int, default=None, help="die with this process (the API that started the probe)"
    )
    parser.add_argument("--hold-s", type=float, default=0.0, help=argparse.SUPPRESS)  # test hooks only
    return parser


def die_with_parent(parent_pid: int) -> None:
    """SIGKILL this process when its parent dies (PR_SET_PDEATHSIG), and exit now if ``parent_pid`` is
    already gone (it died before the request took effect): a crashed API leaves no validator behind."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass
    if os.getppid() != parent_pid:
        os._exit(EXIT_PROBE_FAILED)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.parent_pid is not None:
        die_with_parent(args.parent_pid)
    if args.hold_s > 0:  # the test suite's stand-in for a long validation
        time.sleep(args.hold_s)
    unpacked = args.max_unpacked_mb * 1024 * 1024 if args.max_unpacked_mb else None
    apply_limits(memory_mb=args.memory_mb, cpu_s=args.cpu_s, file_bytes=unpacked)
    if args.nice:
        os.nice(args.nice)  # validation yields the CPU to the API's requests
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    try:
        from workers.pipeline.errors import EigenscopeError
    except MemoryError:
        _emit({"code": "probe-failed", "detail": "the probe's memory cap is too small to start"})
        return EXIT_PROBE_FAILED
    try:
        info = probe(args.path, args)
    except EigenscopeError as exc:
        _emit({"code": exc.code, "detail": str(exc)})
        return EXIT_BAD_CLIP
    except MemoryError:
        _emit(
            {
                "code": "clip-too-large",
                "detail": f"reading the clip's header needed more than {args.memory_mb} MiB of memory",
            }
        )
        return EXIT_BAD_CLIP
    except Exception as exc:
        # A reader choking on a hostile or exotic file: still the clip's fault as far as the user can act.
        _emit({"code": "invalid-clip", "detail": f"the clip could not be read ({type(exc).__name__}: {exc})"})
        return EXIT_BAD_CLIP
    _emit(info)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Decode speed of every clip format on one 640x480 RGB-D clip, measured in one run.

Writes the same synthetic clip in each format (with the formats' own writer libraries), then for each
times the probe (``open_clip`` + ``info``) and streaming every frame (colour + depth in metres). Prints a
table of frames/s and the ratio to the native npz bundle. Never fails on timing.

    python bench/decode.py [--frames 120] [--width 640 --height 480]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.clipio import open_clip, write_npz
from workers.pipeline.clipio import writers as w
from workers.pipeline.synth import Scene, render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--repeat", type=int, default=2, help="best of N decode passes")
    args = ap.parse_args()

    clip = render(Scene(width=args.width, height=args.height, frames=args.frames, fps=30.0))
    rgb, depth, k = clip.rgb, clip.depth, clip.intrinsics
    n = len(rgb)
    stamps = 1_700_000_000_000_000_000 + np.rint(np.arange(n) * 1e9 / 30.0).astype(np.int64)

    cases: dict[str, Callable[[Path], tuple[Path, dict[str, Any]]]] = {
        "npz (stored)": lambda d: (write_npz(d / "c.npz", rgb, fps=30.0, depth=depth, intrinsics=k), {}),
        "npz (deflated)": lambda d: (
            write_npz(d / "z.npz", rgb, fps=30.0, depth=depth, intrinsics=k, compress=True),
            {},
        ),
        "zip-frames png+depth": lambda d: (w.write_zip_frames(d / "c.zip", rgb, depth=depth, fps=30.0), {}),
        "zip-frames jpg": lambda d: (w.write_zip_frames(d / "j.zip", rgb, fps=30.0, image_format="jpg"), {}),
        "tum png+depth": lambda d: (
            w.write_tum(d / "t.zip", rgb, depth, rgb_times_s=stamps * 1e-9, intrinsics=k),
            {},
        ),
        "video mp4 h264": lambda d: (w.write_video(d / "c.mp4", rgb, fps=30.0), {}),
        "video avi mjpeg": lambda d: (w.write_video(d / "c.avi", rgb, fps=30.0, codec="mjpeg"), {}),
        "video mkv ffv1": lambda d: (w.write_video(d / "c.mkv", rgb, fps=30.0, codec="ffv1"), {}),
        "video mp4 + depth npz": lambda d: (
            w.write_video(d / "d.mp4", rgb, fps=30.0),
            {"depth": write_npz(d / "dep.npz", rgb[:, :16, :16], fps=30.0, depth=depth)},
        ),
        "ros1 bag raw": lambda d: (
            bw.write_ros_bag(d / "c.bag", rgb, stamps_ns=stamps, intrinsics=k, depth=depth),
            {},
        ),
        "ros1 bag realsense-sdk": lambda d: (
            bw.write_ros_bag(
                d / "rs.bag",
                rgb,
                stamps_ns=stamps,
                intrinsics=k,
                depth=depth,
                options=bw.RosBagOptions(layout="realsense-sdk"),
            ),
            {},
        ),
        "ros2 mcap raw": lambda d: (
            bw.write_ros_bag(d / "m", rgb, stamps_ns=stamps, intrinsics=k, depth=depth, version=2),
            {},
        ),
        "ros2 sqlite3 raw": lambda d: (
            bw.write_ros_bag(
                d / "s",
                rgb,
                stamps_ns=stamps,
                intrinsics=k,
                depth=depth,
                version=2,
                options=bw.RosBagOptions(storage="sqlite3"),
            ),
            {},
        ),
        "ros2 mcap compressed": lambda d: (
            bw.write_ros_bag(
                d / "mc",
                rgb,
                stamps_ns=stamps,
                intrinsics=k,
                depth=depth,
                version=2,
                options=bw.RosBagOptions(compressed=True),
            ),
            {},
        ),
        "ros2 zipped mcap": lambda d: (
            bw.write_ros2_zip(d / "z.zip", rgb, stamps_ns=stamps, intrinsics=k, depth=depth),
            {},
        ),
    }

    rows = []
    with tempfile.TemporaryDirectory(prefix="eigenscope-bench-") as tmp:
        for name, make in cases.items():
            d = Path(tmp) / name.replace(" ", "_").replace("+", "")
            d.mkdir()
            path, kwargs = make(d)
            size = sum(p.stat().st_size for p in [path, *path.rglob("*")] if p.is_file())
            t = time.perf_counter()
            with open_clip(path, **kwargs) as reader:
                has_depth = reader.info.has_depth
            probe_s = time.perf_counter() - t
            best = float("inf")
            for _ in range(args.repeat):
                t = time.perf_counter()
                with open_clip(path, **kwargs) as reader:
                    count = sum(1 for _ in reader.frames())
                best = min(best, time.perf_counter() - t)
            assert count == n, (name, count)
            rows.append((name, has_depth, size, probe_s, n / best))

    base = rows[0][4]
    print(f"decode speed, {n} frames of {args.width}x{args.height} (best of {args.repeat}; includes open)")
    print(f"{'format':26s} {'depth':>5s} {'MB':>8s} {'probe ms':>9s} {'frames/s':>9s} {'vs npz':>7s}")
    for name, has_depth, size, probe_s, fps in rows:
        print(
            f"{name:26s} {'yes' if has_depth else 'no':>5s} {size / 1e6:8.1f} {probe_s * 1e3:9.1f} "
            f"{fps:9.1f} {fps / base:7.2f}"
        )


if __name__ == "__main__":
    main()

"""The fuzzer's seed corpus: one small valid clip of every format and layout the readers take.

``python tests/fuzz/seeds.py FOLDER`` writes them (about 40 files, 1-60 KB each: eight 16x16 frames,
the least a clip may hold, so the fuzzer mutates headers and structure rather than pixels).
"""

from __future__ import annotations

import sys
import tempfile
import zipfile
from pathlib import Path

# isort: off
import eigenscope  # noqa: F401 - one BLAS/OpenCV thread, as in every entry point

# isort: on
import numpy as np

FRAMES, HEIGHT, WIDTH = 16, 16, 16  # the fewest frames a clip may have (MIN_FRAMES)
INTRINSICS = (20.0, 20.0, 7.5, 7.5)
T0_NS = 1_700_000_000_000_000_000


def _clip() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    rgb = rng.integers(0, 255, (FRAMES, HEIGHT, WIDTH, 3), dtype=np.uint8)
    depth = rng.integers(500, 1500, (FRAMES, HEIGHT, WIDTH), dtype=np.uint16)
    return rgb, depth


def write_seeds(folder: Path) -> list[Path]:
    """Write the seed clips into ``folder``; returns their paths."""
    from workers.pipeline.clipio import bag_writer as bw
    from workers.pipeline.clipio import write_npz
    from workers.pipeline.clipio import writers as w

    folder.mkdir(parents=True, exist_ok=True)
    rgb, depth = _clip()
    stamps = T0_NS + np.arange(FRAMES, dtype=np.int64) * 33_333_333
    out: list[Path] = []
    out.append(write_npz(folder / "plain.npz", rgb, fps=30.0))
    out.append(
        write_npz(folder / "depth.npz", rgb, fps=30.0, depth=depth, intrinsics=INTRINSICS, depth_scale=0.001)
    )
    out.append(
        write_npz(
            folder / "deflated.npz",
            rgb,
            fps=30.0,
            depth=depth.astype(np.float32) / 1000,
            timestamps=np.arange(FRAMES) / 30.0,
            compress=True,
        )
    )
    out.append(
        w.write_zip_frames(folder / "frames-png.zip", rgb, depth=depth, fps=30.0, intrinsics=INTRINSICS)
    )
    out.append(
        w.write_zip_frames(folder / "frames-jpg.zip", rgb, fps=30.0, image_format="jpg", root="take1/")
    )
    out.append(w.write_open3d(folder / "open3d.zip", rgb, depth=depth, intrinsics=INTRINSICS, fps=30.0))
    out.append(w.write_k4a_mkv(folder / "kinect.mkv", rgb, depth=depth, fps=30.0, intrinsics=INTRINSICS))
    times = np.arange(FRAMES) / 30.0
    out.append(
        w.write_tum(
            folder / "tum.zip",
            rgb,
            depth,
            rgb_times_s=times,
            depth_times_s=times + 0.004,
            intrinsics=INTRINSICS,
        )
    )
    for name, codec in (
        ("h264.mp4", "libx264"),
        ("ffv1.mkv", "ffv1"),
        ("mjpeg.avi", "mjpeg"),
        ("mpeg4.mov", "mpeg4"),
    ):
        out.append(w.write_video(folder / name, rgb, fps=30.0, codec=codec))
    video = folder / "ffv1.mkv"
    with zipfile.ZipFile(folder / "video-depth.zip", "w") as zf:
        zf.write(video, "clip.mkv")
        zf.writestr("camera.json", '{"fps": 30, "fx": 20, "fy": 20}')
        import cv2

        for i, d in enumerate(depth):
            zf.writestr(f"depth/{i:03d}.png", bytes(cv2.imencode(".png", d)[1]))
    out.append(folder / "video-depth.zip")
    out.append(
        bw.write_ros_bag(folder / "raw.bag", rgb, stamps_ns=stamps, intrinsics=INTRINSICS, depth=depth)
    )
    out.append(
        bw.write_ros_bag(
            folder / "compressed.bag",
            rgb,
            stamps_ns=stamps,
            intrinsics=INTRINSICS,
            options=bw.RosBagOptions(compressed=True),
        )
    )
    out.append(
        bw.write_ros_bag(
            folder / "realsense.bag",
            rgb,
            stamps_ns=stamps,
            intrinsics=INTRINSICS,
            depth=depth,
            options=bw.RosBagOptions(layout="realsense-sdk"),
        )
    )
    with tempfile.TemporaryDirectory() as tmp:
        for storage, suffix in (("mcap", ".mcap"), ("sqlite3", ".db3")):
            bag = bw.write_ros_bag(
                Path(tmp) / f"bag-{storage}",
                rgb,
                stamps_ns=stamps,
                intrinsics=INTRINSICS,
                depth=depth,
                version=2,
                options=bw.RosBagOptions(storage=storage),  # type: ignore[arg-type]
            )
            single = next(bag.glob(f"*{suffix}"))
            target = folder / f"ros2{suffix}"
            target.write_bytes(single.read_bytes())
            out.append(target)
    out.append(bw.write_ros2_zip(folder / "ros2-folder.zip", rgb, stamps_ns=stamps, intrinsics=INTRINSICS))
    write_refused_seeds(folder)
    return out


def write_refused_seeds(folder: Path) -> list[Path]:
    """Seeds the readers must refuse (not clips: :func:`write_seeds` does not return them), for the
    fuzzer to mutate around: a playlist and a concat list naming a video beside them."""
    segment = folder / "h264.mp4"
    hls = f"#EXTM3U\n#EXT-X-TARGETDURATION:10\n#EXTINF:10,\nfile://{segment}\n#EXT-X-ENDLIST\n"
    (folder / "playlist.m3u8").write_text(hls)
    (folder / "concat.txt").write_text(f"ffconcat version 1.0\nfile '{segment}'\n")
    # The corpus's zip of 50,000 one-byte frames, scaled to the fuzzer's entry cap (2,000): mutations of
    # a zip with many names keep the name lookups busy.
    with zipfile.ZipFile(folder / "many-entries.zip", "w", zipfile.ZIP_STORED) as zf:
        for i in range(1_500):
            zf.writestr(f"rgb/{i:06d}.png", b"x")
    return [folder / "playlist.m3u8", folder / "concat.txt", folder / "many-entries.zip"]


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python tests/fuzz/seeds.py FOLDER")
    for path in write_seeds(Path(sys.argv[1])):
        print(f"{path.stat().st_size:8d}  {path}")

"""Each clip format, written with its own writer library from one synthetic scene, reads back the same.

Lossless encodings (PNG, raw ROS images, FFV1 video) must return the source frames exactly; lossy ones
(JPEG, H.264, MPEG-4) close to them. Metadata (format, size, frame rate and its source, intrinsics, depth
scale, timestamps, dropped frames) must be what was written.
"""

from __future__ import annotations

import shutil
import zipfile
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from workers.pipeline.clipio import (
    ClipInfo,
    ClipOverrides,
    detect_format,
    open_clip,
    write_npz,
)
from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.clipio import writers as w
from workers.pipeline.clipio._common import align_depth_to_color, associate_nearest

MM = 0.001
T0_NS = 1_700_000_000_000_000_000
Truth = Any  # the session fixture from conftest.py


def read_all(path: Path, **kwargs: Any) -> tuple[ClipInfo, np.ndarray, np.ndarray | None, np.ndarray]:
    with open_clip(path, **kwargs) as reader:
        info = reader.info
        frames = list(reader.frames())
    assert [f.index for f in frames] == list(range(info.frames))
    rgb = np.stack([f.rgb for f in frames])
    depth = np.stack([f.depth_m for f in frames]) if info.has_depth else None  # type: ignore[misc]
    ts = np.array([f.timestamp_s for f in frames])
    for f in frames:
        assert f.rgb.dtype == np.uint8
        assert f.rgb.shape == (info.height, info.width, 3)
        if f.depth_m is not None:
            assert f.depth_m.dtype == np.float32
            assert f.depth_m.shape == (info.height, info.width)
    return info, rgb, depth, ts


def assert_depth_equal(depth_m: np.ndarray, depth_mm: np.ndarray) -> None:
    valid = depth_mm > 0
    assert np.all(np.isnan(depth_m[~valid]))
    np.testing.assert_allclose(depth_m[valid], depth_mm[valid] * MM, rtol=1e-6)


def assert_uniform(info: ClipInfo, fps: float, source: str) -> None:
    assert info.fps == pytest.approx(fps, rel=1e-6)
    assert info.fps_source == source
    assert info.dropped_frames == 0


# ------------------------------------------------------------------------------------------ npz / zip


def test_npz_reads_back_exactly(truth: Truth, tmp_path: Path) -> None:
    path = write_npz(
        tmp_path / "c.npz", truth.rgb, fps=truth.fps, depth=truth.depth, intrinsics=truth.intrinsics
    )
    assert detect_format(path) == "npz"
    info, rgb, depth, ts = read_all(path)
    assert (info.format, info.frames, info.width, info.height) == ("npz", 24, 96, 80)
    assert_uniform(info, 30.0, "bundle")
    np.testing.assert_array_equal(rgb, truth.rgb)
    assert depth is not None
    assert_depth_equal(depth, truth.depth)
    np.testing.assert_allclose(ts, np.arange(24) / 30.0)


@pytest.mark.parametrize("root", ["", "my clip/"])
def test_zip_frames_png_exact_with_camera_json(truth: Truth, tmp_path: Path, root: str) -> None:
    path = w.write_zip_frames(
        tmp_path / "c.zip", truth.rgb, depth=truth.depth, fps=30.0, intrinsics=truth.intrinsics, root=root
    )
    assert detect_format(path) == "zip-frames"
    info, rgb, depth, _ = read_all(path)
    assert info.format == "zip-frames"
    assert_uniform(info, 30.0, "bundle")
    assert info.intrinsics is not None
    assert (info.intrinsics.fx, info.intrinsics.cx) == (truth.intrinsics[0], truth.intrinsics[2])
    assert info.depth_scale == pytest.approx(MM)
    np.testing.assert_array_equal(rgb, truth.rgb)
    assert depth is not None
    assert_depth_equal(depth, truth.depth)


def test_zip_frames_jpeg_close_and_flags_fill_missing_metadata(truth: Truth, tmp_path: Path) -> None:
    path = w.write_zip_frames(tmp_path / "c.zip", truth.rgb, image_format="jpg")
    info, rgb, depth, _ = read_all(path, overrides=ClipOverrides(fps=120.0, fx=100.0))
    assert depth is None
    assert not info.has_depth
    assert_uniform(info, 120.0, "user")
    assert info.intrinsics is not None
    assert (info.intrinsics.fx, info.intrinsics.fy, info.intrinsics.cx) == (100.0, 100.0, 47.5)
    assert np.abs(rgb.astype(int) - truth.rgb).mean() < 6.0  # JPEG of a noisy texture


def test_zip_frames_natural_order(truth: Truth, tmp_path: Path) -> None:
    """frame2 comes before frame10 even though it sorts after it as text."""
    import cv2

    path = tmp_path / "c.zip"
    with zipfile.ZipFile(path, "w") as zf:
        for i, frame in enumerate(truth.rgb[:20]):
            zf.writestr(f"rgb/frame{i}.png", bytes(cv2.imencode(".png", frame[:, :, ::-1])[1]))
    _, rgb, _, _ = read_all(path, overrides=ClipOverrides(fps=30.0))
    np.testing.assert_array_equal(rgb, truth.rgb[:20])


def test_frames_folder_is_read_like_a_zip(truth: Truth, tmp_path: Path) -> None:
    path = w.write_zip_frames(tmp_path / "c.zip", truth.rgb, depth=truth.depth, fps=30.0)
    folder = tmp_path / "folder"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(folder)
    info, rgb, _, _ = read_all(folder)
    assert info.format == "zip-frames"
    np.testing.assert_array_equal(rgb, truth.rgb)


def test_frames_start_stop_window(truth: Truth, tmp_path: Path) -> None:
    path = w.write_zip_frames(tmp_path / "c.zip", truth.rgb, depth=truth.depth, fps=30.0)
    with open_clip(path) as reader:
        frames = list(reader.frames(5, 9))
    assert [f.index for f in frames] == [5, 6, 7, 8]
    np.testing.assert_array_equal(frames[0].rgb, truth.rgb[5])
    assert frames[0].timestamp_s == pytest.approx(5 / 30.0)


# ----------------------------------------------------------------------------------------------- TUM


def test_tum_pairs_by_nearest_timestamp_and_reports_drops(truth: Truth, tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    t_rgb = 1305031102.0 + np.arange(24) / 30.0 + rng.uniform(-0.002, 0.002, 24)
    keep = np.ones(24, bool)
    keep[[7, 15, 16]] = False  # three dropped colour frames
    t_depth = t_rgb + 0.009  # depth lags colour by 9 ms, as the Kinect did
    depth5000 = (truth.depth.astype(np.float64) * 5).astype(np.uint16)  # TUM units: 1/5000 m
    path = w.write_tum(
        tmp_path / "tum.zip",
        truth.rgb[keep],
        depth5000,
        rgb_times_s=t_rgb[keep],
        depth_times_s=t_depth,
        intrinsics=truth.intrinsics,
    )
    assert detect_format(path) == "tum"
    info, rgb, depth, ts = read_all(path)
    assert info.format == "tum"
    assert info.frames == 21
    assert info.fps_source == "timestamps"
    assert info.fps == pytest.approx(30.0, rel=0.01)
    assert info.measured_fps == pytest.approx(30.0, rel=0.01)
    assert info.dropped_frames == 3
    assert info.depth_scale == pytest.approx(1 / 5000)
    np.testing.assert_allclose(ts, t_rgb[keep] - t_rgb[keep][0], atol=1e-5)
    np.testing.assert_array_equal(rgb, truth.rgb[keep])
    assert depth is not None
    assert_depth_equal(depth, truth.depth[keep])


def test_tum_without_camera_json_takes_flags(truth: Truth, tmp_path: Path) -> None:
    t = 100.0 + np.arange(24) / 30.0
    path = w.write_tum(tmp_path / "tum.zip", truth.rgb, None, rgb_times_s=t)
    info, _, depth, _ = read_all(path, overrides=ClipOverrides(fx=525.0, fy=525.0, cx=47.0, cy=39.0))
    assert depth is None
    assert info.intrinsics is not None
    assert info.intrinsics.fx == 525.0


# --------------------------------------------------------------------------------------------- video


@pytest.mark.parametrize(
    ("name", "codec", "exact"),
    [
        ("c.mkv", "ffv1", True),
        ("c.mp4", "libx264", False),
        ("c.mov", "mpeg4", False),
        ("c.avi", "mjpeg", False),
    ],
)
def test_video_pyav_written(truth: Truth, tmp_path: Path, name: str, codec: str, exact: bool) -> None:
    path = w.write_video(tmp_path / name, truth.rgb, fps=30.0, codec=codec)
    assert detect_format(path) == "video"
    info, rgb, depth, ts = read_all(path)
    assert (info.format, info.frames, info.width, info.height) == ("video", 24, 96, 80)
    assert_uniform(info, 30.0, "container")
    assert depth is None
    assert info.intrinsics is None
    np.testing.assert_allclose(ts, np.arange(24) / 30.0, atol=1e-3)
    err = np.abs(rgb.astype(int) - truth.rgb).mean()
    assert err == 0 if exact else err < 8.0  # lossy 4:2:0 codecs on a noisy 96x80 texture


@pytest.mark.parametrize(
    ("name", "codec"),
    [("c.mkv", "ffv1"), ("c.mp4", "libx264"), ("c.avi", "mjpeg")],
    ids=["bgr0", "yuv", "yuvj"],
)
def test_video_grey_frames_for_a_quick_survey(truth: Truth, tmp_path: Path, name: str, codec: str) -> None:
    """``gray_frames`` copies the decoder's luma plane (or converts a packed RGB stream): the grey image
    of each frame, whatever the stride of the decoder's buffer, in order, for any frame range."""
    import cv2

    from workers.pipeline.clipio import open_clip

    path = w.write_video(tmp_path / name, truth.rgb, fps=30.0, codec=codec)
    with open_clip(path) as reader:
        grays = list(reader.gray_frames())  # type: ignore[attr-defined]
        part = list(reader.gray_frames(5, 9))  # type: ignore[attr-defined]
    assert len(grays) == 24
    assert all(g.shape == (80, 96) and g.dtype == np.uint8 for g in grays)
    expected = np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in truth.rgb]).astype(float)
    # Studio-range luma (16-235) differs from full-range grey by a gain and an offset: compare shapes.
    got = np.stack(grays).astype(float)
    for g, e in zip(got, expected, strict=True):
        assert np.corrcoef(g.ravel(), e.ravel())[0, 1] > 0.97
    np.testing.assert_array_equal(np.stack(part), np.stack(grays[5:9]))


def test_video_opencv_written_avi(truth: Truth, tmp_path: Path) -> None:
    import cv2

    path = tmp_path / "cv.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 30.0, (96, 80))
    for frame in truth.rgb:
        writer.write(np.ascontiguousarray(frame[:, :, ::-1]))
    writer.release()
    info, rgb, _, _ = read_all(path)
    assert info.frames == 24
    assert info.fps == pytest.approx(30.0)
    assert np.abs(rgb.astype(int) - truth.rgb).mean() < 6.0


def test_video_user_fps_wins_and_rescales_time(truth: Truth, tmp_path: Path) -> None:
    """A high-speed camera wrote 30 fps into the file; the true rate is 240 fps."""
    path = w.write_video(tmp_path / "c.mkv", truth.rgb, fps=30.0, codec="ffv1")
    info, _, _, ts = read_all(path, overrides=ClipOverrides(fps=240.0))
    assert info.fps == 240.0
    assert info.fps_source == "user"
    assert info.container_fps == pytest.approx(30.0)
    assert info.measured_fps == pytest.approx(30.0, rel=1e-3)
    np.testing.assert_allclose(ts, np.arange(24) / 240.0, atol=1e-4)
    assert info.duration_s == pytest.approx(23 / 240.0, rel=1e-3)


def test_video_dropped_frames_from_timestamps(truth: Truth, tmp_path: Path) -> None:
    ticks = [i for i in range(27) if i not in (5, 11, 12)][:24]  # 3 frames never written
    path = w.write_video(tmp_path / "c.mkv", truth.rgb, fps=30.0, codec="ffv1", pts=ticks, time_base=(1, 30))
    info, _, _, ts = read_all(path)
    assert info.dropped_frames == 3
    np.testing.assert_allclose(ts, np.array(ticks, float) / 30.0, atol=1e-3)


@pytest.mark.parametrize("kind", ["npz", "png-zip"])
def test_video_with_depth_companion(truth: Truth, tmp_path: Path, kind: str) -> None:
    video = w.write_video(tmp_path / "c.mkv", truth.rgb, fps=30.0, codec="ffv1")
    if kind == "npz":
        companion = tmp_path / "d.npz"
        np.savez(companion, depth=truth.depth, depth_scale=np.float64(MM))
    else:
        companion = w.write_zip_frames(tmp_path / "d.zip", truth.rgb, depth=truth.depth)
        with zipfile.ZipFile(companion) as zin, zipfile.ZipFile(tmp_path / "d2.zip", "w") as zout:
            for n in zin.namelist():
                if n.startswith("depth/"):
                    zout.writestr(n, zin.read(n))
        companion = tmp_path / "d2.zip"
    info, rgb, depth, _ = read_all(video, depth=companion, overrides=ClipOverrides(fx=80.0))
    assert info.has_depth
    assert info.depth_scale == pytest.approx(MM)
    np.testing.assert_array_equal(rgb, truth.rgb)
    assert depth is not None
    assert_depth_equal(depth, truth.depth)


def test_zip_with_video_depth_and_camera_json(truth: Truth, tmp_path: Path) -> None:
    video = w.write_video(tmp_path / "c.mp4", truth.rgb, fps=30.0)
    path = w.write_zip_frames(tmp_path / "bundle.zip", truth.rgb[:0], depth=None, fps=None)
    with zipfile.ZipFile(path, "w") as zf:
        zf.write(video, "clip.mp4")
        for i, d in enumerate(truth.depth):
            import cv2

            zf.writestr(f"depth/{i:04d}.png", bytes(cv2.imencode(".png", d)[1]))
        zf.writestr("camera.json", '{"fx": 80, "fy": 80, "cx": 47.5, "cy": 39.5, "depth_scale": 0.001}')
    assert detect_format(path) == "video"
    info, rgb, depth, _ = read_all(path)
    assert info.has_depth
    assert info.intrinsics is not None
    assert info.intrinsics.fx == 80.0
    assert depth is not None
    assert_depth_equal(depth, truth.depth)
    assert np.abs(rgb.astype(int) - truth.rgb).mean() < 6.0


# ---------------------------------------------------------------------------------------------- bags


def _bag_checks(
    info: ClipInfo, rgb: np.ndarray, depth: np.ndarray | None, truth: Truth, *, exact: bool
) -> None:
    assert (info.frames, info.width, info.height) == (24, 96, 80)
    assert_uniform(info, 30.0, "timestamps")
    assert info.intrinsics is not None
    assert info.intrinsics.fx == pytest.approx(truth.intrinsics[0])
    assert info.timestamps_s is not None
    np.testing.assert_allclose(info.timestamps_s, np.arange(24) / 30.0, atol=1e-6)
    err = np.abs(rgb.astype(int) - truth.rgb).mean()
    assert err == 0 if exact else err < 4.0
    assert depth is not None
    assert_depth_equal(depth, truth.depth)


def test_ros1_bag_realsense_ros_layout(truth: Truth, tmp_path: Path) -> None:
    path = bw.write_ros_bag(
        tmp_path / "c.bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
    )
    assert detect_format(path) == "ros1-bag"
    info, rgb, depth, _ = read_all(path)
    assert info.format == "ros1-bag"
    assert info.streams[:2] == ("/camera/color/image_raw", "/camera/aligned_depth_to_color/image_raw")
    assert info.depth_scale == pytest.approx(MM)
    _bag_checks(info, rgb, depth, truth, exact=True)


def test_ros1_bag_realsense_sdk_layout_depth_units_from_bag(truth: Truth, tmp_path: Path) -> None:
    units = 0.0001  # D405-style 0.1 mm units, stored in the bag
    depth_units = (truth.depth.astype(np.float64) * 10).astype(np.uint16)
    path = bw.write_ros_bag(
        tmp_path / "rs.bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=depth_units,
        options=bw.RosBagOptions(layout="realsense-sdk", depth_scale=units),
    )
    info, rgb, depth, _ = read_all(path)
    assert info.streams[0] == "/device_0/sensor_1/Color_0/image/data"
    assert info.depth_source == "/device_0/sensor_0/Depth_0/image/data"
    assert info.depth_scale == pytest.approx(units)
    assert "layout: realsense-sdk" in info.notes
    _bag_checks(info, rgb, depth, truth, exact=True)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ros2_bag_folder(truth: Truth, tmp_path: Path, storage: str) -> None:
    path = bw.write_ros_bag(
        tmp_path / "bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
        version=2,
        options=bw.RosBagOptions(storage=storage),  # type: ignore[arg-type]
    )
    assert detect_format(path) == "ros2-bag"
    info, rgb, depth, _ = read_all(path)
    assert info.format == "ros2-bag"
    _bag_checks(info, rgb, depth, truth, exact=True)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ros2_zipped_bag_folder(truth: Truth, tmp_path: Path, storage: str) -> None:
    path = bw.write_ros2_zip(
        tmp_path / "bag.zip",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
        options=bw.RosBagOptions(storage=storage),  # type: ignore[arg-type]
    )
    assert detect_format(path) == "ros2-bag"
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    info, rgb, depth, _ = read_all(path, scratch_dir=scratch)
    _bag_checks(info, rgb, depth, truth, exact=True)
    assert list(scratch.iterdir()) == []  # the unpacked bag is removed on close


@pytest.mark.parametrize("suffix", [".mcap", ".upload"])
def test_ros2_single_mcap_file_detected_by_content(truth: Truth, tmp_path: Path, suffix: str) -> None:
    folder = bw.write_ros_bag(
        tmp_path / "bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
        version=2,
    )
    mcap = next(folder.glob("*.mcap"))
    path = tmp_path / f"clip{suffix}"
    shutil.copy(mcap, path)
    assert detect_format(path) == "ros2-bag"
    info, rgb, depth, _ = read_all(path)
    _bag_checks(info, rgb, depth, truth, exact=True)


def test_ros2_compressed_image_and_compressed_depth(truth: Truth, tmp_path: Path) -> None:
    path = bw.write_ros_bag(
        tmp_path / "bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
        version=2,
        options=bw.RosBagOptions(compressed=True),
    )
    info, rgb, depth, _ = read_all(path)
    assert info.streams[0].endswith("/compressed")
    _bag_checks(info, rgb, depth, truth, exact=False)


def test_bag_jitter_drops_and_depth_offset(truth: Truth, tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    period = 1e9 / 30.0
    ticks = np.array([i for i in range(28) if i not in (4, 9, 10, 20)][:24])
    stamps = (T0_NS + ticks * period + rng.uniform(-2e6, 2e6, 24)).astype(np.int64)
    d_stamps = stamps + 7_000_000  # depth 7 ms late
    path = bw.write_ros_bag(
        tmp_path / "c.bag",
        truth.rgb,
        stamps_ns=stamps,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
        depth_stamps_ns=d_stamps,
    )
    info, rgb, depth, ts = read_all(path)
    assert info.frames == 24
    assert info.dropped_frames == 4
    assert info.fps == pytest.approx(30.0, rel=0.02)
    np.testing.assert_allclose(ts, (stamps - stamps[0]) * 1e-9, atol=1e-9)
    np.testing.assert_array_equal(rgb, truth.rgb)
    assert depth is not None
    assert_depth_equal(depth, truth.depth)


def test_bag_topics_by_parameter_and_depth_none(truth: Truth, tmp_path: Path) -> None:
    path = bw.write_ros_bag(
        tmp_path / "c.bag",
        truth.rgb,
        stamps_ns=truth.stamps_ns,
        intrinsics=truth.intrinsics,
        depth=truth.depth,
    )
    over = ClipOverrides(color_topic="/camera/color/image_raw", depth_topic="none")
    info, _, depth, _ = read_all(path, overrides=over)
    assert not info.has_depth
    assert depth is None
    with pytest.raises(Exception, match="not in the bag"):
        open_clip(path, overrides=ClipOverrides(color_topic="/nope"))


def test_bag_unaligned_depth_is_reprojected(truth: Truth, tmp_path: Path) -> None:
    """Depth at half resolution on a non-'aligned' topic is reprojected onto the colour grid."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    fx, fy, cx, cy = truth.intrinsics
    half = (fx / 2, fy / 2, (cx - 0.5) / 2, (cy - 0.5) / 2)
    flat = np.full((40, 48), 900, np.uint16)  # a wall at 0.9 m
    path = tmp_path / "c.bag"
    with Writer(path) as writer:
        cc = writer.add_connection("/cam/color/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        ci = writer.add_connection("/cam/color/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        dc = writer.add_connection("/cam/depth/image_rect_raw", "sensor_msgs/msg/Image", typestore=ts)
        di = writer.add_connection("/cam/depth/camera_info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        for i, stamp in enumerate(truth.stamps_ns):
            h = bw._header(ts, int(stamp), "f", True, i)
            writer.write(
                cc,
                int(stamp),
                bytes(ts.serialize_ros1(bw._image_msg(ts, h, truth.rgb[i], "rgb8"), cc.msgtype)),
            )
            writer.write(
                ci,
                int(stamp),
                bytes(
                    ts.serialize_ros1(bw._camera_info_msg(ts, h, 96, 80, truth.intrinsics, True), ci.msgtype)
                ),
            )
            writer.write(
                dc, int(stamp), bytes(ts.serialize_ros1(bw._image_msg(ts, h, flat, "16UC1"), dc.msgtype))
            )
            writer.write(
                di,
                int(stamp),
                bytes(ts.serialize_ros1(bw._camera_info_msg(ts, h, 48, 40, half, True), di.msgtype)),
            )
    info, _, depth, _ = read_all(path)
    assert any("reprojected" in n for n in info.notes)
    assert depth is not None
    assert depth.shape == (24, 80, 96)
    assert np.isfinite(depth).mean() > 0.95
    np.testing.assert_allclose(np.nanmedian(depth), 0.9, rtol=1e-6)


# --------------------------------------------------------------------------------------------- units


def test_associate_nearest() -> None:
    ref = np.array([0.0, 1.0, 2.0, 3.0])
    other = np.array([0.1, 0.9, 2.6, 10.0])
    idx, ok = associate_nearest(ref, other, 0.3)
    assert idx.tolist() == [0, 1, 2, 2]
    assert ok.tolist() == [True, True, False, False]


def test_align_depth_translation_shifts_edge() -> None:
    """A 5 cm baseline shifts a wall edge at 1 m by f * 0.05 = 5 px in the colour image."""
    depth = np.full((60, 80), np.nan, np.float32)
    depth[:, 40:] = 1.0
    k = (100.0, 100.0, 39.5, 29.5)
    out = align_depth_to_color(depth, k, k, (60, 80), None, np.array([-0.05, 0.0, 0.0]))
    row = np.isfinite(out[30])
    assert int(np.argmax(row)) == 35
    np.testing.assert_allclose(out[30, 36:70], 1.0)


def test_video_fraction_rate_declared(truth: Truth, tmp_path: Path) -> None:
    path = w.write_video(tmp_path / "c.mkv", truth.rgb, fps=float(Fraction(30000, 1001)), codec="ffv1")
    info, _, _, _ = read_all(path)
    assert info.fps == pytest.approx(29.97, rel=1e-3)


def test_frame_names_sort_by_their_ascii_numbers():
    """``²`` is a digit to Unicode but no number to int(): a name holding one sorts as text (the fuzzer
    found an Open3D zip whose frame name held one)."""
    from workers.pipeline.clipio._common import natural_key

    names = ["f10.png", "f2.png", "f\u00b2x.png", "f1.png", "g\u0663.png"]
    assert sorted(names, key=natural_key) == ["f1.png", "f2.png", "f10.png", "f\u00b2x.png", "g\u0663.png"]

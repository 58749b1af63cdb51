"""A corpus of malformed and hostile clips: each is refused with its own one-line message, writing nothing
outside the test's folder. A refusal that hangs fails on the test's timeout; how fast each is refused is
printed by ``bench/refusal.py``."""

from __future__ import annotations

import json
import os
import struct
import tempfile
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from workers.pipeline.clipio import ClipOverrides, ReadLimits, open_clip, write_npz
from workers.pipeline.clipio import bag_writer as bw
from workers.pipeline.clipio import writers as w
from workers.pipeline.errors import ClipError, ClipTooLargeError, UnsupportedFormatError

T0 = 1_700_000_000_000_000_000


def _png(img: np.ndarray) -> bytes:
    import cv2

    return bytes(cv2.imencode(".png", img)[1])


def _rgb(n: int = 20, h: int = 32, w_: int = 40) -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 255, (n, h, w_, 3), dtype=np.uint8)


def _stamps(n: int) -> np.ndarray:
    return T0 + np.arange(n, dtype=np.int64) * 33_333_333


# Each builder writes one bad clip into the folder and returns (path, open_clip kwargs).
Builder = Callable[[Path], tuple[Path, dict[str, Any]]]


def zip_slip(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "slip.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i, f in enumerate(_rgb()):
            zf.writestr(f"rgb/{i:03d}.png", _png(f))
        zf.writestr("../../evil.png", b"owned")
    return p, {}


def zip_slip_absolute(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "slip_abs.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i, f in enumerate(_rgb()):
            zf.writestr(f"rgb/{i:03d}.png", _png(f))
        info = zipfile.ZipInfo("x")
        info.filename = "/tmp/eigenscope-evil.png"
        zf.writestr(info, b"owned")
    return p, {}


def zip_bomb(d: Path) -> tuple[Path, dict[str, Any]]:
    """64 MiB of zeros deflated to ~64 KiB, against a 16 MiB cap."""
    p = d / "bomb.zip"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_DEFLATED) as zf:
        for i, f in enumerate(_rgb()):
            zf.writestr(f"rgb/{i:03d}.png", _png(f))
        zf.writestr("depth/000.png", b"\0" * (64 << 20))
    return p, {"limits": ReadLimits(max_uncompressed_bytes=16 << 20)}


def png_pixel_bomb(d: Path) -> tuple[Path, dict[str, Any]]:
    """A tiny PNG whose header claims 60000 x 60000 pixels."""
    ihdr = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", len(ihdr)) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    png = b"\x89PNG\r\n\x1a\n" + chunk + b"\0" * 64
    p = d / "pixels.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i in range(20):
            zf.writestr(f"rgb/{i:03d}.png", png)
    return p, {}


def too_many_entries(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "entries.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i in range(300):
            zf.writestr(f"rgb/{i:04d}.png", b"x")
    return p, {"limits": ReadLimits(max_entries=200)}


def truncated_npz(d: Path) -> tuple[Path, dict[str, Any]]:
    p = write_npz(d / "t.npz", _rgb(), fps=30.0)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    return p, {}


def mismatched_depth_count(d: Path) -> tuple[Path, dict[str, Any]]:
    rgb = _rgb()
    depth = np.full((10, 32, 40), 1000, np.uint16)
    p = d / "count.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i, f in enumerate(rgb):
            zf.writestr(f"rgb/{i:03d}.png", _png(f))
        for i, f in enumerate(depth):
            zf.writestr(f"depth/{i:03d}.png", _png(f))
    return p, {}


def mismatched_depth_size(d: Path) -> tuple[Path, dict[str, Any]]:
    p = w.write_zip_frames(d / "size.zip", _rgb(), depth=np.full((20, 16, 20), 900, np.uint16), fps=30.0)
    return p, {}


def mismatched_depth_npz(d: Path) -> tuple[Path, dict[str, Any]]:
    p = write_npz(d / "m.npz", _rgb(), fps=30.0, depth=np.zeros((11, 32, 40), np.uint16))
    return p, {}


def eight_bit_depth(d: Path) -> tuple[Path, dict[str, Any]]:
    p = w.write_zip_frames(d / "d8.zip", _rgb(), depth=np.full((20, 32, 40), 9, np.uint8), fps=30.0)
    return p, {}


def too_few_frames(d: Path) -> tuple[Path, dict[str, Any]]:
    return write_npz(d / "few.npz", _rgb(4), fps=30.0), {}


def nan_fps_npz(d: Path) -> tuple[Path, dict[str, Any]]:
    return write_npz(d / "nan.npz", _rgb(), fps=float("nan")), {}


def nan_fps_camera_json(d: Path) -> tuple[Path, dict[str, Any]]:
    p = w.write_zip_frames(d / "nanfps.zip", _rgb())
    with zipfile.ZipFile(p, "a") as zf:
        zf.writestr("camera.json", json.dumps({"fps": float("nan"), "fx": 500.0}))
    return p, {}


def text_named_mp4(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "notes.mp4"
    p.write_text("These are my lab notes, not a video.\n" * 20)
    return p, {}


def truncated_mp4(d: Path) -> tuple[Path, dict[str, Any]]:
    p = w.write_video(d / "cut.mp4", _rgb(24, 64, 80), fps=30.0)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 3])
    return p, {}


def kinect_depth_in_an_unknown_codec(d: Path) -> tuple[Path, dict[str, Any]]:
    """An Azure Kinect recording whose depth track's FOURCC FFmpeg has no decoder for (found by the
    fuzzer: the reader read the size of a codec that did not exist)."""
    depth = np.full((6, 32, 40), 1.0, np.float32)
    p = w.write_k4a_mkv(d / "kinect.mkv", _rgb(6), depth=depth, fps=30.0, intrinsics=(40.0, 40.0, 20.0, 16.0))
    data = p.read_bytes()
    assert data.count(b"b16g") == 1
    p.write_bytes(data.replace(b"b16g", b"zq9x"))
    return p, {}


def empty_file(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "empty.bag"
    p.write_bytes(b"")
    return p, {}


def random_bytes(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "blob.bin"
    p.write_bytes(np.random.default_rng(0).integers(0, 255, 4096, dtype=np.uint8).tobytes())
    return p, {}


def empty_bag(d: Path) -> tuple[Path, dict[str, Any]]:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    p = d / "empty.bag"
    with Writer(p) as writer:
        writer.add_connection(
            "/camera/color/image_raw", "sensor_msgs/msg/Image", typestore=get_typestore(Stores.ROS1_NOETIC)
        )
    return p, {}


def bag_without_images(d: Path) -> tuple[Path, dict[str, Any]]:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    f32 = ts.types["std_msgs/msg/Float32"]
    p = d / "noimg.bag"
    with Writer(p) as writer:
        c = writer.add_connection("/imu/temperature", "std_msgs/msg/Float32", typestore=ts)
        for i in range(20):
            writer.write(c, T0 + i, bytes(ts.serialize_ros1(f32(data=1.0), "std_msgs/msg/Float32")))
    return p, {}


def truncated_bag(d: Path) -> tuple[Path, dict[str, Any]]:
    p = bw.write_ros_bag(d / "cut.bag", _rgb(), stamps_ns=_stamps(20), intrinsics=(50, 50, 20, 16))
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    return p, {}


def empty_ros2_bag(d: Path) -> tuple[Path, dict[str, Any]]:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    p = d / "empty2"
    with Writer(p, version=9) as writer:
        writer.add_connection(
            "/camera/color/image_raw", "sensor_msgs/msg/Image", typestore=get_typestore(Stores.ROS2_HUMBLE)
        )
    return p, {}


def truncated_mcap(d: Path) -> tuple[Path, dict[str, Any]]:
    folder = bw.write_ros_bag(d / "b2", _rgb(), stamps_ns=_stamps(20), intrinsics=(50, 50, 20, 16), version=2)
    mcap = next(folder.glob("*.mcap"))
    p = d / "cut.mcap"
    p.write_bytes(mcap.read_bytes()[:-2000])
    return p, {}


def db3_topic_without_name(d: Path) -> tuple[Path, dict[str, Any]]:
    """A ROS 2 SQLite bag whose topic row has no name (found by the fuzzer)."""
    import sqlite3

    folder = bw.write_ros_bag(
        d / "b3",
        _rgb(),
        stamps_ns=_stamps(20),
        intrinsics=(50, 50, 20, 16),
        version=2,
        options=bw.RosBagOptions(storage="sqlite3"),
    )
    p = d / "noname.db3"
    p.write_bytes(next(folder.glob("*.db3")).read_bytes())
    with sqlite3.connect(p) as db:
        (create,) = db.execute("SELECT sql FROM sqlite_master WHERE name = 'topics'").fetchone()
        db.execute("ALTER TABLE topics RENAME TO topics_old")
        db.execute(create.replace("NOT NULL", ""))
        db.execute("INSERT INTO topics SELECT * FROM topics_old")
        db.execute("DROP TABLE topics_old")
        db.execute("UPDATE topics SET name = NULL")
    return p, {}


def corrupt_png_frame(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "corrupt.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i, f in enumerate(_rgb()):
            data = _png(f)
            if i == 5:
                data = data[:40] + b"\0" * (len(data) - 40)
            zf.writestr(f"rgb/{i:03d}.png", data)
    return p, {"overrides": ClipOverrides(fps=30.0)}


def zip_without_layout(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "misc.zip"
    with zipfile.ZipFile(p, "w") as zf:
        zf.writestr("README.txt", "hello")
        zf.writestr("data/values.csv", "1,2,3")
    return p, {}


def video_depth_count_mismatch(d: Path) -> tuple[Path, dict[str, Any]]:
    video = w.write_video(d / "v.mkv", _rgb(20), fps=30.0, codec="ffv1")
    comp = d / "dep.npz"
    np.savez(comp, depth=np.full((9, 32, 40), 1000, np.uint16))
    return video, {"depth": comp}


def _frames_zip(path: Path, frames: list[bytes], *, link: int | None = None) -> Path:
    """A zip of ``rgb/NNN.png`` frames; frame ``link`` a symbolic link."""
    with zipfile.ZipFile(path, "w") as zf:
        for i, data in enumerate(frames):
            info = zipfile.ZipInfo(f"rgb/{i:03d}.png")
            if i == link:
                info.external_attr = (0o120777 << 16) | 0x20
                data = b"../../../etc/passwd"
            zf.writestr(info, data)
    return path


def _mark_encrypted(path: Path, name: str) -> Path:
    """Set the 'encrypted' flag of entry ``name`` in its local and central headers (zipfile writes none)."""
    data = bytearray(path.read_bytes())
    encoded = name.encode()
    for signature, flags_at, name_at in ((b"PK\x03\x04", 6, 30), (b"PK\x01\x02", 8, 46)):
        start = 0
        while (start := data.find(signature, start)) >= 0:
            if data[start + name_at : start + name_at + len(encoded)] == encoded:
                data[start + flags_at] |= 0x1
            start += 4
    path.write_bytes(bytes(data))
    return path


def encrypted_zip_entry(d: Path) -> tuple[Path, dict[str, Any]]:
    return _mark_encrypted(_frames_zip(d / "locked.zip", [_png(f) for f in _rgb()]), "rgb/004.png"), {}


def encrypted_npz_member(d: Path) -> tuple[Path, dict[str, Any]]:
    return _mark_encrypted(write_npz(d / "locked.npz", _rgb(), fps=30.0), "rgb.npy"), {}


def symlink_entry(d: Path) -> tuple[Path, dict[str, Any]]:
    return _frames_zip(d / "link.zip", [_png(f) for f in _rgb()], link=2), {}


def fortran_order_npz(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "fortran.npz"
    np.savez(p, rgb=np.asfortranarray(_rgb()), fps=np.float64(30.0))
    return p, {}


def hundred_entry_npz(d: Path) -> tuple[Path, dict[str, Any]]:
    p = d / "many.npz"
    extra = {f"extra{i:02d}": np.zeros(1) for i in range(98)}
    np.savez(p, rgb=_rgb(), fps=np.float64(30.0), **extra)
    return p, {}


def repeated_timestamps(d: Path) -> tuple[Path, dict[str, Any]]:
    stamps = np.arange(20, dtype=np.float64) / 30.0
    stamps[6] = stamps[5]
    return write_npz(d / "repeat.npz", _rgb(), fps=30.0, timestamps=stamps), {}


def one_pixel_frames(d: Path) -> tuple[Path, dict[str, Any]]:
    return write_npz(d / "dot.npz", _rgb(16, 1, 1), fps=30.0), {}


def png_frame_bomb(d: Path) -> tuple[Path, dict[str, Any]]:
    """The review's bomb: the fourth PNG declares 16000x16000 16-bit RGB (1.5 GB decoded)."""
    from tests.unit.clipio.bombs import png_bomb_zip

    return png_bomb_zip(d / "bomb-frames.zip"), {}


def npz_deflate_bomb(d: Path) -> tuple[Path, dict[str, Any]]:
    """302 MB of zeros deflated a thousandfold into 0.3 MB (the review's bomb was 4.8 GB in 4.7 MB)."""
    from tests.unit.clipio.bombs import npz_bomb

    return npz_bomb(d / "bomb.npz", (24, 2048, 2048, 3)), {}


def frame_of_another_size(d: Path) -> tuple[Path, dict[str, Any]]:
    frames = [_png(f) for f in _rgb()]
    frames[7] = _png(_rgb(1, 64, 80)[0])
    return _frames_zip(d / "sizes.zip", frames), {}


def jpeg_frame_bomb(d: Path) -> tuple[Path, dict[str, Any]]:
    """A JPEG frame whose SOF declares 60000x60000 pixels (the data is a 40x32 image's)."""
    import cv2

    p = d / "jpeg-bomb.zip"
    with zipfile.ZipFile(p, "w") as zf:
        for i, f in enumerate(_rgb()):
            data = bytes(cv2.imencode(".jpg", f)[1])
            if i == 2:
                sof = data.index(b"\xff\xc0")
                data = data[: sof + 5] + struct.pack(">HH", 60000, 60000) + data[sof + 9 :]
            zf.writestr(f"rgb/{i:03d}.jpg", data)
    return p, {}


def many_tiny_entries(d: Path, count: int = 50_000) -> tuple[Path, dict[str, Any]]:
    """A 5 MB zip of 50,000 one-byte "frames": looking each name up in a list of all names took the
    readers 25-54 s before its refusal."""
    p = d / "many.zip"
    with zipfile.ZipFile(p, "w", zipfile.ZIP_STORED) as zf:
        for i in range(count):
            zf.writestr(f"rgb/{i:06d}.png", b"x")
    return p, {}


CORPUS: list[tuple[Builder, type[Exception], str]] = [
    (zip_slip, ClipError, "points outside the archive"),
    # The API shows the entry without its folders (no absolute path in a problem detail).
    (zip_slip_absolute, ClipError, "eigenscope-evil.png' points outside"),
    (zip_bomb, ClipTooLargeError, "expands to more than"),
    (png_pixel_bomb, ClipTooLargeError, "60000x60000 frames exceed the cap"),
    (too_many_entries, ClipTooLargeError, "lists 300 entries"),
    (truncated_npz, ClipError, "npz: t.npz is a zip archive but is corrupt or truncated"),
    (mismatched_depth_count, ClipError, "20 colour frames but 10 depth frames"),
    (mismatched_depth_size, ClipError, "depth frames are 20x16 but colour frames are 40x32"),
    (mismatched_depth_npz, ClipError, "'depth' has shape (11, 32, 40)"),
    (eight_bit_depth, ClipError, "must be a 16-bit single-channel PNG"),
    (too_few_frames, ClipError, "only 4 frames"),
    (nan_fps_npz, ClipError, "declares fps=nan"),
    (nan_fps_camera_json, ClipError, "zip-frames: the file declares fps=nan"),
    (text_named_mp4, ClipError, "notes.mp4 has a video extension but its content is not a readable video"),
    (truncated_mp4, ClipError, "video: cut.mp4 is an MP4/MOV file but is truncated or corrupt"),
    (kinect_depth_in_an_unknown_codec, ClipError, "kinect.mkv's depth track is in a codec FFmpeg cannot"),
    (empty_file, ClipError, "empty.bag is empty"),
    (random_bytes, UnsupportedFormatError, "blob.bin: not a clip format"),
    (empty_bag, ClipError, "empty.bag holds no messages"),
    (bag_without_images, ClipError, "no sensor_msgs/Image or CompressedImage topic"),
    (truncated_bag, ClipError, "ros1-bag: cut.bag cannot be read"),
    (empty_ros2_bag, ClipError, "empty2 holds no messages"),
    (truncated_mcap, ClipError, "ros2-bag: cut.mcap cannot be read"),
    (db3_topic_without_name, ClipError, "a connection has no topic name or message type"),
    (corrupt_png_frame, ClipError, "005.png: image data is corrupt"),
    (zip_without_layout, UnsupportedFormatError, "zip holds no clip layout"),
    (video_depth_count_mismatch, ClipError, "20 video frames but 9 depth maps"),
    (encrypted_zip_entry, ClipError, "entry 'rgb/004.png' is encrypted"),
    (encrypted_npz_member, ClipError, "npz: 'rgb' is encrypted"),
    (symlink_entry, ClipError, "entry 'rgb/002.png' is a symbolic link"),
    (fortran_order_npz, ClipError, "'rgb' is stored in Fortran order"),
    (hundred_entry_npz, ClipError, "npz: 100 entries"),
    (repeated_timestamps, ClipError, "timestamps are not strictly increasing (1 repeats"),
    (one_pixel_frames, ClipError, "frames of 1x1 pixels are too small"),
    (png_frame_bomb, ClipTooLargeError, "rgb/0003.png: the frame declares 16000x16000 pixels, over the cap"),
    (npz_deflate_bomb, ClipTooLargeError, "this is a decompression bomb"),
    (frame_of_another_size, ClipError, "rgb/007.png: the frame declares 80x64 pixels, but the clip is 40x32"),
    (jpeg_frame_bomb, ClipTooLargeError, "rgb/002.jpg: the frame declares 60000x60000 pixels"),
    (many_tiny_entries, ClipError, "rgb/000000.png: not a PNG or JPEG image"),
]


def _consume(path: Path, kwargs: dict[str, Any]) -> None:
    with open_clip(path, **kwargs) as reader:
        for _ in reader.frames():
            pass


def _outside_snapshot() -> set[str]:
    tmp = Path(tempfile.gettempdir())
    return {p.name for p in tmp.iterdir() if p.name.startswith("eigenscope")} | set(os.listdir("."))


@pytest.mark.timeout(30)
@pytest.mark.parametrize(("build", "error", "message"), CORPUS, ids=[c[0].__name__ for c in CORPUS])
def test_malformed_clip_is_refused(
    build: Builder, error: type[Exception], message: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    path, kwargs = build(work)
    run_dir = tmp_path / "cwd"
    run_dir.mkdir()
    monkeypatch.chdir(run_dir)
    # The readers' temporary files go to a folder of this test's (other processes use the system's).
    private_tmp = tmp_path / "tmp"
    private_tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(private_tmp))
    before = _outside_snapshot()
    listing = sorted(p.name for p in work.rglob("*"))
    with pytest.raises(error) as caught:
        _consume(path, kwargs)
    text = str(caught.value)
    assert message in text
    assert "\n" not in text
    assert _outside_snapshot() == before
    assert sorted(p.name for p in work.rglob("*")) == listing
    assert list(run_dir.iterdir()) == []
    assert not (tmp_path / "evil.png").exists()
    assert not Path("/tmp/eigenscope-evil.png").exists()


def test_every_malformed_clip_has_its_own_message(tmp_path: Path) -> None:
    messages = []
    for i, (build, _, _) in enumerate(CORPUS):
        d = tmp_path / str(i)
        d.mkdir()
        path, kwargs = build(d)
        try:
            _consume(path, kwargs)
        except ClipError as exc:
            messages.append(str(exc))
    assert len(messages) == len(CORPUS)
    assert len(set(messages)) == len(messages)


def test_video_over_the_decoded_cap_is_refused_when_opened(tmp_path: Path) -> None:
    """A video's declared size times its frame count is checked when it is opened (from the demuxed
    packets), before any frame is decoded; the decoder itself is told the pixel cap."""
    path = w.write_video(tmp_path / "long.mkv", _rgb(20), fps=30.0, codec="ffv1")
    with pytest.raises(ClipTooLargeError, match="20 frames of 40x32 decode to 0 MiB, over the cap of 0 MiB"):
        open_clip(path, limits=ReadLimits(max_decoded_bytes=40 * 32 * 3 * 10))
    with open_clip(path, limits=ReadLimits(max_decoded_bytes=40 * 32 * 3 * 20)) as reader:
        assert sum(1 for _ in reader.frames()) == 20


@pytest.mark.timeout(10)  # a generous bound: it is refused in well under a second (bench/refusal.py)
def test_a_zip_of_fifty_thousand_entries_is_refused_at_once(tmp_path: Path) -> None:
    """Frame names are looked up in constant time and the frame count is checked before any per-frame
    work (the lookups were quadratic: 5k entries 0.8 s, 20k 8.4 s, 50k 25-54 s)."""
    path, _ = many_tiny_entries(tmp_path)
    with pytest.raises(ClipError, match="not a PNG or JPEG image"):
        open_clip(path)
    with pytest.raises(ClipTooLargeError, match="50000 frames"):
        open_clip(path, limits=ReadLimits(max_frames=10_000))

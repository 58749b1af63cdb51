"""Write a clip held in memory into each format the readers accept, with the formats' own writer libraries.

Used to make sample and test clips: ``zipfile`` + OpenCV PNG/JPEG for frame zips, TUM and Open3D
datasets, PyAV (or OpenCV) for video and Azure Kinect recordings, ``rosbags`` writers for ROS 1 and ROS 2
bags. Arrays follow the clip conventions: ``rgb`` uint8 (T, H, W, 3), ``depth`` uint16 (T, H, W) in units
of ``depth_scale`` metres.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

Intr = tuple[float, float, float, float]


def _png(img: NDArray[Any]) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", img)
    assert ok
    return bytes(buf)


def _jpg(img: NDArray[Any], quality: int = 95) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return bytes(buf)


def _bgr(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    return np.ascontiguousarray(rgb[:, :, ::-1])


def _camera(fps: float | None, intrinsics: Intr | None, depth_scale: float | None) -> dict[str, float]:
    cam: dict[str, float] = {}
    if fps is not None:
        cam["fps"] = fps
    if intrinsics is not None:
        cam.update(zip(("fx", "fy", "cx", "cy"), intrinsics, strict=True))
    if depth_scale is not None:
        cam["depth_scale"] = depth_scale
    return cam


def write_zip_frames(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    depth: NDArray[np.uint16] | None = None,
    fps: float | None = None,
    intrinsics: Intr | None = None,
    depth_scale: float | None = None,
    image_format: Literal["png", "jpg"] = "png",
    root: str = "",
) -> Path:
    """Write a zip of ``rgb/NNNNNN.png|jpg`` (+ ``depth/NNNNNN.png``) and ``camera.json``.

    Parameters
    ----------
    path : path-like
    rgb : ndarray of uint8, shape (T, H, W, 3)
    depth : ndarray of uint16, shape (T, H, W), optional
    fps, intrinsics, depth_scale : optional
        Written to ``camera.json`` when given.
    image_format : ``"png"`` or ``"jpg"``
    root : str
        Folder inside the archive that holds everything (e.g. ``"clip/"``), default the top level.
    """
    path = Path(path)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        for i, frame in enumerate(rgb):
            data = _png(_bgr(frame)) if image_format == "png" else _jpg(_bgr(frame))
            zf.writestr(f"{root}rgb/{i:06d}.{image_format}", data)
            if depth is not None:
                zf.writestr(f"{root}depth/{i:06d}.png", _png(depth[i]))
        cam = _camera(fps, intrinsics, depth_scale)
        if cam:
            zf.writestr(f"{root}camera.json", json.dumps(cam))
    return path


def write_tum(
    path: str | Path,
    rgb: NDArray[np.uint8],
    depth: NDArray[np.uint16] | None,
    *,
    rgb_times_s: Sequence[float] | NDArray[np.float64],
    depth_times_s: Sequence[float] | NDArray[np.float64] | None = None,
    intrinsics: Intr | None = None,
    root: str = "rgbd_dataset_synthetic/",
) -> Path:
    """Write a zipped TUM RGB-D sequence: ``rgb.txt``, ``depth.txt``, ``rgb/``, ``depth/``, ``camera.json``.

    Depth must already be in TUM units (1/5000 m). Files are named by their timestamps, as in TUM.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    depth : ndarray of uint16, shape (Td, H, W), or None
    rgb_times_s : sequence of float, length T
        Absolute timestamps (seconds since the epoch in TUM; any origin works).
    depth_times_s : sequence of float, length Td, optional
        Defaults to ``rgb_times_s``.
    """
    path = Path(path)
    depth_times = rgb_times_s if depth_times_s is None else depth_times_s
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        lines = ["# color images", "# file: 'synthetic'", "# timestamp filename"]
        for t, frame in zip(rgb_times_s, rgb, strict=True):
            name = f"rgb/{t:.6f}.png"
            lines.append(f"{t:.6f} {name}")
            zf.writestr(root + name, _png(_bgr(frame)))
        zf.writestr(root + "rgb.txt", "\n".join(lines) + "\n")
        if depth is not None:
            lines = ["# depth maps", "# file: 'synthetic'", "# timestamp filename"]
            for t, d in zip(depth_times, depth, strict=True):
                name = f"depth/{t:.6f}.png"
                lines.append(f"{t:.6f} {name}")
                zf.writestr(root + name, _png(d))
            zf.writestr(root + "depth.txt", "\n".join(lines) + "\n")
        if intrinsics is not None:
            zf.writestr(root + "camera.json", json.dumps(_camera(None, intrinsics, None)))
    return path


def write_video(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    fps: float,
    codec: str = "libx264",
    options: dict[str, str] | None = None,
    pts: Sequence[int] | None = None,
    time_base: tuple[int, int] | None = None,
) -> Path:
    """Encode RGB frames into a video file with PyAV; the container follows the file extension.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    fps : float
        Rate declared in the stream.
    codec : str
        FFmpeg encoder (``libx264``, ``mpeg4``, ``ffv1``, ``mjpeg`` ...).
    options : dict, optional
        Encoder options; default near-lossless quality.
    pts : sequence of int, optional
        Presentation times in ``time_base`` units (for dropped frames / variable rate); default uniform.
    time_base : (num, den), optional
    """
    from fractions import Fraction

    import av

    path = Path(path)
    rate = Fraction(fps).limit_denominator(1001)
    with av.open(str(path), mode="w") as out:
        stream: Any = out.add_stream(codec, rate=rate)
        stream.width, stream.height = int(rgb.shape[2]), int(rgb.shape[1])
        stream.pix_fmt = {"ffv1": "bgr0", "mjpeg": "yuvj420p"}.get(codec, "yuv420p")
        if options is None:
            options = {
                "libx264": {"crf": "10", "preset": "veryfast"},
                "mjpeg": {"qmin": "1", "qmax": "3"},
            }.get(codec, {})
            if codec in ("mpeg4",):
                stream.bit_rate = 20_000_000
        stream.options = options
        if time_base is not None:
            stream.time_base = Fraction(*time_base)
            stream.codec_context.time_base = Fraction(*time_base)
        for i, frame in enumerate(rgb):
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
            if pts is not None:
                vf.pts = int(pts[i])
                vf.time_base = Fraction(*time_base) if time_base else stream.codec_context.time_base
            for packet in stream.encode(vf):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


def write_compressed(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    fps: float,
    codec: str = "libx264",
    bit_rate: int = 1_500_000,
    keyframe_every: int = 15,
) -> Path:
    """Encode RGB frames as a real camera's video: a lossy codec at a phone's or action camera's bit rate
    with a keyframe every ``keyframe_every`` frames (what nearly every real clip went through).

    Parameters
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    fps : float
    codec : ``"libx264"`` (H.264) or ``"mpeg4"`` (MPEG-4 part 2)
    bit_rate : int
        Bits per second (about 1-2 Mbit/s at 640 x 480 for phones and action cameras).
    keyframe_every : int
        Group of pictures, frames (12-30 in real cameras).
    """
    from fractions import Fraction

    import av

    path = Path(path)
    with av.open(str(path), mode="w") as out:
        stream: Any = out.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = int(rgb.shape[2]), int(rgb.shape[1])
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(bit_rate)
        stream.codec_context.gop_size = int(keyframe_every)
        if codec == "libx264":
            gop = str(int(keyframe_every))
            stream.options = {"preset": "veryfast", "g": gop, "keyint_min": gop, "sc_threshold": "0"}
        for frame in rgb:
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
            for packet in stream.encode(vf):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


@dataclass(frozen=True)
class Open3dOptions:
    """How :func:`write_open3d` names and places the dataset's files (the defaults are Open3D's).

    Attributes
    ----------
    image_format : ``"png"`` or ``"jpg"``
        Encoding of the colour frames.
    intrinsic_name : str
        File name of the intrinsics document (Open3D also reads ``intrinsic.json``).
    root : str
        Folder inside the dataset that holds everything (e.g. ``"clip/"``), default the top level.
    """

    image_format: Literal["png", "jpg"] = "jpg"
    intrinsic_name: str = "camera_intrinsic.json"
    root: str = ""


def write_open3d(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    depth: NDArray[np.uint16] | None = None,
    intrinsics: Intr | None = None,
    units_per_metre: float | None = None,
    fps: float | None = None,
    options: Open3dOptions | None = None,
) -> Path:
    """Write an Open3D RGB-D dataset: ``color/``, ``depth/``, ``camera_intrinsic.json``, ``config.json``.

    ``path`` ending in ``.zip`` gives a zip archive, anything else a folder.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    depth : ndarray of uint16, shape (T, H, W), optional
        Depth in units of ``1 / units_per_metre`` metres (Open3D's default 1000: millimetres).
    intrinsics : (fx, fy, cx, cy), optional
        Written as Open3D's column-major ``intrinsic_matrix``.
    units_per_metre, fps : optional
        Written to ``config.json`` as ``depth_scale`` and ``fps`` when given.
    options : Open3dOptions, optional
        Colour frame encoding, intrinsics file name and root folder; default Open3D's layout.
    """
    path = Path(path)
    opts = options or Open3dOptions()
    files: dict[str, bytes] = {}
    for i, frame in enumerate(rgb):
        encoded = _png(_bgr(frame)) if opts.image_format == "png" else _jpg(_bgr(frame))
        files[f"color/{i:06d}.{opts.image_format}"] = encoded
        if depth is not None:
            files[f"depth/{i:06d}.png"] = _png(depth[i])
    if intrinsics is not None:
        fx, fy, cx, cy = intrinsics
        doc = {"width": int(rgb.shape[2]), "height": int(rgb.shape[1])}
        files[opts.intrinsic_name] = json.dumps(
            {**doc, "intrinsic_matrix": [fx, 0, 0, 0, fy, 0, cx, cy, 1]}
        ).encode()
    config: dict[str, float] = {}
    if units_per_metre is not None:
        config["depth_scale"] = units_per_metre
    if fps is not None:
        config["fps"] = fps
    if config:
        files["config.json"] = json.dumps(config).encode()
    if path.suffix.lower() == ".zip":
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
            for name, data in files.items():
                zf.writestr(opts.root + name, data)
        return path
    for name, data in files.items():
        target = path / opts.root / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(data)
    return path


@dataclass(frozen=True)
class K4aOptions:
    """The depth camera :func:`write_k4a_mkv` simulates (the defaults are an Azure Kinect's).

    Attributes
    ----------
    depth_mode : str
        K4A depth mode (a key of :data:`~workers.pipeline.clipio.mkv.DEPTH_MODES`): the depth frame size.
    depth_intrinsics : (fx, fy, cx, cy), optional
        The depth camera's, pixels; default the colour camera's focal length scaled to the mode's frame,
        centred.
    translation_m : (x, y, z)
        Depth-camera to colour-camera translation, metres.
    depth_delay_frames : float
        Depth frames are stamped this many frame periods after their colour frame.
    """

    depth_mode: str = "NFOV_2X2BINNED"
    depth_intrinsics: Intr | None = None
    translation_m: tuple[float, float, float] = (-0.032, -0.002, 0.004)
    depth_delay_frames: float = 0.0


def write_k4a_mkv(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    depth: NDArray[np.uint16] | None,
    fps: float,
    intrinsics: Intr | None = None,
    options: K4aOptions | None = None,
) -> Path:
    """Write an Azure Kinect style recording: MJPEG ``COLOR`` track, ``b16g`` ``DEPTH`` track (millimetres),
    K4A tags and, with ``intrinsics``, a ``calibration.json`` attachment.

    With ``intrinsics`` the depth track is what the K4A depth camera of ``options.depth_mode`` would see:
    ``depth`` (aligned to colour) is reprojected into a depth camera of ``options.depth_intrinsics``
    placed ``options.translation_m`` from the colour camera. Without ``intrinsics`` the depth track holds
    ``depth`` as it is (colour size) and there is no attachment.

    FFmpeg's Matroska muxer writes raw 16-bit video without a FourCC; the header is patched to ``b16g``
    (big-endian 16-bit grey), which is what ``k4arecorder`` writes and how FFmpeg reads K4A files back.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    depth : ndarray of uint16, shape (T, H, W), or None
        Millimetres, aligned to the colour frames.
    fps : float
    intrinsics : (fx, fy, cx, cy), optional
        The colour camera's, pixels.
    options : K4aOptions, optional
        Depth mode, depth camera intrinsics and pose, depth delay; default an Azure Kinect's.
    """
    path = Path(path)
    opts = options or K4aOptions()
    maps, calibration = _k4a_depth_track(rgb, depth, intrinsics, opts)
    _mux_k4a(path, rgb, maps, calibration, fps, opts)
    if maps is not None:
        _patch_b16g(path, maps)
    return path


def _k4a_depth_track(
    rgb: NDArray[np.uint8], depth: NDArray[np.uint16] | None, intrinsics: Intr | None, opts: K4aOptions
) -> tuple[NDArray[np.uint16] | None, dict[str, Any] | None]:
    """The depth track's maps and the ``calibration.json`` document of a K4A recording.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (T, H, W, 3)
    depth : ndarray of uint16, shape (T, H, W), or None
        Millimetres, aligned to the colour frames.
    intrinsics : (fx, fy, cx, cy), optional
        The colour camera's, pixels.
    opts : K4aOptions

    Returns
    -------
    (maps, calibration)
        With ``depth`` and ``intrinsics``: ``depth`` reprojected into the depth camera of
        ``opts.depth_mode`` (uint16 millimetres) and the calibration that describes both cameras.
        Otherwise ``depth`` as it is and None.
    """
    from workers.pipeline.clipio._common import align_depth_to_color
    from workers.pipeline.clipio.mkv import DEPTH_MODES, calibration_json

    frames, height, width = int(rgb.shape[0]), int(rgb.shape[1]), int(rgb.shape[2])
    if depth is None or intrinsics is None:
        return depth, None
    dw, dh = DEPTH_MODES[opts.depth_mode][2]
    depth_intrinsics = opts.depth_intrinsics
    if depth_intrinsics is None:
        f = intrinsics[0] * dw / width
        depth_intrinsics = (f, f, (dw - 1) / 2, (dh - 1) / 2)
    rot = np.eye(3)
    trans = np.asarray(opts.translation_m, np.float64)
    calibration = calibration_json(
        color=intrinsics,
        color_size=(width, height),
        depth=depth_intrinsics,
        depth_mode=opts.depth_mode,
        rotation=rot,
        translation_m=trans,
    )
    maps = np.zeros((frames, dh, dw), np.uint16)
    for i in range(frames):  # the colour view into the depth camera: the inverse of depth -> colour
        view = align_depth_to_color(
            depth[i].astype(np.float32) * np.float32(0.001), intrinsics, depth_intrinsics, (dh, dw),
            rot.T, -rot.T @ trans,
        )  # fmt: skip
        maps[i] = np.where(np.isfinite(view), np.rint(view * 1000.0), 0).astype(np.uint16)
    return maps, calibration


def _mux_k4a(
    path: Path,
    rgb: NDArray[np.uint8],
    maps: NDArray[np.uint16] | None,
    calibration: dict[str, Any] | None,
    fps: float,
    opts: K4aOptions,
) -> None:
    """Encode the colour frames (MJPEG) and depth ``maps`` (raw 16-bit) into a K4A-tagged Matroska file.

    Parameters
    ----------
    path : Path
    rgb : ndarray of uint8, shape (T, H, W, 3)
    maps : ndarray of uint16, shape (T, h, w), or None
        The depth track's frames, millimetres; None writes no depth track.
    calibration : dict or None
        Attached as ``calibration.json`` (and the depth track tagged with ``opts.depth_mode``) when given.
    fps : float
    opts : K4aOptions
    """
    from fractions import Fraction

    import av

    tick = Fraction(1, 1_000_000)
    period_us = round(1_000_000 / fps)
    with av.open(str(path), mode="w", format="matroska", options={"allow_raw_vfw": "1"}) as out:
        out.metadata["title"] = "Azure Kinect"
        out.metadata["K4A_DEPTH_DELAY_NS"] = str(round(opts.depth_delay_frames * period_us * 1000))
        rate = Fraction(fps).limit_denominator(1001)
        color = _k4a_color_stream(out, rate, tick, (int(rgb.shape[2]), int(rgb.shape[1])))
        dstream: Any = None
        if maps is not None:
            mode = opts.depth_mode if calibration is not None else None
            dstream = _k4a_depth_stream(out, rate, tick, (int(maps.shape[2]), int(maps.shape[1])), mode)
        if calibration is not None:
            out.add_attachment(
                "calibration.json", "application/octet-stream", json.dumps(calibration).encode()
            )
        for i in range(int(rgb.shape[0])):
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb[i]), format="rgb24")
            vf.pts, vf.time_base = i * period_us, tick
            for packet in color.encode(vf.reformat(format="yuvj422p")):
                out.mux(packet)
            if dstream is not None and maps is not None:
                df = av.VideoFrame.from_ndarray(np.ascontiguousarray(maps[i]), format="gray16be")
                df.pts, df.time_base = i * period_us + round(opts.depth_delay_frames * period_us), tick
                for packet in dstream.encode(df):
                    out.mux(packet)
        for stream in (color, dstream):
            if stream is not None:
                for packet in stream.encode():
                    out.mux(packet)


def _k4a_color_stream(out: Any, rate: Any, tick: Any, size: tuple[int, int]) -> Any:
    """Add the MJPEG ``COLOR`` track of ``size`` (width, height), with its K4A tags, to ``out``."""
    width, height = size
    color: Any = out.add_stream("mjpeg", rate=rate)
    color.width, color.height, color.pix_fmt = width, height, "yuvj422p"
    color.options = {"qmin": "1", "qmax": "3"}
    color.time_base = tick
    color.metadata["title"] = "COLOR"
    color.metadata["K4A_COLOR_TRACK"] = "1"
    color.metadata["K4A_COLOR_MODE"] = f"MJPG_{height}P"
    return color


def _k4a_depth_stream(out: Any, rate: Any, tick: Any, size: tuple[int, int], depth_mode: str | None) -> Any:
    """Add the raw 16-bit ``DEPTH`` track of ``size`` (width, height) to ``out``, tagged with
    ``depth_mode`` when given."""
    dstream: Any = out.add_stream("rawvideo", rate=rate)
    dstream.width, dstream.height, dstream.pix_fmt = size[0], size[1], "gray16be"
    dstream.time_base = tick
    dstream.metadata["title"] = "DEPTH"
    dstream.metadata["K4A_DEPTH_TRACK"] = "2"
    if depth_mode is not None:
        dstream.metadata["K4A_DEPTH_MODE"] = depth_mode
    return dstream


def _patch_b16g(path: Path, maps: NDArray[np.uint16]) -> None:
    """Rewrite the depth track's BITMAPINFOHEADER in the file at ``path`` with the ``b16g`` FourCC."""
    import struct

    dh, dw = int(maps.shape[1]), int(maps.shape[2])
    data = path.read_bytes()
    ffmpeg_header = struct.pack("<IiiHHI", 40, dw, -dh, 1, 16, 0)
    if data.count(ffmpeg_header) != 1:
        raise OSError(f"{path.name}: the depth track's BITMAPINFOHEADER was not found once; cannot patch it")
    k4a_header = struct.pack("<IiiHH4s", 40, dw, dh, 1, 16, b"b16g")
    path.write_bytes(data.replace(ffmpeg_header, k4a_header))


# ------------------------------------------------------------------------------------------------ bags


def _header(typestore: Any, stamp_ns: int, frame_id: str, ros1: bool, seq: int) -> Any:
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    if ros1:
        return Header(seq=seq, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def _image_msg(typestore: Any, header: Any, img: NDArray[Any], encoding: str) -> Any:
    Image = typestore.types["sensor_msgs/msg/Image"]
    h, w = img.shape[:2]
    data = np.ascontiguousarray(img).view(np.uint8).reshape(-1)
    return Image(
        header=header,
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=int(data.size // h),
        data=data,
    )


def _compressed_msg(typestore: Any, header: Any, data: bytes, fmt: str) -> Any:
    CompressedImage = typestore.types["sensor_msgs/msg/CompressedImage"]
    return CompressedImage(header=header, format=fmt, data=np.frombuffer(data, dtype=np.uint8))


def _camera_info_msg(typestore: Any, header: Any, w: int, h: int, k: Intr, ros1: bool) -> Any:
    CameraInfo = typestore.types["sensor_msgs/msg/CameraInfo"]
    RegionOfInterest = typestore.types["sensor_msgs/msg/RegionOfInterest"]
    fx, fy, cx, cy = k
    kmat = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64)
    rmat = np.eye(3).ravel()
    pmat = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64)
    fields = {
        "header": header,
        "height": h,
        "width": w,
        "distortion_model": "plumb_bob",
        "binning_x": 0,
        "binning_y": 0,
        "roi": RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    }
    if ros1:
        fields.update(D=np.zeros(5), K=kmat, R=rmat, P=pmat)
    else:
        fields.update(d=np.zeros(5), k=kmat, r=rmat, p=pmat)
    return CameraInfo(**fields)


@dataclass(frozen=True)
class RosBagOptions:
    """How :func:`write_ros_bag` lays the bag out (the defaults are a plain realsense-ros recording).

    Attributes
    ----------
    layout : ``"ros"`` or ``"realsense-sdk"``
        ``ros``: realsense-ros topic names (``/camera/color/image_raw``,
        ``/camera/aligned_depth_to_color/image_raw``). ``realsense-sdk``: the RealSense Viewer layout
        (``/device_0/sensor_1/Color_0/image/data`` ...), with depth units in the bag (ROS 1 only).
    storage : ``"mcap"`` or ``"sqlite3"``
        ROS 2 storage plugin.
    compressed : bool
        Colour as ``CompressedImage`` (jpeg) and depth as ``compressedDepth`` png (ROS 2 style topics).
    depth_scale : float
        Metres per depth unit; stored in the bag for the SDK layout.
    extra_topics : bool
        Also write unrelated topics (IMU-like floats, tf) as real recordings have.
    """

    layout: Literal["ros", "realsense-sdk"] = "ros"
    storage: Literal["mcap", "sqlite3"] = "mcap"
    compressed: bool = False
    depth_scale: float = 0.001
    extra_topics: bool = True


@dataclass(frozen=True)
class _BagTopics:
    """Topic names of one bag layout, and the image message type and depth encoding they carry."""

    color: str
    color_info: str
    depth: str
    depth_info: str
    depth_encoding: str
    image_type: str


def _bag_topics(layout: str, compressed: bool) -> _BagTopics:
    """The colour, depth and camera-info topics of ``layout`` (``/compressed`` image topics if asked)."""
    if layout == "realsense-sdk":
        c_img, c_info = "/device_0/sensor_1/Color_0/image/data", "/device_0/sensor_1/Color_0/info/camera_info"
        d_img, d_info = "/device_0/sensor_0/Depth_0/image/data", "/device_0/sensor_0/Depth_0/info/camera_info"
        d_enc = "mono16"
    else:
        c_img, c_info = "/camera/color/image_raw", "/camera/color/camera_info"
        d_img = "/camera/aligned_depth_to_color/image_raw"
        d_info = "/camera/aligned_depth_to_color/camera_info"
        d_enc = "16UC1"
    if compressed:
        c_img += "/compressed"
        d_img += "/compressedDepth"
    img_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    return _BagTopics(c_img, c_info, d_img, d_info, d_enc, img_type)


def _open_bag_writer(path: Path, ros1: bool, storage: str) -> Any:
    """A ``rosbags`` writer (not yet opened) of a ROS 1 bag file or a ROS 2 bag folder at ``path``."""
    if ros1:
        from rosbags.rosbag1 import Writer as Ros1Writer

        return Ros1Writer(path)
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Ros2Writer

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    return Ros2Writer(path, version=9, storage_plugin=plugin)


@dataclass
class _BagOut:
    """An open bag and what all its camera messages share: one connection per topic (made on the
    topic's first message), messages serialised for the bag's ROS version."""

    writer: Any
    typestore: Any
    ros1: bool
    topics: _BagTopics
    intrinsics: Intr
    size: tuple[int, int]  # (width, height)
    options: RosBagOptions
    conns: dict[str, Any] = field(default_factory=dict)

    def write(self, topic: str, msgtype: str, stamp: int, msg: Any) -> None:
        """Write ``msg`` of ``msgtype`` on ``topic`` with receive time ``stamp`` (ns)."""
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
        if self.ros1:
            raw = bytes(self.typestore.serialize_ros1(msg, msgtype))
        else:
            raw = bytes(self.typestore.serialize_cdr(msg, msgtype))
        self.writer.write(self.conns[topic], stamp, raw)

    def sdk_options(self, t0: int) -> None:
        """The RealSense SDK's depth units and per-stream (identity) extrinsics, stamped ``t0``."""
        f32 = self.typestore.types["std_msgs/msg/Float32"]
        self.write(
            "/device_0/sensor_0/option/Depth_Units/value",
            "std_msgs/msg/Float32",
            t0,
            f32(data=self.options.depth_scale),
        )
        tf = self.typestore.types["geometry_msgs/msg/Transform"]
        vec = self.typestore.types["geometry_msgs/msg/Vector3"]
        quat = self.typestore.types["geometry_msgs/msg/Quaternion"]
        for stream in ("/device_0/sensor_0/Depth_0", "/device_0/sensor_1/Color_0"):
            msg = tf(translation=vec(x=0.0, y=0.0, z=0.0), rotation=quat(x=0.0, y=0.0, z=0.0, w=1.0))
            self.write(stream + "/tf/0", "geometry_msgs/msg/Transform", t0, msg)

    def color(self, stamp: int, index: int, frame: NDArray[np.uint8]) -> None:
        """Colour frame ``index`` with its camera info (and, every 4th frame, an unrelated topic)."""
        ts, topics = self.typestore, self.topics
        header = _header(ts, stamp, "camera_color_optical_frame", self.ros1, index)
        if self.options.compressed:
            msg = _compressed_msg(ts, header, _jpg(_bgr(frame)), "rgb8; jpeg compressed bgr8")
        else:
            msg = _image_msg(ts, header, frame, "rgb8")
        self.write(topics.color, topics.image_type, stamp, msg)
        info = _camera_info_msg(ts, header, *self.size, self.intrinsics, self.ros1)
        self.write(topics.color_info, "sensor_msgs/msg/CameraInfo", stamp, info)
        if self.options.extra_topics and index % 4 == 0:
            f32 = ts.types["std_msgs/msg/Float32"]
            self.write("/imu/temperature", "std_msgs/msg/Float32", stamp, f32(data=21.5))

    def depth(self, stamp: int, index: int, frame: NDArray[np.uint16]) -> None:
        """Depth frame ``index`` with its camera info."""
        ts, topics = self.typestore, self.topics
        header = _header(ts, stamp, "camera_color_optical_frame", self.ros1, index)
        if self.options.compressed:
            data = bytes(12) + _png(frame)
            msg = _compressed_msg(ts, header, data, "16UC1; compressedDepth png")
        else:
            msg = _image_msg(ts, header, frame, topics.depth_encoding)
        self.write(topics.depth, topics.image_type, stamp, msg)
        info = _camera_info_msg(ts, header, *self.size, self.intrinsics, self.ros1)
        self.write(topics.depth_info, "sensor_msgs/msg/CameraInfo", stamp, info)


@dataclass(frozen=True)
class WrenchTopic:
    """A wrist force/torque sensor's ``geometry_msgs/WrenchStamped`` topic to write beside the frames.

    Attributes
    ----------
    stamps_ns : ndarray of int64, shape (N,)
        Header stamps (and receive times), nanoseconds, on the frames' clock.
    force_n : ndarray of float64, shape (N, 3)
        Force in the sensor's frame, newtons (the torque is written as zero).
    name, frame_id : str
    """

    stamps_ns: NDArray[np.int64]
    force_n: NDArray[np.float64]
    name: str = "/ft_sensor/wrench"
    frame_id: str = "ft_sensor_link"


@dataclass(frozen=True)
class StaticTransform:
    """A ``/tf_static`` transform: ``child``'s pose in ``parent``'s frame (rotation as x, y, z, w)."""

    parent: str
    child: str
    rotation_xyzw: tuple[float, float, float, float]
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)


def write_ros_bag(
    path: str | Path,
    rgb: NDArray[np.uint8],
    *,
    stamps_ns: Sequence[int] | NDArray[np.int64],
    intrinsics: Intr,
    depth: NDArray[np.uint16] | None = None,
    depth_stamps_ns: Sequence[int] | NDArray[np.int64] | None = None,
    version: Literal[1, 2] = 1,
    options: RosBagOptions | None = None,
    wrenches: Sequence[WrenchTopic] = (),
    transforms: Sequence[StaticTransform] = (),
) -> Path:
    """Write colour (+ depth) frames as a ROS 1 or ROS 2 bag with the ``rosbags`` writers.

    Parameters
    ----------
    path : path-like
        ROS 1: the ``.bag`` file. ROS 2: the bag folder to create (holds ``metadata.yaml``).
    rgb : ndarray of uint8, shape (T, H, W, 3)
    stamps_ns : sequence of int, length T
        Header stamps (and receive times) of the colour frames, nanoseconds.
    intrinsics : (fx, fy, cx, cy)
    depth : ndarray of uint16, shape (Td, H, W), optional
        Aligned depth in units of ``options.depth_scale``.
    depth_stamps_ns : sequence of int, length Td, optional
        Defaults to ``stamps_ns``.
    version : 1 or 2
    options : RosBagOptions, optional
        Topic layout, ROS 2 storage plugin, compression, depth scale and extra topics; see
        :class:`RosBagOptions` for the defaults.
    wrenches : sequence of WrenchTopic
        Force/torque topics written beside the frames.
    transforms : sequence of StaticTransform
        Written on ``/tf_static`` before the first frame (the colour frames' frame is
        ``camera_color_optical_frame``).
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    opts = options or RosBagOptions()
    path = Path(path)
    ros1 = version == 1
    typestore = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1 and transforms:  # ROS 1's store has no tf2 message built in
        typestore.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms\n", _TF))
    writer = _open_bag_writer(path, ros1, opts.storage)
    d_stamps = list(stamps_ns if depth_stamps_ns is None else depth_stamps_ns)
    h, w = rgb.shape[1:3]
    topics = _bag_topics(opts.layout, opts.compressed)
    with writer:
        out = _BagOut(writer, typestore, ros1, topics, intrinsics, (w, h), opts)
        t0 = int(min(stamps_ns[0], d_stamps[0] if depth is not None else stamps_ns[0]))
        if opts.layout == "realsense-sdk":
            out.sdk_options(t0)
        for transform in transforms:
            _write_static(out, transform, t0 - 1)
        events: list[tuple[int, int, str, int]] = [(int(s), 0, "c", i) for i, s in enumerate(stamps_ns)]
        if depth is not None:
            events += [(int(s), 1, "d", i) for i, s in enumerate(d_stamps)]
        for w, topic in enumerate(wrenches):
            events += [(int(s), 2 + w, "w", i) for i, s in enumerate(topic.stamps_ns)]
        events.sort()
        for stamp, order, kind, i in events:
            if kind == "c":
                out.color(stamp, i, rgb[i])
            elif kind == "w":
                _write_wrench(out, wrenches[order - 2], stamp, i)
            else:
                assert depth is not None
                out.depth(stamp, i, depth[i])
    return path


_WRENCH = "geometry_msgs/msg/WrenchStamped"
_TF = "tf2_msgs/msg/TFMessage"


def _vector(out: _BagOut, v: Sequence[float]) -> Any:
    return out.typestore.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _write_wrench(out: _BagOut, topic: WrenchTopic, stamp: int, i: int) -> None:
    types = out.typestore.types
    wrench = types["geometry_msgs/msg/Wrench"](
        force=_vector(out, topic.force_n[i]), torque=_vector(out, (0, 0, 0))
    )
    header = _header(out.typestore, stamp, topic.frame_id, out.ros1, i)
    out.write(topic.name, _WRENCH, stamp, types[_WRENCH](header=header, wrench=wrench))


def _write_static(out: _BagOut, transform: StaticTransform, stamp: int) -> None:
    types = out.typestore.types
    x, y, z, w = transform.rotation_xyzw
    stamped = types["geometry_msgs/msg/TransformStamped"](
        header=_header(out.typestore, stamp, transform.parent, out.ros1, 0),
        child_frame_id=transform.child,
        transform=types["geometry_msgs/msg/Transform"](
            translation=_vector(out, transform.translation_m),
            rotation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
        ),
    )
    out.write("/tf_static", _TF, stamp, types[_TF](transforms=[stamped]))


def zip_folder(folder: str | Path, dest: str | Path, *, root: str | None = None) -> Path:
    """Zip a folder (for example a ROS 2 bag folder) with its files under ``root/`` (default its name)."""
    folder, dest = Path(folder), Path(dest)
    prefix = (folder.name if root is None else root).strip("/")
    with zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                arc = p.relative_to(folder).as_posix()
                zf.write(p, f"{prefix}/{arc}" if prefix else arc)
    return dest


def write_ros2_zip(path: str | Path, rgb: NDArray[np.uint8], **kwargs: Any) -> Path:
    """Write a ROS 2 bag folder with :func:`write_ros_bag` and zip it to ``path``."""
    with tempfile.TemporaryDirectory(prefix="eigenscope-write-") as tmp:
        bag = Path(tmp) / Path(path).stem
        write_ros_bag(bag, rgb, version=2, **kwargs)
        zip_folder(bag, path)
        shutil.rmtree(bag, ignore_errors=True)
    return Path(path)

"""Write a clip held in memory into each format the readers accept, with the formats' own writer libraries.

Used to make sample and test clips: ``zipfile`` + OpenCV PNG/JPEG for frame zips, TUM and Open3D
datasets, PyAV (or OpenCV) for video and Azure Kinect recordings; ROS 1 and ROS 2 bags are written by
:mod:`workers.pipeline.clipio.bag_writer`. Arrays follow the clip conventions: ``rgb`` uint8
(T, H, W, 3), ``depth`` uint16 (T, H, W) in units of ``depth_scale`` metres.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

Intr = tuple[float, float, float, float]


def png_bytes(img: NDArray[Any]) -> bytes:
    """An image (H, W) or (H, W, 3) BGR, uint8 or uint16, encoded as PNG."""
    import cv2

    ok, buf = cv2.imencode(".png", img)
    assert ok
    return bytes(buf)


def jpg_bytes(img: NDArray[Any], quality: int = 95) -> bytes:
    """A BGR image (H, W, 3) uint8 encoded as JPEG."""
    import cv2

    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return bytes(buf)


def bgr_of(rgb: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """An RGB image (H, W, 3) as OpenCV's BGR, contiguous."""
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
            data = png_bytes(bgr_of(frame)) if image_format == "png" else jpg_bytes(bgr_of(frame))
            zf.writestr(f"{root}rgb/{i:06d}.{image_format}", data)
            if depth is not None:
                zf.writestr(f"{root}depth/{i:06d}.png", png_bytes(depth[i]))
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
            zf.writestr(root + name, png_bytes(bgr_of(frame)))
        zf.writestr(root + "rgb.txt", "\n".join(lines) + "\n")
        if depth is not None:
            lines = ["# depth maps", "# file: 'synthetic'", "# timestamp filename"]
            for t, d in zip(depth_times, depth, strict=True):
                name = f"depth/{t:.6f}.png"
                lines.append(f"{t:.6f} {name}")
                zf.writestr(root + name, png_bytes(d))
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
        encoded = png_bytes(bgr_of(frame)) if opts.image_format == "png" else jpg_bytes(bgr_of(frame))
        files[f"color/{i:06d}.{opts.image_format}"] = encoded
        if depth is not None:
            files[f"depth/{i:06d}.png"] = png_bytes(depth[i])
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

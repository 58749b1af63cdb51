"""ROS ``sensor_msgs/Image`` messages as arrays: colour encodings to RGB8, depth encodings to their values,
with the message's declared size and row step checked (a truncated or resized frame is a clear error).
Used by the bag reader (:mod:`workers.pipeline.clipio.rosbag`)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio._common import to_rgb8
from workers.pipeline.errors import ClipError

#: Image encodings read as depth (``mono16`` may also be an infrared camera's: the bag reader decides).
DEPTH_ENCODINGS = {"16uc1", "mono16", "32fc1", "16sc1"}
#: Image encodings read as colour (and every ``bayer_*``).
COLOR_ENCODINGS = {
    "rgb8", "bgr8", "rgba8", "bgra8", "mono8", "8uc1", "8uc3", "8uc4",
    "yuv422", "uyvy", "yuyv", "yuv422_yuy2", "rgb16", "bgr16",
}  # fmt: skip


def check_raw_size(msg: Any, what: str, size: tuple[int, int]) -> None:
    """A raw Image must declare the topic's frame size (checked before its rows are converted)."""
    if (int(msg.width), int(msg.height)) != size:
        raise ClipError(
            f"{what}: a frame is {int(msg.width)}x{int(msg.height)}, the topic started at "
            f"{size[0]}x{size[1]}; the resolution must not change"
        )


def _rows(msg: Any, what: str, bytes_per_pixel: int) -> NDArray[np.uint8]:
    """The message's pixel rows as bytes (h, w * bytes_per_pixel), its row padding cut off."""
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * bytes_per_pixel or data.size < step * h:
        raise ClipError(
            f"{what}: image data is {data.size} bytes, too short for {w}x{h} with row step {step}; "
            "the message is truncated"
        )
    return data[: step * h].reshape(h, step)[:, : w * bytes_per_pixel]


def image_to_rgb(msg: Any, what: str) -> NDArray[np.uint8]:
    """A ``sensor_msgs/Image`` of any supported colour encoding as RGB8 (H, W, 3)."""
    enc = str(msg.encoding).lower()
    h, w = int(msg.height), int(msg.width)
    if enc in ("rgb8", "bgr8", "8uc3"):
        arr = _rows(msg, what, 3).reshape(h, w, 3)
        return to_rgb8(arr, "bgr" if enc != "rgb8" else "rgb", what)
    if enc in ("rgba8", "bgra8", "8uc4"):
        arr = _rows(msg, what, 4).reshape(h, w, 4)
        return to_rgb8(arr, "rgb" if enc == "rgba8" else "bgr", what)
    if enc in ("rgb16", "bgr16"):
        big = bool(msg.is_bigendian)
        arr16 = _rows(msg, what, 6).copy().view(">u2" if big else "<u2").reshape(h, w, 3).astype(np.uint16)
        return to_rgb8(arr16, "rgb" if enc == "rgb16" else "bgr", what)
    if enc in ("mono8", "8uc1"):
        return to_rgb8(_rows(msg, what, 1).reshape(h, w), "rgb", what)
    import cv2

    if enc in ("yuv422", "uyvy", "yuyv", "yuv422_yuy2"):
        packed = np.ascontiguousarray(_rows(msg, what, 2).reshape(h, w, 2))
        code = cv2.COLOR_YUV2RGB_UYVY if enc in ("yuv422", "uyvy") else cv2.COLOR_YUV2RGB_YUY2
        return np.asarray(cv2.cvtColor(packed, code), dtype=np.uint8)
    bayer = {
        "bayer_rggb8": cv2.COLOR_BayerBG2RGB,
        "bayer_bggr8": cv2.COLOR_BayerRG2RGB,
        "bayer_gbrg8": cv2.COLOR_BayerGR2RGB,
        "bayer_grbg8": cv2.COLOR_BayerGB2RGB,
    }
    if enc in bayer:
        raw = np.ascontiguousarray(_rows(msg, what, 1).reshape(h, w))
        return np.asarray(cv2.cvtColor(raw, bayer[enc]), dtype=np.uint8)
    raise ClipError(f"{what}: colour encoding {msg.encoding!r} is not supported; record rgb8 or bgr8")


def image_to_depth(msg: Any, what: str) -> NDArray[Any]:
    """A ``sensor_msgs/Image`` of a depth encoding as its raw values (uint16 or float32, H x W)."""
    enc = str(msg.encoding).lower()
    h, w = int(msg.height), int(msg.width)
    big = bool(msg.is_bigendian)
    if enc in ("16uc1", "mono16"):
        rows = np.ascontiguousarray(_rows(msg, what, 2))
        return rows.view(">u2" if big else "<u2").reshape(h, w).astype(np.uint16)
    if enc == "16sc1":
        rows = np.ascontiguousarray(_rows(msg, what, 2))
        signed = rows.view(">i2" if big else "<i2").reshape(h, w)
        clipped: NDArray[np.uint16] = np.clip(signed, 0, None).astype(np.uint16)
        return clipped
    if enc == "32fc1":
        rows = np.ascontiguousarray(_rows(msg, what, 4))
        out: NDArray[np.float32] = rows.view(">f4" if big else "<f4").reshape(h, w).astype(np.float32)
        return out
    raise ClipError(f"{what}: depth encoding {msg.encoding!r} is not supported; record 16UC1 or 32FC1")


__all__ = ["COLOR_ENCODINGS", "DEPTH_ENCODINGS", "check_raw_size", "image_to_depth", "image_to_rgb"]

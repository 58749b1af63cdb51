"""Helpers shared by the clip readers: timing, caps, image headers and decoding, stream pairing.

Nothing here imports OpenCV at module level: probing a clip (reading ``info``) must stay light, so
image decoding imports ``cv2`` on first use.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import MIN_FRAMES, ReadLimits, uniform_fps_from_timestamps
from workers.pipeline.errors import ClipError, ClipTooLargeError

#: Fewest frames any reader accepts.
#: Smallest frame side, pixels.
MIN_SIDE = 16
#: Declared and measured frame rates that differ by more than this fraction get a note.
_RATE_MISMATCH = 0.05


@dataclass(frozen=True, slots=True)
class Timing:
    """Frame rate and timeline resolved from the user, the file and its timestamps."""

    fps: float | None
    fps_source: str | None
    timestamps_s: NDArray[np.float64] | None
    measured_fps: float | None
    dropped_frames: int
    notes: tuple[str, ...]


def resolve_timing(
    fmt: str,
    *,
    user_fps: float | None,
    declared_fps: float | None,
    declared_source: str,
    timestamps_s: NDArray[np.float64] | None,
) -> Timing:
    """Decide the frame rate: the user's wins, then the file's declared rate, then the timestamps.

    Parameters
    ----------
    fmt : str
        Format name for messages.
    user_fps : float or None
        ``--fps`` / API ``fps``.
    declared_fps : float or None
        Rate written in the container or bundle (validated here: must be finite and positive).
    declared_source : str
        ``bundle`` or ``container``.
    timestamps_s : ndarray of float64, shape (T,), or None
        Per-frame capture times (any origin).

    Returns
    -------
    Timing
        When the user gives a rate and the file carries timestamps, the timestamps are rescaled so their
        median interval is ``1 / user_fps``: the high-speed camera that wrote "30 fps" into its file keeps
        its dropped-frame and jitter pattern on the true time base.
    """
    notes: list[str] = []
    measured: float | None = None
    dropped = 0
    ts: NDArray[np.float64] | None = None
    if timestamps_s is not None and len(timestamps_s) >= 2:
        ts = np.asarray(timestamps_s, dtype=np.float64)
        if not np.all(np.isfinite(ts)):
            raise ClipError(f"{fmt}: frame timestamps contain NaN or infinite values; fix the recording")
        ts = ts - ts[0]
        dt = np.diff(ts)
        if np.any(dt <= 0):
            raise ClipError(
                f"{fmt}: frame timestamps are not strictly increasing ({int(np.sum(dt <= 0))} repeats or "
                "steps back); fix the recording or give --fps"
            )
        measured, dropped = uniform_fps_from_timestamps(ts)
    if declared_fps is not None and not (math.isfinite(declared_fps) and declared_fps > 0):
        if user_fps is None:
            raise ClipError(
                f"{fmt}: the file declares fps={declared_fps}, which is not a positive finite rate; "
                "pass --fps (API parameter fps) with the true recording rate"
            )
        declared_fps = None
    if user_fps is not None:
        fps, source = user_fps, "user"
        if ts is not None and measured is not None:
            ts = ts * (measured / user_fps)
            if abs(measured / user_fps - 1) > _RATE_MISMATCH:
                notes.append(
                    f"timestamps measure {measured:.4g} fps; rescaled to the given {user_fps:.4g} fps"
                )
    elif declared_fps is not None:
        fps, source = declared_fps, declared_source
        if measured is not None and abs(measured / declared_fps - 1) > _RATE_MISMATCH:
            notes.append(
                f"{declared_source} declares {declared_fps:.4g} fps but timestamps measure {measured:.4g} fps"
            )
    elif measured is not None:
        fps, source = measured, "timestamps"
    else:
        return Timing(None, None, None, None, 0, tuple(notes))
    return Timing(fps, source, ts, measured, dropped, tuple(notes))


def check_frames(fmt: str, frames: int, limits: ReadLimits) -> None:
    """Refuse too few or too many frames."""
    if frames > limits.max_frames:
        raise ClipTooLargeError(
            f"{fmt}: {frames} frames exceed the cap of {limits.max_frames}; trim the clip"
        )
    if frames < MIN_FRAMES:
        raise ClipError(
            f"{fmt}: only {frames} frames; at least {MIN_FRAMES} are needed (64 or more is better)"
        )


def check_size(fmt: str, width: int, height: int, limits: ReadLimits) -> None:
    """Refuse frames larger than the pixel cap or too small to analyse."""
    if width * height > limits.max_pixels_per_frame:
        raise ClipTooLargeError(
            f"{fmt}: {width}x{height} frames exceed the cap of {limits.max_pixels_per_frame} pixels; "
            "downscale the clip"
        )
    if width < MIN_SIDE or height < MIN_SIDE:
        raise ClipError(
            f"{fmt}: frames of {width}x{height} pixels are too small; "
            f"at least {MIN_SIDE}x{MIN_SIDE} is needed"
        )


def check_decoded(
    fmt: str, frames: int, width: int, height: int, has_depth: bool, limits: ReadLimits
) -> None:
    """Refuse a clip whose frames would decode to more than ``limits.max_decoded_bytes`` in total.

    Counted as delivered: RGB at 3 bytes a pixel, depth at 4 (float32 metres).
    """
    per_frame = width * height * (3 + (4 if has_depth else 0))
    total = frames * per_frame
    if total > limits.max_decoded_bytes:
        mib = 1024 * 1024
        raise ClipTooLargeError(
            f"{fmt}: {frames} frames of {width}x{height}{' with depth' if has_depth else ''} decode to "
            f"{total // mib} MiB, over the cap of {limits.max_decoded_bytes // mib} MiB; trim the clip or "
            "downscale it"
        )


def check_inflation(fmt: str, what: str, decompressed: int, compressed: int, limits: ReadLimits) -> None:
    """Refuse ``what`` when it decompresses to more than ``limits.max_inflation_ratio`` times its
    compressed size (only beyond ``limits.inflation_floor_bytes``): a decompression bomb."""
    if decompressed <= limits.inflation_floor_bytes:
        return
    ratio = decompressed / max(compressed, 1)
    if ratio > limits.max_inflation_ratio:
        raise ClipTooLargeError(
            f"{fmt}: {what} inflates from {compressed} to {decompressed} bytes, {ratio:.0f} times (the cap "
            f"is {limits.max_inflation_ratio:g}); this is a decompression bomb, not footage"
        )


def check_image(
    head: ImageHeader,
    what: str,
    limits: ReadLimits,
    *,
    size: tuple[int, int] | None = None,
    depth: bool = False,
) -> None:
    """Refuse an encoded frame, from its header, before it is decoded.

    Parameters
    ----------
    head : ImageHeader
        What the frame's PNG IHDR or JPEG SOF declares.
    what : str
        Names the frame in messages.
    size : (width, height), optional
        The clip's frame size: every frame must declare it.
    depth : bool
        A depth frame: a 16-bit single-channel PNG.
    """
    if head.width * head.height > limits.max_pixels_per_frame:
        raise ClipTooLargeError(
            f"{what}: the frame declares {head.width}x{head.height} pixels, over the cap of "
            f"{limits.max_pixels_per_frame} pixels; downscale the clip"
        )
    if size is not None and (head.width, head.height) != size:
        raise ClipError(
            f"{what}: the frame declares {head.width}x{head.height} pixels, but the clip is "
            f"{size[0]}x{size[1]}; all frames must have one size"
        )
    if depth and (head.kind != "png" or head.bit_depth != 16 or head.channels != 1):
        raise ClipError(
            f"{what}: a depth frame must be a 16-bit single-channel PNG "
            f"(got {head.kind}, {head.bit_depth}-bit, {head.channels} channel(s))"
        )
    if not depth and (head.bit_depth not in (1, 2, 4, 8, 12, 16) or head.channels not in (1, 2, 3, 4)):
        raise ClipError(
            f"{what}: the frame declares {head.bit_depth}-bit samples in {head.channels} channel(s), which "
            "no camera writes; the file is corrupt"
        )


def frame_window(fmt: str, start: int, stop: int | None, frames: int) -> int:
    """The end of the window ``[start, stop)`` of a clip of ``frames`` frames (``stop`` None: to the
    end, beyond it: cut); a window outside the clip is a :class:`ClipError`."""
    stop = frames if stop is None else min(stop, frames)
    if not 0 <= start <= stop:
        raise ClipError(f"{fmt}: frame range [{start}, {stop}) is outside the clip's {frames} frames")
    return stop


def natural_key(name: str) -> tuple[Any, ...]:
    """Sort key that orders ``frame2`` before ``frame10`` (ASCII digits only: ``²`` is a digit to Unicode
    but no number to :func:`int`)."""
    return tuple(int(p) if p.isascii() and p.isdigit() else p for p in re.split(r"([0-9]+)", name))


# ---------------------------------------------------------------------------------------------- images


@dataclass(frozen=True, slots=True)
class ImageHeader:
    """What an encoded image's header says."""

    kind: str  # "png" or "jpeg"
    width: int
    height: int
    bit_depth: int
    channels: int


_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}


def image_header(data: bytes, what: str) -> ImageHeader:
    """Read size and depth of a PNG or JPEG image from its header, without decoding it.

    Parameters
    ----------
    data : bytes
        The start of the file (a few kilobytes suffice for PNG; JPEG may need more).
    what : str
        Names the image in error messages.
    """
    if data.startswith(_PNG_MAGIC):
        if len(data) < 33 or data[12:16] != b"IHDR":
            raise ClipError(f"{what}: PNG header is truncated or corrupt")
        width, height, bit_depth, color_type = struct.unpack(">IIBB", data[16:26])
        if color_type not in _PNG_CHANNELS:
            raise ClipError(f"{what}: PNG colour type {color_type} is invalid; the file is corrupt")
        return ImageHeader("png", width, height, bit_depth, _PNG_CHANNELS[color_type])
    if data.startswith(b"\xff\xd8"):
        pos = 2
        while pos + 4 <= len(data):
            if data[pos] != 0xFF:
                pos += 1
                continue
            marker = data[pos + 1]
            if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7 or marker == 0xFF:
                pos += 1 if marker == 0xFF else 2
                continue
            (length,) = struct.unpack(">H", data[pos + 2 : pos + 4])
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                if pos + 10 > len(data):
                    break
                precision, height, width, comps = struct.unpack(">BHHB", data[pos + 4 : pos + 10])
                return ImageHeader("jpeg", width, height, precision, comps)
            pos += 2 + length
        raise ClipError(f"{what}: JPEG header is truncated or corrupt (no frame header found)")
    raise ClipError(f"{what}: not a PNG or JPEG image (starts with {data[:8]!r})")


def decode_color(data: bytes, what: str) -> NDArray[np.uint8]:
    """Decode an encoded colour image to RGB.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
    """
    import cv2

    buf = np.frombuffer(data, dtype=np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ClipError(f"{what}: image data is corrupt or truncated and cannot be decoded")
    return to_rgb8(img, "bgr", what)


def decode_depth_png(data: bytes, what: str) -> NDArray[np.uint16]:
    """Decode a 16-bit single-channel depth PNG.

    Returns
    -------
    ndarray of uint16, shape (H, W)
    """
    import cv2

    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ClipError(f"{what}: depth image is corrupt or truncated and cannot be decoded")
    if img.ndim != 2 or img.dtype != np.uint16:
        raise ClipError(
            f"{what}: depth must be a 16-bit single-channel PNG in depth units, got {img.dtype} "
            f"with shape {img.shape}"
        )
    return np.asarray(img, dtype=np.uint16)


def to_rgb8(img: NDArray[Any], order: str, what: str) -> NDArray[np.uint8]:
    """Convert a decoded image (gray, BGR/RGB, with or without alpha, 8 or 16 bit) to RGB uint8.

    Parameters
    ----------
    img : ndarray, shape (H, W) or (H, W, C)
    order : ``"bgr"`` or ``"rgb"``
        Channel order of ``img`` when it has 3 or 4 channels.
    """
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise ClipError(f"{what}: colour image has dtype {img.dtype}; expected 8-bit")
    if img.ndim == 2:
        return np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4):
        raise ClipError(f"{what}: colour image has shape {img.shape}; expected (H, W, 3)")
    if img.shape[2] == 1:
        return np.repeat(img, 3, axis=2)
    rgb = img[:, :, :3]
    if order == "bgr":
        rgb = rgb[:, :, ::-1]
    return np.ascontiguousarray(rgb)


# -------------------------------------------------------------------------------------- stream pairing


def associate_nearest(
    ref_s: NDArray[np.float64], other_s: NDArray[np.float64], max_dt_s: float
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Pair each reference time with the nearest other time.

    Parameters
    ----------
    ref_s : ndarray of float64, shape (N,)
        Sorted reference timestamps (colour frames).
    other_s : ndarray of float64, shape (M,)
        Sorted timestamps of the other stream (depth frames).
    max_dt_s : float
        Pairs further apart than this are rejected.

    Returns
    -------
    index : ndarray of int64, shape (N,)
        Index into ``other_s`` of each reference frame's partner.
    ok : ndarray of bool, shape (N,)
        Whether the partner is within ``max_dt_s``.
    """
    if len(other_s) == 0:
        return np.zeros(len(ref_s), np.int64), np.zeros(len(ref_s), bool)
    right = np.clip(np.searchsorted(other_s, ref_s), 0, len(other_s) - 1)
    left = np.clip(right - 1, 0, len(other_s) - 1)
    pick_left = np.abs(other_s[left] - ref_s) <= np.abs(other_s[right] - ref_s)
    index = np.where(pick_left, left, right).astype(np.int64)
    ok = np.abs(other_s[index] - ref_s) <= max_dt_s
    return index, ok


def pairing_tolerance(*stamp_lists: NDArray[np.float64]) -> float:
    """Largest time offset accepted between paired frames: 0.75 of the slowest stream's median period."""
    periods = [float(np.median(np.diff(s))) for s in stamp_lists if len(s) > 1]
    periods = [p for p in periods if p > 0]
    return 0.75 * max(periods) if periods else 0.0


# ------------------------------------------------------------------------------------- depth alignment


def align_depth_to_color(
    depth_m: NDArray[np.float32],
    depth_k: Sequence[float],
    color_k: Sequence[float],
    color_shape: tuple[int, int],
    rotation: NDArray[np.float64] | None = None,
    translation_m: NDArray[np.float64] | None = None,
) -> NDArray[np.float32]:
    """Reproject a depth map into the colour camera (z-buffered splat, nearest surface wins).

    Parameters
    ----------
    depth_m : ndarray of float32, shape (Hd, Wd)
        Depth in metres, NaN where invalid.
    depth_k, color_k : (fx, fy, cx, cy)
        Intrinsics of the depth and colour cameras, pixels.
    color_shape : (H, W)
        Colour frame size.
    rotation : ndarray of float64, shape (3, 3), optional
        Rotation from depth-camera to colour-camera coordinates (identity when None).
    translation_m : ndarray of float64, shape (3,), optional
        Translation from depth-camera to colour-camera coordinates, metres (zero when None).

    Returns
    -------
    ndarray of float32, shape (H, W)
        Depth along the colour camera's axis, metres; NaN where no depth pixel lands.
    """
    hd, wd = depth_m.shape
    h, w = color_shape
    valid = np.isfinite(depth_m) & (depth_m > 0)
    vs, us = np.nonzero(valid)
    z = depth_m[vs, us].astype(np.float64)
    fxd, fyd, cxd, cyd = depth_k
    pts = np.stack([(us - cxd) / fxd * z, (vs - cyd) / fyd * z, z])
    if rotation is not None:
        pts = rotation @ pts
    if translation_m is not None:
        pts = pts + translation_m.reshape(3, 1)
    out = np.full((h, w), np.inf, np.float64)
    zc = pts[2]
    front = zc > 0
    pts, zc = pts[:, front], zc[front]
    fxc, fyc, cxc, cyc = color_k
    # Each depth pixel covers a footprint in the colour image; splat it over that footprint (at most
    # the scale ratio rounded up) so an upsampled depth map leaves no holes.
    sx = max(1, math.ceil(fxc / fxd * 1.0)) if fxd > 0 else 1
    sy = max(1, math.ceil(fyc / fyd * 1.0)) if fyd > 0 else 1
    u0 = pts[0] / zc * fxc + cxc - (sx - 1) / 2.0
    v0 = pts[1] / zc * fyc + cyc - (sy - 1) / 2.0
    for dy in range(sy):
        for dx in range(sx):
            u = np.rint(u0 + dx).astype(np.int64)
            v = np.rint(v0 + dy).astype(np.int64)
            inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            np.minimum.at(out, (v[inside], u[inside]), zc[inside])
    del hd, wd
    out[~np.isfinite(out)] = np.nan
    return out.astype(np.float32)

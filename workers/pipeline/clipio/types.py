"""Data types of clip I/O: what a reader tells about a clip and the frames it streams."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, Protocol, Self

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.errors import ClipError, ParameterError

#: Fewest frames a clip may have, and an analysis window: readers refuse shorter clips, every window is at
#: least this long (16 frames give 15 flow maps, 7 frequencies above zero).
MIN_FRAMES = 16


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole camera intrinsics, pixels."""

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ClipError(f"intrinsics: {name}={value} is not finite; give --{name} with a real value")
        if self.fx <= 0 or self.fy <= 0:
            raise ClipError(
                f"intrinsics: focal lengths must be positive, got fx={self.fx}, fy={self.fy}; "
                "give the camera's --fx/--fy in pixels"
            )


@dataclass(frozen=True, slots=True)
class ClipOverrides:
    """Metadata the user supplies; each given field wins over what the file says."""

    fps: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    depth_scale: float | None = None
    color_topic: str | None = None
    depth_topic: str | None = None

    def __post_init__(self) -> None:
        if self.fps is not None and not (math.isfinite(self.fps) and self.fps > 0):
            raise ParameterError(f"fps={self.fps} must be a positive finite number (frames per second)")
        if self.depth_scale is not None and not (math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise ParameterError(f"depth_scale={self.depth_scale} must be positive (metres per depth unit)")
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ParameterError(f"{name}={value} must be a positive focal length in pixels")

    def intrinsics_over(self, base: Intrinsics | None, width: int, height: int) -> Intrinsics | None:
        """Intrinsics with these overrides applied over ``base``.

        Missing principal point defaults to the image centre; a missing ``fy`` defaults to ``fx``.
        Returns None when no focal length is known at all.
        """
        fx = self.fx if self.fx is not None else (base.fx if base else None)
        fy = self.fy if self.fy is not None else (base.fy if base else None)
        if fx is None and fy is None:
            return None
        fx = fx if fx is not None else fy
        fy = fy if fy is not None else fx
        assert fx is not None
        assert fy is not None
        cx = self.cx if self.cx is not None else (base.cx if base else (width - 1) / 2.0)
        cy = self.cy if self.cy is not None else (base.cy if base else (height - 1) / 2.0)
        return Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy)


@dataclass(frozen=True, slots=True)
class ReadLimits:
    """Caps that keep hostile or oversized files from exhausting memory or disk.

    Attributes
    ----------
    max_frames : int
        Most frames a clip may hold.
    max_pixels_per_frame : int
        Largest frame, width x height.
    max_uncompressed_bytes : int
        Largest total a zip archive may expand to (declared sizes, enforced while reading), and the most
        bytes written when a zipped ROS 2 bag is unpacked to a scratch folder.
    max_entries : int
        Most entries a zip archive may list.
    max_decoded_bytes : int
        Most a clip may decode to: frames x (width x height x 3 for RGB, + width x height x 4 for depth
        in metres), from the sizes the file declares, checked before any frame is decoded.
    max_inflation_ratio : float
        Largest ratio of decompressed to compressed bytes of a zip archive (all its entries) or a deflated
        npz member, applied once it decompresses to more than ``inflation_floor_bytes``: real footage
        deflates by a few, a decompression bomb by up to 1032.
    inflation_floor_bytes : int
        Archives and members decompressing to less than this are not ratio-checked.
    """

    max_frames: int = 100_000
    max_pixels_per_frame: int = 4096 * 4096
    max_uncompressed_bytes: int = 32 * 1024**3
    max_entries: int = 200_000
    max_decoded_bytes: int = 32 * 1024**3
    max_inflation_ratio: float = 100.0
    inflation_floor_bytes: int = 256 * 1024**2

    def __post_init__(self) -> None:
        for name in (
            "max_frames",
            "max_pixels_per_frame",
            "max_uncompressed_bytes",
            "max_entries",
            "max_decoded_bytes",
            "inflation_floor_bytes",
        ):
            value = getattr(self, name)
            if not isinstance(value, int) or value <= 0:
                raise ParameterError(f"read limit {name}={value!r} must be a positive integer")
        ratio = self.max_inflation_ratio
        if not (isinstance(ratio, int | float) and math.isfinite(ratio) and ratio >= 1):
            raise ParameterError(f"read limit max_inflation_ratio={ratio!r} must be a number of at least 1")


@dataclass(frozen=True)
class ClipInfo:
    """What a reader found in a clip.

    Attributes
    ----------
    format : str
        Detected format (``npz``, ``zip-frames``, ``tum``, ``video``, ``ros1-bag``, ``ros2-bag``).
    frames, width, height : int
        Frame count and frame size in pixels.
    fps : float or None
        Frame rate that will be used, Hz; None when neither the file nor the user gives one.
    fps_source : str or None
        ``user``, ``bundle``, ``timestamps``, ``container`` or ``metadata`` (a capture rate the file records
        beside a slower playback rate, as phones write for slow motion).
    has_depth : bool
        Whether frames carry a depth map.
    depth_scale : float or None
        Metres per stored depth unit (informational; frames are delivered in metres).
    intrinsics : Intrinsics or None
    timestamps_s : ndarray of float64, shape (T,), or None
        Per-frame capture times when the format carries them.
    dropped_frames : int
        Frames missing from a uniform timeline, estimated from timestamps.
    streams : tuple of str
        Streams, arrays or topics found.
    measured_fps : float or None
        Frame rate measured from the timestamps the file carries (median interval), Hz.
    container_fps : float or None
        Frame rate the container or bundle declares, Hz.
    size_bytes : int
        Size of the clip file on disk.
    depth_source : str or None
        Where the depth frames come from (array, folder, topic or companion file).
    notes : tuple of str
        How the reader aligned or adjusted the streams (for example dropped unpaired frames).
    capture_fps_hint : float or None
        A capture rate named by the file but not used (its name, say ``..._fps1000.mp4``): a container
        rate may be a high-speed camera's playback rate.
    capture_fps_hint_source : str or None
        Where the hint comes from, in words.
    """

    format: str
    frames: int
    width: int
    height: int
    fps: float | None
    fps_source: str | None
    has_depth: bool
    depth_scale: float | None
    intrinsics: Intrinsics | None
    timestamps_s: NDArray[np.float64] | None = None
    dropped_frames: int = 0
    streams: tuple[str, ...] = field(default_factory=tuple)
    measured_fps: float | None = None
    container_fps: float | None = None
    size_bytes: int = 0
    depth_source: str | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)
    capture_fps_hint: float | None = None
    capture_fps_hint_source: str | None = None

    @property
    def duration_s(self) -> float | None:
        """Time spanned by the clip, seconds (last timestamp minus first, else frames / fps)."""
        if self.timestamps_s is not None and len(self.timestamps_s) > 1:
            return float(self.timestamps_s[-1] - self.timestamps_s[0])
        if self.fps:
            return self.frames / self.fps
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (what ``eigenscope probe --json`` prints and the API's clip resource shows).

        Per-frame timestamps are summarised (count, first/last, measured rate), not listed.
        """
        intr = self.intrinsics
        return {
            "format": self.format,
            "frames": self.frames,
            "width": self.width,
            "height": self.height,
            "fps": self.fps,
            "fps_source": self.fps_source,
            "measured_fps": self.measured_fps,
            "container_fps": self.container_fps,
            "dropped_frames": self.dropped_frames,
            "duration_s": self.duration_s,
            "has_timestamps": self.timestamps_s is not None,
            "has_depth": self.has_depth,
            "depth_scale": self.depth_scale,
            "depth_source": self.depth_source,
            "intrinsics": None
            if intr is None
            else {"fx": intr.fx, "fy": intr.fy, "cx": intr.cx, "cy": intr.cy},
            "streams": list(self.streams),
            "size_bytes": self.size_bytes,
            "notes": list(self.notes),
        }


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded frame.

    Attributes
    ----------
    index : int
        Position in the clip, from 0.
    rgb : ndarray of uint8, shape (H, W, 3)
        Colour image, RGB order.
    depth_m : ndarray of float32, shape (H, W), or None
        Depth in metres; NaN where the sensor gave no reading.
    timestamp_s : float
        Capture time, seconds from the first frame.
    """

    index: int
    rgb: NDArray[np.uint8]
    depth_m: NDArray[np.float32] | None
    timestamp_s: float


class ClipReader(Protocol):
    """A clip opened for streaming. Readers are context managers and hold at most a few frames.

    Every reader derives from :class:`ClosingReader`, which gives :meth:`gray_frames` and
    :meth:`frames_with_depth_on` from :meth:`frames`; a reader overrides them where it has a faster way
    (a video's luma plane, depth sampled before its conversion to metres), and a reader that wraps
    another passes them through.
    """

    @property
    def info(self) -> ClipInfo: ...

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Yield frames ``start <= index < stop`` in order."""
        ...

    def gray_frames(self, start: int = 0, stop: int | None = None) -> Iterator[NDArray[np.uint8]]:
        """Yield the grey image (H, W), uint8, of frames ``start <= index < stop`` in order."""
        ...

    def frames_with_depth_on(
        self, shape: tuple[int, int], start: int = 0, stop: int | None = None
    ) -> Iterator[Frame]:
        """Yield frames as :meth:`frames`, with ``depth_m`` sampled (nearest) onto ``shape`` (rows,
        columns)."""
        ...

    def close(self) -> None: ...

    def __enter__(self) -> Self: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...


class ClosingReader:
    """What every reader shares: ``with reader:`` closes it, and the defaults of the protocol's fast paths
    (grey frames and depth on a grid, from :meth:`frames`)."""

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:  # pragma: no cover
        raise NotImplementedError

    def gray_frames(self, start: int = 0, stop: int | None = None) -> Iterator[NDArray[np.uint8]]:
        """The grey image (H, W), uint8, of frames ``start <= index < stop`` (from :meth:`frames`)."""
        import cv2

        for frame in self.frames(start, stop):
            yield np.asarray(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), np.uint8)

    def frames_with_depth_on(
        self, shape: tuple[int, int], start: int = 0, stop: int | None = None
    ) -> Iterator[Frame]:
        """Frames as :meth:`frames`, with ``depth_m`` sampled (nearest) onto ``shape`` (rows, columns)."""
        for frame in self.frames(start, stop):
            if frame.depth_m is None or frame.depth_m.shape == tuple(shape):
                yield frame
            else:
                yield Frame(
                    index=frame.index,
                    rgb=frame.rgb,
                    depth_m=sample_nearest(frame.depth_m, shape),
                    timestamp_s=frame.timestamp_s,
                )

    def close(self) -> None:  # pragma: no cover - every reader overrides it
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def nearest_indices(source: int, target: int) -> NDArray[np.intp]:
    """Source indices of nearest-neighbour resampling from ``source`` to ``target`` samples.

    The same samples as OpenCV's ``cv2.resize(..., interpolation=cv2.INTER_NEAREST)`` (index
    ``floor(i / (target / source))``, clipped to the last), so a map sampled with these before a
    per-pixel conversion is bit for bit the converted map resized afterwards.

    Parameters
    ----------
    source, target : int
        Samples along the axis before and after resampling, both at least 1.

    Returns
    -------
    ndarray of intp, shape (target,)
    """
    if source < 1 or target < 1:
        raise ParameterError(f"cannot resample {source} samples to {target}; both must be at least 1")
    inverse = 1.0 / (target / source)
    index = np.floor(np.arange(target, dtype=np.float64) * inverse).astype(np.intp)
    return np.minimum(index, source - 1)


def sample_nearest(image: NDArray[Any], shape: tuple[int, int]) -> NDArray[Any]:
    """``image`` resampled to ``shape`` (rows, columns) by nearest neighbour, as OpenCV's INTER_NEAREST.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C), any dtype
    shape : (rows, columns)

    Returns
    -------
    ndarray, shape (rows, columns) or (rows, columns, C), dtype of ``image``
        A new array (``image`` itself when it already has ``shape``).
    """
    height, width = image.shape[:2]
    if (height, width) == tuple(shape):
        return image
    # A whole-number ratio (640 -> 320) is a strided slice, ten times cheaper than fancy indexing.
    rows = _as_slice(nearest_indices(height, shape[0]))
    cols = _as_slice(nearest_indices(width, shape[1]))
    return np.ascontiguousarray(image[rows][:, cols])


def _as_slice(index: NDArray[np.intp]) -> slice | NDArray[np.intp]:
    """``index`` as the equivalent slice when it is 0, s, 2s, ... (s >= 1); otherwise ``index``."""
    step = int(index[1] - index[0]) if len(index) > 1 else 1
    if index[0] == 0 and step >= 1 and np.array_equal(index, np.arange(len(index)) * step):
        return slice(0, step * (len(index) - 1) + 1, step)
    return index


def depth_to_metres(raw: NDArray[np.generic], depth_scale: float) -> NDArray[np.float32]:
    """Convert a stored depth map to metres.

    Parameters
    ----------
    raw : ndarray, shape (H, W)
        Integer depth in sensor units (0 = no reading) or float metres (NaN or <= 0 = no reading).
    depth_scale : float
        Metres per unit for integer input; ignored for float input.

    Returns
    -------
    ndarray of float32, shape (H, W)
        Depth in metres, NaN where invalid.
    """
    if np.issubdtype(raw.dtype, np.floating) or not depth_scale > 0:
        out = raw.astype(np.float32, copy=True)
        if not np.issubdtype(raw.dtype, np.floating):
            out *= np.float32(depth_scale)
        out[~(out > 0)] = np.nan
        return out
    # Integer units (every frame of a clip comes through here): one pass to metres, and the invalid
    # readings found on the integers.
    metres: NDArray[np.float32] = np.multiply(raw, np.float32(depth_scale), dtype=np.float32)
    metres[np.less_equal(raw, 0)] = np.nan
    return metres


def uniform_fps_from_timestamps(timestamps_s: NDArray[np.float64]) -> tuple[float, int]:
    """Estimate the nominal frame rate and dropped-frame count from capture times.

    The nominal period starts as the median frame interval; gaps of k periods count as k - 1 drops, and
    the period is then refined as the whole span over the number of periods it holds.

    Returns
    -------
    fps : float
    dropped : int
    """
    if len(timestamps_s) < 2:
        raise ClipError("timestamps: need at least two frames to measure a frame rate")
    dt = np.diff(timestamps_s)
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        raise ClipError("timestamps: must be finite and strictly increasing; fix the recording or give --fps")
    period = float(np.median(dt))
    steps = np.maximum(np.rint(dt / period).astype(np.int64), 1)
    dropped = int(np.sum(steps - 1))
    # Refine over the whole span: robust to timestamps quantised to a coarse time base (e.g. 1 ms).
    period = float(timestamps_s[-1] - timestamps_s[0]) / float(np.sum(steps))
    return 1.0 / period, dropped

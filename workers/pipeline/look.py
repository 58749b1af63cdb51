"""The first pass over a window: the whole picture on a coarse grid, to find where and at what it moves.

:func:`look_at` reads the window's frames once. Each is turned grey and area-averaged onto a grid about
:data:`LOOK_WIDTH_PX` pixels wide (an integer factor: exact and cheap), and coarse optical flow (DIS at its
fastest, on the grid's finest level) is computed between consecutive frames on worker threads while the
next frames decode. Averaging a frame down averages its sensor and codec noise with it, so a thin edge
moving a fifth of a pixel stands out on this grid (its motion is a twentieth of a grid pixel, but coherent
over the window). Kept, besides the coarse flow:

- the mean grey frame (the texture the flow can hold on to, :mod:`workers.pipeline.confidence`);
- the brightness of 8 x 8 blocks of each frame and their change (lighting flicker, codec keyframes);
- the motion of the picture's border in each map (the camera's own, removed when the border moves as a
  whole, :mod:`workers.pipeline.camera`);
- the largest per-frame motion (how fine the second pass must be);
- the window's grey frames at full resolution and its depth on a half-resolution grid, written as they
  decode to a temporary file (:class:`KeptFrames`), so that the second pass (:mod:`workers.pipeline.fine`)
  decodes no frame twice and the window's frames never sit in the process's memory (1000 frames of
  640 x 420 are 269 MB; decoding them again cost a tenth of the analysis).

The whole-picture statistics of :mod:`workers.pipeline.significance` and the artefact evidence of
:mod:`workers.pipeline.detection` are computed from a :class:`Look`; the second pass measures the regions
it found.
"""

from __future__ import annotations

import math
import os
import tempfile
import threading
import time
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TypeVar

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.camera import CameraRing, remove_camera_motion
from workers.pipeline.clipio.types import MIN_FRAMES, ClipReader
from workers.pipeline.codec import keyframe_maps, repair_keyframe_maps
from workers.pipeline.confidence import Confidence, flow_confidence
from workers.pipeline.errors import AnalysisError
from workers.pipeline.fft import warm_up as spectrum_warm_up
from workers.pipeline.light import BRIGHTNESS_BLOCKS, block_brightness, block_change
from workers.pipeline.model import Progress, report_progress

#: Width of the coarse grid, pixels (an integer factor below the frame's width, never above it).
LOOK_WIDTH_PX = 160
#: Threads computing the coarse flow while the main thread decodes (consecutive pairs are independent).
FLOW_THREADS = 2

_T = TypeVar("_T")


@dataclass(frozen=True)
class CoarseGrid:
    """The look's grid: input frames cropped to a multiple of ``factor`` and area-averaged by it.

    Attributes
    ----------
    factor : int
        Input pixels per grid pixel (along each axis).
    shape : (h, w)
    """

    factor: int
    shape: tuple[int, int]

    @classmethod
    def for_frame(cls, height: int, width: int, *, width_px: int = LOOK_WIDTH_PX) -> CoarseGrid:
        """The grid for frames ``height`` x ``width``: about ``width_px`` wide, at least 16 x 12."""
        factor = max(1, round(width / max(width_px, 1)))
        while factor > 1 and (width // factor < 16 or height // factor < 12):
            factor -= 1
        return cls(factor, (height // factor, width // factor))

    def shrink(self, gray: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """A grey frame (H, W) on the grid."""
        if self.factor == 1:
            return np.ascontiguousarray(gray[: self.shape[0], : self.shape[1]])
        h, w = self.shape
        crop = gray[: h * self.factor, : w * self.factor]
        return np.asarray(cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA), np.uint8)


class KeptFrames:
    """The window's frames as the first pass decoded them, for the second pass: grey frames at input
    resolution and depth on a half-resolution grid, appended to an unlinked temporary file (the system's
    page cache holds them, not the process) and read back one at a time.

    Parameters
    ----------
    gray_shape : (H, W)
    depth_shape : (hd, wd) or None
        None when the clip has no depth.
    directory : path-like, optional
        Where the temporary file lies; default the system's temporary folder.
    """

    def __init__(
        self,
        gray_shape: tuple[int, int],
        depth_shape: tuple[int, int] | None,
        *,
        directory: str | None = None,
    ) -> None:
        self.gray_shape, self.depth_shape = gray_shape, depth_shape
        self._gray_bytes = gray_shape[0] * gray_shape[1]
        self._depth_bytes = 0 if depth_shape is None else depth_shape[0] * depth_shape[1] * 4
        self._file = tempfile.TemporaryFile(dir=directory)  # noqa: SIM115 (closed by close())
        self._count = 0

    @property
    def _stride(self) -> int:
        return self._gray_bytes + self._depth_bytes

    def __len__(self) -> int:
        return self._count

    def append(self, gray: NDArray[np.uint8], depth: NDArray[np.float32] | None) -> None:
        """Write the next frame (``depth`` None on a frame without one: NaN is kept)."""
        parts = [np.ascontiguousarray(gray, np.uint8).data]
        if self.depth_shape is not None:
            if depth is None:
                depth = np.full(self.depth_shape, np.nan, np.float32)
            parts.append(np.ascontiguousarray(depth, np.float32).data)
        os.pwritev(self._file.fileno(), parts, self._count * self._stride)
        self._count += 1

    def frame(self, i: int) -> tuple[NDArray[np.uint8], NDArray[np.float32] | None]:
        """Frame ``i``: grey (H, W) uint8 and depth (hd, wd) float32 metres or None."""
        if not 0 <= i < self._count:
            raise IndexError(f"frame {i} of {self._count} kept frames")
        gray = np.empty(self.gray_shape, np.uint8)
        parts = [gray.data.cast("B")]
        depth = None
        if self.depth_shape is not None:
            depth = np.empty(self.depth_shape, np.float32)
            parts.append(depth.data.cast("B"))
        if os.preadv(self._file.fileno(), parts, i * self._stride) != self._stride:
            raise OSError(f"the kept frame {i} could not be read back from its temporary file")
        return gray, depth

    def truncate(self, count: int) -> None:
        """Keep the first ``count`` frames only."""
        self._count = min(self._count, count)

    def close(self) -> None:
        """Remove the file (the frames are gone)."""
        self._file.close()


@dataclass
class Look:
    """What :func:`look_at` saw of a window.

    Attributes
    ----------
    grid : CoarseGrid
    flow : ndarray of float32, shape (N, h, w, 2)
        Coarse flow, grid pixels per frame; the camera's motion removed when ``camera_removed``.
    mean_gray : ndarray of float32, shape (h, w)
    confidence : Confidence
        Of ``mean_gray``.
    count : int
        Flow maps N.
    announced : int
        Flow maps the reader announced (more than ``count`` when the clip ended early).
    times_s : ndarray of float64, shape (N + 1,)
        Capture times from the window's first frame.
    start_s : float
        Capture time of the window's first frame, from the clip's first.
    first_rgb : ndarray of uint8, shape (H, W, 3)
    brightness : ndarray of float32, shape (N + 1, B, B)
        Mean grey level of B x B blocks of each frame.
    frame_change : ndarray of float32, shape (N, B, B)
        Mean absolute change of each block between consecutive frames.
    keyframe_maps : ndarray of intp, shape (M,)
        The maps that span a codec's keyframe (:func:`~workers.pipeline.codec.keyframe_maps`), repaired
        in ``flow`` (and to be repaired in any other flow of the window).
    border_px : ndarray of float32, shape (N, 2)
        Median motion of the picture's border in each map, grid pixels (before any removal).
    camera_px : ndarray of float32, shape (N, 2)
        The camera's motion removed from ``flow`` (zeros when none was).
    camera_removed : bool
    camera_still_fraction : float
        See :meth:`workers.pipeline.camera.CameraRing.still_fraction`.
    ring : CameraRing
        The border ring on the grid, its texture set.
    max_step_px : float
        Per-frame motion of the fastest moving pixels, input pixels (99th percentile over the pixels,
        90th over the frames).
    decode_s : float
        CPU seconds the reader spent.
    kept : KeptFrames or None
    """

    grid: CoarseGrid
    flow: NDArray[np.float32]
    mean_gray: NDArray[np.float32]
    confidence: Confidence
    count: int
    announced: int
    times_s: NDArray[np.float64]
    start_s: float
    first_rgb: NDArray[np.uint8]
    brightness: NDArray[np.float32]
    frame_change: NDArray[np.float32]
    keyframe_maps: NDArray[np.intp]
    border_px: NDArray[np.float32]
    camera_px: NDArray[np.float32]
    camera_removed: bool
    camera_still_fraction: float
    ring: CameraRing
    max_step_px: float
    decode_s: float
    kept: KeptFrames | None

    @property
    def input_px_per_grid_px(self) -> float:
        return float(self.grid.factor)


def _coarse_dis() -> cv2.DISOpticalFlow:
    dis = cv2.DISOpticalFlow.create(cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST)
    dis.setFinestScale(0)  # the grid is already coarse: do not skip its finest level
    return dis


class _Frames:
    """The window's frames as (grey at input resolution, depth on the depth grid or None, time), with
    the first frame's colour and the reader's CPU time."""

    def __init__(self, reader: ClipReader, start: int, stop: int, depth_shape: tuple[int, int]) -> None:
        self.reader, self.start, self.stop, self.depth_shape = reader, start, stop, depth_shape
        self.first_rgb: NDArray[np.uint8] | None = None
        self.decode_s = 0.0

    def __iter__(self) -> Iterator[tuple[NDArray[np.uint8], NDArray[np.float32] | None, float]]:
        info = self.reader.info
        stamps = info.timestamps_s
        fps = info.fps or 1.0
        if info.has_depth:
            frames = self.reader.frames_with_depth_on(self.depth_shape, self.start, self.stop)
            for frame in self._timed(frames):
                if self.first_rgb is None:
                    self.first_rgb = np.array(frame.rgb, copy=True)
                gray = np.asarray(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), np.uint8)
                yield gray, frame.depth_m, frame.timestamp_s
            return
        first = next(iter(self.reader.frames(self.start, self.start + 1)), None)
        if first is not None:
            self.first_rgb = np.array(first.rgb, copy=True)
        for i, gray in enumerate(self._timed(self.reader.gray_frames(self.start, self.stop))):
            index = self.start + i
            yield gray, None, float(stamps[index]) if stamps is not None else index / fps

    def _timed(self, items: Iterator[_T]) -> Iterator[_T]:
        """``items``, adding the reader's own CPU time (its wall time would count the moments the flow
        thread held the CPU)."""
        while True:
            started = time.thread_time()
            item = next(items, None)
            self.decode_s += time.thread_time() - started
            if item is None:
                return
            yield item


def look_at(
    reader: ClipReader,
    start: int,
    stop: int,
    *,
    progress: Progress | None = None,
    keep: bool = True,
    width_px: int = LOOK_WIDTH_PX,
) -> Look:
    """The first pass over frames ``[start, stop)`` (see the module's description).

    Parameters
    ----------
    reader : ClipReader
    start, stop : int
        Frame range of the window (of ``reader``: a strided reader for a window analysed every k-th frame).
    progress : callable, optional
    keep : bool
        Keep the frames for the second pass (:class:`KeptFrames`).
    width_px : int
        Width of the coarse grid (about).

    Returns
    -------
    Look

    Raises
    ------
    AnalysisError
        When fewer than :data:`MIN_FRAMES` frames decode.
    """
    # The FFT library's import (a third of a second, cold) overlaps this pass's decoding and flow instead
    # of delaying the scan that follows it.
    threading.Thread(target=spectrum_warm_up, name="spectrum-warm-up", daemon=True).start()
    info = reader.info
    grid = CoarseGrid.for_frame(info.height, info.width, width_px=width_px)
    n = stop - start - 1
    depth_shape = ((info.height + 1) // 2, info.width // 2 + info.width % 2)
    state = _LookState(
        grid,
        n,
        full_shape=(info.height, info.width) if keep else None,
        depth_shape=depth_shape if keep and info.has_depth else None,
    )
    source = _Frames(reader, start, stop, depth_shape)
    own = threading.local()  # a DIS instance per flow thread (one instance is not safe to share)

    def flow(prev: NDArray[np.uint8], nxt: NDArray[np.uint8], i: int) -> int:
        if not hasattr(own, "dis"):
            own.dis = _coarse_dis()
        state.flow[i] = own.dis.calc(prev, nxt, None)
        return i

    pending: deque[Future[int]] = deque()
    previous: NDArray[np.uint8] | None = None
    with ThreadPoolExecutor(max_workers=FLOW_THREADS, thread_name_prefix="look") as pool:
        try:
            for i, (gray, depth, stamp) in enumerate(source):
                small = state.add(i, gray, depth, stamp)
                if previous is not None:
                    pending.append(pool.submit(flow, previous, small, i - 1))
                    if len(pending) >= 2 * FLOW_THREADS + 1:
                        state.flowed(pending.popleft().result())
                previous = small
                if i % 16 == 0:
                    report_progress(progress, "look", i / max(n, 1))
                if i >= n:
                    break
            while pending:
                state.flowed(pending.popleft().result())
        finally:
            for job in pending:
                job.cancel()
    if source.first_rgb is None or state.frames < MIN_FRAMES:
        raise AnalysisError(
            f"the clip ended after {state.frames} of the {n + 1} frames it announced; at least "
            f"{MIN_FRAMES} frames are needed"
        )
    return state.finish(first_rgb=source.first_rgb, decode_s=source.decode_s)


class _LookState:
    """The buffers :func:`look_at` fills frame by frame, and what it makes of them at the end."""

    def __init__(
        self,
        grid: CoarseGrid,
        n: int,
        *,
        full_shape: tuple[int, int] | None,
        depth_shape: tuple[int, int] | None,
    ) -> None:
        h, w = grid.shape
        blocks = BRIGHTNESS_BLOCKS
        self.grid, self.n = grid, n
        self.flow = np.empty((n, h, w, 2), np.float32)
        self.sum = np.zeros((h, w), np.float64)
        self.times = np.empty(n + 1, np.float64)
        self.brightness = np.empty((n + 1, blocks, blocks), np.float32)
        self.change = np.zeros((n, blocks, blocks), np.float32)
        self.ring = CameraRing(grid.shape)
        self.frames = 0
        self.flows = 0
        self._previous: NDArray[np.uint8] | None = None
        self.kept = None if full_shape is None else KeptFrames(full_shape, depth_shape)

    def add(
        self, i: int, gray: NDArray[np.uint8], depth: NDArray[np.float32] | None, stamp: float
    ) -> NDArray[np.uint8]:
        """Frame ``i``: its coarse image (returned), brightness, change, and what is kept of it."""
        small = self.grid.shrink(gray)
        self.sum += small
        self.times[i] = stamp
        self.brightness[i] = block_brightness(small)
        if self._previous is not None:
            self.change[i - 1] = block_change(self._previous, small)
        self._previous = small
        if self.kept is not None:
            try:
                self.kept.append(gray, depth)
            except OSError:  # no room for the temporary file: the second pass reads the clip again
                self.kept.close()
                self.kept = None
        self.frames = i + 1
        return small

    def flowed(self, i: int) -> None:
        self.flows = max(self.flows, i + 1)

    def finish(self, *, first_rgb: NDArray[np.uint8], decode_s: float) -> Look:
        count = min(self.flows, self.frames - 1)
        flow, times = self.flow[:count], self.times[: count + 1]
        keyframes = keyframe_maps(self.change[:count])
        repair_keyframe_maps(flow, keyframes)
        mean = (self.sum / max(self.frames, 1)).astype(np.float32)
        self.ring.set_texture(np.clip(mean, 0, 255).astype(np.uint8))
        flat = flow.reshape(count, -1, 2)
        camera = remove_camera_motion(flow, self.ring.motions(flat), self.ring)
        if self.kept is not None:
            self.kept.truncate(count + 1)
        confidence = flow_confidence(mean, frame_noise=frame_noise(self.change[:count]))
        return Look(
            grid=self.grid,
            flow=flow,
            mean_gray=mean,
            confidence=confidence,
            count=count,
            announced=self.n,
            times_s=times - times[0],
            start_s=float(times[0]),
            first_rgb=first_rgb,
            brightness=self.brightness[: count + 1],
            frame_change=self.change[:count],
            keyframe_maps=keyframes,
            border_px=camera.border_px,
            camera_px=camera.camera_px,
            camera_removed=camera.removed,
            camera_still_fraction=camera.still_fraction,
            ring=self.ring,
            max_step_px=_fastest(flow, confidence.weight >= 0.5) * self.grid.factor,
            decode_s=decode_s,
            kept=self.kept,
        )


def frame_noise(change: NDArray[np.float32]) -> float:
    """One frame's noise (standard deviation, grey levels) from the mean absolute change of blocks
    between consecutive frames (E|X| = 2 sigma / sqrt(pi) for the difference X of two frames' noise): the
    median block's (most of a picture is still), as a root mean square over the frames (a codec repeats
    a still picture between its keyframes and changes it at each: the noise's power is in those
    changes); never below the rounding of grey levels to integers (the flow is computed on 8-bit
    frames)."""
    quantisation = 1 / math.sqrt(12)
    if change.size == 0:
        return quantisation
    per_frame = np.median(change.reshape(len(change), -1).astype(np.float64), axis=1)
    return max(quantisation, math.sqrt(float(np.mean(per_frame**2))) * math.sqrt(math.pi) / 2)


def _fastest(flow: NDArray[np.float32], textured: NDArray[np.bool_]) -> float:
    """The per-frame motion of the fastest moving textured pixels (flat ones show noise): the 99th
    percentile over the pixels of each map, the 90th over the maps (robust to a few glitches), grid
    pixels."""
    if len(flow) == 0 or not textured.any():
        return 0.0
    step = max(1, len(flow) // 64)
    sample = flow[::step].reshape(len(flow[::step]), -1, 2)[:, textured.ravel()]
    speed = np.sqrt((sample.astype(np.float32) ** 2).sum(axis=2))
    top = np.percentile(speed, 99, axis=1)
    return float(np.percentile(top, 90)) if math.isfinite(float(top.max())) else 0.0


__all__ = [
    "LOOK_WIDTH_PX",
    "CoarseGrid",
    "KeptFrames",
    "Look",
    "look_at",
]

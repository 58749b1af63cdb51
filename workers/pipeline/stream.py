"""The frame stream: frames of a window read once, turned grey onto the flow grid, their optical flow
computed on both cores as they arrive, depth sampled onto the grid, and the camera's own motion removed.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.camera import CameraRemoval, CameraRing, remove_camera_motion
from workers.pipeline.clipio.types import MIN_FRAMES, ClipReader, Frame
from workers.pipeline.errors import AnalysisError
from workers.pipeline.fft import warm_up as spectrum_warm_up
from workers.pipeline.flow import FlowConfig, flow_magnitude, flow_stream, prepare_gray
from workers.pipeline.light import BRIGHTNESS_BLOCKS, block_brightness, block_change
from workers.pipeline.model import Progress, report_progress
from workers.pipeline.roi import Roi


@dataclass
class FrameBuffers:
    """What the frame stream keeps of a window.

    Attributes
    ----------
    flow : ndarray of float32, shape (N, h, w, 2)
        Flow maps (the camera's motion removed when ``camera_removed``); (N, h, w, 1) magnitudes for
        the paper's recipe.
    depth : ndarray of float32, shape (N + 1, h, w), or None
        Depth on the grid, metres, NaN invalid.
    gray : ndarray of uint8, shape (N + 1, H', W'), or None
        Grey frames of the box, for registration: at input resolution, or on a coarser grid when they
        would not fit a memory budget (``gray_pixel_scale``).
    first_rgb : ndarray of uint8, shape (H, W, 3)
    count : int
        Flow maps N.
    times_s : ndarray of float64, shape (N + 1,)
        Capture times, seconds from the window's first frame.
    camera_px : ndarray of float32, shape (N, 2)
        Per-frame camera motion removed from ``flow``, grid pixels (zeros when none was removed).
    start_s : float
        Capture time of the window's first frame, seconds from the clip's first frame.
    decode_s : float
        CPU time the reader took to read and decode the frames (beside the flow).
    brightness : ndarray of float32, shape (N + 1, B, B)
        Mean grey level of each of B x B blocks of each frame (lighting flicker shows here).
    frame_change : ndarray of float32, shape (N, B, B)
        Mean absolute grey-level change of each block between consecutive frames (codec keyframes pulse
        in every block at once).
    camera_removed : bool
    border_px : ndarray of float32, shape (N, 2), or None
        The median motion of the picture's border in each map, grid pixels, whether removed or not.
    camera_still_fraction : float
        Fraction of the border's textured pixels that stayed still while its median moved (a high value
        means an object, not the camera, moved the border).
    announced : int
        Flow maps the reader announced; more than ``count`` when the clip ended early.
    roi : Roi or None
        The box of the frame the flow grid covers (None: the whole frame).
    gray_pixel_scale : float
        Input pixels per pixel of ``gray`` (1: input resolution).
    pooled_flow : ndarray of float32, shape (N, h / k, w / k, 2), or None
        ``flow`` on the first pass's grid (:func:`workers.pipeline.front.pool_map`, the camera's motion
        removed alike) when the stream pooled each map as it arrived (a live stream); None: pooled when
        needed.
    """

    flow: NDArray[np.float32]
    depth: NDArray[np.float32] | None
    gray: NDArray[np.uint8] | None
    first_rgb: NDArray[np.uint8]
    count: int
    times_s: NDArray[np.float64]
    camera_px: NDArray[np.float32]
    start_s: float
    decode_s: float = 0.0
    brightness: NDArray[np.float32] | None = None
    frame_change: NDArray[np.float32] | None = None
    camera_removed: bool = False
    border_px: NDArray[np.float32] | None = None
    camera_still_fraction: float = 0.0
    announced: int = 0
    roi: Roi | None = None
    gray_pixel_scale: float = 1.0
    pooled_flow: NDArray[np.float32] | None = None

    def box(self, frame_shape: tuple[int, int]) -> Roi:
        """The box the flow grid covers (the whole frame when ``roi`` is None)."""
        if self.roi is not None:
            return self.roi
        return Roi.whole(frame_shape, (int(self.flow.shape[1]), int(self.flow.shape[2])))


def stream_frames(
    reader: ClipReader,
    start: int,
    stop: int,
    grid: tuple[int, int],
    flow_cfg: FlowConfig,
    progress: Progress | None,
    magnitude: bool = False,
    keep_gray: bool = False,
) -> FrameBuffers:
    """Read frames ``[start, stop)`` of ``reader`` once and keep what the analysis needs of them.

    Parameters
    ----------
    reader : ClipReader
    start, stop : int
        Frame range.
    grid : (h, w)
        Flow grid.
    flow_cfg : FlowConfig
    progress : callable or None
    magnitude : bool
        Keep flow magnitudes (the paper's recipe) instead of signed flow.
    keep_gray : bool
        Keep the grey frames at input resolution (for registration).

    Returns
    -------
    FrameBuffers
        A clip that ends early (a damaged or truncated file) gives the frames that decoded, with
        ``announced`` saying how many were expected.

    Raises
    ------
    AnalysisError
        When fewer than ``MIN_FRAMES`` frames decoded.
    """
    # The FFT library's import (a third of a second) overlaps decoding and flow instead of following them.
    threading.Thread(target=spectrum_warm_up, name="spectrum-warm-up", daemon=True).start()
    n = stop - start - 1
    kept = _Kept(
        n, grid, reader.info.has_depth, (reader.info.height, reader.info.width) if keep_gray else None
    )
    frames = iter(reader.frames_with_depth_on(grid, start, stop))
    flow_buf, camera, count = _flows(kept, frames, flow_cfg, magnitude=magnitude, progress=progress)
    if kept.first_rgb is None or count + 1 < MIN_FRAMES:
        raise AnalysisError(
            f"the clip ended after {kept.frames_read} of the {n + 1} frames it announced; at least "
            f"{MIN_FRAMES} frames are needed"
        )
    if count < n:  # the clip ended early: keep what decoded
        flow_buf, camera = flow_buf[:count], camera[:count]
        kept.trim(count + 1)
    removal = (
        CameraRemoval(camera_px=camera * 0, border_px=camera, removed=False, still_fraction=0.0)
        if magnitude
        else remove_camera_motion(flow_buf, camera, kept.ring)
    )
    return FrameBuffers(
        camera_px=removal.camera_px,
        border_px=removal.border_px,
        flow=flow_buf,
        depth=kept.depth,
        gray=kept.gray,
        first_rgb=kept.first_rgb,
        count=count,
        times_s=kept.times - kept.times[0],
        start_s=float(kept.times[0]),
        decode_s=kept.decode_s,
        brightness=kept.brightness,
        frame_change=kept.change,
        camera_removed=removal.removed,
        camera_still_fraction=removal.still_fraction,
        announced=n,
    )


def _flows(
    kept: _Kept, frames: Iterator[Frame], flow_cfg: FlowConfig, *, magnitude: bool, progress: Progress | None
) -> tuple[NDArray[np.float32], NDArray[np.float32], int]:
    """The flow of ``frames`` (N, h, w, 2), or its magnitude (N, h, w, 1), each map's border motion
    (N, 2), and how many maps the frames gave (N at most: a clip may end early)."""
    n = kept.n
    flow_buf = np.empty((n, *kept.grid, 1 if magnitude else 2), np.float32)
    # The camera's own motion (shake, drift) moves the whole frame; estimate it each frame from a ring
    # along the border (see workers.pipeline.camera) so that it is neither an object nor mixed into one.
    camera = np.zeros((n, 2), np.float32)
    # Flow is written straight into the buffer by the flow threads (magnitudes are reduced here); the
    # camera's motion is taken from each map while the threads compute the next ones.
    count = 0
    for i, flow in enumerate(
        flow_stream(kept.grays(frames), config=flow_cfg, out=None if magnitude else flow_buf)
    ):
        if magnitude:
            flow_buf[i, ..., 0] = flow_magnitude(flow)
        else:
            camera[i] = kept.ring.motion(flow)
        count = i + 1
        if i % 8 == 0 or i == n - 1:
            report_progress(progress, "flow", count / n)
    return flow_buf, camera, count


class _Kept:
    """What the frame stream keeps of each frame as it passes on its way to the flow: capture times, the
    first colour frame, depth on the grid, grey frames (at input resolution, ``gray_shape``, or none),
    block brightness and change, and the camera ring's texture."""

    def __init__(
        self, n: int, grid: tuple[int, int], has_depth: bool, gray_shape: tuple[int, int] | None
    ) -> None:
        self.n, self.grid, self.has_depth = n, grid, has_depth
        self.times = np.empty(n + 1, np.float64)
        self.first_rgb: NDArray[np.uint8] | None = None
        self.depth: NDArray[np.float32] | None = None
        self.gray = None if gray_shape is None else np.empty((n + 1, *gray_shape), np.uint8)
        self.brightness = np.empty((n + 1, BRIGHTNESS_BLOCKS, BRIGHTNESS_BLOCKS), np.float32)
        self.change = np.zeros((n, BRIGHTNESS_BLOCKS, BRIGHTNESS_BLOCKS), np.float32)
        self.ring = CameraRing(grid)
        self.decode_s = 0.0  # CPU seconds spent in the reader
        self.frames_read = 0

    def grays(self, frames: Iterator[Frame]) -> Iterator[NDArray[np.uint8]]:
        """Each frame of ``frames`` grey on the grid, after keeping what the analysis needs of it."""
        previous: NDArray[np.uint8] | None = None
        for i in itertools.count():
            # The reader's own CPU time: its wall time would count the moments the flow threads, busy on
            # both cores meanwhile, held the CPU.
            started = time.thread_time()
            frame = next(frames, None)
            self.decode_s += time.thread_time() - started
            if frame is None:
                return
            self.frames_read = i + 1
            small = self._keep(i, frame)
            self.brightness[i] = block_brightness(small)
            if previous is not None:
                self.change[i - 1] = block_change(previous, small)
            else:
                self.ring.set_texture(small)
            previous = small
            yield small

    def _keep(self, i: int, frame: Frame) -> NDArray[np.uint8]:
        """Keep frame ``i``'s time, colour (the first), depth and grey frame; its grey frame on the grid."""
        import cv2

        h, w = self.grid
        self.times[i] = frame.timestamp_s
        if self.first_rgb is None:
            self.first_rgb = np.array(frame.rgb, copy=True)
        if self.has_depth and frame.depth_m is not None:
            # A reader that can sample depth onto the grid before converting it to metres saves the
            # conversion of pixels the grid drops (same values: nearest-neighbour either way).
            if self.depth is None:
                self.depth = np.empty((self.n + 1, h, w), np.float32)
                self.depth[:i] = np.nan
            d = frame.depth_m
            self.depth[i] = (
                d if d.shape == self.grid else cv2.resize(d, (w, h), interpolation=cv2.INTER_NEAREST)
            )
        elif self.depth is not None:
            self.depth[i] = np.nan
        if self.gray is None:
            return prepare_gray(frame.rgb, self.grid)
        full = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY, dst=self.gray[i])
        small = full if full.shape == self.grid else cv2.resize(full, (w, h), interpolation=cv2.INTER_AREA)
        return np.asarray(small, np.uint8)

    def trim(self, frames: int) -> None:
        """Keep the first ``frames`` frames only (the clip ended early)."""
        self.times, self.brightness, self.change = (
            self.times[:frames],
            self.brightness[:frames],
            self.change[: frames - 1],
        )
        if self.depth is not None:
            self.depth = self.depth[:frames]
        if self.gray is not None:
            self.gray = self.gray[:frames]


__all__ = [
    "BRIGHTNESS_BLOCKS",
    "FrameBuffers",
    "stream_frames",
]

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

from workers.pipeline.camera import CameraRing
from workers.pipeline.clipio.types import MIN_FRAMES, ClipReader, Frame
from workers.pipeline.errors import AnalysisError
from workers.pipeline.fft import warm_up as spectrum_warm_up
from workers.pipeline.flow import FlowConfig, flow_magnitude, flow_stream, prepare_gray
from workers.pipeline.light import BRIGHTNESS_BLOCKS
from workers.pipeline.model import Progress
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
    import cv2

    # The FFT library's import (a third of a second) overlaps decoding and flow instead of following them.
    threading.Thread(target=spectrum_warm_up, name="spectrum-warm-up", daemon=True).start()
    n = stop - start - 1
    h, w = grid
    channels = 1 if magnitude else 2
    flow_buf = np.empty((n, h, w, channels), np.float32)
    depth_buf: NDArray[np.float32] | None = None
    first_rgb: NDArray[np.uint8] | None = None
    times = np.empty(n + 1, np.float64)
    has_depth = reader.info.has_depth
    info = reader.info
    gray_buf = np.empty((n + 1, info.height, info.width), np.uint8) if keep_gray else None
    blocks = BRIGHTNESS_BLOCKS
    brightness = np.empty((n + 1, blocks, blocks), np.float32)
    change = np.zeros((n, blocks, blocks), np.float32)
    ring = CameraRing(grid)
    decode_s = 0.0  # CPU seconds spent in the reader
    frames_read = 0

    def grays() -> Iterator[NDArray[np.uint8]]:
        nonlocal depth_buf, first_rgb, decode_s, frames_read
        # A reader that can sample depth onto the grid before converting it to metres saves the
        # conversion of pixels the grid drops (same values: nearest-neighbour either way).
        frames: Iterator[Frame] = iter(reader.frames_with_depth_on(grid, start, stop))
        previous: NDArray[np.uint8] | None = None
        for i in itertools.count():
            # The reader's own CPU time: its wall time would count the moments the flow threads,
            # busy on both cores meanwhile, held the CPU.
            started = time.thread_time()
            next_frame = next(frames, None)
            decode_s += time.thread_time() - started
            if next_frame is None:
                return
            frame = next_frame
            frames_read = i + 1
            times[i] = frame.timestamp_s
            if first_rgb is None:
                first_rgb = np.array(frame.rgb, copy=True)
            if has_depth and frame.depth_m is not None:
                if depth_buf is None:
                    depth_buf = np.empty((n + 1, h, w), np.float32)
                    depth_buf[:i] = np.nan
                d = frame.depth_m
                if d.shape != grid:
                    d = cv2.resize(d, (w, h), interpolation=cv2.INTER_NEAREST)
                depth_buf[i] = d
            elif depth_buf is not None:
                depth_buf[i] = np.nan
            if gray_buf is not None:
                full = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY, dst=gray_buf[i])
                small = full if full.shape == grid else cv2.resize(full, (w, h), interpolation=cv2.INTER_AREA)
            else:
                small = prepare_gray(frame.rgb, grid)
            brightness[i] = cv2.resize(small, (blocks, blocks), interpolation=cv2.INTER_AREA)
            if previous is not None:
                diff = cv2.absdiff(small, previous)
                change[i - 1] = cv2.resize(diff, (blocks, blocks), interpolation=cv2.INTER_AREA)
            else:
                ring.set_texture(small)
            previous = small
            yield small

    count = 0
    # The camera's own motion (shake, drift) moves the whole frame; estimate it each frame from a ring
    # along the border (see workers.pipeline.camera) so that it is neither an object nor mixed into one.
    camera = np.zeros((n, 2), np.float32)
    # Flow is written straight into the buffer by the flow threads (magnitudes are reduced here); the
    # camera's motion is taken from each map while the threads compute the next ones.
    direct = None if magnitude else flow_buf
    for i, flow in enumerate(flow_stream(grays(), config=flow_cfg, out=direct)):
        if magnitude:
            flow_buf[i, ..., 0] = flow_magnitude(flow)
        else:
            camera[i] = ring.motion(flow)
        count = i + 1
        if progress is not None and (i % 8 == 0 or i == n - 1):
            progress("flow", 0.05 + 0.75 * count / n)
    if first_rgb is None or count + 1 < MIN_FRAMES:
        raise AnalysisError(
            f"the clip ended after {frames_read} of the {n + 1} frames it announced; at least "
            f"{MIN_FRAMES} frames are needed"
        )
    if count < n:  # the clip ended early: keep what decoded
        flow_buf, camera, change = flow_buf[:count], camera[:count], change[:count]
        times, brightness = times[: count + 1], brightness[: count + 1]
        if depth_buf is not None:
            depth_buf = depth_buf[: count + 1]
        if gray_buf is not None:
            gray_buf = gray_buf[: count + 1]
    # Compensate only real camera motion: subtracting the jitter of a still camera (codec noise) from
    # every pixel would bury a sub-pixel vibration, and the median of a border an object reaches into is
    # the object's motion.
    flat = flow_buf.reshape(len(flow_buf), -1, channels)
    removed = not magnitude and ring.moves_as_whole(flat, camera)
    still = ring.still_fraction(flat, camera) if not magnitude else 0.0
    border = camera.copy()
    if removed:
        flow_buf -= camera[:, None, None, :]
    else:
        camera[:] = 0.0
    return FrameBuffers(
        camera_px=camera,
        border_px=border,
        flow=flow_buf,
        depth=depth_buf,
        gray=gray_buf,
        first_rgb=first_rgb,
        count=count,
        times_s=times - times[0],
        start_s=float(times[0]),
        decode_s=decode_s,
        brightness=brightness,
        frame_change=change,
        camera_removed=removed,
        camera_still_fraction=still,
        announced=n,
    )


__all__ = ["BRIGHTNESS_BLOCKS", "FrameBuffers", "stream_frames"]

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

from workers.pipeline.clipio.types import ClipReader, Frame
from workers.pipeline.errors import AnalysisError
from workers.pipeline.fft import warm_up as spectrum_warm_up
from workers.pipeline.flow import FlowConfig, flow_magnitude, flow_stream, prepare_gray
from workers.pipeline.model import Progress
from workers.pipeline.spectra import median_rows

#: RMS per-frame motion of the picture's border (flow-grid pixels) above which it is removed as camera motion.
CAMERA_MOTION_MIN_PX = 0.05


@dataclass
@dataclass
class FrameBuffers:
    """What the frame stream keeps of a window: flow maps, depth and grey frames, capture times and the
    camera's own motion."""

    flow: NDArray[np.float32]  # (N, h, w, 2)
    depth: NDArray[np.float32] | None  # (N + 1, h, w), metres, NaN invalid
    gray: NDArray[np.uint8] | None  # (N + 1, H, W) at input resolution, for registration
    first_rgb: NDArray[np.uint8]
    count: int
    times_s: NDArray[np.float64]  # (N + 1,) capture times, seconds from the window's first frame
    camera_px: NDArray[np.float32]  # (N, 2) per-frame camera motion removed from the flow, grid px
    start_s: float  # capture time of the window's first frame, seconds from the clip's first frame
    decode_s: float = 0.0  # CPU time the reader took to read and decode the frames (beside the flow)


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
    decode_s = 0.0  # CPU seconds spent in the reader

    def grays() -> Iterator[NDArray[np.uint8]]:
        nonlocal depth_buf, first_rgb, decode_s
        # A reader that can sample depth onto the grid before converting it to metres saves the
        # conversion of pixels the grid drops (same values: nearest-neighbour either way).
        on_grid = getattr(reader, "frames_with_depth_on", None)
        frames: Iterator[Frame] = iter(
            on_grid(grid, start, stop) if callable(on_grid) else reader.frames(start, stop)
        )
        for i in itertools.count():
            # The reader's own CPU time: its wall time would count the moments the flow threads,
            # busy on both cores meanwhile, held the CPU.
            started = time.thread_time()
            next_frame = next(frames, None)
            decode_s += time.thread_time() - started
            if next_frame is None:
                return
            frame = next_frame
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
                yield full if full.shape == grid else cv2.resize(full, (w, h), interpolation=cv2.INTER_AREA)
            else:
                yield prepare_gray(frame.rgb, grid)

    count = 0
    # The camera's own motion (shake, drift) moves the whole frame; estimate it each frame from a ring
    # along the border, where objects rarely are, and remove it so it is neither an object nor mixed
    # into one.
    ring = np.ones(grid, bool)
    mh, mw = max(1, round(0.12 * h)), max(1, round(0.12 * w))
    ring[mh:-mh, mw:-mw] = False
    # Every 7th ring pixel (7 shares no factor with common grid widths, so the samples do not line up
    # in columns): thousands of samples, whose median is as steady as all of theirs, at a third of the cost.
    ring_idx = np.flatnonzero(ring.ravel())[::7]
    # (u, v) of the ring's pixels in the flattened map: u indices first, then v.
    ring_uv = (ring_idx[None, :] * 2 + np.arange(2)[:, None]).ravel()
    camera = np.zeros((n, 2), np.float32)
    # Flow is written straight into the buffer by the flow threads (magnitudes are reduced here); the
    # camera's motion is taken from each map while the threads compute the next ones.
    direct = None if magnitude else flow_buf
    for i, flow in enumerate(flow_stream(grays(), config=flow_cfg, out=direct)):
        if magnitude:
            flow_buf[i, ..., 0] = flow_magnitude(flow)
        else:
            camera[i] = median_rows(flow.reshape(-1).take(ring_uv).reshape(2, -1))
        count = i + 1
        if progress is not None and (i % 8 == 0 or i == n - 1):
            progress("flow", 0.05 + 0.75 * count / n)
    if count < n or first_rgb is None:
        raise AnalysisError(f"the clip ended after {count + 1} of the {n + 1} frames it announced")
    # Compensate only real camera motion: subtracting the jitter of a still camera (codec noise) from
    # every pixel would bury a sub-pixel vibration.
    if not magnitude and float(np.sqrt(np.mean(camera.astype(np.float64) ** 2))) > CAMERA_MOTION_MIN_PX:
        flow_buf -= camera[:, None, None, :]
    else:
        camera[:] = 0.0
    return FrameBuffers(
        camera_px=camera,
        flow=flow_buf,
        depth=depth_buf,
        gray=gray_buf,
        first_rgb=first_rgb,
        count=count,
        times_s=times - times[0],
        start_s=float(times[0]),
        decode_s=decode_s,
    )


__all__ = ["CAMERA_MOTION_MIN_PX", "FrameBuffers", "stream_frames"]

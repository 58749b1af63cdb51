"""The second pass over a window: dense flow over the region that moves, at the resolution it needs.

The first pass (:mod:`workers.pipeline.look`) saw the whole picture on a coarse grid and found where it
moves (:mod:`workers.pipeline.significance`). :func:`plan_roi` draws a box around those regions, with a
margin of still background around them (the segmentation's noise reference), and chooses the box's flow
grid: full resolution when the box is small (a thin bar, a string), coarser when it is large or the window
long, within :data:`ROI_BUDGET_PX` grid pixels and :data:`ROI_BUDGET_MIB` of flow. :func:`stream_roi` then
computes the flow of that box only, from the frames the first pass kept (or read again when it could
not), with its depth and its grey frames at input resolution (registration), into
:class:`~workers.pipeline.stream.FrameBuffers` whose ``roi`` says where the box lies.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import MIN_FRAMES, ClipReader
from workers.pipeline.codec import keyframe_maps, repair_keyframe_maps
from workers.pipeline.errors import AnalysisError
from workers.pipeline.flow import FlowConfig, flow_stream
from workers.pipeline.look import Look
from workers.pipeline.model import Progress, report_progress
from workers.pipeline.roi import Roi
from workers.pipeline.stream import FrameBuffers

#: Most grid pixels the second pass computes flow for (the cost of half-resolution flow over 640 x 480).
ROI_BUDGET_PX = 320 * 240
#: Most memory the second pass's flow maps may take, MiB (the window's length bounds its grid: a 1000-frame
#: window of a 366 x 420 box gets a grid of 12,600 pixels, finer than the look's 4 x 4 blocks; the peak
#: memory of that analysis is then flat in the window's length).
ROI_BUDGET_MIB = 96.0
#: Most memory the second pass's grey frames may take at input resolution, MiB; beyond it they are kept
#: on the box's flow grid, where registration then works (they grow with the window: 146 MiB of a 1000-frame
#: window of a 366 x 420 box).
GRAY_BUDGET_MIB = 64.0
#: A box whose fastest pixels move this many input pixels a frame or more (the look's ``max_step_px``) is
#: measured in 2 x 2 blocks rather than a fraction of full resolution when it is over the budgets: the
#: motion is a grid pixel a frame or more there too.
HALVING_STEP_PX = 2.0
#: Background kept around the moving regions: this many input pixels at least ...
MIN_MARGIN_PX = 24
#: ... and this fraction of the square root of the regions' area (a large object gets a wide margin).
MARGIN_FRACTION = 0.5


def grid_for(
    width: int, height: int, *, samples: int, budget_px: int = ROI_BUDGET_PX, halve: bool = False
) -> tuple[int, int]:
    """The flow grid (h, w) of a ``width`` x ``height`` box: full resolution within ``budget_px`` and
    :data:`ROI_BUDGET_MIB` of flow for ``samples`` maps (float32 u and v), area-averaged below by the
    fraction they allow; with ``halve`` (a motion the half-resolution grid follows), in 2 x 2 blocks
    wherever full resolution is beyond them and halving is within them (OpenCV's exact area average,
    several times cheaper on every frame than a fractional one, and half the pixels)."""
    memory_px = ROI_BUDGET_MIB * 2**20 / (8 * max(samples, 1))
    allowed = max(64 * 48, min(budget_px, memory_px))
    scale = min(1.0, math.sqrt(allowed / max(width * height, 1)))
    if halve and 0.5 <= scale < 1.0:
        scale = 0.5
    return max(8, round(height * scale)), max(8, round(width * scale))


def plan_roi(
    look: Look,
    regions: Sequence[NDArray[np.bool_]],
    *,
    frame_shape: tuple[int, int],
    samples: int,
    budget_px: int = ROI_BUDGET_PX,
) -> Roi:
    """The box around the moving regions (coarse masks of the look's grid), with a margin of background,
    and its grid (:func:`grid_for`); the whole frame when no region was found.

    Parameters
    ----------
    look : Look
    regions : sequence of ndarray of bool, shape (h, w)
        Where the picture moves, on the look's grid.
    frame_shape : (H, W)
    samples : int
        Flow maps of the window (memory).
    budget_px : int

    Returns
    -------
    Roi
    """
    H, W = frame_shape
    box = _moving_box(regions, factor=look.grid.factor, frame_shape=frame_shape)
    if box is None:
        h, w = grid_for(W, H, samples=samples, budget_px=budget_px)
        return Roi(0, 0, W, H, (h, w), frame_shape)
    x0, y0, x1, y1 = box
    width, height = x1 - x0, y1 - y0
    halve = look.max_step_px >= HALVING_STEP_PX
    grid = grid_for(width, height, samples=samples, budget_px=budget_px, halve=halve)
    if halve and abs(2 * grid[1] - width) <= 1 and (x0, y0, width, height) != (0, 0, W, H):
        width, height = width - width % 2, height - height % 2  # whole 2 x 2 blocks (a pixel less)
        grid = (height // 2, width // 2)
    return Roi(x0, y0, width, height, grid, frame_shape)


def _moving_box(
    regions: Sequence[NDArray[np.bool_]], *, factor: float, frame_shape: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """The box (x0, y0, x1, y1), input pixels, around ``regions`` (masks of a grid of ``factor`` input
    pixels a pixel) with a margin of background; None when they are empty, (0, 0, W, H) when the box
    would hold most of the frame (the border shows the camera)."""
    H, W = frame_shape
    if not regions:
        return None
    union = np.zeros(regions[0].shape, bool)
    for region in regions:
        union |= region
    if not union.any():
        return None
    ys, xs = np.nonzero(union)
    x0, x1 = int(int(xs.min()) * factor), math.ceil((int(xs.max()) + 1) * factor)
    y0, y1 = int(int(ys.min()) * factor), math.ceil((int(ys.max()) + 1) * factor)
    area = float(union.sum()) * factor * factor
    margin = max(MIN_MARGIN_PX, round(MARGIN_FRACTION * math.sqrt(area)))
    x0, y0 = max(0, x0 - margin), max(0, y0 - margin)
    x1, y1 = min(W, x1 + margin), min(H, y1 + margin)
    if (x1 - x0) * (y1 - y0) >= 0.6 * W * H:
        return 0, 0, W, H
    return x0, y0, x1, y1


def crop_to_motion(
    buffers: FrameBuffers,
    regions: Sequence[NDArray[np.bool_]],
    *,
    factor: float,
    frame_shape: tuple[int, int],
) -> FrameBuffers:
    """A whole-frame window's buffers cut, on their own grid, to the box around the moving regions (with
    :func:`plan_roi`'s margin): what a live stream's final analysis measures, its flow computed as the
    frames came (the spectra, segmentation and measurement then cover the box, not the frame).

    Parameters
    ----------
    buffers : FrameBuffers
        Flow over the whole frame (``roi`` None); grey frames at input resolution or on the flow grid.
    regions : sequence of ndarray of bool, shape (h', w')
        Where the picture moves, on a grid of ``factor`` input pixels a pixel.
    factor : float
    frame_shape : (H, W)

    Returns
    -------
    FrameBuffers
        With ``roi`` set; ``buffers`` itself when nothing moves, when the box holds most of the frame, or
        when a grid pixel is not a whole number of input pixels (the box could not be cut on it).
    """
    H, W = frame_shape
    h, w = buffers.flow.shape[1:3]
    scale = W / w
    box = _moving_box(regions, factor=factor, frame_shape=frame_shape)
    if buffers.roi is not None or box is None or box == (0, 0, W, H) or scale != int(scale) or h * scale != H:
        return buffers
    s = int(scale)
    gx0, gy0 = box[0] // s, box[1] // s
    gx1, gy1 = min(w, -(-box[2] // s)), min(h, -(-box[3] // s))
    roi = Roi(gx0 * s, gy0 * s, (gx1 - gx0) * s, (gy1 - gy0) * s, (gy1 - gy0, gx1 - gx0), frame_shape)
    # The grey frames and the depth are views (they are read a frame or a few pixels at a time: copying
    # them cost a stream's final analysis 5 ms of fresh memory); the flow is copied, its pixels' series
    # are read whole.
    gray, gray_scale = buffers.gray, buffers.gray_pixel_scale
    if gray is not None and gray.shape[1:] == (H, W):
        rows, cols = slice(roi.y, roi.y + roi.height), slice(roi.x, roi.x + roi.width)
        gray, gray_scale = gray[:, rows, cols], 1.0
    elif gray is not None and gray.shape[1:] == (h, w):
        gray, gray_scale = gray[:, gy0:gy1, gx0:gx1], float(s)
    depth = buffers.depth
    return replace(
        buffers,
        flow=np.ascontiguousarray(buffers.flow[:, gy0:gy1, gx0:gx1]),
        depth=None if depth is None else depth[:, gy0:gy1, gx0:gx1],
        gray=gray,
        gray_pixel_scale=gray_scale,
        roi=roi,
        pooled_flow=None,
    )


@dataclass
class _Window:
    """The second pass's buffers, filled frame by frame."""

    roi: Roi
    n: int
    has_depth: bool

    def __post_init__(self) -> None:
        h, w = self.roi.grid_shape
        self.flow = np.empty((self.n, h, w, 2), np.float32)
        whole = (self.n + 1) * self.roi.height * self.roi.width <= GRAY_BUDGET_MIB * 2**20
        self.gray = np.empty(
            (self.n + 1, *((self.roi.height, self.roi.width) if whole else (h, w))), np.uint8
        )
        self.depth = np.full((self.n + 1, h, w), np.nan, np.float32) if self.has_depth else None
        self.frames = 0

    @property
    def gray_pixel_scale(self) -> float:
        """Input pixels per pixel of the kept grey frames."""
        return self.roi.width / self.gray.shape[2]

    def add(self, i: int, gray: NDArray[np.uint8], depth: NDArray[np.float32] | None) -> NDArray[np.uint8]:
        """Frame ``i``: its grey crop kept (at input resolution or on the grid), its depth on the grid;
        returns the grey frame on the grid."""
        crop = self.roi.crop(gray)
        if self.depth is not None and depth is not None:
            self.depth[i] = _depth_on(depth, self.roi)
        self.frames = i + 1
        h, w = self.roi.grid_shape
        if crop.shape == (h, w):
            self.gray[i] = crop
            return np.asarray(self.gray[i], np.uint8)
        small = np.asarray(cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA), np.uint8)
        self.gray[i] = small if self.gray.shape[1:] == (h, w) else crop
        return small


def _depth_on(depth: NDArray[np.float32], roi: Roi) -> NDArray[np.float32]:
    """A depth map of the whole frame on any grid, sampled (nearest) at the centres of the box's grid
    pixels: each grid pixel's depth is the depth under it, whatever the box's offset from the depth
    grid (a crop of the depth grid would shift it by up to a depth pixel: at an object's edge, a band of
    background at the object's depth)."""
    dh, dw = depth.shape
    H, W = roi.frame_shape
    h, w = roi.grid_shape
    ys = roi.y + (np.arange(h) + 0.5) * roi.height / h
    xs = roi.x + (np.arange(w) + 0.5) * roi.width / w
    rows = np.clip((ys * dh / H).astype(np.intp), 0, dh - 1)
    cols = np.clip((xs * dw / W).astype(np.intp), 0, dw - 1)
    return np.asarray(depth[rows[:, None], cols[None, :]], np.float32)


def _frames(
    source: ClipReader | Look, start: int, stop: int, depth_shape: tuple[int, int]
) -> Iterator[tuple[NDArray[np.uint8], NDArray[np.float32] | None]]:
    """Grey frames at input resolution and depth (on any grid), from the look's kept frames or read again."""
    if isinstance(source, Look):
        kept = source.kept
        assert kept is not None
        for i in range(len(kept)):
            yield kept.frame(i)
        return
    if source.info.has_depth:
        for frame in source.frames_with_depth_on(depth_shape, start, stop):
            yield np.asarray(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), np.uint8), frame.depth_m
    else:
        for gray in source.gray_frames(start, stop):
            yield gray, None


def stream_roi(
    source: ClipReader | Look,
    roi: Roi,
    *,
    start: int,
    stop: int,
    look: Look,
    flow_config: FlowConfig,
    progress: Progress | None = None,
) -> FrameBuffers:
    """The second pass: flow, depth and grey frames of the box over frames ``[start, stop)``.

    Parameters
    ----------
    source : ClipReader or Look
        A reader to read the frames again, or the look whose kept frames to use.
    roi : Roi
    start, stop : int
        The window's frame range (of the reader the look read).
    look : Look
        The first pass (its times, brightness, camera motion and first frame are the window's).
    flow_config : FlowConfig
        The flow's method and preset (its scale is the box's grid).
    progress : callable, optional

    Returns
    -------
    FrameBuffers
        On the box's grid, ``roi`` set.

    Raises
    ------
    AnalysisError
        When fewer than :data:`~workers.pipeline.clipio.types.MIN_FRAMES` frames decode.
    """
    n = look.count
    if isinstance(source, Look):
        has_depth = source.kept is not None and source.kept.depth_shape is not None
    else:
        has_depth = source.info.has_depth
    window = _Window(roi, n, has_depth)
    depth_shape = ((roi.frame_shape[0] + 1) // 2, (roi.frame_shape[1] + 1) // 2)
    decode_s = 0.0
    frames = iter(_frames(source, start, stop, depth_shape))

    def grays() -> Iterator[NDArray[np.uint8]]:
        nonlocal decode_s
        for i in itertools.count():
            started = time.thread_time()
            item = next(frames, None)
            decode_s += time.thread_time() - started
            if item is None or i > n:
                return
            yield window.add(i, *item)

    count = 0
    for i, _ in enumerate(flow_stream(grays(), config=flow_config, out=window.flow)):
        count = i + 1
        if i % 16 == 0 or count == n:
            report_progress(progress, "fine", count / max(n, 1))
    if count + 1 < MIN_FRAMES:
        raise AnalysisError(
            f"the clip ended after {window.frames} of the {n + 1} frames it announced; at least "
            f"{MIN_FRAMES} frames are needed"
        )
    return _buffers(window, count, look=look, decode_s=decode_s)


def _buffers(window: _Window, count: int, *, look: Look, decode_s: float) -> FrameBuffers:
    """The second pass's buffers, with the look's whole-picture series (times, brightness, camera)."""
    roi = window.roi
    to_grid = look.grid.factor / roi.pixel_scale  # grid pixels of the box per look grid pixel
    camera = (look.camera_px[:count] * to_grid).astype(np.float32)
    flow = window.flow[:count]
    repair_keyframe_maps(flow, keyframe_maps(look.frame_change[:count]))
    if look.camera_removed:
        flow -= camera[:, None, None, :]
    depth = None if window.depth is None else window.depth[: count + 1]
    return FrameBuffers(
        flow=flow,
        depth=depth,
        gray=window.gray[: count + 1],
        first_rgb=look.first_rgb,
        count=count,
        times_s=look.times_s[: count + 1],
        camera_px=camera,
        start_s=look.start_s,
        decode_s=look.decode_s + decode_s,
        brightness=look.brightness[: count + 1],
        frame_change=look.frame_change[:count],
        camera_removed=look.camera_removed,
        border_px=(look.border_px[:count] * to_grid).astype(np.float32),
        camera_still_fraction=look.camera_still_fraction,
        announced=look.announced,
        roi=roi,
        gray_pixel_scale=window.gray_pixel_scale,
    )


__all__ = [
    "GRAY_BUDGET_MIB",
    "HALVING_STEP_PX",
    "MARGIN_FRACTION",
    "MIN_MARGIN_PX",
    "ROI_BUDGET_MIB",
    "ROI_BUDGET_PX",
    "crop_to_motion",
    "grid_for",
    "plan_roi",
    "stream_roi",
]

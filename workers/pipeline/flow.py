"""Dense optical flow between consecutive frames (Farnebäck or DIS), computed while frames stream in.

Flow is computed on grey images, optionally downscaled by ``scale`` for speed; vectors are returned in
pixels of the computation grid (multiply by ``1 / scale`` for input pixels). Frame pairs are independent, so
:func:`flow_stream` spreads them over worker threads (OpenCV releases the GIL) while keeping output order
and holding at most ``2 * threads`` frames in flight.
"""

from __future__ import annotations

import itertools
import threading
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.errors import ParameterError

FlowMethod = Literal["farneback", "dis"]
DisPreset = Literal["ultrafast", "fast", "fine", "medium"]
_DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "fine": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
#: Settings changed from the base preset: (finest scale, patch size, patch stride, gradient-descent
#: iterations, variational-refinement iterations). "fine" keeps medium's finest scale (flow at full grid
#: resolution, so object edges stay sharp) and drops the variational refinement, which costs most of
#: medium's time: about 5x faster than medium. Its patches overlap less than medium's (stride 5 of 8
#: instead of 4): a third less time per frame pair (2.1 instead of 3.1 ms at 320x240 on one core), with
#: every ground-truth test still inside its bound.
_DIS_OVERRIDES = {"fine": (1, 8, 5, 16, 0)}


@dataclass(frozen=True, kw_only=True)
class FlowConfig:
    """How flow is computed.

    Attributes
    ----------
    method : ``"farneback"`` or ``"dis"``
    scale : float or None
        Downscale factor in (0, 1] applied before flow (0.5 = half width and height); None picks one
        from the frame width (see :meth:`effective_scale`).
    dis_preset : ``"ultrafast"``, ``"fast"`` or ``"medium"``
        DIS quality preset.
    threads : int
        Frame pairs computed at once.
    farneback : tuple
        (pyr_scale, levels, winsize, iterations, poly_n, poly_sigma), the paper's (0.5, 3, 15, 3, 5, 1.2).
    """

    method: FlowMethod = "dis"
    scale: float | None = None
    dis_preset: DisPreset = "fine"
    threads: int = 2
    farneback: tuple[float, int, int, int, int, float] = (0.5, 3, 15, 3, 5, 1.2)

    def __post_init__(self) -> None:
        if self.method not in ("farneback", "dis"):
            raise ParameterError(f"flow method {self.method!r} is unknown; use 'farneback' or 'dis'")
        if self.scale is not None and not 0 < self.scale <= 1:
            raise ParameterError(f"flow scale {self.scale} must be in (0, 1]")
        if self.dis_preset not in _DIS_PRESETS:
            raise ParameterError(
                f"DIS preset {self.dis_preset!r} is unknown; use ultrafast, fast, fine or medium"
            )
        if self.threads < 1:
            raise ParameterError("flow threads must be at least 1")

    def effective_scale(self, width: int) -> float:
        """The scale used for frames ``width`` pixels wide: the given one, or about 320 px of flow grid
        (half resolution at 640, full resolution at 320 and below, a quarter at 1280 and above)."""
        if self.scale is not None:
            return self.scale
        return float(min(1.0, max(0.25, 320.0 / max(width, 1))))

    def grid_shape(self, height: int, width: int) -> tuple[int, int]:
        """(h, w) of the flow grid for input frames of ``height`` x ``width``."""
        scale = self.effective_scale(width)
        if scale == 1:
            return height, width
        return max(8, round(height * scale)), max(8, round(width * scale))


def prepare_gray(rgb: NDArray[np.uint8], shape: tuple[int, int]) -> NDArray[np.uint8]:
    """Grey image on the flow grid.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (H, W, 3)
    shape : (h, w)
        Target grid; area-averaged when smaller than the input.

    Returns
    -------
    ndarray of uint8, shape (h, w)
    """
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    if gray.shape != shape:
        gray = cv2.resize(gray, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return np.asarray(gray, dtype=np.uint8)


class _Engine:
    """One flow engine per thread (DIS objects are not thread-safe)."""

    def __init__(self, config: FlowConfig) -> None:
        self.config = config
        self._local = threading.local()

    def __call__(
        self, prev: NDArray[np.uint8], nxt: NDArray[np.uint8], out: NDArray[np.float32] | None = None
    ) -> NDArray[np.float32]:
        cfg = self.config
        if cfg.method == "farneback":
            pyr, levels, win, iters, poly_n, poly_sigma = cfg.farneback
            flow = cv2.calcOpticalFlowFarneback(
                prev, nxt, out, pyr, levels, win, iters, poly_n, poly_sigma, 0
            )
        else:
            dis = getattr(self._local, "dis", None)
            if dis is None:
                dis = cv2.DISOpticalFlow.create(_DIS_PRESETS[cfg.dis_preset])
                if cfg.dis_preset in _DIS_OVERRIDES:
                    finest, patch, stride, descent, refine = _DIS_OVERRIDES[cfg.dis_preset]
                    dis.setFinestScale(finest)
                    dis.setPatchSize(patch)
                    dis.setPatchStride(stride)
                    dis.setGradientDescentIterations(descent)
                    dis.setVariationalRefinementIterations(refine)
                self._local.dis = dis
            # Never hand DIS a buffer to write into: it reads what the buffer holds (NaN crashes it,
            # zeros change the result), so it gets a fresh one and the flow is copied.
            flow = dis.calc(prev, nxt, None)
        if out is None:
            return np.asarray(flow, dtype=np.float32)
        if not np.shares_memory(flow, out):
            out[...] = flow
        return out


def compute_flow(
    prev: NDArray[np.uint8], nxt: NDArray[np.uint8], *, config: FlowConfig | None = None
) -> NDArray[np.float32]:
    """Flow from ``prev`` to ``nxt``.

    Parameters
    ----------
    prev, nxt : ndarray of uint8, shape (h, w)
        Grey frames on the flow grid (see :func:`prepare_gray`).
    config : FlowConfig, optional

    Returns
    -------
    ndarray of float32, shape (h, w, 2)
        (dx, dy) per pixel, in grid pixels.
    """
    return _Engine(config or FlowConfig())(prev, nxt)


def flow_stream(
    grays: Iterable[NDArray[np.uint8]],
    *,
    config: FlowConfig | None = None,
    out: NDArray[np.float32] | None = None,
) -> Iterator[NDArray[np.float32]]:
    """Flow between each pair of consecutive grey frames, in order.

    Parameters
    ----------
    grays : iterable of ndarray of uint8, shape (h, w)
        Frames on the flow grid; consumed lazily.
    config : FlowConfig, optional
    out : ndarray of float32, shape (N, h, w, 2), optional
        Where to write the flow maps: flow i goes straight into ``out[i]`` (written by the worker
        threads, so the caller neither copies it nor first-touches the buffer's memory itself). At most
        N pairs are computed; the frames after them are not consumed.

    Yields
    ------
    ndarray of float32, shape (h, w, 2)
        Flow from frame i to frame i + 1, for i = 0, 1, ...; ``out[i]`` itself when ``out`` is given.
    """
    config = config or FlowConfig()
    engine = _Engine(config)
    iterator = iter(grays)
    try:
        prev = next(iterator)
    except StopIteration:
        return
    following = iterator if out is None else itertools.islice(iterator, len(out))

    def slot(i: int) -> NDArray[np.float32] | None:
        return None if out is None else out[i]

    if config.threads == 1:
        for i, nxt in enumerate(following):
            yield engine(prev, nxt, slot(i))
            prev = nxt
        return
    pending: deque[Future[NDArray[np.float32]]] = deque()
    with ThreadPoolExecutor(max_workers=config.threads, thread_name_prefix="flow") as pool:
        try:
            for i, nxt in enumerate(following):
                pending.append(pool.submit(engine, prev, nxt, slot(i)))
                prev = nxt
                if len(pending) >= 2 * config.threads:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for fut in pending:
                fut.cancel()


def flow_magnitude(flow: NDArray[np.float32]) -> NDArray[np.float32]:
    """Per-pixel speed |v| of a flow field.

    Parameters
    ----------
    flow : ndarray of float32, shape (..., 2)

    Returns
    -------
    ndarray of float32, shape (...)
    """
    mag: Any = cv2.magnitude(np.ascontiguousarray(flow[..., 0]), np.ascontiguousarray(flow[..., 1]))
    return np.asarray(mag, dtype=np.float32)


def pixel_columns(maps: NDArray[np.floating[Any]], pixels: NDArray[np.intp]) -> NDArray[np.floating[Any]]:
    """The columns of the given pixels of a stack of maps, side by side: ``maps[:, pixels, :]`` as
    (N, C x P), in the maps' own dtype (C components per pixel: 2 for flow's u and v).

    Taken along each map's row of values (``np.take`` on (N, C x pixels)), three times faster than a fancy
    index over the pixel axis of (N, pixels, C) (20 000 pixels of 1000 flow maps: 0.16 s against 0.53 s).

    Parameters
    ----------
    maps : ndarray, shape (N, h, w, C) or (N, h x w, C)
    pixels : ndarray of intp, shape (P,)
        Flat indices into the maps' h x w pixels.

    Returns
    -------
    ndarray, shape (N, C x P)
        Columns ``C i`` to ``C i + C - 1`` are pixel ``pixels[i]``'s components (for flow: u, then v).
    """
    channels = maps.shape[-1]
    columns = (np.asarray(pixels, np.intp)[:, None] * channels + np.arange(channels)).ravel()
    return np.asarray(np.take(maps.reshape(len(maps), -1), columns, axis=1))


def to_float16(maps: NDArray[np.floating[Any]]) -> NDArray[np.float16]:
    """``maps.astype(np.float16)``, bit for bit, for a stack of maps (N, ...), each a view whose rows may
    lie apart (a box of a picture's flow).

    Converted by OpenCV (:func:`_converted`): numpy converts results below float16's normal range (6e-5,
    most of a still picture's flow) one value at a time, 5 to 20 times slower (1000 maps of a fork's box:
    0.2 s against 0.02 s).

    Parameters
    ----------
    maps : ndarray of float32 (or float16), shape (N, ...)

    Returns
    -------
    ndarray of float16, same shape
    """
    return _converted(maps, np.float16, cv2.CV_16F)


def as_float32(maps: NDArray[np.floating[Any]]) -> NDArray[np.float32]:
    """``np.asarray(maps, np.float32)`` for a stack of maps (N, ...): float16 maps (the front's kept flow)
    converted by OpenCV, exactly (see :func:`to_float16`: numpy is as slow the other way)."""
    if maps.dtype != np.float16:
        return np.asarray(maps, np.float32)
    return _converted(maps, np.float32, cv2.CV_32F)


def _converted(maps: NDArray[Any], dtype: type[np.floating[Any]], depth: int) -> NDArray[Any]:
    """``maps`` (N, ...) in ``dtype`` (OpenCV's ``depth``), written by OpenCV into a new array: at once when
    they lie in one block of memory, else a map at a time (a box's rows lie apart)."""
    if maps.ndim < 2 or maps.size == 0 or maps.size < _MIN_CONVERTED * len(maps):
        return maps.astype(dtype)  # (OpenCV takes a few values for a scalar)
    out = np.empty(maps.shape, dtype)
    pairs = [(maps, out)] if maps.flags.c_contiguous else zip(maps, out, strict=True)
    for source, target in pairs:
        # rows of one channel: OpenCV would multiply a second channel by the scalar's second component (0)
        rows = (len(source), -1) if source.ndim > 1 else (1, -1)
        cv2.multiply(source.reshape(rows), 1.0, dst=target.reshape(rows), dtype=depth)
    return out


#: Maps of fewer values than this are converted by numpy.
_MIN_CONVERTED = 64


def needs_resampling(
    timestamps_s: NDArray[np.float64], sample_rate_hz: float, *, tolerance: float = 0.05
) -> bool:
    """Whether frame times stray from a uniform grid at ``fps`` by more than ``tolerance`` of a period."""
    if len(timestamps_s) < 2:
        return False
    period = 1.0 / sample_rate_hz
    dt = np.diff(timestamps_s)
    return bool(np.any(np.abs(dt - period) > tolerance * period))


def resample_uniform(
    steps: NDArray[np.floating[Any]], timestamps_s: NDArray[np.float64], sample_rate_hz: float
) -> tuple[NDArray[np.float32], int]:
    """Per-interval motion measured between unevenly timed frames, resampled onto a uniform grid.

    Flow between frames k and k+1 is a displacement over ``t[k+1] - t[k]``; when frames were dropped
    (or timing jitters) that interval is not one period. Displacements are accumulated into positions
    at the true frame times, linearly interpolated at ``t[0] + j / fps``, and differenced again, so a
    dropped frame neither shifts nor biases the frequency.

    Parameters
    ----------
    steps : ndarray, shape (N, ...)
        Motion from frame k to frame k + 1 (for example flow maps (N, h, w, 2), or a 1-D signal).
    timestamps_s : ndarray of float64, shape (N + 1,)
        Capture times of the N + 1 frames, strictly increasing.
    sample_rate_hz : float
        Nominal frame rate of the uniform grid.

    Returns
    -------
    uniform : ndarray of float32, shape (M, ...)
        Motion per uniform period, M = round((t[-1] - t[0]) * fps).
    count : int
        M.
    """
    t = np.asarray(timestamps_s, np.float64) - float(timestamps_s[0])
    n = steps.shape[0]
    if t.shape != (n + 1,):
        raise ParameterError(f"resample: {n} motion steps need {n + 1} timestamps, got {t.shape[0]}")
    m = round(t[-1] * sample_rate_hz)
    grid = np.arange(m + 1, dtype=np.float64) / sample_rate_hz
    grid[-1] = min(grid[-1], t[-1])
    idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, n - 1)
    weight = ((grid - t[idx]) / (t[idx + 1] - t[idx])).astype(np.float32)
    # Position at frame k = sum of steps before k; position at grid time = pos[idx] + w * steps[idx].
    out = np.empty((m, *steps.shape[1:]), np.float32)
    position_prev = np.zeros(steps.shape[1:], np.float32)
    cumulative = np.zeros(steps.shape[1:], np.float32)
    k_done = 0
    shape_tail = (1,) * (steps.ndim - 1)
    for j in range(m + 1):
        k = int(idx[j])
        while k_done < k:
            cumulative += steps[k_done]
            k_done += 1
        position = cumulative + weight[j].reshape(shape_tail) * steps[k]
        if j > 0:
            out[j - 1] = position - position_prev
        position_prev = position
    return out, m

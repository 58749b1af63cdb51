"""Dense optical flow between consecutive frames (Farnebäck or DIS), computed while frames stream in.

Flow is computed on grey images, optionally downscaled by ``scale`` for speed; vectors are returned in
pixels of the computation grid (multiply by ``1 / scale`` for input pixels). Frame pairs are independent, so
:func:`flow_stream` spreads them over worker threads (OpenCV releases the GIL) while keeping output order
and holding at most ``2 * threads`` frames in flight.
"""

from __future__ import annotations

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
DisPreset = Literal["ultrafast", "fast", "medium"]
_DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


@dataclass(frozen=True, kw_only=True)
class FlowConfig:
    """How flow is computed.

    Attributes
    ----------
    method : ``"farneback"`` or ``"dis"``
    scale : float
        Downscale factor in (0, 1] applied before flow (0.5 = half width and height).
    dis_preset : ``"ultrafast"``, ``"fast"`` or ``"medium"``
        DIS quality preset.
    threads : int
        Frame pairs computed at once.
    farneback : tuple
        (pyr_scale, levels, winsize, iterations, poly_n, poly_sigma), the paper's (0.5, 3, 15, 3, 5, 1.2).
    """

    method: FlowMethod = "dis"
    scale: float = 0.5
    dis_preset: DisPreset = "medium"
    threads: int = 2
    farneback: tuple[float, int, int, int, int, float] = (0.5, 3, 15, 3, 5, 1.2)

    def __post_init__(self) -> None:
        if self.method not in ("farneback", "dis"):
            raise ParameterError(f"flow method {self.method!r} is unknown; use 'farneback' or 'dis'")
        if not 0 < self.scale <= 1:
            raise ParameterError(f"flow scale {self.scale} must be in (0, 1]")
        if self.dis_preset not in _DIS_PRESETS:
            raise ParameterError(f"DIS preset {self.dis_preset!r} is unknown; use ultrafast, fast or medium")
        if self.threads < 1:
            raise ParameterError("flow threads must be at least 1")

    def grid_shape(self, height: int, width: int) -> tuple[int, int]:
        """(h, w) of the flow grid for input frames of ``height`` x ``width``."""
        if self.scale == 1:
            return height, width
        return max(8, round(height * self.scale)), max(8, round(width * self.scale))


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

    def __call__(self, prev: NDArray[np.uint8], nxt: NDArray[np.uint8]) -> NDArray[np.float32]:
        cfg = self.config
        if cfg.method == "farneback":
            pyr, levels, win, iters, poly_n, poly_sigma = cfg.farneback
            flow = cv2.calcOpticalFlowFarneback(
                prev, nxt, None, pyr, levels, win, iters, poly_n, poly_sigma, 0
            )
        else:
            dis = getattr(self._local, "dis", None)
            if dis is None:
                dis = cv2.DISOpticalFlow.create(_DIS_PRESETS[cfg.dis_preset])
                self._local.dis = dis
            flow = dis.calc(prev, nxt, None)
        return np.asarray(flow, dtype=np.float32)


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
    grays: Iterable[NDArray[np.uint8]], *, config: FlowConfig | None = None
) -> Iterator[NDArray[np.float32]]:
    """Flow between each pair of consecutive grey frames, in order.

    Parameters
    ----------
    grays : iterable of ndarray of uint8, shape (h, w)
        Frames on the flow grid; consumed lazily.
    config : FlowConfig, optional

    Yields
    ------
    ndarray of float32, shape (h, w, 2)
        Flow from frame i to frame i + 1, for i = 0, 1, ...
    """
    config = config or FlowConfig()
    engine = _Engine(config)
    iterator = iter(grays)
    try:
        prev = next(iterator)
    except StopIteration:
        return
    if config.threads == 1:
        for nxt in iterator:
            yield engine(prev, nxt)
            prev = nxt
        return
    pending: deque[Future[NDArray[np.float32]]] = deque()
    with ThreadPoolExecutor(max_workers=config.threads, thread_name_prefix="flow") as pool:
        try:
            for nxt in iterator:
                pending.append(pool.submit(engine, prev, nxt))
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

"""The live frame window: frames in one at a time, their optical flow computed as they arrive, memory bounded.

:class:`LiveWindow` takes frames (:meth:`LiveWindow.push`), computes their optical flow as they arrive
(:func:`workers.pipeline.flow.flow_stream` on a thread of its own) and keeps only the analysis window in
memory: until motion is seen, the last ``lead_frames`` frames; from then on, up to ``window_frames``
frames (later frames still update nothing but the frame count). Beside each frame it keeps its grey
image (uint8, (H, W)), its capture time (float64, seconds from the stream's first frame), its depth on
the flow grid (float32, (h, w), metres, NaN invalid, when frames carry depth) and its block brightness
and change from the frame before (float32, (B, B)); beside each frame pair its flow map (float32,
(h, w, 2), grid pixels), the map pooled on the first pass's grid, the camera's motion (float32, (2,))
and the pair's activity; over the window, the motion energy of each grid pixel (float64, (h, w)).

The flow thread writes under the window's lock; whoever reads copies under it
(:meth:`LiveWindow.signal_snapshot`, :meth:`LiveWindow.kept_times`, :meth:`LiveWindow.depth`), and
:meth:`LiveWindow.buffers` hands the window to the full analysis as the batch frame stream would
(:class:`workers.pipeline.stream.FrameBuffers`). :mod:`workers.pipeline.live` estimates from it.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.camera import CameraRing, remove_camera_motion
from workers.pipeline.errors import AnalysisError, ClipError
from workers.pipeline.flow import FlowConfig, flow_stream, pixel_columns, prepare_gray
from workers.pipeline.front import look_factor, pool_map
from workers.pipeline.light import BRIGHTNESS_BLOCKS, block_brightness, block_change
from workers.pipeline.stream import FrameBuffers

#: Chooses the moving region from the window's motion energy (float64, (h, w)): its mask on the grid
#: (bool, (h, w)) and the flat indices of the grid pixels to sample (intp, (P,)); None when none moves.
RegionChooser = Callable[[NDArray[np.float64]], tuple[NDArray[np.bool_], NDArray[np.intp]] | None]


@dataclass(frozen=True)
class SignalSnapshot:
    """What the live estimate reads of the window, copied under the window's lock in one go.

    Attributes
    ----------
    samples : int
        Flow maps N in the window.
    times_s : ndarray of float64, shape (N + 1,)
        Capture times of the window's frames, seconds from the stream's first frame.
    region : ndarray of bool, shape (h, w)
        The moving region the chooser found on the grid.
    columns_px : ndarray of float32, shape (N, 2 x P)
        The flow of the region's P sampled pixels in each map, grid pixels
        (:func:`~workers.pipeline.flow.pixel_columns`: u, then v of each pixel).
    camera_px : ndarray of float64, shape (N, 2)
        The camera's motion in each map, grid pixels.
    """

    samples: int
    times_s: NDArray[np.float64]
    region: NDArray[np.bool_]
    columns_px: NDArray[np.floating[Any]]
    camera_px: NDArray[np.float64]


class LiveWindow:
    """Frames in, their flow computed as they arrive, memory bounded by the window; see the module docstring.

    Parameters
    ----------
    width, height : int
        Frame size, pixels; every pushed frame must have it.
    flow : FlowConfig
        Optical flow settings (their grid is the window's ``grid``).
    window_frames : int
        Most frames kept.
    lead_frames : int
        Frames kept from before the motion was first seen.
    motion_threshold_px : float
        Least speed (flow-grid pixels per frame, 99.5th percentile over the frame) that counts as motion.

    Attributes
    ----------
    grid : (h, w)
        The flow grid's shape.

    Notes
    -----
    One thread pushes and reads; the flow runs on a thread of its own, which writes under the window's
    lock. Call :meth:`close` to stop it.
    """

    def __init__(
        self,
        *,
        width: int,
        height: int,
        flow: FlowConfig,
        window_frames: int,
        lead_frames: int,
        motion_threshold_px: float,
    ) -> None:
        self.width, self.height = width, height
        self.flow = flow
        self.window_frames = cap = window_frames
        self.lead_frames = lead_frames
        self.motion_threshold_px = motion_threshold_px
        self.grid = flow.grid_shape(height, width)
        h, w = self.grid
        self._flow = np.empty((cap - 1, h, w, 2), np.float32)
        # Each map also on the first pass's grid, pooled as it arrives: the final analysis scans there.
        self._factor = f = look_factor(w)
        self._pooled = np.empty((cap - 1, h // f, w // f, 2) if f > 1 else (0, 1, 1, 2), np.float32)
        self._camera = np.zeros((cap - 1, 2), np.float32)
        self._activity = np.zeros(cap - 1, np.float64)
        self._gray = np.empty((cap, height, width), np.uint8)
        self._depth: NDArray[np.float32] | None = None
        self._times = np.zeros(cap, np.float64)
        # Block brightness of each kept frame and its change from the frame before (flicker and codec
        # keyframe evidence), taken as frames arrive.
        self._brightness = np.zeros((cap, BRIGHTNESS_BLOCKS, BRIGHTNESS_BLOCKS), np.float32)
        self._change = np.zeros((cap - 1, BRIGHTNESS_BLOCKS, BRIGHTNESS_BLOCKS), np.float32)
        self._last_small: NDArray[np.uint8] | None = None
        self._energy = np.zeros((h, w), np.float64)
        self._first_rgb: NDArray[np.uint8] | None = None
        self._base = 0  # absolute index of the frame in slot 0
        self._stored = 0  # frames in the slots
        self._flows = 0  # flow maps in the slots (pair k -> k + 1 in slot k)
        self._received = 0
        self._flow_count = 0  # frame pairs whose flow is computed (absolute)
        self._first_time: float | None = None
        self._last_time: float | None = None
        self._motion_at: int | None = None  # absolute index of the first sample seen moving
        self._noise: list[float] = []
        self._lock = threading.Lock()
        self._ring = CameraRing(self.grid)
        self._grays: queue.Queue[NDArray[np.uint8] | None] = queue.Queue()
        self._error: BaseException | None = None
        self._done = threading.Event()
        self._consumed = threading.Condition()
        self._thread = threading.Thread(target=self._flow_loop, name="live-flow", daemon=True)
        self._thread.start()

    # What the window holds ---------------------------------------------------------------------

    @property
    def frames_received(self) -> int:
        """Frames pushed so far."""
        return self._received

    @property
    def flows_done(self) -> int:
        """Frame pairs whose flow has been computed (of ``frames_received - 1``)."""
        return self._flow_count

    @property
    def motion_seen(self) -> bool:
        """Whether a frame pair has moved above the noise yet."""
        return self._motion_at is not None

    @property
    def motion_at(self) -> int | None:
        """Stream index of the first frame pair seen moving (pair k: frames k, k + 1); None before."""
        return self._motion_at

    @property
    def full(self) -> bool:
        """Whether the window holds as many frames as it may (later frames are counted, not kept)."""
        return self._stored >= self.window_frames

    @property
    def base(self) -> int:
        """Stream index of the window's first frame."""
        return self._base

    @property
    def flows(self) -> int:
        """Flow maps in the window, N (map k is of the window's frames k and k + 1)."""
        with self._lock:
            return self._flows

    @property
    def has_first_frame(self) -> bool:
        """Whether the stream's first frame (its colour, for the final analysis) has arrived."""
        return self._first_rgb is not None

    @property
    def has_depth(self) -> bool:
        """Whether any pushed frame carried depth."""
        return self._depth is not None

    def buffer_shapes(self) -> dict[str, tuple[int, ...]]:
        """The shapes of the window's buffers by name (``flow``, ``pooled``, ``camera``, ``activity``,
        ``gray``, ``times``, ``brightness``, ``change``, ``energy``, and ``depth`` once a frame carried
        depth): allocated once, they bound the memory whatever the stream's length."""
        arrays: dict[str, NDArray[Any]] = {
            "flow": self._flow,
            "pooled": self._pooled,
            "camera": self._camera,
            "activity": self._activity,
            "gray": self._gray,
            "times": self._times,
            "brightness": self._brightness,
            "change": self._change,
            "energy": self._energy,
        }
        if self._depth is not None:
            arrays["depth"] = self._depth
        return {name: a.shape for name, a in arrays.items()}

    # Frames in -------------------------------------------------------------------------------

    def push(
        self, *, rgb: NDArray[np.uint8], depth_m: NDArray[np.float32] | None = None, timestamp_s: float
    ) -> int:
        """Add the next frame; its flow is computed in the background.

        Parameters
        ----------
        rgb : ndarray of uint8, shape (H, W, 3)
        depth_m : ndarray of float32, shape (H, W), optional
            Depth aligned to ``rgb``, metres, NaN where invalid.
        timestamp_s : float
            Capture time, seconds (any origin); must increase from frame to frame.

        Returns
        -------
        int
            The frame's index in the stream, from 0.

        Raises
        ------
        ClipError
            A frame of the wrong shape, or a timestamp that does not increase; the frame is not kept.
        """
        self.raise_flow_error()
        if rgb.shape != (self.height, self.width, 3) or rgb.dtype != np.uint8:
            raise ClipError(
                f"frame {self._received}: colour is {rgb.shape} {rgb.dtype}, expected "
                f"({self.height}, {self.width}, 3) uint8 like the stream's first frame"
            )
        if depth_m is not None and depth_m.shape != (self.height, self.width):
            raise ClipError(
                f"frame {self._received}: depth is {depth_m.shape[1]}x{depth_m.shape[0]}, but colour is "
                f"{self.width}x{self.height}; depth must be aligned to colour"
            )
        t = float(timestamp_s)
        if not math.isfinite(t) or (self._last_time is not None and t <= self._last_time):
            raise ClipError(
                f"frame {self._received}: timestamp {t!r} s does not follow the previous frame's "
                f"{self._last_time!r} s; timestamps must increase"
            )
        import cv2

        index = self._received
        if self._first_time is None:
            self._first_time = t
            self._first_rgb = np.array(rgb, copy=True)
        self._last_time = t
        self._received += 1
        gray_grid = prepare_gray(rgb, self.grid)
        with self._lock:
            self._make_room()
            slot = index - self._base
            if 0 <= slot < self.window_frames:
                cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY, dst=self._gray[slot])
                self._times[slot] = t - self._first_time
                self._brightness[slot] = block_brightness(gray_grid)
                if slot > 0 and self._last_small is not None:
                    self._change[slot - 1] = block_change(self._last_small, gray_grid)
                if depth_m is not None:
                    if self._depth is None:
                        self._depth = np.full((self.window_frames, *self.grid), np.nan, np.float32)
                    h, w = self.grid
                    d = (
                        depth_m
                        if depth_m.shape == self.grid
                        else cv2.resize(depth_m, (w, h), interpolation=cv2.INTER_NEAREST)
                    )
                    self._depth[slot] = d
                elif self._depth is not None:
                    self._depth[slot] = np.nan
                self._stored = slot + 1
        self._last_small = gray_grid
        self._grays.put(gray_grid)
        # Bounded lag: a caller faster than the flow waits here (and so slows whoever feeds it).
        lag = 2 * self.flow.threads + 4
        with self._consumed:
            self._consumed.wait_for(
                lambda: self._received - 1 - self._flow_count <= lag or self._done.is_set()
            )
        return index

    def _make_room(self) -> None:
        """Before motion is seen, slide the window so that it keeps the last ``lead_frames`` frames; once
        it is seen, slide it once more to start ``lead_frames`` before the motion (the slides before went
        as far as the flow had reached, which lags the frames by up to a few pairs: without this, the
        window held up to that many frames fewer after the motion, as many more before it)."""
        cap = self.window_frames
        if self._stored < cap:
            return
        lead = self.lead_frames
        if self._motion_at is not None:
            keep_from = self._motion_at - lead - self._base
            if keep_from <= 0:
                return
        else:
            # The flow thread may lag a few pairs behind: keep the frames whose flow is pending too.
            keep_from = max(0, min(self._stored - 1 - lead, self._flow_count - self._base))
            keep_from = max(keep_from, 1)
        n = self._stored - keep_from
        self._gray[:n] = self._gray[keep_from : self._stored]
        self._times[:n] = self._times[keep_from : self._stored]
        self._brightness[:n] = self._brightness[keep_from : self._stored]
        self._change[: n - 1] = self._change[keep_from : self._stored - 1]
        if self._depth is not None:
            self._depth[:n] = self._depth[keep_from : self._stored]
        flows_kept = max(0, self._flow_count - self._base - keep_from)
        self._flow[:flows_kept] = self._flow[keep_from : keep_from + flows_kept]
        self._pooled[:flows_kept] = self._pooled[keep_from : keep_from + flows_kept]
        self._camera[:flows_kept] = self._camera[keep_from : keep_from + flows_kept]
        self._activity[:flows_kept] = self._activity[keep_from : keep_from + flows_kept]
        self._base += keep_from
        self._stored = n
        self._flows = flows_kept
        self._energy[:] = 0.0
        for k in range(flows_kept):
            self._accumulate(k)

    def _accumulate(self, slot: int) -> None:
        f = self._flow[slot] - self._camera[slot]
        self._energy += f[..., 0].astype(np.float64) ** 2 + f[..., 1].astype(np.float64) ** 2

    def _gray_source(self) -> Iterator[NDArray[np.uint8]]:
        while True:
            gray = self._grays.get()
            if gray is None:
                return
            yield gray

    def _flow_loop(self) -> None:
        try:
            pooled = np.empty(self._pooled.shape[1:], np.float32)
            for k, flow in enumerate(flow_stream(self._gray_source(), config=self.flow)):
                camera = self._ring.motion(flow)
                if self._factor > 1:
                    pool_map(flow, self._factor, out=pooled)
                speed = np.hypot(flow[..., 0] - camera[0], flow[..., 1] - camera[1])
                activity = float(np.percentile(speed, 99.5))
                with self._lock:
                    self._note_activity(k, activity)
                    slot = k - self._base
                    if slot == self._flows and slot < min(self.window_frames - 1, self._stored - 1):
                        self._flow[slot] = flow
                        if self._factor > 1:
                            self._pooled[slot] = pooled
                        self._camera[slot] = camera
                        self._activity[slot] = activity
                        self._accumulate(slot)
                        self._flows = slot + 1
                    self._flow_count = k + 1
                with self._consumed:
                    self._consumed.notify_all()
        except BaseException as exc:  # reported to the pushing thread
            self._error = exc
        finally:
            self._done.set()
            with self._consumed:
                self._consumed.notify_all()

    def _note_activity(self, k: int, activity: float) -> None:
        if self._motion_at is not None:
            return
        if len(self._noise) < 5:
            self._noise.append(activity)
        baseline = float(np.median(self._noise)) if len(self._noise) >= 3 else 0.0
        if activity > max(self.motion_threshold_px, 4.0 * baseline):
            self._motion_at = k

    def raise_flow_error(self) -> None:
        """Raise :class:`~workers.pipeline.errors.AnalysisError` if the flow thread failed."""
        if self._error is not None:
            raise AnalysisError(f"optical flow failed: {self._error}") from self._error

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the flow of every pushed frame is computed; False on timeout."""
        target = max(self._received - 1, 0)
        with self._consumed:
            return self._consumed.wait_for(
                lambda: self._flow_count >= target or self._done.is_set() or self._error is not None,
                timeout=timeout_s,
            )

    def close(self) -> None:
        """Stop the flow threads (idempotent)."""
        if not self._done.is_set():
            self._grays.put(None)
            self._thread.join()

    # What the estimates read -------------------------------------------------------------------

    def kept_times(self) -> NDArray[np.float64]:
        """Capture times of the kept frames, seconds from the stream's first frame, float64 (frames,);
        a copy taken under the lock."""
        with self._lock:
            n = self._stored
            return self._times[:n].copy()

    def signal_snapshot(self, *, min_flows: int, region_of: RegionChooser) -> SignalSnapshot | None:
        """The window's flow maps so far, as much of them as the live signal needs, copied under the lock.

        Parameters
        ----------
        min_flows : int
            Fewest flow maps worth a snapshot.
        region_of : callable
            Chooses the moving region from the motion energy (see :data:`RegionChooser`); called under
            the lock, on the window's own energy (float64, (h, w)), which it must not change.

        Returns
        -------
        SignalSnapshot or None
            None while fewer than ``min_flows`` maps are in the window, or when ``region_of`` finds none.
        """
        with self._lock:
            n = self._flows
            if n < min_flows:
                return None
            times = self._times[: n + 1].copy()
            chosen = region_of(self._energy)
            if chosen is None:
                return None
            mask, idx = chosen
            columns = pixel_columns(self._flow[:n], idx)
            camera = self._camera[:n].astype(np.float64)
        return SignalSnapshot(n, times, mask, columns, camera)

    def depth(
        self, n: int, *, rows: slice = slice(None), cols: slice = slice(None)
    ) -> NDArray[np.float32] | None:
        """Depth of the window's first ``n + 1`` frames on the grid, float32 (n + 1, h, w), metres, NaN
        invalid, a copy taken under the lock; None when no frame carried depth. Given ``rows`` and
        ``cols``, only that part of the grid is copied (an estimate needs its region's, a twentieth of the
        window's depth)."""
        with self._lock:
            return None if self._depth is None else self._depth[: n + 1, rows, cols].copy()

    def flow_maps(self, n: int) -> NDArray[np.float32]:
        """The window's first ``n`` flow maps as computed (the camera's motion in them), float32
        (n, h, w, 2), grid pixels; a copy taken under the lock."""
        with self._lock:
            return self._flow[:n].copy()

    def camera_motion_px(self, n: int) -> NDArray[np.float32]:
        """The camera's motion measured in each of the window's first ``n`` flow maps (the median motion
        of the picture's border), float32 (n, 2), grid pixels; a copy taken under the lock."""
        with self._lock:
            return self._camera[:n].copy()

    def buffers(self, n: int) -> FrameBuffers:
        """The window's ``n`` flow maps and what the frame stream keeps beside them, the camera's motion
        removed as the batch stream removes it.

        Views of the window's buffers, the pooled maps' camera motion removed in place: call once, after
        :meth:`close`, with ``n`` at most :attr:`flows` and the first frame arrived.
        """
        assert self._first_rgb is not None
        flow = self._flow[:n]
        ring = CameraRing(self.grid)
        ring.set_texture(prepare_gray(self._first_rgb, self.grid))
        camera = remove_camera_motion(flow, self._camera[:n].copy(), ring)
        pooled = None
        if self._factor > 1:
            pooled = self._pooled[:n]
            if camera.removed:
                pooled -= (camera.camera_px / np.float32(self._factor))[:, None, None, :]
        times = self._times[: n + 1]
        return FrameBuffers(
            flow=flow,
            depth=None if self._depth is None else self._depth[: n + 1],
            gray=self._gray[: n + 1],
            first_rgb=self._first_rgb,
            count=n,
            times_s=times - times[0],
            camera_px=camera.camera_px,
            start_s=float(times[0]),
            brightness=self._brightness[: n + 1],
            frame_change=self._change[:n],
            camera_removed=camera.removed,
            camera_still_fraction=camera.still_fraction,
            border_px=camera.border_px,
            announced=n,
            pooled_flow=pooled,
        )


__all__ = ["LiveWindow", "RegionChooser", "SignalSnapshot"]

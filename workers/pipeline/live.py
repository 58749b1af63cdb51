"""Live estimation: measure an object while its frames arrive, and say when the estimate has converged.

:class:`LiveAnalysis` takes frames one at a time (:meth:`LiveAnalysis.push`), computes their optical flow
as they arrive (:func:`workers.pipeline.flow.flow_stream` on a thread of its own), and keeps only the
analysis window in memory: until motion is seen, the last ``lead_frames`` frames; from then on, up to
``window_frames`` frames (later frames still update nothing but the frame count). At any time
:meth:`LiveAnalysis.estimate` gives the main object's frequency, damping, amplitude, stiffness and mass
from the frames so far, each with a standard uncertainty, and whether the convergence rule holds.
:meth:`LiveAnalysis.finish` runs the full analysis (segmentation, registration, every object) on the
window's flow, which is never computed twice.

The live estimate (what moves most since the release, its mean flow projected on its motion axis, a
damped-sine fit from the release on) is cheap enough to repeat several times a second. Its frequency
uncertainty is the fit's, inflated for the few samples of an early estimate and floored like the full
analysis's; ``bench/stream.py`` measures how often its 95 % intervals cover the truth.

Convergence: the relative standard uncertainty of the frequency is at most the target, the fit spans at
least ``min_periods`` periods and ``min_samples`` samples after the release and stands ``min_snr_db``
above the noise, and ``confirmations`` successive estimates agree (each within the combined 95 %
interval of the one before).
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.analysis import analyze_window
from workers.pipeline.camera import CAMERA_MOTION_MIN_PX, CameraRing, remove_camera_motion
from workers.pipeline.clipio.types import ClipInfo, Intrinsics
from workers.pipeline.errors import AnalysisError, ClipError, ParameterError
from workers.pipeline.flow import FlowConfig, flow_stream, pixel_columns, prepare_gray
from workers.pipeline.front import look_factor, pool_map
from workers.pipeline.light import BRIGHTNESS_BLOCKS, block_brightness, block_change
from workers.pipeline.live_estimate import LIVE_FREQUENCY_REL_FLOOR, LiveEstimate, few_samples_factor
from workers.pipeline.measure import object_mechanics
from workers.pipeline.mechanics import detect_release, release_amplitude, release_instant
from workers.pipeline.metric import DepthContext, ImageAmplitude, MetricAmplitude, metric_amplitude
from workers.pipeline.model import Analysis, AnalysisConfig, Excitation, QualityNote, Stopwatch
from workers.pipeline.ringdown import (
    FREQUENCY_REL_FLOOR,
    RingdownFit,
    damping_sd,
    fit_ringdown,
    frequency_sd_hz,
)
from workers.pipeline.stream import FrameBuffers
from workers.pipeline.window import Plan, band_edges

#: Pixels sampled from the moving region for the live signal.
_SIGNAL_PIXELS = 4000
#: Pixels whose motion energy is at least this fraction of the strongest (99.5th percentile) form the region.
_REGION_LEVEL = 0.5


@dataclass(frozen=True, kw_only=True)
class LiveConfig:
    """How a live analysis keeps frames and when it calls an estimate converged.

    Attributes
    ----------
    fps : float or None
        Nominal frame rate, Hz; None measures it from the frames' timestamps.
    flow : FlowConfig
        Optical flow settings: the analysis's (DIS on a grid about 320 px wide) on one thread, so that
        each frame pair's flow is ready as soon as its second frame arrives (two threads would hold back
        the last few pairs until more frames come; the stream's decoding runs beside it anyway).
    window_frames : int
        Most frames kept for the analysis (memory is bounded by this, not by the stream's length).
    lead_frames : int
        Frames kept from before the motion was first seen.
    target_relative_uncertainty : float
        Relative standard uncertainty of the frequency at which the estimate has converged.
    min_frequency_hz, max_frequency_hz : float or None
        Band of acceptable frequencies; default :func:`~workers.pipeline.window.band_edges` of the
        frames the estimate used (two periods of them up to 0.98 x Nyquist), as a batch analysis.
    min_periods : float
        Periods of motion after the release a converged estimate must span.
    min_samples : int
        Flow samples after the release a converged estimate must span.
    min_snr_db : float
        Ring-down fit signal-to-noise ratio a converged estimate needs.
    confirmations : int
        Successive estimates that must meet the target and agree.
    motion_threshold_px : float
        Least speed (flow-grid pixels per frame, 99.5th percentile over the frame) that counts as motion.
    depth_m : float or None
        Object distance when frames carry no depth.
    """

    fps: float | None = None
    flow: FlowConfig = field(default_factory=lambda: FlowConfig(threads=1))
    window_frames: int = 256
    lead_frames: int = 8
    target_relative_uncertainty: float = 0.01
    min_frequency_hz: float | None = None
    max_frequency_hz: float | None = None
    min_periods: float = 2.0
    min_samples: int = 12
    min_snr_db: float = 10.0
    confirmations: int = 2
    motion_threshold_px: float = 0.15
    depth_m: float | None = None

    def __post_init__(self) -> None:
        if self.fps is not None and not (math.isfinite(self.fps) and self.fps > 0):
            raise ParameterError(f"fps={self.fps} must be a positive frame rate in Hz")
        if self.window_frames < 16:
            raise ParameterError(f"window_frames={self.window_frames}: the window needs at least 16 frames")
        if not 0 <= self.lead_frames < self.window_frames // 2:
            raise ParameterError(f"lead_frames={self.lead_frames} must be in [0, window_frames / 2)")
        if not 0 < self.target_relative_uncertainty < 1:
            raise ParameterError(
                f"target_relative_uncertainty={self.target_relative_uncertainty} must be in (0, 1)"
            )
        if self.confirmations < 1 or self.min_samples < 6:
            raise ParameterError("confirmations must be at least 1 and min_samples at least 6")


@dataclass(frozen=True)
class _Signal:
    """The moving region's mean flow along its motion axis (input px per sample), the frame times (N + 1,),
    the region on the grid, the number of flow samples N and the axis (x, y)."""

    velocity_px: NDArray[np.float64]
    times_s: NDArray[np.float64]
    region: NDArray[np.bool_]
    samples: int
    axis_px: tuple[float, float]


class LiveAnalysis:
    """Frames in, estimates out, memory bounded by the analysis window; see the module docstring.

    Parameters
    ----------
    width, height : int
        Frame size, pixels; every pushed frame must have it.
    intrinsics : Intrinsics or None
        Camera intrinsics (metric amplitude, stiffness and mass need them and depth).
    config : LiveConfig, optional
    excitation : Excitation, optional
        How the main object was excited (stiffness and mass need it).

    Notes
    -----
    Not thread-safe: one thread pushes, estimates and finishes. Flow runs on threads of its own; call
    :meth:`close` (or :meth:`finish`) to stop them.
    """

    def __init__(
        self,
        *,
        width: int,
        height: int,
        intrinsics: Intrinsics | None = None,
        config: LiveConfig | None = None,
        excitation: Excitation | None = None,
    ) -> None:
        if width < 16 or height < 16:
            raise ParameterError(f"frames of {width}x{height} are too small; need at least 16x16 pixels")
        self.config = cfg = config or LiveConfig()
        self.width, self.height = width, height
        self.intrinsics = intrinsics
        self.excitation = excitation
        self.grid = cfg.flow.grid_shape(height, width)
        self.pixel_scale = width / self.grid[1]
        cap = cfg.window_frames
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
        self._agree = 0
        self._previous: LiveEstimate | None = None
        self._converged = False
        self._ring = CameraRing(self.grid)
        self._grays: queue.Queue[NDArray[np.uint8] | None] = queue.Queue()
        self._error: BaseException | None = None
        self._done = threading.Event()
        self._consumed = threading.Condition()
        self._thread = threading.Thread(target=self._flow_loop, name="live-flow", daemon=True)
        self._thread.start()
        # The FFT library's import (a third of a second) happens now, not after the last frame.
        from workers.pipeline.fft import warm_up

        threading.Thread(target=warm_up, name="spectrum-warm-up", daemon=True).start()

    # Frames in -------------------------------------------------------------------------------

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
    def window_full(self) -> bool:
        """Whether the window holds as many frames as it may (later frames are counted, not kept)."""
        return self._stored >= self.config.window_frames

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
        self._raise_flow_error()
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
            if 0 <= slot < self.config.window_frames:
                cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY, dst=self._gray[slot])
                self._times[slot] = t - self._first_time
                self._brightness[slot] = block_brightness(gray_grid)
                if slot > 0 and self._last_small is not None:
                    self._change[slot - 1] = block_change(self._last_small, gray_grid)
                if depth_m is not None:
                    if self._depth is None:
                        self._depth = np.full((self.config.window_frames, *self.grid), np.nan, np.float32)
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
        lag = 2 * self.config.flow.threads + 4
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
        cap = self.config.window_frames
        if self._stored < cap:
            return
        lead = self.config.lead_frames
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
            for k, flow in enumerate(flow_stream(self._gray_source(), config=self.config.flow)):
                camera = self._ring.motion(flow)
                if self._factor > 1:
                    pool_map(flow, self._factor, out=pooled)
                speed = np.hypot(flow[..., 0] - camera[0], flow[..., 1] - camera[1])
                activity = float(np.percentile(speed, 99.5))
                with self._lock:
                    self._note_activity(k, activity)
                    slot = k - self._base
                    if slot == self._flows and slot < min(self.config.window_frames - 1, self._stored - 1):
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
        if activity > max(self.config.motion_threshold_px, 4.0 * baseline):
            self._motion_at = k

    def _raise_flow_error(self) -> None:
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

    # Estimates ---------------------------------------------------------------------------------

    @property
    def fps(self) -> float:
        """The nominal frame rate: the configured one, or measured from the kept frames' timestamps."""
        if self.config.fps is not None:
            return self.config.fps
        with self._lock:
            n = self._stored
            times = self._times[:n].copy()
        if n < 2:
            raise AnalysisError("the frame rate cannot be measured from fewer than two frames; give fps")
        from workers.pipeline.clipio.types import uniform_fps_from_timestamps

        return uniform_fps_from_timestamps(times)[0]

    def _signal(self) -> _Signal | None:
        """The moving region's mean flow along its motion axis; None before there is motion to follow."""
        import cv2

        with self._lock:
            n = self._flows
            if n < 8:
                return None
            energy = self._energy.copy()
            times = self._times[: n + 1].copy()
            top = float(np.percentile(energy, 99.5))
            if not top > 0:
                return None
            region = (energy > _REGION_LEVEL * top).astype(np.uint8)
            count, labels, _stats, _ = cv2.connectedComponentsWithStats(region, connectivity=8)
            if count < 2:
                return None
            # The component holding the most motion energy.
            sums = np.bincount(labels.ravel(), weights=energy.ravel(), minlength=count)[1:]
            mask = labels == int(np.argmax(sums)) + 1
            idx = np.flatnonzero(mask.ravel())
            if len(idx) > _SIGNAL_PIXELS:
                idx = idx[np.linspace(0, len(idx) - 1, _SIGNAL_PIXELS).astype(np.intp)]
            mean = pixel_columns(self._flow[:n], idx).reshape(n, -1, 2).mean(axis=1, dtype=np.float64)
            camera = self._camera[:n].astype(np.float64)
        if float(np.sqrt(np.mean(camera**2))) > CAMERA_MOTION_MIN_PX:
            mean -= camera
        centred = mean - mean.mean(axis=0)
        _, vecs = np.linalg.eigh(centred.T @ centred)
        axis = vecs[:, -1]
        velocity = (mean @ axis) * self.pixel_scale
        return _Signal(velocity, times, mask, n, (float(axis[0]), float(axis[1])))

    def estimate(self) -> LiveEstimate | None:
        """The main object's figures from the frames so far; None until a ring-down can be fitted.

        Each call also advances the convergence rule (its ``confirmations`` count successive calls).
        """
        self._raise_flow_error()
        if self._motion_at is None:
            return None
        signal = self._signal()
        if signal is None:
            return None
        velocity, n = signal.velocity_px, signal.samples
        fps = self.fps
        onset = detect_release(velocity)
        if n - onset < 6:
            return None
        try:
            fit = fit_ringdown(velocity, sample_rate_hz=fps, start_index=onset, frame_times_s=signal.times_s)
        except AnalysisError:
            return None
        if not (math.isfinite(fit.frequency_hz) and fit.frequency_hz > 0):
            return None
        est = self._figures(fit, signal, onset=onset, fps=fps)
        self._judge(est)
        return self._previous

    def _figures(self, fit: RingdownFit, signal: _Signal, *, onset: int, fps: float) -> LiveEstimate:
        """The estimate from ``fit`` of ``signal``'s motion after ``onset``: uncertainties, metric
        amplitude, stiffness and mass as a batch analysis gives them, with the live systematics."""
        times, mask, n, axis = signal.times_s, signal.region, signal.samples, signal.axis_px
        samples = n - onset
        f = fit.frequency_hz
        t_factor = few_samples_factor(samples)
        f_sd = frequency_sd_hz(
            fit, rel_floor=max(LIVE_FREQUENCY_REL_FLOOR, FREQUENCY_REL_FLOOR), t_factor=t_factor
        )
        zeta_sd = damping_sd(fit, t_factor=t_factor)
        kind = self.excitation.kind if self.excitation else None
        t_rel = release_instant(fit, sample_rate_hz=fps, excitation=kind)
        amp_px = release_amplitude(fit, t_release_s=t_rel, excitation=kind)
        amp_sd_px = fit.amplitude_sd * math.exp(-fit.decay_per_s * t_rel)
        image = ImageAmplitude(
            fit=fit,
            amplitude_px=amp_px,
            amplitude_sd_px=amp_sd_px if math.isfinite(amp_sd_px) else math.inf,
            axis_px=axis,
            source="mean_flow",
        )
        metric = self._metric(image, mask=mask, times=times, onset=onset, n=n)
        reasons = list(metric.null_reasons)
        amp_m, amp_sd_m, depth = metric.amplitude_m, metric.amplitude_uncertainty_m, metric.depth_m
        mech = object_mechanics(fit, metric, self.excitation, frequency_sd_hz=f_sd)
        reasons.extend(mech.null_reasons)
        duration = float(times[n] - times[onset])
        base = self._base
        return LiveEstimate(
            frames_received=self._received,
            frames_used=(base, base + n + 1),
            samples_after_release=samples,
            release_time_s=float(times[onset]) + max(t_rel, 0.0),
            periods=f * duration,
            eigenfrequency_hz=f,
            eigenfrequency_uncertainty_hz=f_sd,
            natural_frequency_hz=fit.natural_frequency_hz,
            damping_ratio=fit.damping_ratio,
            damping_ratio_uncertainty=zeta_sd,
            amplitude_px=amp_px,
            amplitude_m=amp_m,
            amplitude_uncertainty_m=amp_sd_m,
            depth_m=depth,
            stiffness_n_per_m=mech.stiffness_n_per_m,
            stiffness_uncertainty_n_per_m=mech.stiffness_uncertainty_n_per_m,
            mass_kg=mech.mass_kg,
            mass_uncertainty_kg=mech.mass_uncertainty_kg,
            snr_db=fit.snr_db,
            relative_uncertainty=f_sd / f,
            converged=False,
            null_reasons=tuple(reasons),
        )

    def _metric(
        self,
        image: ImageAmplitude,
        *,
        mask: NDArray[np.bool_],
        times: NDArray[np.float64],
        onset: int,
        n: int,
    ) -> MetricAmplitude:
        """The amplitude in metres as a batch analysis measures it
        (:func:`~workers.pipeline.metric.metric_amplitude`), from the window's depth over the moving
        region (grid ``mask``) or the configured distance."""
        import cv2

        with self._lock:
            depth = None if self._depth is None else self._depth[: n + 1].copy()
        full_mask = (
            cv2.resize(mask.astype(np.uint8), (self.width, self.height), interpolation=cv2.INTER_NEAREST) > 0
        )
        where = DepthContext(
            depth=depth,
            region=mask,
            shifts_grid_px=None,
            times_from_onset_s=times[: n + 1] - times[onset],
            onset=onset,
            override_m=self.config.depth_m,
        )
        return metric_amplitude(image, where, full_mask=full_mask, intrinsics=self.intrinsics)

    def _judge(self, est: LiveEstimate) -> None:
        """Apply the convergence rule; remember ``est`` (with its verdict) as the latest estimate."""
        cfg = self.config
        fps = self.fps
        # the band a batch analysis of the same frames would search
        maps = max(1, est.frames_used[1] - est.frames_used[0] - 1)
        lo, hi = band_edges(cfg.min_frequency_hz, cfg.max_frequency_hz, fps, maps)
        meets = (
            est.relative_uncertainty <= cfg.target_relative_uncertainty
            and est.periods >= cfg.min_periods
            and est.samples_after_release >= cfg.min_samples
            and est.snr_db >= cfg.min_snr_db
            and lo <= est.eigenfrequency_hz <= hi
        )
        prev = self._previous
        agrees = prev is None or abs(est.eigenfrequency_hz - prev.eigenfrequency_hz) <= 1.96 * math.hypot(
            est.eigenfrequency_uncertainty_hz, prev.eigenfrequency_uncertainty_hz
        )
        self._agree = self._agree + 1 if meets and agrees else (1 if meets else 0)
        self._converged = self._converged or self._agree >= cfg.confirmations
        self._previous = LiveEstimate(**{**est.__dict__, "converged": self._converged})

    @property
    def latest(self) -> LiveEstimate | None:
        """The last estimate :meth:`estimate` returned."""
        return self._previous

    # The end -----------------------------------------------------------------------------------

    def finish(
        self, *, analysis_config: AnalysisConfig | None = None, excitations: list[Excitation]
    ) -> Analysis:
        """Wait for the last flow maps, then run the full analysis on the window's flow.

        Parameters
        ----------
        analysis_config : AnalysisConfig, optional
            Band, segmentation and depth options (its window options do not apply: the window is the
            frames kept).
        excitations : list of Excitation
            One per excited object, as for :func:`workers.pipeline.analysis.analyze`.

        Returns
        -------
        Analysis
            With ``frames_used`` in stream frame indices and ``fps_source`` ``"stream"``.

        Raises
        ------
        AnalysisError
            Fewer than 8 frames were kept.
        """
        self.close()
        self._raise_flow_error()
        with self._lock:
            n = self._flows
            if n < 7 or self._first_rgb is None:
                raise AnalysisError(
                    f"the stream delivered {self._received} frame(s); an analysis needs at least 8"
                )
        return self._final_analysis(n, config=analysis_config or AnalysisConfig(), excitations=excitations)

    def _final_analysis(self, n: int, *, config: AnalysisConfig, excitations: list[Excitation]) -> Analysis:
        """The full analysis of the window's ``n`` flow maps, without computing them again: the batch
        stages after the frame stream (:func:`~workers.pipeline.analysis.analyze_window`)."""
        watch = Stopwatch()
        buffers = self._window_buffers(n)
        first, stop = self._base, self._base + n + 1
        plan = Plan(
            sample_rate_hz=self.fps,
            fps=self.fps,
            start=first,
            stop=stop,
            step=1,
            flow=self.config.flow,
            grid=self.grid,
            pixel_scale=self.pixel_scale,
            decodable_frames=stop,
        )
        info = ClipInfo(
            format="stream",
            frames=stop,
            width=self.width,
            height=self.height,
            fps=self.fps,
            fps_source="user" if self.config.fps is not None else "timestamps",
            has_depth=self._depth is not None,
            depth_scale=None,
            intrinsics=self.intrinsics,
        )
        watch.lap("flow")
        result = analyze_window(buffers, plan, info, config=config, excitations=excitations, watch=watch)
        if self._received > stop:
            result.quality.append(
                QualityNote(
                    "window",
                    f"frames {first}-{stop} of the {self._received} streamed were analysed (the window "
                    f"holds at most {self.config.window_frames} frames from just before the motion)",
                    "info",
                )
            )
        result.parameters |= {
            "live": True,
            "target_relative_uncertainty": self.config.target_relative_uncertainty,
        }
        return result

    def _window_buffers(self, n: int) -> FrameBuffers:
        """The window's ``n`` flow maps and what the frame stream keeps beside them, the camera's motion
        removed as the batch stream removes it."""
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


__all__ = ["LiveAnalysis", "LiveConfig"]

"""Live estimation: measure an object while its frames arrive, and say when the estimate has converged.

:class:`LiveAnalysis` takes frames one at a time (:meth:`LiveAnalysis.push`) into a
:class:`workers.pipeline.live_window.LiveWindow`, which computes their optical flow as they arrive and
keeps only the analysis window in memory (until motion is seen, the last ``lead_frames`` frames; from
then on, up to ``window_frames`` frames). This module estimates from locked snapshots of that window: at
any time :meth:`LiveAnalysis.estimate` gives the main object's frequency, damping, amplitude, stiffness
and mass from the frames so far, each with a standard uncertainty, and whether the convergence rule
holds (a :class:`workers.pipeline.live_estimate.LiveEstimate`). :meth:`LiveAnalysis.finish` runs the full
analysis (segmentation, registration, every object) on the window's flow (a
:class:`workers.pipeline.stream.FrameBuffers`), which is never computed twice.

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
import threading
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.analysis import analyze_window
from workers.pipeline.camera import CAMERA_MOTION_MIN_PX
from workers.pipeline.clipio.types import ClipInfo, Intrinsics
from workers.pipeline.errors import AnalysisError, ParameterError
from workers.pipeline.flow import FlowConfig
from workers.pipeline.live_estimate import LIVE_FREQUENCY_REL_FLOOR, LiveEstimate, few_samples_factor
from workers.pipeline.live_window import LiveWindow
from workers.pipeline.measure import bounding_box, object_mechanics
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
from workers.pipeline.window import Plan, band_edges

#: Pixels sampled from the moving region for the live signal.
_SIGNAL_PIXELS = 4000
#: Grid pixels kept around the moving region's box when an estimate reads the window's depth: more than
#: the depth track's erosion reaches (:func:`~workers.pipeline.metric.depth_track`), so the crop changes
#: nothing it measures.
DEPTH_MARGIN_PX = 3
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


def _around(mask: NDArray[np.bool_], *, margin: int) -> tuple[slice, slice]:
    """The rows and columns of ``mask``'s bounding box grown by ``margin`` (a slice past the mask's edge
    stops there); the whole of it when nothing is set."""
    x, y, width, height = bounding_box(mask)
    if width == 0:
        return slice(None), slice(None)
    return slice(max(y - margin, 0), y + height + margin), slice(max(x - margin, 0), x + width + margin)


def _moving_region(energy: NDArray[np.float64]) -> tuple[NDArray[np.bool_], NDArray[np.intp]] | None:
    """The moving region on the grid from the window's motion energy (float64, (h, w)): the connected
    component of the pixels with at least ``_REGION_LEVEL`` of the strongest energy that holds the most
    of it, as a mask (bool, (h, w)), and up to ``_SIGNAL_PIXELS`` of its flat pixel indices, evenly spaced
    (intp, (P,)); None when nothing moves."""
    import cv2

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
    return mask, idx


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

    Attributes
    ----------
    window : LiveWindow
        The frames kept and their flow (:class:`workers.pipeline.live_window.LiveWindow`); the estimates
        read it through its public methods only.

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
        self.window = LiveWindow(
            width=width,
            height=height,
            flow=cfg.flow,
            window_frames=cfg.window_frames,
            lead_frames=cfg.lead_frames,
            motion_threshold_px=cfg.motion_threshold_px,
        )
        self.grid = self.window.grid
        self.pixel_scale = width / self.grid[1]
        self._agree = 0
        self._previous: LiveEstimate | None = None
        self._converged = False
        # The FFT library's import (a third of a second) happens now, not after the last frame.
        from workers.pipeline.fft import warm_up

        threading.Thread(target=warm_up, name="spectrum-warm-up", daemon=True).start()

    # Frames in (the window) ------------------------------------------------------------------

    @property
    def frames_received(self) -> int:
        """Frames pushed so far."""
        return self.window.frames_received

    @property
    def flows_done(self) -> int:
        """Frame pairs whose flow has been computed (of ``frames_received - 1``)."""
        return self.window.flows_done

    @property
    def motion_seen(self) -> bool:
        """Whether a frame pair has moved above the noise yet."""
        return self.window.motion_seen

    @property
    def window_full(self) -> bool:
        """Whether the window holds as many frames as it may (later frames are counted, not kept)."""
        return self.window.full

    def push(
        self, *, rgb: NDArray[np.uint8], depth_m: NDArray[np.float32] | None = None, timestamp_s: float
    ) -> int:
        """Add the next frame (colour, depth in metres aligned to it, capture time in seconds); its flow
        is computed in the background. Parameters, the frame's index returned and the :class:`ClipError`
        of a frame that is not kept: :meth:`LiveWindow.push <workers.pipeline.live_window.LiveWindow.push>`.
        """
        return self.window.push(rgb=rgb, depth_m=depth_m, timestamp_s=timestamp_s)

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the flow of every pushed frame is computed; False on timeout."""
        return self.window.wait(timeout_s)

    def close(self) -> None:
        """Stop the flow threads (idempotent)."""
        self.window.close()

    # Estimates ---------------------------------------------------------------------------------

    @property
    def fps(self) -> float:
        """The nominal frame rate: the configured one, or measured from the kept frames' timestamps."""
        if self.config.fps is not None:
            return self.config.fps
        times = self.window.kept_times()
        n = len(times)
        if n < 2:
            raise AnalysisError("the frame rate cannot be measured from fewer than two frames; give fps")
        from workers.pipeline.clipio.types import uniform_fps_from_timestamps

        return uniform_fps_from_timestamps(times)[0]

    def _signal(self) -> _Signal | None:
        """The moving region's mean flow along its motion axis; None before there is motion to follow."""
        snapshot = self.window.signal_snapshot(min_flows=8, region_of=_moving_region)
        if snapshot is None:
            return None
        n, times, mask = snapshot.samples, snapshot.times_s, snapshot.region
        mean = snapshot.columns_px.reshape(n, -1, 2).mean(axis=1, dtype=np.float64)
        camera = snapshot.camera_px
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
        self.window.raise_flow_error()
        if not self.window.motion_seen:
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
        base = self.window.base
        return LiveEstimate(
            frames_received=self.window.frames_received,
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

        rows, cols = _around(mask, margin=DEPTH_MARGIN_PX)
        depth = self.window.depth(n, rows=rows, cols=cols)
        full_mask = (
            cv2.resize(mask.astype(np.uint8), (self.width, self.height), interpolation=cv2.INTER_NEAREST) > 0
        )
        where = DepthContext(
            depth=depth,
            region=mask[rows, cols],
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
        self.window.raise_flow_error()
        n = self.window.flows
        if n < 7 or not self.window.has_first_frame:
            raise AnalysisError(
                f"the stream delivered {self.window.frames_received} frame(s); an analysis needs at least 8"
            )
        return self._final_analysis(n, config=analysis_config or AnalysisConfig(), excitations=excitations)

    def _final_analysis(self, n: int, *, config: AnalysisConfig, excitations: list[Excitation]) -> Analysis:
        """The full analysis of the window's ``n`` flow maps, without computing them again: the batch
        stages after the frame stream (:func:`~workers.pipeline.analysis.analyze_window`)."""
        watch = Stopwatch()
        buffers = self.window.buffers(n)
        first, stop = self.window.base, self.window.base + n + 1
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
            has_depth=self.window.has_depth,
            depth_scale=None,
            intrinsics=self.intrinsics,
        )
        watch.lap("flow")
        result = analyze_window(buffers, plan, info, config=config, excitations=excitations, watch=watch)
        received = self.window.frames_received
        if received > stop:
            result.quality.append(
                QualityNote(
                    "window",
                    f"frames {first}-{stop} of the {received} streamed were analysed (the window "
                    f"holds at most {self.config.window_frames} frames from just before the motion)",
                    "info",
                )
            )
        result.parameters |= {
            "live": True,
            "target_relative_uncertainty": self.config.target_relative_uncertainty,
        }
        return result


__all__ = ["LiveAnalysis", "LiveConfig"]

"""The measuring pipeline wired together: clip -> flow -> spectra -> peaks -> segmentation -> ring-down fit
-> mechanics. :func:`analyze` is the one entry point; it takes a clip reader and dataclasses and returns an
:class:`Analysis` dataclass (no files are written here).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import ClipInfo, ClipReader, ClosingReader, Frame, Intrinsics
from workers.pipeline.errors import AnalysisError, ParameterError
from workers.pipeline.flow import (
    FlowConfig,
    flow_magnitude,
    flow_stream,
    needs_resampling,
    prepare_gray,
    resample_uniform,
)
from workers.pipeline.mechanics import (
    depth_track,
    detect_release,
    fit_component,
    object_motion,
    register_translation,
    release_amplitude,
    release_instant,
    silhouette,
    stiffness_and_mass,
)
from workers.pipeline.segmentation import (
    Exclusion,
    RejectedPeak,
    SegmentationConfig,
    exclude_background_surfaces,
    frequency_map,
    reject_artefacts,
    segment,
    upsample_labels,
)
from workers.pipeline.spectrum import (
    Peak,
    Ringdown,
    RingdownFit,
    background_spectrum,
    find_peaks,
    fit_ringdown,
    fold_harmonics,
    median_rows,
    noise_floor,
    pixel_spectra,
    sliding_ringdown,
    whitened_spectrum,
)
from workers.pipeline.spectrum import warm_up as spectrum_warm_up
from workers.pipeline.survey import Survey, WindowPlan, plan_window, survey_motion

Method = Literal["default", "paper"]
#: progress(stage, fraction of the whole analysis in [0, 1])
Progress = Callable[[str, float], None]

DEFAULT_MAX_FRAMES = 256
#: Memory budget of an automatically chosen window's buffers (flow maps, grey frames, depth, spectra).
DEFAULT_WINDOW_MIB = 384.0
#: Relative standard uncertainty of flow-measured amplitudes (dense flow is biased low near edges).
FLOW_AMPLITUDE_REL_SD = 0.03
#: ... of registration-measured amplitudes (texture interpolation, residual non-rigidity).
REGISTRATION_REL_SD = 0.004
#: Relative systematic uncertainty of a depth sensor's distance (calibration, plane fit).
DEPTH_REL_SD = 0.004
#: Relative uncertainty per unit of line-of-sight motion (|z| / amplitude), measured on ground truth.
OUT_OF_PLANE_REL_SD = 0.015
#: Relative uncertainty assumed for a user-given constant distance (depth_m).
DEPTH_OVERRIDE_REL_SD = 0.02
#: Systematic floors on the ring-down fit's statistical uncertainties (model mismatch: projection
#: nonlinearity, registration errors correlated with the motion), measured on randomised ground truth.
FREQUENCY_REL_FLOOR = 3e-4
#: ... and, for a strongly damped object, this fraction of its resonance's half-power width (2 zeta f):
#: model mismatch shifts a broad resonance further (a clear 8-10 Hz object at zeta 0.09 is 8e-4 off).
FREQUENCY_LINEWIDTH_FLOOR = 0.005
DAMPING_REL_FLOOR = 0.015
DAMPING_ABS_FLOOR = 3e-4
#: A region whose motion fits a damped oscillation this poorly (dB) is not an object.
MIN_RINGDOWN_SNR_DB = 3.0
#: RMS per-frame motion of the picture's border (flow-grid pixels) above which it is removed as camera motion.
CAMERA_MOTION_MIN_PX = 0.05
#: Objects whose pixels move this coherently are registered as rigid bodies for their amplitude.
RIGID_COHERENCE = 0.7


@dataclass(frozen=True, kw_only=True)
class Excitation:
    """How the object was excited.

    Attributes
    ----------
    kind : ``"step_release"`` (value: held force F in N) or ``"impulse"`` (value: impulse J in N·s)
    value : float
    uncertainty : float
        Standard uncertainty of ``value``.
    object_id : int or None
        The object it applies to, by id.
    point_px : (x, y) or None
        ... or by a point on it (input pixels).
    box_px : (x, y, w, h) or None
        ... or by a box around it (input pixels). With none of the three: the main (strongest) object.
    """

    kind: Literal["step_release", "impulse"]
    value: float
    uncertainty: float = 0.0
    object_id: int | None = None
    point_px: tuple[float, float] | None = None
    box_px: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("step_release", "impulse"):
            raise ParameterError(f"excitation type {self.kind!r} is unknown; use step_release or impulse")
        if not (math.isfinite(self.value) and self.value > 0):
            raise ParameterError(f"excitation value {self.value} must be a positive finite number")
        if not (math.isfinite(self.uncertainty) and self.uncertainty >= 0):
            raise ParameterError("excitation uncertainty must be finite and >= 0")


@dataclass(frozen=True, kw_only=True)
class AnalysisConfig:
    """Analysis options; defaults work without tuning.

    Attributes
    ----------
    method : ``"default"`` or ``"paper"``
        ``paper`` runs the seed recipe literally (flow magnitude, argmax bin, x ≈ Vmax / 4f) for comparison.
    flow : FlowConfig or None
        None picks the method's default (DIS at half resolution; Farnebäck at full resolution for paper).
    frames : int or None
        Analysis window length in frames (N + 1 frames give N flow maps). Default: min(clip, 256), or for
        a longer clip the window a survey of the whole clip chooses (see ``auto_window``).
    start_frame : int or None
        First frame of the window; default 0 (or the survey's choice).
    min_frequency_hz, max_frequency_hz : float or None
        Band searched; default two cycles per window up to 0.98 x Nyquist.
    depth_m : float or None
        Object distance for clips without depth.
    segmentation : SegmentationConfig
    max_objects : int
    auto_window : bool
        When neither ``frames`` nor ``start_frame`` is given and the clip is longer than 256 frames, survey
        the whole clip first (:mod:`workers.pipeline.survey`) and analyse the window where the strongest
        ring-down is, long enough for about ten periods of its lowest frequency, every k-th frame when
        the motion is far slower than the frame rate. False: the first 256 frames.
    max_window_mib : float
        Memory budget (MiB) of an automatically chosen window's buffers; bounds its length.
    flow_threads : int or None
        Frame pairs whose flow is computed at once; None keeps the flow's own setting (two). One runs
        the flow as the paper's recipe did, a pair at a time.
    """

    method: Method = "default"
    flow: FlowConfig | None = None
    frames: int | None = None
    start_frame: int | None = None
    min_frequency_hz: float | None = None
    max_frequency_hz: float | None = None
    depth_m: float | None = None
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    max_objects: int = 8
    auto_window: bool = True
    max_window_mib: float = DEFAULT_WINDOW_MIB
    flow_threads: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_window_mib) and self.max_window_mib > 0):
            raise ParameterError(f"max_window_mib={self.max_window_mib} must be a positive number of MiB")
        if self.flow_threads is not None and self.flow_threads < 1:
            raise ParameterError(f"flow_threads={self.flow_threads} must be at least 1")

    def resolved_flow(self) -> FlowConfig:
        if self.flow is not None:
            flow = self.flow
        elif self.method == "paper":
            flow = FlowConfig(method="farneback", scale=1.0)
        else:
            flow = FlowConfig()
        if self.flow_threads is not None:
            flow = dataclasses.replace(flow, threads=self.flow_threads)
        return flow

    def describe(self) -> dict[str, Any]:
        """Every parameter, defaults included, as JSON-ready data."""
        fl = self.resolved_flow()
        return {
            "method": self.method,
            "flow": fl.method,
            "flow_scale": fl.scale if fl.scale is not None else "auto",
            "dis_preset": fl.dis_preset if fl.method == "dis" else None,
            "flow_threads": fl.threads,
            "frames": self.frames,
            "start_frame": self.start_frame or 0,
            "min_frequency_hz": self.min_frequency_hz,
            "max_frequency_hz": self.max_frequency_hz,
            "depth_m": self.depth_m,
            "segmentation": {
                "noise_factor": self.segmentation.noise_factor,
                "relative_level": self.segmentation.relative_level,
                "purity": self.segmentation.purity,
                "band_bins": self.segmentation.band_bins,
                "min_area_fraction": self.segmentation.min_area_fraction,
            },
            "max_objects": self.max_objects,
            "auto_window": self.auto_window,
            "max_window_mib": self.max_window_mib,
        }


@dataclass(frozen=True)
class QualityNote:
    """A reason why a result may be unreliable."""

    code: str
    message: str
    severity: Literal["info", "warning", "error"] = "warning"


@dataclass
class ObjectMeasurement:
    """Everything measured for one object. Frequencies in Hz, lengths in metres unless ``_px``."""

    id: int
    eigenfrequency_hz: float
    eigenfrequency_sd_hz: float | None
    natural_frequency_hz: float
    damping_ratio: float | None
    damping_ratio_sd: float | None
    amplitude_px: float | None
    amplitude_m: float | None
    amplitude_sd_m: float | None
    depth_m: float | None
    motion_direction: tuple[float, float, float] | None
    stiffness_n_per_m: float | None
    stiffness_sd: float | None
    mass_kg: float | None
    mass_sd: float | None
    pixel_count: int
    bbox_px: tuple[int, int, int, int]
    harmonics_hz: list[float]
    release_time_s: float | None
    snr_db: float | None
    null_reasons: list[str] = field(default_factory=list)
    #: How the amplitude was measured: ``registration`` (rigid body, sub-pixel) or ``flow``.
    amplitude_source: str = "flow"
    #: What else was seen: excluded pixels, out-of-plane motion, ...
    notes: list[str] = field(default_factory=list)
    #: Sliding-window ring-down of the motion after release (times relative to the window start).
    ringdown: Ringdown | None = None
    #: Fraction of the object's pixels at the sensor's limits (0 or 255) in the first frame.
    saturated_fraction: float = 0.0
    #: Seconds of motion after release that were fitted.
    fitted_duration_s: float = 0.0
    #: Displacement of the object along its axis, input pixels, per frame of the window (for plots).
    displacement_px: NDArray[np.float64] | None = None
    #: Fitted model displacement at the same frames (NaN before release), input pixels.
    model_displacement_px: NDArray[np.float64] | None = None

    @property
    def angular_frequency_rad_s(self) -> float:
        return 2 * math.pi * self.natural_frequency_hz


@dataclass
class Analysis:
    """The outcome of :func:`analyze`.

    Attributes
    ----------
    objects : list of ObjectMeasurement
        Strongest first; ``objects[i].id == i + 1`` is its value in ``labels``.
    labels : ndarray of uint16, shape (H, W)
        Object label per input pixel, 0 = background.
    frequencies_hz, power : ndarray of float64, shape (F,)
        Summed motion spectrum.
    frequency_map_hz : ndarray of float32, shape (h, w)
        Per-pixel dominant frequency on the flow grid; ``frequency_map_valid`` marks pixels above noise.
    frame_rgb : ndarray of uint8, shape (H, W, 3)
        A representative frame (the first of the window).
    fps : float
        The clip's frame rate.
    fps_source : str
    frames_used : (first, last)
        Frame index range [first, last) analysed.
    frame_step : int
        Every ``frame_step``-th frame of that range was analysed (flow maps and spectra are sampled at
        ``sample_rate_hz = fps / frame_step``).
    window_survey : Survey or None
        The survey of the whole clip that chose the window (None when the window was given or the clip
        is short).
    band_hz : (low, high)
    quality : list of QualityNote
    timings_s : dict
        Seconds per stage, adding up to the analysis's time: ``setup`` or ``survey``, ``decode`` and
        ``flow`` (the stream of frames: the reader's CPU time reading and decoding them, and the rest of
        the stream's time, the optical flow), ``spectrum``, ``segmentation``, ``mechanics``.
    parameters : dict
    method : str
    """

    objects: list[ObjectMeasurement]
    labels: NDArray[np.uint16]
    frequencies_hz: NDArray[np.float64]
    power: NDArray[np.float64]
    frequency_map_hz: NDArray[np.float32]
    frequency_map_valid: NDArray[np.bool_]
    frame_rgb: NDArray[np.uint8]
    fps: float
    fps_source: str
    frames_used: tuple[int, int]
    band_hz: tuple[float, float]
    quality: list[QualityNote]
    timings_s: dict[str, float]
    parameters: dict[str, Any]
    method: str
    peaks: list[Peak] = field(default_factory=list)
    #: What the summed spectrum would be over static background (same frequencies), for the noise floor.
    noise_power: NDArray[np.float64] | None = None
    #: Peaks that were not objects (flicker, keyframes, camera motion), with the reason.
    rejected_peaks: list[RejectedPeak] = field(default_factory=list)
    #: Ring-down fit SNR (dB) of each region dropped because its motion did not ring down coherently.
    incoherent_snr_db: list[float] = field(default_factory=list)
    frame_step: int = 1
    window_survey: Survey | None = None

    @property
    def eigenfrequency_hz(self) -> float | None:
        return self.objects[0].eigenfrequency_hz if self.objects else None

    @property
    def sample_rate_hz(self) -> float:
        """Rate of the analysed samples (flow maps, spectra, displacement), Hz."""
        return self.fps / self.frame_step


@dataclass
class _Buffers:
    flow: NDArray[np.float32]  # (N, h, w, 2)
    depth: NDArray[np.float32] | None  # (N + 1, h, w), metres, NaN invalid
    gray: NDArray[np.uint8] | None  # (N + 1, H, W) at input resolution, for registration
    first_rgb: NDArray[np.uint8]
    count: int
    times_s: NDArray[np.float64]  # (N + 1,) capture times, seconds from the window's first frame
    camera_px: NDArray[np.float32]  # (N, 2) per-frame camera motion removed from the flow, grid px
    start_s: float  # capture time of the window's first frame, seconds from the clip's first frame
    decode_s: float = 0.0  # CPU time the reader took to read and decode the frames (beside the flow)


class _Stopwatch:
    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now

    def stream_lap(self, buffers: _Buffers) -> None:
        """The lap of the frame stream, as ``decode`` (the reader's share) and ``flow`` (the rest)."""
        now = time.perf_counter()
        self.times["decode"] = buffers.decode_s
        self.times["flow"] = now - self._t - buffers.decode_s
        self._t = now


@dataclass(frozen=True)
class _Plan:
    """What :func:`_plan` decided: frame rates, window, flow settings and the survey behind them."""

    fps: float  # rate of the analysed samples: the clip's rate / step
    clip_fps: float
    start: int  # clip frames [start, stop), every step-th
    stop: int
    step: int
    flow: FlowConfig
    grid: tuple[int, int]
    pixel_scale: float  # input pixels per grid pixel
    survey: Survey | None = None
    window: WindowPlan | None = None

    def source(self, reader: ClipReader) -> tuple[ClipReader, int, int]:
        """The reader and frame range to stream: every ``step``-th frame of the window."""
        if self.step == 1:
            return reader, self.start, self.stop
        strided = _Strided(reader, start=self.start, stop=self.stop, step=self.step)
        return strided, 0, strided.info.frames


class _Strided(ClosingReader):
    """Every ``step``-th frame of ``[start, stop)`` of a clip, as a clip of its own (frame rate / step)."""

    def __init__(self, reader: ClipReader, *, start: int, stop: int, step: int) -> None:
        self._reader, self._start, self._step = reader, start, step
        info = reader.info
        count = (stop - start - 1) // step + 1
        self._stop = start + (count - 1) * step + 1
        stamps = info.timestamps_s
        self._info = dataclasses.replace(
            info,
            frames=count,
            fps=None if info.fps is None else info.fps / step,
            timestamps_s=None if stamps is None else stamps[start : self._stop : step],
        )

    @property
    def info(self) -> ClipInfo:
        return self._info

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        stop = self._info.frames if stop is None else min(stop, self._info.frames)
        first = self._start + start * self._step
        last = self._start + (stop - 1) * self._step + 1
        for i, frame in enumerate(self._reader.frames(first, last)):
            if i % self._step == 0:
                yield dataclasses.replace(frame, index=start + i // self._step)

    def close(self) -> None:
        """The wrapped reader is its owner's to close."""


def _plan(
    info: ClipInfo,
    config: AnalysisConfig,
    *,
    reader: ClipReader | None = None,
    progress: Progress | None = None,
    survey: Survey | None = None,
) -> _Plan:
    """Frame rate, window [start, stop) and step, flow settings, flow grid and input pixels per grid pixel.

    With a ``reader``, a clip longer than the default window whose window the user did not fix is
    surveyed first (unless a ``survey`` of it is given) and the window chosen from what moves where
    (see :mod:`workers.pipeline.survey`).
    """
    if info.fps is None:
        raise ParameterError(
            "the clip carries no frame rate; give the true recording rate with --fps (API: fps)"
        )
    fps = float(info.fps)
    flow_cfg = config.resolved_flow()
    grid = flow_cfg.grid_shape(info.height, info.width)
    pixel_scale = info.width / grid[1]
    surveyed = (
        reader is not None
        and config.auto_window
        and config.frames is None
        and config.start_frame is None
        and info.frames > DEFAULT_MAX_FRAMES
    )
    if not surveyed:
        start, stop = _window(info.frames, config)
        return _Plan(fps, fps, start, stop, 1, flow_cfg, grid, pixel_scale)
    assert reader is not None
    if survey is None:
        survey = survey_motion(_survey_grays(reader, progress), fps=fps, total_frames=info.frames)
    # Bytes per flow map: flow (2 x float32), its share of the spectra and depth on the grid, and the
    # grey frame at input resolution kept for registration.
    per_sample = grid[0] * grid[1] * (8 + 4 + (4 if info.has_depth else 0)) + info.height * info.width
    budget = int(config.max_window_mib * 2**20 / per_sample)
    window = plan_window(
        survey,
        total_frames=info.frames,
        default_frames=DEFAULT_MAX_FRAMES,
        max_samples=max(budget, DEFAULT_MAX_FRAMES),
        grid_scale=1.0 / pixel_scale,
    )
    start, stop, step = window.start_frame, window.stop_frame, window.frame_step
    return _Plan(fps / step, fps, start, stop, step, flow_cfg, grid, pixel_scale, survey, window)


def _survey_grays(reader: ClipReader, progress: Progress | None) -> Iterator[NDArray[np.uint8]]:
    """Every frame of the clip in grey at input resolution (the reader's fast path when it has one)."""
    import cv2

    total = max(reader.info.frames, 1)
    fast = getattr(reader, "gray_frames", None)
    frames: Iterator[NDArray[np.uint8]] = (
        fast() if callable(fast) else (cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY) for f in reader.frames())
    )
    for i, gray in enumerate(frames):
        if progress is not None and i % 64 == 0:
            progress("survey", 0.05 * i / total)
        yield gray


def _window(total: int, config: AnalysisConfig) -> tuple[int, int]:
    """The window the user gave (or the first ``DEFAULT_MAX_FRAMES`` frames)."""
    start = config.start_frame or 0
    if start >= total - 2:
        raise ParameterError(f"start_frame={start} leaves fewer than 3 of the clip's {total} frames")
    length = config.frames if config.frames is not None else min(total - start, DEFAULT_MAX_FRAMES)
    if length < 8:
        raise ParameterError(f"frames={length}: the analysis window needs at least 8 frames")
    stop = min(total, start + length)
    if stop - start < 8:
        raise ParameterError(f"only {stop - start} frames from start_frame={start}; need at least 8")
    return start, stop


def _survey_notes(plan: _Plan, objects: list[ObjectMeasurement]) -> list[QualityNote]:
    """What the survey of the whole clip says about the window and the frequencies found in it."""
    survey, window = plan.survey, plan.window
    if survey is None or window is None:
        return []
    notes = [QualityNote("window", window.reason, "info")]
    if objects and survey.peaks and not survey.explains(objects[0].eigenfrequency_hz):
        seen = ", ".join(f"{p.frequency_hz:.4g}" for p in survey.peaks[:3])
        notes.append(
            QualityNote(
                "survey_disagrees",
                f"the main object's {objects[0].eigenfrequency_hz:.4g} Hz in frames {plan.start}-{plan.stop} "
                f"is not among the peaks of the whole clip's averaged (Welch) spectrum ({seen} Hz): the "
                "window may miss the main motion or alias it; check start_frame and frames",
            )
        )
    return notes


def _band(config: AnalysisConfig, fps: float, n: int) -> tuple[float, float]:
    nyquist = fps / 2
    lo = config.min_frequency_hz if config.min_frequency_hz is not None else 1.5 * fps / n
    hi = config.max_frequency_hz if config.max_frequency_hz is not None else 0.98 * nyquist
    hi = min(hi, nyquist)
    if lo >= hi:
        raise ParameterError(
            f"frequency band [{lo:.3g}, {hi:.3g}] Hz is empty at {fps:g} fps with {n} flow samples; "
            "widen the band or analyse more frames"
        )
    return lo, hi


def _stream(
    reader: ClipReader,
    start: int,
    stop: int,
    grid: tuple[int, int],
    flow_cfg: FlowConfig,
    progress: Progress | None,
    magnitude: bool = False,
    keep_gray: bool = False,
) -> _Buffers:
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
    return _Buffers(
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


def _object_depth(depth: NDArray[np.float32] | None, mask: NDArray[np.bool_]) -> float | None:
    if depth is None:
        return None
    # Interior of the mask: erode so edge pixels that sometimes see the background do not count.
    import cv2

    core = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    if core.sum() < 10:
        core = mask
    values = depth[:, core]
    values = values[np.isfinite(values)]
    if values.size == 0:
        return None
    return float(np.median(values))


def _bbox(mask: NDArray[np.bool_]) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return (0, 0, 0, 0)
    x0, y0 = int(xs.min()), int(ys.min())
    return (x0, y0, int(xs.max()) - x0 + 1, int(ys.max()) - y0 + 1)


def analyze(
    reader: ClipReader,
    *,
    config: AnalysisConfig | None = None,
    excitation: Excitation | Sequence[Excitation] | None = None,
    progress: Progress | None = None,
) -> Analysis:
    """Measure the vibrating objects of a clip.

    Parameters
    ----------
    reader : ClipReader
        An open clip (see :func:`workers.pipeline.clipio.open_clip`).
    config : AnalysisConfig, optional
    excitation : Excitation or sequence of Excitation, optional
        One per excited object (by id, image point or box; the main object when none is named). Objects
        without one get frequencies, damping and masks, and stiffness and mass None.
    progress : callable, optional
        ``progress(stage, fraction)``.

    Returns
    -------
    Analysis
    """
    config = config or AnalysisConfig()
    if excitation is None:
        excitations: list[Excitation] = []
    elif isinstance(excitation, Excitation):
        excitations = [excitation]
    else:
        excitations = list(excitation)
    if config.method == "paper":
        from workers.pipeline.paper import analyze_paper

        main = next((e for e in excitations if e.object_id in (None, 1)), None)
        return analyze_paper(reader, config=config, excitation=main, progress=progress)
    result = _analyze_default(reader, config=config, excitations=excitations, progress=progress)
    if config.flow is None and _needs_careful_flow(result):
        # The fast default flow ("fine": no variational refinement) is five times cheaper than DIS
        # "medium" and as accurate on clear motion; weak, sub-pixel motion is measured again on medium.
        careful = dataclasses.replace(config, flow=FlowConfig(dis_preset="medium"))
        first = result.timings_s
        result = _analyze_default(
            reader,
            config=careful,
            excitations=excitations,
            progress=progress,
            survey=result.window_survey,
        )
        result.timings_s = {"fast_flow_pass": sum(first.values()), **result.timings_s}
        result.quality.append(
            QualityNote(
                "careful_flow",
                "the fast optical flow found only weak motion, so the clip was analysed again with the "
                "careful flow (DIS medium)",
                "info",
            )
        )
    return result


#: Objects whose ring-down stands less than this above the noise are measured again on careful flow.
CAREFUL_FLOW_SNR_DB = 10.0
#: ... as are clips with a region dropped as incoherent whose ring-down fit still explained at least as
#: much as its residual (a weak vibration the fast flow may have blurred); regions further below are
#: noise (a clear 5 Hz object at 1280x720 left one at -5 dB, which cost a second, careful pass).
CAREFUL_FLOW_INCOHERENT_DB = 0.0


def _needs_careful_flow(result: Analysis) -> bool:
    """Whether the fast flow may have missed or blurred something: no object, a weak one, a peak that
    was rejected (a weak vibration on noisy flow can look like an artefact, and an artefact such as
    flicker is characterised better on the careful flow), or a dropped region that was nearly coherent."""
    if not result.objects or result.rejected_peaks:
        return True
    if any(snr >= CAREFUL_FLOW_INCOHERENT_DB for snr in result.incoherent_snr_db):
        return True
    return any(o.snr_db is None or o.snr_db < CAREFUL_FLOW_SNR_DB for o in result.objects)


def _analyze_default(
    reader: ClipReader,
    *,
    config: AnalysisConfig,
    excitations: list[Excitation],
    progress: Progress | None,
    survey: Survey | None = None,
) -> Analysis:
    """``survey``: a survey of this clip already made (a second pass reuses the first's)."""
    watch = _Stopwatch()
    info = reader.info
    plan = _plan(info, config, reader=reader, progress=progress, survey=survey)
    if progress:
        progress("flow", 0.05)
    watch.lap("survey" if plan.survey is not None else "setup")
    source, first, last = plan.source(reader)
    buffers = _stream(source, first, last, plan.grid, plan.flow, progress, keep_gray=True)
    watch.stream_lap(buffers)
    n = buffers.count
    band = _band(config, plan.fps, n)
    quality: list[QualityNote] = []

    if progress:
        progress("spectrum", 0.82)
    uniform_flow = buffers.flow
    if needs_resampling(buffers.times_s, plan.fps):
        uniform_flow, _ = resample_uniform(buffers.flow, buffers.times_s, plan.fps)
        quality.append(
            QualityNote(
                "uneven_timing",
                f"frame times deviate from a uniform {plan.fps:g} fps grid "
                f"({info.dropped_frames} dropped frames): spectra were resampled and the ring-down "
                "was fitted at the true frame times",
                "info",
            )
        )
    spectra = pixel_spectra(uniform_flow, fps=plan.fps, band_hz=band)
    del uniform_flow
    summed = spectra.power.sum(axis=1, dtype=np.float64)
    noise = background_spectrum(spectra)
    # Two detectors: the summed spectrum against static background finds strong motion, however
    # damped; the whitened spectrum finds weak, sub-pixel vibration spread over many pixels.
    strong = find_peaks(
        spectra.frequencies_hz, summed, band_hz=band, noise=noise, max_peaks=config.max_objects
    )
    whitened, _ = whitened_spectrum(spectra, band_hz=band)
    weak = find_peaks(
        spectra.frequencies_hz,
        whitened,
        band_hz=band,
        noise=noise_floor(whitened, width=max(15, len(whitened) // 6)),
        min_snr_db=3.0,
        max_peaks=config.max_objects,
    )
    peaks = fold_harmonics(
        [*strong, *(Peak(**{**vars(p), "harmonics_hz": []}) for p in weak)],
        bin_hz=spectra.bin_hz,
        max_peaks=config.max_objects,
    )
    watch.lap("spectrum")

    if progress:
        progress("segmentation", 0.88)
    seg = segment(spectra, peaks, grid_shape=plan.grid, band_hz=band, config=config.segmentation)
    seg, rejected = reject_artefacts(seg, spectra, band_hz=band)
    for item in rejected:
        quality.append(QualityNote("artefact_peak", item.reason, "info"))
    labels_grid = seg.labels
    exclusions: list[Exclusion] = []
    if buffers.depth is not None and seg.peaks:
        labels_grid, exclusions = exclude_background_surfaces(labels_grid, buffers.depth)
    fmap, fvalid = frequency_map(spectra, grid_shape=plan.grid, band_hz=band)
    labels_full = upsample_labels(labels_grid, (info.height, info.width))
    watch.lap("segmentation")

    if progress:
        progress("mechanics", 0.93)
    intrinsics: Intrinsics | None = info.intrinsics
    by_label = _excitations_by_label(list(excitations), labels_full, len(seg.peaks))
    objects: list[ObjectMeasurement] = []
    for label, peak in enumerate(seg.peaks, start=1):
        mask = labels_grid == label
        full_mask = labels_full == label
        objects.append(
            _measure_object(
                label=label,
                peak=peak,
                mask=mask,
                full_mask=full_mask,
                buffers=buffers,
                fps=plan.fps,
                pixel_scale=plan.pixel_scale,
                intrinsics=intrinsics,
                depth_override=config.depth_m,
                excitation=by_label.get(label),
                excluded=[e.reason for e in exclusions if e.label == label],
            )
        )
    objects, labels_full, dropped = _drop_incoherent(objects, labels_full, quality, by_label)
    incoherent = [o.snr_db or 0.0 for o in dropped]
    if not objects:
        quality.append(
            QualityNote(
                "no_motion",
                "no vibrating object stands above the noise; check the frame rate, the band and that the "
                "object moves in the analysed frames",
                "error",
            )
        )
    if not info.has_depth and config.depth_m is None:
        quality.append(
            QualityNote(
                "no_depth",
                "the clip has no depth: amplitudes in metres, stiffness and mass need depth or depth_m",
            )
        )
    quality.extend(_quality_notes(objects, fps=plan.fps, band=band, bin_hz=plan.fps / n))
    quality.extend(_survey_notes(plan, objects))
    watch.lap("mechanics")
    return Analysis(
        objects=objects,
        labels=labels_full,
        frequencies_hz=spectra.frequencies_hz,
        power=summed,
        frequency_map_hz=fmap,
        frequency_map_valid=fvalid,
        frame_rgb=buffers.first_rgb,
        fps=plan.clip_fps,
        fps_source=info.fps_source or "unknown",
        frames_used=(plan.start, plan.stop),
        band_hz=band,
        quality=quality,
        timings_s=watch.times,
        parameters=config.describe()
        | {
            "frames": plan.stop - plan.start,
            "start_frame": plan.start,
            "frame_step": plan.step,
            "band_hz": list(band),
            "flow_scale": plan.flow.effective_scale(info.width),
        },
        method="default",
        peaks=seg.peaks,
        noise_power=noise,
        rejected_peaks=rejected,
        incoherent_snr_db=incoherent,
        frame_step=plan.step,
        window_survey=plan.survey,
    )


def _drop_incoherent(
    objects: list[ObjectMeasurement],
    labels: NDArray[np.uint16],
    quality: list[QualityNote],
    excited: dict[int, Excitation],
) -> tuple[list[ObjectMeasurement], NDArray[np.uint16], list[ObjectMeasurement]]:
    """Remove regions whose motion does not ring down coherently (fit SNR below ``MIN_RINGDOWN_SNR_DB``)
    unless the user named them in an excitation; renumber the rest 1, 2, ... in objects and labels.
    Returns the kept objects, their labels and the removed objects."""
    kept = [o for o in objects if (o.snr_db or 0.0) >= MIN_RINGDOWN_SNR_DB or o.id in excited]
    dropped = [o for o in objects if o not in kept]
    for o in dropped:
        quality.append(
            QualityNote(
                "artefact_peak",
                f"{o.eigenfrequency_hz:.4g} Hz: the region's motion does not ring down coherently "
                f"({(o.snr_db or 0.0):.1f} dB); not reported as an object",
                "info",
            )
        )
    if not dropped:
        return objects, labels, dropped
    relabelled = np.zeros_like(labels)
    for new_id, o in enumerate(kept, start=1):
        relabelled[labels == o.id] = new_id
        o.id = new_id
    return kept, relabelled, dropped


def _quality_notes(
    objects: list[ObjectMeasurement], *, fps: float, band: tuple[float, float], bin_hz: float
) -> list[QualityNote]:
    """Reasons why an object's figures may be unreliable."""
    notes: list[QualityNote] = []
    for obj in objects:
        f = obj.eigenfrequency_hz
        name = f"object {obj.id} ({f:.4g} Hz)"
        if f >= 0.4 * fps:
            notes.append(
                QualityNote(
                    "possibly_aliased",
                    f"{name} is near the Nyquist rate ({fps / 2:g} Hz): the true frequency may be "
                    f"{fps - f:.4g} Hz or higher; record at a higher frame rate or give the true fps",
                )
            )
        if obj.snr_db is not None and obj.snr_db < 6:
            notes.append(
                QualityNote(
                    "low_snr",
                    f"{name}: the ring-down stands only {obj.snr_db:.1f} dB above the noise; "
                    "push harder, light the object better or film closer",
                )
            )
        periods = f * obj.fitted_duration_s
        if periods < 3:
            notes.append(
                QualityNote(
                    "few_periods",
                    f"{name}: only {periods:.1f} periods of motion were analysed; record longer after the "
                    "release for reliable frequency and damping",
                )
            )
        if f - band[0] < 1.5 * bin_hz or band[1] - f < 1.5 * bin_hz:
            notes.append(
                QualityNote(
                    "band_edge",
                    f"{name} lies at the edge of the analysed band [{band[0]:.3g}, {band[1]:.3g}] Hz; "
                    "widen the band or change the window length",
                )
            )
        if obj.saturated_fraction > 0.05:
            notes.append(
                QualityNote(
                    "saturation",
                    f"{name}: {obj.saturated_fraction * 100:.0f} % of its pixels are clipped (black or "
                    "white); reduce the exposure so its texture can be tracked",
                )
            )
    return notes


def _excitations_by_label(
    excitations: list[Excitation], labels: NDArray[np.uint16], count: int
) -> dict[int, Excitation]:
    """Resolve each excitation to an object label: by id, by an image point, by a box, or the main one."""
    out: dict[int, Excitation] = {}
    for exc in excitations:
        label: int
        if exc.object_id is not None:
            label = exc.object_id
            where = f"object {label}"
        elif exc.point_px is not None:
            x, y = (round(v) for v in exc.point_px)
            where = f"point ({x}, {y})"
            if not (0 <= y < labels.shape[0] and 0 <= x < labels.shape[1]):
                raise ParameterError(
                    f"excitation {where} is outside the {labels.shape[1]}x{labels.shape[0]} frame"
                )
            label = int(labels[y, x])
            if label == 0:
                # Nearest object within 5 % of the frame diagonal.
                ys, xs = np.nonzero(labels)
                if len(xs):
                    d2 = (xs - x) ** 2 + (ys - y) ** 2
                    i = int(np.argmin(d2))
                    if d2[i] <= (0.05 * math.hypot(*labels.shape)) ** 2:
                        label = int(labels[ys[i], xs[i]])
        elif exc.box_px is not None:
            x, y, w, h = (round(v) for v in exc.box_px)
            where = f"box ({x}, {y}, {w}, {h})"
            crop = labels[max(0, y) : max(0, y + h), max(0, x) : max(0, x + w)]
            counts = np.bincount(crop.ravel(), minlength=count + 1)[1:]
            label = int(np.argmax(counts)) + 1 if counts.size and counts.max() > 0 else 0
        else:
            label = 1
            where = "the main object"
        if count == 0:
            continue  # nothing moved: the quality notes say so; the excitation applies to nothing
        if not 1 <= label <= count:
            raise ParameterError(
                f"excitation for {where} matches no object: {count} object(s) were found; "
                "name one by id, or by a point or box on it"
            )
        if label in out:
            raise ParameterError(f"two excitations apply to object {label}; give at most one per object")
        out[label] = exc
    return out


def _outline_grid(outline: NDArray[np.bool_], grid: tuple[int, int]) -> NDArray[np.bool_]:
    import cv2

    small = cv2.resize(outline.astype(np.uint8), (grid[1], grid[0]), interpolation=cv2.INTER_NEAREST)
    return np.asarray(small.astype(bool))


def _measure_object(
    *,
    label: int,
    peak: Peak,
    mask: NDArray[np.bool_],
    full_mask: NDArray[np.bool_],
    buffers: _Buffers,
    fps: float,
    pixel_scale: float,
    intrinsics: Intrinsics | None,
    depth_override: float | None,
    excitation: Excitation | None,
    excluded: list[str],
) -> ObjectMeasurement:
    def fitted(signal: NDArray[np.float64]) -> tuple[int, RingdownFit]:
        start = detect_release(signal)
        return start, fit_ringdown(
            signal,
            fps=fps,
            frequency_guess_hz=peak.frequency_hz,
            start_index=start,
            frame_times_s=buffers.times_s,
        )

    motion = object_motion(buffers.flow, mask, pixel_scale=pixel_scale)
    velocity = motion.velocity_px
    axis = motion.axis_px
    tracking = "flow"
    onset, fit = fitted(velocity)  # replaced by the registration's when that tracked the object
    shifts: NDArray[np.float64] | None = None  # image displacement per frame vs the reference, input px
    region = mask  # object pixels in the reference frame, grid
    if buffers.gray is not None and motion.coherence >= RIGID_COHERENCE:
        ref = int(np.argmax(np.abs(velocity)))
        position = np.concatenate([[0.0], np.cumsum(velocity)])
        initial = (position - position[ref])[:, None] * np.asarray(axis)[None, :]
        reach = float(np.abs(position - position[ref]).max()) / pixel_scale
        outline = silhouette(buffers.flow[ref], mask, axis_px=axis, shape=full_mask.shape, reach_px=reach)
        camera = np.concatenate([[[0.0, 0.0]], np.cumsum(buffers.camera_px, axis=0)]) * pixel_scale
        camera -= camera[ref]
        disp2d, failed = register_translation(
            buffers.gray, outline, ref_index=ref, initial_px=initial + camera
        )
        disp2d = disp2d - camera  # the object's motion relative to the camera
        if failed <= 0.1:
            centred = disp2d - disp2d.mean(axis=0)
            _, vecs = np.linalg.eigh(centred.T @ centred)
            new_axis = vecs[:, -1] if float(vecs[:, -1] @ np.asarray(axis)) >= 0 else -vecs[:, -1]
            registered = np.diff(disp2d @ new_axis)
            reg_onset, reg_fit = fitted(registered)
            # Registration is the sharper measurement (flow is biased low by smoothing) when it tracked
            # the object; when it locked onto the wrong texture (very fast or blurred motion) its
            # motion no longer follows the flow's.
            agreement = float(np.corrcoef(registered, velocity)[0, 1]) if np.std(registered) > 0 else 0.0
            if agreement >= 0.9:
                axis = (float(new_axis[0]), float(new_axis[1]))
                velocity, onset, fit = registered, reg_onset, reg_fit
                tracking = "registration"
                shifts = disp2d + camera  # where the object is in the image (depth maps)
                grid_outline = _outline_grid(outline, mask.shape)
                if grid_outline.sum() >= 16:
                    region = grid_outline
    f_floor = max(FREQUENCY_REL_FLOOR, FREQUENCY_LINEWIDTH_FLOOR * 2 * abs(fit.damping_ratio))
    f_sd = math.hypot(fit.frequency_sd_hz, f_floor * fit.frequency_hz)
    zeta_sd = math.sqrt(
        fit.damping_sd**2 + (DAMPING_REL_FLOOR * fit.damping_ratio) ** 2 + DAMPING_ABS_FLOOR**2
    )
    kind = excitation.kind if excitation else None
    t_rel = release_instant(fit, fps=fps, excitation=kind)
    amp_px = release_amplitude(fit, t_release_s=t_rel, excitation=kind)
    amp_sd_px = fit.amplitude_sd * math.exp(-fit.decay_per_s * t_rel)
    release_time = buffers.start_s + float(buffers.times_s[onset]) + t_rel
    times_from_onset = buffers.times_s - buffers.times_s[onset]

    null_reasons: list[str] = []
    notes: list[str] = list(excluded)
    amp_m = amp_sd_m = None
    direction = None
    depth: float | None = None
    depth_rel_sd = 0.0
    z_amp = z_sd = 0.0
    if buffers.depth is not None:
        grid_shifts = None if shifts is None else shifts / pixel_scale
        z_track = depth_track(buffers.depth, region, shifts_px=grid_shifts)
        finite = z_track[np.isfinite(z_track)]
        if finite.size:
            depth = float(np.median(finite))
            spread = float(np.median(np.abs(finite - depth))) * 1.4826 / math.sqrt(finite.size)
            depth_rel_sd = math.hypot(spread / depth, DEPTH_REL_SD)
            z_amp, z_sd, _ = fit_component(z_track, times_from_onset, fit, start_index=onset)
            if not (math.isfinite(z_sd) and abs(z_amp) > 2.5 * z_sd):
                z_amp, z_sd = 0.0, 0.0
    if depth is None and depth_override is not None:
        depth = depth_override
        depth_rel_sd = DEPTH_OVERRIDE_REL_SD
    if depth is None:
        null_reasons.append("no depth: give a clip with depth, or depth_m with the intrinsics")
    elif intrinsics is None:
        null_reasons.append("no camera intrinsics: give fx, fy (and cx, cy) for metric amplitude")
    else:
        # Envelope amplitudes at the fit start: image (px, along the axis) and depth (m, signed).
        a_img = fit.amplitude
        ax, ay = axis
        ys, xs = np.nonzero(full_mask)
        u = float(xs.mean()) if len(xs) else intrinsics.cx
        v = float(ys.mean()) if len(ys) else intrinsics.cy
        # Pinhole: u = fx X / Z + cx, so dX = du Z / fx + (u - cx) dZ / fx (likewise for y).
        dx = a_img * ax * depth / intrinsics.fx + (u - intrinsics.cx) * z_amp / intrinsics.fx
        dy = a_img * ay * depth / intrinsics.fy + (v - intrinsics.cy) * z_amp / intrinsics.fy
        vec = np.array([dx, dy, z_amp])
        a3 = float(np.linalg.norm(vec))
        if a3 > 0 and a_img > 0:
            amp_m = amp_px * a3 / a_img
            # An oscillation's axis has no sign: report it with its largest component positive.
            unit = vec / a3 * (1.0 if vec[int(np.argmax(np.abs(vec)))] >= 0 else -1.0)
            direction = (float(unit[0]), float(unit[1]), float(unit[2]))
            sys_rel = REGISTRATION_REL_SD if tracking == "registration" else FLOW_AMPLITUDE_REL_SD
            a_xy = math.hypot(dx, dy)
            rel_xy = math.sqrt((amp_sd_px / max(amp_px, 1e-12)) ** 2 + sys_rel**2 + depth_rel_sd**2)
            var = (a_xy / a3) ** 2 * (a_xy * rel_xy) ** 2 + (abs(z_amp) / a3) ** 2 * z_sd**2
            # Motion along the line of sight also scales the image; the residual coupling of scale
            # into the registered displacement is not modelled, so it is carried as uncertainty.
            var += (OUT_OF_PLANE_REL_SD * abs(z_amp)) ** 2
            amp_sd_m = amp_m * math.sqrt(var) / a3
            if abs(direction[2]) >= 0.05:
                notes.append(
                    f"motion has a component along the line of sight ({abs(direction[2]) * 100:.0f} %), "
                    "measured from depth"
                )
        else:
            null_reasons.append("amplitude is zero: the object did not move measurably")

    k = k_sd = m = m_sd = None
    if excitation is None:
        null_reasons.append("no excitation given: stiffness and mass need a held force or an impulse")
    elif amp_m is not None and amp_sd_m is not None:
        mech = stiffness_and_mass(
            kind=excitation.kind,
            value=excitation.value,
            value_sd=excitation.uncertainty,
            amplitude_m=amp_m,
            amplitude_sd_m=amp_sd_m,
            natural_frequency_hz=fit.natural_frequency_hz,
            damped_frequency_hz=fit.frequency_hz,
            frequency_sd_hz=f_sd,
        )
        k, k_sd, m, m_sd = mech.stiffness_n_per_m, mech.stiffness_sd, mech.mass_kg, mech.mass_sd
        null_reasons.extend(mech.null_reasons)

    n = len(velocity)
    ringdown = None
    if n - onset >= 16:
        ringdown = sliding_ringdown(velocity[onset:], fps=fps, frequency_hz=fit.frequency_hz)
        ringdown = Ringdown(
            times_s=ringdown.times_s + float(buffers.times_s[onset]),
            amplitude=ringdown.amplitude,
            frequency_hz=ringdown.frequency_hz,
            spectrogram_hz=ringdown.spectrogram_hz,
            spectrogram_power=ringdown.spectrogram_power,
        )
    pixels = buffers.first_rgb[full_mask]
    saturated = float(np.mean(np.any((pixels >= 255) | (pixels <= 0), axis=1))) if pixels.size else 0.0
    disp = np.concatenate([[0.0], np.cumsum(velocity)])
    t = times_from_onset[: n + 1]
    model = np.full(n + 1, np.nan)
    after = t >= t_rel
    model[after] = fit.displacement(t[after])
    # Align the integrated displacement to the model's mean level after release.
    if after.any():
        disp = disp - np.nanmean(disp[after] - model[after])
    return ObjectMeasurement(
        id=label,
        eigenfrequency_hz=fit.frequency_hz,
        eigenfrequency_sd_hz=f_sd,
        natural_frequency_hz=fit.natural_frequency_hz,
        damping_ratio=fit.damping_ratio,
        damping_ratio_sd=zeta_sd,
        amplitude_px=amp_px,
        amplitude_m=amp_m,
        amplitude_sd_m=amp_sd_m,
        depth_m=depth,
        motion_direction=direction,
        stiffness_n_per_m=k,
        stiffness_sd=k_sd,
        mass_kg=m,
        mass_sd=m_sd,
        pixel_count=int(full_mask.sum()),
        bbox_px=_bbox(full_mask),
        harmonics_hz=list(peak.harmonics_hz),
        release_time_s=release_time,
        snr_db=fit.snr_db,
        null_reasons=null_reasons,
        amplitude_source=tracking,
        notes=notes,
        ringdown=ringdown,
        saturated_fraction=saturated,
        fitted_duration_s=float(buffers.times_s[n] - buffers.times_s[onset]),
        displacement_px=disp,
        model_displacement_px=model,
    )


__all__ = [
    "Analysis",
    "AnalysisConfig",
    "Excitation",
    "ObjectMeasurement",
    "QualityNote",
    "analyze",
]

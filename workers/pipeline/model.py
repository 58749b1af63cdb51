"""The measuring pipeline's inputs and outputs as dataclasses: how the object was excited, the analysis
options, and the result (objects, labels, spectra, quality notes).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.errors import ParameterError
from workers.pipeline.flow import FlowConfig
from workers.pipeline.modes import ObjectModeShapes
from workers.pipeline.peaks import Peak
from workers.pipeline.ringdown import Ringdown
from workers.pipeline.segmentation import SegmentationConfig

Method = Literal["default", "paper"]
#: progress(stage, fraction of the whole analysis in [0, 1])
Progress = Callable[[str, float], None]

#: The one progress schedule: each phase of an analysis, the stage it reports and the span of the whole
#: analysis it covers. A clip analysed in one flow pass runs ``flow``; the two-pass front end runs
#: ``look`` (the whole picture on a coarse grid), then ``fine`` (the region that moves). A second pass over
#: a longer window lays the schedule again over what is left (``analysis._Onwards``): progress never goes
#: back.
PROGRESS_SCHEDULE: dict[str, tuple[str, float, float]] = {
    "survey": ("survey", 0.0, 0.05),
    "flow": ("flow", 0.05, 0.80),
    "look": ("flow", 0.05, 0.50),
    "fine": ("flow", 0.50, 0.80),
    "spectrum": ("spectrum", 0.82, 0.88),
    "segmentation": ("segmentation", 0.88, 0.93),
    "mechanics": ("mechanics", 0.93, 1.0),
}


def report_progress(progress: Progress | None, phase: str, done: float = 0.0) -> None:
    """Tell ``progress`` that ``phase`` (a key of :data:`PROGRESS_SCHEDULE`) is ``done`` (0 to 1) through."""
    if progress is None:
        return
    stage, start, end = PROGRESS_SCHEDULE[phase]
    progress(stage, start + (end - start) * min(max(done, 0.0), 1.0))


DEFAULT_MAX_FRAMES = 256
#: Memory budget of an automatically chosen window's buffers (flow maps, grey frames, depth, spectra).
DEFAULT_WINDOW_MIB = 384.0
#: The band's default upper edge, and the highest frequency any stage searches: this fraction of the
#: Nyquist rate (the default band is :func:`workers.pipeline.window.default_band`).
BAND_NYQUIST_FRACTION = 0.98


@dataclass(frozen=True, kw_only=True)
class Excitation:
    """How the object was excited.

    Attributes
    ----------
    kind : ``"step_release"``, ``"impulse"`` or ``"forced"``
        ``value`` is the held force F in N, the impulse J in N·s, or the RMS of a force that keeps acting in
        N (only from a force recording, whose samples it carries).
    value : float
    uncertainty : float
        Standard uncertainty of ``value``.
    object_id : int or None
        The object it applies to, by id.
    point_px : (x, y) or None
        ... or by a point on it (input pixels).
    box_px : (x, y, w, h) or None
        ... or by a box around it (input pixels). With none of the three: the main (strongest) object.
    release_time_s : float or None
        When it was let go (step_release) or struck (impulse), seconds on the clip's clock (0 = its first
        frame), when a force sensor recorded it: the fit's release instant, instead of one guessed from
        the motion.
    source : str
        Where it came from: ``request`` (typed), or the force recording (``topic /ft_sensor/wrench``,
        ``log force.csv``).
    notes : tuple of str
        What its reader should know (the direction used, a typed value overriding a recorded one).
    direction : (x, y, z) or None
        The recorded force's unit direction in the camera's optical frame, when a transform (``/tf``,
        ``/tf_static``) put it there: ``value`` is then the force along that direction, and the mechanics
        take its component along the object's motion
        (:func:`~workers.pipeline.mechanics.along_motion`). None: ``value`` is used as it is.
    force_times_s, force_along_n : ndarray, shape (M,), float64, or None
        A recorded excitation's samples: times on the clip's clock and the force along ``direction`` (or
        its dominant one), its baseline removed, newtons: a forced vibration's response is fitted to them
        (:mod:`workers.pipeline.response`), a release or a strike is weighed by them at the object's
        frequency (:func:`~workers.pipeline.mechanics.at_frequency`).
    event_s : (start, end) or None
        The span of those samples the release's drop or the strike's pulse takes, clip clock.
    """

    kind: Literal["step_release", "impulse", "forced"]
    value: float
    uncertainty: float = 0.0
    object_id: int | None = None
    point_px: tuple[float, float] | None = None
    box_px: tuple[float, float, float, float] | None = None
    release_time_s: float | None = None
    source: str = "request"
    notes: tuple[str, ...] = ()
    direction: tuple[float, float, float] | None = None
    force_times_s: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    force_along_n: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    event_s: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("step_release", "impulse", "forced"):
            raise ParameterError(f"excitation type {self.kind!r} is unknown; use step_release or impulse")
        if self.kind == "forced" and (self.force_times_s is None or self.force_along_n is None):
            raise ParameterError(
                "a forced excitation carries the force's samples (force_times_s, force_along_n)"
            )
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
class RejectedPeak:
    """A spectral peak that is not an object, and the evidence why.

    Attributes
    ----------
    frequency_hz : float
    reason : str
        What was seen, in a sentence.
    evidence : str
        ``camera_motion``, ``illumination_flicker``, ``codec_keyframes``, ``harmonic`` (of an object
        already reported, possibly folded back below the Nyquist rate), ``same_pixels`` (another motion of
        a reported object's pixels, not its harmonic: a higher mode), ``incoherent``,
        ``not_significant`` (noise alone gives as high a peak too often), ``uncertain`` (frequency
        uncertainty a quarter of the frequency or more) or ``out_of_band``.
    figures : dict of str to float
        The numbers behind the verdict (the keyframe comb's period and the peak's distance from it, the
        false-alarm probability, ...), named with their units.
    """

    frequency_hz: float
    reason: str
    evidence: str = "not_significant"
    figures: dict[str, float] = field(default_factory=dict)


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
    eigenfrequency_uncertainty_hz: float | None
    natural_frequency_hz: float
    damping_ratio: float | None
    damping_ratio_uncertainty: float | None
    amplitude_px: float | None
    amplitude_m: float | None
    amplitude_uncertainty_m: float | None
    depth_m: float | None
    motion_direction: tuple[float, float, float] | None
    stiffness_n_per_m: float | None
    stiffness_uncertainty_n_per_m: float | None
    mass_kg: float | None
    mass_uncertainty_kg: float | None
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
    #: Fraction of the object's pixels whose grey level is at the sensor's limits, first frame.
    saturated_fraction: float = 0.0
    #: Seconds of motion after release that were fitted.
    fitted_duration_s: float = 0.0
    #: Displacement of the object along its axis, input pixels, per frame of the window (for plots).
    displacement_px: NDArray[np.float64] | None = None
    #: Fitted model displacement at the same frames (NaN before release), input pixels.
    model_displacement_px: NDArray[np.float64] | None = None
    #: ``ring_down`` (decays in the window: damping measured), ``steady`` (sustained or forced: no decay
    #: in the window, damping null), ``growing`` or ``beating`` (two close, unresolved frequencies).
    #: The object's modes and their shapes (None when its window was too short to seek them).
    modes: ObjectModeShapes | None = None
    #: The excitation its stiffness and mass were measured with (None: not excited, or not known).
    excitation: Excitation | None = None
    regime: str = "ring_down"
    #: Unit vector of the motion's axis in the image (x right, y down), when measured.
    axis_px: tuple[float, float] | None = None
    #: The oscillation's energy over the noise's variance, dB (see RingdownFit.detection_db).
    detection_db: float | None = None
    #: Fraction of the motion's energy near its frequency that one oscillation explains.
    concentration: float | None = None
    #: Power of a second, independent motion in the object's region near its frequency, relative to the
    #: first (0: one motion): two oscillations closer than the window resolves.
    second_motion: float = 0.0
    #: Probability per clip that noise alone gives a peak as high as the object's, anywhere in the band
    #: (:mod:`workers.pipeline.significance`).
    false_alarm_probability: float | None = None
    #: The object's standardised height in the scan statistic (see the same module).
    detection_z: float | None = None

    @property
    def angular_frequency_rad_s(self) -> float:
        return 2 * math.pi * self.natural_frequency_hz


@dataclass(frozen=True)
class Survey:
    """What :func:`~workers.pipeline.survey.survey_motion` saw in a whole clip.

    Attributes
    ----------
    fps : float
        Frame rate of the surveyed frames, Hz.
    first_frame : int
        Clip index of the first surveyed frame.
    frames : int
        Frames surveyed (flow maps + 1).
    grid_shape : (h, w)
        Survey grid; ``grid_scale`` survey pixels per input pixel.
    grid_scale : float
    segment_frames : int
        Welch segment length, flow samples (hop: half of it).
    frequencies_hz : ndarray of float64, shape (F,)
    power : ndarray of float64, shape (F,)
        Welch average of the summed per-pixel power (survey pixels² / frame²).
    whitened : ndarray of float64, shape (F,)
        Welch average of the per-pixel power over each pixel's median power in the band, summed.
    median_snr : ndarray of float64, shape (F,)
        Welch average of the median pixel's whitened power: about 1 for noise, high for a frequency seen
        all over the picture.
    segments : int
        Welch segments averaged.
    segment_starts : ndarray of int64, shape (S,)
        Clip index of the first frame of each stored segment (each covers ``segment_span`` frames).
    segment_span : int
    segment_power : ndarray of float32, shape (S, F)
        Summed per-pixel power of each stored segment (merged segments are added).
    block_frames : int
        Frames per entry of ``block_energy``.
    block_energy : ndarray of float64, shape (B,)
        Mean squared motion per frame, input px², of block b, which starts at clip frame
        ``first_frame + b * block_frames``.
    max_step_px : float
        Per-frame motion of the fastest moving pixels (99th percentile over the pixels), input pixels, in
        the frames where it is largest (90th percentile over the frames, robust to a few glitches).
    peaks : list of Peak
        Confident peaks, strongest first, harmonics folded in (``snr_db`` over the whitened floor).
    global_peaks_hz : list of float
        The peaks (among ``peaks``) that are seen over the whole picture.
    flicker_hz : list of float
        The peaks (among ``peaks``) at which the picture's brightness oscillates: lighting flicker.
    local_lines_hz : list of float
        Lines of the local spectrum (motion on a small share of the pixels: a small object, a mode of a
        larger one), which the summed spectra may hide; the window's stride keeps them.
    """

    fps: float
    first_frame: int
    frames: int
    grid_shape: tuple[int, int]
    grid_scale: float
    segment_frames: int
    frequencies_hz: NDArray[np.float64]
    power: NDArray[np.float64]
    whitened: NDArray[np.float64]
    median_snr: NDArray[np.float64]
    segments: int
    segment_starts: NDArray[np.int64]
    segment_span: int
    segment_power: NDArray[np.float32]
    block_frames: int
    block_energy: NDArray[np.float64]
    max_step_px: float
    peaks: list[Peak]
    global_peaks_hz: list[float]
    flicker_hz: list[float] = field(default_factory=list)
    local_lines_hz: list[float] = field(default_factory=list)

    @property
    def bin_hz(self) -> float:
        """Width of one Welch bin, Hz."""
        return self.fps / self.segment_frames

    @property
    def object_peaks(self) -> list[Peak]:
        """Confident peaks that are not seen over the whole picture, strongest first."""
        return [p for p in self.peaks if p.frequency_hz not in self.global_peaks_hz]

    def band_energy(self, frequency_hz: float, *, half_width_bins: float = 1.5) -> NDArray[np.float64]:
        """Power of each stored segment near ``frequency_hz`` (within ``half_width_bins``).

        Returns
        -------
        ndarray of float64, shape (S,)
        """
        sel = np.abs(self.frequencies_hz - frequency_hz) <= half_width_bins * self.bin_hz
        if not sel.any():
            sel[int(np.argmin(np.abs(self.frequencies_hz - frequency_hz)))] = True
        return np.asarray(self.segment_power[:, sel].sum(axis=1), np.float64)

    def decay_at(self, frequency_hz: float, *, isolation_bins: float = 3.0) -> tuple[float, float] | None:
        """The envelope's decay rate at ``frequency_hz`` over the whole clip, from the stored segments'
        energy after its strongest one: (σ, its standard uncertainty), 1/s; None when fewer than three
        segments follow it, or another peak lies within ``isolation_bins`` (their energies would mix).
        """
        if any(
            self.bin_hz < abs(p.frequency_hz - frequency_hz) <= isolation_bins * self.bin_hz
            for p in self.peaks
        ):
            return None
        energy = self.band_energy(frequency_hz)
        first = int(np.argmax(energy))
        energy = energy[first:]
        if energy.size < 3 or not np.all(energy > 0):
            return None
        t = (self.segment_starts[first:] + self.segment_span / 2) / self.fps
        design = np.stack([np.ones_like(t, dtype=np.float64), t.astype(np.float64)], axis=1)
        coef, *_ = np.linalg.lstsq(design, np.log(energy), rcond=None)
        res = np.log(energy) - design @ coef
        dof = max(len(t) - 2, 1)
        cov = np.linalg.inv(design.T @ design) * float(res @ res) / dof
        # Energy falls as exp(-2 sigma t).
        return -float(coef[1]) / 2, math.sqrt(max(float(cov[1, 1]), 0.0)) / 2

    def explains(self, frequency_hz: float, *, tolerance: float = 0.02) -> bool:
        """Whether ``frequency_hz`` is one of the survey's peaks, or a harmonic of one, within
        ``tolerance`` (relative) or one and a half Welch bins, whichever is wider."""
        slack = max(tolerance * frequency_hz, 1.5 * self.bin_hz)
        for peak in self.peaks:
            for f in (peak.frequency_hz, *peak.harmonics_hz):
                if abs(f - frequency_hz) <= slack:
                    return True
        return False


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
    #: The detection statistic's calibration on this clip: ``location`` and ``scale`` of the Gumbel law of
    #: log T, ``bins_fitted`` and ``bins_searched``, and the bound on the false-alarm probability.
    detection: dict[str, float] = field(default_factory=dict)

    @property
    def eigenfrequency_hz(self) -> float | None:
        return self.objects[0].eigenfrequency_hz if self.objects else None

    @property
    def sample_rate_hz(self) -> float:
        """Rate of the analysed samples (flow maps, spectra, displacement), Hz."""
        return self.fps / self.frame_step


def finite_or_none(x: float | None) -> float | None:
    """``x`` as a float, or None when it is None, NaN or infinite (a figure that was not measured).

    Parameters
    ----------
    x : float or None

    Returns
    -------
    float or None
    """
    return float(x) if x is not None and math.isfinite(x) else None


class Stopwatch:
    """Seconds per stage of an analysis (``Analysis.timings_s``), each lap adding to its stage."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.times[name] = self.times.get(name, 0.0) + now - self._t
        self._t = now

    def stream_lap(self, decode_s: float) -> None:
        """The lap of a pass over the frames, as ``decode`` (``decode_s``, the reader's share) and ``flow``
        (the rest), each adding to its stage."""
        now = time.perf_counter()
        self.times["decode"] = self.times.get("decode", 0.0) + decode_s
        self.times["flow"] = self.times.get("flow", 0.0) + max(0.0, now - self._t - decode_s)
        self._t = now

    def add(self, other: dict[str, float]) -> None:
        """Add another pass's stages (an earlier pass over the same clip) to these."""
        for name, seconds in other.items():
            self.times[name] = self.times.get(name, 0.0) + seconds


__all__ = [
    "DEFAULT_MAX_FRAMES",
    "DEFAULT_WINDOW_MIB",
    "Analysis",
    "AnalysisConfig",
    "Excitation",
    "Method",
    "ObjectMeasurement",
    "Progress",
    "QualityNote",
    "RejectedPeak",
    "Stopwatch",
    "Survey",
    "finite_or_none",
]

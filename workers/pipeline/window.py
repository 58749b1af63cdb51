"""Which frames to analyse: the window the user gave, or for a long clip the one a survey of the whole clip
chooses (start, length and frame step; :func:`plan_window`), the flow grid, and the frequency band searched.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import MIN_FRAMES, ClipInfo, ClipReader, ClosingReader, Frame
from workers.pipeline.errors import ParameterError
from workers.pipeline.flow import FlowConfig
from workers.pipeline.look import CoarseGrid
from workers.pipeline.model import (
    BAND_NYQUIST_FRACTION,
    DEFAULT_MAX_FRAMES,
    AnalysisConfig,
    ObjectMeasurement,
    Progress,
    QualityNote,
    Survey,
    report_progress,
)
from workers.pipeline.peaks import Peak
from workers.pipeline.survey import survey_motion

#: The band's default lower edge: this many periods of the window (nothing slower is an oscillation of it).
BAND_MIN_PERIODS = 2.0
#: A band holds at least this many of the window's frequencies (so that its noise can be measured).
MIN_BAND_BINS = 16


def band_asked(config: AnalysisConfig) -> tuple[float, float]:
    """The band the user asked for before a window is chosen: 0 and infinity where they gave no edge
    (the window's length sets the lower edge, its sample rate the upper, :func:`analysis_band`)."""
    lo = config.min_frequency_hz if config.min_frequency_hz is not None else 0.0
    hi = config.max_frequency_hz if config.max_frequency_hz is not None else math.inf
    return lo, hi


def frames_for_band(config: AnalysisConfig, fps: float) -> int:
    """Frames a window needs for the band the user asked for to hold :data:`MIN_BAND_BINS` frequencies
    (its lines are 1 / duration apart, whatever the frame step); 0 without a narrowed band."""
    lo, hi = band_asked(config)
    hi = min(hi, BAND_NYQUIST_FRACTION * fps / 2)
    if (config.min_frequency_hz is None and config.max_frequency_hz is None) or hi <= lo:
        return 0
    return math.ceil(MIN_BAND_BINS * fps / (hi - lo)) + 1


@dataclass(frozen=True)
class Plan:
    """What :func:`plan_analysis` decided: frame rates, window, flow settings and the survey behind them."""

    sample_rate_hz: float  # rate of the analysed samples: the clip's rate / step
    fps: float  # the clip's frame rate
    start: int  # clip frames [start, stop), every step-th
    stop: int
    step: int
    flow: FlowConfig
    grid: tuple[int, int]
    pixel_scale: float  # input pixels per grid pixel
    survey: Survey | None = None
    window: WindowPlan | None = None
    decodable_frames: int = 0  # frames of the clip that decode (the survey counts them)

    def source(self, reader: ClipReader) -> tuple[ClipReader, int, int]:
        """The reader and frame range to stream: every ``step``-th frame of the window."""
        if self.step == 1:
            return reader, self.start, self.stop
        strided = StridedReader(reader, start=self.start, stop=self.stop, step=self.step)
        return strided, 0, strided.info.frames


class StridedReader(ClosingReader):
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

    def _span(self, start: int, stop: int | None) -> tuple[int, int]:
        """The wrapped reader's frame range [first, last) holding frames ``start <= k < stop`` of this one."""
        stop = self._info.frames if stop is None else min(stop, self._info.frames)
        return self._start + start * self._step, self._start + (stop - 1) * self._step + 1

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        for i, frame in enumerate(self._reader.frames(*self._span(start, stop))):
            if i % self._step == 0:
                yield dataclasses.replace(frame, index=start + i // self._step)

    def gray_frames(self, start: int = 0, stop: int | None = None) -> Iterator[NDArray[np.uint8]]:
        """Every ``step``-th grey frame, through the wrapped reader's own fast path."""
        for i, gray in enumerate(self._reader.gray_frames(*self._span(start, stop))):
            if i % self._step == 0:
                yield gray

    def frames_with_depth_on(
        self, shape: tuple[int, int], start: int = 0, stop: int | None = None
    ) -> Iterator[Frame]:
        """Every ``step``-th frame with depth on ``shape``, through the wrapped reader's own fast path."""
        for i, frame in enumerate(self._reader.frames_with_depth_on(shape, *self._span(start, stop))):
            if i % self._step == 0:
                yield dataclasses.replace(frame, index=start + i // self._step)

    def close(self) -> None:
        """The wrapped reader is its owner's to close."""


def plan_analysis(
    info: ClipInfo,
    config: AnalysisConfig,
    *,
    reader: ClipReader | None = None,
    progress: Progress | None = None,
    survey: Survey | None = None,
    min_duration_s: float | None = None,
) -> Plan:
    """Frame rate, window [start, stop) and step, flow settings, flow grid and input pixels per grid pixel.

    With a ``reader``, a clip longer than the default window whose window the user did not fix is
    surveyed first (unless a ``survey`` of it is given) and the window chosen from what moves where
    (see :mod:`workers.pipeline.survey`), at least ``min_duration_s`` long when given.
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
    band = band_asked(config)
    if not surveyed:
        start, stop = fixed_window(info.frames, config, needed=frames_for_band(config, fps))
        return Plan(fps, fps, start, stop, 1, flow_cfg, grid, pixel_scale, decodable_frames=info.frames)
    assert reader is not None
    if survey is None:
        grays = survey_grays(reader, progress)
        survey = survey_motion(grays, fps=fps, total_frames=info.frames, band_hz=band)
    # A damaged file decodes fewer frames than it lists: plan within those.
    decodable = min(info.frames, survey.first_frame + survey.frames)
    # Bytes per flow map that grow with the window: the look's flow on its coarse grid (2 x float32), the
    # half-precision copy of it the front keeps, and the scan's pooled levels. (The window's frames wait
    # in a temporary file, and the second pass's flow, grey frames and spectra have budgets of their
    # own: workers.pipeline.fine.)
    look_h, look_w = CoarseGrid.for_frame(info.height, info.width).shape
    per_sample = look_h * look_w * BYTES_PER_LOOK_PIXEL
    budget = int(config.max_window_mib * 2**20 / per_sample)
    needed = frames_for_band(config, fps)
    if needed:
        min_duration_s = max(min_duration_s or 0.0, (needed - 1) / fps)
    window = plan_window(
        survey,
        total_frames=decodable,
        default_frames=DEFAULT_MAX_FRAMES,
        max_samples=max(budget, DEFAULT_MAX_FRAMES),
        grid_scale=1.0 / pixel_scale,
        band_hz=band,
        min_duration_s=min_duration_s,
    )
    start, stop, step = window.start_frame, window.stop_frame, window.frame_step
    return Plan(
        fps / step,
        fps,
        start,
        stop,
        step,
        flow_cfg,
        grid,
        pixel_scale,
        survey,
        window,
        decodable_frames=decodable,
    )


def survey_grays(reader: ClipReader, progress: Progress | None) -> Iterator[NDArray[np.uint8]]:
    """Every frame of the clip in grey at input resolution (the reader's fast path when it has one)."""

    total = max(reader.info.frames, 1)
    for i, gray in enumerate(reader.gray_frames()):
        if i % 64 == 0:
            report_progress(progress, "survey", i / total)
        yield gray


def fixed_window(total: int, config: AnalysisConfig, *, needed: int = 0) -> tuple[int, int]:
    """The window the user gave (or the first ``DEFAULT_MAX_FRAMES`` frames, more when the band needs
    ``needed`` frames and the clip has them).

    Raises
    ------
    ParameterError
        When the window leaves too few frames, or the user's window cannot resolve the band they asked for.
    """
    start = config.start_frame or 0
    if start >= total - 2:
        raise ParameterError(f"start_frame={start} leaves fewer than 3 of the clip's {total} frames")
    default = max(DEFAULT_MAX_FRAMES, needed)
    length = config.frames if config.frames is not None else min(total - start, default)
    if length < MIN_FRAMES:
        raise ParameterError(f"frames={length}: the analysis window needs at least {MIN_FRAMES} frames")
    stop = min(total, start + length)
    if stop - start < MIN_FRAMES:
        raise ParameterError(
            f"only {stop - start} frames from start_frame={start}; need at least {MIN_FRAMES}"
        )
    if config.frames is not None and needed > stop - start:
        raise ParameterError(
            f"frames={config.frames}: the frequency band asked for needs at least {needed} frames to hold "
            f"{MIN_BAND_BINS} of the window's frequencies; give more frames or widen the band"
        )
    return start, stop


def default_band(sample_rate_hz: float, n: int) -> tuple[float, float]:
    """The band a window of ``n`` flow maps at ``fps`` can show: from :data:`BAND_MIN_PERIODS` periods of
    the window up to :data:`BAND_NYQUIST_FRACTION` of the Nyquist rate."""
    return BAND_MIN_PERIODS * sample_rate_hz / n, BAND_NYQUIST_FRACTION * sample_rate_hz / 2


def band_edges(
    min_frequency_hz: float | None, max_frequency_hz: float | None, sample_rate_hz: float, n: int
) -> tuple[float, float]:
    """The edges the user gave, :func:`default_band`'s where they gave none, the upper one at most the
    Nyquist rate (unchecked: :func:`analysis_band` refuses an empty band)."""
    default_lo, default_hi = default_band(sample_rate_hz, n)
    lo = min_frequency_hz if min_frequency_hz is not None else default_lo
    hi = max_frequency_hz if max_frequency_hz is not None else default_hi
    return lo, min(hi, sample_rate_hz / 2)


def analysis_band(config: AnalysisConfig, sample_rate_hz: float, n: int) -> tuple[float, float]:
    """The band searched in a window of ``n`` flow maps at ``fps``: the user's, or from
    :data:`BAND_MIN_PERIODS` periods of the window up to :data:`BAND_NYQUIST_FRACTION` of the Nyquist
    rate (the one owner of the default band).

    Raises
    ------
    ParameterError
        When the band is empty at this rate and length.
    """
    lo, hi = band_edges(config.min_frequency_hz, config.max_frequency_hz, sample_rate_hz, n)
    if lo >= hi:
        raise ParameterError(
            f"frequency band [{lo:.3g}, {hi:.3g}] Hz is empty at {sample_rate_hz:g} fps with {n} flow "
            "samples; widen the band or analyse more frames"
        )
    return lo, hi


def survey_notes(plan: Plan, objects: list[ObjectMeasurement]) -> list[QualityNote]:
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


@dataclass(frozen=True)
class WindowPlan:
    """The main analysis window chosen by :func:`plan_window`.

    Attributes
    ----------
    start_frame, stop_frame : int
        Clip frames [start, stop) analysed.
    frame_step : int
        Every ``frame_step``-th frame of the window is analysed (1: all).
    reference_hz : float or None
        Frequency whose periods set the length (the lowest confident one); None when nothing stood out.
    periods : float
        Periods of ``reference_hz`` the window spans.
    reason : str
        One sentence for the result's quality notes.
    """

    start_frame: int
    stop_frame: int
    frame_step: int
    reference_hz: float | None
    periods: float
    reason: str

    @property
    def samples(self) -> int:
        """Flow maps the window gives."""
        return (self.stop_frame - self.start_frame - 1) // self.frame_step


@dataclass(frozen=True)
class WindowRules:
    """How :func:`plan_window` sizes a window (the defaults are the analysis's).

    Attributes
    ----------
    min_periods : float
        The window spans at least this many periods of the lowest confident frequency.
    max_step_grid_px : float
        Most motion between two analysed frames, flow-grid pixels (bounds the stride).
    samples_per_period : float
        Fewest analysed frames per period of any frequency seen (bounds the stride).
    resolve_lines : float
        Lines resolved between two close peaks.
    end_energy : float
        A motion ends where its energy falls below this share of its peak ...
    lasting_energy : float
        ... and is followed that far when it is still this strong where the default window would end.
    """

    min_periods: float = 10.0
    max_step_grid_px: float = 6.0
    samples_per_period: float = 4.0
    resolve_lines: float = 4.0
    end_energy: float = 0.02
    lasting_energy: float = 0.5


def plan_window(
    survey: Survey,
    *,
    total_frames: int,
    default_frames: int,
    max_samples: int,
    grid_scale: float,
    band_hz: tuple[float, float] | None = None,
    min_duration_s: float | None = None,
    rules: WindowRules = WindowRules(),
) -> WindowPlan:
    """Choose the main analysis window from a survey of the whole clip.

    The window starts where the strongest ring-down of the strongest object frequency begins and lasts
    as long as the scene needs: at least ``rules.min_periods`` periods of the lowest confident frequency
    and ``default_frames`` frames when the clip has them; as long as the motion lasts when it is still
    ``rules.lasting_energy`` as strong (in energy) where that window would end (until it falls below
    ``rules.end_energy`` of its peak: a steady vibration lasts to the end of the clip), at most
    :data:`LASTING_PERIODS` periods; and long enough to resolve close frequencies (``rules.resolve_lines``
    lines between two peaks closer than a few survey bins, or within a peak wider than a line). When
    that needs more than ``default_frames`` flow maps, every k-th frame is analysed (:func:`_frame_step`);
    the window never gives more than ``max_samples`` flow maps.

    Parameters
    ----------
    survey : Survey
    total_frames, default_frames : int
        Frames in the clip (that decode); the window's length when nothing asks for more.
    max_samples : int
        Most flow maps the main analysis may hold (its memory budget).
    grid_scale : float
        Main flow grid pixels per input pixel.
    band_hz : (low, high), optional
        Only peaks in this band shape the window (the analysis searches no other).
    min_duration_s : float, optional
        The window spans at least this long (a second pass that separates close frequencies).
    rules : WindowRules, optional

    Returns
    -------
    WindowPlan
    """
    if max_samples < 8 or default_frames < 9:
        raise ParameterError(
            f"plan_window: max_samples={max_samples} and default_frames={default_frames} are too small; "
            "allow at least 8 flow maps"
        )
    lo, hi = band_hz if band_hz is not None else (0.0, math.inf)
    seen = [p for p in survey.peaks if lo <= p.frequency_hz <= hi and p.frequency_hz not in survey.flicker_hz]
    objects = [p for p in seen if p.frequency_hz not in survey.global_peaks_hz]
    if not seen and min_duration_s is None:
        return _first_frames(total_frames, default_frames)
    main = (objects or seen)[0] if seen else None
    lowest = min((p.frequency_hz for p in seen), default=None)
    onset = _onset_frame(survey, main.frequency_hz) if main is not None else survey.first_frame
    length, why = _window_length(
        survey, seen, onset=onset, first_guess=min(default_frames, total_frames), rules=rules
    )
    if min_duration_s is not None and math.ceil(min_duration_s * survey.fps) + 1 > length:
        length = math.ceil(min_duration_s * survey.fps) + 1
        why += f"; {min_duration_s:.3g} s asked for"
    step = _frame_step(
        survey, length, default_frames=default_frames, grid_scale=grid_scale, top_hz=hi, rules=rules
    )
    length = min(length, step * max_samples + 1, total_frames)
    start, stop = _placed(onset, length, step, total_frames)
    periods = (lowest or 0.0) * (stop - start - 1) / survey.fps
    every = "" if step == 1 else f" (one frame in {step})"
    reason = f"frames {start}-{stop}{every} of {total_frames}{why}"
    if main is not None and lowest is not None:
        reason = (
            f"a survey of all {total_frames} frames found motion at {main.frequency_hz:.3g} Hz starting "
            f"near frame {onset}; frames {start}-{stop}{every} span {periods:.1f} periods of "
            f"{lowest:.3g} Hz{why}"
        )
    return WindowPlan(start, stop, step, lowest, periods, reason)


def _first_frames(total_frames: int, default_frames: int) -> WindowPlan:
    """The default window from the clip's start, when the survey saw nothing to follow."""
    stop = min(total_frames, default_frames)
    reason = (
        f"nothing stood out in a survey of all {total_frames} frames: the first {stop} were analysed; "
        "give start_frame and frames to choose the window"
    )
    return WindowPlan(
        start_frame=0, stop_frame=stop, frame_step=1, reference_hz=None, periods=0.0, reason=reason
    )


def _window_length(
    survey: Survey, seen: list[Peak], *, onset: int, first_guess: int, rules: WindowRules
) -> tuple[int, str]:
    """Frames the window needs for the peaks ``seen`` (at least ``first_guess``), and why, as the tail of
    a sentence: enough periods of the lowest, close frequencies resolved, a lasting motion followed."""
    fps = survey.fps
    length, why = first_guess, ""
    lowest = min((p.frequency_hz for p in seen), default=None)
    if lowest is not None:
        length = max(length, math.ceil(rules.min_periods * fps / lowest) + 1)
    resolve_s = _resolution_needed(survey, seen, lines=rules.resolve_lines)
    if resolve_s > 0 and math.ceil(resolve_s * fps) + 1 > length:
        length = math.ceil(resolve_s * fps) + 1
        why = f"; {resolve_s:.3g} s resolve frequencies {rules.resolve_lines / resolve_s:.3g} Hz apart"
    frequencies = [p.frequency_hz for p in seen]
    if seen and _energy_at(survey, frequencies, onset + length) >= rules.lasting_energy:
        # Still strong where the window would end (a steady vibration, a lightly damped fork): follow
        # the motion while it lasts ...
        lasting = _motion_end(survey, frequencies, onset, level=rules.end_energy) - onset
        # ... until the window holds LASTING_PERIODS periods of the slowest motion: more costs its time
        # for a precision no one needs (a lightly damped 128 Hz fork rings for 1500 frames at 500 fps)
        lasting = min(lasting, math.ceil(LASTING_PERIODS * fps / lowest) + 1) if lowest else lasting
        if lasting > length:
            length = lasting
            why += "; the motion lasts that long"
    return length, why


def _frame_step(
    survey: Survey, length: int, *, default_frames: int, grid_scale: float, top_hz: float, rules: WindowRules
) -> int:
    """Frames skipped between analysed frames: as few as keep a window of ``length`` frames near the
    default size, provided each frequency seen keeps at least ``rules.samples_per_period`` samples per
    period (its strong harmonics stay below the Nyquist rate; lighting flicker may fold back, it is
    rejected anyway), the motion between analysed frames stays below ``rules.max_step_grid_px``, the
    band's top (``top_hz``) stays below the Nyquist rate of the analysed frames, and so does every local
    line below it (``survey.local_lines_hz``, :data:`LINE_SAMPLES` samples per period)."""
    step = max(1, math.ceil((length - 1) / max(default_frames - 1, 1)))
    step_max_rate = _max_step_for_rate(survey, samples_per_period=rules.samples_per_period)
    per_frame_grid_px = survey.max_step_px * grid_scale
    step_max_motion = max(1, math.floor(rules.max_step_grid_px / max(per_frame_grid_px, 1e-9)))
    # Striding never folds the band's top away.
    step_max_band = (
        max(1, math.floor(BAND_NYQUIST_FRACTION * survey.fps / (2 * top_hz)))
        if math.isfinite(top_hz)
        else 1 << 30
    )
    # ... nor a line on a few pixels that the summed spectra hide (an object's faster mode).
    lines = [f for f in survey.local_lines_hz if f <= top_hz]
    step_max_lines = max(1, math.floor(survey.fps / (LINE_SAMPLES * max(lines)))) if lines else 1 << 30
    return max(1, min(step, step_max_rate, step_max_motion, step_max_band, step_max_lines))


def _placed(onset: int, length: int, step: int, total_frames: int) -> tuple[int, int]:
    """[start, stop) of a window of ``length`` frames from ``onset``, inside the clip, in whole steps."""
    start = max(0, onset)
    stop = min(total_frames, start + length)
    if stop - start < min(length, total_frames):
        start = max(0, stop - length)  # late ring-down: take the frames before it rather than fewer
    # Whole steps: round the window up to the next analysed frame when the clip has it, else down.
    intervals = math.ceil((stop - start - 1) / step)
    if start + intervals * step + 1 > total_frames:
        intervals = (stop - start - 1) // step
    return start, start + intervals * step + 1


def _resolution_needed(survey: Survey, peaks: list[Peak], *, lines: float, near_bins: float = 6.0) -> float:
    """Seconds of window that resolve ``lines`` lines between any two peaks closer than ``near_bins``
    survey bins, or within a peak wider than its decay explains: a Hann window's tone is 1.44 bins wide
    at half power, a decay at rate σ widens it by about σ / π Hz; one half as wide again may be two tones
    about half its width apart. (A peak whose decay cannot be measured, being too short or too late in
    the clip, asks for nothing.)"""
    bin_hz = survey.bin_hz
    needed = 0.0
    for i, a in enumerate(peaks):
        for b in peaks[i + 1 :]:
            gap = abs(a.frequency_hz - b.frequency_hz)
            if 0 < gap < near_bins * bin_hz:
                needed = max(needed, lines / gap)
        if a.width_bins > 1.0:
            decay = survey.decay_at(a.frequency_hz)
            if decay is None:
                continue
            explained = 1.44 * bin_hz + max(decay[0], 0.0) / math.pi
            if 2 * a.width_bins * bin_hz > 1.5 * explained:
                needed = max(needed, lines / (a.width_bins * bin_hz))
    return needed


def _energy_at(survey: Survey, frequencies_hz: list[float], frame: int) -> float:
    """How strong the motion still is at clip ``frame`` relative to its strongest: the lower of two
    readings, the stored segments' energy at ``frequencies_hz`` (coarse in time) and the motion energy
    of the blocks of frames (fine in time, all frequencies)."""
    energy = sum(survey.band_energy(f) for f in frequencies_hz)
    if not isinstance(energy, np.ndarray) or energy.size == 0 or float(energy.max()) <= 0:
        return 0.0
    i = int(np.searchsorted(survey.segment_starts + survey.segment_span // 2, frame))
    coarse = float(energy[min(i, len(energy) - 1)] / energy.max())
    blocks = survey.block_energy
    # The fine reading against the motion's typical strength (a few noisy blocks must not set the scale).
    typical = float(np.percentile(blocks, 90)) if blocks.size else 0.0
    if typical <= 0:
        return coarse
    b = min(len(blocks) - 1, max(0, (frame - survey.first_frame) // survey.block_frames))
    fine = float(blocks[b] / typical)
    return min(coarse, fine)


def _motion_end(survey: Survey, frequencies_hz: list[float], onset: int, *, level: float) -> int:
    """Clip frame where the motion at ``frequencies_hz`` has faded below ``level`` of its strongest after
    ``onset`` (the clip's end when it never does)."""
    energy = sum(survey.band_energy(f) for f in frequencies_hz)
    starts = survey.segment_starts
    end = survey.first_frame + survey.frames
    if not isinstance(energy, np.ndarray) or energy.size == 0:
        return end
    after = np.flatnonzero(starts + survey.segment_span > onset)
    if after.size == 0:
        return end
    peak_at = int(after[np.argmax(energy[after])])
    peak = float(energy[peak_at])
    for i in range(peak_at + 1, len(energy)):
        if energy[i] < level * peak:
            return int(min(end, starts[i] + survey.segment_span // 2))
    return end


def _max_step_for_rate(
    survey: Survey,
    *,
    samples_per_period: float,
    relative_power: float = 0.1,
    harmonic_samples: float = 2.5,
    minor_power: float = 0.05,
) -> int:
    """Largest frame step that keeps ``samples_per_period`` samples in each period of every confident
    peak carrying at least ``minor_power`` of the strongest one's power, and each harmonic carrying
    ``relative_power`` of its peak's power below the reduced Nyquist rate (``harmonic_samples`` per
    period; weaker overtones fold back as faint peaks, which the segmentation recognises as folded
    harmonics). Lighting flicker, and minor peaks far above the motion that matters, may fold back: the
    analysis recognises their images (see :func:`folded_image`)."""
    fps = survey.fps
    step = math.inf
    bins = survey.frequencies_hz
    strongest = max((float(survey.power[p.bin]) for p in survey.peaks), default=0.0)
    for peak in survey.peaks:
        if peak.frequency_hz in survey.flicker_hz or float(survey.power[peak.bin]) < minor_power * strongest:
            continue
        step = min(step, fps / (samples_per_period * peak.frequency_hz))
        base = float(survey.power[max(peak.bin - 1, 0) : peak.bin + 2].max())
        for f in peak.harmonics_hz:
            k = int(np.argmin(np.abs(bins - f)))
            if survey.power[max(k - 1, 0) : k + 2].max() >= relative_power * base:
                step = min(step, fps / (harmonic_samples * f))
    return max(1, math.floor(step)) if math.isfinite(step) else 1


#: Fewest analysed frames per period of a local line of the survey (a mode the window must keep; 2.5
#: keeps it below 0.8 of the Nyquist rate, inside the band the analysis searches).
LINE_SAMPLES = 2.5

#: Memory an automatically chosen window takes per flow map and pixel of the look's grid, bytes (its flow, 8;
#: the front's half-precision copy of the moving box, at most 4; the scan's levels, about 4).
BYTES_PER_LOOK_PIXEL = 16

#: A motion still strong where the default window would end is followed until the window holds this many
#: periods of its slowest frequency (a turning wheel's 3.2 periods in 0.87 s left its rate 2 % off).
LASTING_PERIODS = 30

#: A survey segment holding this share of the strongest segment's energy at a motion's frequency is part of
#: that motion's burst (see :func:`_onset_frame`).
STEADY_SHARE = 0.5


def _onset_frame(survey: Survey, frequency_hz: float) -> int:
    """Clip frame where the strongest burst of motion at ``frequency_hz`` starts (a few frames early)."""
    energy = survey.band_energy(frequency_hz)
    for harmonic in next((p.harmonics_hz for p in survey.peaks if p.frequency_hz == frequency_hz), []):
        energy = energy + survey.band_energy(harmonic)
    if energy.size == 0:
        return survey.first_frame
    strongest = int(np.argmax(energy))
    quiet = float(np.min(energy))
    # A segment belongs to the burst when it stands a tenth of the way from the quietest to the strongest,
    # or holds half the strongest's energy: a steady vibration's segments differ by their noise alone,
    # and the first of them, not the one its noise made strongest, is where it starts.
    threshold = min(quiet + 0.1 * (float(energy[strongest]) - quiet), STEADY_SHARE * float(energy[strongest]))
    first = strongest
    while first > 0 and energy[first - 1] >= threshold:
        first -= 1
    # The burst begins inside segment ``first`` (or before the clip when that is the first one): find
    # where the motion energy rises within it.
    seg_start = int(survey.segment_starts[first])
    seg_stop = seg_start + survey.segment_span
    blocks = survey.block_energy
    b0 = max(0, (seg_start - survey.first_frame) // survey.block_frames)
    b1 = min(len(blocks), (seg_stop - survey.first_frame) // survey.block_frames + 1)
    if b1 - b0 < 2:
        return seg_start
    inside = blocks[b0:b1]
    floor = float(np.percentile(blocks, 10))
    peak = float(inside.max())
    rising = np.flatnonzero(inside >= floor + 0.2 * (peak - floor))
    b = b0 + int(rising[0]) if rising.size else b0
    # Walk back over the ramp (a released object starts from rest): blocks still above the quiet level.
    while b > b0 and blocks[b - 1] > floor + 0.02 * (peak - floor):
        b -= 1
    margin = max(2, survey.block_frames)
    return max(survey.first_frame, survey.first_frame + b * survey.block_frames - margin)


__all__ = [
    "Plan",
    "StridedReader",
    "WindowPlan",
    "WindowRules",
    "analysis_band",
    "band_edges",
    "default_band",
    "fixed_window",
    "plan_analysis",
    "plan_window",
    "survey_grays",
    "survey_notes",
]

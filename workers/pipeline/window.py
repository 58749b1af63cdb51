"""Which frames to analyse: the window the user gave, or for a long clip the one a survey of the whole clip
chooses (start, length and frame step), the flow grid, and the frequency band searched.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from workers.pipeline.clipio.types import ClipInfo, ClipReader, ClosingReader, Frame
from workers.pipeline.errors import ParameterError
from workers.pipeline.flow import FlowConfig
from workers.pipeline.model import (
    DEFAULT_MAX_FRAMES,
    AnalysisConfig,
    ObjectMeasurement,
    Progress,
    QualityNote,
)
from workers.pipeline.survey import Survey, WindowPlan, plan_window, survey_motion


@dataclass(frozen=True)
class Plan:
    """What :func:`plan_analysis` decided: frame rates, window, flow settings and the survey behind them."""

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

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        stop = self._info.frames if stop is None else min(stop, self._info.frames)
        first = self._start + start * self._step
        last = self._start + (stop - 1) * self._step + 1
        for i, frame in enumerate(self._reader.frames(first, last)):
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
) -> Plan:
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
        start, stop = fixed_window(info.frames, config)
        return Plan(fps, fps, start, stop, 1, flow_cfg, grid, pixel_scale)
    assert reader is not None
    if survey is None:
        survey = survey_motion(survey_grays(reader, progress), fps=fps, total_frames=info.frames)
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
    return Plan(fps / step, fps, start, stop, step, flow_cfg, grid, pixel_scale, survey, window)


def survey_grays(reader: ClipReader, progress: Progress | None) -> Iterator[NDArray[np.uint8]]:
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


def fixed_window(total: int, config: AnalysisConfig) -> tuple[int, int]:
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


def analysis_band(config: AnalysisConfig, fps: float, n: int) -> tuple[float, float]:
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


__all__ = [
    "Plan",
    "StridedReader",
    "analysis_band",
    "fixed_window",
    "plan_analysis",
    "survey_grays",
    "survey_notes",
]

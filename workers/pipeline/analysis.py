"""The measuring pipeline wired together: clip -> window -> look -> candidates -> region -> fine flow ->
spectra -> segmentation -> objects measured and judged -> result. :func:`analyze` is the one entry point;
it takes a clip reader and dataclasses and returns an :class:`Analysis` dataclass (no files are written
here).

Where each decision lives: :mod:`~workers.pipeline.window` (which frames), :mod:`~workers.pipeline.look`
(the first pass: the whole picture on a coarse grid), :mod:`~workers.pipeline.significance` and
:mod:`~workers.pipeline.detection` (which frequencies stand out of the noise, and where),
:mod:`~workers.pipeline.fine` (the second pass: flow over the region that moves, at the resolution it
needs), :mod:`~workers.pipeline.regions` and :mod:`~workers.pipeline.segmentation` (which pixels),
:mod:`~workers.pipeline.verdicts` (which measured regions are objects),
:mod:`~workers.pipeline.artefacts` (the camera, the light, the codec), :mod:`~workers.pipeline.measure`
(each object's figures).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from workers.pipeline.artefacts import (
    Suspect,
    artefact_verdict,
    block_coverage,
    camera_intermodulation,
    light_images,
)
from workers.pipeline.clipio.types import ClipInfo, ClipReader
from workers.pipeline.confidence import Confidence, flow_confidence, tensor_sqrt
from workers.pipeline.detection import shared_region
from workers.pipeline.fine import crop_to_motion, plan_roi, stream_roi
from workers.pipeline.flow import needs_resampling, resample_uniform
from workers.pipeline.front import Front, coarse_region, coarse_share, front_of_buffers, front_of_look
from workers.pipeline.light import BRIGHTNESS_BLOCKS
from workers.pipeline.look import Look, frame_noise, look_at
from workers.pipeline.measure import Region, WindowContext, assign_excitations, bounding_box, measure_object
from workers.pipeline.model import (
    DEFAULT_MAX_FRAMES,
    DEFAULT_WINDOW_MIB,
    Analysis,
    AnalysisConfig,
    Excitation,
    ObjectMeasurement,
    Progress,
    QualityNote,
    RejectedPeak,
    Stopwatch,
    Survey,
    report_progress,
)
from workers.pipeline.peaks import Peak
from workers.pipeline.quality import (
    SECOND_MOTION,
    clip_notes,
    close_pairs,
    frame_notes,
    frame_rate_notes,
    object_quality_notes,
    resolution_notes,
)
from workers.pipeline.regions import Regions, segment_candidates
from workers.pipeline.roi import Roi
from workers.pipeline.segmentation import at_rest
from workers.pipeline.spectra import PixelSpectra, background_spectrum, pixel_spectra
from workers.pipeline.stream import FrameBuffers
from workers.pipeline.tracking import CoarseView
from workers.pipeline.verdicts import (
    MIN_PERIODS,
    Footing,
    clip_regime,
    drop_objects,
    folded_verdicts,
    judge_objects,
)
from workers.pipeline.window import Plan, analysis_band, plan_analysis, survey_notes


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
    onwards = None if progress is None else _Onwards(progress)
    result = _analyze_default(reader, config=config, excitations=excitations, progress=onwards)
    if not _needs_longer_window(result):
        return result
    if onwards is not None:
        onwards.next_pass()
    # Two oscillations share a region or stand closer than the window resolves, and the clip has more:
    # analyse as long a window as the memory budget allows (every k-th frame if need be).
    survey = result.window_survey
    assert survey is not None
    first = result.timings_s
    result = _analyze_default(
        reader,
        config=config,
        excitations=excitations,
        progress=onwards,
        survey=survey,
        min_duration_s=survey.frames / survey.fps,
    )
    result.timings_s = {
        k: first.get(k, 0.0) + result.timings_s.get(k, 0.0) for k in {*first, *result.timings_s}
    }
    result.quality.append(
        QualityNote(
            "longer_window",
            "two oscillations were closer than the first window resolves, so the clip was analysed "
            f"again over frames {result.frames_used[0]}-{result.frames_used[1]}",
            "info",
        )
    )
    return result


class _Onwards:
    """Progress that only goes forward across passes: a second pass's fractions are laid over what the
    first left (its 5 % is ahead of the first's 93 %), and no report goes back."""

    def __init__(self, progress: Progress) -> None:
        self._progress = progress
        self._base = 0.0
        self._last = 0.0

    def __call__(self, stage: str, fraction: float) -> None:
        value = self._base + (1.0 - self._base) * min(max(fraction, 0.0), 1.0)
        if value >= self._last:
            self._last = value
            self._progress(stage, value)

    def next_pass(self) -> None:
        self._base = self._last


def _needs_longer_window(result: Analysis) -> bool:
    """Whether a longer window of a surveyed clip may separate what this one mixed: a region holding two
    oscillations, or two objects closer than three lines; and the clip has frames to spare."""
    survey = result.window_survey
    if survey is None:
        return False
    first, last = result.frames_used
    if last - first >= survey.first_frame + survey.frames - 2:
        return False  # the window already spans the clip
    if any(o.second_motion >= SECOND_MOTION for o in result.objects):
        return True
    freqs = result.frequencies_hz
    return len(freqs) > 1 and bool(close_pairs(result.objects, bin_hz=float(freqs[1] - freqs[0])))


def _analyze_default(
    reader: ClipReader,
    *,
    config: AnalysisConfig,
    excitations: list[Excitation],
    progress: Progress | None,
    survey: Survey | None = None,
    min_duration_s: float | None = None,
) -> Analysis:
    """One pass of the default method: the window, the look at the whole picture, then the fine flow of
    the region that moves (none when nothing stands out) and what is measured there. ``survey``: a
    survey of this clip already made; ``min_duration_s``: the window spans at least this long."""
    watch = Stopwatch()
    info = reader.info
    plan = plan_analysis(
        info, config, reader=reader, progress=progress, survey=survey, min_duration_s=min_duration_s
    )
    watch.lap("survey" if plan.survey is not None else "setup")
    source, first, last = plan.source(reader)
    look = look_at(source, first, last, progress=progress)
    watch.stream_lap(look.decode_s)
    band = analysis_band(config, plan.sample_rate_hz, look.count)
    front = front_of_look(
        look,
        sample_rate_hz=plan.sample_rate_hz,
        band_hz=band,
        max_objects=config.max_objects,
        asserted=len(excitations),
    )
    watch.lap("spectrum")
    if not front.candidates.found:
        if look.kept is not None:
            look.kept.close()
        return _still(look_buffers(look), plan, info, front, config=config, watch=watch)
    roi = plan_roi(look, front.candidates.regions, frame_shape=(info.height, info.width), samples=look.count)
    front = front.keeping_flow_of(roi)
    # the front keeps the box's flow; the rest is not read again (an empty array, not a view that keeps it)
    look.flow = np.empty((look.count, 0, look.flow.shape[2], 2), np.float32)
    try:
        buffers = stream_roi(
            look if look.kept is not None else source,
            roi,
            start=first,
            stop=last,
            look=look,
            flow_config=plan.flow,
            progress=progress,
        )
    finally:
        if look.kept is not None:
            look.kept.close()  # the window's frames, kept in a temporary file
    watch.stream_lap(buffers.decode_s - look.decode_s)
    return analyze_window(
        buffers,
        plan,
        info,
        config=config,
        excitations=excitations,
        watch=watch,
        progress=progress,
        front=front,
    )


def look_buffers(look: Look) -> FrameBuffers:
    """The look's whole-picture series as frame buffers without flow (what a still clip's result shows)."""
    return FrameBuffers(
        flow=look.flow[:, :0],
        depth=None,
        gray=None,
        first_rgb=look.first_rgb,
        count=look.count,
        times_s=look.times_s,
        camera_px=look.camera_px,
        start_s=look.start_s,
        decode_s=look.decode_s,
        brightness=look.brightness,
        frame_change=look.frame_change,
        camera_removed=look.camera_removed,
        border_px=look.border_px,
        camera_still_fraction=look.camera_still_fraction,
        announced=look.announced,
    )


@dataclass(frozen=True)
class _Window:
    """The window being analysed: its buffers, which frames they are, the clip, the options, and the box
    of the frame their grid covers."""

    buffers: FrameBuffers
    plan: Plan
    info: ClipInfo
    config: AnalysisConfig
    box: Roi


@dataclass(frozen=True)
class _Spectra:
    """The window's per-pixel spectra on its grid, their sum over the pixels and the background's; and,
    when asked for, the spectra of the constrained flow (what the image shows of each pixel's motion: along
    an edge only its normal component), taken from ``flow``."""

    pixels: PixelSpectra
    summed: NDArray[np.float64]
    noise: NDArray[np.float64]
    confidence: Confidence
    flow: NDArray[np.float32] | None = None

    @functools.cached_property
    def constrained(self) -> PixelSpectra:
        """Spectra of J^(1/2) u: computed on first use, since only a candidate that the plain spectra do not
        segment needs them (a thin, plain object moving a fraction of a pixel); the plain spectra without
        a window's flow."""
        if self.flow is None:
            return self.pixels
        return pixel_spectra(
            self.flow, sample_rate_hz=self.pixels.sample_rate_hz, mix=tensor_sqrt(self.confidence)
        )


def window_confidence(buffers: FrameBuffers) -> Confidence:
    """The confidence of the window's flow: the structure tensor of its mean grey frame on the flow grid,
    against one frame's noise there (:mod:`workers.pipeline.confidence`)."""
    h, w = buffers.flow.shape[1:3]
    if buffers.gray is None:
        gray = cv2.cvtColor(buffers.first_rgb, cv2.COLOR_RGB2GRAY)
        box = buffers.box(gray.shape)
        return flow_confidence(box.on_grid(gray).astype(np.float32))
    sampled = buffers.gray[:: max(1, len(buffers.gray) // 32)]
    if sampled.shape[1:] == (h, w):
        frames = sampled.astype(np.float32)
    else:  # frame by frame: no float copy of 32 frames at input resolution (0.1 s at 640 x 480)
        frames = np.stack(
            [cv2.resize(f.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) for f in sampled]
        )
    # the median change between frames is a statistic of the pixels: every fourth one estimates it as
    # well (to 0.1 %), at a tenth of the cost (0.06 s of a live stream's final analysis at 320 x 240)
    change = np.abs(np.diff(frames[:, ::2, ::2], axis=0))
    return flow_confidence(frames.mean(axis=0), frame_noise=frame_noise(change[:, None, :, :]))


def _window_spectra(
    buffers: FrameBuffers, plan: Plan, info: ClipInfo, quality: list[QualityNote]
) -> _Spectra:
    """Per-pixel spectra of the window's flow (resampled onto a uniform grid when frames were dropped)."""
    confidence = window_confidence(buffers)
    flow = buffers.flow
    if needs_resampling(buffers.times_s, plan.sample_rate_hz):
        flow, _ = resample_uniform(flow, buffers.times_s, plan.sample_rate_hz)
        quality.append(
            QualityNote(
                "uneven_timing",
                f"frame times deviate from a uniform {plan.sample_rate_hz:g} fps grid "
                f"({info.dropped_frames} dropped frames): spectra were resampled and the ring-down "
                "was fitted at the true frame times",
                "info",
            )
        )
    flow = np.asarray(flow, np.float32)
    spectra = pixel_spectra(flow, sample_rate_hz=plan.sample_rate_hz)
    summed = spectra.power.sum(axis=1, dtype=np.float64)
    return _Spectra(spectra, summed, background_spectrum(spectra), confidence, flow)


def _measure(
    window: _Window,
    regions: Regions,
    spectra: _Spectra,
    front: Front,
    *,
    excitations: Sequence[Excitation],
) -> tuple[list[ObjectMeasurement], dict[int, Excitation]]:
    """Measure every segmented region."""
    buffers, plan, info, config, box = window.buffers, window.plan, window.info, window.config, window.box
    by_label = assign_excitations(list(excitations), regions.labels_full, len(regions.seg.peaks))
    context = WindowContext(
        buffers=buffers,
        sample_rate_hz=plan.sample_rate_hz,
        pixel_scale=box.pixel_scale,
        intrinsics=info.intrinsics,
        depth_override_m=config.depth_m,
        band_hz=plan_band(plan, config, buffers),
        confidence=spectra.confidence,
    )
    objects = [
        measure_object(
            Region(
                label=label,
                peak=peak,
                mask=regions.labels_grid == label,
                full_mask=regions.labels_full == label,
                excluded=tuple(e.reason for e in regions.exclusions if e.label == label),
                coarse=_coarse_view(front, regions, label),
            ),
            context,
            excitation=by_label.get(label),
        )
        for label, peak in enumerate(regions.seg.peaks, start=1)
    ]
    return objects, by_label


def _coarse_view(front: Front, regions: Regions, label: int) -> CoarseView:
    """Object ``label`` on the first pass's grid: where its candidate moved there and where its mask lies."""
    region = regions.candidates[label - 1].region | coarse_region(front, regions.labels_full == label)
    return front.coarse_view(region)


def _to_rest(objects: list[ObjectMeasurement], labels: NDArray[np.uint16]) -> None:
    """Without depth to tell the background from an object, its region holds the background it swept:
    each object's region becomes where it is at rest (:func:`~workers.pipeline.segmentation.at_rest`), in
    ``labels`` and in its pixel count and box."""
    for obj in objects:
        if obj.axis_px is None or obj.amplitude_px is None or not math.isfinite(obj.amplitude_px):
            continue
        region = labels == obj.id
        rest = at_rest(region, axis_px=obj.axis_px, amplitude_px=abs(obj.amplitude_px))
        labels[region & ~rest] = 0
        obj.pixel_count = int(rest.sum())
        obj.bbox_px = bounding_box(rest)


def plan_band(plan: Plan, config: AnalysisConfig, buffers: FrameBuffers) -> tuple[float, float]:
    """The analysis band of the window (see :func:`workers.pipeline.window.analysis_band`)."""
    return analysis_band(config, plan.sample_rate_hz, buffers.count)


def _artefacts(
    objects: list[ObjectMeasurement], regions: Regions, front: Front, *, sample_rate_hz: float
) -> dict[int, RejectedPeak]:
    """The objects (by id) that are artefacts of the light, the codec or the camera."""
    out: dict[int, RejectedPeak] = {}
    for obj in objects:
        cand = regions.candidates[obj.id - 1]
        own = coarse_region(front, regions.labels_full == obj.id)
        region_power, ring_power = front.band_powers(
            obj.eigenfrequency_hz, cand.peak.width_bins, own | cand.region
        )
        suspect = Suspect(
            frequency_hz=obj.eigenfrequency_hz,
            sd_hz=obj.eigenfrequency_uncertainty_hz or 0.0,
            width_bins=cand.peak.width_bins,
            localised=front.scan.localised_share(obj.eigenfrequency_hz, own),
            region_power=region_power,
            peak_hz=cand.peak.frequency_hz,
            peak_sd_hz=peak_sd_hz(cand.peak, front.scan.bin_hz),
            coverage=block_coverage(regions.labels_full, obj.id, BRIGHTNESS_BLOCKS),
            ring_power=ring_power,
        )
        verdict = artefact_verdict(front.evidence, suspect, sample_rate_hz=sample_rate_hz)
        if verdict is None:
            stronger = [
                o for o in objects if (o.detection_z or 0.0) > (obj.detection_z or 0.0) and o.id not in out
            ]
            tolerance_hz = max(1.5 * front.scan.bin_hz, 2 * (obj.eigenfrequency_uncertainty_hz or 0.0))
            verdict = camera_intermodulation(
                front.evidence,
                obj.eigenfrequency_hz,
                objects_hz=[
                    o.eigenfrequency_hz
                    for o in stronger
                    if shared_region(cand.region, regions.candidates[o.id - 1].region)
                ],
                tolerance_hz=tolerance_hz,
            ) or light_images(
                front.evidence,
                obj.eigenfrequency_hz,
                tolerance_hz=tolerance_hz,
                motion_at=front.scan.statistic_at,
                amplitude_px=obj.amplitude_px,
                objects=[(o.eigenfrequency_hz, o.amplitude_px) for o in stronger],
            )
        if verdict is not None:
            out[obj.id] = verdict
    return out


def peak_sd_hz(peak: Peak, bin_hz: float) -> float:
    """Standard uncertainty of a scan peak's interpolated frequency: the Cramér-Rao bound of a tone's
    frequency from its height over the noise (``power`` of the peak, normalised), with a floor of a tenth
    of a bin for the interpolation's own error."""
    return bin_hz * max(0.1, math.sqrt(3.0 / max(peak.power, 1.0)) / math.pi)


def _ordered(
    objects: list[ObjectMeasurement], labels: NDArray[np.uint16], window_s: float
) -> tuple[list[ObjectMeasurement], NDArray[np.uint16]]:
    """Objects most significant first, renumbered 1, 2, ...; one with fewer than ``MIN_PERIODS`` periods
    in the window never first."""

    def key(o: ObjectMeasurement) -> tuple[bool, float]:
        return (o.eigenfrequency_hz * window_s < MIN_PERIODS, -(o.detection_z or 0.0))

    ordered = sorted(objects, key=key)
    relabelled = np.zeros_like(labels)
    for new_id, o in enumerate(ordered, start=1):
        relabelled[labels == o.id] = new_id
        o.id = new_id
    return ordered, relabelled


def analyze_window(
    buffers: FrameBuffers,
    plan: Plan,
    info: ClipInfo,
    *,
    config: AnalysisConfig,
    excitations: Sequence[Excitation] = (),
    watch: Stopwatch | None = None,
    progress: Progress | None = None,
    front: Front | None = None,
) -> Analysis:
    """Everything after the frame stream: the window's flow, depth and grey frames to the result.

    Spectra, segmentation of the candidates, each object measured and judged (its significance, the
    artefact evidence, overtones), and the quality notes. :func:`analyze` calls it on the fine flow of
    the region that moves; a live stream (:mod:`workers.pipeline.live`) on the whole-frame flow it
    computed as the frames arrived.

    Parameters
    ----------
    buffers : FrameBuffers
        The window's buffers (``roi`` says which box of the frame their grid covers).
    plan : Plan
        Which frames they are and their sample rate.
    info : ClipInfo
        The clip's metadata (frame size, rate and its source, intrinsics).
    config : AnalysisConfig
    excitations : sequence of Excitation
    watch : Stopwatch, optional
        Adds this function's stages to the stopwatch's laps (a new one when None).
    progress : callable, optional
    front : Front, optional
        The whole picture's findings (the look's); when None, made from ``buffers`` (the whole frame's),
        which are then cut to the box that moves (:func:`~workers.pipeline.fine.crop_to_motion`).

    Returns
    -------
    Analysis
    """
    watch = watch or Stopwatch()
    if front is None:
        buffers, front = _whole_frame_front(buffers, plan, info, config=config, asserted=len(excitations))
        watch.lap("spectrum")
    window = _Window(buffers, plan, info, config, buffers.box((info.height, info.width)))
    quality: list[QualityNote] = [*clip_notes(plan, buffers, info), *frame_notes(buffers)]
    report_progress(progress, "spectrum")
    spectra = _window_spectra(buffers, plan, info, quality)
    watch.lap("spectrum")
    report_progress(progress, "segmentation")
    regions = segment_candidates(
        spectra.pixels,
        lambda: spectra.constrained,
        front=front,
        box=window.box,
        depth=buffers.depth,
        config=config.segmentation,
    )
    watch.lap("segmentation")
    report_progress(progress, "mechanics")
    objects, by_label = _measure(window, regions, spectra, front, excitations=excitations)
    if buffers.depth is None:
        _to_rest(objects, regions.labels_full)
    objects, labels_full, rejected = _judge(objects, regions, front, plan, by_label, quality)
    objects, labels_full = _ordered(objects, labels_full, float(buffers.times_s[-1]))
    quality.extend(_notes(objects, plan, info, config, buffers, spectra))
    watch.lap("mechanics")
    return _analysis(window, front, spectra, objects, labels_full, rejected, quality, watch)


def _whole_frame_front(
    buffers: FrameBuffers, plan: Plan, info: ClipInfo, *, config: AnalysisConfig, asserted: int
) -> tuple[FrameBuffers, Front]:
    """The whole picture's findings made from a window's whole-frame buffers (a live stream's), and the
    buffers cut to the box that moves, as the batch path's second pass covers it
    (:func:`~workers.pipeline.fine.crop_to_motion`)."""
    band = analysis_band(config, plan.sample_rate_hz, buffers.count)
    front = front_of_buffers(
        buffers,
        sample_rate_hz=plan.sample_rate_hz,
        band_hz=band,
        max_objects=config.max_objects,
        asserted=asserted,
    )
    if not front.candidates.found:
        return buffers, front
    frame_shape = (info.height, info.width)
    buffers = crop_to_motion(
        buffers, front.candidates.regions, factor=front.grid_factor, frame_shape=frame_shape
    )
    return buffers, front.keeping_flow_of(buffers.box(frame_shape))


def _footing(front: Front, regions: Regions, label: int) -> Footing:
    """Where object ``label``'s line was found and where its mask lies, on the scan's grid."""
    held = coarse_share(front, regions.labels_full == label)
    return Footing(found=regions.candidates[label - 1].region, held=held)


def _judge(
    objects: list[ObjectMeasurement],
    regions: Regions,
    front: Front,
    plan: Plan,
    by_label: dict[int, Excitation],
    quality: list[QualityNote],
) -> tuple[list[ObjectMeasurement], NDArray[np.uint16], list[RejectedPeak]]:
    """Drop what is not an object (every drop a rejected peak and a note); a region the user named in
    an excitation is kept unless it is an artefact."""
    verdicts = judge_objects(
        objects,
        regions.seg,
        scan=front.scan,
        band_hz=front.band_hz,
        sample_rate_hz=plan.sample_rate_hz,
        bin_hz=front.scan.bin_hz,
        footings=[_footing(front, regions, o.id) for o in objects],
    )
    verdicts |= folded_verdicts(
        objects, plan.survey, sample_rate_hz=plan.sample_rate_hz, frame_step=plan.step
    )
    # Artefact evidence is asked of what stands out of the noise only (what does not is just that).
    significant = [o for o in objects if o.id not in verdicts or verdicts[o.id].evidence != "not_significant"]
    artefacts = _artefacts(significant, regions, front, sample_rate_hz=plan.sample_rate_hz)
    dropped = {i: v for i, v in verdicts.items() if i not in by_label} | artefacts
    quality.extend(
        QualityNote(
            "low_snr",
            f"{v.reason}; reported all the same, since an excitation names this object (its "
            "false-alarm probability says how far to trust it)",
        )
        for i, v in verdicts.items()
        if i in by_label and i not in artefacts and v.evidence == "not_significant"
    )
    rejected = [*front.candidates.rejected, *dropped.values()]
    kept, labels = drop_objects(objects, regions.labels_full, dropped, quality)
    if plan.survey is not None:
        for obj in kept:
            clip_regime(obj, plan.survey, clip_s=plan.survey.frames / plan.fps)
    return kept, labels, rejected


def _notes(
    objects: list[ObjectMeasurement],
    plan: Plan,
    info: ClipInfo,
    config: AnalysisConfig,
    buffers: FrameBuffers,
    spectra: _Spectra,
) -> list[QualityNote]:
    """The quality notes of the objects, the clip and the window."""
    notes: list[QualityNote] = []
    if not objects:
        notes.append(NO_MOTION)
    if not info.has_depth and config.depth_m is None:
        notes.append(NO_DEPTH)
    band = analysis_band(config, plan.sample_rate_hz, buffers.count)
    window_s = float(buffers.times_s[-1])
    notes.extend(
        object_quality_notes(
            objects, sample_rate_hz=plan.sample_rate_hz, band=band, bin_hz=plan.sample_rate_hz / buffers.count
        )
    )
    notes.extend(resolution_notes(objects, bin_hz=spectra.pixels.bin_hz, window_s=window_s))
    notes.extend(frame_rate_notes(objects, info, window_s=window_s))
    notes.extend(survey_notes(plan, objects))
    return notes


NO_MOTION = QualityNote(
    "no_motion",
    "no vibrating object stands above the noise; check the frame rate, the band and that the object moves "
    "in the analysed frames",
    "error",
)
NO_DEPTH = QualityNote(
    "no_depth", "the clip has no depth: amplitudes in metres, stiffness and mass need depth or depth_m"
)


def _analysis(
    window: _Window,
    front: Front,
    spectra: _Spectra,
    objects: list[ObjectMeasurement],
    labels_full: NDArray[np.uint16],
    rejected: list[RejectedPeak],
    quality: list[QualityNote],
    watch: Stopwatch,
) -> Analysis:
    """The window's result: its objects and labels, spectra, the scan's frequency map and detection
    statistic, and what was analysed."""
    buffers, plan, config, box = window.buffers, window.plan, window.config, window.box
    fmap, fvalid = front.scan.frequency_map()
    return Analysis(
        objects=objects,
        labels=labels_full,
        frequencies_hz=spectra.pixels.frequencies_hz,
        power=spectra.summed,
        frequency_map_hz=fmap,
        frequency_map_valid=fvalid,
        frame_rgb=buffers.first_rgb,
        fps=plan.fps,
        fps_source=window.info.fps_source or "unknown",
        frames_used=(plan.start, plan.start + buffers.count * plan.step + 1),
        band_hz=front.band_hz,
        quality=quality,
        timings_s=watch.times,
        parameters=config.describe()
        | {
            "frames": buffers.count * plan.step + 1,
            "start_frame": plan.start,
            "frame_step": plan.step,
            "band_hz": list(front.band_hz),
            "flow_scale": 1.0 / box.pixel_scale,
            "region": box.describe(),
        },
        method="default",
        peaks=[o for o in front.candidates.peaks],
        noise_power=spectra.noise,
        rejected_peaks=rejected,
        frame_step=plan.step,
        window_survey=plan.survey,
        detection=front.detection(),
    )


def _still(
    buffers: FrameBuffers,
    plan: Plan,
    info: ClipInfo,
    front: Front,
    *,
    config: AnalysisConfig,
    watch: Stopwatch,
) -> Analysis:
    """The result of a window in which nothing stands out of the noise (no second pass)."""
    quality = [*clip_notes(plan, buffers, info), *frame_notes(buffers), NO_MOTION]
    if not info.has_depth and config.depth_m is None:
        quality.append(NO_DEPTH)
    quality.extend(survey_notes(plan, []))
    summed = front.spectra.power.sum(axis=1, dtype=np.float64)
    box = Roi.whole((info.height, info.width), front.scan.grid_shape)
    spectra = _Spectra(front.spectra, summed, background_spectrum(front.spectra), front.scan_confidence)
    labels = np.zeros((info.height, info.width), np.uint16)
    return _analysis(
        _Window(buffers, plan, info, config, box), front, spectra, [], labels, [], quality, watch
    )


__all__ = [
    "DEFAULT_MAX_FRAMES",
    "DEFAULT_WINDOW_MIB",
    "Analysis",
    "AnalysisConfig",
    "Excitation",
    "ObjectMeasurement",
    "QualityNote",
    "analyze",
    "analyze_window",
]

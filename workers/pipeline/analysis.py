"""The measuring pipeline wired together: clip -> window -> flow -> spectra -> peaks -> segmentation ->
objects measured -> result. :func:`analyze` is the one entry point; it takes a clip reader and dataclasses
and returns an :class:`Analysis` dataclass (no files are written here).

Where each decision lives: :mod:`~workers.pipeline.window` (which frames), :mod:`~workers.pipeline.stream`
(flow and camera motion), :mod:`~workers.pipeline.spectra` and :mod:`~workers.pipeline.peaks` (spectra and
their peaks), :mod:`~workers.pipeline.segmentation` (which pixels), :mod:`~workers.pipeline.detection`
(which peaks are objects), :mod:`~workers.pipeline.measure` (each object's figures).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

from workers.pipeline.camera import CameraRing
from workers.pipeline.clipio.types import ClipInfo, ClipReader, Intrinsics
from workers.pipeline.detection import (
    ARTEFACT_EVIDENCE,
    WindowEvidence,
    candidate_peaks,
    clip_regime,
    drop_objects,
    folded_verdicts,
    judge_objects,
    reject_artefacts,
)
from workers.pipeline.flow import FlowConfig, needs_resampling, resample_uniform
from workers.pipeline.measure import assign_excitations, measure_object
from workers.pipeline.model import (
    DEFAULT_MAX_FRAMES,
    DEFAULT_WINDOW_MIB,
    Analysis,
    AnalysisConfig,
    Excitation,
    ObjectMeasurement,
    Progress,
    QualityNote,
    Stopwatch,
)
from workers.pipeline.quality import (
    SECOND_MOTION,
    clip_notes,
    close_pairs,
    frame_notes,
    frame_rate_notes,
    object_quality_notes,
    resolution_notes,
)
from workers.pipeline.segmentation import (
    Exclusion,
    exclude_background_surfaces,
    frequency_map,
    segment,
    upsample_labels,
)
from workers.pipeline.spectra import PixelSpectra, pixel_spectra
from workers.pipeline.stream import FrameBuffers, stream_frames
from workers.pipeline.survey import Survey
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
    result = _analyze_default(reader, config=config, excitations=excitations, progress=progress)
    longer: float | None = None
    if _needs_longer_window(result):
        # Two oscillations share a region or stand closer than the window resolves, and the clip has
        # more: analyse as long a window as the memory budget allows (every k-th frame if need be).
        survey = result.window_survey
        assert survey is not None
        longer = survey.frames / survey.fps
        first = result.timings_s
        result = _analyze_default(
            reader,
            config=config,
            excitations=excitations,
            progress=progress,
            survey=survey,
            min_duration_s=longer,
        )
        result.timings_s = {"short_window_pass": sum(first.values()), **result.timings_s}
        result.quality.append(
            QualityNote(
                "longer_window",
                "two oscillations were closer than the first window resolves, so the clip was analysed "
                f"again over frames {result.frames_used[0]}-{result.frames_used[1]}",
                "info",
            )
        )
    if config.flow is None and _needs_careful_flow(result):
        # The fast default flow ("fine": no variational refinement) is five times cheaper than DIS
        # "medium" and as accurate on clear motion; weak, sub-pixel motion is measured again on medium.
        careful = dataclasses.replace(config, flow=FlowConfig(dis_preset="medium"))
        first = result.timings_s
        kept = [q for q in result.quality if q.code == "longer_window"]
        result = _analyze_default(
            reader,
            config=careful,
            excitations=excitations,
            progress=progress,
            survey=result.window_survey,
            min_duration_s=longer,
        )
        result.timings_s = {"fast_flow_pass": sum(first.values()), **result.timings_s}
        result.quality.extend(kept)
        result.quality.append(
            QualityNote(
                "careful_flow",
                "the fast optical flow found only weak motion, so the clip was analysed again with the "
                "careful flow (DIS medium)",
                "info",
            )
        )
    return result


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
    if not result.objects or any(r.evidence in ARTEFACT_EVIDENCE for r in result.rejected_peaks):
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
    min_duration_s: float | None = None,
) -> Analysis:
    """One pass of the default method. ``survey``: a survey of this clip already made (a second pass
    reuses the first's); ``min_duration_s``: the window must span at least this long (a second pass that
    separates close frequencies)."""
    watch = Stopwatch()
    info = reader.info
    plan = plan_analysis(
        info, config, reader=reader, progress=progress, survey=survey, min_duration_s=min_duration_s
    )
    if progress:
        progress("flow", 0.05)
    watch.lap("survey" if plan.survey is not None else "setup")
    source, first, last = plan.source(reader)
    buffers = stream_frames(source, first, last, plan.grid, plan.flow, progress, keep_gray=True)
    watch.stream_lap(buffers)
    return analyze_window(
        buffers, plan, info, config=config, excitations=excitations, watch=watch, progress=progress
    )


def analyze_window(
    buffers: FrameBuffers,
    plan: Plan,
    info: ClipInfo,
    *,
    config: AnalysisConfig,
    excitations: Sequence[Excitation] = (),
    watch: Stopwatch | None = None,
    progress: Progress | None = None,
) -> Analysis:
    """Everything after the frame stream: the window's flow, depth and grey frames to the result.

    Spectra, candidate peaks, segmentation, the evidence that drops artefacts, each object measured and
    judged, and the quality notes. :func:`analyze` calls it on the frames it streamed; a live stream
    (:mod:`workers.pipeline.live`) calls it on the flow it computed as the frames arrived.

    Parameters
    ----------
    buffers : FrameBuffers
        The window's buffers (see :func:`workers.pipeline.stream.stream_frames`).
    plan : Plan
        Which frames they are, their sample rate, the flow grid.
    info : ClipInfo
        The clip's metadata (frame size, rate and its source, intrinsics).
    config : AnalysisConfig
    excitations : sequence of Excitation
    watch : Stopwatch, optional
        Adds this function's stages to the stopwatch's laps (a new one when None).
    progress : callable, optional

    Returns
    -------
    Analysis
    """
    watch = watch or Stopwatch()
    n = buffers.count
    band = analysis_band(config, plan.fps, n)
    quality: list[QualityNote] = [*clip_notes(plan, buffers, info), *frame_notes(buffers)]

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
    peaks, summed, noise = candidate_peaks(spectra, band_hz=band, max_peaks=config.max_objects)
    watch.lap("spectrum")

    if progress:
        progress("segmentation", 0.88)
    seg = segment(spectra, peaks, grid_shape=plan.grid, band_hz=band, config=config.segmentation)
    evidence = window_evidence(buffers, spectra, grid=plan.grid)
    seg, rejected = reject_artefacts(seg, spectra, evidence, band_hz=band)
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
    by_label = assign_excitations(list(excitations), labels_full, len(seg.peaks))
    objects: list[ObjectMeasurement] = []
    for label, peak in enumerate(seg.peaks, start=1):
        mask = labels_grid == label
        full_mask = labels_full == label
        objects.append(
            measure_object(
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
                band_hz=band,
            )
        )
    for item in rejected:
        quality.append(QualityNote("artefact_peak", f"{item.reason}; not reported as an object", "info"))
    # Every region measured is judged: a coherent oscillation inside the band, known well enough, that
    # is no overtone of another (a region the user named in an excitation is always kept).
    verdicts = judge_objects(objects, seg, band_hz=band, fps=plan.fps, bin_hz=spectra.bin_hz)
    verdicts |= folded_verdicts(objects, plan.survey, sample_rate_hz=plan.fps, frame_step=plan.step)
    dropped = {i: v for i, v in verdicts.items() if i not in by_label}
    incoherent = [
        o.snr_db or 0.0 for o in objects if o.id in dropped and dropped[o.id].evidence == "incoherent"
    ]
    rejected.extend(dropped.values())
    objects, labels_full = drop_objects(objects, labels_full, dropped, quality)
    if plan.survey is not None:
        for obj in objects:
            clip_regime(obj, plan.survey, clip_s=plan.survey.frames / plan.clip_fps)
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
    quality.extend(object_quality_notes(objects, fps=plan.fps, band=band, bin_hz=plan.fps / n))
    quality.extend(resolution_notes(objects, bin_hz=spectra.bin_hz, window_s=float(buffers.times_s[-1])))
    quality.extend(frame_rate_notes(objects, info, window_s=float(buffers.times_s[-1])))
    quality.extend(survey_notes(plan, objects))
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
        frames_used=(plan.start, plan.start + buffers.count * plan.step + 1),
        band_hz=band,
        quality=quality,
        timings_s=watch.times,
        parameters=config.describe()
        | {
            "frames": buffers.count * plan.step + 1,
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


def window_evidence(buffers: FrameBuffers, spectra: PixelSpectra, *, grid: tuple[int, int]) -> WindowEvidence:
    """What the whole picture did in the window (brightness, frame changes, the border's motion)."""
    ring = CameraRing(grid)
    if buffers.gray is not None:
        import cv2

        first = buffers.gray[0]
        small = (
            first
            if first.shape == grid
            else cv2.resize(first, (grid[1], grid[0]), interpolation=cv2.INTER_AREA)
        )
        ring.set_texture(small)
    return WindowEvidence(
        frequencies_hz=spectra.frequencies_hz,
        nfft=spectra.n,
        brightness=buffers.brightness,
        frame_change=buffers.frame_change,
        border_px=buffers.border_px,
        camera_removed=buffers.camera_removed,
        ring_pixels=ring.pixels,
        ring_textured=ring.textured,
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

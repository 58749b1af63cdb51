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

from workers.pipeline.clipio.types import ClipReader, Intrinsics
from workers.pipeline.detection import candidate_peaks, drop_incoherent, reject_artefacts
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
from workers.pipeline.quality import object_quality_notes
from workers.pipeline.segmentation import (
    Exclusion,
    exclude_background_surfaces,
    frequency_map,
    segment,
    upsample_labels,
)
from workers.pipeline.spectra import pixel_spectra
from workers.pipeline.stream import stream_frames
from workers.pipeline.survey import Survey
from workers.pipeline.window import analysis_band, plan_analysis, survey_notes


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
    watch = Stopwatch()
    info = reader.info
    plan = plan_analysis(info, config, reader=reader, progress=progress, survey=survey)
    if progress:
        progress("flow", 0.05)
    watch.lap("survey" if plan.survey is not None else "setup")
    source, first, last = plan.source(reader)
    buffers = stream_frames(source, first, last, plan.grid, plan.flow, progress, keep_gray=True)
    watch.stream_lap(buffers)
    n = buffers.count
    band = analysis_band(config, plan.fps, n)
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
    peaks, summed, noise = candidate_peaks(spectra, band_hz=band, max_peaks=config.max_objects)
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
            )
        )
    objects, labels_full, dropped = drop_incoherent(objects, labels_full, quality, by_label)
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
    quality.extend(object_quality_notes(objects, fps=plan.fps, band=band, bin_hz=plan.fps / n))
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


__all__ = [
    "DEFAULT_MAX_FRAMES",
    "DEFAULT_WINDOW_MIB",
    "Analysis",
    "AnalysisConfig",
    "Excitation",
    "ObjectMeasurement",
    "QualityNote",
    "analyze",
]

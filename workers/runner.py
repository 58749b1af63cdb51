"""Run one analysis from a clip file to a result directory.

This is the single code path shared by ``eigenscope analyze`` and the Celery task: open the clip, run
:func:`workers.pipeline.analysis.analyze`, convert its dataclasses into :class:`api_schemas.AnalysisResult`,
and write ``result.json``, ``mask.png`` and the other images into the output directory.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from api_schemas import (
    AnalysisParameters,
    AnalysisResult,
    Artifacts,
    Detection,
    ExcitationUsed,
    ForceLog,
    ImpulseExcitation,
    ModeHarmonicResult,
    ModeResult,
    ObjectResult,
    QualityFlag,
    RejectedPeakResult,
    RingdownResult,
    Spectrum,
    StepReleaseExcitation,
)

if TYPE_CHECKING:
    from backend.settings import Settings
    from workers.pipeline.analysis import Analysis, ObjectMeasurement
    from workers.pipeline.analysis import AnalysisConfig as PipelineConfig
    from workers.pipeline.analysis import Excitation as PipelineExcitation
    from workers.pipeline.clipio import ReadLimits
    from workers.pipeline.clipio.types import ClipReader
    from workers.pipeline.force import ForceSeries

#: ``progress(stage, fraction)`` with fraction in [0, 1] over the whole analysis.
ProgressCallback = Callable[[str, float], None]

RESULT_FILE = "result.json"
MASK_FILE = "mask.png"


def _version() -> str:
    from backend.version import __version__

    return __version__


def _pipeline_excitation(e: StepReleaseExcitation | ImpulseExcitation) -> PipelineExcitation:
    from workers.pipeline.analysis import Excitation

    point = (float(e.point_px[0]), float(e.point_px[1])) if e.point_px else None
    box = tuple(float(v) for v in e.box_px) if e.box_px else None
    if isinstance(e, StepReleaseExcitation):
        kind, value, sd = "step_release", e.force_n, e.force_uncertainty_n
    else:
        kind, value, sd = "impulse", e.impulse_ns, e.impulse_uncertainty_ns
    return Excitation(
        kind=kind,  # type: ignore[arg-type]
        value=value,
        uncertainty=sd,
        object_id=e.object_id,
        point_px=point,
        box_px=box,  # type: ignore[arg-type]
    )


def _ringdown(o: ObjectMeasurement) -> RingdownResult | None:
    r = o.ringdown
    if r is None:
        return None
    decay = None
    if o.damping_ratio is not None:
        decay = o.damping_ratio * o.angular_frequency_rad_s
    return RingdownResult(
        times_s=[round(float(t), 6) for t in r.times_s],
        amplitude_px=[float(a) for a in r.amplitude],
        frequency_hz=[float(f) for f in r.frequency_hz],
        decay_per_s=decay,
    )


@dataclass(frozen=True)
class RunOptions:
    """How :func:`run_analysis` runs, apart from what it measures.

    Attributes
    ----------
    scratch_dir : path or None
        Where a zipped ROS 2 bag may be unpacked (default: the system temporary folder).
    flow_threads : int or None
        Frame pairs whose flow is computed at once (default two).
    limits : ReadLimits or None
        What the clip may hold and decode to (default :class:`~workers.pipeline.clipio.ReadLimits`).
    """

    scratch_dir: str | Path | None = None
    flow_threads: int | None = None
    limits: ReadLimits | None = None


def run_analysis(
    clip_path: str | Path,
    out_dir: str | Path,
    *,
    excitation: StepReleaseExcitation
    | ImpulseExcitation
    | Sequence[StepReleaseExcitation | ImpulseExcitation]
    | None = None,
    parameters: AnalysisParameters | None = None,
    progress: ProgressCallback | None = None,
    depth_path: str | Path | None = None,
    force_log: ForceLog | None = None,
    options: RunOptions | None = None,
) -> AnalysisResult:
    """Analyse the clip at ``clip_path`` and write the result files into ``out_dir``.

    The excitation is the typed one (``excitation``), else what the robot's force sensor recorded: a
    ``force_log`` sent with the clip, or the bag's force topic (``parameters.force_topic``, or the bag's one
    force topic): see :func:`recorded_force`.

    Files are written to a temporary name and renamed, so a reader never sees half a result.
    ``depth_path`` is a video's depth companion (npz or zip of depth PNGs); ``options`` says where to
    unpack, how many flow threads to use and what the clip may hold (:class:`RunOptions`). The images are
    drawn by :func:`workers.drawing.draw_all`, which imports matplotlib when they are drawn: no earlier, in
    a thread beside the measurement as it was, whose import and warm-up figure then held the interpreter
    the registration needs (``eigenscope analyze`` of a 640 x 480 x 256 clip 7 % slower, its peak memory
    36 MiB higher with matplotlib loaded beside the window's buffers; ``bench/README.md``).

    Raises
    ------
    workers.pipeline.errors.EigenscopeError
        Subclasses for bad clips (``ClipError``), bad parameters (``ParameterError``) and clips that
        cannot be analysed (``AnalysisError``); their messages are meant for the user.
    """
    from workers.pipeline.analysis import analyze
    from workers.pipeline.clipio import ClipOverrides, open_clip
    from workers.pipeline.force import chosen_excitations
    from workers.pipeline.model import QualityNote

    opts = options or RunOptions()

    params = parameters or AnalysisParameters()
    overrides = ClipOverrides(
        fps=params.fps,
        fx=params.fx,
        fy=params.fy,
        cx=params.cx,
        cy=params.cy,
        depth_scale=params.depth_scale,
        color_topic=params.color_topic,
        depth_topic=params.depth_topic,
    )
    config = analysis_config(params, flow_threads=opts.flow_threads)
    requested = requested_excitations(excitation)
    exc = pipeline_excitations(requested)

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with open_clip(
        clip_path, overrides=overrides, limits=opts.limits, depth=depth_path, scratch_dir=opts.scratch_dir
    ) as reader:
        recorded, notes = recorded_force(reader, params, force_log)
        chosen = chosen_excitations(exc, recorded)
        analysis = analyze(reader, config=config, excitation=chosen, progress=progress)
    analysis.quality.extend(QualityNote("force_recording", n, "info") for n in notes)
    if progress is not None:
        progress("rendering", 0.97)
    result = write_result(
        analysis,
        out,
        excitation=requested,
        parameters=params,
    )
    if progress is not None:
        progress("done", 1.0)
    return result


def recorded_force(
    reader: ClipReader, params: AnalysisParameters, force_log: ForceLog | None
) -> tuple[PipelineExcitation | None, list[str]]:
    """The excitation the robot's force sensor recorded, and notes: from ``force_log`` (sent with the clip),
    else from the bag's force topic (the one named by ``params.force_topic``, or the bag's only one). A
    recording the user named (a log, a topic) that shows no hold, release or strike is an error; one
    merely found in the bag gives a note.

    Raises
    ------
    workers.pipeline.errors.ForceError
        A bad log or topic, several force topics with none chosen, clocks that do not overlap, or (when
        asked for) a recording without an excitation.
    """
    from workers.pipeline.clipio.force_topics import force_topics, read_force
    from workers.pipeline.clipio.rosbag import BagClip
    from workers.pipeline.errors import ForceError
    from workers.pipeline.force import recorded_excitation

    if force_log is not None:
        series = force_series(force_log)
        _check_log_clock(series, reader)
        return recorded_excitation(series, asked=True)
    topic = params.force_topic
    if not isinstance(reader, BagClip):
        if topic is not None:
            raise ForceError(
                f"force_topic {topic!r} was given but the clip is not a ROS bag; send the force as a force "
                "log (--force-log FILE) instead"
            )
        return None, []
    if topic is None and not force_topics(reader):
        return None, []
    return recorded_excitation(read_force(reader, topic=topic), asked=topic is not None)


def _check_log_clock(series: ForceSeries, reader: ClipReader) -> None:
    """Refuse a force log whose times do not overlap the clip's frames (0 s at the first frame, a frame's
    time of slack at the end): it is on another clock.

    Raises
    ------
    workers.pipeline.errors.ForceError
    """
    from workers.pipeline.errors import ForceError

    info = reader.info
    stamps = info.timestamps_s
    if stamps is not None and len(stamps):
        last = float(stamps[-1])
    elif info.fps:
        last = (info.frames - 1) / info.fps
    else:
        return
    start, end = float(series.times_s[0]), float(series.times_s[-1])
    if end >= 0.0 and start <= last + (1.0 / info.fps if info.fps else 0.0):
        return
    raise ForceError(
        f"the force {series.source}'s times ({start:.6g} s to {end:.6g} s on the clip's clock) do not "
        f"overlap the clip's frames (0 s to {last:.6g} s): the log is on another clock; give its offset "
        "(--force-log-offset-s, or offset_s in the request), minus the log's time at the clip's first frame"
    )


def force_series(log: ForceLog) -> ForceSeries:
    """A request's force log as the pipeline's series on the clip's clock (checked there)."""
    import numpy as np

    from workers.pipeline.force import ForceSeries

    columns = [log.force_n] if log.force_n is not None else [log.fx, log.fy, log.fz]
    return ForceSeries(
        times_s=np.asarray(log.time_s, np.float64) + log.offset_s,
        force_n=np.asarray(columns, np.float64).T,
        source=f"log {log.name}",
        frame_id=log.frame_id,
    )


def analysis_config(params: AnalysisParameters, *, flow_threads: int | None = None) -> PipelineConfig:
    """The pipeline's configuration for the API's analysis parameters."""
    from workers.pipeline.analysis import AnalysisConfig
    from workers.pipeline.flow import FlowConfig

    flow = None
    if params.flow is not None:
        flow = FlowConfig(method=params.flow, scale=1.0 if params.method == "paper" else None)
    return AnalysisConfig(
        method=params.method,
        flow=flow,
        frames=params.frames,
        start_frame=params.start_frame,
        min_frequency_hz=params.min_frequency_hz,
        max_frequency_hz=params.max_frequency_hz,
        depth_m=params.depth_m,
        flow_threads=flow_threads,
    )


def requested_excitations(
    excitation: StepReleaseExcitation
    | ImpulseExcitation
    | Sequence[StepReleaseExcitation | ImpulseExcitation]
    | None,
) -> list[StepReleaseExcitation | ImpulseExcitation]:
    """The request's excitation (one, several or none) as a list."""
    if excitation is None:
        return []
    if isinstance(excitation, StepReleaseExcitation | ImpulseExcitation):
        return [excitation]
    return list(excitation)


def pipeline_excitations(
    requested: Sequence[StepReleaseExcitation | ImpulseExcitation],
) -> list[PipelineExcitation]:
    """The API's excitation models as the pipeline's dataclasses."""
    return [_pipeline_excitation(e) for e in requested]


def write_result(
    analysis: Analysis,
    out: Path,
    *,
    excitation: Sequence[StepReleaseExcitation | ImpulseExcitation],
    parameters: AnalysisParameters,
) -> AnalysisResult:
    """Draw the images of ``analysis`` into ``out`` and write ``result.json`` there; returns the result."""
    from time import perf_counter

    from workers.drawing import draw_all

    started = perf_counter()
    # mask.png (MASK_FILE) and every other image
    artifacts = draw_all(analysis, out)
    analysis.timings_s["rendering"] = perf_counter() - started  # the stage `Job.stage` calls so
    result = build_result(analysis, excitation=excitation, parameters=parameters, artifacts=artifacts)
    write_result_json(out, result)
    return result


def write_result_json(out: Path, result: AnalysisResult) -> None:
    """Write ``result`` as ``out``/``result.json`` (atomically, with the images' permissions)."""
    from workers.pipeline._files import write_atomically

    write_atomically(out / RESULT_FILE, json.dumps(result.model_dump(mode="json"), indent=2))


def _object_result(o: ObjectMeasurement) -> ObjectResult:
    """An object as the API gives it: the pipeline's measurement carries the API's names and units, so its
    fields are copied by name (non-finite numbers become null, tuples lists), and its ring-down series
    sampled for the result."""
    values = {
        name: _finite(getattr(o, name))
        for name in ObjectResult.model_fields
        if name not in ("ringdown", "modes", "mode_mac", "mode_harmonics", "excitation") and hasattr(o, name)
    }
    return ObjectResult(**values, ringdown=_ringdown(o), excitation=_excitation_used(o), **_modes(o))


def _excitation_used(o: ObjectMeasurement) -> ExcitationUsed | None:
    """The excitation the object was measured with, and where it came from."""
    e = o.excitation
    if e is None:
        return None
    return ExcitationUsed(
        type=e.kind,
        value=e.value,
        uncertainty=e.uncertainty,
        release_time_s=e.release_time_s,
        source=e.source,
        notes=list(e.notes),
    )


def _finite(value: Any) -> Any:
    """A value as JSON takes it: a non-finite number becomes None, a tuple a list."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return list(value) if isinstance(value, tuple) else value


def _modes(o: ObjectMeasurement) -> dict[str, Any]:
    """The object's modes as the API gives them (the pipeline's names are the API's), and the MAC between
    their shapes when there are two or more."""
    if o.modes is None:
        return {"modes": [], "mode_mac": None, "mode_harmonics": []}
    found = o.modes.found
    fields = ModeResult.model_fields
    modes = [ModeResult(**{name: _finite(getattr(m, name)) for name in fields}) for m in found.modes]
    mac = [[round(float(v), 4) for v in row] for row in found.mac] if len(found.modes) > 1 else None
    harmonics = [
        ModeHarmonicResult(**{name: getattr(h, name) for name in ModeHarmonicResult.model_fields})
        for h in found.harmonics
    ]
    return {"modes": modes, "mode_mac": mac, "mode_harmonics": harmonics}


def build_result(
    analysis: Analysis,
    *,
    excitation: Sequence[StepReleaseExcitation | ImpulseExcitation],
    parameters: AnalysisParameters,
    artifacts: Mapping[str, str],
) -> AnalysisResult:
    """The :class:`AnalysisResult` of ``analysis``, naming the image files ``artifacts`` (key -> file name);
    nothing is drawn or written (a live stream sends it before its images are drawn)."""
    requested, params = list(excitation), parameters
    objects = [_object_result(o) for o in analysis.objects]
    parameters_used = analysis.parameters | {
        "fps": analysis.fps,
        "fps_source": analysis.fps_source,
        "excitation": [e.model_dump(mode="json") for e in requested] or None,
        "overrides": params.model_dump(exclude_none=True),
    }
    return AnalysisResult(
        eigenfrequency_hz=analysis.eigenfrequency_hz,
        objects=objects,
        spectrum=Spectrum(
            frequencies_hz=[float(f) for f in analysis.frequencies_hz],
            power=[float(p) for p in analysis.power],
            noise_power=None if analysis.noise_power is None else [float(p) for p in analysis.noise_power],
        ),
        artifacts=Artifacts(**artifacts),
        quality=[QualityFlag(code=q.code, message=q.message, severity=q.severity) for q in analysis.quality],
        rejected_peaks=[
            RejectedPeakResult(
                frequency_hz=r.frequency_hz,
                evidence=r.evidence,
                reason=r.reason,
                figures={k: float(v) for k, v in r.figures.items() if math.isfinite(v)},
            )
            for r in analysis.rejected_peaks
            if math.isfinite(r.frequency_hz)
        ],
        detection=_detection(analysis.detection),
        method=analysis.method,
        parameters=parameters_used,
        fps=analysis.fps,
        fps_source=analysis.fps_source,
        frames_used=list(analysis.frames_used),
        frame_step=analysis.frame_step,
        frame_size_px=[int(analysis.labels.shape[1]), int(analysis.labels.shape[0])],
        timings_s={k: round(v, 4) for k, v in analysis.timings_s.items()},
        version=_version(),
    )


def _detection(figures: Mapping[str, float]) -> Detection | None:
    """The detection statistic's figures of an analysis (None for the paper's recipe, which has none)."""
    if not figures:
        return None
    return Detection(
        max_false_alarm=figures["max_false_alarm"],
        location=figures["location"],
        scale=figures["scale"],
        bins_searched=int(figures["bins_searched"]),
        bins_fitted=int(figures["bins_fitted"]),
    )


def read_limits(settings: Settings) -> ReadLimits:
    """The clip readers' caps from the service settings (the same the upload's validation applies)."""
    from workers.pipeline.clipio import ReadLimits

    mib = 1024 * 1024
    return ReadLimits(
        max_frames=settings.max_frames,
        max_pixels_per_frame=settings.max_pixels_per_frame,
        max_uncompressed_bytes=settings.max_decoded_mb * mib,
        max_decoded_bytes=settings.max_decoded_mb * mib,
        max_inflation_ratio=settings.max_inflation_ratio,
        inflation_floor_bytes=settings.inflation_floor_mb * mib,
    )


def job_runner(settings: Settings) -> Callable[..., AnalysisResult]:
    """:func:`run_analysis` for a worker: the settings' read limits, and a scratch folder beside the
    attempt's output folder (``<out_dir>-scratch``: a zipped ROS 2 bag is unpacked there, and an
    abandoned attempt's scratch is removed with its outputs)."""
    limits = read_limits(settings)

    def run(clip_path: str | Path, out_dir: str | Path, **options: Any) -> AnalysisResult:
        scratch = Path(out_dir).with_name(Path(out_dir).name + "-scratch")
        scratch.mkdir(exist_ok=True)
        try:
            return run_analysis(
                clip_path, out_dir, options=RunOptions(scratch_dir=scratch, limits=limits), **options
            )
        finally:
            shutil.rmtree(scratch, ignore_errors=True)

    return run

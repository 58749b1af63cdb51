"""The API's resources as typed, frozen dataclasses, and the excitations a job request names.

Field names and meanings are the OpenAPI document's (``openapi/openapi.json``; a test keeps them in
step). Units live in the names: ``eigenfrequency_hz``, ``stiffness_n_per_m``, ``mass_kg``. Members a
newer server adds are kept in ``raw`` and otherwise ignored, so an older client keeps working.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, ClassVar, Generic, Literal, TypedDict, TypeVar

from eigenscope_client._errors import JobFailedError

#: Job states; the last three are final.
JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
FINAL_STATUSES = ("succeeded", "failed", "cancelled")

T = TypeVar("T")


def _datetime(value: Any) -> datetime | None:
    if value is None:
        return None
    text = str(value)
    if text.endswith("Z"):  # Python 3.10 does not read the Z suffix
        text = text[:-1] + "+00:00"
    return datetime.fromisoformat(text)


def _list_of(convert: Callable[[Any], T]) -> Callable[[Any], list[T]]:
    return lambda items: [convert(item) for item in items or []]


def _optional(convert: Callable[[Any], T]) -> Callable[[Any], T | None]:
    return lambda value: None if value is None else convert(value)


class _Model:
    """``from_dict`` for the dataclasses below: known members by name, nested ones converted."""

    #: The OpenAPI schema this class mirrors.
    schema: ClassVar[str] = ""
    #: Converters of nested members.
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {}

    @classmethod
    def from_dict(cls: type[Any], data: dict[str, Any]) -> Any:
        kwargs: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name == "raw":
                kwargs["raw"] = data
                continue
            if f.name not in data:
                continue
            value = data[f.name]
            converter = cls.convert.get(f.name)
            kwargs[f.name] = converter(value) if converter is not None else value
        return cls(**kwargs)


@dataclass(frozen=True)
class CameraIntrinsics(_Model):
    """Pinhole intrinsics, pixels."""

    schema: ClassVar[str] = "CameraIntrinsics"
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class Problem(_Model):
    """An RFC 9457 problem document: why a job failed."""

    schema: ClassVar[str] = "Problem"
    title: str
    status: int
    type: str = "about:blank"
    detail: str | None = None
    instance: str | None = None
    errors: list[dict[str, Any]] | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


@dataclass(frozen=True)
class Clip(_Model):
    """An uploaded clip and what the server found in it."""

    schema: ClassVar[str] = "Clip"
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {
        "intrinsics": _optional(CameraIntrinsics.from_dict),
        "created_at": _datetime,
    }
    id: str
    format: str
    frames: int
    fps: float | None
    width: int
    height: int
    has_depth: bool
    size_bytes: int
    created_at: datetime
    fps_source: str | None = None
    depth_scale: float | None = None
    intrinsics: CameraIntrinsics | None = None
    duration_s: float | None = None
    dropped_frames: int = 0
    streams: list[str] = field(default_factory=list)
    filename: str | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


@dataclass(frozen=True)
class QualityFlag(_Model):
    """Why (part of) a result may be unreliable, and what to do about it."""

    schema: ClassVar[str] = "QualityFlag"
    code: str
    message: str
    severity: str = "warning"


@dataclass(frozen=True)
class Ringdown(_Model):
    """How an object's oscillation decays: amplitude and frequency over sliding windows."""

    schema: ClassVar[str] = "Ringdown"
    times_s: list[float]
    amplitude_px: list[float]
    frequency_hz: list[float]
    decay_per_s: float | None = None


@dataclass(frozen=True)
class Mode(_Model):
    """One mode of an object: a narrow-band component of its motion with a shape of its own (the shapes
    are in the ``modes`` artifact, an npz archive, drawn in ``mode_shapes`` (PNG) and ``mode_animation``
    (GIF))."""

    schema: ClassVar[str] = "Mode"
    frequency_hz: float
    energy_share: float
    regime: str
    complexity: float
    frequency_uncertainty_hz: float | None = None
    damping_ratio: float | None = None
    damping_ratio_uncertainty: float | None = None


@dataclass(frozen=True)
class ModeHarmonic(_Model):
    """A line at an integer multiple of a mode that moves with the mode's shape (a harmonic, not a mode)."""

    schema: ClassVar[str] = "ModeHarmonic"
    frequency_hz: float
    fundamental_hz: float
    order: int
    mac: float


@dataclass(frozen=True)
class ExcitationUsed(_Model):
    """The excitation an object's stiffness and mass were measured with, and where it came from
    (``request``, or a force sensor's recording: ``topic <name>``, ``log <name>``)."""

    schema: ClassVar[str] = "ExcitationUsed"
    type: str
    value: float
    uncertainty: float
    source: str
    release_time_s: float | None = None
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class ObjectResult(_Model):
    """One vibrating object: its frequency, damping, amplitude, stiffness and mass (with uncertainties)."""

    schema: ClassVar[str] = "ObjectResult"
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {
        "ringdown": _optional(Ringdown.from_dict),
        "modes": _list_of(Mode.from_dict),
        "mode_harmonics": _list_of(ModeHarmonic.from_dict),
        "excitation": _optional(ExcitationUsed.from_dict),
    }
    id: int
    eigenfrequency_hz: float
    angular_frequency_rad_s: float
    pixel_count: int
    bbox_px: list[int]
    regime: str = "ring_down"
    eigenfrequency_uncertainty_hz: float | None = None
    natural_frequency_hz: float | None = None
    damping_ratio: float | None = None
    damping_ratio_uncertainty: float | None = None
    amplitude_px: float | None = None
    amplitude_source: str | None = None
    amplitude_m: float | None = None
    amplitude_uncertainty_m: float | None = None
    depth_m: float | None = None
    motion_direction: list[float] | None = None
    stiffness_n_per_m: float | None = None
    stiffness_uncertainty_n_per_m: float | None = None
    mass_kg: float | None = None
    mass_uncertainty_kg: float | None = None
    harmonics_hz: list[float] = field(default_factory=list)
    release_time_s: float | None = None
    snr_db: float | None = None
    false_alarm_probability: float | None = None
    null_reasons: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    ringdown: Ringdown | None = None
    modes: list[Mode] = field(default_factory=list)
    mode_mac: list[list[float]] | None = None
    mode_harmonics: list[ModeHarmonic] = field(default_factory=list)
    excitation: ExcitationUsed | None = None


@dataclass(frozen=True)
class RejectedPeak(_Model):
    """A spectral peak that is not an object, and the evidence why (``camera_motion``,
    ``illumination_flicker``, ``codec_keyframes``, ``harmonic``, ``same_pixels``, ``incoherent``, ...)."""

    schema: ClassVar[str] = "RejectedPeak"
    frequency_hz: float
    evidence: str
    reason: str


@dataclass(frozen=True)
class Spectrum(_Model):
    """The summed motion spectrum and its noise floor."""

    schema: ClassVar[str] = "Spectrum"
    frequencies_hz: list[float]
    power: list[float]
    noise_power: list[float] | None = None


@dataclass(frozen=True)
class Detection(_Model):
    """How objects were told from noise: the scan statistic's law on this clip (objects are reported at a
    false-alarm probability per clip of at most ``max_false_alarm``)."""

    schema: ClassVar[str] = "Detection"
    max_false_alarm: float
    location: float
    scale: float
    bins_searched: int
    bins_fitted: int
    statistic: str = "scan"


@dataclass(frozen=True)
class AnalysisResult(_Model):
    """Everything one analysis measured. ``artifacts`` maps artifact keys (``mask``, ``overlay`` ...,
    ``modes``, ``mode_shapes``, ``mode_animation``, ``result``) to URLs."""

    schema: ClassVar[str] = "AnalysisResult"
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {
        "objects": _list_of(ObjectResult.from_dict),
        "spectrum": Spectrum.from_dict,
        "quality": _list_of(QualityFlag.from_dict),
        "rejected_peaks": _list_of(RejectedPeak.from_dict),
        "detection": _optional(Detection.from_dict),
        "artifacts": lambda a: {k: v for k, v in (a or {}).items() if isinstance(v, str)},
    }
    eigenfrequency_hz: float | None
    objects: list[ObjectResult]
    spectrum: Spectrum
    method: str
    parameters: dict[str, Any]
    fps: float
    fps_source: str
    frames_used: list[int]
    frame_size_px: list[int]
    version: str
    artifacts: dict[str, str] = field(default_factory=dict)
    quality: list[QualityFlag] = field(default_factory=list)
    rejected_peaks: list[RejectedPeak] = field(default_factory=list)
    frame_step: int = 1
    timings_s: dict[str, float] = field(default_factory=dict)
    detection: Detection | None = None

    @property
    def main(self) -> ObjectResult | None:
        """The main object (the first), or None when nothing moved."""
        return self.objects[0] if self.objects else None


@dataclass(frozen=True)
class Callback(_Model):
    """The state of a job's webhook."""

    schema: ClassVar[str] = "Callback"
    url: str
    status: str
    attempts: int = 0
    last_error: str | None = None


@dataclass(frozen=True)
class ForceLogSummary(_Model):
    """The force log a job was sent with, as the job shows it: its name, size, the span of its times on the
    clip's clock (``offset_s`` added) and its columns; never its samples."""

    schema: ClassVar[str] = "ForceLogSummary"
    name: str
    samples: int
    start_s: float
    end_s: float
    columns: list[str]
    frame_id: str | None = None


#: The converters of the members a job and its summary share.
_JOB_CONVERT: dict[str, Callable[[Any], Any]] = {
    "force_log": _optional(ForceLogSummary.from_dict),
    "created_at": _datetime,
    "started_at": _datetime,
    "finished_at": _datetime,
    "error": _optional(Problem.from_dict),
    "callback": _optional(Callback.from_dict),
}


@dataclass(frozen=True)
class _JobFields(_Model):
    """The members a job and its summary share."""

    id: str
    clip_id: str
    status: JobStatus
    progress: float
    parameters: dict[str, Any]
    created_at: datetime
    stage: str | None = None
    attempts: int = 0
    excitation: dict[str, Any] | list[dict[str, Any]] | None = None
    force_log: ForceLogSummary | None = None
    started_at: datetime | None = None
    finished_at: datetime | None = None
    error: Problem | None = None
    callback: Callback | None = None
    source: str = "upload"

    @property
    def done(self) -> bool:
        """Whether the job has ended (succeeded, failed or cancelled)."""
        return self.status in FINAL_STATUSES

    @property
    def succeeded(self) -> bool:
        return self.status == "succeeded"


@dataclass(frozen=True)
class Job(_JobFields):
    """An analysis job. ``etag`` identifies this representation (for long-polls that wait for a change)."""

    schema: ClassVar[str] = "Job"
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {
        **_JOB_CONVERT,
        "result": _optional(AnalysisResult.from_dict),
    }
    result: AnalysisResult | None = None
    etag: str | None = field(default=None, compare=False)
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def raise_for_status(self) -> Job:
        """Return the job if it succeeded (or has not ended yet); raise :class:`JobFailedError` if it
        failed or was cancelled."""
        if self.status in ("failed", "cancelled"):
            raise JobFailedError(self)
        return self


@dataclass(frozen=True)
class ResultSummary(_Model):
    """The headline of a succeeded job's result, as job lists carry it (the main object's figures)."""

    schema: ClassVar[str] = "ResultSummary"
    eigenfrequency_hz: float | None
    objects: int
    warnings: int
    eigenfrequency_uncertainty_hz: float | None = None
    damping_ratio: float | None = None
    stiffness_n_per_m: float | None = None
    mass_kg: float | None = None


@dataclass(frozen=True)
class JobSummary(_JobFields):
    """A job as :meth:`Client.list_jobs` gives it: the record without its result, the result's
    ``summary``, ``url`` (the job) and ``result_url`` (its whole result: :meth:`Client.get_result`)."""

    schema: ClassVar[str] = "JobSummary"
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {
        **_JOB_CONVERT,
        "summary": _optional(ResultSummary.from_dict),
    }
    url: str = ""
    summary: ResultSummary | None = None
    result_url: str | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


@dataclass(frozen=True)
class Stream(_Model):
    """A live stream session (frames go over its ``websocket_url``; :class:`StreamSession` drives it).
    ``resume_token`` is only in the answer that created it."""

    schema: ClassVar[str] = "Stream"
    convert: ClassVar[dict[str, Callable[[Any], Any]]] = {
        "created_at": _datetime,
        "updated_at": _datetime,
        "error": _optional(Problem.from_dict),
    }
    id: str
    job_id: str
    clip_id: str
    status: str
    websocket_url: str
    parameters: dict[str, Any]
    target_relative_uncertainty: float
    max_duration_s: float
    created_at: datetime
    resume_token: str | None = None
    excitation: dict[str, Any] | list[dict[str, Any]] | None = None
    frames_received: int = 0
    converged: bool = False
    last_estimate: dict[str, Any] | None = None
    updated_at: datetime | None = None
    error: Problem | None = None
    raw: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)


@dataclass(frozen=True)
class Page(Generic[T]):
    """One page of a list; pass ``next_cursor`` for the next (None on the last page)."""

    items: list[T]
    next_cursor: str | None = None


# -------------------------------------------------------------------------------------------- requests


@dataclass(frozen=True)
class StepRelease:
    """The object was held by ``force_n`` newtons and released: A = F/k gives stiffness, then mass.

    Name the object by ``object_id``, a point ``point_px`` [x, y] or a box ``box_px`` [x, y, w, h]
    (default: the main object).
    """

    force_n: float
    force_uncertainty_n: float | None = None
    object_id: int | None = None
    point_px: tuple[float, float] | None = None
    box_px: tuple[float, float, float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return _excitation("step_release", self)


@dataclass(frozen=True)
class Impulse:
    """The object was struck by ``impulse_ns`` newton-seconds: v0 = J/m gives mass, then stiffness."""

    impulse_ns: float
    impulse_uncertainty_ns: float | None = None
    object_id: int | None = None
    point_px: tuple[float, float] | None = None
    box_px: tuple[float, float, float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return _excitation("impulse", self)


def _excitation(kind: str, value: Any) -> dict[str, Any]:
    doc: dict[str, Any] = {"type": kind}
    for f in dataclasses.fields(value):
        item = getattr(value, f.name)
        if item is not None:
            doc[f.name] = list(item) if isinstance(item, tuple) else item
    return doc


Excitation = StepRelease | Impulse


class AnalysisParameters(TypedDict, total=False):
    """Analysis options of a job (every one optional; the server's defaults need no tuning)."""

    method: Literal["default", "paper"]
    flow: Literal["farneback", "dis"]
    frames: int
    start_frame: int
    fps: float
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float
    depth_m: float
    color_topic: str
    depth_topic: str
    force_topic: str
    min_frequency_hz: float
    max_frequency_hz: float

"""Job requests and records."""

from __future__ import annotations

from datetime import datetime
from enum import StrEnum
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from api_schemas.parameters import AnalysisParameters, ExcitationSpec, ForceLog, ForceLogSummary
from api_schemas.problem import Problem
from api_schemas.result import RESPONSE, AnalysisResult


class JobCreate(BaseModel):
    """Request body of ``POST /v1/jobs``."""

    model_config = ConfigDict(title="JobCreate", allow_inf_nan=False, extra="forbid")

    clip_id: str = Field(min_length=1, max_length=64)
    excitation: ExcitationSpec | None = Field(
        default=None,
        description="How the object was excited; a list gives one per object (each naming its object by "
        "`object_id`, `point_px` or `box_px`). Without it, stiffness and mass are null.",
    )
    parameters: AnalysisParameters = Field(default_factory=AnalysisParameters)
    force_log: ForceLog | None = Field(
        default=None,
        description="The robot's force sensor, recorded as a time series beside the clip: its push, hold and "
        "release, or its strike, is the excitation (stiffness and mass follow as from a typed one, and the "
        "result's `excitation.source` names the log). A typed `excitation` overrides it. Its clock: 0 is "
        "the clip's first frame, `offset_s` is added to every time. The job shows a summary of it, never "
        "its samples.",
    )
    callback_url: str | None = Field(
        default=None,
        min_length=1,
        max_length=2048,
        description="http(s) URL told when the job ends (a signed POST, retried until it answers 2xx). Its "
        "host must be on the server's allow-list.",
    )


class CallbackState(BaseModel):
    """Delivery of a job's webhook."""

    model_config = ConfigDict(title="Callback", **RESPONSE)

    url: str
    status: Literal["waiting", "pending", "delivered", "failed"] = Field(
        description="`waiting` for the job to end, `pending` delivery (retrying), `delivered`, or `failed` "
        "after every attempt."
    )
    attempts: int = Field(default=0, ge=0, description="Deliveries tried so far.")
    last_error: str | None = Field(default=None, description="Why the last attempt failed.")


class JobStatus(StrEnum):
    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"


#: What a job is doing: the store's states (``queued``, ``starting``, ``requeued``, ``retrying``, ``done``,
#: ``failed``, ``cancelled``) and the analysis's stages in their order (``setup`` or the ``survey`` of a
#: long clip, ``decode`` and ``flow`` of the frames -- reported together as ``flow`` --, ``spectrum``,
#: ``segmentation``, ``mechanics``, ``rendering`` of the images). The ``stage`` labels of
#: ``eigenscope_analysis_stage_seconds`` and the keys of ``AnalysisResult.timings_s`` use the same names.
JobStage = Literal[
    "queued",
    "starting",
    "setup",
    "survey",
    "decode",
    "flow",
    "spectrum",
    "segmentation",
    "mechanics",
    "rendering",
    "done",
    "requeued",
    "retrying",
    "cancelled",
    "failed",
]
#: ``upload``: a job of an uploaded clip; ``stream``: the job a live stream ended as.
JobSource = Literal["upload", "stream"]


class _JobFields(BaseModel):
    """The members a job and its summary share."""

    model_config = ConfigDict(allow_inf_nan=False, json_schema_serialization_defaults_required=True)

    id: str
    clip_id: str
    status: JobStatus
    progress: float = Field(ge=0, le=1)
    stage: JobStage | None = Field(default=None, description="What the job is doing (see the enumeration).")
    attempts: int = 0
    excitation: ExcitationSpec | None = None
    parameters: AnalysisParameters
    force_log: ForceLogSummary | None = Field(
        default=None, description="The force log the job was sent with (its samples are not echoed)."
    )
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    error: Problem | None = None
    callback: CallbackState | None = None
    source: JobSource = Field(
        default="upload", description="`stream`: the job a live stream ended as (see `/v1/streams`)."
    )


class JobModel(_JobFields):
    """A job record."""

    model_config = ConfigDict(title="Job", **RESPONSE)

    result: AnalysisResult | None = None


class ResultSummary(BaseModel):
    """The headline of a succeeded job's result: its main object's figures (each `*_uncertainty` a standard
    uncertainty) and counts of what else it holds. The whole result is one link away (`result_url`)."""

    model_config = ConfigDict(title="ResultSummary", **RESPONSE)

    eigenfrequency_hz: float | None = Field(description="The main object's eigenfrequency, Hz.")
    eigenfrequency_uncertainty_hz: float | None = None
    damping_ratio: float | None = None
    stiffness_n_per_m: float | None = None
    mass_kg: float | None = None
    objects: int = Field(ge=0, description="Objects found.")
    warnings: int = Field(ge=0, description="Quality flags of severity `warning` or `error`.")


class JobSummary(_JobFields):
    """A job as lists show it: the record without its result, a summary of the result instead, and where
    the whole result is."""

    model_config = ConfigDict(title="JobSummary", **RESPONSE)

    summary: ResultSummary | None = Field(default=None, description="Present once the job has succeeded.")
    url: str = Field(description="The job (`GET`: the whole record, its result included).")
    result_url: str | None = Field(
        default=None,
        description="The job's result alone (`GET /v1/jobs/{job_id}/result`, an `AnalysisResult`), once the "
        "job has succeeded.",
    )


class JobList(BaseModel):
    """A page of jobs, newest first (summaries: each job's whole result is at its `result_url`)."""

    model_config = ConfigDict(title="JobList", **RESPONSE)

    items: list[JobSummary]
    next_cursor: str | None = None


class JobEvent(BaseModel):
    """The body of a job's webhook: the job ended (see the `webhooks` of the OpenAPI document)."""

    model_config = ConfigDict(title="JobEvent", **RESPONSE)

    type: Literal["job.succeeded", "job.failed", "job.cancelled"] = Field(description="How the job ended.")
    timestamp: datetime = Field(description="When the event was sent (UTC).")
    data: JobModel = Field(description="The job, as `GET /v1/jobs/{job_id}` serves it.")

"""Job requests and records."""

from __future__ import annotations

from datetime import datetime
from enum import StrEnum
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from api_schemas.problem import Problem
from api_schemas.result import AnalysisResult


class StepReleaseExcitation(BaseModel):
    """Object held by a known force, then released: A = F/k."""

    model_config = ConfigDict(title="StepReleaseExcitation", allow_inf_nan=False, extra="forbid")

    type: Literal["step_release"]
    force_n: float = Field(gt=0, description="Holding force, newtons.")
    force_uncertainty_n: float = Field(default=0.0, ge=0)
    object_id: int | None = Field(default=None, ge=1, description="Which object; default the main one.")
    point_px: list[float] | None = Field(
        default=None, min_length=2, max_length=2, description="... or a point [x, y] on the object, pixels."
    )
    box_px: list[float] | None = Field(
        default=None, min_length=4, max_length=4, description="... or a box [x, y, w, h] around it, pixels."
    )


class ImpulseExcitation(BaseModel):
    """Object struck by a known impulse: v0 = J/m."""

    model_config = ConfigDict(title="ImpulseExcitation", allow_inf_nan=False, extra="forbid")

    type: Literal["impulse"]
    impulse_ns: float = Field(gt=0, description="Impulse, newton-seconds.")
    impulse_uncertainty_ns: float = Field(default=0.0, ge=0)
    object_id: int | None = Field(default=None, ge=1, description="Which object; default the main one.")
    point_px: list[float] | None = Field(
        default=None, min_length=2, max_length=2, description="... or a point [x, y] on the object, pixels."
    )
    box_px: list[float] | None = Field(
        default=None, min_length=4, max_length=4, description="... or a box [x, y, w, h] around it, pixels."
    )


Excitation = Annotated[StepReleaseExcitation | ImpulseExcitation, Field(discriminator="type")]

#: One excitation (for the main object, or the one it names), or one per excited object.
ExcitationSpec = Excitation | Annotated[list[Excitation], Field(min_length=1, max_length=16)]


class AnalysisParameters(BaseModel):
    """Analysis options; every field has a default that works without tuning."""

    model_config = ConfigDict(title="AnalysisParameters", allow_inf_nan=False, extra="forbid")

    method: Literal["default", "paper"] = "default"
    flow: Literal["farneback", "dis"] | None = Field(
        default=None, description="Optical flow; default depends on the method."
    )
    frames: int | None = Field(default=None, ge=8, le=100_000, description="Analysis window length N.")
    start_frame: int | None = Field(default=None, ge=0)
    fps: float | None = Field(default=None, gt=0, le=100_000, description="True recording rate, Hz.")
    fx: float | None = Field(default=None, gt=0)
    fy: float | None = Field(default=None, gt=0)
    cx: float | None = None
    cy: float | None = None
    depth_scale: float | None = Field(default=None, gt=0, description="Metres per depth unit.")
    depth_m: float | None = Field(
        default=None, gt=0, description="Object distance when the clip has no depth."
    )
    color_topic: str | None = Field(
        default=None,
        max_length=256,
        description="Bag topic of the colour images (default: chosen automatically).",
    )
    depth_topic: str | None = Field(
        default=None,
        max_length=256,
        description="Bag topic of the depth images (default: chosen automatically; `none` ignores depth).",
    )
    min_frequency_hz: float | None = Field(default=None, ge=0)
    max_frequency_hz: float | None = Field(default=None, gt=0)


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
    callback_url: str | None = Field(
        default=None,
        min_length=1,
        max_length=2048,
        description="http(s) URL told when the job ends (a signed POST, retried until it answers 2xx). Its "
        "host must be on the server's allow-list.",
    )


class CallbackState(BaseModel):
    """Delivery of a job's webhook."""

    model_config = ConfigDict(title="Callback")

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


class JobModel(BaseModel):
    """A job record."""

    model_config = ConfigDict(title="Job", allow_inf_nan=False)

    id: str
    clip_id: str
    status: JobStatus
    progress: float = Field(ge=0, le=1)
    stage: str | None = None
    attempts: int = 0
    excitation: ExcitationSpec | None = None
    parameters: AnalysisParameters
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    error: Problem | None = None
    result: AnalysisResult | None = None
    callback: CallbackState | None = None
    source: Literal["upload", "stream"] = Field(
        default="upload", description="`stream`: the job a live stream ended as (see `/v1/streams`)."
    )


class JobList(BaseModel):
    """A page of jobs, newest first."""

    model_config = ConfigDict(title="JobList", allow_inf_nan=False)

    items: list[JobModel]
    next_cursor: str | None = None

"""Live streams: the session resource (``/v1/streams``) and the messages of its WebSocket protocol.

A robot opens a session with ``POST /v1/streams``, connects to its WebSocket and sends frames as binary
messages; the server answers with the JSON messages below. The protocol is documented as an AsyncAPI 3
document (``openapi/asyncapi.json``) generated from these models.

Binary frame message: a 4-byte big-endian length ``L``, then ``L`` bytes of UTF-8 JSON (a
:class:`FrameHeader`), then the image bytes.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from api_schemas.job import AnalysisParameters, ExcitationSpec
from api_schemas.problem import Problem
from api_schemas.result import AnalysisResult

StreamStatus = Literal["waiting", "streaming", "finishing", "succeeded", "failed"]


class StreamCreate(BaseModel):
    """Request body of ``POST /v1/streams``."""

    model_config = ConfigDict(title="StreamCreate", extra="forbid")

    excitation: ExcitationSpec | None = Field(
        default=None,
        description="How the object is excited (as for a job); without it stiffness and mass are null.",
    )
    parameters: AnalysisParameters = Field(
        default_factory=AnalysisParameters,
        description="Frame rate (`fps`), intrinsics (`fx`, `fy`, `cx`, `cy`) and depth scale when known, "
        "and analysis options. `frames` is the most frames analysed (the window kept from just before the "
        "motion); `method` must be `default`; `start_frame` and the bag topics do not apply.",
    )
    target_relative_uncertainty: float = Field(
        default=0.01,
        gt=0,
        lt=0.5,
        description="`converged` is sent when the eigenfrequency's relative standard uncertainty is at "
        "most this (and the estimate is stable).",
    )
    max_duration_s: float = Field(
        default=60.0, gt=0, description="Longest capture (by frame timestamps) before the server ends it."
    )
    width: int | None = Field(default=None, ge=16, le=8192, description="Frame width; default the first's.")
    height: int | None = Field(default=None, ge=16, le=8192, description="Frame height; default the first's.")


class LiveEstimateModel(BaseModel):
    """The main object's figures from the frames so far (each `*_uncertainty` a standard uncertainty)."""

    model_config = ConfigDict(title="LiveEstimate")

    frames_received: int
    frames_used: list[int] = Field(description="[first, last) frame indices whose flow was used.")
    samples_after_release: int = Field(description="Flow samples fitted, from the release on.")
    release_time_s: float = Field(description="Release instant, seconds from the first frame.")
    periods: float = Field(description="Periods of motion fitted.")
    eigenfrequency_hz: float
    eigenfrequency_uncertainty_hz: float
    natural_frequency_hz: float | None = None
    damping_ratio: float | None = None
    damping_ratio_uncertainty: float | None = None
    amplitude_px: float | None = None
    amplitude_m: float | None = None
    amplitude_uncertainty_m: float | None = None
    depth_m: float | None = None
    stiffness_n_per_m: float | None = None
    stiffness_uncertainty_n_per_m: float | None = None
    mass_kg: float | None = None
    mass_uncertainty_kg: float | None = None
    snr_db: float | None = None
    relative_uncertainty: float = Field(description="eigenfrequency_uncertainty_hz / eigenfrequency_hz.")
    converged: bool
    null_reasons: list[str] = Field(default_factory=list)


class StreamModel(BaseModel):
    """A live stream session."""

    model_config = ConfigDict(title="Stream")

    id: str
    job_id: str = Field(description="The job the stream ends as (its result, images and clip).")
    clip_id: str = Field(description="The clip the stream's frames are kept as, once it has ended.")
    status: StreamStatus
    websocket_url: str = Field(description="Where to connect: `ws(s)://host/v1/streams/{id}`.")
    resume_token: str | None = Field(
        default=None,
        description="Only in the response that creates the session: send it as `?resume_token=` to "
        "reconnect after a dropped connection.",
    )
    excitation: ExcitationSpec | None = None
    parameters: AnalysisParameters
    target_relative_uncertainty: float
    max_duration_s: float
    frames_received: int = 0
    converged: bool = False
    last_estimate: LiveEstimateModel | None = None
    created_at: datetime
    updated_at: datetime | None = None
    error: Problem | None = None


class StreamList(BaseModel):
    """A page of streams, newest first."""

    model_config = ConfigDict(title="StreamList")

    items: list[StreamModel]


# WebSocket messages ----------------------------------------------------------------------------------


class FrameHeader(BaseModel):
    """The JSON header of a binary frame message.

    Send each frame's colour message first, then (for RGB-D) its depth message with the same `frame`.
    A colour frame is complete when its depth arrives, or when the next colour frame arrives (no depth).
    """

    model_config = ConfigDict(title="FrameHeader", extra="forbid")

    frame: int = Field(ge=0, description="Frame index, from 0, increasing.")
    kind: Literal["color", "depth"]
    timestamp_s: float = Field(description="Capture time, seconds (any origin); increasing.")
    encoding: Literal["jpeg", "png", "raw"] = Field(
        description="Colour: `jpeg` or `png`. Depth: 16-bit `png` or `raw` little-endian uint16."
    )
    width: int | None = Field(default=None, ge=1, description="Required for `raw` depth.")
    height: int | None = Field(default=None, ge=1, description="Required for `raw` depth.")


class EndMessage(BaseModel):
    """Client -> server (text): no more frames; analyse and send the `result`."""

    model_config = ConfigDict(title="EndMessage", extra="forbid")

    type: Literal["end"]


class ReadyMessage(BaseModel):
    """Server -> client, first on every connection."""

    model_config = ConfigDict(title="ReadyMessage")

    type: Literal["ready"]
    stream_id: str
    job_id: str
    window: int = Field(description="Most frame messages in flight (sent but not `accepted`).")
    next_frame: int = Field(description="The frame index to send next (after a resume: where to go on).")
    messages: int = Field(
        description="Frame messages the worker had consumed when this connection opened: a message's "
        "`messages` minus this, against the frame messages sent on this connection, gives those in flight."
    )
    resumed: bool = False


class AcceptedMessage(BaseModel):
    """Server -> client: a frame was decoded and taken into the analysis (flow control)."""

    model_config = ConfigDict(title="AcceptedMessage")

    type: Literal["accepted"]
    frame: int
    messages: int = Field(description="Frame messages (colour and depth) the worker has consumed.")
    in_flight: int = Field(description="Frame messages sent but not yet consumed.")
    window: int


class BackpressureMessage(BaseModel):
    """Server -> client: the worker is behind. `slow_down`: in-flight messages near the window;
    `dropped`: this frame message was refused (the window was full) and is not analysed."""

    model_config = ConfigDict(title="BackpressureMessage")

    type: Literal["backpressure"]
    action: Literal["slow_down", "dropped"]
    frame: int | None = None
    kind: Literal["color", "depth"] | None = None
    in_flight: int
    window: int


class EstimateMessage(BaseModel):
    """Server -> client: the estimate from the frames so far (at least 4 a second once motion is seen)."""

    model_config = ConfigDict(title="EstimateMessage")

    type: Literal["estimate"]
    estimate: LiveEstimateModel


class ConvergedMessage(BaseModel):
    """Server -> client: the target uncertainty is reached; the robot may stop recording."""

    model_config = ConfigDict(title="ConvergedMessage")

    type: Literal["converged"]
    quantity: Literal["eigenfrequency_hz"] = "eigenfrequency_hz"
    relative_uncertainty: float
    target_relative_uncertainty: float
    frames_received: int
    estimate: LiveEstimateModel


class ResultMessage(BaseModel):
    """Server -> client: the final result (the same schema as a job's), sent as soon as the analysis
    ends, then the server closes. The images it names are drawn after it is sent: the stream's job
    completes (and serves them) a moment later, so wait for the job (`GET /v1/jobs/{id}?wait=`) before
    fetching them."""

    model_config = ConfigDict(title="ResultMessage")

    type: Literal["result"]
    job_id: str
    clip_id: str
    result: AnalysisResult


class ErrorMessage(BaseModel):
    """Server -> client: an RFC 9457 problem naming the frame (`frame`) or field. `fatal`: the session is
    over (the server closes)."""

    model_config = ConfigDict(title="ErrorMessage")

    type: Literal["error"]
    fatal: bool
    frame: int | None = None
    messages: int | None = Field(default=None, description="As in `accepted`, when the worker sent it.")
    problem: Problem


ServerMessage = Annotated[
    ReadyMessage
    | AcceptedMessage
    | BackpressureMessage
    | EstimateMessage
    | ConvergedMessage
    | ResultMessage
    | ErrorMessage,
    Field(discriminator="type"),
]
